//! The instruction set the hot loops run on, chosen once per process.
//!
//! On x86-64 the BVH's traversal and leaf kernel ([`super::block`]) are compiled twice: for
//! the baseline every x86-64 CPU has (SSE2) and with AVX2 and FMA enabled, taken when the CPU
//! reports both (the kernels use no fused multiply-add; FMA comes with every AVX2 CPU). Elsewhere (aarch64, …) there is one path, for the target's own baseline.
//! `POINTRAY_ISA=baseline` forces the baseline; CI runs the oracle tests that way too.
//!
//! Both paths give the same bits: the kernels are written without fused multiply-adds, so
//! every lane rounds as the scalar code does (tested below and by the oracle tests).
//!
//! This module holds the crate's only SIMD `unsafe`: calling the AVX2 build, which is sound
//! only on a CPU that has AVX2.

use super::bvh::Bvh;
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

/// The path this process runs: the best the CPU has, unless `POINTRAY_ISA=baseline`.
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
    super::bvh::traverse::traverse(bvh, ray, visitor, stats);
}

/// `bvh::traverse` (inlined, with the leaf kernel and the visitor) compiled for AVX2: one
/// 256-bit instruction per operation of the eight-lane leaf test, VEX encodings elsewhere.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn bvh_traverse_avx2<V: SplatVisitor>(bvh: &Bvh, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
    super::bvh::traverse::traverse(bvh, ray, visitor, stats);
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::super::block::{BlockHits, SplatBlock, tests::check_against_scalar};
    use crate::math::Ray;
    use crate::splat::DiskShape;

    #[target_feature(enable = "avx2,fma")]
    fn block_hits_avx2(block: &SplatBlock, shape: DiskShape, ray: &Ray, t_max: f32) -> BlockHits {
        block.hits(shape, ray, t_max)
    }

    /// The leaf kernel compiled for AVX2 gives the scalar tests' bits. (Runs where the CPU has
    /// AVX2, as this machine and CI's do; the baseline build is tested in `block`.)
    #[test]
    fn avx2_block_equals_the_scalar_tests() {
        if super::detect() != super::Isa::Avx2 {
            eprintln!("no AVX2 on this CPU: the AVX2 kernel cannot run here");
            return;
        }
        // SAFETY: `detect` saw the CPU report AVX2 and FMA.
        #[allow(unsafe_code)]
        let (hits, misses) = check_against_scalar(|b, s, r, t| unsafe { block_hits_avx2(b, s, r, t) });
        assert!(hits > 5_000 && misses > 50_000, "{hits} hits, {misses} misses");
    }
}
