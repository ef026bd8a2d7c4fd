//! Lights, and the environment that rays leaving the scene see.

use std::sync::Arc;

use glam::Vec3;

use crate::env_map::{EnvFrame, EnvMap};

/// A light. Its `intensity` is in the units of what it shows: a white Lambert surface facing
/// it (at distance 1 from a point, sphere or spot light) has radiance `intensity`, in the path
/// tracer and in Whitted's Phong alike (which takes 1 − ambient of it and adds its ambient
/// term instead). Radiometrically that is an irradiance of π × `intensity` on the albedo/π
/// BRDF, so the path tracer's lights and its sky (a radiance) add up physically, and a scene
/// keeps its brightness when it changes integrator.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum Light {
    /// Light arriving from `direction` (pointing *towards* the light), from infinitely far.
    Directional { direction: Vec3, intensity: f32 },
    /// A point light; intensity falls off with the square of the distance.
    Point { position: Vec3, intensity: f32 },
    /// A spherical area light: it lights like a point light at its centre, but shadow rays
    /// aim at random points of it, so shadows have penumbrae (soft shadows, converging with
    /// the samples per pixel).
    Sphere { center: Vec3, radius: f32, intensity: f32 },
    /// A point light shining into a cone around `direction` (unit, from the light): full
    /// within `inner` radians of the axis, none beyond `outer`, smoothly between.
    Spot { position: Vec3, direction: Vec3, inner: f32, outer: f32, intensity: f32 },
}

impl Light {
    /// A directional light from behind `camera`, raised and shifted right: the command line's
    /// default and the bench's (Embree's bench lights its frames so too).
    pub fn headlight(camera: &crate::camera::Camera, intensity: f32) -> Self {
        Light::Directional { direction: -camera.forward() + 0.6 * camera.up() + 0.4 * camera.right(), intensity }
    }

    /// The same light at `intensity`.
    #[must_use]
    pub fn with_intensity(self, intensity: f32) -> Self {
        match self {
            Light::Directional { direction, .. } => Light::Directional { direction, intensity },
            Light::Point { position, .. } => Light::Point { position, intensity },
            Light::Sphere { center, radius, .. } => Light::Sphere { center, radius, intensity },
            Light::Spot { position, direction, inner, outer, .. } => {
                Light::Spot { position, direction, inner, outer, intensity }
            }
        }
    }

    /// Unit direction towards the light, the distance to it, and the irradiance scale at `p`.
    pub fn towards(&self, p: Vec3) -> (Vec3, f32, f32) {
        match *self {
            Light::Directional { direction, intensity } => (direction.normalize(), f32::INFINITY, intensity),
            Light::Point { position, intensity } | Light::Sphere { center: position, intensity, .. } => {
                let d = position - p;
                let dist2 = d.length_squared().max(f32::MIN_POSITIVE);
                (d / dist2.sqrt(), dist2.sqrt(), intensity / dist2)
            }
            Light::Spot { position, direction, inner, outer, intensity } => {
                let d = position - p;
                let dist2 = d.length_squared().max(f32::MIN_POSITIVE);
                let towards = d / dist2.sqrt();
                let cos = (-towards).dot(direction.normalize());
                // Smoothstep in the cosine, from the outer edge (0) to the inner cone (1).
                let (lo, hi) = (outer.cos(), inner.min(outer).cos());
                let x = if hi > lo { ((cos - lo) / (hi - lo)).clamp(0.0, 1.0) } else { f32::from(cos >= lo) };
                (towards, dist2.sqrt(), intensity * x * x * (3.0 - 2.0 * x) / dist2)
            }
        }
    }

    /// Whether shadow rays need random numbers (the light has an area).
    pub fn is_area(&self) -> bool {
        matches!(self, Light::Sphere { radius, .. } if *radius > 0.0)
    }

    /// Where the shadow ray from `p` goes, and how far it must be free: towards the light, or
    /// for a sphere in a direction uniformly distributed over the cone it subtends at `p`
    /// (chosen by the two uniform numbers `u`), as far as the sphere's surface. From inside
    /// the sphere, towards its centre.
    pub fn shadow_target(&self, p: Vec3, u: [f32; 2]) -> (Vec3, f32) {
        let (towards, distance, _) = self.towards(p);
        let Light::Sphere { radius, .. } = *self else { return (towards, distance) };
        let sin2_max = (radius / distance).powi(2);
        if sin2_max >= 1.0 {
            return (towards, distance);
        }
        let cos_max = (1.0 - sin2_max).sqrt();
        let cos = 1.0 - u[0] * (1.0 - cos_max);
        let sin = (1.0 - cos * cos).max(0.0).sqrt();
        let phi = std::f32::consts::TAU * u[1];
        let (a, b) = crate::math::orthonormal_basis(towards);
        let direction = (towards * cos + (a * phi.cos() + b * phi.sin()) * sin).normalize();
        // The nearer crossing of the sphere along that direction.
        let along = distance * cos;
        let to_surface = along - (radius * radius - distance * distance * sin * sin).max(0.0).sqrt();
        (direction, to_surface)
    }
}

/// [`Environment::sky`]'s zenith, horizon and ground, linear RGB.
pub const SKY: [[f32; 3]; 3] = [[0.18, 0.32, 0.62], [0.75, 0.82, 0.90], [0.25, 0.24, 0.22]];

/// What a ray that leaves the scene sees.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum Environment {
    /// The same linear radiance from every direction.
    Uniform { color: [f32; 3] },
    /// A sky: `horizon` level with the horizon, blending linearly in the sine of the elevation
    /// to `zenith` straight up (along unit `up`); `ground` everywhere below the horizon.
    Gradient { up: Vec3, zenith: [f32; 3], horizon: [f32; 3], ground: [f32; 3] },
    /// An HDR panorama placed in the world by its frame: seen by the rays that leave, and a
    /// light of its own (the path tracer samples it, Whitted's Phong takes its irradiance
    /// as the ambient term; see [`crate::env_map`]).
    #[serde(skip_deserializing)]
    Map {
        #[serde(serialize_with = "shared")]
        map: Arc<EnvMap>,
        frame: EnvFrame,
    },
}

fn shared<S: serde::Serializer>(map: &Arc<EnvMap>, s: S) -> Result<S::Ok, S::Error> {
    serde::Serialize::serialize(map.as_ref(), s)
}

impl Environment {
    /// The dark blue the command line renders behind a model by default.
    pub const BACKGROUND: Environment = Environment::Uniform { color: [0.010, 0.011, 0.019] };

    /// The sky of `--sky` (and a scene file's default), its zenith up `up` (unit): a blue
    /// zenith, a pale horizon and a grey-brown ground.
    pub fn sky(up: Vec3) -> Environment {
        let [zenith, horizon, ground] = SKY;
        Environment::Gradient { up, zenith, horizon, ground }
    }

    /// Linear radiance arriving along unit `dir` (pointing away from the scene).
    pub fn radiance(&self, dir: Vec3) -> Vec3 {
        match self {
            Environment::Uniform { color } => Vec3::from(*color),
            Environment::Gradient { up, zenith, horizon, ground } => {
                let elevation = dir.dot(*up);
                if elevation < 0.0 {
                    Vec3::from(*ground)
                } else {
                    Vec3::from(*horizon).lerp(Vec3::from(*zenith), elevation.min(1.0))
                }
            }
            Environment::Map { map, frame } => map.radiance(frame, dir),
        }
    }

    /// One colour for the film outside the rendered region: the horizon's for a sky.
    pub fn flat_color(&self) -> [f32; 3] {
        match self {
            Environment::Uniform { color } => *color,
            Environment::Gradient { horizon, .. } => *horizon,
            Environment::Map { map, .. } => map.mean(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spot_light_is_full_inside_dark_outside_and_smooth_between() {
        let spot = Light::Spot {
            position: Vec3::new(0.0, 2.0, 0.0),
            direction: Vec3::NEG_Y,
            inner: 20f32.to_radians(),
            outer: 30f32.to_radians(),
            intensity: 4.0,
        };
        let at = |degrees: f32| {
            let x = 2.0 * degrees.to_radians().tan();
            let (towards, distance, irradiance) = spot.towards(Vec3::new(x, 0.0, 0.0));
            assert!((towards.length() - 1.0).abs() < 1e-6 && (distance * distance - (4.0 + x * x)).abs() < 1e-4);
            irradiance * distance * distance / 4.0
        };
        assert!((at(0.0) - 1.0).abs() < 1e-6 && (at(19.0) - 1.0).abs() < 1e-6);
        assert_eq!(at(31.0), 0.0);
        let between: Vec<f32> = [21.0, 23.0, 25.0, 27.0, 29.0].iter().map(|&d| at(d)).collect();
        assert!(between.windows(2).all(|w| w[0] > w[1]) && between[0] < 1.0 && between[4] > 0.0, "{between:?}");
    }
}
