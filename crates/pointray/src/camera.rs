//! Pinhole camera. Primary rays carry their footprint: one pixel's angular width.

use glam::{Vec3, Vec4};

use crate::math::{Aabb, Ray, RayCone, RayLanes};

/// A rectangle of pixels `[x0, x1) × [y0, y1)` of the full frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Region {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Region {
    pub fn full(width: u32, height: u32) -> Self {
        Self { x0: 0, y0: 0, x1: width, y1: height }
    }

    pub fn width(&self) -> u32 {
        self.x1.saturating_sub(self.x0)
    }

    pub fn height(&self) -> u32 {
        self.y1.saturating_sub(self.y0)
    }

    pub fn pixel_count(&self) -> u64 {
        self.width() as u64 * self.height() as u64
    }

    /// The part of `self` inside a `width × height` frame.
    #[must_use]
    pub fn clamp_to(self, width: u32, height: u32) -> Self {
        let x1 = self.x1.min(width);
        let y1 = self.y1.min(height);
        Self { x0: self.x0.min(x1), y0: self.y0.min(y1), x1, y1 }
    }
}

#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub eye: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    tan_half_fov: f32,
    aspect: f32,
    pub width: u32,
    pub height: u32,
    /// Depth of field: the radius of the thin lens (0: a pinhole, everything sharp)
    pub lens_radius: f32,
    /// and the distance along the view at which it focuses.
    pub focus_distance: f32,
    /// An orthographic camera: parallel rays along the view from the film's plane through the
    /// eye, framing what the perspective camera frames at this distance (its field of view
    /// there); `None` for a perspective one.
    pub orthographic: Option<f32>,
}

impl Camera {
    /// A camera at `eye` looking at `target`, `vfov_deg` the vertical field of view.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, vfov_deg: f32, width: u32, height: u32) -> Self {
        let forward = (target - eye).normalize();
        let mut up_hint = up.normalize();
        if forward.dot(up_hint).abs() > 0.999 {
            // Looking along `up`: +y up the image where it is not the view (north, in a plan
            // of a z-up survey), else −z (a y-up model's front, +z, at the foot of its plan).
            up_hint = if forward.y.abs() < 0.9 { Vec3::Y } else { Vec3::NEG_Z };
        }
        let right = forward.cross(up_hint).normalize();
        let up = right.cross(forward);
        Self {
            eye,
            forward,
            right,
            up,
            tan_half_fov: (vfov_deg.to_radians() * 0.5).tan(),
            aspect: width as f32 / height as f32,
            width,
            height,
            lens_radius: 0.0,
            focus_distance: (target - eye).length(),
            orthographic: None,
        }
    }

    /// The same view, orthographic: what the perspective camera shows at the distance it
    /// looks at (a plan, an elevation or a façade at that scale), without perspective.
    #[must_use]
    pub fn into_orthographic(mut self) -> Self {
        self.orthographic = Some(self.focus_distance);
        self
    }

    /// The camera with a thin lens of `radius` focused `focus_distance` away (depth of field).
    pub fn with_lens(mut self, radius: f32, focus_distance: f32) -> Self {
        self.lens_radius = radius.max(0.0);
        self.focus_distance = focus_distance;
        self
    }

    /// The ray through film position (`x`, `y`) from lens position `lens` (two uniform
    /// numbers): with a lens, it leaves a point of the lens disk towards where the pinhole ray
    /// meets the plane of focus, so that plane stays sharp and the rest blurs.
    pub fn lens_ray(&self, x: f32, y: f32, lens: [f32; 2]) -> Ray {
        let pinhole = self.ray(x, y);
        if self.lens_radius <= 0.0 {
            return pinhole;
        }
        let focus = pinhole.at(self.focus_distance / pinhole.dir.dot(self.forward));
        // Uniform on the disk (polar: r = R·√u).
        let (r, phi) = (self.lens_radius * lens[0].sqrt(), std::f32::consts::TAU * lens[1]);
        let origin = self.eye + self.right * (r * phi.cos()) + self.up * (r * phi.sin());
        Ray::new(origin, focus - origin, pinhole.cone)
    }

    /// The convention of `shared/bench/embree`: the camera sits `distance × diagonal` from the
    /// centre of `bounds` along `view_dir`, looking at the centre. At distance 1 with a 60°
    /// field of view the bounding sphere just fills the frame.
    pub fn orbit(
        bounds: &Aabb,
        view_dir: Vec3,
        up: Vec3,
        distance: f32,
        vfov_deg: f32,
        width: u32,
        height: u32,
    ) -> Self {
        let center = bounds.center();
        let eye = center + view_dir.normalize() * distance * bounds.diagonal();
        Self::look_at(eye, center, up, vfov_deg, width, height)
    }

    /// Angular width of one pixel (radians): the spread of a primary ray's footprint cone.
    pub fn pixel_spread(&self) -> f32 {
        2.0 * self.tan_half_fov / self.height as f32
    }

    /// The ray through film position (`x`, `y`) in pixels (pixel centres at +0.5).
    pub fn ray(&self, x: f32, y: f32) -> Ray {
        Ray::new(self.origin(x, y), self.direction(x, y), self.pinhole_cone())
    }

    /// Where [`Self::ray`] through film position (`x`, `y`) starts: the eye, or for an
    /// orthographic camera the film position on the plane through the eye.
    pub fn origin(&self, x: f32, y: f32) -> Vec3 {
        match self.orthographic {
            None => self.eye,
            Some(scale) => {
                let [u, v] = self.film_to_view(x, y);
                self.eye + (u * self.right + v * self.up) * scale
            }
        }
    }

    /// The direction, not normalised, of [`Self::ray`] through film position (`x`, `y`):
    /// `Ray::new` normalises it to the ray's very bits (normalising twice may not).
    pub fn direction(&self, x: f32, y: f32) -> Vec3 {
        if self.orthographic.is_some() {
            return self.forward;
        }
        let [u, v] = self.film_to_view(x, y);
        self.forward + u * self.right + v * self.up
    }

    /// [`Self::ray`] through `N` film positions at once (`N` a multiple of four), with the same
    /// bits ([`RayLanes`]). Always inlined: called for every eighth pixel, it went out of line
    /// when the render loop moved crates (callgrind: the dragon's first hits +8 instructions a
    /// pixel).
    #[inline(always)]
    pub fn rays<const N: usize>(&self, x: [f32; N], y: [f32; N]) -> RayLanes<N> {
        let mut dir = [[0.0; N]; 3];
        for i in (0..N).step_by(4) {
            let [u, v] = self.film_to_view(Vec4::from_slice(&x[i..i + 4]), Vec4::from_slice(&y[i..i + 4]));
            for (k, lanes) in dir.iter_mut().enumerate() {
                // `forward + u * right + v * up`, summed as `Vec3` sums it.
                let d = Vec4::splat(self.forward[k]) + u * self.right[k] + v * self.up[k];
                d.write_to_slice(&mut lanes[i..i + 4]);
            }
        }
        RayLanes::new(self.eye, dir, self.pinhole_cone())
    }

    /// Film position (`x`, `y`) in pixels as offsets (u, v) along `right` and `up` at unit
    /// distance; for one position (`f32`) or four (`Vec4`, the same operations lane by lane).
    #[inline(always)]
    fn film_to_view<T>(&self, x: T, y: T) -> [T; 2]
    where
        T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Div<f32, Output = T> + std::ops::Sub<f32, Output = T>,
        f32: std::ops::Mul<T, Output = T> + std::ops::Sub<T, Output = T>,
    {
        let u = (2.0 * x / self.width as f32 - 1.0) * self.tan_half_fov * self.aspect;
        let v = (1.0 - 2.0 * y / self.height as f32) * self.tan_half_fov;
        [u, v]
    }

    /// A primary ray's footprint: a pixel's angle, or an orthographic pixel's width.
    fn pinhole_cone(&self) -> RayCone {
        match self.orthographic {
            None => RayCone { width0: 0.0, spread: self.pixel_spread() },
            Some(scale) => RayCone { width0: self.pixel_spread() * scale, spread: 0.0 },
        }
    }

    /// Film position of `p`, or `None` if `p` is not in front of the camera.
    pub fn project(&self, p: Vec3) -> Option<(f32, f32)> {
        let d = p - self.eye;
        let z = d.dot(self.forward);
        if z <= 0.0 {
            return None;
        }
        // The perspective divides by the depth; an orthographic camera by its fixed scale.
        let z = self.orthographic.unwrap_or(z);
        let u = d.dot(self.right) / (z * self.tan_half_fov * self.aspect);
        let v = d.dot(self.up) / (z * self.tan_half_fov);
        Some((0.5 * (u + 1.0) * self.width as f32, 0.5 * (1.0 - v) * self.height as f32))
    }

    /// The pixels inside the projection of `bounds`, grown by one pixel (the Embree bench's
    /// `--crop`). The full frame when a corner lies behind the camera; empty when the box
    /// projects outside the frame.
    pub fn region_of(&self, bounds: &Aabb) -> Region {
        let full = Region::full(self.width, self.height);
        let mut lo = (f32::INFINITY, f32::INFINITY);
        let mut hi = (f32::NEG_INFINITY, f32::NEG_INFINITY);
        for c in bounds.corners() {
            let Some((x, y)) = self.project(c) else { return full };
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        let clampi = |v: f32, max: u32| v.clamp(0.0, max as f32) as u32;
        Region {
            x0: clampi(lo.0.floor() - 1.0, self.width),
            y0: clampi(lo.1.floor() - 1.0, self.height),
            x1: clampi(hi.0.ceil() + 1.0, self.width),
            y1: clampi(hi.1.ceil() + 1.0, self.height),
        }
    }

    pub fn forward(&self) -> Vec3 {
        self.forward
    }

    pub fn right(&self) -> Vec3 {
        self.right
    }

    pub fn up(&self) -> Vec3 {
        self.up
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lens_keeps_the_plane_of_focus_sharp() {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 48).with_lens(0.2, 5.0);
        for (x, y) in [(3.5, 7.5), (32.0, 24.0), (60.5, 40.5)] {
            let pinhole = cam.ray(x, y);
            let sharp = pinhole.at(5.0 / pinhole.dir.dot(Vec3::NEG_Z));
            let mut spread = 0.0f32;
            for lens in [[0.0, 0.0], [1.0, 0.25], [0.5, 0.7], [0.9, 0.1]] {
                let ray = cam.lens_ray(x, y, lens);
                assert!((ray.origin - cam.eye).length() <= 0.2 + 1e-6 && ray.origin.z == 5.0);
                // Every lens ray passes through the pinhole ray's point on the plane z = 0...
                let at_focus = ray.at(5.0 / ray.dir.dot(Vec3::NEG_Z));
                assert!((at_focus - sharp).length() < 1e-4, "{at_focus} against {sharp}");
                // ...and they spread apart elsewhere.
                let behind = ray.at(8.0 / ray.dir.dot(Vec3::NEG_Z));
                spread = spread.max((behind - pinhole.at(8.0 / pinhole.dir.dot(Vec3::NEG_Z))).length());
            }
            assert!(spread > 0.05, "{spread}");
        }
        let pinhole = Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 48);
        assert_eq!(pinhole.lens_ray(10.0, 10.0, [0.3, 0.3]).dir, pinhole.ray(10.0, 10.0).dir);
    }

    /// Rays made eight at a time are the rays made one at a time, bit for bit: on random film
    /// positions from several cameras, on the frame's corners and edges, and where a direction
    /// has a zero component (an infinite inverse).
    #[test]
    fn rays_in_lanes_equal_rays_one_at_a_time() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        let cameras = [
            Camera::look_at(Vec3::new(1.0, 2.0, 5.0), Vec3::ZERO, Vec3::Y, 60.0, 640, 480),
            Camera::look_at(Vec3::new(-3e3, 7.0, 0.1), Vec3::new(2.0, -1.0, 0.3), Vec3::Z, 25.0, 97, 1031),
            // Looking down an axis: the centre ray's direction has zero components.
            Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 48),
        ];
        let bits = |r: &Ray| [r.dir, r.inv_dir].map(|v| v.to_array().map(f32::to_bits));
        for cam in &cameras {
            let (w, h) = (cam.width as f32, cam.height as f32);
            let mut points: Vec<[f32; 2]> = vec![[0.0, 0.0], [w, h], [w / 2.0, h / 2.0], [0.0, h], [w, 0.0]];
            points.extend((0..995).map(|_| [rng.random_range(0.0..w), rng.random_range(0.0..h)]));
            for chunk in points.chunks_exact(8) {
                let rays = cam.rays::<8>(std::array::from_fn(|i| chunk[i][0]), std::array::from_fn(|i| chunk[i][1]));
                for (i, &[x, y]) in chunk.iter().enumerate() {
                    let (lane, one) = (rays.ray(i), cam.ray(x, y));
                    assert_eq!(bits(&lane), bits(&one), "({x}, {y})");
                    assert_eq!((lane.origin, lane.cone), (one.origin, one.cone));
                }
            }
        }
        let centre = cameras[2].ray(32.0, 24.0);
        assert!(centre.dir.x == 0.0 && centre.inv_dir.x.is_infinite(), "{centre:?}");
    }

    #[test]
    fn centre_pixel_looks_at_target_and_projection_inverts_rays() {
        let cam = Camera::look_at(Vec3::new(1.0, 2.0, 5.0), Vec3::ZERO, Vec3::Y, 60.0, 64, 48);
        let r = cam.ray(32.0, 24.0);
        assert!(r.dir.dot(-cam.eye.normalize()) > 0.99999);
        let p = cam.ray(10.5, 7.5).at(3.0);
        let (x, y) = cam.project(p).unwrap();
        assert!((x - 10.5).abs() < 1e-3 && (y - 7.5).abs() < 1e-3, "{x} {y}");
    }

    #[test]
    fn looking_along_up_still_gives_a_frame() {
        for (eye, up) in [(Vec3::new(0.0, 0.0, 5.0), Vec3::Z), (Vec3::new(0.0, 5.0, 0.0), Vec3::Y)] {
            let cam = Camera::look_at(eye, Vec3::ZERO, up, 60.0, 8, 8);
            assert!(cam.right().is_finite() && cam.up().is_finite());
            assert!(cam.ray(4.0, 4.0).dir.dot(-eye.normalize()) > 0.9999);
        }
    }

    #[test]
    fn orbit_at_distance_one_frames_the_bounding_sphere() {
        let b = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
        let cam = Camera::orbit(&b, Vec3::new(0.4, 0.3, 1.0), Vec3::Y, 1.0, 60.0, 100, 100);
        assert!((cam.eye.length() - b.diagonal()).abs() < 1e-4);
        // The bounding sphere (radius diagonal/2, seen from distance diagonal under a 60° field
        // of view) subtends exactly 60°: its outline touches the top and bottom of the frame.
        let (r, d) = (b.diagonal() / 2.0, cam.eye.length());
        let a = (r / d).asin();
        let (f, u) = (cam.forward(), cam.up());
        let touch_top = cam.eye + (f * a.cos() + u * a.sin()) * (d * d - r * r).sqrt();
        let touch_bottom = cam.eye + (f * a.cos() - u * a.sin()) * (d * d - r * r).sqrt();
        assert!(cam.project(touch_top).unwrap().1.abs() < 0.01);
        assert!((cam.project(touch_bottom).unwrap().1 - 100.0).abs() < 0.01);
        let region = cam.region_of(&b);
        assert!(region.x0 > 0 && region.x1 < 100 && region.y0 > 0 && region.y1 < 100, "{region:?}");
    }
}
