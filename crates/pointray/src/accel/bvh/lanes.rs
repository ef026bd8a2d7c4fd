//! Eight `f32` lanes, one per child of a node: the BVH's node tests, written once for all
//! eight children.
//!
//! Stored as two SSE vectors (glam's `Vec4`) side by side, and computed so on the baseline
//! x86-64 build and other targets; the AVX2 build (`accel::isa`) loads the same eight floats
//! into one register. Through [`Wide`], the traversal is written once for both, and both give
//! the same bits. Comparisons give a [`Mask`], whose [`Wide::bitmask`] has bit i for lane i.
//! Minimum and maximum are glam's, on x86-64 SSE's: where either lane is NaN, the second
//! operand.

use std::ops::{Add, BitAnd, Index, Mul, Sub};

use glam::{BVec4A, Vec4};

/// Lanes per value.
pub(crate) const LANES: usize = 8;

/// As stored in the nodes: eight consecutive floats, 32-byte aligned (what an AVX load takes).
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(32))]
pub(crate) struct Lanes {
    lo: Vec4,
    hi: Vec4,
}

/// The lanes where a comparison held.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Mask {
    lo: BVec4A,
    hi: BVec4A,
}

impl Lanes {
    pub(crate) const ZERO: Lanes = Lanes::splat(0.0);

    #[inline(always)]
    pub(crate) const fn splat(x: f32) -> Self {
        Self { lo: Vec4::splat(x), hi: Vec4::splat(x) }
    }

    #[inline(always)]
    pub(crate) fn from_array(a: [f32; LANES]) -> Self {
        Self { lo: Vec4::new(a[0], a[1], a[2], a[3]), hi: Vec4::new(a[4], a[5], a[6], a[7]) }
    }
}

impl BitAnd for Mask {
    type Output = Mask;
    #[inline(always)]
    fn bitand(self, o: Mask) -> Mask {
        Mask { lo: self.lo & o.lo, hi: self.hi & o.hi }
    }
}

macro_rules! lanewise {
    ($trait:ident, $f:ident) => {
        impl $trait for Lanes {
            type Output = Lanes;
            #[inline(always)]
            fn $f(self, o: Lanes) -> Lanes {
                Lanes { lo: self.lo.$f(o.lo), hi: self.hi.$f(o.hi) }
            }
        }
    };
}
lanewise!(Add, add);
lanewise!(Sub, sub);
lanewise!(Mul, mul);

/// `Wide` methods of two operands, glam's own on each half.
macro_rules! halves {
    ($($f:ident -> $out:ident),*) => {$(
        #[inline(always)]
        fn $f(self, o: Self) -> $out {
            $out { lo: self.lo.$f(o.lo), hi: self.hi.$f(o.hi) }
        }
    )*};
}

impl Index<usize> for Lanes {
    type Output = f32;
    fn index(&self, i: usize) -> &f32 {
        if i < 4 { &self.lo[i] } else { &self.hi[i - 4] }
    }
}

/// Eight lanes as an instruction set computes them: [`Lanes`] itself, two SSE vectors, or one
/// AVX register (`accel::isa`), loaded from the `Lanes` a node stores. Every implementation
/// runs each operation lane by lane with the same rounding and the same NaN rules (SSE's
/// minimum and maximum), so all give the same bits.
pub(crate) trait Wide: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> {
    type Mask: Copy + BitAnd<Output = Self::Mask>;
    fn splat(x: f32) -> Self;
    fn load(lanes: &Lanes) -> Self;
    fn to_array(self) -> [f32; LANES];
    fn min(self, o: Self) -> Self;
    fn max(self, o: Self) -> Self;
    fn abs(self) -> Self;
    fn cmplt(self, o: Self) -> Self::Mask;
    fn cmple(self, o: Self) -> Self::Mask;
    fn cmpgt(self, o: Self) -> Self::Mask;
    /// Bit i set where lane i of `mask` held.
    fn bitmask(mask: Self::Mask) -> u32;
}

impl Wide for Lanes {
    type Mask = Mask;

    #[inline(always)]
    fn splat(x: f32) -> Self {
        Lanes::splat(x)
    }

    #[inline(always)]
    fn load(lanes: &Lanes) -> Self {
        *lanes
    }

    #[inline(always)]
    fn to_array(self) -> [f32; LANES] {
        let (lo, hi) = (self.lo.to_array(), self.hi.to_array());
        [lo[0], lo[1], lo[2], lo[3], hi[0], hi[1], hi[2], hi[3]]
    }

    #[inline(always)]
    fn abs(self) -> Self {
        Self { lo: self.lo.abs(), hi: self.hi.abs() }
    }

    halves!(min -> Lanes, max -> Lanes, cmplt -> Mask, cmple -> Mask, cmpgt -> Mask);

    #[inline(always)]
    fn bitmask(mask: Mask) -> u32 {
        mask.lo.bitmask() | mask.hi.bitmask() << 4
    }
}

/// `a·b` for three axes of lanes, in the scalar code's order: `(x·x' + y·y') + z·z'`.
#[inline(always)]
pub(crate) fn dot3<W: Wide>(a: &[W; 3], b: &[W; 3]) -> W {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lanes_keep_their_places() {
        let a = Lanes::from_array(std::array::from_fn(|i| i as f32));
        let b = Lanes::splat(3.5);
        assert_eq!(a.to_array(), [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
        assert_eq!((a[2], a[6]), (2.0, 6.0));
        assert_eq!(Lanes::bitmask(a.cmplt(b)), 0b0000_1111);
        assert_eq!(Lanes::bitmask(a.cmpgt(b)), 0b1111_0000);
        assert_eq!(Lanes::bitmask(a.cmple(Lanes::splat(5.0)) & a.cmpgt(Lanes::splat(1.0))), 0b0011_1100);
        assert_eq!((a - b).abs().min(Lanes::splat(1.0)).max(Lanes::ZERO).to_array()[3], 0.5);
        assert_eq!((a * a + a).to_array()[7], 56.0);
        // SSE's minimum: the second operand where either is NaN.
        let nan = Lanes::splat(f32::NAN);
        assert_eq!(nan.min(Lanes::splat(1.0)).to_array(), [1.0; 8]);
        assert!(Lanes::splat(1.0).max(nan).to_array().iter().all(|x| x.is_nan()));
    }
}
