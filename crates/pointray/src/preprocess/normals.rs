//! PCA normal estimation (thesis §2.1.3, Eq. 2.1): the normal of a point is the direction of
//! least variance of its neighbourhood, i.e. the eigenvector of the smallest eigenvalue of the
//! covariance matrix about the neighbourhood's centroid. Orientation is arbitrary here; see
//! [`super::orient`].

use glam::Vec3;
use rayon::prelude::*;

use crate::knn::Neighbourhoods;
use crate::math::eigen::sym_eigen;

/// A neighbourhood is treated as collinear when its middle eigenvalue (a variance) is below
/// this fraction of the largest, i.e. its second principal spread is under 0.3 % of the first:
/// the plane through a line is then undetermined.
const COLLINEAR_RATIO: f32 = 1e-5;

/// PCA normals of every point from the first `k` (clamped to `nbrs.k`) neighbours, computed
/// in parallel, and the number of degenerate neighbourhoods (see [`pca`]).
pub fn pca_normals(points: &[Vec3], nbrs: &Neighbourhoods, k: usize) -> (Vec<Vec3>, usize) {
    let estimates: Vec<(Vec3, bool)> =
        (0..points.len()).into_par_iter().map(|i| pca_normal(points, i, nbrs, k)).collect();
    let degenerate = estimates.iter().filter(|(_, ok)| !ok).count();
    (estimates.into_iter().map(|(n, _)| n).collect(), degenerate)
}

/// Unit PCA normal of point `i` and whether the neighbourhood determined it ([`pca`]).
pub fn pca_normal(points: &[Vec3], i: usize, nbrs: &Neighbourhoods, k: usize) -> (Vec3, bool) {
    let p = pca(points, i, nbrs, k);
    (p.normal, p.determined)
}

/// What PCA says of a point's neighbourhood.
#[derive(Clone, Copy, Debug)]
pub struct Pca {
    /// The unit normal.
    pub normal: Vec3,
    /// False for a degenerate neighbourhood, whose normal is a fallback (see [`pca`]).
    pub determined: bool,
    /// Pauly's surface variation λ₀ / (λ₀ + λ₁ + λ₂): 0 on a plane, up to ⅓ where the
    /// neighbourhood spreads alike every way (a fold, a corner, noise); 0 for a degenerate one.
    pub variation: f32,
}

/// PCA of point `i` over itself and its first `k` neighbours (Eq. 2.1).
///
/// Degenerate neighbourhoods get a defined fallback normal and `determined: false`: with no
/// neighbours or all of them coincident, +Z; with all of them collinear, the unit vector
/// perpendicular to the line that is closest to +Z (or +X for a vertical line).
pub fn pca(points: &[Vec3], i: usize, nbrs: &Neighbourhoods, k: usize) -> Pca {
    let centre = points[i];
    let neighbours = if nbrs.k == 0 { &[][..] } else { &nbrs.of(i)[..k.min(nbrs.k)] };
    // Offsets from the point itself keep f32 precision for clouds far from the origin.
    let offsets = || std::iter::once(Vec3::ZERO).chain(neighbours.iter().map(|&j| points[j as usize] - centre));
    let count = (neighbours.len() + 1) as f32;
    let centroid = offsets().sum::<Vec3>() / count;
    let mut c = [[0f32; 3]; 3];
    for d in offsets().map(|o| o - centroid) {
        let d = d.to_array();
        for (row, &dr) in c.iter_mut().zip(&d) {
            for (v, &dc) in row.iter_mut().zip(&d) {
                *v += dr * dc;
            }
        }
    }
    let eigen = sym_eigen(c);
    let [least, middle, largest] = eigen.values;
    let degenerate = |normal| Pca { normal, determined: false, variation: 0.0 };
    if largest.is_nan() || largest <= 0.0 {
        return degenerate(Vec3::Z);
    }
    if middle <= COLLINEAR_RATIO * largest {
        return degenerate(perpendicular_closest_to_z(eigen.vectors[2]));
    }
    let variation = least.max(0.0) / (least.max(0.0) + middle + largest);
    Pca { normal: eigen.vectors[0], determined: true, variation }
}

/// The unit vector orthogonal to the unit `line` that is closest to +Z (+X if `line` ∥ Z).
fn perpendicular_closest_to_z(line: Vec3) -> Vec3 {
    let toward = if line.z.abs() > 0.999 { Vec3::X } else { Vec3::Z };
    (toward - line * line.dot(toward)).normalize()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::knn::k_nearest;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64Mcg;
    use std::f32::consts::TAU;

    /// Area-uniform points on the unit sphere, with their outward normals.
    pub(crate) fn sphere(n: usize, seed: u64) -> (Vec<Vec3>, Vec<Vec3>) {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let points: Vec<Vec3> = (0..n)
            .map(|_| {
                let z: f32 = rng.random_range(-1.0..1.0);
                let phi = rng.random_range(0.0..TAU);
                let s = (1.0 - z * z).sqrt();
                Vec3::new(s * phi.cos(), s * phi.sin(), z)
            })
            .collect();
        (points.clone(), points)
    }

    /// [`sphere`]'s points scaled by `axes` (an ellipsoid; not area-uniform), with their
    /// outward normals.
    pub(crate) fn ellipsoid(n: usize, axes: Vec3, seed: u64) -> (Vec<Vec3>, Vec<Vec3>) {
        let points: Vec<Vec3> = sphere(n, seed).0.iter().map(|&p| p * axes).collect();
        let outward = points.iter().map(|&p| (p / (axes * axes)).normalize()).collect();
        (points, outward)
    }

    /// The thin flat ellipsoid of the orientation tests: semi-axes 1, 1 and 0.05, two sheets
    /// about two point spacings apart at 20,000 points.
    pub(crate) const THIN: Vec3 = Vec3::new(1.0, 1.0, 0.05);

    /// Area-uniform points on a torus around Z (major radius `big`, minor `small`), with their
    /// outward normals; rejection sampling on the tube angle makes the density uniform.
    pub(crate) fn torus(n: usize, big: f32, small: f32, seed: u64) -> (Vec<Vec3>, Vec<Vec3>) {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let (mut points, mut normals) = (Vec::with_capacity(n), Vec::with_capacity(n));
        while points.len() < n {
            let (u, v): (f32, f32) = (rng.random_range(0.0..TAU), rng.random_range(0.0..TAU));
            // Area element ∝ big + small·cos v.
            if rng.random_range(0.0..big + small) > big + small * v.cos() {
                continue;
            }
            let normal = Vec3::new(v.cos() * u.cos(), v.cos() * u.sin(), v.sin());
            let ring = Vec3::new(u.cos(), u.sin(), 0.0) * big;
            points.push(ring + normal * small);
            normals.push(normal);
        }
        (points, normals)
    }

    /// Angles in degrees between estimated and true normals, up to sign.
    pub(crate) fn unsigned_errors(estimated: &[Vec3], truth: &[Vec3]) -> Vec<f32> {
        estimated.iter().zip(truth).map(|(a, b)| a.dot(*b).abs().min(1.0).acos().to_degrees()).collect()
    }

    fn check_accuracy(name: &str, points: &[Vec3], truth: &[Vec3]) {
        let nbrs = k_nearest(points, 16);
        let (normals, degenerate) = pca_normals(points, &nbrs, 16);
        let errors = unsigned_errors(&normals, truth);
        let within = errors.iter().filter(|&&e| e <= 3.0).count() as f32 / errors.len() as f32;
        let max = errors.iter().copied().fold(0.0, f32::max);
        let mean = errors.iter().sum::<f32>() / errors.len() as f32;
        println!("{name}: {:.3} % within 3°, max {max:.3}°, mean {mean:.4}°", within * 100.0);
        assert_eq!(degenerate, 0);
        assert!(within >= 0.995, "{name}: only {within} within 3°");
        assert!(normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-5));
    }

    #[test]
    fn sphere_normals_are_accurate() {
        let (points, truth) = sphere(20_000, 1);
        check_accuracy("sphere 20k, k 16", &points, &truth);
    }

    #[test]
    fn torus_normals_are_accurate() {
        // 50k: at 20k the tube (r = 0.35) is only ~13 spacings across and curvature limits
        // PCA to 98.75 % within 3° (mean 1.05°), for any k from 8 to 24.
        let (points, truth) = torus(50_000, 1.0, 0.35, 2);
        check_accuracy("torus 50k, k 16", &points, &truth);
    }

    #[test]
    #[ignore]
    fn sweep_k_and_density() {
        for n in [20_000, 50_000, 100_000] {
            for k in [8, 10, 12, 16, 24] {
                let (points, truth) = torus(n, 1.0, 0.35, 2);
                let nbrs = k_nearest(&points, k);
                let (normals, _) = pca_normals(&points, &nbrs, k);
                let errors = unsigned_errors(&normals, &truth);
                let within = errors.iter().filter(|&&e| e <= 3.0).count() as f32 / errors.len() as f32;
                let max = errors.iter().copied().fold(0.0, f32::max);
                let mean = errors.iter().sum::<f32>() / errors.len() as f32;
                println!("torus {n} k {k}: {:.3} % within 3°, max {max:.3}°, mean {mean:.4}°", within * 100.0);
            }
        }
    }

    /// Surface variation: 0 on a plane; in a cube of random points, well above (17 points spread
    /// unevenly: 0.18 on average, not ⅓).
    #[test]
    fn surface_variation_tells_a_plane_from_a_cube() {
        let mut rng = Pcg64Mcg::seed_from_u64(12);
        let mut v = |z: f32| {
            Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), z * rng.random_range(-1.0..1.0))
        };
        let variation = |points: &[Vec3]| {
            let nbrs = k_nearest(points, 16);
            (0..points.len()).map(|i| pca(points, i, &nbrs, 16).variation).sum::<f32>() / points.len() as f32
        };
        let plane: Vec<Vec3> = (0..2000).map(|_| v(0.0)).collect();
        let cube: Vec<Vec3> = (0..2000).map(|_| v(1.0)).collect();
        let (plane, cube) = (variation(&plane), variation(&cube));
        assert!(plane < 1e-6, "plane {plane}");
        assert!(cube > 0.1, "cube {cube}");
    }

    #[test]
    fn tilted_plane_is_exact() {
        let mut rng = Pcg64Mcg::seed_from_u64(5);
        let normal = Vec3::new(0.3, -0.8, 0.5).normalize();
        let (u, v) = crate::math::orthonormal_basis(normal);
        let offset = Vec3::new(100.0, -50.0, 20.0);
        let points: Vec<Vec3> = (0..5000)
            .map(|_| offset + u * rng.random_range(-1.0..1.0f32) + v * rng.random_range(-1.0..1.0f32))
            .collect();
        let nbrs = k_nearest(&points, 16);
        let (normals, degenerate) = pca_normals(&points, &nbrs, 16);
        assert_eq!(degenerate, 0);
        let worst = unsigned_errors(&normals, &vec![normal; points.len()]).into_iter().fold(0.0, f32::max);
        assert!(worst < 0.5, "worst {worst}°");
    }

    #[test]
    fn degenerate_neighbourhoods_have_defined_normals() {
        // Coincident points.
        let points = vec![Vec3::new(1.0, 2.0, 3.0); 40];
        let nbrs = k_nearest(&points, 16);
        let (normals, degenerate) = pca_normals(&points, &nbrs, 16);
        assert_eq!(degenerate, 40);
        assert!(normals.iter().all(|&n| n == Vec3::Z));

        // A line along (1, 1, 1): normals perpendicular to it.
        let dir = Vec3::ONE.normalize();
        let points: Vec<Vec3> = (0..100).map(|i| dir * i as f32 * 0.01).collect();
        let nbrs = k_nearest(&points, 16);
        let (normals, degenerate) = pca_normals(&points, &nbrs, 16);
        assert_eq!(degenerate, 100);
        assert!(normals.iter().all(|n| n.dot(dir).abs() < 1e-4 && n.is_normalized()));

        // 0, 1 and 2 points.
        for n in 0..3 {
            let points: Vec<Vec3> = (0..n).map(|i| Vec3::X * i as f32).collect();
            let nbrs = k_nearest(&points, 16);
            let (normals, degenerate) = pca_normals(&points, &nbrs, 16);
            assert_eq!((normals.len(), degenerate), (n, n));
            assert!(normals.iter().all(|n| n.is_normalized()));
        }
    }
}
