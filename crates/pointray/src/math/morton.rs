//! 63-bit Morton (Z-order) codes, used to sort points so that neighbours in space are
//! neighbours in memory (kNN and BVH builds run markedly faster on sorted input).

use glam::Vec3;

use super::Aabb;

/// Spreads the low 21 bits of `v` so that there are two zero bits between each.
fn spread_bits(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// Morton code of `p` quantised to 2²¹ cells per axis of `bounds`.
pub fn encode(p: Vec3, bounds: &Aabb) -> u64 {
    const CELLS: f32 = (1u32 << 21) as f32;
    let e = bounds.extent().max(Vec3::splat(f32::MIN_POSITIVE));
    let q = ((p - bounds.min) / e * CELLS).clamp(Vec3::ZERO, Vec3::splat(CELLS - 1.0));
    spread_bits(q.x as u64) | spread_bits(q.y as u64) << 1 | spread_bits(q.z as u64) << 2
}

/// The permutation that sorts `points` by Morton code (ties by index, so it is deterministic).
pub fn sort_order(points: &[Vec3]) -> Vec<u32> {
    use rayon::prelude::*;
    let bounds = Aabb::from_points(points.iter().copied());
    let mut keyed: Vec<(u64, u32)> =
        points.par_iter().enumerate().map(|(i, p)| (encode(*p, &bounds), i as u32)).collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_interleaves() {
        assert_eq!(spread_bits(0b111), 0b1001001);
        assert_eq!(spread_bits(0x1f_ffff).count_ones(), 21);
    }

    #[test]
    fn corners_order() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        assert_eq!(encode(Vec3::ZERO, &b), 0);
        assert!(encode(Vec3::new(1.0, 0.0, 0.0), &b) < encode(Vec3::new(0.0, 1.0, 0.0), &b));
        assert!(encode(Vec3::new(0.0, 1.0, 0.0), &b) < encode(Vec3::new(0.0, 0.0, 1.0), &b));
    }
}
