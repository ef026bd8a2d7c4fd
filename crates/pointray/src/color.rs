//! Colour: sRGB and linear light, and the 8-bit encodings both ways through tables (the
//! splats store sRGB bytes, the film encodes its radiance for PNGs). The one module that knows
//! the sRGB curve.

/// The sRGB encoding of a linear value, clamped to [0, 1].
pub fn linear_to_srgb(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

/// The linear value of an sRGB-encoded one in [0, 1].
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.040_45 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// The linear value of each sRGB byte (the splats' colours are stored as bytes).
#[inline]
pub(crate) fn srgb8_to_linear_table() -> &'static [f32; 256] {
    static TABLE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0)))
}

/// Buckets of the display range for [`Srgb8Table::byte`]'s first guess. The steps lie at least
/// 1 / (255 · 12.92) ≈ 3.0e-4 apart (the curve's steepest slope), more than a bucket's width
/// (2.4e-4), so a bucket holds at most one step.
const BUCKETS: usize = 4096;

/// The byte by the formula itself (the table's definition).
fn srgb8_by_formula(display: f32) -> u8 {
    (linear_to_srgb(display) * 255.0 + 0.5) as u8
}

pub(crate) struct Srgb8Table {
    /// `steps[k]` is the least display value whose byte is at least k (`steps[0]` = −∞), and
    /// `steps[256]` NaN, which no value reaches.
    steps: [f32; 257],
    /// The byte at the start of each bucket, `i / BUCKETS`.
    bucket_start: [u8; BUCKETS],
}

/// The steps are each found by bisection over the bit patterns of the floats in [0, 1], which
/// order like the floats, so the table reproduces the formula exactly wherever the formula is
/// monotonic.
pub(crate) fn srgb8_table() -> &'static Srgb8Table {
    static TABLE: std::sync::OnceLock<Srgb8Table> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let steps = std::array::from_fn(|k| {
            match k {
                0 => return f32::NEG_INFINITY,
                256 => return f32::NAN,
                _ => {}
            }
            let (mut lo, mut hi) = (0u32, 1f32.to_bits());
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if usize::from(srgb8_by_formula(f32::from_bits(mid))) >= k { hi = mid } else { lo = mid + 1 }
            }
            f32::from_bits(lo)
        });
        let bucket_start = std::array::from_fn(|i| {
            let start = i as f32 / BUCKETS as f32;
            (steps.partition_point(|&s: &f32| s <= start) - 1) as u8
        });
        Srgb8Table { steps, bucket_start }
    })
}

impl Srgb8Table {
    /// A display value in [0, 1] as 8-bit sRGB: the same byte as rounding
    /// [`linear_to_srgb`]` × 255`. `powf` per channel cost ~110 instructions a pixel of a 512²
    /// render, a binary search over the steps where the byte goes up ~48 (callgrind,
    /// `docs/RESULTS.md`); a first guess from the display value's bucket and one compare ~42
    /// (`Film::frame_srgb8` as a whole 86 → 80 on the dragon at 512², first hit).
    #[inline(always)]
    pub(crate) fn byte(&self, display: f32) -> u8 {
        // Display values are in [0, 1]; the clamp puts anything else into a bucket. (A cast to
        // `i32` is 3 instructions, to `usize` 15.)
        let bucket = ((display * BUCKETS as f32) as i32).clamp(0, BUCKETS as i32 - 1) as usize;
        let code = usize::from(self.bucket_start[bucket]);
        // The guess is never above the byte (the byte is monotonic) and a bucket holds one
        // step at most; past 255 the step is NaN, which no value reaches.
        (code + usize::from(display >= self.steps[code + 1])) as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip() {
        for i in 0..=100 {
            let c = i as f32 / 100.0;
            assert!((srgb_to_linear(linear_to_srgb(c)) - c).abs() < 1e-5);
        }
    }

    /// The table gives the formula's byte: at and around every step, and at a spread of
    /// display values over [0, 1] (an exhaustive run over all 1,065,353,217 floats in [0, 1]
    /// agreed too, see `docs/RESULTS.md`).
    #[test]
    fn srgb8_table_matches_the_formula() {
        let steps = &srgb8_table().steps;
        let mut checked = 0;
        let mut check = |bits: u32| {
            let d = f32::from_bits(bits);
            assert_eq!(srgb8_table().byte(d), srgb8_by_formula(d), "display {d}");
            checked += 1;
        };
        for &step in &steps[1..256] {
            (step.to_bits().saturating_sub(3)..=step.to_bits() + 3).for_each(&mut check);
        }
        // Around every bucket's start.
        for i in 0..=BUCKETS {
            let start = (i as f32 / BUCKETS as f32).to_bits();
            (start.saturating_sub(3)..=(start + 3).min(1f32.to_bits())).for_each(&mut check);
        }
        (0..=1f32.to_bits()).step_by(4099).for_each(&mut check);
        assert!(checked > 250_000);
        assert_eq!((srgb8_table().byte(0.0), srgb8_table().byte(1.0), srgb8_table().byte(0.5)), (0, 255, 188));
        // Outside [0, 1], where the last bucket's step is the NaN sentinel.
        let outside = [-1.0, f32::NEG_INFINITY, 1.5, f32::INFINITY, f32::NAN].map(|d| srgb8_table().byte(d));
        assert_eq!(outside, [0, 0, 255, 255, 0]);
    }

    /// Every float in [0, 1] (6 s in release here: `cargo test --release -- --ignored`).
    #[test]
    #[ignore]
    fn srgb8_table_matches_the_formula_everywhere() {
        for bits in 0..=1f32.to_bits() {
            let d = f32::from_bits(bits);
            assert_eq!(srgb8_table().byte(d), srgb8_by_formula(d), "display {d}");
        }
    }
}
