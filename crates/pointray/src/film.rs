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
    /// ([`Film::with_first_hits`]): 32 bytes a pixel that a plain render neither fills nor
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
    /// the distance along the ray, averaged over the samples that hit (∞ if none did),
    pub depth: Vec<f32>,
    /// and the coverage: the fraction of the samples that hit (a PNG's or EXR's alpha).
    pub coverage: Vec<f32>,
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
        let channels = FirstHitChannels {
            normal: vec![[0.0; 3]; n],
            albedo: vec![[0.0; 3]; n],
            depth: vec![f32::INFINITY; n],
            coverage: vec![0.0; n],
        };
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
            // Channel by channel: `rgb.map(&srgb8)` went out of line in some builds (`try_map`,
            // +5 instructions a pixel, callgrind).
            for (px, rgb) in out[start..start + row_bytes].chunks_exact_mut(3).zip(row) {
                for (byte, &linear) in px.iter_mut().zip(rgb) {
                    *byte = srgb8(linear);
                }
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

    /// One linear channel as the 16-bit sRGB of a 16-bit PNG, for many channels.
    pub fn encoder16(&self) -> impl Fn(f32) -> u16 + use<> {
        let (scale, curve) = (self.exposure.exp2(), self.curve);
        move |linear| (crate::color::linear_to_srgb(curve.apply(linear * scale)) * 65535.0 + 0.5) as u16
    }

    /// [`Self::srgb8`] for many channels: the exposure's scale computed once.
    pub fn encoder(&self) -> impl Fn(f32) -> u8 + use<> {
        let (scale, curve, table) = (self.exposure.exp2(), self.curve, crate::color::srgb8_table());
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

impl Default for ToneMap {
    fn default() -> Self {
        Self::CLAMP
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
