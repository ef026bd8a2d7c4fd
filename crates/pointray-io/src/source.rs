//! What a render draws, from files: a point cloud read and preprocessed, or a scene file's
//! clouds each read, preprocessed and placed in the world with their materials, lights and
//! settings. The result is the library's [`SceneParts`], ready for [`pointray::Scene::build`].
//!
//! World coordinates are f64 in a scene file and f32 once placed: put the models near the
//! origin (a survey-coordinate scan is moved there by its `translate`).

use pointray::math::Aabb;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::{DMat3, DVec3, Vec3};
use pointray::PointCloud;
use pointray::color::srgb_to_linear;
use pointray::env_map::{EnvFrame, EnvMap};
use pointray::ground::{Checker, GroundPlane};
use pointray::material::{Material, Phong};
use pointray::preprocess::{PreprocessConfig, PreprocessStats, preprocess_with_progress};
use pointray::scene::{SceneContent, SceneParts};
use pointray::settings::Settings;
use pointray::shading::{Environment, Light};

use crate::scene::{CloudSpec, EnvironmentSpec, GridSpec, GroundSpec, LightSpec, MaterialSpec, SceneFile, parse_scene};
use crate::{IoError, ReadOptions};

/// A render's input, read and prepared.
pub struct Source {
    pub parts: SceneParts,
    /// A scene file's camera and render settings (its `[camera]` and `[render]` tables); none
    /// for a lone cloud.
    pub settings: Option<Settings>,
    /// A scene file's `[animation]`.
    pub animation: Option<pointray::camera_path::Animation>,
    /// Points the readers returned, before preprocessing dropped any.
    pub points_read: usize,
    pub preprocess: PreprocessStats,
    /// Seconds spent reading (preprocessing's own are in `preprocess`).
    pub load_seconds: f64,
}

/// Whether `path` names a scene file (by its `.toml` extension).
pub fn is_scene(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"))
}

/// Reads a cloud file (as `read` says) or a scene file and prepares what it holds. `stage` is
/// told what is being done ("read FILE", "preprocess: kNN", …), for a progress display; what
/// was dropped or repaired is logged as warnings naming the file.
pub fn load(
    path: &Path,
    preprocess: &PreprocessConfig,
    read: &ReadOptions,
    stage: &dyn Fn(&str),
) -> Result<Source, IoError> {
    if is_scene(path) {
        return load_scene(path, preprocess, stage);
    }
    if crate::prs::is_prs(path) {
        return load_prs(path, stage);
    }
    load_cloud(&[path.to_path_buf()], preprocess, read, stage)
}

/// [`load`] for several cloud files, the tiles of one survey read as one cloud
/// ([`crate::read_tiles`]); a lone path is [`load`]'s.
pub fn load_tiles(
    paths: &[PathBuf],
    preprocess: &PreprocessConfig,
    read: &ReadOptions,
    stage: &dyn Fn(&str),
) -> Result<Source, IoError> {
    if let [path] = paths {
        return load(path, preprocess, read, stage);
    }
    if let Some(scene) = paths.iter().find(|p| is_scene(p) || crate::prs::is_prs(p)) {
        return Err(IoError::invalid(scene, "a scene file is read alone, not as one of several inputs"));
    }
    load_cloud(paths, preprocess, read, stage)
}

fn load_cloud(
    paths: &[PathBuf],
    preprocess: &PreprocessConfig,
    read: &ReadOptions,
    stage: &dyn Fn(&str),
) -> Result<Source, IoError> {
    let p = read_prepared(paths, preprocess, read, stage)?;
    let parts = SceneParts { view: sensor_view(&p.cloud), cloud: p.cloud, ..lone_cloud_parts(p.up, p.sun) };
    Ok(Source {
        parts,
        settings: None,
        animation: None,
        points_read: p.points_read,
        preprocess: p.preprocess,
        load_seconds: p.read_seconds,
    })
}

/// A lone cloud's scene parts from its file's up axis and sun: a survey under its sun, and the
/// sky round it for the light that bounces (no points, no view).
pub(crate) fn lone_cloud_parts(up: Option<Vec3>, sun: Option<Vec3>) -> SceneParts {
    let light = sun.map(|direction| Light::Directional { direction, intensity: 1.0 });
    let environment = sun.map(|_| Environment::sky(up.unwrap_or(Vec3::Z).normalize()));
    SceneParts { up, light, environment, ..SceneParts::default() }
}

/// A prepared scene file, opened: built already, nothing to preprocess.
fn load_prs(path: &Path, stage: &dyn Fn(&str)) -> Result<Source, IoError> {
    stored_source(&path.display().to_string(), || crate::prs::open_prs(path), stage)
}

/// The prepared scene file `name` (a URL, say) of `len` bytes that `reader` reads by ranges,
/// opened: fetched as it is read (`crate::fetched`).
pub fn open_fetched(
    name: &str,
    len: u64,
    reader: Box<dyn crate::fetched::RangeReader>,
    stage: &dyn Fn(&str),
) -> Result<Source, IoError> {
    stored_source(name, || crate::prs::open_prs_fetched(name, len, reader), stage)
}

fn stored_source(
    name: &str,
    open: impl FnOnce() -> Result<pointray::scene::StoredScene, IoError>,
    stage: &dyn Fn(&str),
) -> Result<Source, IoError> {
    let start = Instant::now();
    stage("open");
    let stored = open()?;
    let points_read = stored.meta().points;
    let load_seconds = start.elapsed().as_secs_f64();
    tracing::info!("opened the scene file {name} ({points_read} points) in {load_seconds:.3} s");
    let parts = SceneParts { stored: Some(stored), ..SceneParts::default() };
    Ok(Source {
        parts,
        settings: None,
        animation: None,
        points_read,
        preprocess: PreprocessStats::default(),
        load_seconds,
    })
}

/// The environment map `settings.env_map` names, read, for [`pointray::Scene::set_environment_map`];
/// none if it names none.
pub fn environment_map(settings: &Settings) -> Result<Option<(PathBuf, Arc<EnvMap>)>, IoError> {
    let Some(path) = &settings.env_map else { return Ok(None) };
    let map = crate::read_env_map(path)?;
    let (w, h) = map.size();
    tracing::info!("read the {w} x {h} environment map {}", path.display());
    Ok(Some((path.clone(), Arc::new(map))))
}

/// Where the default camera stands for a cloud one sensor saw from outside it (an organised
/// depth frame's): at the sensor, looking at the cloud's centre. A scanner inside the cloud (a
/// terrestrial scan's) leaves the default view.
fn sensor_view(cloud: &PointCloud) -> Option<(Vec3, f32)> {
    let [sensor] = cloud.viewpoints.as_slice() else { return None };
    sensor_view_of(*sensor, cloud.bounds())
}

/// [`sensor_view`] of a sensor at `sensor` and a cloud within `bounds`.
pub(crate) fn sensor_view_of(sensor: Vec3, bounds: Aabb) -> Option<(Vec3, f32)> {
    let outside = sensor.cmplt(bounds.min).any() || sensor.cmpgt(bounds.max).any();
    let offset = sensor - bounds.center();
    (outside && bounds.diagonal() > 0.0).then(|| (offset.normalize(), offset.length() / bounds.diagonal()))
}

/// A cloud file, read and preprocessed.
pub struct PreparedCloud {
    pub cloud: PointCloud,
    /// The up axis the file's format gives, if any (`FileInfo::up`).
    pub up: Option<Vec3>,
    /// The direction towards the data's default sun, if any (`FileInfo::sun`).
    pub sun: Option<Vec3>,
    /// Points the reader returned, before preprocessing dropped any.
    pub points_read: usize,
    pub preprocess: PreprocessStats,
    pub read_seconds: f64,
}

/// Reads a cloud file (as `read` says), or a survey's tiles as one ([`crate::read_tiles`]), and
/// preprocesses it.
pub fn read_prepared(
    paths: &[PathBuf],
    config: &PreprocessConfig,
    read: &ReadOptions,
    stage: &dyn Fn(&str),
) -> Result<PreparedCloud, IoError> {
    let name = crate::set_name(paths);
    config.check().map_err(|e| IoError::invalid(&name, e.to_string()))?;
    let start = Instant::now();
    stage("read");
    let loaded = crate::read_tiles(paths, read)?;
    let read_seconds = start.elapsed().as_secs_f64();
    let (mut cloud, up, sun) = (loaded.cloud, loaded.info.up.map(Vec3::from), loaded.info.sun.map(Vec3::from));
    tracing::info!("read {} points from {} in {read_seconds:.3} s", cloud.len(), name.display());
    let points_read = cloud.len();
    let preprocess = prepare(&mut cloud, config, &name.display().to_string(), stage)
        .map_err(|message| IoError::invalid(&name, message))?;
    Ok(PreparedCloud { cloud, up, sun, points_read, preprocess, read_seconds })
}

/// Preprocesses a cloud read from `input`, logging what was repaired; the message of a
/// failure, to go with the file's name.
pub fn prepare(
    cloud: &mut PointCloud,
    config: &PreprocessConfig,
    input: &str,
    stage: &dyn Fn(&str),
) -> Result<PreprocessStats, String> {
    let stats = preprocess_with_progress(cloud, config, &|s| stage(&format!("preprocess: {s}")))
        .map_err(|e| format!("preprocessing: {e}"))?;
    stats.warn_repairs(input);
    Ok(stats)
}

/// The built-in demo scene's source: `points` points drawn with `seed`, prepared as a cloud
/// read from a file is (errors name the demo).
pub fn demo(points: usize, seed: u64, config: &PreprocessConfig, stage: &dyn Fn(&str)) -> Result<Source, String> {
    let mut cloud = pointray::demo::demo_cloud(points, seed);
    let points_read = cloud.len();
    let preprocess = prepare(&mut cloud, config, "demo", stage).map_err(|e| format!("demo: {e}"))?;
    let parts = pointray::demo::demo_scene_parts(cloud);
    Ok(Source { parts, settings: None, animation: None, points_read, preprocess, load_seconds: 0.0 })
}

/// Reads the scene at `path` and every cloud it names, preprocessed and placed.
fn load_scene(path: &Path, preprocess: &PreprocessConfig, stage: &dyn Fn(&str)) -> Result<Source, IoError> {
    let start = Instant::now();
    let text = std::fs::read_to_string(path).map_err(|e| IoError::Io { path: path.to_path_buf(), io: e })?;
    let spec = parse_scene(path, &text)?;
    preprocess.check().map_err(|e| IoError::invalid(path, e.to_string()))?;
    let folder = path.parent().unwrap_or(Path::new("."));
    let mut placed = Vec::new();
    let (mut point_materials, mut materials) = (Vec::new(), Vec::new());
    let (mut points_read, mut stats) = (0, PreprocessStats::default());
    for (index, cloud) in spec.clouds.iter().enumerate() {
        let name = format!("cloud {}", index + 1);
        let in_scene = |e: &dyn std::fmt::Display| IoError::invalid(path, format!("{name}: {e}"));
        let (mut points, label) = match (&cloud.file, &cloud.grid) {
            (Some(file), None) => {
                let file = folder.join(file);
                stage(&format!("read {}", file.display()));
                let points = crate::read_cloud(&file).map_err(|e| in_scene(&e))?.cloud;
                (points, file.display().to_string())
            }
            (None, Some(grid)) => (grid_cloud(grid).map_err(|e| in_scene(&e))?, format!("{name} (grid)")),
            _ => return Err(in_scene(&"give either `file` or `grid`")),
        };
        if let Some(color) = cloud.color {
            points.colors = Some(vec![color; points.len()]);
        }
        points_read += points.len();
        let one = prepare(&mut points, preprocess, &label, stage).map_err(|e| in_scene(&format!("{label}: {e}")))?;
        stats.add(&one);
        place(&mut points, cloud);
        point_materials.extend(std::iter::repeat_n(index as u8, points.len()));
        materials.push(material(&cloud.material));
        placed.push(points);
    }
    let settings = scene_settings(&spec);
    let up = Vec3::from(spec.camera.up).normalize();
    let environment = match &spec.environment {
        &EnvironmentSpec::Uniform { color } => Environment::Uniform { color },
        &EnvironmentSpec::Sky { zenith, horizon, ground } => Environment::Gradient { up, zenith, horizon, ground },
        EnvironmentSpec::Map { file, rotation } => {
            let file = folder.join(file);
            stage(&format!("read {}", file.display()));
            let map = crate::read_env_map(&file).map_err(|e| IoError::invalid(path, format!("[environment]: {e}")))?;
            Environment::Map { map: Arc::new(map), frame: EnvFrame::new(up, *rotation) }
        }
    };
    let content = SceneContent {
        lights: spec.lights.iter().map(light).collect(),
        materials,
        environment,
        background: None,
        ground: spec.ground.as_ref().map(ground),
    };
    let parts = SceneParts {
        cloud: merge(placed),
        point_materials: Some(point_materials),
        content: Some(content),
        ..SceneParts::default()
    };
    let load_seconds = start.elapsed().as_secs_f64() - stats.seconds.total();
    let animation = spec.animation().map_err(|e| IoError::invalid(path, e))?;
    Ok(Source { parts, settings: Some(settings), animation, points_read, preprocess: stats, load_seconds })
}

/// The settings a scene file's `[camera]` and `[render]` tables give; the rest default.
fn scene_settings(spec: &SceneFile) -> Settings {
    let (c, r) = (&spec.camera, &spec.render);
    Settings {
        eye: Some(DVec3::from(c.eye)),
        look_at: Some(DVec3::from(c.look_at)),
        up: Some(Vec3::from(c.up)),
        fov: c.fov,
        lens_radius: c.lens_radius,
        focus_distance: c.focus_distance,
        width: r.width,
        height: r.height,
        spp: r.spp,
        max_depth: r.max_depth,
        seed: r.seed,
        surface: r.surface,
        integrator: r.integrator,
        ao_distance: r.ao_distance,
        sampler: r.sampler,
        filter: r.filter,
        tonemap: r.tonemap,
        exposure: r.exposure,
        shadows: r.shadows,
        lod_threshold: r.lod_threshold,
        prefilter: r.prefilter,
        color_by: r.color_by,
        edl: r.edl,
        ..Settings::default()
    }
}

fn grid_cloud(g: &GridSpec) -> Result<PointCloud, String> {
    if !(g.size > 0.0 && g.spacing > 0.0) {
        return Err("grid: size and spacing must be positive".into());
    }
    // In f64 first: a huge size over a tiny spacing must not overflow the count.
    let side = (g.size / g.spacing).ceil() + 1.0;
    let most = (pointray::accel::bvh::MAX_SPLATS as f64).sqrt();
    if side > most {
        return Err(format!("grid: {side} x {side} points is too many (at most {most:.0} a side)"));
    }
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
    let mut residuals = points.residuals.take();
    for (i, p) in points.positions.iter_mut().enumerate() {
        let residual = residuals.as_ref().map_or(DVec3::ZERO, |r| r[i].as_dvec3());
        let world = rotation * ((origin + p.as_dvec3() + residual) * scale) + translate;
        *p = world.as_vec3();
        if let Some(r) = &mut residuals {
            r[i] = pointray::cloud::residual(world, DVec3::ZERO, *p);
        }
    }
    points.residuals = residuals;
    if let Some(normals) = &mut points.normals {
        normals.iter_mut().for_each(|n| *n = (rotation * n.as_dvec3()).normalize().as_vec3());
    }
    if let Some(radii) = &mut points.radii {
        radii.iter_mut().for_each(|r| *r *= scale as f32);
    }
    points.origin = DVec3::ZERO;
}

/// One cloud of all the placed ones; colours kept where any cloud has them, the default
/// colour for those without; scan attributes likewise (zero for those without).
fn merge(clouds: Vec<PointCloud>) -> PointCloud {
    let any_colors = clouds.iter().any(|c| c.colors.is_some());
    let any_residuals = clouds.iter().any(|c| c.residuals.is_some());
    let mut all = PointCloud::default();
    let (mut normals, mut radii, mut colors, mut residuals) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for c in clouds {
        let n = c.len();
        all.scan.append(all.positions.len(), c.scan, n);
        if any_residuals {
            residuals.extend(c.residuals.unwrap_or_else(|| vec![Vec3::ZERO; n]));
        }
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
    all.residuals = any_residuals.then_some(residuals);
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
        assert!(grid_cloud(&spec).unwrap_err().contains("too many"));
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

    /// A scene's `[environment] kind = "map"` reads the panorama beside the scene file and turns
    /// it about the camera's up; a missing one fails naming both files.
    #[test]
    fn a_scene_takes_its_environment_map_from_beside_it() {
        let dir = tempfile::tempdir().unwrap();
        let texels: Vec<[f32; 3]> = (0..32).map(|i| [0.5 + (i / 8) as f32; 3]).collect();
        std::fs::write(dir.path().join("sky.hdr"), crate::env_map::encode_rgbe(8, 4, &texels)).unwrap();
        let scene = |map: &str| {
            let text = format!(
                "[camera]\neye = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 1.0]\n\
                 [environment]\nkind = \"map\"\nfile = \"{map}\"\nrotation = 90.0\n\
                 [[cloud]]\ngrid = {{ size = 1.0, spacing = 0.1 }}\n"
            );
            let path = dir.path().join("scene.toml");
            std::fs::write(&path, text).unwrap();
            load(&path, &PreprocessConfig::standard(), &ReadOptions::default(), &|_| {})
        };
        let source = scene("sky.hdr").unwrap();
        let Some(SceneContent { environment: Environment::Map { map, frame }, .. }) = source.parts.content else {
            panic!("no map");
        };
        assert_eq!(map.size(), (8, 4));
        assert_eq!((frame.up, frame.forward), (Vec3::Z, EnvFrame::new(Vec3::Z, 90.0).forward));
        let err = scene("none.hdr").err().unwrap().to_string();
        assert!(err.contains("scene.toml") && err.contains("none.hdr"), "{err}");
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
