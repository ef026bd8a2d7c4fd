//! Eight disks against one ray in one pass: the BVH's leaf kernel.
//!
//! A leaf's splats are stored as blocks of eight in structure-of-arrays form, and the exact
//! ray–disk test of `splat::oriented_disk` (or `splat::ray_facing_disk`) runs over all eight
//! lanes at once, giving each lane's hit distance and in-plane distance: the visitor receives
//! finished crossings and tests nothing itself.
//!
//! The kernel is plain arithmetic on `[f32; 8]`, written lane by lane in the scalar tests'
//! order of operations: the compiler turns it into one AVX instruction per operation where
//! the traversal is compiled for AVX2 (`accel::isa`), two SSE ones on the x86-64 baseline, and
//! NEON elsewhere, and every path gives the scalar test's bits (no fused multiply-add: IEEE
//! arithmetic rounds the same lane by lane). Measured with callgrind on the dragon, first
//! hit: ~75 instructions per 4-wide packet for the SSE pre-filter plus the visitor's scalar
//! re-test of the candidates before, ~45 per 8-wide block after (`docs/RESULTS.md`).

use super::bvh::lanes::{Lanes, Wide};
use crate::math::Ray;
use crate::splat::oriented_disk::DiskHit;
use crate::splat::{DiskShape, Splat};
use glam::Vec3;

/// Disks per block.
pub(crate) const BLOCK: usize = 8;

/// Up to eight consecutive splats of one leaf: the only copy of the BVH's splats. Lane i of
/// block b is splat `BLOCK·b + i`. Unused lanes hold a disk of radius 0 and no normal, which
/// no ray hits. Four cache lines: the kernel reads the first three and a half; the colours,
/// at the end, only the visitors' look-ups read.
#[repr(C, align(32))]
#[derive(Clone, Copy, Debug)]
pub(crate) struct SplatBlock {
    pub(super) center: [[f32; BLOCK]; 3],
    pub(super) normal: [[f32; BLOCK]; 3],
    pub(super) radius: [f32; BLOCK],
    pub(super) color: [u32; BLOCK],
}

/// The leaf kernel a traversal runs: [`Portable`], or one written for an instruction set
/// (`accel::isa`). All give the same bits.
pub(crate) trait LeafKernel: Copy {
    /// How the same instruction set computes a node's eight lanes.
    type Lanes: Wide;
    fn hits(self, block: &SplatBlock, shape: DiskShape, ray: &Ray, t_max: f32) -> BlockHits;
}

/// [`SplatBlock::hits`], which the compiler vectorizes for whatever it targets.
#[derive(Clone, Copy)]
pub(crate) struct Portable;

impl LeafKernel for Portable {
    type Lanes = Lanes;

    #[inline(always)]
    fn hits(self, block: &SplatBlock, shape: DiskShape, ray: &Ray, t_max: f32) -> BlockHits {
        block.hits(shape, ray, t_max)
    }
}

/// The lanes a ray crosses (bit i for lane i), with every lane's crossing.
pub(crate) struct BlockHits {
    pub(crate) mask: u32,
    pub(crate) t: [f32; BLOCK],
    pub(crate) dist2: [f32; BLOCK],
}

impl BlockHits {
    pub(crate) fn hit(&self, lane: usize) -> DiskHit {
        DiskHit { t: self.t[lane], dist2: self.dist2[lane] }
    }
}

impl SplatBlock {
    /// The block of `splats` (at most [`BLOCK`]).
    pub(crate) fn new(splats: &[Splat]) -> Self {
        debug_assert!((1..=BLOCK).contains(&splats.len()));
        let mut block =
            Self { center: [[0.0; BLOCK]; 3], normal: [[0.0; BLOCK]; 3], radius: [0.0; BLOCK], color: [0; BLOCK] };
        for (i, s) in splats.iter().enumerate() {
            for k in 0..3 {
                block.center[k][i] = s.center[k];
                block.normal[k][i] = s.normal[k];
            }
            block.radius[i] = s.radius;
            block.color[i] = s.color;
        }
        block
    }

    /// Component `k` of the eight normals, as node lanes (the cone axes of a node's
    /// representatives).
    #[inline(always)]
    pub(crate) fn normal_lanes(&self, k: usize) -> Lanes {
        Lanes::from_array(self.normal[k])
    }

    /// The splat in `lane`.
    #[inline]
    pub(crate) fn splat(&self, lane: usize) -> Splat {
        let (c, n) = (&self.center, &self.normal);
        Splat {
            center: Vec3::new(c[0][lane], c[1][lane], c[2][lane]),
            radius: self.radius[lane],
            normal: Vec3::new(n[0][lane], n[1][lane], n[2][lane]),
            color: self.color[lane],
        }
    }

    /// The crossings of the disks `shape` stands for within `[ray.t_min, t_max]`.
    #[inline(always)]
    pub(crate) fn hits(&self, shape: DiskShape, ray: &Ray, t_max: f32) -> BlockHits {
        match shape {
            DiskShape::Oriented => self.oriented(ray, t_max),
            DiskShape::RayFacing => self.ray_facing(ray, t_max),
        }
    }

    /// `oriented_disk::intersect` lane by lane. The divisions run only for blocks with a
    /// candidate (about one block in four on the dragon).
    #[inline(always)]
    fn oriented(&self, ray: &Ray, t_max: f32) -> BlockHits {
        const SLACK: f32 = 1.0 / 65536.0;
        let (o, d, t_min) = (ray.origin.to_array(), ray.dir.to_array(), ray.t_min);
        let (c, n) = (&self.center, &self.normal);
        let mut num = [0.0; BLOCK];
        let mut den = [0.0; BLOCK];
        let mut q2 = [0.0; BLOCK];
        let mut candidate = [0u32; BLOCK];
        for i in 0..BLOCK {
            let dn = d[0] * n[0][i] + d[1] * n[1][i] + d[2] * n[2][i];
            let to_center = [c[0][i] - o[0], c[1][i] - o[1], c[2][i] - o[2]];
            let nm = to_center[0] * n[0][i] + to_center[1] * n[1][i] + to_center[2] * n[2][i];
            let (num_s, den_a) = if dn < 0.0 { (-nm, -dn) } else { (nm, dn) };
            let in_range =
                (num_s >= t_min * den_a * (1.0 - SLACK)) & (num_s <= t_max * den_a * (1.0 + SLACK)) & (den_a > 0.0);
            let q = [d[0] * nm - to_center[0] * dn, d[1] * nm - to_center[1] * dn, d[2] * nm - to_center[2] * dn];
            let qq = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
            // NaN compares false: no hit, as in the scalar test.
            let inside = qq < self.radius[i] * self.radius[i] * dn * dn;
            (num[i], den[i], q2[i], candidate[i]) = (nm, dn, qq, u32::from(in_range & inside));
        }
        let mut hits = BlockHits { mask: lane_mask(&candidate), t: [0.0; BLOCK], dist2: [0.0; BLOCK] };
        if hits.mask == 0 {
            return hits;
        }
        let mut in_range = [0u32; BLOCK];
        for i in 0..BLOCK {
            let t = num[i] / den[i];
            hits.t[i] = t;
            hits.dist2[i] = q2[i] / (den[i] * den[i]);
            // Re-checked with the rounded t, so that a hit never lies outside [t_min, t_max].
            in_range[i] = u32::from((t >= t_min) & (t <= t_max));
        }
        hits.mask &= lane_mask(&in_range);
        hits
    }

    /// `ray_facing_disk::intersect` lane by lane.
    #[inline(always)]
    fn ray_facing(&self, ray: &Ray, t_max: f32) -> BlockHits {
        let (o, d, t_min) = (ray.origin.to_array(), ray.dir.to_array(), ray.t_min);
        let c = &self.center;
        let mut hits = BlockHits { mask: 0, t: [0.0; BLOCK], dist2: [0.0; BLOCK] };
        let mut hit = [0u32; BLOCK];
        for i in 0..BLOCK {
            let to_center = [c[0][i] - o[0], c[1][i] - o[1], c[2][i] - o[2]];
            let t = to_center[0] * d[0] + to_center[1] * d[1] + to_center[2] * d[2];
            let q = [to_center[0] - d[0] * t, to_center[1] - d[1] * t, to_center[2] - d[2] * t];
            let dist2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
            hit[i] = u32::from((t >= t_min) & (t <= t_max) & (dist2 < self.radius[i] * self.radius[i]));
            (hits.t[i], hits.dist2[i]) = (t, dist2);
        }
        hits.mask = lane_mask(&hit);
        hits
    }
}

/// Bit i set where `lanes[i]` is 1 (a shift and an OR-reduction the compiler vectorizes).
#[inline(always)]
fn lane_mask(lanes: &[u32; BLOCK]) -> u32 {
    let mut mask = 0;
    for (i, &l) in lanes.iter().enumerate() {
        mask |= l << i;
    }
    mask
}

#[cfg(test)]
pub(crate) mod tests {
    use glam::Vec3;

    use super::*;
    use crate::accel::lane_cases::random_disks_and_rays;
    use crate::math::RayCone;

    /// The block test gives exactly the scalar tests' hits, bit for bit, on the path this
    /// build runs (`accel::isa` runs it again compiled for AVX2).
    #[test]
    fn block_equals_the_scalar_tests() {
        let (hits, misses) = check_against_scalar(|block, shape, ray, t_max| block.hits(shape, ray, t_max));
        assert!(hits > 5_000 && misses > 50_000, "the test must see both: {hits} hits, {misses} misses");
    }

    /// A block gives back the splats it was made of, bit for bit.
    #[test]
    fn block_holds_its_splats() {
        for (round, (splats, _, _)) in random_disks_and_rays(3, BLOCK, 64).into_iter().enumerate() {
            let colored =
                |(i, s): (usize, Splat)| Splat { color: ((round * BLOCK + i) as u32).wrapping_mul(0x0101_0101), ..s };
            let splats: Vec<Splat> = splats.into_iter().enumerate().map(colored).collect();
            let block = SplatBlock::new(&splats);
            for (lane, s) in splats.iter().enumerate() {
                let bits = |s: Splat| {
                    (
                        s.center.to_array().map(f32::to_bits),
                        s.normal.to_array().map(f32::to_bits),
                        s.radius.to_bits(),
                        s.color,
                    )
                };
                assert_eq!(bits(block.splat(lane)), bits(*s));
            }
        }
    }

    /// The edges random cases never reach, on the portable kernel.
    #[test]
    fn block_equals_the_scalar_tests_at_the_edges() {
        check_edges(|block, shape, ray, t_max| block.hits(shape, ray, t_max));
    }

    /// The edges random cases never reach: a ray in the disk's plane (den = 0), crossings exactly
    /// at t_min and at t_max, a NaN radius, a ray with a zero direction component.
    pub(crate) fn check_edges(kernel: impl Fn(&SplatBlock, DiskShape, &Ray, f32) -> BlockHits) {
        let disk = |z: f32, radius: f32| Splat { center: Vec3::new(0.0, 0.0, z), radius, normal: Vec3::Z, color: 0 };
        let down = Ray::new(Vec3::new(0.1, 0.0, 5.0), -Vec3::Z, RayCone::default());
        let cases = [
            (disk(0.0, 0.5), Ray::new(Vec3::new(-2.0, 0.0, 0.0), Vec3::X, RayCone::default()), f32::INFINITY),
            (disk(0.0, 0.5), down, 5.0),
            (disk(0.0, 0.5), down.with_t_min(5.0), f32::INFINITY),
            (disk(0.0, f32::NAN), down, f32::INFINITY),
            (disk(1.0, 0.5), Ray::new(Vec3::new(0.5, 0.0, 5.0), -Vec3::Z, RayCone::default()), f32::INFINITY),
        ];
        let mut hits = 0;
        for (s, ray, t_max) in cases {
            let block = SplatBlock::new(&[s]);
            for shape in [DiskShape::Oriented, DiskShape::RayFacing] {
                let got = kernel(&block, shape, &ray, t_max);
                let lane = (got.mask & 1 != 0).then(|| got.hit(0));
                let exact = shape.intersect(&ray, &s, t_max);
                let bits = |h: Option<DiskHit>| h.map(|h| (h.t.to_bits(), h.dist2.to_bits()));
                assert_eq!(bits(lane), bits(exact), "{shape:?}: {s:?}, {ray:?} up to {t_max}");
                assert_eq!(got.mask >> 1, 0, "an unused lane hit");
                hits += usize::from(exact.is_some());
            }
        }
        assert!(hits >= 4, "the edge cases must include hits at t_min and t_max, got {hits}");
    }

    /// Random blocks and rays; every lane of `kernel`'s answer against the scalar test. Returns
    /// (hits, misses) seen.
    pub(crate) fn check_against_scalar(
        kernel: impl Fn(&SplatBlock, DiskShape, &Ray, f32) -> BlockHits,
    ) -> (usize, usize) {
        let (mut hits, mut misses) = (0, 0);
        for (splats, ray, t_max) in random_disks_and_rays(11, BLOCK, 20_000) {
            let lanes = splats.len();
            let block = SplatBlock::new(&splats);
            for shape in [DiskShape::Oriented, DiskShape::RayFacing] {
                let got = kernel(&block, shape, &ray, t_max);
                assert_eq!(got.mask >> lanes, 0, "an unused lane hit");
                for (lane, s) in splats.iter().enumerate() {
                    let exact = shape.intersect(&ray, s, t_max);
                    let lane_hit = (got.mask & (1 << lane) != 0).then(|| got.hit(lane));
                    let bits = |h: Option<DiskHit>| h.map(|h| (h.t.to_bits(), h.dist2.to_bits()));
                    assert_eq!(bits(lane_hit), bits(exact), "{shape:?} lane {lane} of {s:?}, {ray:?} up to {t_max}");
                    hits += usize::from(exact.is_some());
                    misses += usize::from(exact.is_none());
                }
            }
        }
        (hits, misses)
    }
}
