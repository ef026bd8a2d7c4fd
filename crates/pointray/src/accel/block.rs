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
use crate::splat::{DiskShape, NORMAL_SCALE, Splat};
use glam::Vec3;
use rayon::prelude::*;

/// Disks per block.
pub(crate) const BLOCK: usize = 8;

/// Up to eight consecutive splats of one leaf: the only copy of the BVH's splats. Lane i of
/// block b is splat `BLOCK·b + i`. Unused lanes hold a disk of radius 0 and no normal, which
/// no ray hits.
///
/// Compact: a lane's centre is `origin + step·offset` (16-bit offsets, `step` a power of two)
/// and its normal `NORMAL_UNIT·normal` (16-bit components), both exact in f32, so the kernel
/// computes on the very values [`SplatBlock::splat`] gives back. 176 bytes for eight disks where
/// f32 centres and normals took 256. A leaf block holds its splats without loss when they are
/// [`snap`]ped and the leaf spans at most [`leaf_span`] of its finest grid (the BVH's build sees
/// to both); a block of representatives rounds their centres to its step (see [`SplatBlock::new`]).
/// The kernel reads the first 144 bytes; the colours, at the end, only the visitors' look-ups.
/// The rows come before the origin and step: with those first, the compiler loaded the first
/// row of offsets in two halves and joined them (first hits 704 → 692 instructions a pixel at
/// 256², callgrind).
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct SplatBlock {
    pub(super) offset: [[u16; BLOCK]; 3],
    pub(super) normal: [[i16; BLOCK]; 3],
    pub(super) origin: [f32; 3],
    pub(super) step: f32,
    pub(super) radius: [f32; BLOCK],
    pub(super) color: [u32; BLOCK],
}

/// A stored normal component is a multiple of this (2⁻¹⁴: ±1 fits an `i16`, and every multiple
/// is an exact f32). The oriented-disk test scales normals by its inverse, so the kernel uses
/// the stored integers as they are.
pub(crate) const NORMAL_UNIT: f32 = 1.0 / NORMAL_SCALE;

/// The largest centre offset a block stores.
const MAX_OFFSET: f32 = u16::MAX as f32;

/// The grid step of a splat of radius `r`: 2⁻¹⁰ of the largest power of two not above it (so a
/// centre moves by at most a 2,048th of its radius); 2⁻¹²⁶ for a radius that is not positive.
/// Each splat's own, so that snapping depends on nothing else and a sparse region's wide disks
/// get a grid as coarse as they are.
pub(crate) fn grid_step(r: f32) -> f32 {
    // 2^⌊log₂ r⌋ is r with its mantissa cleared (+∞ for an infinite or NaN radius). (Through
    // f64's bits and a clamp, 22 instructions a splat, twice in a build.)
    let power = f32::from_bits(r.to_bits() & 0x7f80_0000);
    if r > 0.0 && power < f32::INFINITY { (power * (1.0 / 1024.0)).max(f32::MIN_POSITIVE) } else { f32::MIN_POSITIVE }
}

/// The widest a leaf whose finest grid step is `step` may be along any axis, as measured on its
/// centres in f32, for its blocks to hold their snapped centres exactly: half the 65,535 steps a
/// block can span (the half covers the rounding of the measure), 16 of its narrowest radii.
pub(crate) fn leaf_span(step: f32) -> f32 {
    step * 32_768.0
}

/// `c` moved to the nearest multiple of `step` along each axis (a no-op for coordinates whose
/// f32 spacing is the step or coarser: they are multiples already), −0 made +0 as a block gives
/// it back.
fn snap_center(c: Vec3, step: f32) -> Vec3 {
    // Exact but for the rounding: the step is a power of two, and a multiple of it below 2²⁴
    // steps is a float. From 2²³ steps on (or where x/step overflows, for a tiny step), x is a
    // multiple already.
    let inv = 1.0 / step;
    let snap = |x: f32| {
        let v = x * inv;
        if v.abs() < 8_388_608.0 { round_to_integer(v) * step + 0.0 } else { x + 0.0 }
    };
    c.to_array().map(snap).into()
}

/// The smallest power of two `s` (within f32's normal range) with `extent ≤ MAX_OFFSET·s`. (From
/// the bits: with `log2` and `powi`, library calls, blocks took 130 instructions a splat to make.)
fn block_step(extent: f64) -> f32 {
    let x = extent / f64::from(MAX_OFFSET);
    let exact = x.to_bits() & ((1 << 52) - 1) == 0;
    pow2(exponent(x) + i32::from(!exact))
}

/// ⌊log₂ x⌋ for a positive normal `x` (−1,023 for 0 and subnormals).
fn exponent(x: f64) -> i32 {
    ((x.to_bits() >> 52) & 0x7ff) as i32 - 1023
}

/// 2ᵉ, `e` clamped to f32's normal exponents.
fn pow2(e: i32) -> f32 {
    f32::from_bits(((e.clamp(-126, 127) + 127) as u32) << 23)
}

/// `n` with each component moved to the nearest multiple of [`NORMAL_UNIT`]: what a block
/// stores. Not renormalised (its length stays within 10⁻⁴ of one); the ray–disk test does not
/// depend on the normal's length, and shading normalises.
pub(crate) fn snap_normal(n: Vec3) -> Vec3 {
    n.to_array().map(|x| unit(quantize_normal(x))).into()
}

/// Snaps `splats` to what the blocks store, the same for every accelerator built from them so
/// that all find the same hits: each centre onto its splat's grid ([`grid_step`]), normals onto
/// multiples of [`NORMAL_UNIT`]; radii and colours as they are. Snapping twice changes nothing.
pub(crate) fn snap(splats: &mut [Splat]) {
    splats.par_iter_mut().for_each(|s| {
        s.center = snap_center(s.center, grid_step(s.radius));
        s.normal = snap_normal(s.normal);
    });
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

/// `v` rounded to an integer (ties to even) by adding and taking away 1.5·2²³ (from 2²³ on,
/// every float is an integer): `round`, a library call, took about 200 million of the 1M
/// torus's load-and-build instructions for snapping and making blocks.
#[inline(always)]
fn round_to_integer(v: f32) -> f32 {
    if v.abs() <= 4_194_304.0 { round_small(v) } else { v.round_ties_even() }
}

/// [`round_to_integer`] for |v| ≤ 2²² (and NaN, which stays NaN).
#[inline(always)]
fn round_small(v: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5·2²³
    (v + MAGIC) - MAGIC
}

/// A normal component as a block stores it (NaN as 0).
fn quantize_normal(x: f32) -> i16 {
    // Within ±2¹⁴ for a unit normal; the cast saturates anything else.
    round_small(x * NORMAL_SCALE) as i16
}

/// A stored offset as a float.
#[inline(always)]
fn widen(q: u16) -> f32 {
    f32::from(q)
}

/// A stored normal component as a float.
#[inline(always)]
fn unit(q: i16) -> f32 {
    f32::from(q) * NORMAL_UNIT
}

impl SplatBlock {
    /// The block of `splats` (at most [`BLOCK`]). Centres are stored as offsets from their
    /// least corner in steps of the smallest power of two that spans them: exactly where every
    /// centre is a multiple of that step away (snapped leaves), rounded to the nearest step
    /// otherwise (representatives, a 65,535th of the block's extent at most). Normals are
    /// rounded as [`snap_normal`] does.
    pub(crate) fn new(splats: &[Splat]) -> Self {
        debug_assert!((1..=BLOCK).contains(&splats.len()));
        let lo = splats.iter().fold(Vec3::INFINITY, |m, s| m.min(s.center));
        let hi = splats.iter().fold(Vec3::NEG_INFINITY, |m, s| m.max(s.center));
        let extent = (hi - lo).max_element();
        let step = block_step(if extent.is_finite() { f64::from(extent) } else { 0.0 });
        let inv_step = 1.0 / step; // exact: a power of two
        let mut block = Self {
            origin: lo.to_array(),
            step,
            offset: [[0; BLOCK]; 3],
            normal: [[0; BLOCK]; 3],
            radius: [0.0; BLOCK],
            color: [0; BLOCK],
        };
        for (i, s) in splats.iter().enumerate() {
            for k in 0..3 {
                // Exact for snapped centres (multiples of the step, fewer than 2¹⁶ of them).
                let off = (s.center[k] - lo[k]) * inv_step;
                block.offset[k][i] = round_small(off) as u16; // the cast saturates
                block.normal[k][i] = quantize_normal(s.normal[k]);
            }
            block.radius[i] = s.radius;
            block.color[i] = s.color;
        }
        block
    }

    /// Component `k` of the eight centres.
    #[inline(always)]
    pub(crate) fn center_lanes(&self, k: usize) -> [f32; BLOCK] {
        let (o, step) = (self.origin[k], self.step);
        // A loop, not `array::map`, which the build's calls did not inline.
        let mut lanes = [0.0; BLOCK];
        for (x, &q) in lanes.iter_mut().zip(&self.offset[k]) {
            *x = o + widen(q) * step;
        }
        lanes
    }

    /// Component `k` of the eight normals.
    #[inline(always)]
    pub(crate) fn normal_lanes(&self, k: usize) -> [f32; BLOCK] {
        let mut lanes = [0.0; BLOCK];
        for (x, &q) in lanes.iter_mut().zip(&self.normal[k]) {
            *x = unit(q);
        }
        lanes
    }

    /// [`Self::center_lanes`] for every axis, in f64 (the level-of-detail build's sums).
    #[inline(always)]
    pub(crate) fn centers_f64(&self) -> [[f64; BLOCK]; 3] {
        let mut lanes = [[0.0; BLOCK]; 3];
        for (k, axis) in lanes.iter_mut().enumerate() {
            let (o, step) = (self.origin[k], self.step);
            for (x, &q) in axis.iter_mut().zip(&self.offset[k]) {
                *x = f64::from(o + widen(q) * step);
            }
        }
        lanes
    }

    /// [`Self::normal_lanes`] for every axis, in f64.
    #[inline(always)]
    pub(crate) fn normals_f64(&self) -> [[f64; BLOCK]; 3] {
        let mut lanes = [[0.0; BLOCK]; 3];
        for (axis, q) in lanes.iter_mut().zip(&self.normal) {
            for (x, &q) in axis.iter_mut().zip(q) {
                *x = f64::from(unit(q));
            }
        }
        lanes
    }

    /// The eight radii.
    pub(crate) fn radii(&self) -> &[f32; BLOCK] {
        &self.radius
    }

    /// The eight packed colours.
    pub(crate) fn colors(&self) -> &[u32; BLOCK] {
        &self.color
    }

    /// Component `k` of the eight normals, as node lanes (the cone axes of a node's
    /// representatives).
    #[inline(always)]
    pub(crate) fn normal_node_lanes(&self, k: usize) -> Lanes {
        Lanes::from_array(self.normal_lanes(k))
    }

    /// The splat in `lane`.
    #[inline]
    pub(crate) fn splat(&self, lane: usize) -> Splat {
        let center = |k: usize| self.origin[k] + widen(self.offset[k][lane]) * self.step;
        let normal = |k: usize| unit(self.normal[k][lane]);
        Splat {
            center: Vec3::new(center(0), center(1), center(2)),
            radius: self.radius[lane],
            normal: Vec3::new(normal(0), normal(1), normal(2)),
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
        let c = [self.center_lanes(0), self.center_lanes(1), self.center_lanes(2)];
        // In units of `NORMAL_UNIT`, as the scalar test scales them.
        let n = self.normal.map(|k| k.map(f32::from));
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
        let c = [self.center_lanes(0), self.center_lanes(1), self.center_lanes(2)];
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

    /// A block gives back snapped splats bit for bit when they lie within a leaf's span, and
    /// any others within half a step of each coordinate (the centres' step, `NORMAL_UNIT`).
    #[test]
    fn block_holds_its_splats() {
        let mut exact = 0;
        for (round, (splats, _, _)) in random_disks_and_rays(3, BLOCK, 200).into_iter().enumerate() {
            let colored =
                |(i, s): (usize, Splat)| Splat { color: ((round * BLOCK + i) as u32).wrapping_mul(0x0101_0101), ..s };
            let mut splats: Vec<Splat> = splats.into_iter().enumerate().map(colored).collect();
            // Half the rounds narrowed to a leaf's span of their finest grid: those must be held
            // exactly.
            let narrow = round % 2 == 0;
            if narrow {
                let finest = splats.iter().map(|s| grid_step(s.radius)).fold(f32::INFINITY, f32::min);
                let scale = leaf_span(finest) / 2.0;
                splats.iter_mut().for_each(|s| s.center *= scale);
                snap(&mut splats);
            }
            let block = SplatBlock::new(&splats);
            for (lane, s) in splats.iter().enumerate() {
                let got = block.splat(lane);
                assert_eq!((got.radius.to_bits(), got.color), (s.radius.to_bits(), s.color));
                if narrow {
                    assert_eq!(got.bits(), s.bits());
                    exact += 1;
                }
                assert!(
                    (got.center - s.center).abs().max_element() <= 0.5 * block.step * (1.0 + 1e-6),
                    "{got:?} {s:?}"
                );
                assert!((got.normal - s.normal).abs().max_element() <= 0.5 * NORMAL_UNIT, "{got:?} {s:?}");
            }
        }
        assert!(exact > 300, "{exact} exact lanes");
    }

    /// Snapping twice changes nothing, and moves a centre by at most half its grid step (a
    /// 2,048th of its radius at most).
    #[test]
    fn snapping_is_idempotent() {
        let (splats, _, _) = random_disks_and_rays(8, 64, 64).pop().unwrap();
        let mut once = splats.clone();
        snap(&mut once);
        let mut twice = once.clone();
        snap(&mut twice);
        assert_eq!(once, twice);
        for (a, b) in splats.iter().zip(&once) {
            let step = grid_step(a.radius);
            assert!(step <= a.radius / 1024.0 && step > a.radius / 2048.0);
            assert!((a.center - b.center).abs().max_element() <= 0.5 * step);
            assert_eq!(snap_normal(b.normal), b.normal);
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
            let s = block.splat(0);
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
            // The splats as the block holds them (rounded: these are not snapped).
            let splats: Vec<Splat> = (0..lanes).map(|i| block.splat(i)).collect();
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
