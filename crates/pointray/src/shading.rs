//! Lights, and the environment that rays leaving the scene see.

use glam::Vec3;

#[derive(Clone, Copy, Debug, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum Light {
    /// Light arriving from `direction` (pointing *towards* the light), from infinitely far.
    Directional { direction: Vec3, intensity: f32 },
    /// A point light; intensity falls off with the square of the distance.
    Point { position: Vec3, intensity: f32 },
}

impl Light {
    /// Unit direction towards the light, the distance to it, and the irradiance scale at `p`.
    pub fn towards(&self, p: Vec3) -> (Vec3, f32, f32) {
        match *self {
            Light::Directional { direction, intensity } => (direction.normalize(), f32::INFINITY, intensity),
            Light::Point { position, intensity } => {
                let d = position - p;
                let dist2 = d.length_squared().max(f32::MIN_POSITIVE);
                (d / dist2.sqrt(), dist2.sqrt(), intensity / dist2)
            }
        }
    }
}

/// What a ray that leaves the scene sees.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum Environment {
    /// The same linear radiance from every direction.
    Uniform { color: [f32; 3] },
    /// A sky: `horizon` level with the horizon, blending linearly in the sine of the elevation
    /// to `zenith` straight up (along unit `up`); `ground` everywhere below the horizon.
    Gradient { up: Vec3, zenith: [f32; 3], horizon: [f32; 3], ground: [f32; 3] },
}

impl Environment {
    /// Linear radiance arriving along unit `dir` (pointing away from the scene).
    pub fn radiance(&self, dir: Vec3) -> Vec3 {
        match *self {
            Environment::Uniform { color } => Vec3::from(color),
            Environment::Gradient { up, zenith, horizon, ground } => {
                let elevation = dir.dot(up);
                if elevation < 0.0 {
                    Vec3::from(ground)
                } else {
                    Vec3::from(horizon).lerp(Vec3::from(zenith), elevation.min(1.0))
                }
            }
        }
    }

    /// One colour for the film outside the rendered region: the horizon's for a sky.
    pub fn flat_color(&self) -> [f32; 3] {
        match *self {
            Environment::Uniform { color } => color,
            Environment::Gradient { horizon, .. } => horizon,
        }
    }
}
