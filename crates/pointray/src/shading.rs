//! Lights and the Phong material: what a surface hit looks like.

use glam::Vec3;

use crate::splat::scheme::SurfaceHit;

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

/// Phong: ambient + Lambert diffuse (albedo = splat colour) + a white specular lobe.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Material {
    pub ambient: f32,
    pub specular: f32,
    pub shininess: f32,
}

impl Material {
    pub fn standard() -> Self {
        Self { ambient: 0.12, specular: 0.15, shininess: 40.0 }
    }

    /// Linear radiance towards `view` (unit, from the surface towards the eye) with light
    /// arriving along `to_light` at `irradiance`; `lit` is false in shadow.
    pub fn shade(&self, hit: &SurfaceHit, view: Vec3, to_light: Vec3, irradiance: f32, lit: bool) -> [f32; 3] {
        let albedo = Vec3::from(hit.color);
        let mut c = albedo * self.ambient;
        let n_dot_l = hit.normal.dot(to_light);
        if lit && n_dot_l > 0.0 {
            c += albedo * (n_dot_l * irradiance * (1.0 - self.ambient));
            if self.specular > 0.0 {
                let h = (to_light + view).normalize_or_zero();
                c += Vec3::splat(self.specular * irradiance * h.dot(hit.normal).max(0.0).powf(self.shininess));
            }
        }
        c.to_array()
    }
}
