//! The image being rendered: linear RGB plus a per-pixel work count (pbrt's pixel stats).

/// Linear RGB radiance per pixel and arbitrary output variables, row-major, top row first.
#[derive(Clone, Debug)]
pub struct Film {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[f32; 3]>,
    /// Accelerator nodes visited per pixel, all rays of the pixel together.
    pub nodes_visited: Vec<u32>,
}

impl Film {
    pub fn new(width: u32, height: u32, background: [f32; 3]) -> Self {
        let n = width as usize * height as usize;
        Self { width, height, rgb: vec![background; n], nodes_visited: vec![0; n] }
    }

    pub fn index(&self, x: u32, y: u32) -> usize {
        y as usize * self.width as usize + x as usize
    }

    /// 8-bit sRGB, clamped: what a PNG stores.
    pub fn to_srgb8(&self) -> Vec<u8> {
        self.rgb.iter().flat_map(|p| p.map(|c| (linear_to_srgb(c) * 255.0 + 0.5) as u8)).collect()
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
}
