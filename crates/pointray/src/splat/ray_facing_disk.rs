//! Ray versus ray-facing disk (the thesis's RFD, RECONSTRUCTION A10): a disk centred at the
//! splat, of its radius, turned to face the ray. The ray meets it at the projection of the
//! centre onto the ray, if it passes within the radius of the centre: no division, no normal,
//! and no grazing angle at which the disk goes edge-on (so no cracks at silhouettes). The
//! surface it makes is view dependent and up to about r thicker at silhouettes.

use super::Splat;
use super::oriented_disk::DiskHit;
use crate::math::Ray;

/// The ray's closest approach to the centre, t_c = (c − o)·d, and the squared perpendicular
/// distance there; a hit if that is below r² and t_c lies in `[ray.t_min, t_max]`.
#[inline(always)]
pub fn intersect(ray: &Ray, splat: &Splat, t_max: f32) -> Option<DiskHit> {
    let to_center = splat.center - ray.origin;
    let t = to_center.dot(ray.dir);
    if !(t >= ray.t_min && t <= t_max) {
        return None;
    }
    let dist2 = (to_center - ray.dir * t).length_squared();
    (dist2 < splat.radius * splat.radius).then_some(DiskHit { t, dist2 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::RayCone;
    use glam::Vec3;

    #[test]
    fn faces_every_ray_even_along_the_disk_plane() {
        let s = Splat { center: Vec3::ZERO, radius: 0.5, normal: Vec3::Z, color: 0 };
        // Along the oriented disk's plane (where an oriented disk is edge-on and missed) and
        // through its face: the same hit at the centre's projection.
        for dir in [Vec3::X, -Vec3::Z, Vec3::new(1.0, 0.0, -1.0)] {
            let origin = Vec3::new(0.0, 0.3, 0.0) - dir.normalize() * 4.0;
            let ray = Ray::new(origin, dir, RayCone::default());
            let h = intersect(&ray, &s, f32::INFINITY).expect("a ray within r of the centre hits");
            assert!((h.t - 4.0).abs() < 1e-5 && (h.dist2 - 0.09).abs() < 1e-5, "{dir}: {h:?}");
        }
        let wide = Ray::new(Vec3::new(-4.0, 0.51, 0.0), Vec3::X, RayCone::default());
        assert!(intersect(&wide, &s, f32::INFINITY).is_none(), "beyond the radius");
        let ray = Ray::new(Vec3::new(-4.0, 0.0, 0.0), Vec3::X, RayCone::default());
        assert!(intersect(&ray, &s, 3.9).is_none() && intersect(&ray.with_t_min(4.1), &s, 9.0).is_none());
    }
}
