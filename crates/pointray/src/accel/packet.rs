//! Four disks against one ray at once (SSE): the pre-filter the kd-tree runs over its leaves, so
//! that only the few disks a ray may cross get the exact test. (The BVH's leaves have their own
//! exact eight-lane kernel, `accel::block`.)

use glam::{Mat4, Vec4};

use crate::math::Ray;
use crate::splat::{DiskShape, NORMAL_SCALE, Splat};

/// Disks tested together.
pub(crate) const LANES: usize = 4;

/// Four disks in structure-of-arrays form. Unused lanes hold [`NO_DISK`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct DiskLanes {
    pub(crate) center: [Vec4; 3],
    pub(crate) normal: [Vec4; 3],
    pub(crate) radius: Vec4,
}

impl DiskLanes {
    #[inline(always)]
    pub(crate) fn new(lanes: [&Splat; LANES]) -> Self {
        // A splat is two rows of four floats (centre and radius, normal and colour): two 4×4
        // transposes, a few shuffles, gather the lanes, where 28 scalar inserts would not.
        let [a, b, c, d] = lanes;
        let first = |s: &Splat| Vec4::new(s.center.x, s.center.y, s.center.z, s.radius);
        // Normals scaled as the scalar test scales them.
        let second = |s: &Splat| Vec4::new(s.normal.x, s.normal.y, s.normal.z, 0.0) * NORMAL_SCALE;
        let centers = Mat4::from_cols(first(a), first(b), first(c), first(d)).transpose();
        let normals = Mat4::from_cols(second(a), second(b), second(c), second(d)).transpose();
        Self {
            center: [centers.x_axis, centers.y_axis, centers.z_axis],
            normal: [normals.x_axis, normals.y_axis, normals.z_axis],
            radius: centers.w_axis,
        }
    }

    /// Lanes from up to four consecutive splats.
    #[cfg(test)]
    pub(crate) fn from_slice(splats: &[Splat]) -> Self {
        debug_assert!(splats.len() <= LANES);
        Self::new(std::array::from_fn(|i| splats.get(i).unwrap_or(&NO_DISK)))
    }
}

/// Fills unused lanes: radius 0 and no normal, a disk no ray hits.
pub(crate) const NO_DISK: Splat = Splat { center: glam::Vec3::ZERO, normal: glam::Vec3::ZERO, radius: 0.0, color: 0 };

#[inline(always)]
pub(crate) fn dot3(a: &[Vec4; 3], b: &[Vec4; 3]) -> Vec4 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// A ray's origin and direction, each axis splatted to four lanes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PacketRay {
    pub(crate) origin: [Vec4; 3],
    pub(crate) dir: [Vec4; 3],
}

impl PacketRay {
    #[inline(always)]
    pub(crate) fn new(ray: &Ray) -> Self {
        Self {
            origin: std::array::from_fn(|k| Vec4::splat(ray.origin[k])),
            dir: std::array::from_fn(|k| Vec4::splat(ray.dir[k])),
        }
    }

    /// The lanes whose disk the ray may cross in `[t0, t1]`, as a bit mask. The arithmetic is
    /// the scalar test's (`splat::oriented_disk::intersect`) lane by lane, in the same order,
    /// with a little more slack: a pre-filter that never rejects a disk the exact test accepts.
    #[inline(always)]
    pub(crate) fn candidates(&self, disks: &DiskLanes, t0: f32, t1: f32) -> u32 {
        let den = dot3(&self.dir, &disks.normal);
        let to_center: [Vec4; 3] = std::array::from_fn(|k| disks.center[k] - self.origin[k]);
        let num = dot3(&to_center, &disks.normal);
        let negative = den.cmplt(Vec4::ZERO);
        let num_s = Vec4::select(negative, -num, num);
        let den_a = den.abs();
        const SLACK: f32 = 1.0 / 16384.0;
        let in_range = num_s.cmpge(Vec4::splat(t0 * (1.0 - SLACK)) * den_a)
            & num_s.cmple(Vec4::splat(t1 * (1.0 + SLACK)) * den_a)
            & den_a.cmpgt(Vec4::ZERO);
        let q: [Vec4; 3] = std::array::from_fn(|k| self.dir[k] * num - to_center[k] * den);
        let q2 = dot3(&q, &q);
        let r2_den2 = disks.radius * disks.radius * den * den * (1.0 + SLACK);
        (in_range & q2.cmplt(r2_den2)).bitmask()
    }

    /// As [`Self::candidates`], for ray-facing disks (`splat::ray_facing_disk::intersect`, lane
    /// by lane): the centre's projection on the ray lies in `[t0, t1]` and within r of it.
    #[inline(always)]
    pub(crate) fn ray_facing_candidates(&self, disks: &DiskLanes, t0: f32, t1: f32) -> u32 {
        let to_center: [Vec4; 3] = std::array::from_fn(|k| disks.center[k] - self.origin[k]);
        let t = dot3(&to_center, &self.dir);
        const SLACK: f32 = 1.0 / 16384.0;
        let in_range = t.cmpge(Vec4::splat(t0 - t0.abs() * SLACK)) & t.cmple(Vec4::splat(t1 + t1.abs() * SLACK));
        let q: [Vec4; 3] = std::array::from_fn(|k| to_center[k] - self.dir[k] * t);
        let q2 = dot3(&q, &q);
        (in_range & q2.cmplt(disks.radius * disks.radius * (1.0 + SLACK))).bitmask()
    }

    /// The candidates for the disks `shape` stands for.
    #[inline(always)]
    pub(crate) fn candidates_as(&self, shape: DiskShape, disks: &DiskLanes, t0: f32, t1: f32) -> u32 {
        match shape {
            DiskShape::Oriented => self.candidates(disks, t0, t1),
            DiskShape::RayFacing => self.ray_facing_candidates(disks, t0, t1),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::lane_cases::random_disks_and_rays;
    use crate::splat::{oriented_disk, ray_facing_disk};

    /// The pre-filter may pass disks the exact test rejects, never the other way round:
    /// otherwise an accelerator would miss hits that brute force finds.
    #[test]
    fn prefilter_never_rejects_an_exact_hit() {
        check_prefilter(DiskShape::Oriented);
        check_prefilter(DiskShape::RayFacing);
    }

    fn check_prefilter(shape: DiskShape) {
        let (mut hits, mut rejected) = (0, 0);
        for (splats, ray, t_max) in random_disks_and_rays(5, LANES, 20_000) {
            let lanes = splats.len();
            let disks = DiskLanes::from_slice(&splats);
            let candidates = PacketRay::new(&ray).candidates_as(shape, &disks, ray.t_min, t_max);
            assert_eq!(candidates >> lanes, 0, "an unused lane passed");
            for (lane, s) in splats.iter().enumerate() {
                let exact = match shape {
                    DiskShape::Oriented => oriented_disk::intersect(&ray, s, t_max),
                    DiskShape::RayFacing => ray_facing_disk::intersect(&ray, s, t_max),
                }
                .is_some();
                let passed = candidates & (1 << lane) != 0;
                assert!(!exact || passed, "lane {lane} of {splats:?} rejected for {ray:?} up to {t_max}");
                hits += usize::from(exact);
                rejected += usize::from(!passed);
            }
        }
        assert!(
            hits > 1_000 && rejected > 10_000,
            "{shape:?}: the test must see both: {hits} hits, {rejected} rejections"
        );
    }
}
