//! Scene files (TOML): the schema of `pointray render scene.toml`, parsed here with the other
//! file formats (`scenes/README.md` documents every key); [`crate::source`] loads the clouds
//! a scene names and places them.

use std::path::{Path, PathBuf};

use pointray::camera_path::{Animation, Keyframe};
use pointray::film::{MAX_PIXELS, ToneCurve, ToneMap};
use pointray::material::Phong;
use pointray::render::{Filter, Integrator, Sampler};
use pointray::splat::scheme::SurfaceKind;
use serde::Deserialize;

use crate::IoError;

/// Parses a scene file's text; errors name `path` and the line and column.
pub fn parse_scene(path: &Path, text: &str) -> Result<SceneFile, IoError> {
    let scene: SceneFile = toml::from_str(text).map_err(|e| IoError::invalid(path, e.to_string()))?;
    scene.check().map_err(|message| IoError::invalid(path, message))?;
    Ok(scene)
}

/// Every number in range, named by its table and key when it is not: what TOML's types
/// cannot say (a zero direction, a negative intensity, a NaN).
impl SceneFile {
    fn check(&self) -> Result<(), String> {
        if self.clouds.is_empty() {
            return Err("the scene has no [[cloud]]".into());
        }
        if self.clouds.len() > 256 {
            return Err("at most 256 clouds".into());
        }
        let c = &self.camera;
        finite_points("[camera] eye", &[c.eye])?;
        finite_points("[camera] look_at", &[c.look_at])?;
        ensure(c.eye != c.look_at, "[camera]: `eye` and `look_at` must differ")?;
        nonzero_direction("[camera] up", c.up)?;
        ensure(c.fov > 0.0 && c.fov < 180.0, "[camera] fov: must be between 0 and 180 degrees")?;
        ensure(c.lens_radius >= 0.0 && c.lens_radius.is_finite(), "[camera] lens_radius: must not be negative")?;
        ensure(positive(c.focus_distance), "[camera] focus_distance: must be positive")?;
        let r = &self.render;
        ensure(r.width > 0 && r.height > 0, "[render] width and height: must be positive")?;
        ensure(r.spp >= 1, "[render] spp: must be at least 1")?;
        ensure(r.max_depth <= 64, "[render] max_depth: must be at most 64")?;
        ensure(r.edl >= 0.0 && r.edl.is_finite(), "[render] edl: must be a non-negative strength")?;
        let pixels = u64::from(r.width) * u64::from(r.height);
        ensure(pixels <= MAX_PIXELS, &format!("[render] width and height: at most {MAX_PIXELS} pixels"))?;
        let most = ToneMap::MAX_EXPOSURE;
        ensure(r.exposure.abs() <= most, &format!("[render] exposure: must be between -{most} and {most} stops"))?;
        ensure(positive(r.ao_distance), "[render] ao_distance: must be positive")?;
        let tau = r.lod_threshold;
        ensure(tau >= 0.0 && tau.is_finite(), "[render] lod_threshold: must not be negative (0: full detail)")?;
        match &self.environment {
            &EnvironmentSpec::Uniform { color } => colors("[environment] color", &[color], f32::MAX)?,
            &EnvironmentSpec::Sky { zenith, horizon, ground } => {
                colors("[environment] zenith, horizon and ground", &[zenith, horizon, ground], f32::MAX)?
            }
            EnvironmentSpec::Map { rotation, .. } => {
                ensure(rotation.is_finite(), "[environment] rotation: must be a finite number of degrees")?
            }
        }
        for (i, light) in self.lights.iter().enumerate() {
            light.check().map_err(|e| format!("[[light]] {}: {e}", i + 1))?;
        }
        self.animation()?;
        if let Some(g) = &self.ground {
            nonzero_direction("[ground] up", g.up)?;
            ensure((g.height as f32).is_finite(), "[ground] height: must be a finite 32-bit number")?;
            let tile = g.checker.as_ref().map(|c| c.tile);
            ground_colors(g.color, g.checker.as_ref().map(|c| c.color), tile).map_err(|e| format!("[ground]: {e}"))?;
            g.material.check().map_err(|e| format!("[ground] material: {e}"))?;
            // Glass would make the half-space below a glass body, which the path's one inside
            // flag cannot tell from the clouds' glass.
            let glass = matches!(g.material, MaterialSpec::Glass { .. });
            ensure(!glass, "[ground] material: may be phong or mirror, not glass")?;
        }
        for (i, cloud) in self.clouds.iter().enumerate() {
            let name = format!("[[cloud]] {}", i + 1);
            ensure(cloud.scale > 0.0 && cloud.scale.is_finite(), &format!("{name}: scale must be positive"))?;
            finite_points(&format!("{name}: rotate and translate"), &[cloud.rotate, cloud.translate])?;
            if let Some(color) = cloud.color {
                colors(&format!("{name} color"), &[color], 1.0)?;
            }
            cloud.material.check().map_err(|e| format!("{name} material: {e}"))?;
            if let Some(grid) = &cloud.grid {
                let [a, b] = grid.checker.map_or([[0.0; 3]; 2], |(a, b, _)| [a, b]);
                ground_colors(a, Some(b), grid.checker.map(|(.., tile)| tile))
                    .map_err(|e| format!("{name} grid: {e}"))?;
            }
        }
        Ok(())
    }
}

impl LightSpec {
    fn check(&self) -> Result<(), String> {
        let intensity = match *self {
            LightSpec::Directional { direction, intensity } => {
                nonzero_direction("direction", direction)?;
                intensity
            }
            LightSpec::Point { position, intensity } => {
                finite_points("position", &[position])?;
                intensity
            }
            LightSpec::Sphere { position, radius, intensity } => {
                finite_points("position", &[position])?;
                ensure(radius >= 0.0 && radius.is_finite(), "radius: must not be negative")?;
                intensity
            }
            LightSpec::Spot { position, direction: axis, inner, outer, intensity } => {
                finite_points("position", &[position])?;
                nonzero_direction("direction", axis)?;
                let angle = |a: f32| (0.0..=180.0).contains(&a);
                ensure(angle(inner) && angle(outer), "inner and outer: must be between 0 and 180 degrees")?;
                intensity
            }
        };
        ensure(intensity >= 0.0 && intensity.is_finite(), "intensity: must not be negative")
    }
}

impl MaterialSpec {
    fn check(&self) -> Result<(), String> {
        match *self {
            MaterialSpec::Phong { ambient, specular, shininess } => {
                ensure((0.0..=1.0).contains(&ambient), "ambient: must be between 0 and 1")?;
                ensure(specular >= 0.0 && specular.is_finite(), "specular: must not be negative")?;
                ensure(shininess > 0.0 && shininess.is_finite(), "shininess: must be positive")
            }
            MaterialSpec::Mirror { tint } => colors("tint", &[tint], 1.0),
            MaterialSpec::Glass { ior, tint } => {
                ensure(ior > 0.0 && ior.is_finite(), "ior: must be positive")?;
                colors("tint", &[tint], 1.0)
            }
        }
    }
}

fn ensure(ok: bool, message: &str) -> Result<(), String> {
    if ok { Ok(()) } else { Err(message.to_string()) }
}

fn positive(value: Option<f32>) -> bool {
    value.is_none_or(|v| v > 0.0 && v.is_finite())
}

fn finite_points(key: &str, points: &[[f64; 3]]) -> Result<(), String> {
    ensure(points.iter().flatten().all(|v| v.is_finite()), &format!("{key}: must be finite"))
}

/// A direction that normalises to a unit vector (not zero, nor so small that its length
/// underflows, nor infinite).
fn nonzero_direction(key: &str, v: [f32; 3]) -> Result<(), String> {
    ensure(glam::Vec3::from(v).try_normalize().is_some(), &format!("{key}: must be a non-zero direction"))
}

/// Colours between 0 and `most` in every channel.
fn colors(key: &str, colors: &[[f32; 3]], most: f32) -> Result<(), String> {
    let ok = colors.iter().flatten().all(|&c| (0.0..=most).contains(&c));
    let range = if most == 1.0 { "between 0 and 1" } else { "finite and not negative" };
    ensure(ok, &format!("{key}: every channel must be {range}"))
}

fn ground_colors(color: [f32; 3], second: Option<[f32; 3]>, tile: Option<f64>) -> Result<(), String> {
    colors("colors", &[color, second.unwrap_or(color)], 1.0)?;
    // Used as f32: a tile must stay positive and finite there too.
    let fits = |t: f64| t > 0.0 && (t as f32) > 0.0 && (t as f32).is_finite();
    ensure(tile.is_none_or(fits), "the checker's `tile` must be a positive 32-bit number")
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub camera: CameraSpec,
    #[serde(default)]
    pub render: RenderSpec,
    #[serde(default)]
    pub environment: EnvironmentSpec,
    #[serde(default, rename = "light")]
    pub lights: Vec<LightSpec>,
    pub ground: Option<GroundSpec>,
    #[serde(rename = "cloud")]
    pub clouds: Vec<CloudSpec>,
    pub animation: Option<AnimationSpec>,
}

/// `[animation]`: `frames` views, round the camera's (`orbit = true`, the turntable about its
/// look-at point) or along `[[animation.keyframe]]`s (two or more: eye, look_at, and fov,
/// the camera's by default), as `pointray::camera_path` passes through them.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnimationSpec {
    pub frames: u32,
    #[serde(default)]
    pub orbit: bool,
    #[serde(default)]
    pub keyframe: Vec<KeyframeSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyframeSpec {
    pub eye: [f64; 3],
    pub look_at: [f64; 3],
    pub fov: Option<f32>,
}

impl SceneFile {
    /// The animation `[animation]` says, checked (none without the table).
    pub fn animation(&self) -> Result<Option<Animation>, String> {
        let Some(a) = &self.animation else { return Ok(None) };
        let animation = match (a.orbit, a.keyframe.is_empty()) {
            (true, true) => Animation::orbit(a.frames),
            (false, true) => return Err("[animation]: give orbit = true or two [[animation.keyframe]]s or more".into()),
            (true, false) => return Err("[animation]: give orbit = true or [[animation.keyframe]]s, not both".into()),
            (false, false) => {
                let key = |k: &KeyframeSpec| Keyframe {
                    eye: k.eye.into(),
                    look_at: k.look_at.into(),
                    fov: k.fov.unwrap_or(self.camera.fov),
                };
                Animation::path(a.keyframe.iter().map(key).collect(), a.frames)
            }
        };
        animation.map(Some).map_err(|e| format!("[animation] {e}"))
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub eye: [f64; 3],
    pub look_at: [f64; 3],
    #[serde(default = "y_up")]
    pub up: [f32; 3],
    /// Vertical field of view, degrees.
    #[serde(default = "default_fov")]
    pub fov: f32,
    /// Depth of field: the lens radius (0: everything sharp)
    #[serde(default)]
    pub lens_radius: f32,
    /// and the distance in focus (default: to `look_at`).
    pub focus_distance: Option<f32>,
}

fn y_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

fn default_fov() -> f32 {
    40.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderSpec {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub max_depth: u32,
    pub seed: u64,
    pub surface: SurfaceKind,
    pub integrator: Integrator,
    pub sampler: Sampler,
    pub filter: Filter,
    /// How a PNG shows radiance (`clamp` or `filmic`) and its exposure in stops.
    pub tonemap: ToneCurve,
    pub exposure: f32,
    /// `integrator = "ao"`: how far a surface looks for what occludes it (default: a tenth of
    /// the scene's bounding-box diagonal).
    pub ao_distance: Option<f32>,
    pub lod_threshold: f32,
    /// Level of detail as a prefilter (`--prefilter`; one ray a pixel: `spp = 1`).
    pub prefilter: bool,
    pub shadows: bool,
    /// What the points' colours show (`auto`, `rgb`, `intensity`, `classification`, ...).
    pub color_by: pointray::color_by::ColorBy,
    /// Eye-dome lighting's strength (0 off).
    pub edl: f32,
}

impl Default for RenderSpec {
    fn default() -> Self {
        Self {
            width: 800,
            height: 600,
            spp: 4,
            max_depth: 5,
            seed: 1,
            surface: SurfaceKind::Sj,
            integrator: Integrator::Whitted,
            sampler: Sampler::R2,
            filter: Filter::Box,
            tonemap: ToneCurve::Clamp,
            exposure: 0.0,
            ao_distance: None,
            lod_threshold: 0.5,
            prefilter: false,
            shadows: true,
            color_by: pointray::color_by::ColorBy::Auto,
            edl: 0.0,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "kebab-case")]
pub enum EnvironmentSpec {
    Uniform {
        color: [f32; 3],
    },
    Sky {
        zenith: [f32; 3],
        horizon: [f32; 3],
        ground: [f32; 3],
    },
    /// An HDR panorama (`.hdr` or `.exr`, relative to the scene file), turned `rotation`
    /// degrees about the camera's up.
    Map {
        file: std::path::PathBuf,
        #[serde(default)]
        rotation: f32,
    },
}

impl Default for EnvironmentSpec {
    fn default() -> Self {
        let [zenith, horizon, ground] = pointray::shading::SKY;
        EnvironmentSpec::Sky { zenith, horizon, ground }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "kebab-case")]
pub enum LightSpec {
    /// `direction` points towards the light.
    Directional {
        direction: [f32; 3],
        intensity: f32,
    },
    Point {
        position: [f64; 3],
        intensity: f32,
    },
    Sphere {
        position: [f64; 3],
        radius: f32,
        intensity: f32,
    },
    /// A cone of light around `direction` (from the light): full within `inner` degrees of
    /// the axis, none beyond `outer`.
    Spot {
        position: [f64; 3],
        direction: [f32; 3],
        inner: f32,
        outer: f32,
        intensity: f32,
    },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CloudSpec {
    /// A point-cloud file, relative to the scene file; or, instead, `grid`.
    pub file: Option<PathBuf>,
    pub grid: Option<GridSpec>,
    /// Applied in this order: scale, rotations about x, y and z (degrees), translation.
    #[serde(default = "one")]
    pub scale: f64,
    #[serde(default)]
    pub rotate: [f64; 3],
    #[serde(default)]
    pub translate: [f64; 3],
    #[serde(default)]
    pub material: MaterialSpec,
    /// One colour (sRGB, 0–1) for every point, instead of the file's.
    pub color: Option<[f32; 3]>,
}

fn one() -> f64 {
    1.0
}

/// A square grid of points at y = 0, normals up (+y): a floor made of splats.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    pub size: f64,
    pub spacing: f64,
    /// Two colours alternating in squares of `tile`.
    #[serde(default)]
    pub checker: Option<([f32; 3], [f32; 3], f64)>,
}

/// The analytic ground plane `{p : p·up = height}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroundSpec {
    #[serde(default)]
    pub height: f64,
    #[serde(default = "y_up")]
    pub up: [f32; 3],
    /// sRGB, 0–1.
    #[serde(default = "ground_color")]
    pub color: [f32; 3],
    /// Squares of side `tile` alternating between `color` and this `color`.
    pub checker: Option<CheckerSpec>,
    #[serde(default)]
    pub material: MaterialSpec,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CheckerSpec {
    pub color: [f32; 3],
    pub tile: f64,
}

fn ground_color() -> [f32; 3] {
    [0.8; 3]
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "kebab-case")]
pub enum MaterialSpec {
    /// Ambient + Lambert diffuse + a white specular lobe (Whitted; the path tracer takes the
    /// diffuse part): `ambient` of the albedo shows unlit, `specular` is the lobe's weight and
    /// `shininess` its exponent (higher: a smaller, sharper highlight).
    Phong {
        #[serde(default = "phong_ambient")]
        ambient: f32,
        #[serde(default = "phong_specular")]
        specular: f32,
        #[serde(default = "phong_shininess")]
        shininess: f32,
    },
    Mirror {
        #[serde(default = "white")]
        tint: [f32; 3],
    },
    Glass {
        #[serde(default = "glass_ior")]
        ior: f32,
        #[serde(default = "white")]
        tint: [f32; 3],
    },
}

impl Default for MaterialSpec {
    fn default() -> Self {
        MaterialSpec::Phong { ambient: phong_ambient(), specular: phong_specular(), shininess: phong_shininess() }
    }
}

fn phong_ambient() -> f32 {
    Phong::standard().ambient
}

fn phong_specular() -> f32 {
    Phong::standard().specular
}

fn phong_shininess() -> f32 {
    Phong::standard().shininess
}

fn white() -> [f32; 3] {
    [1.0; 3]
}

fn glass_ior() -> f32 {
    1.5
}
