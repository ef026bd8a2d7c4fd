//! The perceptual difference of two renders: NVIDIA's FLIP (Andersson et al. 2020), which
//! models how a viewer flipping between them sees their colours and edges differ.

/// Mean FLIP error of `test` against `reference`, both `width × height` sRGB8: 0 for the
/// same image, up to 1 for black against white. At FLIP's default viewing conditions (a
/// 0.7 m distance from a 3840-pixel-wide 0.7 m monitor: 67 pixels per degree).
pub fn flip_mean(reference: &[u8], test: &[u8], width: u32, height: u32) -> f64 {
    assert_eq!(reference.len(), test.len(), "flip_mean: images of different sizes");
    assert_eq!(reference.len(), width as usize * height as usize * 3, "flip_mean: not {width}x{height} RGB8");
    if reference == test {
        return 0.0;
    }
    let image = |rgb: &[u8]| nv_flip::FlipImageRgb8::with_data(width, height, rgb);
    let error = nv_flip::flip(image(reference), image(test), nv_flip::DEFAULT_PIXELS_PER_DEGREE);
    f64::from(nv_flip::FlipPool::from_image(&error).mean())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flip_grows_with_the_difference() {
        let (w, h) = (32u32, 32u32);
        let grey: Vec<u8> = vec![128; (w * h * 3) as usize];
        // A faint and a strong checker over the grey.
        let checker = |amplitude: i16| -> Vec<u8> {
            (0..w * h)
                .flat_map(|i| {
                    let sign = if (i % w / 4 + i / w / 4) % 2 == 0 { 1 } else { -1 };
                    [(128 + sign * amplitude) as u8; 3]
                })
                .collect()
        };
        let (faint, strong) = (flip_mean(&grey, &checker(8), w, h), flip_mean(&grey, &checker(100), w, h));
        assert_eq!(flip_mean(&grey, &grey, w, h), 0.0);
        assert!(0.0 < faint && faint < strong && strong <= 1.0, "faint {faint}, strong {strong}");
        let black = vec![0u8; grey.len()];
        let white = vec![255u8; grey.len()];
        assert!(flip_mean(&black, &white, w, h) > 0.9);
    }
}
