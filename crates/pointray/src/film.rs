//! The image being rendered: linear RGB plus a per-pixel work count (pbrt's pixel stats),
//! over the rendered region of the frame only.

use crate::camera::Region;

/// Linear RGB radiance per pixel of `region` and arbitrary output variables, row-major, top
/// row first.
#[derive(Clone, Debug)]
pub struct Film {
    pub region: Region,
    pub rgb: Vec<[f32; 3]>,
    /// Accelerator nodes visited per pixel, all rays of the pixel together.
    pub nodes_visited: Vec<u32>,
    /// The camera rays' first hits, averaged over the pixel's samples (a miss counts as zero):
    /// the unit shading normal facing the camera,
    pub normal: Vec<[f32; 3]>,
    /// the albedo (linear surface colour),
    pub albedo: Vec<[f32; 3]>,
    /// and the distance along the ray, averaged over the samples that hit (∞ if none did).
    pub depth: Vec<f32>,
}

impl Film {
    pub fn new(region: Region) -> Self {
        let n = region.pixel_count() as usize;
        Self {
            region,
            rgb: vec![[0.0; 3]; n],
            nodes_visited: vec![0; n],
            normal: vec![[0.0; 3]; n],
            albedo: vec![[0.0; 3]; n],
            depth: vec![f32::INFINITY; n],
        }
    }

    /// Index of frame pixel (`x`, `y`), which must lie in the region.
    pub fn index(&self, x: u32, y: u32) -> usize {
        (y - self.region.y0) as usize * self.region.width() as usize + (x - self.region.x0) as usize
    }

    /// The whole `width × height` frame as 8-bit sRGB (what a PNG stores), `background`
    /// (linear) outside the region.
    pub fn frame_srgb8(&self, width: u32, height: u32, background: [f32; 3]) -> Vec<u8> {
        let encode = |c: [f32; 3]| c.map(|v| (linear_to_srgb(v) * 255.0 + 0.5) as u8);
        let bg = encode(background);
        let mut out = Vec::with_capacity(width as usize * height as usize * 3);
        for y in 0..height {
            for x in 0..width {
                let inside =
                    (self.region.x0..self.region.x1).contains(&x) && (self.region.y0..self.region.y1).contains(&y);
                out.extend_from_slice(&if inside { encode(self.rgb[self.index(x, y)]) } else { bg });
            }
        }
        out
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

    #[test]
    fn frame_places_the_region() {
        let mut f = Film::new(Region { x0: 1, y0: 2, x1: 3, y1: 3 });
        let i = f.index(2, 2);
        f.rgb[i] = [1.0, 1.0, 1.0];
        let px = f.frame_srgb8(4, 4, [0.0; 3]);
        let at = |x: usize, y: usize| px[(y * 4 + x) * 3];
        assert_eq!((at(2, 2), at(1, 2), at(0, 0), at(3, 3)), (255, 0, 0, 0));
    }
}
