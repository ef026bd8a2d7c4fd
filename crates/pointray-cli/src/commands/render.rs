//! `pointray render`: load (or make the demo, or a scene file), preprocess, build, render, write
//! the PNG or EXR and the stats.

use std::time::Instant;

use pointray::accel::NodeBounds;
use pointray::camera::{Camera, Region};
use pointray::film::{Film, MAX_PIXELS, ToneMap};
use pointray::ground::{Checker, GroundPlane};
use pointray::material::Material;
use pointray::render::{Filter, Integrator, RenderConfig, Sampler};
use pointray::shading::{Environment, Light};
use pointray::splat::scheme::{SurfaceKind, SurfaceScheme};
use pointray::splat::{DiskShape, splats_from_cloud};
use pointray::stats::RenderStats;
use serde::Serialize;

use crate::any_accel::AnyAccel;
use crate::args::{
    AccelArg, AovArg, CullArg, FilterArg, IntegratorArg, MaterialArg, RenderArgs, SamplerArg, SurfaceArg, Switch,
};

/// `--cull auto` culls when at most this fraction of rays from around the model meets a back
/// face first. Closed scans measure 0.1–0.4 % (stray disks at silhouettes and creases), open
/// ones several percent and more.
const CULL_AUTO_MAX_BACKFACING: f64 = 0.01;

/// What `--stats` writes.
#[derive(Serialize)]
struct StatsReport {
    input: String,
    /// Points the reader returned (a PCD's NaN points are already dropped there).
    points_read: usize,
    /// Points rendered: those read less the non-finite and repeated ones.
    points: usize,
    width: u32,
    height: u32,
    region: Region,
    threads: usize,
    accel: &'static str,
    surface: &'static str,
    integrator: Integrator,
    /// The materials, by index (one per cloud of a scene).
    materials: Vec<&'static str>,
    /// The analytic ground plane's material, if there is one.
    ground: Option<&'static str>,
    samples_per_pixel: u32,
    load_seconds: f64,
    preprocess_seconds: PreprocessSeconds,
    preprocess: pointray::preprocess::PreprocessStats,
    /// The median of `timed_builds` builds (`--bench-builds`), and the fastest.
    build_seconds: f64,
    build_seconds_min: f64,
    timed_builds: u32,
    render_seconds: f64,
    render_seconds_min: f64,
    timed_frames: u32,
    rays: u64,
    primary_rays: u64,
    /// Reflected and refracted rays (mirrors and glass).
    secondary_rays: u64,
    shadow_rays: u64,
    mrays_per_second: f64,
    primary_mrays_per_second: f64,
    hit_fraction: f64,
    nodes_visited_per_ray: f64,
    splat_tests_per_ray: f64,
    box_tests_per_ray: f64,
    sphere_tests_per_ray: f64,
    lod_stops_per_ray: f64,
    culled_per_ray: f64,
    blended_splats_per_hit: f64,
    /// PSS projection steps per camera-ray hit (0 for the other schemes).
    pss_steps_per_hit: f64,
    /// Fraction of PSS hits that kept the SJ seed (the projection did not converge).
    pss_fallback_fraction: f64,
    /// Level-of-detail threshold in pixels; null with `--lod off`.
    lod_threshold: Option<f32>,
    culling: CullingReport,
    node_bounds: NodeBounds,
    nodes: usize,
    sphere_nodes: usize,
    bytes_per_node: usize,
    /// Most nodes visited by one pixel (the top of the `--aov nodes` scale).
    nodes_visited_max_per_pixel: u32,
    accel_bytes: usize,
    /// The accelerator with its splats, per input splat.
    bytes_per_splat: f64,
    mean_radius: f64,
    bounds_diagonal: f32,
    camera_distance: Option<f32>,
    /// The process's peak resident memory (load, preprocessing, build and render), where the
    /// system tells it (Linux).
    peak_memory_bytes: Option<u64>,
    peak_memory_bytes_per_point: Option<f64>,
    /// The instruction-set path the kernels ran on (`pointray::accel::isa`).
    isa: pointray::accel::isa::Isa,
    counters: RenderStats,
}

#[derive(Serialize)]
struct CullingReport {
    mode: CullArg,
    enabled: bool,
    /// Fraction of rays from around the model whose first disk faces away (the auto check).
    backfacing_fraction: Option<f64>,
}

#[derive(Serialize)]
struct PreprocessSeconds {
    total: f64,
    #[serde(flatten)]
    stages: pointray::preprocess::StageSeconds,
}

pub fn run(a: &RenderArgs, quiet: bool) -> anyhow::Result<()> {
    check_args(a).map_err(crate::failure::usage)?;
    // Fail before the work, not after it, when an output cannot be written.
    super::check_output_path(&a.output)?;
    if let Some(stats) = &a.stats {
        super::check_output_path(stats)?;
    }
    // An EXR holds the AOVs as layers; beside a PNG each is a PNG of its own.
    for aov in a.aov.iter().filter(|_| !is_exr(&a.output)) {
        super::check_output_path(&aov_path(&a.output, aov.name()))?;
    }
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads.unwrap_or(0)).build()?;
    pool.install(|| run_in_pool(a, quiet, pool.current_num_threads()))
}

pub fn check_args(a: &RenderArgs) -> anyhow::Result<()> {
    use anyhow::ensure;
    let format = a.output.extension().map(|e| e.to_ascii_lowercase());
    ensure!(
        format.is_some_and(|e| e == "png" || e == "exr"),
        "-o {}: the extension chooses the format, .png or .exr",
        a.output.display()
    );
    ensure!(a.width > 0 && a.height > 0, "--width and --height must be positive");
    ensure!(
        u64::from(a.width) * u64::from(a.height) <= MAX_PIXELS,
        "--width x --height: a {}x{} frame is too large (at most {MAX_PIXELS} pixels)",
        a.width,
        a.height
    );
    ensure!(a.fov > 0.0 && a.fov < 180.0, "--fov must be between 0 and 180 degrees");
    ensure!(a.distance.is_none_or(|d| d > 0.0 && d.is_finite()), "--distance must be positive");
    ensure!(a.spp >= 1, "--spp must be at least 1");
    ensure!(a.threads.is_none_or(|t| (1..=1024).contains(&t)), "--threads must be between 1 and 1024");
    ensure!(a.sj_window.is_none_or(|w| w >= 0.0 && w.is_finite()), "--sj-window must be a non-negative number");
    ensure!(a.sj_min_coverage >= 0.0 && a.sj_min_coverage.is_finite(), "--sj-min-coverage must be non-negative");
    ensure!(
        a.sj_min_coverage_facing_away >= 0.0 && a.sj_min_coverage_facing_away.is_finite(),
        "--sj-min-coverage-facing-away must be non-negative"
    );
    ensure!(a.shadow_offset >= 0.0 && a.shadow_offset.is_finite(), "--shadow-offset must be non-negative");
    ensure!(a.lod_threshold > 0.0 && a.lod_threshold.is_finite(), "--lod-threshold must be a positive number");
    ensure!(a.ior > 0.0 && a.ior.is_finite(), "--ior must be a positive number");
    ensure!(a.lens_radius >= 0.0 && a.lens_radius.is_finite(), "--lens-radius must be non-negative");
    ensure!(a.ao_distance.is_none_or(|d| d > 0.0 && d.is_finite()), "--ao-distance must be positive");
    ensure!(a.focus_distance.is_none_or(|d| d > 0.0 && d.is_finite()), "--focus-distance must be positive");
    ensure!(a.diffuse_spread >= 0.0 && a.diffuse_spread.is_finite(), "--diffuse-spread must be non-negative");
    ensure!(a.light_radius.is_none_or(|r| r >= 0.0 && r.is_finite()), "--light-radius must be a non-negative number");
    ensure!(a.max_depth <= 64, "--max-depth must be at most 64");
    let most = ToneMap::MAX_EXPOSURE;
    ensure!(a.exposure.abs() <= most, "--exposure must be between -{most} and {most} stops");
    ensure!(a.up.length_squared() > 0.0, "--up must not be the zero vector");
    ensure!(a.view_dir.is_none_or(|v| v.length_squared() > 0.0), "--view-dir must not be the zero vector");
    ensure!(a.light_dir.is_none_or(|v| v.length_squared() > 0.0), "--light-dir must not be the zero vector");
    if let (Some(eye), Some(target)) = (a.eye, a.look_at) {
        ensure!(eye != target, "--eye and --look-at must differ");
    }
    Ok(())
}

fn run_in_pool(a: &RenderArgs, quiet: bool, threads: usize) -> anyhow::Result<()> {
    // 1. The cloud, or a scene's clouds, placed and preprocessed.
    if let Some(path) = a.input.as_ref().filter(|p| crate::scene::is_scene(p)) {
        let scene = crate::scene::load(path, a, quiet)?;
        return render_cloud(
            &scene.args.clone(),
            quiet,
            threads,
            Input::Scene(Box::new(scene)),
            path.display().to_string(),
        );
    }
    let (cloud, input_name, load_seconds) = match &a.input {
        Some(path) => {
            let (loaded, secs) = super::load(path, quiet)?;
            (loaded.cloud, path.display().to_string(), secs)
        }
        None => (pointray::demo::demo_cloud(a.demo_points, a.seed), "demo".to_string(), 0.0),
    };
    render_cloud(a, quiet, threads, Input::Cloud { cloud, load_seconds }, input_name)
}

/// What `render` draws: one cloud, to be preprocessed, or a scene's, already placed.
enum Input {
    Cloud { cloud: pointray::PointCloud, load_seconds: f64 },
    Scene(Box<crate::scene::Scene>),
}

fn render_cloud(a: &RenderArgs, quiet: bool, threads: usize, input: Input, input_name: String) -> anyhow::Result<()> {
    let (mut cloud, load_seconds, scene) = match input {
        Input::Cloud { cloud, load_seconds } => (cloud, load_seconds, None),
        Input::Scene(mut scene) => {
            let cloud = std::mem::take(&mut scene.cloud);
            (cloud, scene.load_seconds, Some(scene))
        }
    };
    // Preprocessing only removes points: refuse an oversized cloud before spending on it.
    anyhow::ensure!(
        cloud.len() <= pointray::accel::bvh::MAX_SPLATS,
        "{input_name}: {} points is more than pointray can index ({})",
        cloud.len(),
        pointray::accel::bvh::MAX_SPLATS
    );
    let (points_read, pre) = match &scene {
        // Each of a scene's clouds was preprocessed on its own; its points keep their order.
        Some(scene) => (scene.points_read, scene.preprocess.clone()),
        None => (cloud.len(), super::prepare_cloud(&mut cloud, &a.preprocess, &input_name, quiet)?),
    };
    let bounds = cloud.bounds();

    // 2. The accelerator.
    let mut splats = splats_from_cloud(&cloud);
    if let Some(scene) = &scene {
        splats.iter_mut().zip(&scene.point_materials).for_each(|(s, &m)| s.set_material(m));
    }
    let mean_radius = splats.iter().map(|s| f64::from(s.radius)).sum::<f64>() / splats.len() as f64;
    // The splats hold all the rest needs of the points: free them before the build's peak.
    let (origin, point_count) = (cloud.origin, cloud.len());
    drop(cloud);
    let shape = surface_kind(a.surface).shape();
    let build = |splats| {
        let t = Instant::now();
        let accel =
            crate::progress::spinning("build", quiet, || AnyAccel::build(a.accel, splats, a.sphere_from_level, shape));
        (accel, t.elapsed().as_secs_f64())
    };
    // Benchmark builds first, each from a copy made before its clock starts; the last build
    // takes the splats themselves.
    let mut builds: Vec<f64> = (1..a.bench_builds).map(|_| build(splats.clone()).1).collect();
    let (accel, last) = build(splats);
    builds.push(last);
    builds.sort_by(f64::total_cmp);
    let (build_seconds, build_seconds_min) = (pointray::stats::median(&builds), builds[0]);
    tracing::info!("built {} over {point_count} splats in {build_seconds:.3} s", accel.name());

    // 3. Camera, light, region.
    let (default_view, default_distance) = match a.input {
        Some(_) => (glam::Vec3::new(0.4, 0.3, 1.0), 1.0),
        None => (glam::Vec3::from(pointray::demo::DEMO_VIEW.0), pointray::demo::DEMO_VIEW.1),
    };
    let distance = a.distance.unwrap_or(default_distance);
    // The camera frames the points' bounds (the Embree bench's convention); a cloud of one
    // point, or of coincident points, has none, and then the disks' bounds serve.
    let bounds = if bounds.diagonal() > 0.0 { bounds } else { accel.bounds() };
    let bounds = if bounds.diagonal() > 0.0 {
        bounds
    } else {
        tracing::warn!("{input_name}: the model has no extent; framing a unit box around it");
        pointray::math::Aabb::new(bounds.center() - 0.5, bounds.center() + 0.5)
    };
    // Positions the user gives are in the file's coordinates; the cloud is stored relative to
    // its origin (see `PointCloud`).
    let local = |p: glam::DVec3| (p - origin).as_vec3();
    let camera = match (a.eye.map(local), a.look_at.map(local)) {
        (Some(eye), Some(target)) => Camera::look_at(eye, target, a.up, a.fov, a.width, a.height),
        _ => Camera::orbit(&bounds, a.view_dir.unwrap_or(default_view), a.up, distance, a.fov, a.width, a.height),
    };
    let focus = a.focus_distance.unwrap_or(camera.focus_distance);
    let camera = camera.with_lens(a.lens_radius, focus);
    let light = match (a.light_pos, a.light_dir) {
        (Some(position), _) => match a.light_radius {
            Some(radius) => Light::Sphere { center: local(position), radius, intensity: a.light_intensity },
            None => Light::Point { position: local(position), intensity: a.light_intensity },
        },
        (None, Some(direction)) => Light::Directional { direction, intensity: a.light_intensity },
        (None, None) if a.input.is_none() => pointray::demo::demo_light(),
        (None, None) => Light::headlight(&camera, a.light_intensity),
    };
    let region = if a.crop_to_model {
        let r = camera.region_of(&bounds);
        if r.pixel_count() == 0 {
            let e = anyhow::anyhow!("{input_name}: --crop-to-model: the model lies outside the view");
            return Err(crate::failure::usage(e));
        }
        r
    } else {
        a.region.map_or(Region::full(a.width, a.height), |r| r.clamp_to(a.width, a.height))
    };
    if let Some(r) = a.region.filter(|_| region.pixel_count() == 0) {
        let e = anyhow::anyhow!(
            "--region {},{},{},{} lies outside the {}x{} frame",
            r.x0,
            r.y0,
            r.x1,
            r.y1,
            a.width,
            a.height
        );
        return Err(crate::failure::usage(e));
    }
    let defaults = SurfaceScheme::of_kind(surface_kind(a.surface));
    let scheme = SurfaceScheme {
        window: a.sj_window.unwrap_or(defaults.window),
        min_coverage: if matches!(a.surface, SurfaceArg::FirstHit) { 0.0 } else { a.sj_min_coverage },
        min_coverage_facing_away: if matches!(a.surface, SurfaceArg::FirstHit) {
            0.0
        } else {
            a.sj_min_coverage_facing_away
        },
        ..defaults
    };
    // Level of detail lives in the BVH's and the kd-tree's nodes, normal cones in the BVH's
    // only; brute force traces at full detail. The statistics say what was used.
    let multires = matches!(a.accel, AccelArg::Bvh | AccelArg::Kdtree);
    // Ray-facing disks always face the ray: nothing to cull (`render` ignores culling for them
    // too; checking here skips the probe and keeps the reported setting true).
    let cones = matches!(a.accel, AccelArg::Bvh) && scheme.kind.shape() == DiskShape::Oriented;
    let backfacing = (cones && a.cull == CullArg::Auto).then(|| accel.backfacing_fraction()).flatten();
    let cull_backfaces = cones
        && match a.cull {
            CullArg::On => true,
            CullArg::Off => false,
            CullArg::Auto => backfacing.is_some_and(|f| f <= CULL_AUTO_MAX_BACKFACING),
        };
    tracing::info!("backface culling {cull_backfaces} (back faces first: {backfacing:?})");
    let lod_threshold = if multires && a.lod == Switch::On { a.lod_threshold } else { 0.0 };
    let config = RenderConfig {
        sampler: match a.sampler {
            SamplerArg::Random => Sampler::Random,
            SamplerArg::R2 => Sampler::R2,
        },
        filter: match a.filter {
            FilterArg::Box => Filter::Box,
            FilterArg::Tent => Filter::Tent,
        },
        integrator: match a.integrator {
            IntegratorArg::Whitted => Integrator::Whitted,
            IntegratorArg::Path => Integrator::Path,
            IntegratorArg::EyeLight => Integrator::EyeLight,
            IntegratorArg::Ao => {
                Integrator::AmbientOcclusion { distance: a.ao_distance.unwrap_or(0.1 * bounds.diagonal()) }
            }
        },
        lod_threshold,
        cull_backfaces,
        scheme,
        lights: match &scene {
            Some(scene) => scene.lights.clone(),
            None => vec![light],
        },
        materials: match &scene {
            Some(scene) => scene.materials.clone(),
            None => vec![match a.material {
                MaterialArg::Phong => Material::standard(),
                MaterialArg::Mirror => Material::Mirror { tint: [0.9; 3] },
                MaterialArg::Glass => Material::Glass { ior: a.ior, tint: [1.0; 3] },
            }],
        },
        shadows: !a.no_shadows,
        shadow_offset: a.shadow_offset,
        environment: match &scene {
            Some(scene) => scene.environment,
            // The world's up (the camera's would tilt the horizon with the view).
            None if a.sky => Environment::Gradient {
                up: a.up.normalize(),
                zenith: [0.18, 0.32, 0.62],
                horizon: [0.75, 0.82, 0.90],
                ground: [0.25, 0.24, 0.22],
            },
            None => Environment::BACKGROUND,
        },
        ground: match &scene {
            Some(scene) => scene.ground,
            None => a.ground.then(|| floor_under(&bounds, a.up)),
        },
        max_depth: a.max_depth,
        region,
        samples: a.spp,
        seed: a.seed,
        diffuse_spread: a.diffuse_spread,
        count_work: a.stats.is_some() || a.aov.contains(&AovArg::Nodes),
        first_hit_aovs: a.aov.iter().any(|aov| *aov != AovArg::Nodes),
    };

    // 4. Render: one frame for the image, then any timed benchmark frames, which count no work
    // (the statistics' counts are the first frame's).
    let bar = crate::progress::bar(region.pixel_count(), "render", quiet);
    let t = Instant::now();
    let (film, stats) = accel.render(&camera, &config, &|n| bar.inc(n));
    let first_seconds = t.elapsed().as_secs_f64();
    bar.finish_and_clear();
    let mut times = Vec::new();
    // The timed frames share one film, as a renderer showing frame after frame would.
    let mut scratch = None;
    let timed = RenderConfig { count_work: false, ..config.clone() };
    for _ in 0..a.bench_frames {
        let scratch = scratch.get_or_insert_with(|| pointray::render::film_for(&camera, &timed));
        let t = Instant::now();
        let _ = accel.render_into(&camera, &timed, scratch, &|_| {});
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    let (render_seconds, render_seconds_min) = match times.len() {
        0 => (first_seconds, first_seconds),
        _ => (pointray::stats::median(&times), times[0]),
    };

    let nodes_max = film.nodes_visited.iter().copied().max().unwrap_or(0);
    if is_exr(&a.output) {
        let channels = exr_channels(&film, &a.aov, a.width, a.height, config.environment.flat_color());
        pointray_io::write_exr(&a.output, a.width, a.height, channels).map_err(crate::failure::output)?;
    } else {
        let tone = ToneMap { exposure: a.exposure, curve: a.tonemap.into() };
        let frame = film.frame_srgb8(a.width, a.height, config.environment.flat_color(), tone);
        pointray_io::image::write_png(&a.output, a.width, a.height, &frame).map_err(crate::failure::output)?;
        let mut written = Vec::new();
        for &aov in &a.aov {
            if written.contains(&aov) {
                continue;
            }
            let region = aov_rgb8(&film, aov, nodes_max);
            let frame = frame_from_region(&region, film.region, a.width, a.height);
            pointray_io::image::write_png(&aov_path(&a.output, aov.name()), a.width, a.height, &frame)
                .map_err(crate::failure::output)?;
            written.push(aov);
        }
    }
    let mrays = stats.rays as f64 / render_seconds / 1e6;
    if !quiet {
        eprintln!(
            "{}: {} points, {} {}x{} px, {:.3} s ({:.2} Mrays/s), hits {:.1}%, wrote {}",
            input_name,
            point_count,
            accel.name(),
            region.width(),
            region.height(),
            render_seconds,
            mrays,
            stats.hit_fraction() * 100.0,
            a.output.display()
        );
    }

    if let Some(path) = &a.stats {
        let per_ray = |n: u64| if stats.rays == 0 { 0.0 } else { n as f64 / stats.rays as f64 };
        let per_hit = |n: u64| if stats.primary_hits == 0 { 0.0 } else { n as f64 / stats.primary_hits as f64 };
        let (nodes, sphere_nodes, bytes_per_node) = accel.node_summary();
        let peak_memory_bytes = super::peak_memory_bytes();
        let report = StatsReport {
            input: input_name,
            points_read,
            points: point_count,
            width: a.width,
            height: a.height,
            region,
            threads,
            accel: accel.name(),
            surface: scheme.kind.name(),
            integrator: config.integrator,
            materials: config.materials.iter().map(|m| m.name()).collect(),
            ground: config.ground.map(|g| g.material.name()),
            samples_per_pixel: a.spp,
            load_seconds,
            preprocess_seconds: PreprocessSeconds { total: pre.seconds.total(), stages: pre.seconds },
            preprocess: pre,
            build_seconds,
            build_seconds_min,
            timed_builds: a.bench_builds,
            render_seconds,
            render_seconds_min,
            timed_frames: a.bench_frames,
            rays: stats.rays,
            primary_rays: stats.primary_rays,
            secondary_rays: stats.secondary_rays,
            shadow_rays: stats.shadow_rays,
            mrays_per_second: mrays,
            primary_mrays_per_second: stats.primary_rays as f64 / render_seconds / 1e6,
            hit_fraction: stats.hit_fraction(),
            nodes_visited_per_ray: stats.nodes_visited_per_ray(),
            splat_tests_per_ray: stats.splat_tests_per_ray(),
            box_tests_per_ray: per_ray(stats.traversal.box_tests),
            sphere_tests_per_ray: per_ray(stats.traversal.sphere_tests),
            lod_stops_per_ray: per_ray(stats.traversal.lod_stops),
            culled_per_ray: per_ray(stats.traversal.culled),
            lod_threshold: (lod_threshold > 0.0).then_some(lod_threshold),
            culling: CullingReport { mode: a.cull, enabled: cull_backfaces, backfacing_fraction: backfacing },
            node_bounds: a.sphere_from_level,
            nodes,
            sphere_nodes,
            bytes_per_node,
            nodes_visited_max_per_pixel: nodes_max,
            blended_splats_per_hit: per_hit(stats.blended_splats),
            pss_steps_per_hit: per_hit(stats.traversal.pss_steps),
            pss_fallback_fraction: per_hit(stats.traversal.pss_fallbacks),
            accel_bytes: accel.memory_bytes(),
            bytes_per_splat: accel.memory_bytes() as f64 / point_count as f64,
            mean_radius,
            bounds_diagonal: bounds.diagonal(),
            camera_distance: a.eye.is_none().then(|| distance * bounds.diagonal()),
            peak_memory_bytes,
            peak_memory_bytes_per_point: peak_memory_bytes.map(|b| b as f64 / points_read.max(1) as f64),
            isa: pointray::accel::isa::active(),
            counters: stats,
        };
        let json = serde_json::to_string_pretty(&report)?;
        pointray_io::atomic_write(path, |w| w.write_all(json.as_bytes())).map_err(crate::failure::output)?;
    }
    Ok(())
}

fn is_exr(path: &std::path::Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"))
}

/// The linear radiance as `R`, `G`, `B` (the environment's flat colour outside the rendered
/// region) and each AOV asked for as a layer, in full-frame channels.
fn exr_channels(film: &Film, aovs: &[AovArg], width: u32, height: u32, outside: [f32; 3]) -> Vec<(String, Vec<f32>)> {
    let frame = |value: &dyn Fn(usize) -> f32, fill: f32| {
        let mut out = vec![fill; width as usize * height as usize];
        let r = film.region;
        for (row, y) in (r.y0..r.y1).enumerate() {
            for (col, x) in (r.x0..r.x1).enumerate() {
                out[y as usize * width as usize + x as usize] = value(row * r.width() as usize + col);
            }
        }
        out
    };
    let mut channels: Vec<(String, Vec<f32>)> = ["R", "G", "B"]
        .iter()
        .enumerate()
        .map(|(c, name)| (name.to_string(), frame(&|i| film.rgb[i][c], outside[c])))
        .collect();
    let mut add = |name: &str, value: &dyn Fn(usize) -> f32, fill: f32| {
        if !channels.iter().any(|(n, _)| n == name) {
            channels.push((name.to_string(), frame(value, fill)));
        }
    };
    for aov in aovs {
        match aov {
            AovArg::Nodes => add("nodes.Y", &|i| film.nodes_visited[i] as f32, 0.0),
            AovArg::Depth => add("depth.Z", &|i| first_hits(film).depth[i], f32::INFINITY),
            AovArg::Normal => {
                for (c, axis) in ["X", "Y", "Z"].iter().enumerate() {
                    add(&format!("normal.{axis}"), &|i| first_hits(film).normal[i][c], 0.0);
                }
            }
            AovArg::Albedo => {
                for (c, name) in ["R", "G", "B"].iter().enumerate() {
                    add(&format!("albedo.{name}"), &|i| first_hits(film).albedo[i][c], 0.0);
                }
            }
        }
    }
    channels
}

/// An AOV of the rendered region as 8-bit RGB.
fn aov_rgb8(film: &Film, aov: AovArg, nodes_max: u32) -> Vec<u8> {
    let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    match aov {
        AovArg::Nodes => pointray::metrics::heat_map_rgb8(&film.nodes_visited, nodes_max),
        AovArg::Normal => first_hits(film).normal.iter().flat_map(|n| n.map(|c| byte(0.5 * c + 0.5))).collect(),
        AovArg::Albedo => {
            let linear = &first_hits(film).albedo;
            linear.iter().flat_map(|c| c.map(|v| byte(pointray::film::linear_to_srgb(v)))).collect()
        }
        AovArg::Depth => {
            let depth = &first_hits(film).depth;
            let finite = depth.iter().copied().filter(|d| d.is_finite());
            let (near, far) = finite.fold((f32::INFINITY, 0.0f32), |(lo, hi), d| (lo.min(d), hi.max(d)));
            let range = (far - near).max(f32::MIN_POSITIVE);
            let shade = |d: f32| if d.is_finite() { byte(1.0 - 0.8 * (d - near) / range) } else { 0 };
            depth.iter().flat_map(|&d| [shade(d); 3]).collect()
        }
    }
}

/// The first hits' channels, which `RenderConfig::first_hit_aovs` has the render record
/// whenever an AOV other than the node counts is asked for.
fn first_hits(film: &Film) -> &pointray::film::FirstHitChannels {
    film.first_hits.as_ref().expect("the render records the first hits whenever their AOVs are asked for")
}

/// The full frame, black outside `region`, from the region's RGB8 pixels.
fn frame_from_region(rgb8: &[u8], region: Region, width: u32, height: u32) -> Vec<u8> {
    let mut frame = vec![0u8; width as usize * height as usize * 3];
    let row_bytes = region.width() as usize * 3;
    for (row, y) in (region.y0..region.y1).enumerate() {
        let dst = (y as usize * width as usize + region.x0 as usize) * 3;
        frame[dst..dst + row_bytes].copy_from_slice(&rgb8[row * row_bytes..(row + 1) * row_bytes]);
    }
    frame
}

/// Where an extra image goes: beside the output, `NAME.png` → `NAME.KIND.png`.
fn aov_path(output: &std::path::Path, kind: &str) -> std::path::PathBuf {
    let stem = output.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    output.with_file_name(format!("{stem}.{kind}.png"))
}

fn surface_kind(arg: SurfaceArg) -> SurfaceKind {
    match arg {
        SurfaceArg::Sj => SurfaceKind::Sj,
        SurfaceArg::Rfd => SurfaceKind::Rfd,
        SurfaceArg::Pss => SurfaceKind::Pss,
        SurfaceArg::FirstHit => SurfaceKind::FirstHit,
    }
}

/// `--ground`: a checkered grey plane just under the model's bounding box (along `up`), with
/// squares an eighth of the box's diagonal. It lies a thousandth of the diagonal below the
/// box, so that a floor of points in the model (the demo's) shows instead of fighting it.
fn floor_under(bounds: &pointray::math::Aabb, up: glam::Vec3) -> GroundPlane {
    let up = up.normalize();
    let lowest = bounds.corners().iter().map(|c| c.dot(up)).fold(f32::INFINITY, f32::min);
    let height = lowest - 1e-3 * bounds.diagonal();
    let grey = |c: f32| [pointray::film::srgb_to_linear(c); 3];
    GroundPlane {
        up,
        height,
        color: grey(0.8),
        checker: Some(Checker { color: grey(0.6), tile: bounds.diagonal() / 8.0 }),
        material: Material::standard(),
    }
}
