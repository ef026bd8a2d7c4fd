//! Image metrics: how far two renders are apart, their isolated dark speckles, and per-pixel
//! counts as a colour image.
//!
//! Both work on tightly packed sRGB8 (`[r, g, b, r, g, b, …]`), the format `Film::frame_srgb8`
//! produces and PNGs store; comparing there measures what a viewer of the files would see.

/// How two images of the same size differ. Channel values are compared as stored (sRGB8).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ImageDiff {
    /// Peak signal-to-noise ratio, 10·log10(255² / MSE) over all channel values; `None` when the
    /// images are identical (the ratio is infinite, which JSON cannot hold).
    pub psnr_db: Option<f64>,
    /// Root mean squared difference over all channel values, on a 0..1 scale.
    pub rmse: f64,
    /// The largest difference of any one channel value.
    pub max_abs_diff: u8,
    /// Pixels in which at least one channel differs.
    pub differing_pixels: usize,
    pub pixels: usize,
}

/// Compares two RGB8 images pixel by pixel.
///
/// # Panics
///
/// If the lengths differ or are not a multiple of 3.
pub fn compare_rgb8(a: &[u8], b: &[u8]) -> ImageDiff {
    assert_eq!(a.len(), b.len(), "compare_rgb8: images of {} and {} bytes", a.len(), b.len());
    assert!(a.len().is_multiple_of(3), "compare_rgb8: {} bytes is not a whole number of RGB pixels", a.len());
    let mut squared_sum = 0u64;
    let mut max_abs_diff = 0u8;
    let mut differing_pixels = 0;
    for (p, q) in a.chunks_exact(3).zip(b.chunks_exact(3)) {
        let mut differs = false;
        for (&x, &y) in p.iter().zip(q) {
            let d = x.abs_diff(y);
            squared_sum += u64::from(d) * u64::from(d);
            max_abs_diff = max_abs_diff.max(d);
            differs |= d != 0;
        }
        differing_pixels += usize::from(differs);
    }
    // Empty images count as identical, which also keeps 0/0 out of the MSE.
    let mse = if a.is_empty() { 0.0 } else { squared_sum as f64 / a.len() as f64 };
    ImageDiff {
        psnr_db: (mse > 0.0).then(|| 10.0 * (255.0f64 * 255.0 / mse).log10()),
        rmse: mse.sqrt() / 255.0,
        max_abs_diff,
        differing_pixels,
        pixels: a.len() / 3,
    }
}

/// How much darker than each of its four neighbours a pixel must be, in levels of luma (sRGB8),
/// to count as a speckle: a lone dark dot a viewer notices on a lit surface.
pub const SPECKLE_DROP: u8 = 60;

/// Isolated dark speckles of a `width`-wide RGB8 image: the indices of the pixels, row by row,
/// that are at least `drop` levels of luma darker than each of their four neighbours, the pixel
/// and all four in the `foreground` (one flag a pixel: where the render hit a surface). Edge
/// pixels have no four neighbours and never count.
///
/// # Panics
///
/// If `rgb` and `foreground` disagree on the pixel count, or it is not a whole number of rows.
pub fn dark_speckles(rgb: &[u8], width: usize, foreground: &[bool], drop: u8) -> Vec<usize> {
    let pixels = foreground.len();
    assert_eq!(rgb.len(), pixels * 3, "dark_speckles: {} bytes for {pixels} pixels", rgb.len());
    assert!(width > 0 && pixels.is_multiple_of(width), "dark_speckles: {pixels} pixels in rows of {width}");
    let height = pixels / width;
    let luma: Vec<i32> = rgb.chunks_exact(3).map(luma).collect();
    let mut found = Vec::new();
    for y in 1..height.saturating_sub(1) {
        for x in 1..width - 1 {
            let i = y * width + x;
            let around = [i - 1, i + 1, i - width, i + width];
            let lone = foreground[i] && around.iter().all(|&j| foreground[j] && luma[j] - luma[i] >= i32::from(drop));
            if lone {
                found.push(i);
            }
        }
    }
    found
}

/// The share of a speckle's darkness in `first` that `second` shows at the same pixel `index`
/// (of a `width`-wide RGB8 image, not on its edge): how much darker than the mean of its four
/// neighbours the pixel is in `second`, over the same in `first`, in linear luminance. With
/// `second` a render of many rays a pixel of the same view, about the share of the pixel that
/// is dark: near 0 where it shows no trace of the dot, below 0 where the pixel is brighter than
/// around it, 1 where the whole pixel is as dark; 0 where the dot of `first` is no darker in
/// linear luminance than around it (a saturated colour among greys can be darker in luma
/// only). A dot that one ray of a pixel meets and others do not is the one-ray image's sampling
/// of something under a pixel wide (a sliver of shadow, a crack); one that no ray of the many
/// meets is the image's own. See [`SPECKLE_TRACE`].
///
/// # Panics
///
/// If the images' lengths differ or `index` is not an inner pixel of rows of `width`.
pub fn darkness_share(first: &[u8], second: &[u8], width: usize, index: usize) -> f64 {
    assert_eq!(first.len(), second.len(), "darkness_share: images of {} and {} bytes", first.len(), second.len());
    let (x, y) = (index % width.max(1), index / width.max(1));
    let rows = first.len() / 3 / width.max(1);
    assert!(x > 0 && x + 1 < width && y > 0 && y + 1 < rows, "darkness_share: pixel {index} is on the edge or outside");
    let luminance = |rgb: &[u8], i: usize| {
        let table = crate::color::srgb8_to_linear_table();
        let p = &rgb[i * 3..i * 3 + 3];
        0.2126 * f64::from(table[p[0] as usize])
            + 0.7152 * f64::from(table[p[1] as usize])
            + 0.0722 * f64::from(table[p[2] as usize])
    };
    let depth = |rgb: &[u8]| {
        let around = [index - 1, index + 1, index - width, index + width];
        around.iter().map(|&j| luminance(rgb, j)).sum::<f64>() / 4.0 - luminance(rgb, index)
    };
    let dot = depth(first);
    if dot > 0.0 { depth(second) / dot } else { 0.0 }
}

/// Below this [`darkness_share`] a 16-ray render shows no trace of a speckle: half of what one
/// of its rays meeting the dot would show (for another number of rays, another share).
pub const SPECKLE_TRACE: f64 = 1.0 / 32.0;

/// Rec. 709 luma of an sRGB8 pixel, 0–255 (rounded).
fn luma(p: &[u8]) -> i32 {
    (2126 * i32::from(p[0]) + 7152 * i32::from(p[1]) + 722 * i32::from(p[2]) + 5000) / 10_000
}

/// Control points of the heat map at evenly spaced positions, sRGB8: black through purple, red
/// and orange to pale yellow, in the manner of matplotlib's "inferno". Their relative luminance
/// rises strictly from point to point, so darker always means a smaller count, also in grey print.
const HEAT_POINTS: [[u8; 3]; 9] = [
    [0, 0, 0],
    [31, 12, 72],
    [85, 15, 109],
    [136, 34, 106],
    [186, 54, 85],
    [227, 89, 51],
    [249, 140, 10],
    [249, 201, 50],
    [252, 255, 164],
];

/// Entries of the quantised map. Interpolating every count directly would let a falling channel
/// (blue, past purple) round down one step before a rising one rounds up, a tiny dip in
/// luminance; 256 levels, checked monotone by the tests, avoid that and are finer than the eye.
const HEAT_LEVELS: usize = 256;

/// Colours per-pixel counts (for example `Film::nodes_visited`) as RGB8, 3 bytes per value: 0 is
/// black, `scale_max` and above the palest yellow, linear in between (quantised to 256 levels).
/// With `scale_max == 0` everything is black.
pub fn heat_map_rgb8(values: &[u32], scale_max: u32) -> Vec<u8> {
    if scale_max == 0 {
        return vec![0; values.len() * 3];
    }
    let table = heat_table();
    let max = u64::from(scale_max);
    let last = HEAT_LEVELS as u64 - 1;
    values
        .iter()
        .flat_map(|&v| {
            // Rounded to the nearest level, in integers so the mapping is exact and monotone.
            let level = (u64::from(v).min(max) * last + max / 2) / max;
            table[level as usize]
        })
        .collect()
}

fn heat_table() -> [[u8; 3]; HEAT_LEVELS] {
    let segments = (HEAT_POINTS.len() - 1) as f64;
    std::array::from_fn(|level| {
        let x = level as f64 / (HEAT_LEVELS - 1) as f64 * segments;
        let i = (x as usize).min(HEAT_POINTS.len() - 2);
        let f = x - i as f64;
        let (lo, hi) = (HEAT_POINTS[i], HEAT_POINTS[i + 1]);
        std::array::from_fn(|c| (f64::from(lo[c]) + (f64::from(hi[c]) - f64::from(lo[c])) * f).round() as u8)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dot at the centre of a 3 × 3 patch, and the second image's share of it: none on a flat
    /// patch, all of it for the same image, a quarter where a quarter of the pixel is as dark (in
    /// linear light, to the rounding of the byte), below none where the pixel is brighter; and
    /// none for a dot darker in luma only.
    #[test]
    fn the_darkness_share_is_the_dark_part_of_the_pixel() {
        let patch = |centre: u8| {
            let mut rgb = vec![200u8; 9 * 3];
            rgb[4 * 3..][..3].fill(centre);
            rgb
        };
        let dot = patch(40);
        let lin = |v: u8| crate::color::srgb_to_linear(f32::from(v) / 255.0);
        let quarter = (crate::color::linear_to_srgb(0.75 * lin(200) + 0.25 * lin(40)) * 255.0).round() as u8;
        assert_eq!(darkness_share(&dot, &patch(200), 3, 4), 0.0);
        assert_eq!(darkness_share(&dot, &dot, 3, 4), 1.0);
        assert!((darkness_share(&dot, &patch(quarter), 3, 4) - 0.25).abs() < 0.01);
        assert!(darkness_share(&dot, &patch(220), 3, 4) < 0.0);
        // Pure red among greys of 120: 66 levels of luma darker, brighter in linear light.
        let mut red = vec![120u8; 9 * 3];
        red[4 * 3..][..3].copy_from_slice(&[255, 0, 0]);
        assert_eq!(darkness_share(&red, &patch(200), 3, 4), 0.0);
    }

    /// A lit 5×5 patch with one dark pixel in the middle, one dark pixel beside the background,
    /// and a dark pair (not isolated): only the middle one is a speckle.
    #[test]
    fn a_lone_dark_pixel_is_a_speckle_and_others_are_not() {
        let (w, h) = (7, 6);
        let mut rgb = vec![200u8; w * h * 3];
        let mut fg = vec![true; w * h];
        (0..h).for_each(|y| fg[y * w + 6] = false); // the right column is background
        let set = |rgb: &mut Vec<u8>, x: usize, y: usize, v: u8| rgb[(y * w + x) * 3..][..3].fill(v);
        set(&mut rgb, 2, 2, 100); // lone, 100 levels darker
        set(&mut rgb, 5, 2, 0); // beside the background
        set(&mut rgb, 2, 4, 50); // a pair
        set(&mut rgb, 3, 4, 50);
        set(&mut rgb, 4, 1, 150); // only 50 levels darker
        assert_eq!(dark_speckles(&rgb, w, &fg, SPECKLE_DROP), vec![2 * w + 2]);
        // One neighbour only 59 levels brighter: no speckle.
        set(&mut rgb, 2, 1, 159);
        assert!(dark_speckles(&rgb, w, &fg, SPECKLE_DROP).is_empty());
    }

    #[test]
    fn identical_images_have_no_psnr_and_no_differences() {
        let image: Vec<u8> = (0..300).map(|i| (i * 7 % 256) as u8).collect();
        let diff = compare_rgb8(&image, &image);
        assert_eq!(diff, ImageDiff { psnr_db: None, rmse: 0.0, max_abs_diff: 0, differing_pixels: 0, pixels: 100 });
        assert_eq!(compare_rgb8(&[], &[]).psnr_db, None);
    }

    #[test]
    fn known_mse_gives_the_exact_psnr() {
        let a = vec![100u8; 30];
        // Every channel off by one: MSE 1, PSNR = 20·log10(255) = 48.1308… dB.
        let b = vec![101u8; 30];
        let diff = compare_rgb8(&a, &b);
        let psnr = diff.psnr_db.unwrap();
        assert!((psnr - 20.0 * 255f64.log10()).abs() < 1e-12 && (psnr - 48.1308).abs() < 1e-4, "{psnr}");
        assert_eq!((diff.rmse, diff.max_abs_diff, diff.differing_pixels, diff.pixels), (1.0 / 255.0, 1, 10, 10));

        // One channel of one pixel off by 30 in 4 pixels: MSE 900/12 = 75.
        let mut c = a[..12].to_vec();
        c[4] = 130;
        let diff = compare_rgb8(&a[..12], &c);
        assert!((diff.psnr_db.unwrap() - 10.0 * (65025.0f64 / 75.0).log10()).abs() < 1e-12);
        assert!((diff.rmse - 75f64.sqrt() / 255.0).abs() < 1e-15);
        assert_eq!((diff.max_abs_diff, diff.differing_pixels, diff.pixels), (30, 1, 4));
    }

    #[test]
    #[should_panic(expected = "images of 6 and 3 bytes")]
    fn different_lengths_panic() {
        compare_rgb8(&[0; 6], &[0; 3]);
    }

    /// Relative luminance of an sRGB8 colour (Rec. 709 weights on linear values).
    fn luminance(c: &[u8]) -> f64 {
        let linear = |v: u8| {
            let s = f64::from(v) / 255.0;
            if s <= 0.04045 { s / 12.92 } else { ((s + 0.055) / 1.055).powf(2.4) }
        };
        0.2126 * linear(c[0]) + 0.7152 * linear(c[1]) + 0.0722 * linear(c[2])
    }

    #[test]
    fn heat_map_is_monotone_in_luminance_and_saturates() {
        for scale_max in [1u32, 7, 255, 1000, 4096, 65_535] {
            let values: Vec<u32> = (0..=scale_max).collect();
            let rgb = heat_map_rgb8(&values, scale_max);
            assert_eq!(rgb.len(), values.len() * 3);
            assert_eq!(&rgb[..3], &[0, 0, 0], "0 is black");
            let lum: Vec<f64> = rgb.chunks_exact(3).map(luminance).collect();
            for (v, pair) in lum.windows(2).enumerate() {
                assert!(pair[0] <= pair[1], "scale {scale_max}: luminance falls from {v} to {}", v + 1);
            }
            let top = &rgb[rgb.len() - 3..];
            assert_eq!(top, &HEAT_POINTS[HEAT_POINTS.len() - 1], "scale {scale_max}");
            let above = heat_map_rgb8(&[scale_max + 1, u32::MAX], scale_max);
            assert_eq!(above, [top, top].concat(), "values above the scale saturate");
        }
        // The full table rises strictly, so no two levels look alike.
        let table = heat_table();
        assert!(table.windows(2).all(|w| luminance(&w[0]) < luminance(&w[1])));
        assert_eq!(heat_map_rgb8(&[0, 5, u32::MAX], 0), vec![0; 9]);
        assert!(heat_map_rgb8(&[], 10).is_empty());
    }
}
