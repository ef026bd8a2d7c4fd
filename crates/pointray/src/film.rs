//! The image being rendered: linear RGB plus a per-pixel work count (pbrt's pixel stats),
//! over the rendered region of the frame only.

use crate::camera::Region;

/// Largest frame the command line and scene files accept: 2²⁸ pixels (16k × 16k), so that
/// films and PNG buffers fit.
pub const MAX_PIXELS: u64 = 1 << 28;

/// Linear RGB radiance per pixel of `region` and arbitrary output variables, row-major, top
/// row first.
#[derive(Clone, Debug)]
pub struct Film {
    pub region: Region,
    pub rgb: Vec<[f32; 3]>,
    /// Accelerator nodes visited per pixel, all rays of the pixel together.
    pub nodes_visited: Vec<u32>,
    /// What the camera rays' first hits were, in a film made to hold them
    /// ([`Film::with_first_hits`]): 28 bytes a pixel that a plain render neither fills nor
    /// allocates (zeroing them cost ~20 instructions a pixel, callgrind).
    pub first_hits: Option<FirstHitChannels>,
}

/// The first hits' channels, averaged over the pixel's samples (a miss counts as zero):
#[derive(Clone, Debug)]
pub struct FirstHitChannels {
    /// the unit shading normal facing the camera,
    pub normal: Vec<[f32; 3]>,
    /// the albedo (linear surface colour),
    pub albedo: Vec<[f32; 3]>,
    /// and the distance along the ray, averaged over the samples that hit (∞ if none did).
    pub depth: Vec<f32>,
}

impl Film {
    /// A film of radiance and work counts.
    pub fn new(region: Region) -> Self {
        let n = region.pixel_count() as usize;
        Self { region, rgb: vec![[0.0; 3]; n], nodes_visited: vec![0; n], first_hits: None }
    }

    /// A film that also holds the first hits' channels.
    pub fn with_first_hits(region: Region) -> Self {
        let n = region.pixel_count() as usize;
        let channels =
            FirstHitChannels { normal: vec![[0.0; 3]; n], albedo: vec![[0.0; 3]; n], depth: vec![f32::INFINITY; n] };
        Self { first_hits: Some(channels), ..Self::new(region) }
    }

    /// Index of frame pixel (`x`, `y`), which must lie in the region.
    pub fn index(&self, x: u32, y: u32) -> usize {
        (y - self.region.y0) as usize * self.region.width() as usize + (x - self.region.x0) as usize
    }

    /// The whole `width × height` frame as 8-bit sRGB (what a PNG stores), `background`
    /// (linear) outside the region, both through `tone`.
    ///
    /// The background first, then the region row by row (a test per frame pixel of whether it
    /// lay in the region, and the encoder called through a reference, cost as much as the
    /// encoding: callgrind, 80 → 42 instructions a pixel of the dragon at 512², first hit).
    pub fn frame_srgb8(&self, width: u32, height: u32, background: [f32; 3], tone: ToneMap) -> Vec<u8> {
        let srgb8 = tone.encoder();
        let mut out = background.map(&srgb8).repeat(width as usize * height as usize);
        let r = self.region;
        let row_bytes = 3 * r.width() as usize;
        if row_bytes == 0 {
            return out;
        }
        for (y, row) in (r.y0..r.y1).zip(self.rgb.chunks_exact(r.width() as usize)) {
            let start = 3 * (y as usize * width as usize + r.x0 as usize);
            for (px, rgb) in out[start..start + row_bytes].chunks_exact_mut(3).zip(row) {
                px.copy_from_slice(&rgb.map(&srgb8));
            }
        }
        out
    }
}

/// How linear radiance becomes a display value in [0, 1] before sRGB encoding: scaled by
/// 2^`exposure` (in stops), then clipped or rolled off by `curve`. EXR output stays linear.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ToneMap {
    pub exposure: f32,
    pub curve: ToneCurve,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum ToneCurve {
    /// Radiance up to 1 shown exactly, brighter clipped to white: the default, and what the
    /// known-answer tests and the experiments compare.
    Clamp,
    /// Narkowicz's (2015) fit of the ACES filmic curve, per channel, on 0.6 × the radiance: a
    /// gentle toe and a shoulder that rolls highlights off instead of clipping them (radiance
    /// 1 shows as 0.67, 4 as 0.93, and white is reached near 12), desaturating the brightest
    /// as film does. Mid-tones come out a little darker than clipped: raise the exposure.
    Filmic,
}

impl ToneMap {
    /// Exactly the radiance, clipped at 1.
    pub const CLAMP: ToneMap = ToneMap { exposure: 0.0, curve: ToneCurve::Clamp };
    /// Stops either way that an exposure may take (2^32 spans any radiance worth showing).
    pub const MAX_EXPOSURE: f32 = 32.0;

    /// One linear channel as the 8-bit sRGB a PNG stores.
    pub fn srgb8(&self, linear: f32) -> u8 {
        self.encoder()(linear)
    }

    /// [`Self::srgb8`] for many channels: the exposure's scale computed once.
    pub fn encoder(&self) -> impl Fn(f32) -> u8 + use<> {
        let (scale, curve, table) = (self.exposure.exp2(), self.curve, srgb8_table());
        move |linear| table.byte(curve.apply(linear * scale))
    }

    /// The display value in [0, 1] of one linear channel.
    pub fn display(&self, linear: f32) -> f32 {
        self.curve.apply(linear * self.exposure.exp2())
    }
}

impl ToneCurve {
    /// The display value in [0, 1] of an exposed linear value (NaN shows as black).
    #[inline]
    fn apply(self, exposed: f32) -> f32 {
        let x = exposed.max(0.0);
        match self {
            ToneCurve::Clamp => x.min(1.0),
            ToneCurve::Filmic => {
                let x = 0.6 * x;
                (x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14)).min(1.0)
            }
        }
    }
}

/// Buckets of the display range for [`Srgb8Table::byte`]'s first guess. The steps lie at least
/// 1 / (255 · 12.92) ≈ 3.0e-4 apart (the curve's steepest slope), more than a bucket's width
/// (2.4e-4), so a bucket holds at most one step.
const BUCKETS: usize = 4096;

/// The byte by the formula itself (the table's definition).
fn srgb8_by_formula(display: f32) -> u8 {
    (linear_to_srgb(display) * 255.0 + 0.5) as u8
}

struct Srgb8Table {
    /// `steps[k]` is the least display value whose byte is at least k (`steps[0]` = −∞), and
    /// `steps[256]` NaN, which no value reaches.
    steps: [f32; 257],
    /// The byte at the start of each bucket, `i / BUCKETS`.
    bucket_start: [u8; BUCKETS],
}

/// The steps are each found by bisection over the bit patterns of the floats in [0, 1], which
/// order like the floats, so the table reproduces the formula exactly wherever the formula is
/// monotonic.
fn srgb8_table() -> &'static Srgb8Table {
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
    fn byte(&self, display: f32) -> u8 {
        // Display values are in [0, 1]; the clamp puts anything else into a bucket. (A cast to
        // `i32` is 3 instructions, to `usize` 15.)
        let bucket = ((display * BUCKETS as f32) as i32).clamp(0, BUCKETS as i32 - 1) as usize;
        let code = usize::from(self.bucket_start[bucket]);
        // The guess is never above the byte (the byte is monotonic) and a bucket holds one
        // step at most; past 255 the step is NaN, which no value reaches.
        (code + usize::from(display >= self.steps[code + 1])) as u8
    }
}

impl Default for ToneMap {
    fn default() -> Self {
        Self::CLAMP
    }
}

pub fn linear_to_srgb(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.040_45 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
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

    #[test]
    fn frame_places_the_region() {
        let mut f = Film::new(Region { x0: 1, y0: 2, x1: 3, y1: 3 });
        let i = f.index(2, 2);
        f.rgb[i] = [1.0, 1.0, 1.0];
        let px = f.frame_srgb8(4, 4, [0.0; 3], ToneMap::CLAMP);
        let at = |x: usize, y: usize| px[(y * 4 + x) * 3];
        assert_eq!((at(2, 2), at(1, 2), at(0, 0), at(3, 3)), (255, 0, 0, 0));
    }

    #[test]
    fn tone_maps_keep_order_and_range() {
        let filmic = ToneMap { exposure: 0.0, curve: ToneCurve::Filmic };
        let values: Vec<f32> = (0..=400).map(|i| i as f32 * 0.05).collect();
        for tone in [ToneMap::CLAMP, filmic, ToneMap { exposure: 1.0, curve: ToneCurve::Filmic }] {
            let shown: Vec<f32> = values.iter().map(|&v| tone.display(v)).collect();
            assert!(shown.iter().all(|s| (0.0..=1.0).contains(s)), "{tone:?}");
            assert!(shown.windows(2).all(|w| w[0] <= w[1]), "{tone:?} is not monotonic");
        }
        // Clamp shows radiance up to 1 exactly; one stop of exposure doubles it.
        assert_eq!((ToneMap::CLAMP.display(0.37), ToneMap::CLAMP.display(3.0)), (0.37, 1.0));
        assert_eq!(ToneMap { exposure: 1.0, curve: ToneCurve::Clamp }.display(0.25), 0.5);
        // Filmic keeps highlights apart that clamping merges, and black stays black.
        assert_eq!(filmic.display(0.0), 0.0);
        assert!(filmic.display(2.0) < filmic.display(4.0) && filmic.display(4.0) < 0.95);
        assert!((filmic.display(1.0) - 0.673).abs() < 1e-3, "{}", filmic.display(1.0));
    }
}
