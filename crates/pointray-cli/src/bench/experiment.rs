//! Experiment files (TOML): the models, and the matrices of accelerator × surface scheme ×
//! level of detail × camera distance that `pointray bench` measures on them
//! (`experiments/README.md` documents every key).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail, ensure};
use pointray::accel::NodeBounds;
use pointray::splat::scheme::SurfaceKind;
use serde::Deserialize;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Experiment {
    pub title: String,
    #[serde(default = "default_size")]
    pub width: u32,
    #[serde(default = "default_size")]
    pub height: u32,
    /// Timed frames per point, after one untimed frame that also gives the image; more when
    /// they would take less than `min_seconds` together (small crops of distant models).
    #[serde(default = "default_repeats")]
    pub repeats: u32,
    #[serde(default = "default_min_seconds")]
    pub min_seconds: f64,
    /// Other processes may use this many cores during a point's timed frames; above it the
    /// point is measured again, up to `retries` times, and the quietest attempt kept.
    #[serde(default = "default_max_other_load")]
    pub max_other_load: f64,
    #[serde(default = "default_retries")]
    pub retries: u32,
    #[serde(default)]
    pub camera: CameraSpec,
    /// Shadow rays from a headlight, Embree's too (off: primary rays only).
    #[serde(default)]
    pub shadows: bool,
    /// The surface scheme of the reference image every point is also compared with (full
    /// detail); its points' own full-detail image is always the first comparison.
    pub reference: Option<SurfaceKind>,
    /// Samples a pixel of the converged image: when given, every image is also compared with
    /// its scheme's full-detail image at this many samples a pixel (the quality experiments).
    pub converged_spp: Option<u32>,
    /// Embree's point bench (`shared/bench/embree`), run beside each model in the same session.
    pub embree: Option<PathBuf>,
    #[serde(rename = "model")]
    pub models: Vec<ModelSpec>,
    #[serde(rename = "matrix")]
    pub matrices: Vec<Matrix>,
}

fn default_size() -> u32 {
    512
}
fn default_repeats() -> u32 {
    5
}
fn default_min_seconds() -> f64 {
    0.3
}
fn default_max_other_load() -> f64 {
    0.3
}
fn default_retries() -> u32 {
    2
}

/// The camera of Embree's bench: it looks at the model's bounding-box centre from `view_dir`,
/// `distance` bounding-box diagonals away.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraSpec {
    pub view_dir: [f32; 3],
    pub up: [f32; 3],
    /// Vertical, degrees: at distance 1 and 60° the bounding sphere just fills the frame.
    pub fov: f32,
    /// Trace only the pixels of the model's projected bounding box.
    pub crop_to_model: bool,
}

impl Default for CameraSpec {
    fn default() -> Self {
        Self { view_dir: [0.4, 0.3, 1.0], up: [0.0, 1.0, 0.0], fov: 60.0, crop_to_model: true }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSpec {
    pub name: String,
    /// A point-cloud file, relative to the experiment file;
    pub file: Option<PathBuf>,
    /// or a triangle mesh, sampled with `points` points (as `pointray sample` does).
    pub mesh: Option<PathBuf>,
    pub points: Option<u64>,
    /// The model's up and view, when not the camera's.
    pub up: Option<[f32; 3]>,
    pub view_dir: Option<[f32; 3]>,
}

/// Where a model's points come from.
pub enum Source {
    Cloud(PathBuf),
    Mesh { path: PathBuf, points: u64 },
}

impl ModelSpec {
    pub fn source(&self, folder: &Path) -> anyhow::Result<Source> {
        match (&self.file, &self.mesh, self.points) {
            (Some(file), None, None) => Ok(Source::Cloud(folder.join(file))),
            (None, Some(mesh), Some(points)) if points > 0 => Ok(Source::Mesh { path: folder.join(mesh), points }),
            _ => bail!("model {}: give `file`, or `mesh` and a positive `points`", self.name),
        }
    }
}

/// Every combination of its lists is a point of the experiment.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Matrix {
    /// The models it covers, by name (default: all).
    pub models: Option<Vec<String>>,
    pub accel: Vec<AccelVariant>,
    pub surface: Vec<SurfaceKind>,
    /// Level-of-detail thresholds in pixels; 0 is full detail.
    pub lod_threshold: Vec<f32>,
    pub distance: Vec<f32>,
    /// Samples a pixel (default: one).
    #[serde(default = "one_sample")]
    pub spp: Vec<u32>,
    /// The footprint prefilter off, on, or both (default: off; on is left out at threshold 0,
    /// full detail, and at more than one sample a pixel, where it does not apply).
    #[serde(default = "prefilter_off")]
    pub prefilter: Vec<bool>,
}

fn prefilter_off() -> Vec<bool> {
    vec![false]
}

fn one_sample() -> Vec<u32> {
    vec![1]
}

/// An accelerator and the variant of its bounding volumes: `bvh` (boxes), `bvh-spheres`
/// (spheres from the root down), `bvh-mixed-L` (boxes above level L, spheres from it),
/// `bvh-auto` (each node's by surface area), `kdtree`, or `brute`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Deserialize)]
#[serde(try_from = "String")]
pub enum AccelVariant {
    Bvh(NodeBounds),
    KdTree,
    Brute,
}

impl AccelVariant {
    pub fn name(&self) -> String {
        match self {
            AccelVariant::Bvh(NodeBounds::Boxes) => "bvh".into(),
            AccelVariant::Bvh(NodeBounds::SpheresFrom(0)) => "bvh-spheres".into(),
            AccelVariant::Bvh(NodeBounds::SpheresFrom(level)) => format!("bvh-mixed-{level}"),
            AccelVariant::Bvh(NodeBounds::Auto) => "bvh-auto".into(),
            AccelVariant::KdTree => "kdtree".into(),
            AccelVariant::Brute => "brute".into(),
        }
    }

    pub fn node_bounds(&self) -> NodeBounds {
        match self {
            AccelVariant::Bvh(bounds) => *bounds,
            _ => NodeBounds::Boxes,
        }
    }

    pub fn kind(&self) -> pointray::settings::AccelKind {
        use pointray::settings::AccelKind;
        match self {
            AccelVariant::Bvh(_) => AccelKind::Bvh,
            AccelVariant::KdTree => AccelKind::Kdtree,
            AccelVariant::Brute => AccelKind::Brute,
        }
    }
}

impl TryFrom<String> for AccelVariant {
    type Error = String;

    fn try_from(name: String) -> Result<Self, String> {
        Ok(match name.as_str() {
            "bvh" => AccelVariant::Bvh(NodeBounds::Boxes),
            "bvh-spheres" => AccelVariant::Bvh(NodeBounds::SpheresFrom(0)),
            "bvh-auto" => AccelVariant::Bvh(NodeBounds::Auto),
            "kdtree" => AccelVariant::KdTree,
            "brute" => AccelVariant::Brute,
            _ => match name.strip_prefix("bvh-mixed-").and_then(|l| l.parse().ok()) {
                Some(level) => AccelVariant::Bvh(NodeBounds::SpheresFrom(level)),
                None => {
                    return Err(format!(
                        "unknown accelerator {name:?}: bvh, bvh-spheres, bvh-mixed-LEVEL, bvh-auto, kdtree or brute"
                    ));
                }
            },
        })
    }
}

/// One measurement: a model seen by one accelerator variant through one scheme at one level
/// of detail and distance.
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
pub struct Point {
    pub accel: AccelVariant,
    pub surface: SurfaceKind,
    pub distance: f32,
    pub lod_threshold: f32,
    pub spp: u32,
    pub prefilter: bool,
}

/// Reads and checks the experiment at `path`; errors name it.
pub fn load(path: &Path) -> anyhow::Result<Experiment> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let e: Experiment = toml::from_str(&text).with_context(|| format!("{}", path.display()))?;
    check(&e).with_context(|| format!("{}", path.display()))?;
    Ok(e)
}

/// Samples a pixel at most, for a point or the converged image.
const MAX_SPP: u32 = 1 << 16;

fn check(e: &Experiment) -> anyhow::Result<()> {
    ensure!(
        e.width > 0 && e.height > 0 && u64::from(e.width) * u64::from(e.height) <= 1 << 26,
        "width and height must be 1 to 8192"
    );
    ensure!(e.repeats > 0, "repeats must be at least 1");
    ensure!((0.0..=600.0).contains(&e.min_seconds), "min_seconds must be 0 to 600");
    ensure!(!e.models.is_empty(), "no [[model]]");
    // Its full-detail images are drawn with whichever accelerator a point has built; bounds
    // for ray-facing disks hold oriented ones, not the other way round.
    ensure!(
        e.reference.is_none_or(|r| r.shape() == pointray::splat::DiskShape::Oriented),
        "the reference must be sj, pss or first-hit (oriented disks)"
    );
    ensure!(!e.matrices.is_empty(), "no [[matrix]]");
    let mut names = BTreeSet::new();
    let most = pointray::accel::bvh::MAX_SPLATS as u64;
    for m in &e.models {
        ensure!(names.insert(m.name.as_str()), "two models named {:?}", m.name);
        ensure!(m.points.is_none_or(|n| n <= most), "model {}: at most {most} points", m.name);
    }
    for (i, m) in e.matrices.iter().enumerate() {
        let which = || format!("matrix {}", i + 1);
        for name in m.models.iter().flatten() {
            ensure!(names.contains(name.as_str()), "{}: no model named {name:?}", which());
        }
        ensure!(
            !m.accel.is_empty() && !m.surface.is_empty() && !m.lod_threshold.is_empty() && !m.distance.is_empty(),
            "{}: every list needs at least one value",
            which()
        );
        ensure!(m.lod_threshold.iter().all(|t| *t >= 0.0 && t.is_finite()), "{}: thresholds must be ≥ 0", which());
        ensure!(m.distance.iter().all(|d| *d > 0.0 && d.is_finite()), "{}: distances must be positive", which());
        ensure!(m.spp.iter().all(|n| (1..=MAX_SPP).contains(n)), "{}: spp must be 1 to {MAX_SPP}", which());
        ensure!(!m.prefilter.is_empty(), "{}: every list needs at least one value", which());
    }
    ensure!(e.converged_spp.is_none_or(|n| (1..=MAX_SPP).contains(&n)), "converged_spp must be 1 to {MAX_SPP}");
    Ok(())
}

impl Experiment {
    /// The points of every matrix that covers `model`, each once, in the order they are
    /// measured: by accelerator and the disks its bounds hold (one build each), distance,
    /// scheme, threshold, samples a pixel, then the prefilter.
    pub fn points(&self, model: &str) -> Vec<Point> {
        let mut points = Vec::new();
        for m in self.matrices.iter().filter(|m| m.models.as_ref().is_none_or(|ms| ms.iter().any(|n| n == model))) {
            for &accel in &m.accel {
                for &distance in &m.distance {
                    for &surface in &m.surface {
                        for &lod_threshold in &m.lod_threshold {
                            for (&spp, &prefilter) in m.spp.iter().flat_map(|s| m.prefilter.iter().map(move |f| (s, f)))
                            {
                                // The prefilter is one ray a pixel at a level of detail.
                                let applies = !prefilter || (lod_threshold > 0.0 && spp == 1);
                                let p = Point { accel, surface, distance, lod_threshold, spp, prefilter };
                                if applies && !points.contains(&p) {
                                    points.push(p);
                                }
                            }
                        }
                    }
                }
            }
        }
        points.sort_by(|a, b| {
            (a.accel, a.surface.shape(), a.distance, a.surface, a.lod_threshold, a.spp, a.prefilter)
                .partial_cmp(&(b.accel, b.surface.shape(), b.distance, b.surface, b.lod_threshold, b.spp, b.prefilter))
                .expect("finite")
        });
        points
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = r#"
title = "t"
[[model]]
name = "a"
file = "a.ply"
[[model]]
name = "b"
mesh = "b.ply"
points = 1000
[[matrix]]
accel = ["bvh", "kdtree"]
surface = ["sj"]
lod_threshold = [0, 1]
distance = [1, 4]
[[matrix]]
models = ["b"]
accel = ["bvh-mixed-3", "bvh"]
surface = ["rfd", "sj"]
lod_threshold = [0]
distance = [1]
spp = [1, 4]
"#;

    #[test]
    fn matrices_expand_to_their_points_each_once() {
        let e: Experiment = toml::from_str(SMALL).unwrap();
        check(&e).unwrap();
        assert_eq!(e.points("a").len(), 2 * 2 * 2);
        // b adds bvh-mixed-3 × {rfd, sj} × {1, 4} spp and bvh × (rfd × {1, 4} + sj × 4); bvh ×
        // sj × 0 × 1 × 1 spp it has already.
        let b = e.points("b");
        assert_eq!(b.len(), 8 + 7, "{b:?}");
        assert_eq!(b.iter().filter(|p| p.spp == 4).count(), 4);
        assert_eq!(b[0].accel, AccelVariant::Bvh(NodeBounds::Boxes));
        assert!(b.iter().any(|p| p.accel.name() == "bvh-mixed-3" && p.surface == SurfaceKind::Rfd));
        assert!(matches!(e.models[1].source(Path::new("x")).unwrap(), Source::Mesh { points: 1000, .. }));
    }

    #[test]
    fn the_prefilter_is_a_point_of_its_own_where_level_of_detail_is_on() {
        let text = SMALL.replace("lod_threshold = [0, 1]\n", "lod_threshold = [0, 1]\nprefilter = [false, true]\n");
        let e: Experiment = toml::from_str(&text).unwrap();
        check(&e).unwrap();
        let a = e.points("a");
        // 2 accelerators × 2 distances × (threshold 0; threshold 1 plain and prefiltered).
        assert_eq!(a.len(), 12);
        assert!(a.iter().filter(|p| p.prefilter).all(|p| p.lod_threshold == 1.0));
        assert_eq!(a.iter().filter(|p| p.prefilter).count(), 4);
        // Nor at more than one sample a pixel.
        let text = text.replace("distance = [1, 4]\n", "distance = [1, 4]\nspp = [1, 2]\n");
        let e: Experiment = toml::from_str(&text).unwrap();
        let a = e.points("a");
        assert_eq!((a.len(), a.iter().filter(|p| p.prefilter).count()), (20, 4));
        assert!(a.iter().filter(|p| p.prefilter).all(|p| p.spp == 1));
    }

    #[test]
    fn bad_experiments_say_what_is_wrong() {
        let fails = |text: &str, fragment: &str| {
            let message = match toml::from_str::<Experiment>(text) {
                Ok(e) => format!("{:#}", check(&e).unwrap_err()),
                Err(e) => e.to_string(),
            };
            assert!(message.contains(fragment), "{message:?} lacks {fragment:?}");
        };
        fails(&SMALL.replace("\"kdtree\"", "\"octree\""), "unknown accelerator \"octree\"");
        fails(&SMALL.replace("models = [\"b\"]", "models = [\"c\"]"), "no model named \"c\"");
        fails(&SMALL.replace("distance = [1]", "distance = [0]"), "distances must be positive");
        fails(&SMALL.replace("name = \"b\"", "name = \"a\""), "two models named \"a\"");
        fails(&SMALL.replace("points = 1000", "points = 1_000_000_000"), "model b: at most");
        fails(&SMALL.replace("lod_threshold = [0]", "lod_threshold = []"), "at least one value");
        fails(&SMALL.replace("lod_threshold = [0]", "lod_threshold = [0]\nprefilter = []"), "at least one value");
        fails(&format!("reference = \"rfd\"\n{SMALL}"), "the reference must be sj, pss or first-hit");
        fails(&SMALL.replace("spp = [1, 4]", "spp = [0]"), "spp must be 1 to 65536");
        fails(&format!("converged_spp = 0\n{SMALL}"), "converged_spp must be 1 to 65536");
    }
}
