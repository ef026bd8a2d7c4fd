//! An analytic ground plane for the point clouds to stand on: exact, flat and endless where
//! a floor of points would be sampled, bounded and blurred by its splats' level of detail.
//! The renderer tests it beside the accelerator for every ray, shadow rays included.

use glam::Vec3;

use crate::material::Material;
use crate::math::{Ray, orthonormal_basis};
use crate::splat::scheme::SurfaceHit;

/// The plane `{p : p·up = height}`, seen from both sides.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GroundPlane {
    /// Unit normal of the side the scene stands on.
    pub up: Vec3,
    /// Signed distance of the plane from the origin along `up`.
    pub height: f32,
    /// Linear albedo; with a checker, the colour of the squares whose indices sum to an even number.
    pub color: [f32; 3],
    pub checker: Option<Checker>,
    pub material: Material,
}

/// Squares of side `tile` alternating between the ground's colour and `color` (linear).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Checker {
    pub color: [f32; 3],
    pub tile: f32,
}

impl GroundPlane {
    /// Whether `ray` meets the plane in `(ray.t_min, t_max)` (shadow rays).
    pub fn blocks(&self, ray: &Ray, t_max: f32) -> bool {
        let t = (self.height - ray.origin.dot(self.up)) / ray.dir.dot(self.up);
        t > ray.t_min && t < t_max
    }

    /// Where `ray` meets the plane in `(ray.t_min, t_max)`, if it does. The hit's `splat` is
    /// `u32::MAX` (no splat) and its `radius`, which sets how far rays leaving it start off the
    /// plane, is a few hundred ulps of the hit's coordinates: the plane is exact, so only
    /// rounding can put a leaving ray's origin behind it.
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<SurfaceHit> {
        let facing = ray.dir.dot(self.up);
        let t = (self.height - ray.origin.dot(self.up)) / facing;
        // A ray along the plane gives ±∞ or NaN, which fail the test.
        if !(t > ray.t_min && t < t_max) {
            return None;
        }
        // Snapped onto the plane: the error left is the rounding of the position itself,
        // however far the ray came.
        let position = ray.at(t);
        let position = position - self.up * (position.dot(self.up) - self.height);
        Some(SurfaceHit {
            t,
            position,
            normal: if facing < 0.0 { self.up } else { -self.up },
            color: self.albedo(position),
            radius: 256.0 * f32::EPSILON * (position.abs().max_element() + self.height.abs()).max(1e-6),
            splat: u32::MAX,
            blended: 0,
        })
    }

    fn albedo(&self, position: Vec3) -> [f32; 3] {
        let Some(checker) = self.checker else { return self.color };
        let (a, b) = orthonormal_basis(self.up);
        // Parity in floating point: no integer to overflow however small the tile.
        let square = |axis: Vec3| (position.dot(axis) / checker.tile).floor();
        if (square(a) + square(b)).rem_euclid(2.0) < 1.0 { self.color } else { checker.color }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::RayCone;

    fn ground() -> GroundPlane {
        GroundPlane {
            up: Vec3::Y,
            height: -1.0,
            color: [0.2; 3],
            checker: Some(Checker { color: [0.8; 3], tile: 0.5 }),
            material: Material::standard(),
        }
    }

    #[test]
    fn rays_meet_the_plane_where_it_is_from_either_side() {
        let cone = RayCone { width0: 0.0, spread: 0.0 };
        let down = Ray::new(Vec3::new(0.3, 2.0, 0.1), Vec3::new(0.6, -0.8, 0.0), cone);
        let hit = ground().intersect(&down, f32::INFINITY).unwrap();
        assert!((hit.t - 3.75).abs() < 1e-6 && (hit.position.y + 1.0).abs() < 1e-6, "{hit:?}");
        assert_eq!(hit.normal, Vec3::Y);
        let up = Ray::new(Vec3::new(0.0, -3.0, 0.0), Vec3::Y, cone);
        assert_eq!(ground().intersect(&up, f32::INFINITY).unwrap().normal, Vec3::NEG_Y);
        // Beyond t_max, behind the origin, or along the plane: no hit.
        assert!(ground().intersect(&down, 3.7).is_none());
        assert!(ground().blocks(&down, 3.8) && !ground().blocks(&down, 3.7));
        assert!(ground().intersect(&Ray::new(Vec3::ZERO, Vec3::Y, cone), f32::INFINITY).is_none());
        assert!(ground().intersect(&Ray::new(Vec3::new(0.0, -1.0, 0.0), Vec3::X, cone), f32::INFINITY).is_none());
    }

    #[test]
    fn a_ray_leaving_the_plane_does_not_meet_it_again() {
        // A tilted plane, whose points rounding puts off it, met at many places far and near,
        // and left at a grazing angle from one `radius` off it, as the renderer's rays leave.
        let tilted = GroundPlane { up: Vec3::new(0.2, 1.0, 0.3).normalize(), height: 0.7, ..ground() };
        let along = tilted.up.cross(Vec3::X).normalize();
        let cone = RayCone { width0: 0.0, spread: 0.0 };
        let mut again = 0;
        for i in 0..10_000 {
            let x = (i as f32 * 0.618_034).fract() * 2e3 - 1e3;
            let origin = Vec3::new(x, 0.0, 0.37 * x)
                + tilted.up * (tilted.height + 5.0 - Vec3::new(x, 0.0, 0.37 * x).dot(tilted.up));
            let incoming = Ray::new(origin, -tilted.up + along * 0.4, cone);
            let hit = tilted.intersect(&incoming, f32::INFINITY).unwrap();
            let leaving = Ray::new(hit.position + hit.normal * hit.radius, along + tilted.up * 0.001, cone);
            again += usize::from(tilted.intersect(&leaving, f32::INFINITY).is_some());
        }
        assert_eq!(again, 0, "rays that met the plane again");
    }

    #[test]
    fn the_checker_alternates_by_square() {
        let g = ground();
        let at = |x: f32, z: f32| g.albedo(Vec3::new(x, -1.0, z));
        assert_ne!(at(0.25, 0.25), at(0.75, 0.25));
        assert_ne!(at(0.25, 0.25), at(0.25, 0.75));
        assert_eq!(at(0.25, 0.25), at(0.75, 0.75));
        assert_eq!(at(-0.25, -0.25), at(0.25, 0.25));
    }
}
