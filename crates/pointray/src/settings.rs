//! Render settings: every option of a render, each with one type and one default, by the names
//! the command line's flags and the Python package's keywords use. [`crate::scene`] resolves
//! them against a scene into a camera and a [`RenderConfig`](crate::render::RenderConfig).

use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

use crate::accel::NodeBounds;
use crate::camera::Region;
use crate::clip::{ClipBox, ClipPlane};
use crate::color_by::ColorBy;
use crate::film::{MAX_PIXELS, ToneCurve, ToneMap};
use crate::frame::Aov;
use crate::material::Material;
use crate::render::{Filter, Integrator, Sampler};
use crate::splat::scheme::{SurfaceKind, SurfaceScheme};

/// The accelerator a scene is built with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum AccelKind {
    /// The multiresolution BVH.
    #[default]
    Bvh,
    /// The SAH kd-tree with level of detail (no normal cones: culling and spheres apply to
    /// the BVH only).
    Kdtree,
    /// Brute force, which tests every splat (the reference for tests).
    Brute,
}

/// Normal-cone backface culling of camera rays (the BVH's).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Cull {
    /// On when rays from around the model meet almost no back faces first (a closed,
    /// consistently oriented surface).
    Auto,
    On,
    /// Front-to-back traversal already skips what lies behind the first hit, and culling
    /// measured slower (docs/multires.md).
    #[default]
    Off,
}

/// How the camera projects the scene onto the film.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Projection {
    #[default]
    Perspective,
    /// Parallel rays along the view: plans, elevations and façades, at the scale the
    /// perspective view has at the point it looks at.
    Orthographic,
}

/// A framing by name, turned with the data's up axis (a z-up survey's front is seen from the
/// south, its side from the east, its top with north up).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum ViewPreset {
    /// Looking down the up axis: a plan (with `projection` orthographic, to scale).
    Top,
    /// Square on to the front: an elevation.
    Front,
    /// Square on to the right side.
    Side,
    /// From the front, the right and above alike.
    Iso,
}

impl ViewPreset {
    /// The direction from the model's centre to the camera for +y up (+z the front).
    pub fn direction_for_y_up(self) -> Vec3 {
        match self {
            ViewPreset::Top => Vec3::Y,
            ViewPreset::Front => Vec3::Z,
            ViewPreset::Side => Vec3::X,
            ViewPreset::Iso => Vec3::ONE.normalize(),
        }
    }
}

/// What the points of a lone cloud are made of (a scene file names its own materials).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum MaterialPreset {
    /// Lit by the lights, with shadows.
    #[default]
    Phong,
    Mirror,
    /// Fresnel reflection and refraction, of index `ior`.
    Glass,
}

impl MaterialPreset {
    pub fn material(self, ior: f32) -> Material {
        match self {
            MaterialPreset::Phong => Material::standard(),
            MaterialPreset::Mirror => Material::Mirror { tint: [0.9; 3] },
            MaterialPreset::Glass => Material::Glass { ior, tint: [1.0; 3] },
        }
    }
}

/// `lod_threshold`'s default, in pixels: subtrees up to one pixel across are drawn as their
/// representative. On the dragon at 16 diagonals that is 1.8× faster than full detail and
/// closer to the converged image (24.0 dB against 23.3 dB at 1 spp, docs/multires.md D); τ = 1
/// is 2.6× faster but 1 dB further off.
pub const DEFAULT_LOD_THRESHOLD: f32 = 0.5;

/// Every option of a render. Positions (`eye`, `look_at`, `light_pos`) are in the file's
/// coordinates; a scene file's clouds are placed in world coordinates. The light, material,
/// sky and ground options dress a lone cloud: a scene file brings its own.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Settings {
    pub width: u32,
    pub height: u32,
    pub accel: AccelKind,
    /// Bounding volumes of the BVH: boxes, spheres from a level down, or chosen per node.
    pub sphere_from_level: NodeBounds,
    pub surface: SurfaceKind,
    /// SJ and RFD interpolation window, in radii of the first disk hit (default: the scheme's).
    pub sj_window: Option<f32>,
    pub sj_min_coverage: f32,
    pub sj_min_coverage_facing_away: f32,
    /// Samples per pixel.
    pub spp: u32,
    pub seed: u64,
    pub sampler: Sampler,
    pub filter: Filter,
    pub tonemap: ToneCurve,
    /// Stops: radiance × 2^exposure before the tone map.
    pub exposure: f32,

    pub projection: Projection,
    pub eye: Option<DVec3>,
    pub look_at: Option<DVec3>,
    /// The camera's up, which the sky and the ground take too (default: the data's up, as its
    /// format gives it: +z for LAS and LAZ; else +y).
    pub up: Option<Vec3>,
    /// Vertical field of view, degrees.
    pub fov: f32,
    pub lens_radius: f32,
    pub focus_distance: Option<f32>,
    /// Without `eye`: the direction from the model's centre to the camera (default: the
    /// scene's view)
    pub view_dir: Option<Vec3>,
    /// A named framing instead of `view_dir` (turned with the up axis).
    pub view: Option<ViewPreset>,
    /// and the distance, in bounding-box diagonals.
    pub distance: Option<f32>,
    /// Only this rectangle of the frame.
    pub region: Option<Region>,
    /// Only the pixels inside the model's projected bounding box.
    pub crop_to_model: bool,

    pub light_dir: Option<Vec3>,
    pub light_pos: Option<DVec3>,
    pub light_radius: Option<f32>,
    pub light_intensity: f32,
    pub material: MaterialPreset,
    pub ior: f32,
    pub sky: bool,
    /// An HDR panorama (equirectangular `.hdr` or `.exr`) around a lone cloud: what rays that
    /// leave see, and the light (see [`crate::env_map`]; no headlight unless `light_dir` or
    /// `light_pos` adds a light). The file is read by the front end
    /// (`pointray_io::source::environment_map`) and handed to [`crate::Scene::set_environment_map`].
    pub env_map: Option<std::path::PathBuf>,
    /// Degrees the map turns about the up axis, anticlockwise seen from above.
    pub env_rotation: f32,
    pub ground: bool,
    /// What the points' colours show (a scene is built with it).
    pub color_by: ColorBy,
    /// Draw only the points of these ASPRS classes (all, if none; a scene is built with it).
    pub classes: Option<Vec<u8>>,
    /// Leave out the points of these classes (a scene is built with it).
    pub exclude_classes: Vec<u8>,
    /// Eye-dome lighting's strength ([`crate::eye_dome`]): darkens where neighbours are nearer,
    /// Potree's depth cue; 1 is Potree's default, 0 off.
    pub edl: f32,
    /// Keep only the points inside this box (file coordinates; a scene is built with it).
    pub clip_box: Option<ClipBox>,
    /// Keep only the points on the kept side of each plane (a scene is built with them).
    pub clip_planes: Vec<ClipPlane>,

    pub integrator: Integrator,
    /// Ambient occlusion's reach (default: a tenth of the bounding-box diagonal).
    pub ao_distance: Option<f32>,
    pub diffuse_spread: f32,
    pub max_depth: u32,
    pub shadows: bool,
    /// Shadow- and secondary-ray start offset, in splat radii.
    pub shadow_offset: f32,

    /// Level-of-detail threshold τ in pixels; 0 is full detail.
    pub lod_threshold: f32,
    /// Level of detail as a prefilter: each camera ray gathers what its pixel's beam covers
    /// (`splat::footprint`) where its footprint is wide enough for level of detail.
    pub prefilter: bool,
    pub cull: Cull,
    /// The channels recorded beside the image.
    pub aovs: Vec<Aov>,
    /// Count the traversal's work ([`crate::stats::RenderStats::traversal`]), at a small cost.
    pub count_work: bool,
}

impl Default for Settings {
    fn default() -> Self {
        let sj = SurfaceScheme::sj();
        Self {
            width: 1024,
            height: 1024,
            accel: AccelKind::Bvh,
            sphere_from_level: NodeBounds::Boxes,
            surface: SurfaceKind::Sj,
            sj_window: None,
            sj_min_coverage: sj.min_coverage,
            sj_min_coverage_facing_away: sj.min_coverage_facing_away,
            spp: 1,
            seed: 0,
            sampler: Sampler::R2,
            filter: Filter::Box,
            tonemap: ToneCurve::Clamp,
            exposure: 0.0,
            projection: Projection::Perspective,
            eye: None,
            look_at: None,
            up: None,
            fov: 60.0,
            lens_radius: 0.0,
            focus_distance: None,
            view_dir: None,
            view: None,
            distance: None,
            region: None,
            crop_to_model: false,
            light_dir: None,
            light_pos: None,
            light_radius: None,
            light_intensity: 1.0,
            material: MaterialPreset::Phong,
            ior: 1.5,
            sky: false,
            env_map: None,
            env_rotation: 0.0,
            ground: false,
            color_by: ColorBy::Auto,
            classes: None,
            exclude_classes: Vec::new(),
            edl: 0.0,
            clip_box: None,
            clip_planes: Vec::new(),
            integrator: Integrator::Whitted,
            ao_distance: None,
            // The path tracer's bounced rays: 1.23–1.31× faster on the dragon, 54 dB from full
            // detail, where the Monte Carlo noise itself is 40 dB (docs/path-lod.md).
            diffuse_spread: 0.1,
            max_depth: 5,
            shadows: true,
            shadow_offset: 1.0,
            lod_threshold: DEFAULT_LOD_THRESHOLD,
            prefilter: false,
            cull: Cull::Off,
            aovs: Vec::new(),
            count_work: false,
        }
    }
}

/// A setting out of range: the option's name (as in [`Settings`]) and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{option} {problem}")]
pub struct SettingsError {
    pub option: &'static str,
    pub problem: String,
}

impl SettingsError {
    pub fn new(option: &'static str, problem: impl Into<String>) -> Self {
        Self { option, problem: problem.into() }
    }
}

impl Settings {
    /// Every number in range; the first that is not, named.
    pub fn check(&self) -> Result<(), SettingsError> {
        let check =
            |ok: bool, option, problem: &str| if ok { Ok(()) } else { Err(SettingsError::new(option, problem)) };
        let finite = |v: f32| v.is_finite();
        let positive = |v: Option<f32>| v.is_none_or(|v| v > 0.0 && v.is_finite());
        check(self.width > 0, "width", "must be positive")?;
        check(self.height > 0, "height", "must be positive")?;
        let pixels = u64::from(self.width) * u64::from(self.height);
        if pixels > MAX_PIXELS {
            let (w, h) = (self.width, self.height);
            return Err(SettingsError::new(
                "width",
                format!("x height: a {w}x{h} frame is too large (at most {MAX_PIXELS} pixels)"),
            ));
        }
        check(self.fov > 0.0 && self.fov < 180.0, "fov", "must be between 0 and 180 degrees")?;
        check(!(self.sky && self.env_map.is_some()), "env_map", "and sky: give one of them")?;
        check(finite(self.env_rotation), "env_rotation", "must be a finite number of degrees")?;
        check(positive(self.distance), "distance", "must be positive")?;
        check(self.spp >= 1, "spp", "must be at least 1")?;
        check(self.sj_window.is_none_or(|w| w >= 0.0 && finite(w)), "sj_window", "must be a non-negative number")?;
        check(self.sj_min_coverage >= 0.0 && finite(self.sj_min_coverage), "sj_min_coverage", "must be non-negative")?;
        let away = self.sj_min_coverage_facing_away;
        check(away >= 0.0 && finite(away), "sj_min_coverage_facing_away", "must be non-negative")?;
        check(self.shadow_offset >= 0.0 && finite(self.shadow_offset), "shadow_offset", "must be non-negative")?;
        let tau = self.lod_threshold;
        check(tau >= 0.0 && finite(tau), "lod_threshold", "must be a non-negative number (0: full detail)")?;
        let prefilter_integrator = matches!(self.integrator, Integrator::Whitted | Integrator::EyeLight);
        check(
            !self.prefilter || prefilter_integrator,
            "prefilter",
            "applies to the whitted and eye-light integrators",
        )?;
        check(!self.prefilter || tau > 0.0, "prefilter", "needs level of detail (a threshold above 0)")?;
        // A sample's beam is its share of the pixel: four of them gathered the dragon at 16
        // diagonals 6× slower than one beam, and further from the converged image (32.9 dB
        // against 34.7).
        check(!self.prefilter || self.spp == 1, "prefilter", "is one ray a pixel (--spp 1): it replaces samples")?;
        check(self.ior > 0.0 && finite(self.ior), "ior", "must be a positive number")?;
        check(self.lens_radius >= 0.0 && finite(self.lens_radius), "lens_radius", "must be non-negative")?;
        let lens = self.lens_radius == 0.0 || self.projection == Projection::Perspective;
        check(lens, "lens_radius", "needs a perspective camera (an orthographic one has no lens)")?;
        check(positive(self.ao_distance), "ao_distance", "must be positive")?;
        check(positive(self.focus_distance), "focus_distance", "must be positive")?;
        check(self.diffuse_spread >= 0.0 && finite(self.diffuse_spread), "diffuse_spread", "must be non-negative")?;
        let radius = self.light_radius.is_none_or(|r| r >= 0.0 && finite(r));
        check(radius, "light_radius", "must be a non-negative number")?;
        check(self.light_radius.is_none() || self.light_pos.is_some(), "light_radius", "needs light_pos")?;
        check(self.light_intensity >= 0.0 && finite(self.light_intensity), "light_intensity", "must be non-negative")?;
        check(self.max_depth <= 64, "max_depth", "must be at most 64")?;
        check(self.classes.as_ref().is_none_or(|c| !c.is_empty()), "classes", "must name at least one class")?;
        crate::clip::check(self.clip_box.as_ref(), &self.clip_planes)?;
        check(self.edl >= 0.0 && finite(self.edl), "edl", "must be a non-negative strength (0: off)")?;
        let most = ToneMap::MAX_EXPOSURE;
        if self.exposure.is_nan() || self.exposure.abs() > most {
            return Err(SettingsError::new("exposure", format!("must be between -{most} and {most} stops")));
        }
        let direction = |v: Option<Vec3>| v.is_none_or(|v| v.is_finite() && v.length_squared() > 0.0);
        check(direction(self.up), "up", "must not be the zero vector")?;
        check(direction(self.view_dir), "view_dir", "must not be the zero vector")?;
        check(direction(self.light_dir), "light_dir", "must not be the zero vector")?;
        check(self.light_dir.is_none() || self.light_pos.is_none(), "light_dir", "and light_pos exclude each other")?;
        check(self.view.is_none() || self.view_dir.is_none(), "view", "and view_dir exclude each other")?;
        check(self.view.is_none() || self.eye.is_none(), "view", "and eye exclude each other")?;
        match (self.eye, self.look_at) {
            (Some(eye), Some(target)) => check(eye != target, "eye", "and look_at must differ")?,
            (None, None) => {}
            _ => return Err(SettingsError::new("eye", "and look_at go together")),
        }
        if let Some(r) = self.region {
            let ok = r.x0 < r.x1 && r.y0 < r.y1;
            check(ok, "region", "must not be empty: need x0 < x1 and y0 < y1")?;
            check(!self.crop_to_model, "region", "and crop_to_model exclude each other")?;
        }
        Ok(())
    }

    /// The surface scheme with these settings' window and coverage thresholds (first-hit
    /// blends nothing, so it keeps no coverage threshold).
    pub fn scheme(&self) -> SurfaceScheme {
        let defaults = SurfaceScheme::of_kind(self.surface);
        let first_hit = self.surface == SurfaceKind::FirstHit;
        SurfaceScheme {
            window: self.sj_window.unwrap_or(defaults.window),
            min_coverage: if first_hit { 0.0 } else { self.sj_min_coverage },
            min_coverage_facing_away: if first_hit { 0.0 } else { self.sj_min_coverage_facing_away },
            ..defaults
        }
    }

    pub fn tone_map(&self) -> ToneMap {
        ToneMap { exposure: self.exposure, curve: self.tonemap }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_pass_their_own_check() {
        assert_eq!(Settings::default().check(), Ok(()));
    }

    #[test]
    fn a_bad_setting_is_named() {
        let bad = |s: Settings| s.check().unwrap_err().option;
        assert_eq!(bad(Settings { spp: 0, ..Settings::default() }), "spp");
        assert_eq!(bad(Settings { lens_radius: -1.0, ..Settings::default() }), "lens_radius");
        assert_eq!(bad(Settings { up: Some(Vec3::ZERO), ..Settings::default() }), "up");
        assert_eq!(bad(Settings { exposure: f32::NAN, ..Settings::default() }), "exposure");
        assert_eq!(bad(Settings { eye: Some(DVec3::ONE), ..Settings::default() }), "eye");
        let huge = Settings { width: u32::MAX, height: u32::MAX, ..Settings::default() };
        assert!(huge.check().unwrap_err().to_string().contains("too large"));
    }

    #[test]
    fn settings_read_from_names_and_refuse_unknown_ones() {
        let s: Settings = serde_json::from_str(r#"{"spp": 4, "surface": "first-hit", "integrator": "ao"}"#).unwrap();
        assert_eq!((s.spp, s.surface, s.integrator, s.width), (4, SurfaceKind::FirstHit, Integrator::Ao, 1024));
        let e = serde_json::from_str::<Settings>(r#"{"spp": 4, "sp": 1}"#).unwrap_err();
        assert!(e.to_string().contains("unknown field `sp`"), "{e}");
    }
}
