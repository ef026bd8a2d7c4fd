//! Image-based lighting: an equirectangular (latitude–longitude) environment map, as HDR
//! panoramas are stored, with what the integrators need of it.
//!
//! * [`EnvMap::radiance`]: the map filtered bilinearly between texel centres (nearest texels
//!   showed as blocks behind a model: a 512-texel panorama's texel is 0.7°, a pixel at 60°
//!   and 1024² is 0.06°).
//! * [`EnvMap::sample`] and [`EnvMap::pdf`]: directions drawn in proportion to the texels'
//!   luminance times the solid angle they cover (a marginal distribution over rows, then a
//!   conditional one over the row's columns, as pbrt does), for the path tracer's light
//!   samples, weighed against its bounced rays by multiple importance sampling.
//! * [`EnvMap::irradiance`]: the irradiance on a surface of a given normal with nothing in the
//!   way, from the map's first nine spherical harmonics (Ramamoorthi & Hanrahan 2001): the
//!   ambient term of Whitted's Phong under a map, smooth and noise-free.
//!
//! The map lies in a frame ([`EnvFrame`]): row 0 looks straight up, the centre column along
//! the frame's forward axis, columns running clockwise seen from above (as the panorama
//! appears from inside it, unmirrored).

use std::f32::consts::{PI, TAU};

use glam::Vec3;

/// An equirectangular map of linear RGB radiance, ready to be sampled.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvMap {
    width: usize,
    height: usize,
    /// Row by row from the top (straight up).
    texels: Vec<[f32; 3]>,
    /// The rows' cumulative weights, normalised: `rows[i]` is the share of rows before row i
    /// (`height + 1` entries, the last 1).
    rows: Vec<f32>,
    /// Per row, its columns' cumulative weights, normalised as `rows` (`width + 1` each).
    columns: Vec<f32>,
    /// The sum of the texels' weights: 0 for a black map, which draws no samples.
    total: f64,
    /// Irradiance coefficients: the nine spherical-harmonic projections of the radiance
    /// (frame coordinates), each an RGB triple.
    harmonics: [Vec3; 9],
    /// The mean radiance, each texel weighted by its solid angle.
    mean: [f32; 3],
}

/// Reports say which map by its size: the texels are no setting.
impl serde::Serialize for EnvMap {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("EnvMap", 2)?;
        st.serialize_field("width", &self.width)?;
        st.serialize_field("height", &self.height)?;
        st.end()
    }
}

/// Why pixels cannot make a map.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EnvMapError {
    #[error("an environment map needs at least 2 × 1 pixels, not {0} × {1}")]
    TooSmall(usize, usize),
    #[error("{pixels} pixels for a {width} × {height} map")]
    PixelCount { pixels: usize, width: usize, height: usize },
    #[error("pixel ({x}, {y}) is {value:?}: radiance must be finite and not negative")]
    BadPixel { x: usize, y: usize, value: [f32; 3] },
}

/// Where a map lies in the world: its up axis and the direction its centre column faces.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct EnvFrame {
    pub up: Vec3,
    pub forward: Vec3,
    /// `up × forward`: where the column a quarter turn left of the centre looks.
    pub left: Vec3,
}

impl EnvFrame {
    /// `up` (normalised), with the centre column `rotation` degrees anticlockwise (seen from
    /// above) from the world axis least aligned with up that is not it: −z for a y-up world
    /// (facing a camera on the +z side of the model, looking towards −z), +y for z-up data.
    pub fn new(up: Vec3, rotation_degrees: f32) -> Self {
        let up = up.normalize();
        let reference = if up.y.abs() >= up.z.abs() { Vec3::NEG_Z } else { Vec3::Y };
        let forward0 = (reference - up * reference.dot(up)).normalize();
        let left0 = up.cross(forward0);
        let (sin, cos) = rotation_degrees.to_radians().sin_cos();
        let forward = forward0 * cos + left0 * sin;
        Self { up, forward, left: up.cross(forward) }
    }

    /// `dir` in the frame's coordinates (forward, left, up).
    fn local(&self, dir: Vec3) -> Vec3 {
        Vec3::new(dir.dot(self.forward), dir.dot(self.left), dir.dot(self.up))
    }

    fn world(&self, local: Vec3) -> Vec3 {
        self.forward * local.x + self.left * local.y + self.up * local.z
    }
}

/// A direction drawn from a map: where it goes, the radiance arriving along it and its
/// density in solid angle.
#[derive(Clone, Copy, Debug)]
pub struct EnvSample {
    pub dir: Vec3,
    pub radiance: Vec3,
    pub pdf: f32,
}

fn luminance(c: [f32; 3]) -> f64 {
    0.2126 * f64::from(c[0]) + 0.7152 * f64::from(c[1]) + 0.0722 * f64::from(c[2])
}

impl EnvMap {
    /// A map of `width` × `height` linear RGB pixels, row by row from the top.
    pub fn new(width: usize, height: usize, texels: Vec<[f32; 3]>) -> Result<Self, EnvMapError> {
        if width < 2 || height < 1 {
            return Err(EnvMapError::TooSmall(width, height));
        }
        if texels.len() != width * height {
            return Err(EnvMapError::PixelCount { pixels: texels.len(), width, height });
        }
        if let Some(i) = texels.iter().position(|c| c.iter().any(|v| !v.is_finite() || *v < 0.0)) {
            return Err(EnvMapError::BadPixel { x: i % width, y: i / width, value: texels[i] });
        }
        let mut map = Self {
            width,
            height,
            texels,
            rows: vec![],
            columns: vec![],
            total: 0.0,
            harmonics: [Vec3::ZERO; 9],
            mean: [0.0; 3],
        };
        map.build_distribution();
        (map.harmonics, map.mean) = map.project_harmonics();
        Ok(map)
    }

    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The mean radiance over the sphere (each texel weighted by its solid angle): what a
    /// film shows outside the rendered region.
    pub fn mean(&self) -> [f32; 3] {
        self.mean
    }

    /// Texel weights: the luminance of [`Self::radiance`] averaged over the texel (the bilinear
    /// filter spreads each texel a quarter of a texel into its neighbours: weights 1/8, 3/4,
    /// 1/8 along each axis) times sin θ at the row's centre (the solid angle it covers). From
    /// the texels alone, a 2 × 2-texel sun's bilinear fringe, drawn at the sky's density,
    /// gave the fringe's light to the bounced rays alone: pixels of a plane under it spread
    /// 3.9 about a mean of 1.1 at 16 samples. Each row summed in f64, so that a 4k map's
    /// cumulative sums keep their order.
    fn build_distribution(&mut self) {
        let (w, h) = (self.width, self.height);
        let lum: Vec<f64> = self.texels.iter().map(|&c| luminance(c)).collect();
        // Along each row (wrapping round), then down the columns (clamped at the poles).
        let along: Vec<f64> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                0.125 * lum[y * w + (x + w - 1) % w] + 0.75 * lum[i] + 0.125 * lum[y * w + (x + 1) % w]
            })
            .collect();
        let mut columns = Vec::with_capacity(h * (w + 1));
        let mut row_weights = Vec::with_capacity(h);
        for y in 0..h {
            let sin = ((y as f64 + 0.5) / h as f64 * std::f64::consts::PI).sin();
            let (up, down) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let mut sums = Vec::with_capacity(w + 1);
            let mut sum = 0.0f64;
            sums.push(0.0);
            for x in 0..w {
                sum += (0.125 * along[up * w + x] + 0.75 * along[y * w + x] + 0.125 * along[down * w + x]) * sin;
                sums.push(sum);
            }
            columns.extend(sums.iter().map(|s| if sum > 0.0 { (s / sum) as f32 } else { 0.0 }));
            row_weights.push(sum);
        }
        let total: f64 = row_weights.iter().sum();
        let mut rows = Vec::with_capacity(h + 1);
        let mut acc = 0.0;
        rows.push(0.0);
        for r in &row_weights {
            acc += r;
            rows.push(if total > 0.0 { (acc / total) as f32 } else { 0.0 });
        }
        (self.rows, self.columns, self.total) = (rows, columns, total);
    }

    /// The texel `local` (frame coordinates, unit) falls in, and its sin θ.
    fn texel(&self, local: Vec3) -> (usize, usize, f32) {
        let (u, v) = uv(local);
        let x = ((u * self.width as f32) as usize).min(self.width - 1);
        let y = ((v * self.height as f32) as usize).min(self.height - 1);
        let cos_theta = local.z.clamp(-1.0, 1.0);
        (x, y, (1.0 - cos_theta * cos_theta).max(0.0).sqrt())
    }

    /// Radiance arriving along unit `dir` (pointing away from the scene): bilinear between
    /// the four nearest texel centres, wrapping round in longitude. The samples' density
    /// stays piecewise constant by texel; it is positive wherever a texel's own radiance is,
    /// and multiple importance sampling leaves the rest to the bounced rays, so the
    /// estimate stays unbiased.
    pub fn radiance(&self, frame: &EnvFrame, dir: Vec3) -> Vec3 {
        let (u, v) = uv(frame.local(dir));
        let (w, h) = (self.width, self.height);
        let (fx, fy) = (u * w as f32 - 0.5, (v * h as f32 - 0.5).clamp(0.0, (h - 1) as f32));
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        let x0 = (x0 as isize).rem_euclid(w as isize) as usize;
        let (x1, y0) = ((x0 + 1) % w, y0 as usize);
        let y1 = (y0 + 1).min(h - 1);
        let at = |x: usize, y: usize| Vec3::from(self.texels[y * w + x]);
        let top = at(x0, y0).lerp(at(x1, y0), tx);
        let bottom = at(x0, y1).lerp(at(x1, y1), tx);
        top.lerp(bottom, ty)
    }

    /// The density in solid angle with which [`Self::sample`] draws `dir`.
    pub fn pdf(&self, frame: &EnvFrame, dir: Vec3) -> f32 {
        let (x, y, sin_theta) = self.texel(frame.local(dir));
        self.pdf_of(x, y, sin_theta)
    }

    fn pdf_of(&self, x: usize, y: usize, sin_theta: f32) -> f32 {
        if self.total <= 0.0 || sin_theta <= 0.0 {
            return 0.0;
        }
        let row = (self.rows[y + 1] - self.rows[y]) as f64;
        let c = &self.columns[y * (self.width + 1)..];
        let column = (c[x + 1] - c[x]) as f64;
        // Density in (u, v) over the unit square, then per steradian: dω = 2π² sin θ du dv.
        let uv = row * column * (self.width * self.height) as f64;
        (uv / (2.0 * std::f64::consts::PI * std::f64::consts::PI * f64::from(sin_theta))) as f32
    }

    /// A direction drawn in proportion to luminance × solid angle from two uniform numbers;
    /// `None` for a black map.
    pub fn sample(&self, frame: &EnvFrame, u: [f32; 2]) -> Option<EnvSample> {
        if self.total <= 0.0 {
            return None;
        }
        let (y, fy) = pick(&self.rows, u[0]);
        let (x, fx) = pick(&self.columns[y * (self.width + 1)..(y + 1) * (self.width + 1)], u[1]);
        let uu = (x as f32 + fx) / self.width as f32;
        let v = (y as f32 + fy) / self.height as f32;
        let (sin_theta, cos_theta) = (v * PI).sin_cos();
        let phi = (0.5 - uu) * TAU;
        let local = Vec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta);
        let dir = frame.world(local).normalize();
        // The texel and density as `pdf` finds them for this direction (the same function,
        // so that a sample's weight and a bounced ray's agree).
        let (x, y, sin_theta) = self.texel(frame.local(dir));
        let pdf = self.pdf_of(x, y, sin_theta);
        (pdf > 0.0).then(|| EnvSample { dir, radiance: self.radiance(frame, dir), pdf })
    }

    /// Irradiance on a surface facing unit `normal` under the whole map, nothing in the way
    /// (the cosine-weighted integral of the radiance over the hemisphere): from the nine
    /// spherical harmonics, exact for a map of up to second order and smooth for the rest.
    pub fn irradiance(&self, frame: &EnvFrame, normal: Vec3) -> Vec3 {
        let n = frame.local(normal);
        let basis = sh_basis(n);
        // Convolution with the clamped cosine: Â₀ = π, Â₁ = 2π/3, Â₂ = π/4.
        let bands = [PI, TAU / 3.0, TAU / 3.0, TAU / 3.0, PI / 4.0, PI / 4.0, PI / 4.0, PI / 4.0, PI / 4.0];
        let e: Vec3 = (0..9).map(|i| self.harmonics[i] * (bands[i] * basis[i])).sum();
        e.max(Vec3::ZERO)
    }

    /// The radiance's projections onto the nine real spherical harmonics, texel by texel at
    /// the texels' centres, in frame coordinates; and its mean over the sphere.
    fn project_harmonics(&self) -> ([Vec3; 9], [f32; 3]) {
        let (w, h) = (self.width, self.height);
        let mut sums = [[0.0f64; 3]; 9];
        let (mut mean, mut sphere) = ([0.0f64; 3], 0.0f64);
        for y in 0..h {
            let theta = (y as f64 + 0.5) / h as f64 * std::f64::consts::PI;
            // The row's exact solid angle a texel: Δφ (cos θ₀ − cos θ₁).
            let band = |y: usize| (y as f64 / h as f64 * std::f64::consts::PI).cos();
            let d_omega = (band(y) - band(y + 1)) * (std::f64::consts::TAU / w as f64);
            for x in 0..w {
                let phi = (0.5 - (x as f64 + 0.5) / w as f64) * std::f64::consts::TAU;
                let local =
                    Vec3::new((theta.sin() * phi.cos()) as f32, (theta.sin() * phi.sin()) as f32, theta.cos() as f32);
                let basis = sh_basis(local);
                let c = self.texels[y * w + x];
                sphere += d_omega;
                for k in 0..3 {
                    mean[k] += f64::from(c[k]) * d_omega;
                }
                for (sum, b) in sums.iter_mut().zip(basis) {
                    for k in 0..3 {
                        sum[k] += f64::from(c[k]) * f64::from(b) * d_omega;
                    }
                }
            }
        }
        (sums.map(|s| Vec3::new(s[0] as f32, s[1] as f32, s[2] as f32)), mean.map(|m| (m / sphere) as f32))
    }
}

/// Where unit `local` (frame coordinates) lies on the map, both in [0, 1]: u from the left
/// edge, clockwise from the centre column seen from above; v from the top (straight up).
fn uv(local: Vec3) -> (f32, f32) {
    let u = (0.5 - local.y.atan2(local.x) / TAU).rem_euclid(1.0);
    (u, local.z.clamp(-1.0, 1.0).acos() / PI)
}

/// The nine real spherical harmonics of bands 0–2 at unit `n`.
fn sh_basis(n: Vec3) -> [f32; 9] {
    let (x, y, z) = (n.x, n.y, n.z);
    [
        0.282_095,
        0.488_603 * y,
        0.488_603 * z,
        0.488_603 * x,
        1.092_548 * x * y,
        1.092_548 * y * z,
        0.315_392 * (3.0 * z * z - 1.0),
        1.092_548 * x * z,
        0.546_274 * (x * x - y * y),
    ]
}

/// The interval of the normalised cumulative `cdf` (n + 1 entries, from 0 to exactly 1) that
/// `u` in [0, 1) falls in, and where in it (0–1): the last entry ≤ u begins it, and the next
/// is > u, so an empty interval (a black row or texel) is never chosen.
fn pick(cdf: &[f32], u: f32) -> (usize, f32) {
    let i = cdf.partition_point(|&c| c <= u).clamp(1, cdf.len() - 1) - 1;
    let width = cdf[i + 1] - cdf[i];
    let f = if width > 0.0 { ((u - cdf[i]) / width).min(1.0 - f32::EPSILON) } else { 0.5 };
    (i, f)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A map dark everywhere but a bright patch, on a dim blue sky above the horizon.
    fn patchy(width: usize, height: usize) -> EnvMap {
        let mut texels = vec![[0.0; 3]; width * height];
        for y in 0..height / 2 {
            for x in 0..width {
                texels[y * width + x] = [0.1, 0.2, 0.4];
            }
        }
        for y in height / 8..height / 4 {
            for x in width / 3..width / 3 + width / 16 {
                texels[y * width + x] = [40.0, 38.0, 30.0];
            }
        }
        EnvMap::new(width, height, texels).unwrap()
    }

    fn sphere_directions(n: usize) -> impl Iterator<Item = (Vec3, f32)> {
        // A latitude–longitude grid of n × 2n cells, each with its solid angle.
        (0..n).flat_map(move |i| {
            let theta = (i as f32 + 0.5) / n as f32 * PI;
            (0..2 * n).map(move |j| {
                let phi = (j as f32 + 0.5) / (2 * n) as f32 * TAU;
                let d = Vec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin());
                (d, theta.sin() * (PI / n as f32) * (PI / n as f32))
            })
        })
    }

    impl EnvMap {
        /// The radiance of the texel `dir` falls in, unfiltered.
        fn texel_radiance(&self, frame: &EnvFrame, dir: Vec3) -> Vec3 {
            let (x, y, _) = self.texel(frame.local(dir));
            Vec3::from(self.texels[y * self.width + x])
        }
    }

    #[test]
    fn the_density_integrates_to_one_over_the_sphere() {
        let map = patchy(64, 32);
        let frame = EnvFrame::new(Vec3::Y, 30.0);
        let total: f32 = sphere_directions(400).map(|(d, w)| map.pdf(&frame, d) * w).sum();
        assert!((total - 1.0).abs() < 0.01, "{total}");
    }

    #[test]
    fn samples_follow_their_density_and_carry_their_radiance() {
        let map = patchy(64, 32);
        let frame = EnvFrame::new(Vec3::Z, -70.0);
        let n = 20_000;
        let mut in_patch = 0;
        for i in 0..n {
            let u = [(i as f32 + 0.5) / n as f32, ((i as f32 * 0.618_034) % 1.0)];
            let s = map.sample(&frame, u).unwrap();
            assert!((s.dir.length() - 1.0).abs() < 1e-5);
            assert!((s.pdf / map.pdf(&frame, s.dir) - 1.0).abs() < 1e-4, "{} {}", s.pdf, map.pdf(&frame, s.dir));
            assert_eq!(s.radiance, map.radiance(&frame, s.dir));
            in_patch += usize::from(map.texel_radiance(&frame, s.dir).x > 1.0);
        }
        // The patch texels' share of the filtered radiance's luminance × solid angle, summed
        // directly: the density follows what `radiance` returns.
        let lum = |c: Vec3| 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z;
        let (mut patch, mut all) = (0.0, 0.0);
        for (d, w) in sphere_directions(400) {
            let l = lum(map.radiance(&frame, d)) * w;
            all += l;
            if map.texel_radiance(&frame, d).x > 1.0 {
                patch += l;
            }
        }
        let share = in_patch as f32 / n as f32;
        assert!((share - patch / all).abs() < 0.01, "{share} against {}", patch / all);
    }

    #[test]
    fn a_uniform_map_gives_pi_times_its_radiance_on_every_normal() {
        let map = EnvMap::new(32, 16, vec![[0.5, 1.0, 2.0]; 32 * 16]).unwrap();
        let frame = EnvFrame::new(Vec3::Y, 0.0);
        for n in [Vec3::X, Vec3::Y, Vec3::NEG_Z, Vec3::new(1.0, -2.0, 0.5).normalize()] {
            let e = map.irradiance(&frame, n);
            // Within 1 %: the texel sums integrate the harmonics a little off.
            assert!((e / (Vec3::new(0.5, 1.0, 2.0) * PI) - 1.0).abs().max_element() < 0.01, "{n}: {e}");
        }
        let mean = map.mean();
        assert!((Vec3::from(mean) - Vec3::new(0.5, 1.0, 2.0)).length() < 1e-3, "{mean:?}");
    }

    #[test]
    fn a_sky_above_the_horizon_lights_upward_faces_and_not_downward_ones() {
        // Radiance 1 above the horizon: π on a face looking up, 0 looking down, π/2 on a wall.
        let (w, h) = (64, 32);
        let texels = (0..w * h).map(|i| if i / w < h / 2 { [1.0; 3] } else { [0.0; 3] }).collect();
        let map = EnvMap::new(w, h, texels).unwrap();
        let frame = EnvFrame::new(Vec3::Z, 10.0);
        let e = |n: Vec3| map.irradiance(&frame, n).x;
        // Second-order harmonics smooth the step: within a few percent of π and 0.
        assert!((e(Vec3::Z) / PI - 1.0).abs() < 0.08, "{}", e(Vec3::Z));
        assert!(e(Vec3::NEG_Z) / PI < 0.08, "{}", e(Vec3::NEG_Z));
        assert!((e(Vec3::X) / (PI / 2.0) - 1.0).abs() < 0.02, "{}", e(Vec3::X));
    }

    #[test]
    fn the_centre_column_faces_forward_and_columns_run_clockwise_from_above() {
        // One bright column at the centre, one a quarter of the way from the left edge.
        let (w, h) = (8, 4);
        let mut texels = vec![[0.0; 3]; w * h];
        for y in 0..h {
            texels[y * w + 4] = [1.0, 0.0, 0.0];
            texels[y * w + 2] = [0.0, 1.0, 0.0];
        }
        let map = EnvMap::new(w, h, texels).unwrap();
        let frame = EnvFrame::new(Vec3::Y, 0.0);
        assert_eq!(frame.forward, Vec3::NEG_Z);
        let slightly = |d: Vec3| (d + Vec3::Y * 0.1).normalize();
        // The centre column (texel 4 starts at u = 0.5) just right of forward; texel 2 (u =
        // 0.25–0.375) a quarter turn to the left, seen from inside.
        assert_eq!(map.texel_radiance(&frame, slightly(Vec3::new(0.1, 0.0, -1.0))).x, 1.0);
        assert_eq!(map.texel_radiance(&frame, slightly(Vec3::new(-1.0, 0.0, -0.1))).y, 1.0);
        // Rotated by 90° anticlockwise from above, the centre column looks along −x.
        let turned = EnvFrame::new(Vec3::Y, 90.0);
        assert!((turned.forward - Vec3::NEG_X).length() < 1e-6);
    }

    #[test]
    fn bad_pixels_and_sizes_are_refused() {
        assert_eq!(EnvMap::new(1, 1, vec![[0.0; 3]]), Err(EnvMapError::TooSmall(1, 1)));
        assert!(matches!(EnvMap::new(2, 2, vec![[0.0; 3]; 3]), Err(EnvMapError::PixelCount { .. })));
        let bad = EnvMap::new(2, 1, vec![[0.0; 3], [1.0, f32::NAN, 0.0]]);
        assert!(matches!(bad, Err(EnvMapError::BadPixel { x: 1, y: 0, .. })));
        let black = EnvMap::new(4, 2, vec![[0.0; 3]; 8]).unwrap();
        assert!(black.sample(&EnvFrame::new(Vec3::Y, 0.0), [0.3, 0.7]).is_none());
        assert_eq!(black.pdf(&EnvFrame::new(Vec3::Y, 0.0), Vec3::X), 0.0);
    }

    #[test]
    fn pick_never_chooses_an_empty_interval() {
        let cdf = [0.0, 0.0, 0.5, 0.5, 1.0];
        assert_eq!(pick(&cdf, 0.0).0, 1);
        assert_eq!(pick(&cdf, 0.25), (1, 0.5));
        assert_eq!(pick(&cdf, 0.5).0, 3);
        assert_eq!(pick(&cdf, 0.999_999).0, 3);
    }
}
