//! Materials: what a surface does with the light that reaches it, and the optics they share.
//!
//! Splats are two-sided and a [`SurfaceHit`]'s normal always faces the incoming ray, so a
//! surface cannot tell from its normal whether a ray enters or leaves a glass object. As
//! Schaufler and Jensen do, the integrator tracks it along the path instead (`inside` in
//! `render`), and [`Material::Glass`] takes the relative index from that.

use glam::Vec3;

use crate::splat::scheme::SurfaceHit;

/// The material of every splat of a cloud.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum Material {
    /// Ambient, Lambert diffuse with the splats' colours as albedo, and a white specular lobe.
    Phong(Phong),
    /// A perfect mirror that reflects `tint` of what it sees.
    Mirror { tint: [f32; 3] },
    /// A smooth dielectric (glass, water): Fresnel-weighted reflection and refraction with
    /// index of refraction `ior` against the vacuum outside; `tint` filters each transmission.
    Glass { ior: f32, tint: [f32; 3] },
}

impl Material {
    /// The Phong material of earlier renders.
    pub fn standard() -> Self {
        Material::Phong(Phong::standard())
    }

    pub fn name(&self) -> &'static str {
        match self {
            Material::Phong(_) => "phong",
            Material::Mirror { .. } => "mirror",
            Material::Glass { .. } => "glass",
        }
    }
}

/// Phong: ambient + Lambert diffuse (albedo = splat colour) + a white specular lobe.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Phong {
    pub ambient: f32,
    pub specular: f32,
    pub shininess: f32,
}

impl Phong {
    pub fn standard() -> Self {
        Self { ambient: 0.12, specular: 0.15, shininess: 40.0 }
    }

    /// The part that needs no light: ambient × albedo.
    pub fn ambient(&self, hit: &SurfaceHit) -> Vec3 {
        Vec3::from(hit.color) * self.ambient
    }

    /// What one unshadowed light adds towards `view` (unit, from the surface towards the eye),
    /// arriving along `to_light` at `irradiance`: Lambert diffuse and the specular lobe.
    pub fn direct(&self, hit: &SurfaceHit, view: Vec3, to_light: Vec3, irradiance: f32) -> Vec3 {
        let n_dot_l = hit.normal.dot(to_light);
        if n_dot_l <= 0.0 {
            return Vec3::ZERO;
        }
        Vec3::from(hit.color) * (n_dot_l * irradiance * (1.0 - self.ambient))
            + self.glossy(hit.normal, view, to_light, irradiance)
    }

    /// The material as a patch whose normals spread looks, `agreement` the length of their
    /// mean (1: a smooth patch, the material itself): the lobe widened as Toksvig (2005) widens
    /// it, s' = s·a / (a + s(1 − a)), its energy kept, (1 + s') / (1 + s) as bright at its peak.
    pub fn rough(&self, agreement: f32) -> Phong {
        let a = agreement.clamp(0.0, 1.0);
        let shininess = self.shininess * a / (a + self.shininess * (1.0 - a)).max(f32::MIN_POSITIVE);
        Phong { shininess, specular: self.specular * (1.0 + shininess) / (1.0 + self.shininess), ..*self }
    }

    /// The specular lobe alone (Blinn–Phong, white): what one light at `irradiance` along
    /// `to_light` adds towards `view` on a surface facing `normal`. The path tracer adds the
    /// same lobe to its light samples, so that a highlight has one place and one brightness
    /// whichever integrator draws it.
    pub fn glossy(&self, normal: Vec3, view: Vec3, to_light: Vec3, irradiance: f32) -> Vec3 {
        if self.specular <= 0.0 || normal.dot(to_light) <= 0.0 {
            return Vec3::ZERO;
        }
        let h = (to_light + view).normalize_or_zero();
        Vec3::splat(self.specular * irradiance * h.dot(normal).max(0.0).powf(self.shininess))
    }
}

/// `d` mirrored about the plane with unit normal `n`.
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// The direction of unit `d` refracted through the plane with unit normal `n` facing against
/// it, `eta` = n_incident / n_transmitted; `None` on total internal reflection.
pub fn refract(d: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = -d.dot(n);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((eta * d + (eta * cos_i - cos_t) * n).normalize())
}

/// The fraction of unpolarised light a smooth dielectric reflects, for an incident cosine
/// `cos_i` (> 0) and `eta` = n_incident / n_transmitted: the mean of the s and p Fresnel
/// equations; 1 beyond the critical angle.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_s = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_p = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (r_s * r_s + r_p * r_p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rough_patch_widens_and_lowers_the_highlight() {
        let smooth = Phong::standard();
        let same = smooth.rough(1.0);
        assert_eq!((same.shininess, same.specular, same.ambient), (smooth.shininess, smooth.specular, smooth.ambient));
        let rough = smooth.rough(0.9);
        // s' = 40·0.9 / (0.9 + 40·0.1) = 7.35; the peak scaled by (1 + s') / (1 + s).
        assert!((rough.shininess - 36.0 / 4.9).abs() < 1e-4, "{}", rough.shininess);
        assert!((rough.specular - smooth.specular * (1.0 + rough.shininess) / 41.0).abs() < 1e-6);
        assert_eq!(rough.ambient, smooth.ambient);
        assert_eq!(smooth.rough(0.0).shininess, 0.0, "normals every way: no highlight's shape left");
    }

    #[test]
    fn fresnel_matches_known_values() {
        // Normal incidence: ((n - 1) / (n + 1))², 4 % for glass of index 1.5, either way.
        assert!((fresnel_dielectric(1.0, 1.0 / 1.5) - 0.04).abs() < 1e-6);
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        // Brewster's angle, atan(1.5) = 56.31°: the p part vanishes, R = R_s / 2 = 0.0739.
        let brewster = 1.5f32.atan();
        assert!((fresnel_dielectric(brewster.cos(), 1.0 / 1.5) - 0.0739).abs() < 5e-4);
        // Grazing: everything is reflected; from inside past the critical angle (41.8°) too.
        assert!(fresnel_dielectric(1e-4, 1.0 / 1.5) > 0.99);
        assert_eq!(fresnel_dielectric(43f32.to_radians().cos(), 1.5), 1.0);
        assert!(fresnel_dielectric(40f32.to_radians().cos(), 1.5) < 1.0);
        // Index matched: nothing is reflected.
        assert!(fresnel_dielectric(0.3, 1.0) < 1e-7);
    }

    #[test]
    fn refraction_obeys_snell_and_reflection_mirrors() {
        let n = Vec3::Y;
        let theta = 30f32.to_radians();
        let d = Vec3::new(theta.sin(), -theta.cos(), 0.0);
        let t = refract(d, n, 1.0 / 1.5).unwrap();
        // sin θt = sin θi / 1.5, bent towards the normal, same plane, unit length.
        assert!((t.x - theta.sin() / 1.5).abs() < 1e-6 && t.y < 0.0 && t.z == 0.0);
        assert!((t.length() - 1.0).abs() < 1e-6);
        // Back out through the same interface: the original direction.
        let back = refract(t, n, 1.5).unwrap();
        assert!((back - d).length() < 1e-5);
        // Past the critical angle from inside: none.
        let steep = Vec3::new(45f32.to_radians().sin(), -45f32.to_radians().cos(), 0.0);
        assert!(refract(steep, n, 1.5).is_none());
        assert!((reflect(d, n) - Vec3::new(d.x, -d.y, 0.0)).length() < 1e-7);
    }
}
