//! Scene files: several clouds, each placed in the world and made of its own material,
//! with lights, an environment, a camera and render settings, in TOML. `pointray render
//! scene.toml` reads one; `scenes/` has examples.
//!
//! The schema is `pointray_io::scene`. World coordinates are f64 in the file and f32 once placed: put the models near the origin
//! (a survey-coordinate scan is moved there by its `translate`).

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use glam::{DMat3, DVec3, Vec3};
use pointray::PointCloud;
use pointray::film::srgb_to_linear;
use pointray::ground::{Checker, GroundPlane};
use pointray::material::{Material, Phong};
use pointray::preprocess::PreprocessStats;
use pointray::render::{Filter, Sampler};
use pointray::shading::{Environment, Light};
use pointray::splat::scheme::SurfaceKind;
use pointray_io::scene::{
    CloudSpec, EnvironmentSpec, GridSpec, GroundSpec, IntegratorSpec, LightSpec, MaterialSpec, SceneFile, parse_scene,
};

use crate::args::{FilterArg, IntegratorArg, RenderArgs, SamplerArg, SurfaceArg, Switch};
use crate::failure;

/// A scene, loaded: one cloud of every placed point (world coordinates, origin zero), the
/// material index of each point, and the settings that replace the command line's.
pub struct Scene {
    pub cloud: PointCloud,
    pub point_materials: Vec<u8>,
    pub materials: Vec<Material>,
    pub lights: Vec<Light>,
    pub environment: Environment,
    pub ground: Option<GroundPlane>,
    /// The command line with the scene's camera and render settings put in.
    pub args: RenderArgs,
    pub points_read: usize,
    pub preprocess: PreprocessStats,
    pub load_seconds: f64,
}

/// Whether `path` names a scene file (by its `.toml` extension).
pub fn is_scene(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"))
}

/// Reads the scene at `path` and every cloud it names, preprocessed and placed.
pub fn load(path: &Path, a: &RenderArgs, quiet: bool) -> anyhow::Result<Scene> {
    let start = Instant::now();
    let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let spec = parse_scene(path, &text)?;
    let args = scene_args(path, &spec, a)?;
    let folder = path.parent().unwrap_or(Path::new("."));

    let mut placed = Vec::new();
    let (mut point_materials, mut materials) = (Vec::new(), Vec::new());
    let (mut points_read, mut preprocess) = (0, PreprocessStats::default());
    for (index, cloud) in spec.clouds.iter().enumerate() {
        let name = format!("{}: cloud {}", path.display(), index + 1);
        let (mut points, label) = match (&cloud.file, &cloud.grid) {
            (Some(file), None) => {
                let file = folder.join(file);
                let (loaded, _) = crate::commands::load(&file, quiet).with_context(|| name.clone())?;
                (loaded.cloud, file.display().to_string())
            }
            (None, Some(grid)) => (grid_cloud(grid).with_context(|| name.clone())?, format!("{name} (grid)")),
            _ => anyhow::bail!("{name}: give either `file` or `grid`"),
        };
        if let Some(color) = cloud.color {
            points.colors = Some(vec![color; points.len()]);
        }
        points_read += points.len();
        let stats =
            crate::commands::prepare_cloud(&mut points, &a.preprocess, &label, quiet).with_context(|| name.clone())?;
        preprocess.add(&stats);
        place(&mut points, cloud);
        point_materials.extend(std::iter::repeat_n(index as u8, points.len()));
        materials.push(material(&cloud.material));
        placed.push(points);
    }
    let cloud = merge(placed);
    anyhow::ensure!(
        cloud.len() <= pointray::accel::bvh::MAX_SPLATS,
        "{}: {} points is more than pointray can index",
        path.display(),
        cloud.len()
    );

    let lights = spec.lights.iter().map(light).collect();
    let ground = spec.ground.as_ref().map(ground);
    let environment = match spec.environment {
        EnvironmentSpec::Uniform { color } => Environment::Uniform { color },
        EnvironmentSpec::Sky { zenith, horizon, ground } => {
            Environment::Gradient { up: args.up.normalize(), zenith, horizon, ground }
        }
    };
    Ok(Scene {
        cloud,
        point_materials,
        materials,
        lights,
        environment,
        ground,
        args,
        points_read,
        preprocess,
        load_seconds: start.elapsed().as_secs_f64(),
    })
}

/// Flags that mean nothing beside a scene file, whose camera, lights, materials and sky are its
/// own: given, they are refused rather than silently ignored.
const SCENE_OWNS: [&str; 18] = [
    "eye",
    "look_at",
    "up",
    "fov",
    "lens_radius",
    "focus_distance",
    "view_dir",
    "distance",
    "crop_to_model",
    "light_dir",
    "light_pos",
    "light_radius",
    "light_intensity",
    "material",
    "ior",
    "sky",
    "ground",
    "demo_points",
];

/// The command line with the scene's camera and render settings put in: a render setting given
/// as a flag wins over the scene's (`--spp 1 --width 320` for a quick look); a flag of
/// [`SCENE_OWNS`] is an error.
fn scene_args(path: &Path, spec: &SceneFile, a: &RenderArgs) -> anyhow::Result<RenderArgs> {
    if let Some(flag) = SCENE_OWNS.iter().find(|id| a.given(id)) {
        let flag = flag.replace('_', "-");
        let e = anyhow::anyhow!(
            "--{flag} does not apply to a scene file: {} sets its camera, lights, materials and sky",
            path.display()
        );
        return Err(failure::usage(e));
    }
    let mut args = a.clone();
    let (c, r) = (&spec.camera, &spec.render);
    args.eye = Some(DVec3::from(c.eye));
    args.look_at = Some(DVec3::from(c.look_at));
    args.up = Vec3::from(c.up);
    args.fov = c.fov;
    args.lens_radius = c.lens_radius;
    args.focus_distance = c.focus_distance;
    macro_rules! unless_given {
        ($($field:ident = $value:expr;)*) => {
            $(if !a.given(stringify!($field)) {
                args.$field = $value;
            })*
        };
    }
    unless_given! {
        width = r.width;
        height = r.height;
        spp = r.spp;
        max_depth = r.max_depth;
        seed = r.seed;
        surface = match r.surface {
            SurfaceKind::Sj => SurfaceArg::Sj,
            SurfaceKind::Rfd => SurfaceArg::Rfd,
            SurfaceKind::Pss => SurfaceArg::Pss,
            SurfaceKind::FirstHit => SurfaceArg::FirstHit,
        };
        integrator = match r.integrator {
            IntegratorSpec::Whitted => IntegratorArg::Whitted,
            IntegratorSpec::Path => IntegratorArg::Path,
            IntegratorSpec::Ao => IntegratorArg::Ao,
            IntegratorSpec::EyeLight => IntegratorArg::EyeLight,
        };
        ao_distance = r.ao_distance;
        sampler = match r.sampler {
            Sampler::Random => SamplerArg::Random,
            Sampler::R2 => SamplerArg::R2,
        };
        filter = match r.filter {
            Filter::Box => FilterArg::Box,
            Filter::Tent => FilterArg::Tent,
        };
        tonemap = r.tonemap.into();
        exposure = r.exposure;
        no_shadows = !r.shadows;
    }
    // `lod_threshold = 0` is full detail, as `--lod off` is; `--lod` and `--lod-threshold`
    // each override their own half.
    if !a.given("lod_threshold") && r.lod_threshold > 0.0 {
        args.lod_threshold = r.lod_threshold;
    }
    if !a.given("lod") && !a.given("lod_threshold") {
        args.lod = if r.lod_threshold > 0.0 { Switch::On } else { Switch::Off };
    }
    super::commands::render::check_args(&args).map_err(|e| failure::usage(e.context(path.display().to_string())))?;
    Ok(args)
}

fn grid_cloud(g: &GridSpec) -> anyhow::Result<PointCloud> {
    anyhow::ensure!(g.size > 0.0 && g.spacing > 0.0, "grid: size and spacing must be positive");
    // In f64 first: a huge size over a tiny spacing must not overflow the count.
    let side = (g.size / g.spacing).ceil() + 1.0;
    let most = (pointray::accel::bvh::MAX_SPLATS as f64).sqrt();
    anyhow::ensure!(side <= most, "grid: {side} x {side} points is too many (at most {most:.0} a side)");
    let n = side as usize;
    let half = 0.5 * g.size;
    let mut world = Vec::with_capacity(n * n);
    let mut colors = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let (x, z) = (-half + i as f64 * g.spacing, -half + j as f64 * g.spacing);
            world.push(DVec3::new(x, 0.0, z));
            if let Some((a, b, tile)) = g.checker {
                let dark = ((x / tile).floor() + (z / tile).floor()).rem_euclid(2.0) < 1.0;
                colors.push(if dark { a } else { b });
            }
        }
    }
    let mut cloud = PointCloud::from_world_positions(&world);
    cloud.normals = Some(vec![Vec3::Y; world.len()]);
    cloud.colors = g.checker.is_some().then_some(colors);
    Ok(cloud)
}

/// The ground plane of a `[ground]` table (which `parse_scene` checked).
fn ground(spec: &GroundSpec) -> GroundPlane {
    let linear = |c: [f32; 3]| c.map(srgb_to_linear);
    GroundPlane {
        up: Vec3::from(spec.up).normalize(),
        height: spec.height as f32,
        color: linear(spec.color),
        checker: spec.checker.as_ref().map(|c| Checker { color: linear(c.color), tile: c.tile as f32 }),
        material: material(&spec.material),
    }
}

/// Moves a preprocessed cloud to its place in the world: positions, normals and radii.
fn place(points: &mut PointCloud, spec: &CloudSpec) {
    let [rx, ry, rz] = spec.rotate.map(f64::to_radians);
    let rotation = DMat3::from_rotation_z(rz) * DMat3::from_rotation_y(ry) * DMat3::from_rotation_x(rx);
    let (scale, translate, origin) = (spec.scale, DVec3::from(spec.translate), points.origin);
    for p in &mut points.positions {
        *p = (rotation * ((origin + p.as_dvec3()) * scale) + translate).as_vec3();
    }
    if let Some(normals) = &mut points.normals {
        normals.iter_mut().for_each(|n| *n = (rotation * n.as_dvec3()).normalize().as_vec3());
    }
    if let Some(radii) = &mut points.radii {
        radii.iter_mut().for_each(|r| *r *= scale as f32);
    }
    points.origin = DVec3::ZERO;
}

/// One cloud of all the placed ones; colours kept where every cloud has them, else the
/// default colour for those without.
fn merge(clouds: Vec<PointCloud>) -> PointCloud {
    let any_colors = clouds.iter().any(|c| c.colors.is_some());
    let mut all = PointCloud::default();
    let (mut normals, mut radii, mut colors) = (Vec::new(), Vec::new(), Vec::new());
    for c in clouds {
        let n = c.len();
        all.positions.extend(c.positions);
        normals.extend(c.normals.expect("preprocessed"));
        radii.extend(c.radii.expect("preprocessed"));
        if any_colors {
            let default = pointray::splat::DEFAULT_COLOR;
            colors.extend(c.colors.unwrap_or_else(|| vec![default; n]));
        }
    }
    all.normals = Some(normals);
    all.radii = Some(radii);
    all.colors = any_colors.then_some(colors);
    all
}

fn material(spec: &MaterialSpec) -> Material {
    match *spec {
        MaterialSpec::Phong { ambient, specular, shininess } => Material::Phong(Phong { ambient, specular, shininess }),
        MaterialSpec::Mirror { tint } => Material::Mirror { tint },
        MaterialSpec::Glass { ior, tint } => Material::Glass { ior, tint },
    }
}

fn light(spec: &LightSpec) -> Light {
    match *spec {
        LightSpec::Directional { direction, intensity } => {
            Light::Directional { direction: Vec3::from(direction), intensity }
        }
        LightSpec::Point { position, intensity } => {
            Light::Point { position: DVec3::from(position).as_vec3(), intensity }
        }
        LightSpec::Sphere { position, radius, intensity } => {
            Light::Sphere { center: DVec3::from(position).as_vec3(), radius, intensity }
        }
        LightSpec::Spot { position, direction, inner, outer, intensity } => Light::Spot {
            position: DVec3::from(position).as_vec3(),
            direction: Vec3::from(direction).normalize(),
            inner: inner.to_radians(),
            outer: outer.to_radians(),
            intensity,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placing_scales_then_rotates_then_translates() {
        let mut cloud = PointCloud::from_world_positions(&[DVec3::new(101.0, 0.0, 0.0)]);
        cloud.normals = Some(vec![Vec3::X]);
        cloud.radii = Some(vec![0.5]);
        let spec: CloudSpec =
            toml::from_str("file = \"x.ply\"\nscale = 2.0\nrotate = [0.0, 90.0, 0.0]\ntranslate = [0.0, 1.0, 0.0]")
                .unwrap();
        place(&mut cloud, &spec);
        // (101, 0, 0) × 2 = (202, 0, 0); 90° about y takes +x to −z; then up by 1.
        assert!((cloud.positions[0] - Vec3::new(0.0, 1.0, -202.0)).length() < 1e-3, "{:?}", cloud.positions[0]);
        assert!((cloud.normals.unwrap()[0] - Vec3::NEG_Z).length() < 1e-6);
        assert_eq!((cloud.radii.unwrap()[0], cloud.origin), (1.0, DVec3::ZERO));
    }

    #[test]
    fn a_grid_too_fine_to_count_is_refused() {
        let spec: GridSpec = toml::from_str("size = 1e30\nspacing = 1e-30").unwrap();
        assert!(grid_cloud(&spec).unwrap_err().to_string().contains("too many"));
    }

    #[test]
    fn a_ground_is_placed_and_coloured_as_written() {
        let spec: GroundSpec =
            toml::from_str("height = -0.5\nup = [0.0, 2.0, 0.0]\ncolor = [1.0, 0.5, 0.0]\nchecker = { color = [0.0, 0.0, 0.0], tile = 0.25 }")
                .unwrap();
        let g = ground(&spec);
        assert_eq!((g.up, g.height, g.checker.unwrap().tile), (Vec3::Y, -0.5, 0.25));
        assert_eq!(g.color, [1.0, srgb_to_linear(0.5), 0.0]);
    }

    /// Every flag of `render` is classified: refused beside a scene, set by the scene unless
    /// given, or applied as to any input. A new flag must be placed in one of the three.
    #[test]
    fn every_render_flag_is_refused_overridden_or_applied_beside_a_scene() {
        use clap::CommandFactory;
        // The `unless_given!` fields of `scene_args`, and the level of detail.
        let overridden = [
            "width",
            "height",
            "spp",
            "max_depth",
            "seed",
            "surface",
            "integrator",
            "ao_distance",
            "sampler",
            "filter",
            "tonemap",
            "exposure",
            "no_shadows",
            "lod_threshold",
            "lod",
        ];
        let applied = [
            "input",
            "output",
            "threads",
            "accel",
            "sj_window",
            "sj_min_coverage",
            "sj_min_coverage_facing_away",
            "region",
            "shadow_offset",
            "diffuse_spread",
            "cull",
            "sphere_from_level",
            "aov",
            "stats",
            "bench_frames",
            "bench_builds",
            "k_normals",
            "k_radius",
            "radius_scale",
            "recompute",
        ];
        let cli = crate::args::Cli::command();
        let render = cli.find_subcommand("render").expect("a render subcommand");
        let mut seen = 0;
        for arg in render.get_arguments().filter(|a| a.get_id() != "help") {
            let id = arg.get_id().as_str();
            let places = [SCENE_OWNS.contains(&id), overridden.contains(&id), applied.contains(&id)];
            assert_eq!(places.iter().filter(|&&p| p).count(), 1, "--{id} must be in exactly one list: {places:?}");
            seen += 1;
        }
        assert_eq!(seen, SCENE_OWNS.len() + overridden.len() + applied.len(), "a listed flag does not exist");
    }

    /// The example scenes follow the schema (rendering them needs the shared data).
    #[test]
    fn example_scenes_parse() {
        let folder = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
        let mut parsed = 0;
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if is_scene(&path) {
                let text = std::fs::read_to_string(&path).unwrap();
                let scene = parse_scene(&path, &text).unwrap_or_else(|e| panic!("{e}"));
                assert!(!scene.clouds.is_empty());
                parsed += 1;
            }
        }
        assert!(parsed >= 1, "no scene in {}", folder.display());
    }
}
