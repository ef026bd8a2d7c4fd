//! Thesis §2.1 preprocessing: turns a raw scan into splats by filling in what the input
//! lacks: PCA normals (Eq. 2.1), consistently oriented (Hoppe et al. 1992), and splat radii
//! from the local sampling density.
//!
//! Input normals and radii are trusted where valid; invalid entries (non-finite, zero-length
//! normals; non-finite or non-positive radii) are treated as missing for that point only and
//! recomputed. Computed normals are oriented to agree with any given ones, or to face the
//! scanner where the cloud knows where it stood (`PointCloud::viewpoints`).
//!
//! Bad input has defined outcomes, each counted in [`PreprocessStats`] for the caller to
//! report: points with a non-finite coordinate are dropped, so are repeats of an earlier
//! point's exact position (they would give zero neighbour distances and doubled disks);
//! collinear or coincident neighbourhoods get a defined normal and are counted as degenerate.
//! A radius cannot be estimated without two distinct points: [`preprocess`] returns
//! [`PreprocessError`] then, and for a cloud with no points left.

pub mod normals;
pub mod orient;
pub mod outliers;
pub mod radii;
pub mod visibility;

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use tracing::{debug, info};

use crate::PointCloud;
use crate::knn::{Neighbourhoods, k_nearest};
use crate::math::morton;

/// Preprocessing parameters. See [`PreprocessConfig::standard`] for measured defaults.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PreprocessConfig {
    /// Neighbours in the PCA covariance (Eq. 2.1), besides the point itself. Also the degree
    /// of the kNN graph used for orientation.
    pub k_normals: usize,
    /// The radius is `radius_scale ×` the distance to this neighbour.
    pub k_radius: usize,
    pub radius_scale: f32,
    /// Morton-sort the points first (faster kNN and accelerator builds; changes point order).
    pub sort: bool,
    /// Compute normals and radii even where the cloud has them.
    pub recompute: bool,
    /// What becomes of a point whose computed radius exceeds [`radii::MAX_OVER_NEIGHBOURS`]
    /// times its neighbours' median (a stray point).
    pub strays: Strays,
    /// Drop the points whose mean distance to their `k_normals` nearest neighbours exceeds the
    /// cloud's mean by this many standard deviations ([`outliers`]; PCL's and Open3D's filter,
    /// usually at 1 to 2). Off if `None`.
    pub outlier_std: Option<f32>,
}

/// What preprocessing does with stray points, whose computed radius would be a giant disk.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Strays {
    /// Drop them: a stray return or a no-return pixel stored at the origin is no surface.
    #[default]
    Drop,
    /// Keep them, their radii clamped to the limit.
    Clamp,
}

impl PreprocessConfig {
    /// k_normals 16, k_radius 8, radius_scale 1.0, sort on, recompute off.
    ///
    /// * k_normals = 16: on a noise-free 50k torus, ≥ 99.97 % of the normals are within 3°
    ///   for any k from 8 to 24 (mean error 0.76° at k 8, 0.66° at 16, 0.62° at 24); 16
    ///   averages out scanner noise and keeps the orientation graph well connected.
    /// * k_radius = 8, radius_scale = 1: 99.999 % of a randomly sampled sphere and 100 % of
    ///   a random plane patch and of anisotropic scan rows covered, at a mean radius of
    ///   3.1 × the mean nearest-neighbour spacing (the table in `radii`'s tests). Cheaper
    ///   settings reaching 99.9 % (k 6 / scale 1.0: 2.7×) leave holes in a few pixels per
    ///   million. Same rule as the Embree reference benchmark.
    pub fn standard() -> Self {
        Self {
            k_normals: 16,
            k_radius: 8,
            radius_scale: 1.0,
            sort: true,
            recompute: false,
            strays: Strays::Drop,
            outlier_std: None,
        }
    }

    /// Every parameter in range, else the first that is not, named.
    pub fn check(&self) -> Result<(), crate::settings::SettingsError> {
        use crate::settings::SettingsError;
        let check = |ok: bool, option, problem| if ok { Ok(()) } else { Err(SettingsError::new(option, problem)) };
        check(self.k_normals >= 3, "k_normals", "must be at least 3 (a plane needs 3 points)")?;
        check(self.k_radius >= 1, "k_radius", "must be at least 1")?;
        for (option, k) in [("k_normals", self.k_normals), ("k_radius", self.k_radius)] {
            if k > MAX_NEIGHBOURS {
                return Err(SettingsError::new(option, format!("must be at most {MAX_NEIGHBOURS}")));
            }
        }
        check(self.radius_scale > 0.0 && self.radius_scale.is_finite(), "radius_scale", "must be positive")?;
        let std = self.outlier_std.is_none_or(|s| s > 0.0 && s.is_finite());
        check(std, "outlier_std", "must be a positive number of standard deviations")
    }
}

impl Default for PreprocessConfig {
    fn default() -> Self {
        Self::standard()
    }
}

/// Seconds spent in each stage of [`preprocess`] (0 for a stage that did not run).
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct StageSeconds {
    /// Dropping non-finite and repeated points.
    pub clean: f64,
    pub sort: f64,
    /// Statistical outlier removal (its own neighbour search).
    pub outliers: f64,
    pub knn: f64,
    pub normals: f64,
    pub orient: f64,
    pub radii: f64,
}

impl StageSeconds {
    pub fn total(&self) -> f64 {
        self.clean + self.sort + self.outliers + self.knn + self.normals + self.orient + self.radii
    }
}

/// What [`preprocess`] did and how long each stage took.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct PreprocessStats {
    pub dropped_non_finite: usize,
    /// Points dropped because an earlier point has exactly the same position.
    pub dropped_duplicates: usize,
    /// Given normals that were zero or non-finite, re-estimated.
    pub invalid_normals: usize,
    /// Given radii that were zero, negative or non-finite, recomputed.
    pub invalid_radii: usize,
    /// Reported on its own (`--stats` writes it as `preprocess_seconds`).
    #[serde(skip)]
    pub seconds: StageSeconds,
    /// Some normals (possibly all) were estimated by PCA.
    pub computed_normals: bool,
    /// Some radii (possibly all) were computed.
    pub computed_radii: bool,
    pub flipped_normals: usize,
    /// Estimated normals whose neighbourhood was collinear or coincident (a defined fallback
    /// direction was used, see [`normals::pca`]).
    pub degenerate_normals: usize,
    /// Connected components oriented by a spanning tree each; 0 where the normals were turned
    /// to face the scanners' viewpoints instead (`PointCloud::viewpoints`).
    pub orientation_components: usize,
    /// Computed normals that views round the model set (they agreed on the point's side,
    /// [`visibility`]); the spanning trees oriented the rest from them.
    pub orientation_settled_by_views: usize,
    /// Computed normals the views saw clearly that face away from them all the same: a share
    /// above [`DOUBTFUL_AGAINST_VIEWS`] is warned about.
    pub orientation_against_views: usize,
    /// Computed normals of folds turned after the trees because their neighbours outvoted them
    /// (`orient::turn_against_neighbours`).
    pub orientation_turned_at_folds: usize,
    /// The given normals pointed into the shape and were turned outward
    /// (`orient::turn_given_outward`).
    pub turned_outward: bool,
    /// Computed radii clamped to [`radii::MAX_OVER_NEIGHBOURS`] times their neighbours' median
    /// (stray points kept by [`Strays::Clamp`], see [`radii::clamp_to_neighbours`]).
    pub clamped_radii: usize,
    /// Stray points dropped ([`Strays::Drop`]).
    pub dropped_strays: usize,
    /// Points dropped by the statistical outlier filter (`outlier_std`).
    pub dropped_outliers: usize,
}

/// See [`PreprocessStats::orientation_doubtful`].
pub const DOUBTFUL_AGAINST_VIEWS: f64 = 0.01;

impl PreprocessStats {
    /// One warning (`tracing`) per kind of bad point dropped or repaired, naming `input`.
    pub fn warn_repairs(&self, input: &str) {
        let limit = radii::MAX_OVER_NEIGHBOURS;
        let clamped = format!("over {limit} times the median of the neighbours' radii (stray points); clamped to that");
        let stray = format!("(radius over {limit} times the median of the neighbours')");
        let outlying = "far from their neighbours (statistical outliers)";
        // (count, what comes before it, the noun for one and for many, what comes after)
        let repairs = [
            (self.dropped_non_finite, "dropped ", "point", "points", "with a non-finite coordinate"),
            (self.dropped_duplicates, "dropped ", "point", "points", "at the exact position of an earlier point"),
            (
                self.invalid_normals,
                "",
                "normal was",
                "normals were",
                "zero or non-finite; estimated from the neighbours",
            ),
            (
                self.invalid_radii,
                "",
                "radius was",
                "radii were",
                "zero, negative or non-finite; computed from the neighbours",
            ),
            (self.clamped_radii, "", "radius was", "radii were", &clamped),
            (self.dropped_strays, "dropped ", "stray point", "stray points", &stray),
            (self.dropped_outliers, "dropped ", "point", "points", outlying),
            (
                self.degenerate_normals,
                "",
                "normal has",
                "normals have",
                "no plane through their neighbours (collinear, or none); set to a fallback direction",
            ),
        ];
        for (n, before, one, many, after) in repairs {
            if n > 0 {
                tracing::warn!("{input}: {before}{n} {} {after}", if n == 1 { one } else { many });
            }
        }
        if self.turned_outward {
            tracing::warn!("{input}: the normals pointed into the shape; turned outward");
        }
        if self.orientation_doubtful() {
            tracing::warn!(
                "{input}: {} normals face away from where views round the model see them (the views settled {}): \
                 the orientation is doubtful (thin parts, or pieces apart); if the render shows holes, give \
                 normals or the scanner's position",
                self.orientation_against_views,
                self.orientation_settled_by_views
            );
        }
    }

    /// More normals face away from the views that see them than [`DOUBTFUL_AGAINST_VIEWS`]
    /// of those the views settled.
    pub fn orientation_doubtful(&self) -> bool {
        self.orientation_against_views as f64 > DOUBTFUL_AGAINST_VIEWS * self.orientation_settled_by_views as f64
    }

    /// Adds the work of another cloud's preprocessing (a scene's clouds, summed).
    pub fn add(&mut self, o: &PreprocessStats) {
        self.dropped_non_finite += o.dropped_non_finite;
        self.dropped_duplicates += o.dropped_duplicates;
        self.invalid_normals += o.invalid_normals;
        self.invalid_radii += o.invalid_radii;
        self.computed_normals |= o.computed_normals;
        self.computed_radii |= o.computed_radii;
        self.flipped_normals += o.flipped_normals;
        self.degenerate_normals += o.degenerate_normals;
        self.orientation_components += o.orientation_components;
        self.orientation_settled_by_views += o.orientation_settled_by_views;
        self.orientation_against_views += o.orientation_against_views;
        self.orientation_turned_at_folds += o.orientation_turned_at_folds;
        self.turned_outward |= o.turned_outward;
        self.clamped_radii += o.clamped_radii;
        self.dropped_strays += o.dropped_strays;
        self.dropped_outliers += o.dropped_outliers;
        let (s, t) = (&mut self.seconds, &o.seconds);
        (s.clean, s.sort, s.outliers, s.knn, s.normals, s.orient, s.radii) = (
            s.clean + t.clean,
            s.sort + t.sort,
            s.outliers + t.outliers,
            s.knn + t.knn,
            s.normals + t.normals,
            s.orient + t.orient,
            s.radii + t.radii,
        );
    }
}

/// Why a cloud cannot be made into splats.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PreprocessError {
    #[error("the cloud has no (finite) points")]
    NoPoints,
    #[error("a splat radius cannot be estimated from a single distinct point (the file must give its radius)")]
    SinglePointWithoutRadius,
    #[error("{0} neighbours asked for; at most {MAX_NEIGHBOURS} are taken")]
    TooManyNeighbours(usize),
}

/// Refuses more neighbours than [`MAX_NEIGHBOURS`].
fn check_neighbours(cfg: &PreprocessConfig) -> Result<(), PreprocessError> {
    let k = cfg.k_normals.max(cfg.k_radius);
    if k > MAX_NEIGHBOURS { Err(PreprocessError::TooManyNeighbours(k)) } else { Ok(()) }
}

/// Most neighbours the normals or radii take: the search grows with k (a 36,000-point cloud
/// with 100,000 asked for ran for minutes), and neither needs more than a few dozen.
pub const MAX_NEIGHBOURS: usize = 256;

/// Makes `cloud` ready for splatting, in order: drops points with non-finite coordinates
/// and exact repeats (with their attributes), Morton-sorts (if `cfg.sort`), drops statistical
/// outliers (if `cfg.outlier_std`), re-normalises given normals, computes kNN once (only if
/// normals or radii are missing), PCA normals where missing, orients the computed ones, and
/// computes radii where missing, dropping (or clamping) the strays' (`cfg.strays`).
///
/// Panics if an attribute does not have one entry per point ([`PointCloud::check_lengths`]).
pub fn preprocess(cloud: &mut PointCloud, cfg: &PreprocessConfig) -> Result<PreprocessStats, PreprocessError> {
    preprocess_with_progress(cloud, cfg, &|_| {})
}

/// [`preprocess`], telling `stage` the name of each stage as it starts (`"clean"`, `"sort"`, `"outliers"`,
/// `"kNN"`, `"normals"`, `"orient"`, `"radii"`), for a progress display.
pub fn preprocess_with_progress(
    cloud: &mut PointCloud,
    cfg: &PreprocessConfig,
    stage: &dyn Fn(&'static str),
) -> Result<PreprocessStats, PreprocessError> {
    if let Err(e) = cloud.check_lengths() {
        panic!("preprocess: inconsistent point cloud: {e}");
    }
    check_neighbours(cfg)?;
    if cfg.recompute {
        (cloud.normals, cloud.radii) = (None, None);
    }
    stage("clean");
    let start = Instant::now();
    let mut stats = PreprocessStats {
        dropped_non_finite: drop_non_finite(cloud),
        dropped_duplicates: drop_duplicates(cloud),
        ..Default::default()
    };
    stats.seconds.clean = start.elapsed().as_secs_f64();
    if cloud.is_empty() {
        return Err(PreprocessError::NoPoints);
    }
    if cfg.sort && cloud.len() > 1 {
        stage("sort");
        let start = Instant::now();
        cloud.permute(&morton::sort_order(&cloud.positions));
        stats.seconds.sort = start.elapsed().as_secs_f64();
        debug!(seconds = stats.seconds.sort, "Morton sort");
    }
    if let Some(std_ratio) = cfg.outlier_std {
        stage("outliers");
        let start = Instant::now();
        stats.dropped_outliers = drop_outliers(cloud, cfg.k_normals, std_ratio);
        stats.seconds.outliers = start.elapsed().as_secs_f64();
    }
    let n = cloud.len();
    let normals_missing = invalid_normals(cloud);
    let radii_missing = invalid_radii(cloud);
    let need_normals = cloud.normals.is_none() || normals_missing.contains(&true);
    let need_radii = cloud.radii.is_none() || radii_missing.contains(&true);
    if let Some(normals) = &mut cloud.normals {
        stats.invalid_normals = normals_missing.iter().filter(|&&m| m).count();
        let given: Vec<bool> = normals_missing.iter().map(|m| !m).collect();
        stats.turned_outward = orient::turn_given_outward(&cloud.positions, normals, &given);
    }
    if cloud.radii.is_some() {
        stats.invalid_radii = radii_missing.iter().filter(|&&m| m).count();
    }
    stats.computed_normals = need_normals;
    stats.computed_radii = need_radii;
    if need_radii && n < 2 {
        return Err(PreprocessError::SinglePointWithoutRadius);
    }
    if !need_normals && !need_radii {
        info!(points = n, "preprocess: normals and radii given, nothing to compute");
        return Ok(stats);
    }

    let strays = fill_in(cloud, cfg, [&normals_missing, &radii_missing], &mut stats, stage);
    match cfg.strays {
        Strays::Clamp => stats.clamped_radii = strays.len(),
        Strays::Drop => stats.dropped_strays = drop_indices(cloud, &strays),
    }
    info!(
        points = cloud.len(),
        dropped = stats.dropped_non_finite,
        degenerate = stats.degenerate_normals,
        flipped = stats.flipped_normals,
        components = stats.orientation_components,
        seconds = stats.seconds.total(),
        "preprocess done"
    );
    Ok(stats)
}

/// The missing normals (PCA, oriented) and radii (`missing`: normals', radii's) of `cloud`, whose
/// other normals and radii are given; the strays, whose radii are clamped (ascending indices).
fn fill_in(
    cloud: &mut PointCloud,
    cfg: &PreprocessConfig,
    [normals_missing, radii_missing]: [&[bool]; 2],
    stats: &mut PreprocessStats,
    stage: &dyn Fn(&'static str),
) -> Vec<u32> {
    let n = cloud.len();
    let need_normals = cloud.normals.is_none() || normals_missing.contains(&true);
    let need_radii = cloud.radii.is_none() || radii_missing.contains(&true);
    if !need_normals && !need_radii {
        return Vec::new();
    }
    let k = match (need_normals, need_radii) {
        (true, true) => cfg.k_normals.max(cfg.k_radius),
        (true, false) => cfg.k_normals,
        _ => cfg.k_radius,
    };
    stage("kNN");
    let start = Instant::now();
    let nbrs = k_nearest(&cloud.positions, k);
    stats.seconds.knn = start.elapsed().as_secs_f64();
    debug!(k = nbrs.k, seconds = stats.seconds.knn, "kNN");

    if need_normals {
        fill_normals(cloud, &nbrs, cfg.k_normals, normals_missing, stats, stage);
    }
    if !need_radii {
        return Vec::new();
    }
    stage("radii");
    let start = Instant::now();
    let computed = radii::splat_radii(&cloud.positions, &nbrs, cfg.k_radius, cfg.radius_scale);
    let radii = cloud.radii.get_or_insert_with(|| vec![0.0; n]);
    for ((r, c), &missing) in radii.iter_mut().zip(computed).zip(radii_missing) {
        if missing {
            *r = c;
        }
    }
    let strays = radii::clamp_to_neighbours(radii, radii_missing, &nbrs);
    stats.seconds.radii = start.elapsed().as_secs_f64();
    debug!(seconds = stats.seconds.radii, "radii");
    strays
}

/// What preprocessing computes of one chunk of a cloud prepared out of core
/// (`pointray_io::prepare`), its points with the halo round it: the normals and radii
/// `missing` says, computed and oriented as [`preprocess`] does (the given normals, the halo's
/// already made among them, fixed and seeding the rest; a cloud's `viewpoints` faced). Returns
/// the strays (ascending indices), their radii clamped; dropping them is the caller's, as
/// `cfg.strays` says. Nothing is cleaned, sorted or turned: the caller did that for the cloud.
///
/// # Panics
/// If `missing` or an attribute does not have one entry per point.
pub fn fill_chunk(
    cloud: &mut PointCloud,
    missing: [&[bool]; 2],
    cfg: &PreprocessConfig,
) -> Result<Vec<u32>, PreprocessError> {
    if let Err(e) = cloud.check_lengths() {
        panic!("fill_chunk: inconsistent point cloud: {e}");
    }
    assert!(missing.iter().all(|m| m.len() == cloud.len()), "fill_chunk: a mask per point");
    check_neighbours(cfg)?;
    if missing[1].contains(&true) && cloud.len() < 2 {
        return Err(PreprocessError::SinglePointWithoutRadius);
    }
    Ok(fill_in(cloud, cfg, missing, &mut PreprocessStats::default(), &|_| {}))
}

/// Removes the statistical outliers among `k` neighbours ([`outliers`]); returns how many.
fn drop_outliers(cloud: &mut PointCloud, k: usize, std_ratio: f32) -> usize {
    if cloud.len() < 2 {
        return 0;
    }
    let keep = outliers::statistical_inliers(&k_nearest(&cloud.positions, k), std_ratio);
    let dropped = cloud.len() - keep.len();
    if dropped > 0 {
        cloud.permute(&keep);
    }
    dropped
}

/// Removes the points at `indices` (ascending); returns how many.
fn drop_indices(cloud: &mut PointCloud, indices: &[u32]) -> usize {
    if !indices.is_empty() {
        let keep: Vec<u32> = (0..cloud.len() as u32).filter(|i| indices.binary_search(i).is_err()).collect();
        cloud.permute(&keep);
    }
    indices.len()
}

/// Removes points with a non-finite coordinate; returns how many.
fn drop_non_finite(cloud: &mut PointCloud) -> usize {
    let keep: Vec<u32> = (0..cloud.len() as u32).filter(|&i| cloud.positions[i as usize].is_finite()).collect();
    let dropped = cloud.len() - keep.len();
    if dropped > 0 {
        cloud.permute(&keep);
        info!(dropped, "dropped points with non-finite coordinates");
    }
    dropped
}

/// Removes every point whose position (bit for bit, with -0 = +0) repeats an earlier one's,
/// keeping the first with its attributes; returns how many. Sorting the positions' bits finds
/// them in O(n log n) whatever the input order.
fn drop_duplicates(cloud: &mut PointCloud) -> usize {
    let bits = |p: Vec3| (p + Vec3::ZERO).to_array().map(f32::to_bits);
    let mut keyed: Vec<([u32; 3], u32)> =
        cloud.positions.par_iter().enumerate().map(|(i, &p)| (bits(p), i as u32)).collect();
    keyed.par_sort_unstable();
    let mut repeat = vec![false; cloud.len()];
    for pair in keyed.windows(2) {
        if pair[0].0 == pair[1].0 {
            repeat[pair[1].1 as usize] = true;
        }
    }
    drop(keyed);
    let keep: Vec<u32> = (0..cloud.len() as u32).filter(|&i| !repeat[i as usize]).collect();
    let dropped = cloud.len() - keep.len();
    if dropped > 0 {
        cloud.permute(&keep);
        info!(dropped, "dropped points repeating an earlier point's position");
    }
    dropped
}

/// Normalises the given normals in place; returns which are missing (all, without normals).
fn invalid_normals(cloud: &mut PointCloud) -> Vec<bool> {
    let Some(normals) = &mut cloud.normals else {
        return vec![true; cloud.positions.len()];
    };
    let missing: Vec<bool> = normals
        .par_iter_mut()
        .map(|n| match n.try_normalize() {
            Some(unit) => {
                *n = unit;
                false
            }
            None => true,
        })
        .collect();
    let count = missing.iter().filter(|&&m| m).count();
    if count > 0 {
        info!(count, "given normals invalid (zero or non-finite): re-estimating those");
    }
    missing
}

/// Which radii are missing: all without radii, else the non-finite or non-positive ones.
fn invalid_radii(cloud: &PointCloud) -> Vec<bool> {
    match &cloud.radii {
        None => vec![true; cloud.positions.len()],
        Some(radii) => radii.iter().map(|r| !(r.is_finite() && *r > 0.0)).collect(),
    }
}

/// PCA normals for the missing entries, then orientation: towards the scanners where the cloud
/// knows them, from the given normals where there are some, else from views round a closed
/// shape and the highest point of each component ([`orient_by_views`]).
fn fill_normals(
    cloud: &mut PointCloud,
    nbrs: &Neighbourhoods,
    k: usize,
    missing: &[bool],
    stats: &mut PreprocessStats,
    stage: &dyn Fn(&'static str),
) {
    stage("normals");
    let start = Instant::now();
    let positions = &cloud.positions;
    let normals = cloud.normals.get_or_insert_with(|| vec![Vec3::Z; positions.len()]);
    // Surface variation, for orienting a cloud whose normals are all computed (0 where given).
    let mut variation = vec![0f32; positions.len()];
    let degenerate = normals
        .par_iter_mut()
        .zip(&mut variation)
        .zip(missing)
        .enumerate()
        .filter(|(_, (_, missing))| **missing)
        .map(|(i, ((n, v), _))| {
            let pca = normals::pca(positions, i, nbrs, k);
            (*n, *v) = (pca.normal, pca.variation);
            usize::from(!pca.determined)
        })
        .sum();
    stats.degenerate_normals = degenerate;
    stats.seconds.normals = start.elapsed().as_secs_f64();
    debug!(degenerate, seconds = stats.seconds.normals, "PCA normals");

    stage("orient");
    let start = Instant::now();
    if !cloud.viewpoints.is_empty() {
        let of = cloud.viewpoint_of.as_deref();
        stats.flipped_normals = orient::face_viewpoints(positions, normals, missing, &cloud.viewpoints, of);
    } else if missing.contains(&false) {
        // Some normals given: they are trusted, and seed the rest.
        let fixed: Vec<bool> = missing.iter().map(|m| !m).collect();
        let orientation = orient::orient_normals_from(positions, normals, nbrs, Some(&fixed));
        stats.flipped_normals = orientation.flipped;
        stats.orientation_components = orientation.components;
    } else {
        let orientation = orient_by_views(positions, normals, nbrs, &variation);
        stats.flipped_normals = orientation.flipped;
        stats.orientation_components = orientation.components;
        stats.orientation_settled_by_views = orientation.settled_by_views;
        stats.orientation_against_views = orientation.against_views;
        stats.orientation_turned_at_folds = orientation.turned_at_folds;
    }
    stats.seconds.orient = start.elapsed().as_secs_f64();
    debug!(flipped = stats.flipped_normals, seconds = stats.seconds.orient, "orientation");
}

/// Orients computed normals from views round the model ([`visibility`]): the points the views
/// agree on are turned to face them and seed the spanning trees, which orient the rest, and
/// the points of folds (by their surface `variation`) are turned where their neighbours outvote
/// the tree ([`orient::turn_against_neighbours`]). A cloud the views do not see as closed keeps
/// the trees' orientation alone ([`visibility::looks_closed`]).
fn orient_by_views(
    positions: &[Vec3],
    normals: &mut [Vec3],
    nbrs: &Neighbourhoods,
    variation: &[f32],
) -> orient::OrientStats {
    let radii = radii::splat_radii(positions, nbrs, visibility::FOOTPRINT_K, 1.0);
    // The views' sums do not depend on the normals' signs, only their verdicts do.
    let votes = visibility::outward_votes(positions, normals, &radii);
    if !visibility::looks_closed(&votes) {
        return orient::orient_normals(positions, normals, nbrs);
    }
    let pca: Vec<Vec3> = normals.to_vec();
    let settled: Vec<bool> = votes.iter().map(visibility::Vote::settles).collect();
    for ((n, vote), &settled) in normals.iter_mut().zip(&votes).zip(&settled) {
        if settled && vote.agreement() < 0.0 {
            *n = -*n;
        }
    }
    let mut orientation = orient::orient_normals_from(positions, normals, nbrs, Some(&settled));
    assert_eq!(variation.len(), positions.len());
    let fold = orient::fold_threshold(variation);
    let fixed: Vec<bool> = settled.iter().zip(variation).map(|(&s, &v)| s || v.is_nan() || v <= fold).collect();
    orientation.turned_at_folds = orient::turn_against_neighbours(positions, normals, nbrs, Some(&fixed));
    debug!(turned = orientation.turned_at_folds, fold, "the folds' votes");
    orientation.flipped = normals.iter().zip(&pca).filter(|(n, p)| n.dot(**p) < 0.0).count();
    orientation.settled_by_views = settled.iter().filter(|&&s| s).count();
    orientation.against_views = (0..normals.len())
        .filter(|&i| votes[i].clearly_seen() && (votes[i].agreement() > 0.0) != (normals[i].dot(pca[i]) > 0.0))
        .count();
    orientation
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::preprocess::normals::tests::{THIN, ellipsoid, sphere, torus};
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    /// A closed cone standing on its base (radius 0.25, height 1), 20,000 random points with
    /// the normals `outward`.
    fn cone() -> (Vec<Vec3>, Vec<Vec3>) {
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        let (radius, height) = (0.25f32, 1.0f32);
        let slant = (radius * radius + height * height).sqrt();
        let (mut points, mut outward) = (Vec::new(), Vec::new());
        for _ in 0..20_000 {
            let (phi, u): (f32, f32) = (rng.random_range(0.0..std::f32::consts::TAU), rng.random());
            if rng.random::<f32>() < radius / (radius + slant) {
                // The base disk, by area.
                let r = radius * u.sqrt();
                points.push(Vec3::new(r * phi.cos(), 0.0, r * phi.sin()));
                outward.push(-Vec3::Y);
            } else {
                let s = u.sqrt(); // distance from the apex, as a share of the side
                points.push(Vec3::new(radius * s * phi.cos(), height * (1.0 - s), radius * s * phi.sin()));
                outward.push(Vec3::new(height * phi.cos(), radius, height * phi.sin()).normalize());
            }
        }
        (points, outward)
    }

    /// Views round a closed cone settle nearly every point, each on the side it truly faces,
    /// whichever sign PCA gave it; preprocessing orients it from them with fewer normals
    /// inward than the spanning tree alone (measured: 8 against 16; 9 before the folds' votes).
    #[test]
    fn views_settle_a_closed_cone_from_outside() {
        let (points, outward) = cone();
        let nbrs = k_nearest(&points, 16);
        let (pca, _) = normals::pca_normals(&points, &nbrs, 16);
        let radii = radii::splat_radii(&points, &nbrs, visibility::FOOTPRINT_K, 1.0);
        let votes = visibility::outward_votes(&points, &pca, &radii);
        assert!(visibility::looks_closed(&votes));
        let settled: Vec<usize> = (0..points.len()).filter(|&i| votes[i].settles()).collect();
        let wrong = settled.iter().filter(|&&i| (votes[i].agreement() > 0.0) != (pca[i].dot(outward[i]) > 0.0));
        assert!(settled.len() > 19_000 && wrong.count() <= 5, "{} settled", settled.len());

        let inward = |normals: &[Vec3]| normals.iter().zip(&outward).filter(|(n, o)| n.dot(**o) <= 0.0).count();
        let mut cloud = PointCloud::from_positions(points.clone());
        let stats = preprocess(&mut cloud, &PreprocessConfig { sort: false, ..PreprocessConfig::standard() }).unwrap();
        let mut tree_only = pca.clone();
        orient::orient_normals(&points, &mut tree_only, &nbrs);
        assert!(inward(cloud.normals.as_ref().unwrap()) < inward(&tree_only), "{stats:?}");
        assert!(stats.orientation_settled_by_views == settled.len() && !stats.orientation_doubtful());
    }

    /// A thin flat ellipsoid (semi-axes 1, 1 and 0.05, the trees' hard case in `orient`'s
    /// tests): the folds' votes turn some of the signs the trees got wrong at its rim back
    /// (measured: 123 normals inward → 110, 29 turned), and with no point above the fold
    /// threshold (every variation 0), none.
    #[test]
    fn the_folds_votes_mend_a_thin_ellipsoids_rim() {
        let (points, outward) = ellipsoid(20_000, THIN, 8);
        let nbrs = k_nearest(&points, 16);
        let pca: Vec<normals::Pca> = (0..points.len()).map(|i| normals::pca(&points, i, &nbrs, 16)).collect();
        let orient = |variation: &[f32]| {
            let mut n: Vec<Vec3> = pca.iter().map(|p| p.normal).collect();
            let stats = orient_by_views(&points, &mut n, &nbrs, variation);
            (n.iter().zip(&outward).filter(|(n, o)| n.dot(**o) <= 0.0).count(), stats.turned_at_folds)
        };
        let variation: Vec<f32> = pca.iter().map(|p| p.variation).collect();
        let ((with, turned), (without, none)) = (orient(&variation), orient(&vec![0.0; points.len()]));
        println!("inward: {with} with the folds' votes ({turned} turned), {without} without");
        assert_eq!(none, 0);
        assert!(turned > 0 && with < without, "{with} inward with {turned} turned, {without} without");
    }

    /// An open sheet is seen from both sides: the views do not take it for a closed shape
    /// and leave its orientation to the spanning tree.
    #[test]
    fn views_leave_an_open_sheet_to_the_tree() {
        let sheet: Vec<Vec3> = (0..100 * 100)
            .map(|i| Vec3::new((i % 100) as f32 / 100.0, (i / 100) as f32 / 100.0, 1e-3 * (i as f32).sin()))
            .collect();
        let mut cloud = PointCloud::from_positions(sheet);
        let stats = preprocess(&mut cloud, &PreprocessConfig { sort: false, ..PreprocessConfig::standard() }).unwrap();
        assert_eq!((stats.orientation_settled_by_views, stats.orientation_against_views), (0, 0));
        let normals = cloud.normals.unwrap();
        assert!(normals.iter().all(|n| n.z > 0.5), "the highest point's side, +z, for all");
    }

    #[test]
    fn fills_everything_for_bare_positions() {
        let (points, outward) = sphere(5_000, 1);
        let mut cloud = PointCloud::from_positions(points);
        let stats = preprocess(&mut cloud, &PreprocessConfig { sort: false, ..PreprocessConfig::standard() }).unwrap();
        assert!(stats.computed_normals && stats.computed_radii);
        assert_eq!((stats.degenerate_normals, stats.orientation_components), (0, 1));
        let normals = cloud.normals.unwrap();
        assert!(normals.iter().zip(&outward).all(|(n, o)| n.dot(*o) > 0.9));
        assert!(cloud.radii.unwrap().iter().all(|&r| r > 0.0 && r < 0.2));
    }

    #[test]
    fn sorting_keeps_attributes_with_their_points() {
        let (points, outward) = torus(5_000, 1.0, 0.35, 2);
        let mut cloud = PointCloud::from_positions(points);
        cloud.colors = Some(outward.iter().map(|n| n.to_array()).collect());
        preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        let normals = cloud.normals.unwrap();
        for (n, c) in normals.iter().zip(cloud.colors.unwrap()) {
            assert!(n.dot(Vec3::from(c)) > 0.9);
        }
    }

    #[test]
    fn strays_are_dropped_or_clamped_and_outliers_dropped_on_request() {
        let (mut points, _) = sphere(5_000, 1);
        // A stray return far off the unit sphere, and two points off it (outliers to the
        // statistical filter, not strays: their radii stay below 8 times their neighbours').
        points.extend([Vec3::new(0.0, 3.0, 0.0), Vec3::new(1.3, 0.0, 0.0), Vec3::new(0.0, 0.0, -1.3)]);
        let cloud_of = |points: &[Vec3]| {
            let mut cloud = PointCloud::from_positions(points.to_vec());
            cloud.scan.gps_time = Some((0..points.len()).map(|i| i as f64).collect());
            cloud
        };
        let config = PreprocessConfig { sort: false, ..PreprocessConfig::standard() };
        let mut cloud = cloud_of(&points);
        let stats = preprocess(&mut cloud, &config).unwrap();
        assert_eq!((stats.dropped_strays, stats.clamped_radii, cloud.len()), (1, 0, 5_002));
        assert!(cloud.positions.iter().all(|p| p.length() < 2.0), "the stray is gone");
        let times = cloud.scan.gps_time.as_ref().unwrap();
        assert_eq!((times[4_999], times[5_000]), (4_999.0, 5_001.0), "attributes follow their points");
        let mut clamped = cloud_of(&points);
        let stats = preprocess(&mut clamped, &PreprocessConfig { strays: Strays::Clamp, ..config }).unwrap();
        assert_eq!((stats.dropped_strays, stats.clamped_radii, clamped.len()), (0, 1, 5_003));
        let mut filtered = cloud_of(&points);
        let stats = preprocess(&mut filtered, &PreprocessConfig { outlier_std: Some(3.0), ..config }).unwrap();
        assert_eq!((stats.dropped_outliers, stats.dropped_strays), (3, 0), "all three, before the radii");
        assert!(filtered.positions.iter().all(|p| (p.length() - 1.0).abs() < 1e-5));
        let bad = PreprocessConfig { outlier_std: Some(0.0), ..config };
        assert_eq!(bad.check().unwrap_err().option, "outlier_std");
    }

    #[test]
    fn drops_non_finite_points_and_repairs_invalid_attributes() {
        let (mut points, mut given) = sphere(3_000, 3);
        let mut radii = vec![0.05f32; points.len()];
        points[10] = Vec3::new(f32::NAN, 0.0, 0.0);
        points[20].y = f32::INFINITY;
        given[30] = Vec3::ZERO;
        given[40] = Vec3::splat(f32::NAN);
        given[50] *= -7.0; // valid but inward and not unit: trusted, re-normalised
        radii[60] = -1.0;
        let expected_50 = given[50].normalize();
        let p60 = points[60];
        let mut cloud = PointCloud::from_positions(points);
        cloud.normals = Some(given);
        cloud.radii = Some(radii);
        let stats = preprocess(&mut cloud, &PreprocessConfig { sort: false, ..PreprocessConfig::standard() }).unwrap();
        assert_eq!(stats.dropped_non_finite, 2);
        assert_eq!((stats.invalid_normals, stats.invalid_radii, stats.dropped_duplicates), (2, 1, 0));
        assert_eq!(cloud.len(), 2_998);
        assert!(stats.computed_normals && stats.computed_radii);
        let normals = cloud.normals.as_ref().unwrap();
        let radii = cloud.radii.as_ref().unwrap();
        // Indices shifted by the two dropped points before them.
        assert!(normals[28].dot(cloud.positions[28]) > 0.9);
        assert!(normals[38].dot(cloud.positions[38]) > 0.9);
        assert!((normals[48] - expected_50).length() < 1e-6);
        assert_eq!(cloud.positions[58], p60);
        assert!(radii[58] > 0.0 && radii[58] < 0.2);
        assert!(normals.iter().all(|n| n.is_normalized()));
    }

    /// Given normals and radii are kept, but normals that all point into the shape are turned
    /// outward (and the turn reported).
    #[test]
    fn given_attributes_are_kept() {
        let (points, outward) = sphere(1_000, 4);
        for (sign, turned) in [(1.0, false), (-1.0, true)] {
            let mut cloud = PointCloud::from_positions(points.clone());
            cloud.normals = Some(outward.iter().map(|n| *n * sign).collect());
            cloud.radii = Some(vec![0.1; 1_000]);
            let stats =
                preprocess(&mut cloud, &PreprocessConfig { sort: false, ..PreprocessConfig::standard() }).unwrap();
            assert!(!stats.computed_normals && !stats.computed_radii);
            assert_eq!(stats.turned_outward, turned);
            let normals = cloud.normals.unwrap();
            assert!(normals.iter().zip(&outward).all(|(n, o)| (*n - *o).length() < 1e-6), "sign {sign}");
            assert_eq!(cloud.radii.unwrap(), vec![0.1; 1_000]);
        }
    }

    #[test]
    fn tiny_and_degenerate_clouds() {
        let cfg = PreprocessConfig::standard();
        for n in 2..5 {
            let mut cloud = PointCloud::from_positions((0..n).map(|i| Vec3::X * i as f32).collect());
            let stats = preprocess(&mut cloud, &cfg).unwrap();
            assert_eq!(stats.degenerate_normals, n, "collinear: no normal is determined");
            assert_eq!(cloud.normals.as_ref().map(Vec::len), Some(n));
            assert!(cloud.radii.as_ref().unwrap().iter().all(|&r| r > 0.0));
        }
        let mut cloud = PointCloud::from_positions(vec![Vec3::splat(f32::NAN); 3]);
        assert_eq!(preprocess(&mut cloud, &cfg).unwrap_err(), PreprocessError::NoPoints);
        let mut cloud = PointCloud::from_positions(Vec::new());
        assert_eq!(preprocess(&mut cloud, &cfg).unwrap_err(), PreprocessError::NoPoints);
        // One distinct point: no density to take a radius from, unless the file gives one.
        let mut cloud = PointCloud::from_positions(vec![Vec3::ONE; 100]);
        assert_eq!(preprocess(&mut cloud, &cfg).unwrap_err(), PreprocessError::SinglePointWithoutRadius);
        let mut cloud = PointCloud::from_positions(vec![Vec3::ONE; 100]);
        cloud.radii = Some(vec![0.5; 100]);
        let stats = preprocess(&mut cloud, &cfg).unwrap();
        assert_eq!((stats.dropped_duplicates, stats.degenerate_normals, cloud.len()), (99, 1, 1));
        assert_eq!((cloud.normals.unwrap(), cloud.radii.unwrap()), (vec![Vec3::Z], vec![0.5]));
        // A scanner's viewpoint below a plane: every computed normal faces it, where the
        // spanning tree would have seeded the plane's normals upwards.
        let mut cloud =
            PointCloud::from_positions((0..100).map(|i| Vec3::new((i % 10) as f32, (i / 10) as f32, 0.0)).collect());
        cloud.viewpoints = vec![Vec3::new(4.5, 4.5, -5.0)];
        let stats = preprocess(&mut cloud, &PreprocessConfig { sort: false, ..cfg }).unwrap();
        assert!(cloud.normals.unwrap().iter().all(|n| *n == -Vec3::Z));
        assert_eq!((stats.orientation_components, stats.flipped_normals), (0, 100));
        // Too many neighbours asked for: refused before any work.
        let mut cloud = PointCloud::from_positions((0..10).map(|i| Vec3::X * i as f32).collect());
        let greedy = PreprocessConfig { k_normals: MAX_NEIGHBOURS + 1, ..cfg };
        assert_eq!(
            preprocess(&mut cloud, &greedy).unwrap_err(),
            PreprocessError::TooManyNeighbours(MAX_NEIGHBOURS + 1)
        );
        assert_eq!(cloud.len(), 10);
    }

    #[test]
    fn exact_repeats_are_dropped_keeping_the_first() {
        let (points, outward) = sphere(2_000, 5);
        // Every tenth point again, after the originals, with other attributes; -0 repeats +0.
        let mut positions = points.clone();
        positions.extend(points.iter().step_by(10));
        positions.push(Vec3::new(0.0, 0.0, 0.0));
        positions.push(Vec3::new(-0.0, 0.0, -0.0));
        let n = positions.len();
        let mut cloud = PointCloud::from_positions(positions);
        let mut colors = vec![[0.0; 3]; n];
        colors[2_000..].iter_mut().for_each(|c| *c = [1.0; 3]);
        cloud.colors = Some(colors);
        cloud.normals = Some(outward.iter().chain(outward.iter().step_by(10)).copied().chain([Vec3::Z; 2]).collect());
        let stats = preprocess(&mut cloud, &cfg_unsorted()).unwrap();
        assert_eq!(stats.dropped_duplicates, 201);
        assert_eq!(cloud.len(), 2_001);
        assert_eq!(cloud.positions[..2_000], points[..]);
        assert!(cloud.colors.unwrap()[..2_000].iter().all(|c| *c == [0.0; 3]), "the first occurrence is kept");
    }

    fn cfg_unsorted() -> PreprocessConfig {
        PreprocessConfig { sort: false, ..PreprocessConfig::standard() }
    }

    #[test]
    fn a_plane_gets_one_consistent_normal() {
        let points: Vec<Vec3> = (0..900).map(|i| Vec3::new((i % 30) as f32, (i / 30) as f32, 2.0)).collect();
        let mut cloud = PointCloud::from_positions(points);
        let stats = preprocess(&mut cloud, &cfg_unsorted()).unwrap();
        assert_eq!((stats.degenerate_normals, stats.orientation_components), (0, 1));
        let normals = cloud.normals.unwrap();
        assert!(normals.iter().all(|n| (*n - normals[0]).length() < 1e-5 && n.z.abs() > 0.99999));
        // The 8th neighbour: √2 inside the grid, √8 at a corner.
        assert!(cloud.radii.unwrap().iter().all(|&r| (2f32.sqrt()..=8f32.sqrt()).contains(&r)));
    }

    /// Per-stage timing on 1M points of a torus (run in release:
    /// `cargo test --release -p pointray --lib -- --ignored million --nocapture`).
    #[test]
    #[ignore]
    fn time_stages_on_a_million_point_torus() {
        let (points, outward) = torus(1_000_000, 1.0, 0.35, 9);
        let mut cloud = PointCloud::from_positions(points);
        cloud.colors = Some(outward.iter().map(|n| n.to_array()).collect());
        let start = Instant::now();
        let stats = preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        let total = start.elapsed().as_secs_f64();
        println!(
            "1M torus, {} threads: sort {:.3} s, kNN {:.3} s, normals {:.3} s, orient {:.3} s, \
             radii {:.3} s, total {total:.3} s",
            rayon::current_num_threads(),
            stats.seconds.sort,
            stats.seconds.knn,
            stats.seconds.normals,
            stats.seconds.orient,
            stats.seconds.radii,
        );
        println!("{stats:?}");
        let inward = cloud
            .normals
            .unwrap()
            .iter()
            .zip(cloud.colors.unwrap())
            .filter(|(n, o)| n.dot(Vec3::from(*o)) <= 0.0)
            .count();
        assert_eq!(inward, 0);
    }
}
