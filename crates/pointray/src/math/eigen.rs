//! Eigen-decomposition of symmetric 3×3 matrices, as needed by PCA normal estimation
//! (thesis Eq. 2.1: the normal is the eigenvector of the covariance's smallest eigenvalue).
//!
//! The fast path is closed form: trigonometric eigenvalues of the characteristic cubic, then
//! each eigenvector as the longest cross product of two rows of `A − λI` (their common null
//! space). That path loses accuracy when two eigenvalues nearly coincide (the null space is
//! no longer one-dimensional), so those matrices go to cyclic Jacobi rotations, which are
//! slower but exact for any symmetric input. Everything runs in `f64` internally.

use glam::{DVec3, Vec3};

/// Eigenvalues in ascending order and their unit, mutually orthogonal eigenvectors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SymEigen {
    pub values: [f32; 3],
    pub vectors: [Vec3; 3],
}

/// Closed form is used only when every eigenvalue gap is at least this fraction of the
/// largest matrix entry. Near a double root `acos` amplifies rounding to about √ε ≈ 1.5e-8
/// in the eigenvalues, so at this gap the eigenvector error stays below about 1e-5 rad.
const MIN_RELATIVE_GAP: f64 = 1e-3;

/// Eigen-decomposition of the symmetric matrix `m` (only its symmetric part is used).
///
/// Never returns NaN for finite input. For non-finite input the result is undefined but
/// does not panic.
pub fn sym_eigen(m: [[f32; 3]; 3]) -> SymEigen {
    let a = symmetric_part(m);
    let scale = a.iter().flatten().fold(0.0f64, |s, v| s.max(v.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return SymEigen { values: [a[0][0] as f32, a[1][1] as f32, a[2][2] as f32], vectors: IDENTITY };
    }
    // Normalising makes the gap threshold relative and keeps the cubic well scaled.
    let unit = a.map(|row| row.map(|v| v / scale));
    let (values, vectors) = closed_form(&unit).unwrap_or_else(|| jacobi(&unit));
    SymEigen { values: values.map(|v| (v * scale) as f32), vectors: vectors.map(|v| v.as_vec3().normalize_or(Vec3::Z)) }
}

const IDENTITY: [Vec3; 3] = [Vec3::X, Vec3::Y, Vec3::Z];

type Mat = [[f64; 3]; 3];

fn symmetric_part(m: [[f32; 3]; 3]) -> Mat {
    let mut a = [[0.0; 3]; 3];
    for (i, row) in a.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = 0.5 * (f64::from(m[i][j]) + f64::from(m[j][i]));
        }
    }
    a
}

fn mul(a: &Mat, v: DVec3) -> DVec3 {
    DVec3::new(
        a[0][0] * v.x + a[0][1] * v.y + a[0][2] * v.z,
        a[1][0] * v.x + a[1][1] * v.y + a[1][2] * v.z,
        a[2][0] * v.x + a[2][1] * v.y + a[2][2] * v.z,
    )
}

/// Trigonometric eigenvalues (ascending) of the characteristic cubic.
fn cubic_eigenvalues(a: &Mat) -> [f64; 3] {
    let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    let q = (a[0][0] + a[1][1] + a[2][2]) / 3.0;
    let d = [a[0][0] - q, a[1][1] - q, a[2][2] - q];
    let p = ((d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + 2.0 * off) / 6.0).sqrt();
    if p == 0.0 {
        return [q; 3];
    }
    // B = (A − qI) / p has eigenvalues 2cos(φ + 2πj/3) with cos 3φ = det(B) / 2.
    let b = [
        [d[0] / p, a[0][1] / p, a[0][2] / p],
        [a[0][1] / p, d[1] / p, a[1][2] / p],
        [a[0][2] / p, a[1][2] / p, d[2] / p],
    ];
    let det = b[0][0] * (b[1][1] * b[2][2] - b[1][2] * b[1][2]) - b[0][1] * (b[0][1] * b[2][2] - b[1][2] * b[0][2])
        + b[0][2] * (b[0][1] * b[1][2] - b[1][1] * b[0][2]);
    let phi = (0.5 * det).clamp(-1.0, 1.0).acos() / 3.0;
    let largest = q + 2.0 * p * phi.cos();
    let smallest = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    [smallest, 3.0 * q - largest - smallest, largest]
}

/// The longest cross product of two rows of `A − λI`: a vector spanning its null space when
/// λ is a simple eigenvalue. Returns it with its squared length.
fn null_vector(a: &Mat, lambda: f64) -> (DVec3, f64) {
    let r0 = DVec3::new(a[0][0] - lambda, a[0][1], a[0][2]);
    let r1 = DVec3::new(a[1][0], a[1][1] - lambda, a[1][2]);
    let r2 = DVec3::new(a[2][0], a[2][1], a[2][2] - lambda);
    [r0.cross(r1), r0.cross(r2), r1.cross(r2)]
        .into_iter()
        .map(|c| (c, c.length_squared()))
        .fold((DVec3::ZERO, 0.0), |best, c| if c.1 > best.1 { c } else { best })
}

/// Closed-form decomposition of a matrix normalised to max |entry| = 1, or `None` when its
/// eigenvalues are too close for the cross products to be reliable.
fn closed_form(a: &Mat) -> Option<([f64; 3], [DVec3; 3])> {
    let values = cubic_eigenvalues(a);
    let min_gap = (values[1] - values[0]).min(values[2] - values[1]);
    // Written so that a NaN gap also falls back.
    if min_gap.is_nan() || min_gap < MIN_RELATIVE_GAP {
        return None;
    }
    // With both gaps ≥ g, |row × row| ≥ about g², so anything much smaller is rounding noise.
    let tiny = 1e-3 * min_gap * min_gap;
    let (low, low_len2) = null_vector(a, values[0]);
    let (high, high_len2) = null_vector(a, values[2]);
    if low_len2 < tiny * tiny || high_len2 < tiny * tiny {
        return None;
    }
    let low = low / low_len2.sqrt();
    // Re-orthogonalise against `low` so the frame is orthonormal to rounding.
    let high = (high - low * low.dot(high)).try_normalize()?;
    let mid = high.cross(low);
    let vectors = [low, mid, high];
    // Rayleigh quotients are more accurate than the cubic's roots near a double root.
    Some((vectors.map(|v| v.dot(mul(a, v))), vectors))
}

/// Cyclic Jacobi rotations: slow-ish but exact for any symmetric matrix, including repeated
/// eigenvalues. Returns ascending eigenvalues and matching orthonormal eigenvectors.
fn jacobi(a: &Mat) -> ([f64; 3], [DVec3; 3]) {
    let mut a = *a;
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..32 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        let diag = a[0][0].abs() + a[1][1].abs() + a[2][2].abs();
        if off <= 1e-18 * diag || off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            rotate(&mut a, &mut v, p, q);
        }
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    let column = |c: usize| DVec3::new(v[0][c], v[1][c], v[2][c]);
    let mut vectors = order.map(column);
    // Keep a right-handed frame like the closed-form path.
    vectors[1] = vectors[2].cross(vectors[0]);
    (order.map(|i| a[i][i]), vectors)
}

/// One Jacobi rotation zeroing `a[p][q]`, accumulated into the eigenvector columns of `v`.
fn rotate(a: &mut Mat, v: &mut Mat, p: usize, q: usize) {
    let apq = a[p][q];
    if apq == 0.0 {
        return;
    }
    let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
    // The smaller root of t² + 2θt − 1 = 0 (rotation angle ≤ π/4); signum(0) = 1.
    let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
    let c = 1.0 / (t * t + 1.0).sqrt();
    let s = t * c;
    for row in a.iter_mut() {
        let (akp, akq) = (row[p], row[q]);
        row[p] = c * akp - s * akq;
        row[q] = s * akp + c * akq;
    }
    let (row_p, row_q) = (a[p], a[q]);
    for k in 0..3 {
        a[p][k] = c * row_p[k] - s * row_q[k];
        a[q][k] = s * row_p[k] + c * row_q[k];
    }
    for row in v.iter_mut() {
        let (vp, vq) = (row[p], row[q]);
        row[p] = c * vp - s * vq;
        row[q] = s * vp + c * vq;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    /// Checks A v = λ v, orthonormality and ascending order, with tolerances relative to |A|.
    fn check(m: [[f32; 3]; 3]) -> f32 {
        let e = sym_eigen(m);
        let norm = m.iter().flatten().fold(0f32, |s, v| s.max(v.abs())).max(f32::MIN_POSITIVE);
        assert!(e.values.iter().all(|v| v.is_finite()), "{m:?} → {e:?}");
        assert!(e.values[0] <= e.values[1] && e.values[1] <= e.values[2], "{m:?} → {e:?}");
        let mut worst = 0f32;
        for (i, (&lambda, &v)) in e.values.iter().zip(&e.vectors).enumerate() {
            assert!((v.length() - 1.0).abs() < 1e-5, "not unit: {m:?} → {e:?}");
            for w in &e.vectors[i + 1..] {
                assert!(v.dot(*w).abs() < 1e-5, "not orthogonal: {m:?} → {e:?}");
            }
            let av = Vec3::new(
                m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z,
                m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
                m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z,
            );
            let residual = (av - lambda * v).length() / norm;
            assert!(residual < 2e-5, "residual {residual}: {m:?} → {e:?}");
            worst = worst.max(residual);
        }
        worst
    }

    fn from_eigen(values: [f32; 3], rng: &mut Pcg64Mcg) -> [[f32; 3]; 3] {
        let axis = Vec3::new(rng.random_range(-1.0..1.0), rng.random(), rng.random()).normalize();
        let q = glam::Mat3::from_axis_angle(axis, rng.random_range(0.0..6.3f32));
        let a = q * glam::Mat3::from_diagonal(values.into()) * q.transpose();
        a.transpose().to_cols_array_2d() // row-major
    }

    fn diag(d: [f32; 3]) -> [[f32; 3]; 3] {
        [[d[0], 0.0, 0.0], [0.0, d[1], 0.0], [0.0, 0.0, d[2]]]
    }

    #[test]
    fn degenerate_matrices() {
        for m in [
            diag([0.0; 3]),
            diag([1.0; 3]),
            diag([1.0, 1.0, 2.0]),
            diag([2.0, 1.0, 1.0]),
            diag([3.0, -1.0, 0.0]),
            diag([1e-30, 0.0, 0.0]),
            diag([1e30, 1e30, -1e30]),
            [[1.0; 3]; 3], // rank 1
            [[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [3.0, 6.0, 9.0]],
            [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
            [[f32::MIN_POSITIVE, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        ] {
            check(m);
        }
        let e = sym_eigen(diag([3.0, 1.0, 2.0]));
        assert_eq!(e.values, [1.0, 2.0, 3.0]);
        assert_eq!(e.vectors[0].abs(), Vec3::Y);
    }

    #[test]
    fn random_matrices_match_brute_check() {
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        let mut worst = 0f32;
        for _ in 0..100_000 {
            let mut m = [[0f32; 3]; 3];
            for (i, j) in [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)] {
                m[i][j] = rng.random_range(-10.0..10.0);
                m[j][i] = m[i][j];
            }
            worst = worst.max(check(m));
        }
        println!("worst relative residual, random: {worst:e}");
    }

    #[test]
    fn random_rotations_of_repeated_and_close_eigenvalues() {
        let mut rng = Pcg64Mcg::seed_from_u64(11);
        let mut worst = 0f32;
        for i in 0..100_000 {
            let base: f32 = rng.random_range(-5.0..5.0);
            let eps = [0.0, 1e-7, 1e-5, 1e-3, 1e-2][i % 5];
            let values = match i % 4 {
                0 => [base, base, base],
                1 => [base, base + eps, base + 1.0],
                2 => [base - 1.0, base, base + eps],
                _ => [0.0, 0.0, base.abs()], // rank 1 (or 0)
            };
            worst = worst.max(check(from_eigen(values, &mut rng)));
        }
        println!("worst relative residual, clustered: {worst:e}");
    }

    #[test]
    fn covariance_like_flat_matrices_give_accurate_normals() {
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        for _ in 0..10_000 {
            let flat = rng.random_range(0.0..1e-4f32);
            let m = from_eigen([flat, 0.5, 1.0], &mut rng);
            let e = sym_eigen(m);
            assert!((e.values[0] - flat).abs() < 1e-6, "{e:?}");
        }
    }
}
