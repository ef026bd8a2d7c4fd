//! Ray versus oriented disk (thesis §A1, Schaufler & Jensen 2000).

use super::{NORMAL_SCALE, Splat};
use crate::math::Ray;

/// Where a ray crosses a disk: the ray parameter and the squared distance from the disk's
/// centre, measured in the disk's plane (SJ's dᵢ, which their interpolation weight uses).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiskHit {
    pub t: f32,
    pub dist2: f32,
}

/// Intersects the ray with the disk's plane and accepts the point if it lies within the radius
/// and in `[ray.t_min, t_max]`. Disks are two-sided; a ray parallel to the plane misses.
///
/// With t = num/den, the tests are done multiplied through by den (no division on the hot
/// path, where most disks are rejected): the crossing lies at `c + q/den` with
/// `q = (o − c)·den + num·d`, so it is inside the disk iff |q|² < r²·den².
#[inline(always)]
pub fn intersect(ray: &Ray, splat: &Splat, t_max: f32) -> Option<DiskHit> {
    // The test does not depend on the normal's length. Scaled by 2¹⁴ (exactly), a normal that
    // blocks store (`accel::block`) has integer components, which their kernel reads as they
    // are: the same bits without a multiply a component.
    let normal = splat.normal * NORMAL_SCALE;
    let den = ray.dir.dot(normal);
    let to_center = splat.center - ray.origin;
    let num = to_center.dot(normal);
    // t ∈ [t_min, t_max] ⇔ num·sign(den) ∈ [t_min·|den|, t_max·|den|]; false for den = 0 and
    // for NaN. The bounds are widened by a few ulps here, because t·den rounds differently
    // from num, and the exact test on t itself comes last: a disk that ties with the current
    // nearest hit must reach the visitor whatever order disks arrive in.
    let (num_s, den_a) = if den < 0.0 { (-num, -den) } else { (num, den) };
    const SLACK: f32 = 1.0 / 65536.0;
    if !(num_s >= ray.t_min * den_a * (1.0 - SLACK) && num_s <= t_max * den_a * (1.0 + SLACK) && den_a > 0.0) {
        return None;
    }
    let q = ray.dir * num - to_center * den;
    let r2_den2 = splat.radius * splat.radius * den * den;
    let q2 = q.length_squared();
    // Not `q2 >= r2_den2`: a NaN on either side must miss (as in `accel::block`).
    let inside = q2 < r2_den2;
    if !inside {
        return None;
    }
    let t = num / den;
    // Re-check with the rounded t, so that a hit never lies outside [t_min, t_max].
    (t >= ray.t_min && t <= t_max).then(|| DiskHit { t, dist2: q2 / (den * den) })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Ray, RayCone};
    use glam::Vec3;

    fn disk() -> Splat {
        Splat { center: Vec3::ZERO, radius: 0.5, normal: Vec3::Z, color: 0 }
    }

    #[test]
    fn splat_is_32_bytes() {
        assert_eq!(size_of::<Splat>(), 32);
    }

    #[test]
    fn hits_inside_and_misses_outside() {
        let d = disk();
        for (x, hit) in [(0.10, true), (0.49, true), (0.51, false)] {
            let ray = Ray::new(Vec3::new(x, 0.0, 5.0), -Vec3::Z, RayCone::default());
            let h = intersect(&ray, &d, f32::INFINITY);
            assert_eq!(h.is_some(), hit, "x = {x}");
            if let Some(h) = h {
                assert!((h.t - 5.0).abs() < 1e-6);
                assert!((h.dist2 - x * x).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn two_sided_parallel_and_range() {
        let d = disk();
        let below = Ray::new(Vec3::new(0.0, 0.0, -2.0), Vec3::Z, RayCone::default());
        assert!(intersect(&below, &d, f32::INFINITY).is_some());
        assert!(intersect(&below, &d, 1.5).is_none(), "t_max must bound the hit");
        assert!(intersect(&below.with_t_min(2.5), &d, f32::INFINITY).is_none());
        let parallel = Ray::new(Vec3::new(-1.0, 0.0, 0.0), Vec3::X, RayCone::default());
        assert!(intersect(&parallel, &d, f32::INFINITY).is_none());
    }

    #[test]
    fn hit_lies_on_plane_within_radius() {
        // A tilted disk, many rays: every reported hit is on the plane and inside the radius.
        let n = Vec3::new(0.3, -0.5, 0.8).normalize();
        let s = Splat { center: Vec3::new(0.2, 0.1, -0.3), radius: 0.4, normal: n, color: 0 };
        let mut hits = 0;
        for i in 0..400 {
            let a = i as f32 * 0.618;
            let o = Vec3::new(a.sin() * 2.0, a.cos() * 2.0, 3.0);
            let target = s.center + Vec3::new((a * 3.1).sin(), (a * 1.7).cos(), 0.0) * 0.6;
            let ray = Ray::new(o, target - o, RayCone::default());
            if let Some(h) = intersect(&ray, &s, f32::INFINITY) {
                hits += 1;
                let p = ray.at(h.t);
                assert!((p - s.center).dot(n).abs() < 1e-5);
                assert!((p - s.center).length() < s.radius + 1e-5);
            }
        }
        assert!(hits > 50, "the test should exercise hits, got {hits}");
    }
}
