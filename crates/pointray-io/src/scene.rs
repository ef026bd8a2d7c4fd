//! Scene files (TOML): the schema of `pointray render scene.toml`, parsed here with the other
//! file formats; the command line loads the clouds a scene names and places them
//! (`scenes/README.md` documents every key).

use std::path::{Path, PathBuf};

use pointray::render::{Filter, Sampler};
use pointray::splat::scheme::SurfaceKind;
use serde::Deserialize;

use crate::IoError;

/// Parses a scene file's text; errors name `path` and the line and column.
pub fn parse_scene(path: &Path, text: &str) -> Result<SceneFile, IoError> {
    let scene: SceneFile = toml::from_str(text).map_err(|e| IoError::invalid(path, e.to_string()))?;
    if scene.clouds.is_empty() {
        return Err(IoError::invalid(path, "the scene has no [[cloud]]"));
    }
    if scene.clouds.len() > 256 {
        return Err(IoError::invalid(path, "at most 256 clouds"));
    }
    Ok(scene)
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
    pub integrator: IntegratorSpec,
    pub sampler: Sampler,
    pub filter: Filter,
    /// `integrator = "ao"`: how far a surface looks for what occludes it (default: a tenth of
    /// the scene's bounding-box diagonal).
    pub ao_distance: Option<f32>,
    pub lod_threshold: f32,
    pub shadows: bool,
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
            integrator: IntegratorSpec::Whitted,
            sampler: Sampler::R2,
            filter: Filter::Box,
            ao_distance: None,
            lod_threshold: 0.5,
            shadows: true,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum IntegratorSpec {
    Whitted,
    Path,
    Ao,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "kebab-case")]
pub enum EnvironmentSpec {
    Uniform { color: [f32; 3] },
    Sky { zenith: [f32; 3], horizon: [f32; 3], ground: [f32; 3] },
}

impl Default for EnvironmentSpec {
    fn default() -> Self {
        EnvironmentSpec::Sky { zenith: [0.18, 0.32, 0.62], horizon: [0.75, 0.82, 0.90], ground: [0.25, 0.24, 0.22] }
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

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "kebab-case")]
pub enum MaterialSpec {
    #[default]
    Phong,
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

fn white() -> [f32; 3] {
    [1.0; 3]
}

fn glass_ior() -> f32 {
    1.5
}
