//! The instruction set the hot loops run on, chosen once per process.
//!
//! On x86-64 the BVH's traversal is compiled twice: for the baseline every x86-64 CPU has
//! (SSE2), with the portable leaf kernel ([`super::block`]) and nodes' lanes as two SSE vectors
//! ([`Lanes`](super::bvh::lanes::Lanes)), and with AVX2 and FMA enabled, with a leaf kernel and
//! node lanes in AVX intrinsics (`avx2`), taken when the CPU reports both (the kernels use no
//! fused multiply-add; FMA comes with every AVX2 CPU). Elsewhere (aarch64, …) there is
//! one path, for the target's own baseline. `POINTRAY_ISA=baseline` forces the baseline; CI
//! runs the oracle tests that way too.
//!
//! Both paths give the same bits: the kernels are written without fused multiply-adds, in the
//! scalar code's order of operations, so every lane rounds as the scalar code does (tested
//! below, in `block`, and by the oracle tests).
//!
//! This module holds the crate's only SIMD `unsafe`: calling the AVX2 build, which is sound
//! only on a CPU that has AVX2, the AVX2 kernel's loads and stores, and the AVX operations on
//! node lanes.

use super::block::Portable;
use super::bvh::Bvh;
use super::bvh::traverse::{self, Levels};
use super::{SplatVisitor, TraversalStats};
use crate::math::Ray;

/// An instruction-set path of the hot loops.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Isa {
    /// The target's baseline: SSE2 on x86-64, NEON on aarch64.
    Baseline,
    /// AVX2 (and FMA): eight lanes per instruction.
    Avx2,
}

impl Isa {
    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            Isa::Avx2 => "avx2",
        }
    }
}

/// The path this process runs: the best the CPU has, unless `POINTRAY_ISA=baseline`. Inlined:
/// every traversal asks, and the answer, once made, is one load.
#[inline]
pub fn active() -> Isa {
    static ACTIVE: std::sync::OnceLock<Isa> = std::sync::OnceLock::new();
    *ACTIVE.get_or_init(|| {
        let forced = std::env::var("POINTRAY_ISA").unwrap_or_default();
        match forced.as_str() {
            "baseline" => Isa::Baseline,
            "" | "auto" | "avx2" => detect(),
            other => {
                tracing::warn!("POINTRAY_ISA={other} is not baseline, avx2 or auto: using {}", detect().name());
                detect()
            }
        }
    })
}

/// The best path this CPU supports.
fn detect() -> Isa {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        return Isa::Avx2;
    }
    Isa::Baseline
}

/// The BVH traversal (`bvh::traverse`) on the active path.
#[inline]
pub(crate) fn bvh_traverse<V: SplatVisitor>(bvh: &Bvh, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
    #[cfg(target_arch = "x86_64")]
    if active() == Isa::Avx2 {
        // SAFETY: `active()` is `Avx2` only where `detect` saw the CPU report AVX2 and FMA,
        // the features `bvh_traverse_avx2` is compiled for.
        #[allow(unsafe_code)]
        return unsafe { bvh_traverse_avx2(bvh, ray, visitor, stats) };
    }
    bvh_traverse_baseline(bvh, ray, visitor, stats);
}

/// `bvh::traverse` for the baseline, apart: inlined into `bvh_traverse`, its size kept the
/// wrapper a function of its own that every AVX2 traversal went through, saving and restoring
/// the registers the baseline loop uses (29 instructions a ray). Now the wrapper is inlined
/// into its callers (callgrind, the dragon at distance 16, 64 samples, SJ: 1,340 → 1,305
/// instructions a sample).
#[inline(never)]
fn bvh_traverse_baseline<V: SplatVisitor>(bvh: &Bvh, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
    let multires = |visitor: &mut V, stats: &mut TraversalStats, levels: &Levels| {
        multires_baseline(bvh, ray, visitor, stats, levels)
    };
    traverse::traverse(bvh, ray, visitor, stats, Portable, multires);
}

/// The multiresolution loop for the baseline (see `traverse::multires_walk`).
#[inline(never)]
fn multires_baseline<V: SplatVisitor>(
    bvh: &Bvh,
    ray: &Ray,
    visitor: &mut V,
    stats: &mut TraversalStats,
    levels: &Levels,
) {
    traverse::multires_walk(bvh, ray, visitor, stats, levels, Portable);
}

/// `bvh::traverse` (inlined, with the leaf kernel and the visitor) compiled for AVX2: one
/// 256-bit instruction per operation of the eight-lane leaf test, VEX encodings elsewhere.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn bvh_traverse_avx2<V: SplatVisitor>(bvh: &Bvh, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
    let multires =
        |visitor: &mut V, stats: &mut TraversalStats, levels: &Levels| multires_avx2(bvh, ray, visitor, stats, levels);
    traverse::traverse(bvh, ray, visitor, stats, avx2::Kernel(()), multires);
}

/// The multiresolution loop for AVX2 (see `traverse::multires_walk`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline(never)]
fn multires_avx2<V: SplatVisitor>(bvh: &Bvh, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats, levels: &Levels) {
    traverse::multires_walk(bvh, ray, visitor, stats, levels, avx2::Kernel(()));
}

/// The leaf kernel in AVX intrinsics: [`SplatBlock::hits`] operation for operation (no fused
/// multiply-add, the same comparisons), so the same bits, with the lanes' verdicts gathered by
/// one `movemask` where the portable kernel's reduction of eight lanes took a dozen
/// instructions, and the comparisons kept as masks (callgrind on the dragon: 1,030 → 1,009
/// instructions a pixel with first hits, 1,346 → 1,322 with SJ; 2.8 % more rays a second).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::super::block::{BLOCK, BlockHits, LeafKernel, SplatBlock};
    use crate::accel::bvh::lanes::{Lanes, Wide};
    use crate::math::Ray;
    use crate::splat::DiskShape;

    /// The AVX2 kernel. Made only where `detect` saw AVX2 and FMA: by `bvh_traverse_avx2` and
    /// `multires_avx2`, which run only there, and by `kernel_for_tests` (the field, private to
    /// `isa`, keeps the rest of the crate from making one).
    #[derive(Clone, Copy)]
    pub(super) struct Kernel(pub(super) ());

    impl LeafKernel for Kernel {
        type Lanes = Lanes8;

        #[inline(always)]
        fn hits(self, block: &SplatBlock, shape: DiskShape, ray: &Ray, t_max: f32) -> BlockHits {
            // SAFETY: a `Kernel` exists only where `detect` saw AVX2 and FMA (see above), the
            // features these functions are compiled for.
            #[allow(unsafe_code)]
            unsafe {
                match shape {
                    DiskShape::Oriented => oriented(block, ray, t_max),
                    DiskShape::RayFacing => ray_facing(block, ray, t_max),
                }
            }
        }
    }

    /// A node's eight lanes in one AVX register: [`Wide`] operation for operation as
    /// [`Lanes`] computes it with two SSE vectors (the same IEEE operations, comparisons and
    /// NaN rules), in one instruction each (callgrind on the dragon, first hit: 897 → 841
    /// instructions a pixel). Values exist only inside `bvh_traverse_avx2` and `multires_avx2`,
    /// the only instantiations of the traversal with [`Kernel`], which run only where `detect`
    /// saw AVX2, and in `lanes8_for_tests`, which checks `detect` first: the type is private to
    /// this module.
    #[derive(Clone, Copy)]
    pub(super) struct Lanes8(__m256);

    /// Calls an AVX function on lane values.
    macro_rules! avx {
        ($e:expr) => {
            // SAFETY: `Lanes8` values exist only where the CPU has AVX2 (see `Lanes8`).
            #[allow(unsafe_code)]
            unsafe {
                $e
            }
        };
    }

    macro_rules! lanewise {
        ($trait:ident, $f:ident, $op:ident) => {
            impl std::ops::$trait for Lanes8 {
                type Output = Lanes8;
                #[inline(always)]
                fn $f(self, o: Lanes8) -> Lanes8 {
                    Lanes8(avx!($op(self.0, o.0)))
                }
            }
        };
    }
    lanewise!(Add, add, _mm256_add_ps);
    lanewise!(Sub, sub, _mm256_sub_ps);
    lanewise!(Mul, mul, _mm256_mul_ps);

    /// Lanes where a comparison held (all bits set).
    #[derive(Clone, Copy)]
    pub(super) struct Mask8(__m256);

    impl std::ops::BitAnd for Mask8 {
        type Output = Mask8;
        #[inline(always)]
        fn bitand(self, o: Mask8) -> Mask8 {
            Mask8(avx!(_mm256_and_ps(self.0, o.0)))
        }
    }

    impl Wide for Lanes8 {
        type Mask = Mask8;

        #[inline(always)]
        fn splat(x: f32) -> Self {
            Lanes8(avx!(_mm256_set1_ps(x)))
        }

        #[inline(always)]
        fn load(lanes: &Lanes) -> Self {
            Lanes8(avx!(load_lanes(lanes)))
        }

        #[inline(always)]
        fn to_array(self) -> [f32; 8] {
            avx!(store(self.0))
        }

        /// `_mm_min_ps`'s rule, as [`Lanes`]: where either lane is NaN, the second operand.
        #[inline(always)]
        fn min(self, o: Self) -> Self {
            Lanes8(avx!(_mm256_min_ps(self.0, o.0)))
        }

        #[inline(always)]
        fn max(self, o: Self) -> Self {
            Lanes8(avx!(_mm256_max_ps(self.0, o.0)))
        }

        /// The sign bit cleared, as glam's `Vec4::abs`.
        #[inline(always)]
        fn abs(self) -> Self {
            Lanes8(avx!(_mm256_andnot_ps(_mm256_set1_ps(-0.0), self.0)))
        }

        #[inline(always)]
        fn cmplt(self, o: Self) -> Mask8 {
            Mask8(avx!(_mm256_cmp_ps::<_CMP_LT_OQ>(self.0, o.0)))
        }

        #[inline(always)]
        fn cmple(self, o: Self) -> Mask8 {
            Mask8(avx!(_mm256_cmp_ps::<_CMP_LE_OQ>(self.0, o.0)))
        }

        #[inline(always)]
        fn cmpgt(self, o: Self) -> Mask8 {
            Mask8(avx!(_mm256_cmp_ps::<_CMP_GT_OQ>(self.0, o.0)))
        }

        #[inline(always)]
        fn bitmask(m: Mask8) -> u32 {
            avx!(mask(m.0))
        }
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn load_lanes(lanes: &Lanes) -> __m256 {
        // SAFETY: `Lanes` is eight consecutive floats, 32-byte aligned (`repr(C, align(32))`).
        #[allow(unsafe_code)]
        unsafe {
            _mm256_load_ps((lanes as *const Lanes).cast::<f32>())
        }
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn load(lanes: &[f32; BLOCK]) -> __m256 {
        // SAFETY: eight floats behind a reference; `loadu` needs no alignment.
        #[allow(unsafe_code)]
        unsafe {
            _mm256_loadu_ps(lanes.as_ptr())
        }
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn store(v: __m256) -> [f32; BLOCK] {
        let mut out = [0.0; BLOCK];
        // SAFETY: eight floats of `out`; `storeu` needs no alignment.
        #[allow(unsafe_code)]
        unsafe {
            _mm256_storeu_ps(out.as_mut_ptr(), v)
        };
        out
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn mask(v: __m256) -> u32 {
        _mm256_movemask_ps(v) as u32
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn splat3(v: glam::Vec3) -> [__m256; 3] {
        [_mm256_set1_ps(v.x), _mm256_set1_ps(v.y), _mm256_set1_ps(v.z)]
    }

    /// The eight centres, `origin + step·offset` lane by lane as `SplatBlock::center_lanes`
    /// computes them (a multiply, then an add: the same bits).
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn centers(block: &SplatBlock) -> [__m256; 3] {
        let step = _mm256_set1_ps(block.step);
        std::array::from_fn(|k| {
            // SAFETY: eight `u16`s (16 bytes) behind a reference; `loadu` needs no alignment.
            #[allow(unsafe_code)]
            let q = unsafe { _mm_loadu_si128(block.offset[k].as_ptr().cast()) };
            let q = _mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(q));
            _mm256_add_ps(_mm256_set1_ps(block.origin[k]), _mm256_mul_ps(q, step))
        })
    }

    /// The eight normals in units of `NORMAL_UNIT`, as the oriented-disk test scales them.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn normals(block: &SplatBlock) -> [__m256; 3] {
        std::array::from_fn(|k| {
            // SAFETY: eight `i16`s (16 bytes) behind a reference; `loadu` needs no alignment.
            #[allow(unsafe_code)]
            let q = unsafe { _mm_loadu_si128(block.normal[k].as_ptr().cast()) };
            _mm256_cvtepi32_ps(_mm256_cvtepi16_epi32(q))
        })
    }

    /// `x·y + z·w + u·v` in the scalar code's order: `(x·y + z·w) + u·v`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn dot(a: [__m256; 3], b: [__m256; 3]) -> __m256 {
        _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(a[0], b[0]), _mm256_mul_ps(a[1], b[1])), _mm256_mul_ps(a[2], b[2]))
    }

    /// `SplatBlock::oriented`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn oriented(block: &SplatBlock, ray: &Ray, t_max: f32) -> BlockHits {
        const SLACK: f32 = 1.0 / 65536.0;
        let (o, d) = (splat3(ray.origin), splat3(ray.dir));
        let (c, n) = (centers(block), normals(block));
        let zero = _mm256_setzero_ps();
        let sign = _mm256_set1_ps(-0.0);
        let dn = dot(d, n);
        let to_center = [_mm256_sub_ps(c[0], o[0]), _mm256_sub_ps(c[1], o[1]), _mm256_sub_ps(c[2], o[2])];
        let nm = dot(to_center, n);
        // (−nm, −dn) where dn < 0: negation flips the sign bit, as `-x` does.
        let back = _mm256_cmp_ps::<_CMP_LT_OQ>(dn, zero);
        let num_s = _mm256_blendv_ps(nm, _mm256_xor_ps(nm, sign), back);
        let den_a = _mm256_blendv_ps(dn, _mm256_xor_ps(dn, sign), back);
        let lo = _mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(ray.t_min), den_a), _mm256_set1_ps(1.0 - SLACK));
        let hi = _mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(t_max), den_a), _mm256_set1_ps(1.0 + SLACK));
        let in_range = _mm256_and_ps(
            _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(num_s, lo), _mm256_cmp_ps::<_CMP_LE_OQ>(num_s, hi)),
            _mm256_cmp_ps::<_CMP_GT_OQ>(den_a, zero),
        );
        let q = [
            _mm256_sub_ps(_mm256_mul_ps(d[0], nm), _mm256_mul_ps(to_center[0], dn)),
            _mm256_sub_ps(_mm256_mul_ps(d[1], nm), _mm256_mul_ps(to_center[1], dn)),
            _mm256_sub_ps(_mm256_mul_ps(d[2], nm), _mm256_mul_ps(to_center[2], dn)),
        ];
        let qq = dot(q, q);
        let r = load(&block.radius);
        let limit = _mm256_mul_ps(_mm256_mul_ps(_mm256_mul_ps(r, r), dn), dn);
        let inside = _mm256_cmp_ps::<_CMP_LT_OQ>(qq, limit);
        let mut hits = BlockHits { mask: mask(_mm256_and_ps(in_range, inside)), t: [0.0; BLOCK], dist2: [0.0; BLOCK] };
        if hits.mask == 0 {
            return hits;
        }
        let t = _mm256_div_ps(nm, dn);
        let dist2 = _mm256_div_ps(qq, _mm256_mul_ps(dn, dn));
        // Re-checked with the rounded t, so that a hit never lies outside [t_min, t_max].
        let in_range = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(t, _mm256_set1_ps(ray.t_min)),
            _mm256_cmp_ps::<_CMP_LE_OQ>(t, _mm256_set1_ps(t_max)),
        );
        hits.mask &= mask(in_range);
        (hits.t, hits.dist2) = (store(t), store(dist2));
        hits
    }

    /// `SplatBlock::ray_facing`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn ray_facing(block: &SplatBlock, ray: &Ray, t_max: f32) -> BlockHits {
        let (o, d) = (splat3(ray.origin), splat3(ray.dir));
        let c = centers(block);
        let to_center = [_mm256_sub_ps(c[0], o[0]), _mm256_sub_ps(c[1], o[1]), _mm256_sub_ps(c[2], o[2])];
        let t = dot(to_center, d);
        let q = [
            _mm256_sub_ps(to_center[0], _mm256_mul_ps(d[0], t)),
            _mm256_sub_ps(to_center[1], _mm256_mul_ps(d[1], t)),
            _mm256_sub_ps(to_center[2], _mm256_mul_ps(d[2], t)),
        ];
        let dist2 = dot(q, q);
        let r = load(&block.radius);
        let hit = _mm256_and_ps(
            _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GE_OQ>(t, _mm256_set1_ps(ray.t_min)),
                _mm256_cmp_ps::<_CMP_LE_OQ>(t, _mm256_set1_ps(t_max)),
            ),
            _mm256_cmp_ps::<_CMP_LT_OQ>(dist2, _mm256_mul_ps(r, r)),
        );
        BlockHits { mask: mask(hit), t: store(t), dist2: store(dist2) }
    }

    #[cfg(test)]
    pub(super) fn kernel_for_tests() -> Option<Kernel> {
        (super::detect() == super::Isa::Avx2).then_some(Kernel(()))
    }

    /// Every [`Wide`] operation of [`Lanes8`] on `a` and `b`, as bits (`None` without AVX2).
    #[cfg(test)]
    pub(super) fn lanes8_for_tests(a: &Lanes, b: &Lanes) -> Option<Vec<u32>> {
        kernel_for_tests().map(|_| super::tests::wide_ops::<Lanes8>(a, b))
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use rand::{RngExt, SeedableRng};

    use super::super::block::LeafKernel;
    use super::super::block::tests::{check_against_scalar, check_edges};
    use crate::accel::bvh::lanes::{Lanes, Wide, dot3};

    /// Every `Wide` operation on `a` and `b`, each result's bits in order, every NaN as one:
    /// which operand's NaN an instruction passes on (and so its sign) depends on the operand
    /// order the optimiser picks, and no test of a NaN tells them apart.
    pub(super) fn wide_ops<W: Wide>(a: &Lanes, b: &Lanes) -> Vec<u32> {
        let (x, y) = (W::load(a), W::load(b));
        let values = [x + y, x - y, x * y, x.min(y), x.max(y), x.abs(), W::splat(a[3]), dot3(&[x, y, x], &[y, y, x])];
        let masks = [x.cmplt(y), x.cmple(y), x.cmpgt(y), x.cmplt(y) & y.cmpgt(W::splat(0.0))];
        let canonical = |v: f32| if v.is_nan() { f32::NAN.to_bits() } else { v.to_bits() };
        let bits = values.into_iter().flat_map(|v| v.to_array()).map(canonical);
        bits.chain(masks.map(W::bitmask)).collect()
    }

    /// The AVX register gives the bits of the two SSE vectors, operation by operation, on
    /// random lanes and on lanes holding ±0, ±∞ and NaN.
    #[test]
    fn avx2_lanes_equal_the_sse_lanes() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(5);
        let special = [0.0, -0.0, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1.0, -1.0, f32::MIN_POSITIVE];
        let mut cases = vec![(Lanes::from_array(special), Lanes::from_array(special.map(|x| -x)))];
        cases.push((Lanes::from_array(special), Lanes::from_array(std::array::from_fn(|i| special[7 - i]))));
        for _ in 0..2_000 {
            let mut lanes = || Lanes::from_array(std::array::from_fn(|_| rng.random_range(-4.0f32..4.0)));
            cases.push((lanes(), lanes()));
        }
        for (a, b) in &cases {
            let Some(avx2) = super::avx2::lanes8_for_tests(a, b) else {
                eprintln!("no AVX2 on this CPU: the AVX2 lanes cannot run here");
                return;
            };
            assert_eq!(avx2, wide_ops::<Lanes>(a, b), "{a:?} and {b:?}");
        }
    }

    /// The AVX2 kernel gives the scalar tests' bits, on random blocks and at the edges. (Runs
    /// where the CPU has AVX2, as this machine and CI's do; the portable kernel, which the
    /// baseline runs, is tested in `block`.)
    #[test]
    fn avx2_kernel_equals_the_scalar_tests() {
        let Some(kernel) = super::avx2::kernel_for_tests() else {
            eprintln!("no AVX2 on this CPU: the AVX2 kernel cannot run here");
            return;
        };
        let (hits, misses) = check_against_scalar(|b, s, r, t| kernel.hits(b, s, r, t));
        assert!(hits > 5_000 && misses > 50_000, "{hits} hits, {misses} misses");
        check_edges(|b, s, r, t| kernel.hits(b, s, r, t));
    }
}
