//! Splat radii from local sampling density (thesis §2.1.4: each point becomes a disk, and the
//! disks must overlap so that the surface has no holes).
//!
//! Rule: `r = scale × distance to the k-th nearest neighbour`. The k-th distance grows
//! exactly where the sampling is sparse, which is where a disk has to reach further. With
//! the defaults (k = 8, scale = 1, also the Embree reference's rule) uniformly random samples
//! leave 0.001 % of a sphere uncovered at a mean radius of 3.1 × the mean nearest-neighbour
//! spacing; smoothing the k-th distance over the neighbourhood was measured and only needs a
//! larger scale for the same coverage (see the tests).

use glam::Vec3;
use rayon::prelude::*;

use crate::knn::Neighbourhoods;

/// Radius of every point: `scale ×` its distance to its `k`-th nearest neighbour (k clamped
/// to `nbrs.k`). When that distance is zero (k or more coincident points) the farthest
/// neighbour found is used instead; if every neighbour coincides, the mean of the positive
/// radii. Without any neighbours (fewer than 2 points) the radius is 0.
pub fn splat_radii(points: &[Vec3], nbrs: &Neighbourhoods, k: usize, scale: f32) -> Vec<f32> {
    let k = k.min(nbrs.k);
    if k == 0 {
        return vec![0.0; points.len()];
    }
    let mut radii: Vec<f32> = (0..points.len())
        .into_par_iter()
        .map(|i| {
            let dists = nbrs.sq_dists_of(i);
            let d = if dists[k - 1] > 0.0 { dists[k - 1] } else { dists[nbrs.k - 1] };
            scale * d.sqrt()
        })
        .collect();
    fill_zero_radii(&mut radii);
    radii
}

/// How many times the median of its neighbours' radii a computed radius may be.
pub const MAX_OVER_NEIGHBOURS: f32 = 8.0;

/// Neighbours whose median radius bounds a point's (the nearest, at most this many).
const MEDIAN_OF: usize = 16;

/// Clamps the radii `which` marks to [`MAX_OVER_NEIGHBOURS`] times the median radius of their
/// nearest neighbours (at most [`MEDIAN_OF`]), as the radii were before any was clamped;
/// returns the indices it clamped, in order (preprocessing drops those points by default). A stray point (a stray return, a pixel without a return stored
/// at the origin) lies far from its nearest neighbours, whose radii are the model's: by the
/// k-th-neighbour rule alone it got a radius of its distance to the model, a big flat disc over
/// it. A sparse region's points have neighbours as sparse as they are, and keep their radii.
pub fn clamp_to_neighbours(radii: &mut [f32], which: &[bool], nbrs: &Neighbourhoods) -> Vec<u32> {
    let k = nbrs.k.min(MEDIAN_OF);
    if k == 0 {
        return Vec::new();
    }
    let limits: Vec<Option<f32>> = (0..radii.len())
        .into_par_iter()
        .map(|i| {
            if !which[i] {
                return None;
            }
            let mut near = [0.0f32; MEDIAN_OF];
            for (r, &j) in near.iter_mut().zip(&nbrs.of(i)[..k]) {
                *r = radii[j as usize];
            }
            let median = *near[..k].select_nth_unstable_by(k / 2, f32::total_cmp).1;
            let limit = MAX_OVER_NEIGHBOURS * median;
            (radii[i] > limit && limit > 0.0).then_some(limit)
        })
        .collect();
    let mut clamped = Vec::new();
    for (i, (r, limit)) in radii.iter_mut().zip(limits).enumerate() {
        if let Some(limit) = limit {
            *r = limit;
            clamped.push(i as u32);
        }
    }
    clamped
}

/// Gives points whose neighbours all coincide the mean positive radius, so that they stay
/// visible.
fn fill_zero_radii(radii: &mut [f32]) {
    let (sum, count) =
        radii.iter().filter(|&&r| r > 0.0).fold((0.0f64, 0usize), |(s, c), &r| (s + f64::from(r), c + 1));
    if count == 0 || count == radii.len() {
        return;
    }
    let mean = (sum / count as f64) as f32;
    radii.iter_mut().filter(|r| **r <= 0.0).for_each(|r| *r = mean);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PointCloud;
    use crate::knn::{PointIndex, k_nearest};
    use crate::preprocess::normals::tests::sphere;
    use crate::preprocess::{PreprocessConfig, preprocess};
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    struct Disks {
        centres: Vec<Vec3>,
        normals: Vec<Vec3>,
        radii: Vec<f32>,
    }

    /// Fraction of `probes` inside at least one disk: projected distance to its centre below
    /// its radius and distance to its plane below half its radius.
    fn coverage(disks: &Disks, probes: &[Vec3]) -> f32 {
        let index = PointIndex::new(&disks.centres);
        let max_r = disks.radii.iter().copied().fold(0.0, f32::max);
        let covered = probes
            .par_iter()
            .filter(|&&x| {
                index.within(x, max_r).into_iter().any(|(i, _)| {
                    let i = i as usize;
                    let d = x - disks.centres[i];
                    let h = d.dot(disks.normals[i]);
                    let r = disks.radii[i];
                    h.abs() < 0.5 * r && d.length_squared() - h * h < r * r
                })
            })
            .count();
        covered as f32 / probes.len() as f32
    }

    /// A stray point far off a plane of splats gets a radius of at most eight times its
    /// neighbours' median, not its distance to the plane; the plane's own radii, and those of
    /// a sparse region beside a dense one, stay as the k-th-neighbour rule made them.
    #[test]
    fn a_stray_point_gets_no_giant_disc() {
        let mut points = plane_patch(4_000, 3);
        // A sparse patch beside it, ten times as far apart.
        points.extend(plane_patch(400, 4).iter().map(|p| Vec3::new(2.0 + 10.0 * p.x, 10.0 * p.y, 0.0)));
        points.push(Vec3::new(0.5, 0.5, 3.0));
        let stray = points.len() - 1;
        let nbrs = k_nearest(&points, 16);
        let unclamped = splat_radii(&points, &nbrs, 8, 1.0);
        assert!(unclamped[stray] > 2.0, "{}", unclamped[stray]);
        let mut radii = unclamped.clone();
        let all = vec![true; points.len()];
        assert_eq!(clamp_to_neighbours(&mut radii, &all, &nbrs), vec![stray as u32]);
        let near = nbrs.of(stray).iter().map(|&j| unclamped[j as usize]).fold(0.0, f32::max);
        assert!(radii[stray] <= MAX_OVER_NEIGHBOURS * near && radii[stray] < 0.5, "{}", radii[stray]);
        assert_eq!(radii[..stray], unclamped[..stray]);
        // Only the radii asked for are clamped.
        let mut radii = unclamped.clone();
        let none = vec![false; points.len()];
        assert_eq!((clamp_to_neighbours(&mut radii, &none, &nbrs), radii), (vec![], unclamped));
    }

    fn mean_nn_spacing(nbrs: &Neighbourhoods) -> f32 {
        let n = nbrs.len();
        (0..n).map(|i| nbrs.sq_dists_of(i)[0].sqrt()).sum::<f32>() / n as f32
    }

    fn plane_patch(n: usize, seed: u64) -> Vec<Vec3> {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        (0..n).map(|_| Vec3::new(rng.random(), rng.random(), 0.0)).collect()
    }

    /// Range-scan-like rows: dense along x, rows 4× as far apart in y, with jitter.
    fn scan_rows(n: usize, seed: u64) -> Vec<Vec3> {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let along = (1.0 / (n as f32 * 4.0)).sqrt();
        let across = 4.0 * along;
        let rows = (1.0 / across) as usize;
        let per_row = n / rows;
        (0..rows * per_row)
            .map(|i| {
                let (row, col) = (i / per_row, i % per_row);
                Vec3::new(
                    (col as f32 + rng.random_range(-0.3..0.3)) * along,
                    (row as f32 + rng.random_range(-0.1..0.1)) * across,
                    0.0,
                )
            })
            .collect()
    }

    fn probes_in_square(n: usize, seed: u64) -> Vec<Vec3> {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        (0..n).map(|_| Vec3::new(rng.random_range(0.1..0.9), rng.random_range(0.1..0.9), 0.0)).collect()
    }

    /// Coverage of `points` after the full standard preprocessing (PCA normals, oriented,
    /// radii by the default rule), and the mean radius over the mean NN spacing.
    fn standard_coverage(points: Vec<Vec3>, probes: &[Vec3]) -> (f32, f32) {
        let mut cloud = PointCloud::from_positions(points);
        preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        let nbrs = k_nearest(&cloud.positions, 1);
        let radii = cloud.radii.unwrap();
        let ratio = radii.iter().sum::<f32>() / radii.len() as f32 / mean_nn_spacing(&nbrs);
        let disks = Disks { centres: cloud.positions, normals: cloud.normals.unwrap(), radii };
        (coverage(&disks, probes), ratio)
    }

    fn assert_covered(name: &str, points: Vec<Vec3>, probes: &[Vec3]) {
        let (covered, ratio) = standard_coverage(points, probes);
        println!("{name}: {:.4} % covered, mean radius {ratio:.2} × mean NN spacing", covered * 100.0);
        assert!(covered >= 0.999, "{name}: {covered}");
        assert!(ratio < 4.5, "{name}: radii wastefully large ({ratio})");
    }

    #[test]
    fn default_radii_cover_a_random_sphere() {
        assert_covered("sphere 100k", sphere(100_000, 21).0, &sphere(100_000, 24).0);
    }

    #[test]
    fn default_radii_cover_a_tilted_random_plane_patch() {
        let rotation = glam::Quat::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        let tilt = |p: Vec3| rotation * p + Vec3::new(5.0, -3.0, 2.0);
        let points = plane_patch(100_000, 22).into_iter().map(tilt).collect();
        let probes: Vec<Vec3> = probes_in_square(100_000, 25).into_iter().map(tilt).collect();
        assert_covered("plane 100k", points, &probes);
    }

    #[test]
    fn default_radii_cover_anisotropic_scan_rows() {
        assert_covered("scan rows 100k", scan_rows(100_000, 23), &probes_in_square(100_000, 25));
    }

    #[test]
    fn coincident_points_keep_positive_radii() {
        let mut points = vec![Vec3::ZERO; 20];
        points.extend(plane_patch(1000, 3));
        let nbrs = k_nearest(&points, 8);
        let radii = splat_radii(&points, &nbrs, 8, 1.0);
        assert!(radii.iter().all(|&r| r > 0.0 && r.is_finite()));
        assert_eq!(splat_radii(&[Vec3::ONE], &k_nearest(&[Vec3::ONE], 8), 8, 1.0), vec![0.0]);
        assert_eq!(splat_radii(&[], &k_nearest(&[], 8), 8, 1.0), Vec::<f32>::new());
    }

    /// The measurement behind the defaults: coverage and radius/spacing for k and scale on
    /// 100k uniformly random points (analytic normals). Summary (sphere / plane / rows,
    /// coverage %, mean r / mean NN spacing):
    ///
    /// | k, scale | sphere           | plane            | scan rows      |
    /// |----------|------------------|------------------|----------------|
    /// | 4, 1.2   | 99.956 %, 2.62   | 99.954 %, 2.63   | 100 %, 2.99    |
    /// | 6, 1.0   | 99.964 %, 2.70   | 99.975 %, 2.71   | 100 %, 3.61    |
    /// | 8, 0.9   | 99.977 %, 2.82   | 99.983 %, 2.83   | 100 %, 3.85    |
    /// | **8, 1.0** | **99.999 %, 3.14** | **100.000 %, 3.14** | **100 %, 4.27** |
    /// | 8, 0.8   | 99.881 %, 2.51   | 99.902 %, 2.52   | 100 %, 3.42    |
    /// | 16, 0.8  | 100.000 %, 3.58  | 100.000 %, 3.59  | 100 %, 4.07    |
    ///
    /// Averaging the k-th distance over the neighbourhood lowered coverage at equal mean radius
    /// (k 8, scale 1.0: 99.969 %, 3.05), so the rule stays unsmoothed.
    #[test]
    #[ignore]
    fn sweep_k_and_scale() {
        let n = 100_000;
        let (sph, sph_n) = sphere(n, 21);
        let plane = plane_patch(n, 22);
        let rows = scan_rows(n, 23);
        let sphere_probes = sphere(100_000, 24).0;
        let square_probes = probes_in_square(100_000, 25);
        // (name, points, normals, probes)
        type Case<'a> = (&'a str, Vec<Vec3>, Vec<Vec3>, &'a [Vec3]);
        let cases: [Case; 3] = [
            ("sphere", sph, sph_n, &sphere_probes),
            ("plane", plane, vec![Vec3::Z; n], &square_probes),
            ("rows", rows.clone(), vec![Vec3::Z; rows.len()], &square_probes),
        ];
        for (name, points, normals, probes) in &cases {
            let nbrs = k_nearest(points, 16);
            let spacing = mean_nn_spacing(&nbrs);
            for k in [4, 6, 8, 10, 12, 16] {
                for scale in [0.8f32, 0.9, 1.0, 1.1, 1.2] {
                    let radii = splat_radii(points, &nbrs, k, scale);
                    let ratio = radii.iter().sum::<f32>() / radii.len() as f32 / spacing;
                    let disks = Disks { centres: points.clone(), normals: normals.clone(), radii };
                    let covered = coverage(&disks, probes) * 100.0;
                    println!("{name} k={k} scale={scale}: {covered:.4} %, r/spacing {ratio:.2}");
                }
            }
        }
    }
}
