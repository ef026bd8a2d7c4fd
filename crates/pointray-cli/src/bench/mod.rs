//! `pointray bench EXPERIMENT.toml`: measures an experiment's matrix on its models (thesis
//! E1: accelerator × surface scheme × level of detail × camera distance), with Embree's point
//! bench beside it when the experiment names it, and writes JSON lines and CSV.
//!
//! Each model is loaded and preprocessed once, each accelerator variant built once. Each point
//! renders one untimed frame, which gives the image and the counters, then `repeats` timed
//! frames, measured again when other processes were busy. Every image is compared with the
//! full-detail image of its scheme (and with the reference scheme's, if one is named).

pub mod experiment;
pub mod machine;
mod plot;
pub mod report;

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::Vec3;
use pointray::PointCloud;
use pointray::camera::{Camera, Region};
use pointray::film::{Film, linear_to_srgb};
use pointray::metrics::compare_rgb8;
use pointray::render::RenderConfig;
use pointray::shading::{Environment, Light};
use pointray::splat::DiskShape;
use pointray::splat::scheme::{SurfaceKind, SurfaceScheme};
use pointray::splat::splats_from_cloud;
use serde::{Deserialize, Serialize};

use crate::any_accel::AnyAccel;
use crate::args::BenchArgs;
use experiment::{AccelVariant, Experiment, ModelSpec, Point, Source};
use machine::{LoadSample, Machine};

/// The first line of the JSON lines: what was measured, where and when.
#[derive(Serialize, Deserialize)]
pub struct Header {
    pub kind: String,
    pub title: String,
    pub experiment: String,
    pub pointray: String,
    pub commit: Option<String>,
    pub machine: Machine,
    pub threads: usize,
    pub width: u32,
    pub height: u32,
    pub repeats: u32,
    pub min_seconds: f64,
    pub shadows: bool,
    pub crop_to_model: bool,
    pub fov: f32,
    pub reference: Option<SurfaceKind>,
    pub embree: bool,
}

/// A model as loaded and preprocessed.
#[derive(Serialize, Deserialize)]
pub struct ModelRecord {
    pub kind: String,
    pub model: String,
    pub source: String,
    pub points_read: usize,
    pub points: usize,
    pub load_seconds: f64,
    pub preprocess_seconds: f64,
    pub bounds_diagonal: f32,
    pub mean_radius: f64,
}

/// One point of the matrix, measured. The CSV has one row of these per point.
#[derive(Serialize, Deserialize)]
pub struct PointRecord {
    pub kind: String,
    pub model: String,
    pub points: usize,
    pub accel: String,
    pub surface: SurfaceKind,
    pub lod_threshold: f32,
    pub distance: f32,
    /// Pixels traced (the model's projected box, when cropped).
    pub pixels: u64,
    pub rays: u64,
    pub frames: u32,
    /// Median, least and greatest of the timed frames.
    pub render_seconds: f64,
    pub render_seconds_min: f64,
    pub render_seconds_max: f64,
    pub mrays_per_second: f64,
    pub hit_fraction: f64,
    pub nodes_visited_per_ray: f64,
    pub box_tests_per_ray: f64,
    pub sphere_tests_per_ray: f64,
    pub splat_tests_per_ray: f64,
    pub lod_stops_per_ray: f64,
    pub build_seconds: f64,
    pub accel_bytes: usize,
    /// Against the scheme's full-detail image: PSNR (empty when identical), the pixels that
    /// differ, and the mean FLIP error (0 when identical).
    pub psnr_db: Option<f64>,
    pub differing_pixels: usize,
    pub flip: f64,
    /// The same against the reference scheme's full-detail image, if one is named.
    pub psnr_reference_db: Option<f64>,
    pub flip_reference: Option<f64>,
    /// Cores other processes kept busy during the kept attempt's timed frames.
    pub other_load_cores: Option<f64>,
    pub attempts: u32,
    /// Embree's point bench on the same prepared cloud, camera and pixels: its oriented discs
    /// beside SJ, PSS and first-hit, its ray-facing discs beside RFD.
    pub embree_mrays_per_second: Option<f64>,
    pub embree_build_seconds: Option<f64>,
    /// pointray's rays per second over Embree's.
    pub speed_vs_embree: Option<f64>,
    pub image: Option<String>,
}

pub fn run(a: &BenchArgs, quiet: bool) -> anyhow::Result<()> {
    let experiment = experiment::load(&a.experiment)?;
    let threads = if a.threads == 0 { std::thread::available_parallelism().map_or(1, |n| n.get()) } else { a.threads };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().context("cannot start the threads")?;
    pool.install(|| run_experiment(a, &experiment, threads, quiet))
}

fn run_experiment(a: &BenchArgs, e: &Experiment, threads: usize, quiet: bool) -> anyhow::Result<()> {
    let folder = a.experiment.parent().unwrap_or(Path::new("."));
    let models: Vec<&ModelSpec> =
        e.models.iter().filter(|m| a.models.is_empty() || a.models.contains(&m.name)).collect();
    anyhow::ensure!(!models.is_empty(), "--models {}: no such model in {}", a.models.join(","), a.experiment.display());
    let planned: usize = models.iter().map(|m| e.points(&m.name).len()).sum();
    if a.dry_run {
        for m in &models {
            for p in e.points(&m.name) {
                println!(
                    "{} {} {} lod {} distance {}",
                    m.name,
                    p.accel.name(),
                    p.surface.name(),
                    p.lod_threshold,
                    p.distance
                );
            }
        }
        println!("{planned} points");
        return Ok(());
    }
    std::fs::create_dir_all(a.out.join("images")).with_context(|| format!("{}: cannot create", a.out.display()))?;
    let jsonl_path = a.out.join("results.jsonl");
    let mut jsonl = std::io::BufWriter::new(
        std::fs::File::create(&jsonl_path).with_context(|| format!("{}: cannot create", jsonl_path.display()))?,
    );
    let header = Header {
        kind: "header".into(),
        title: e.title.clone(),
        experiment: a.experiment.display().to_string(),
        pointray: env!("CARGO_PKG_VERSION").into(),
        commit: git_commit(),
        machine: Machine::describe(),
        threads,
        width: e.width,
        height: e.height,
        repeats: e.repeats,
        min_seconds: e.min_seconds,
        shadows: e.shadows,
        crop_to_model: e.camera.crop_to_model,
        fov: e.camera.fov,
        reference: e.reference,
        embree: e.embree.is_some(),
    };
    writeln!(jsonl, "{}", serde_json::to_string(&header)?)?;
    let mut records = Vec::new();
    let bar = crate::progress::bar(planned as u64, "bench", quiet);
    for spec in models {
        let model = load_model(spec, folder, a, quiet)?;
        writeln!(jsonl, "{}", serde_json::to_string(&model.record)?)?;
        let embree = match &e.embree {
            Some(bench) => embree_runs(&folder.join(bench), &model, e, threads, &a.out)?,
            None => BTreeMap::new(),
        };
        for record in measure_model(e, &model, &embree, &a.out, &|| bar.inc(1))? {
            writeln!(jsonl, "{}", serde_json::to_string(&record)?)?;
            jsonl.flush()?;
            records.push(record);
        }
    }
    bar.finish_and_clear();
    let csv_path = a.out.join("results.csv");
    let mut csv =
        csv::Writer::from_path(&csv_path).with_context(|| format!("{}: cannot create", csv_path.display()))?;
    for r in &records {
        csv.serialize(r)?;
    }
    csv.flush()?;
    if !quiet {
        eprintln!("{} points measured; wrote {} and {}", records.len(), jsonl_path.display(), csv_path.display());
    }
    if let Some(path) = &a.report {
        let figures = a.figures.clone().unwrap_or_else(|| default_figures(path));
        report::write_report(&a.out, path, &figures, &command_line())?;
    }
    Ok(())
}

/// The report's figures go beside it, in `results/`.
pub fn default_figures(report: &Path) -> PathBuf {
    report.parent().unwrap_or(Path::new("")).join("results")
}

/// How this process was started, as a user would type it.
pub fn command_line() -> String {
    let args: Vec<String> = std::env::args().skip(1).collect();
    format!("pointray {}", args.join(" "))
}

/// `pointray report`: the report of an earlier run.
pub fn run_report(a: &crate::args::ReportArgs) -> anyhow::Result<()> {
    let figures = a.figures.clone().unwrap_or_else(|| default_figures(&a.output));
    report::write_report(&a.results, &a.output, &figures, &command_line())
}

/// The commit of the working tree pointray runs in, if it is a git checkout.
fn git_commit() -> Option<String> {
    let out = std::process::Command::new("git").args(["describe", "--always", "--dirty"]).output().ok()?;
    out.status.success().then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

struct Model {
    name: String,
    cloud: PointCloud,
    view_dir: Vec3,
    up: Vec3,
    record: ModelRecord,
}

fn load_model(spec: &ModelSpec, folder: &Path, a: &BenchArgs, quiet: bool) -> anyhow::Result<Model> {
    let t = Instant::now();
    let (mut cloud, source) = match spec.source(folder)? {
        Source::Cloud(path) => (crate::commands::load(&path, quiet)?.0.cloud, path.display().to_string()),
        Source::Mesh { path, points } => {
            let mesh = pointray_io::read_mesh(&path)?;
            let samples = pointray::mesh_sampling::sample_surface(
                &mesh.vertices.positions,
                &mesh.triangles,
                points as usize,
                1,
                pointray::mesh_sampling::SampleNormals::Smooth,
            )
            .with_context(|| format!("{}: sampling", path.display()))?;
            let cloud = PointCloud {
                positions: samples.positions,
                normals: Some(samples.normals),
                origin: mesh.vertices.origin,
                ..PointCloud::default()
            };
            (cloud, format!("{} ({points} points sampled)", path.display()))
        }
    };
    let load_seconds = t.elapsed().as_secs_f64();
    let points_read = cloud.len();
    let t = Instant::now();
    crate::commands::prepare_cloud(&mut cloud, &a.preprocess, &source, quiet)?;
    let preprocess_seconds = t.elapsed().as_secs_f64();
    let radii = cloud.radii.as_deref().unwrap_or_default();
    let mean_radius = radii.iter().map(|&r| f64::from(r)).sum::<f64>() / radii.len().max(1) as f64;
    let record = ModelRecord {
        kind: "model".into(),
        model: spec.name.clone(),
        source,
        points_read,
        points: cloud.len(),
        load_seconds,
        preprocess_seconds,
        bounds_diagonal: cloud.bounds().diagonal(),
        mean_radius,
    };
    let or = |v: Option<[f32; 3]>, default: [f32; 3]| Vec3::from(v.unwrap_or(default));
    Ok(Model {
        name: spec.name.clone(),
        view_dir: or(spec.view_dir, [0.4, 0.3, 1.0]),
        up: or(spec.up, [0.0, 1.0, 0.0]),
        cloud,
        record,
    })
}

/// The camera of a point, and the pixels it traces.
fn frame(e: &Experiment, model: &Model, distance: f32) -> (Camera, Region) {
    let bounds = model.cloud.bounds();
    let camera = Camera::orbit(&bounds, model.view_dir, model.up, distance, e.camera.fov, e.width, e.height);
    let region = if e.camera.crop_to_model { camera.region_of(&bounds) } else { Region::full(e.width, e.height) };
    (camera, region)
}

fn config(e: &Experiment, camera: &Camera, region: Region, surface: SurfaceKind, lod_threshold: f32) -> RenderConfig {
    RenderConfig {
        sampler: pointray::render::Sampler::R2,
        filter: pointray::render::Filter::Box,
        integrator: pointray::render::Integrator::Whitted,
        scheme: SurfaceScheme::of_kind(surface),
        // The command line's headlight, raised and shifted right (Embree's bench lights so too).
        lights: vec![Light::Directional {
            direction: -camera.forward() + 0.6 * camera.up() + 0.4 * camera.right(),
            intensity: 1.0,
        }],
        materials: vec![pointray::material::Material::standard()],
        shadows: e.shadows,
        shadow_offset: 1.0,
        environment: Environment::Uniform { color: [0.010, 0.011, 0.019] },
        ground: None,
        max_depth: 0,
        region,
        samples: 1,
        seed: 1,
        lod_threshold,
        diffuse_spread: 0.0,
        cull_backfaces: false,
    }
}

/// The film's region as sRGB8, the pixels its comparisons and images hold.
fn region_srgb8(film: &Film) -> Vec<u8> {
    film.rgb.iter().flat_map(|c| c.map(|v| (linear_to_srgb(v) * 255.0 + 0.5) as u8)).collect()
}

/// An accelerator built for one variant and disk shape, with what the build cost.
struct Built {
    accel: AnyAccel,
    seconds: f64,
}

fn measure_model(
    e: &Experiment,
    model: &Model,
    embree: &BTreeMap<(DiskShape, u32), EmbreeRun>,
    out: &Path,
    tick: &dyn Fn(),
) -> anyhow::Result<Vec<PointRecord>> {
    let points = e.points(&model.name);
    let mut builds: BTreeMap<(AccelVariant, bool), Built> = BTreeMap::new();
    // Full-detail images by (distance, scheme), shared by every accelerator (they agree there).
    let mut full_detail: BTreeMap<(u32, &'static str), Vec<u8>> = BTreeMap::new();
    let mut saved: std::collections::BTreeSet<String> = Default::default();
    let mut records = Vec::new();
    for p in points {
        let shape = p.surface.shape();
        let key = (p.accel, shape == DiskShape::RayFacing);
        if !builds.contains_key(&key) {
            // One accelerator in memory at a time: the next variant replaces it.
            builds.clear();
            let splats = splats_from_cloud(&model.cloud);
            let t = Instant::now();
            let accel = AnyAccel::build(p.accel.kind(), splats, p.accel.node_bounds(), shape);
            builds.insert(key, Built { accel, seconds: t.elapsed().as_secs_f64() });
        }
        let built = &builds[&key];
        let (camera, region) = frame(e, model, p.distance);
        let reference_image = |surface: SurfaceKind| {
            let (film, _) = built.accel.render(&camera, &config(e, &camera, region, surface, 0.0), &|_| {});
            region_srgb8(&film)
        };
        let distance_key = p.distance.to_bits();
        for surface in std::iter::once(p.surface).chain(e.reference) {
            if !full_detail.contains_key(&(distance_key, surface.name()))
                && (surface == p.surface || shape_holds(built, surface))
            {
                let image = reference_image(surface);
                full_detail.insert((distance_key, surface.name()), image);
            }
        }
        let record = measure_point(e, model, &p, built, &camera, region, &full_detail, embree, out, &mut saved)?;
        records.push(record);
        tick();
    }
    Ok(records)
}

fn shape_holds(built: &Built, surface: SurfaceKind) -> bool {
    built.accel.shape().holds(surface.shape())
}

#[allow(clippy::too_many_arguments)]
fn measure_point(
    e: &Experiment,
    model: &Model,
    p: &Point,
    built: &Built,
    camera: &Camera,
    region: Region,
    full_detail: &BTreeMap<(u32, &'static str), Vec<u8>>,
    embree: &BTreeMap<(DiskShape, u32), EmbreeRun>,
    out: &Path,
    saved: &mut std::collections::BTreeSet<String>,
) -> anyhow::Result<PointRecord> {
    let config = config(e, camera, region, p.surface, p.lod_threshold);
    let t = Instant::now();
    let (film, stats) = built.accel.render(camera, &config, &|_| {});
    let first_seconds = t.elapsed().as_secs_f64();
    let image = region_srgb8(&film);
    let distance_key = p.distance.to_bits();
    let (w, h) = (region.width(), region.height());
    let own_full = &full_detail[&(distance_key, p.surface.name())];
    let own = compare_rgb8(&image, own_full);
    let flip = crate::perceptual::flip_mean(own_full, &image, w, h);
    let reference = e.reference.and_then(|r| full_detail.get(&(distance_key, r.name()))).map(|reference| {
        (compare_rgb8(&image, reference).psnr_db, crate::perceptual::flip_mean(reference, &image, w, h))
    });
    let frames = e.repeats.max((e.min_seconds / first_seconds.max(1e-6)).ceil().min(1000.0) as u32);

    // Timed frames; again while other processes were busy, keeping the quietest attempt.
    let mut best: Option<(Vec<f64>, Option<f64>)> = None;
    let mut attempts = 0;
    while attempts <= e.retries {
        attempts += 1;
        let load = LoadSample::now();
        let times: Vec<f64> = (0..frames)
            .map(|_| {
                let t = Instant::now();
                let _ = built.accel.render(camera, &config, &|_| {});
                t.elapsed().as_secs_f64()
            })
            .collect();
        let other = load.other_cores_since();
        let quieter = best.as_ref().is_none_or(|(_, o)| other.unwrap_or(0.0) < o.unwrap_or(0.0));
        if quieter {
            best = Some((times, other));
        }
        if other.is_none_or(|o| o <= e.max_other_load) {
            break;
        }
    }
    let (mut times, other_load_cores) = best.expect("one attempt at least");
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];

    let image_name = format!("{}_{}_d{}_t{}.png", model.name, p.surface.name(), p.distance, p.lod_threshold);
    let image_file = if saved.insert(image_name.clone()) {
        let path = out.join("images").join(&image_name);
        pointray_io::write_png(&path, region.width(), region.height(), &image)?;
        Some(format!("images/{image_name}"))
    } else {
        None
    };
    let embree_run = embree.get(&(p.surface.shape(), distance_key));
    let mrays = stats.rays as f64 / median / 1e6;
    let per_ray = |n: u64| n as f64 / stats.rays.max(1) as f64;
    Ok(PointRecord {
        kind: "point".into(),
        model: model.name.clone(),
        points: model.cloud.len(),
        accel: p.accel.name(),
        surface: p.surface,
        lod_threshold: p.lod_threshold,
        distance: p.distance,
        pixels: region.pixel_count(),
        rays: stats.rays,
        frames,
        render_seconds: median,
        render_seconds_min: times[0],
        render_seconds_max: times[times.len() - 1],
        mrays_per_second: mrays,
        hit_fraction: stats.hit_fraction(),
        nodes_visited_per_ray: stats.nodes_visited_per_ray(),
        box_tests_per_ray: per_ray(stats.traversal.box_tests),
        sphere_tests_per_ray: per_ray(stats.traversal.sphere_tests),
        splat_tests_per_ray: stats.splat_tests_per_ray(),
        lod_stops_per_ray: per_ray(stats.traversal.lod_stops),
        build_seconds: built.seconds,
        accel_bytes: built.accel.memory_bytes(),
        psnr_db: own.psnr_db,
        differing_pixels: own.differing_pixels,
        flip,
        psnr_reference_db: reference.and_then(|r| r.0),
        flip_reference: reference.map(|r| r.1),
        other_load_cores,
        attempts,
        embree_mrays_per_second: embree_run.map(|r| r.mrays_per_second),
        embree_build_seconds: embree_run.map(|r| r.build_seconds),
        speed_vs_embree: embree_run.map(|r| mrays / r.mrays_per_second),
        image: image_file,
    })
}

/// One of Embree's measurements: a geometry at a distance.
#[derive(Clone, Copy, Debug, Serialize)]
struct EmbreeRun {
    mrays_per_second: f64,
    build_seconds: f64,
    rays: u64,
    other_load_cores: f64,
}

/// Runs Embree's point bench on the model, prepared as pointray prepared it, with the camera
/// and pixels of the experiment: oriented discs and ray-facing discs at every distance the
/// model's points use. Keyed by the disk shape and the distance's bits.
fn embree_runs(
    bench: &Path,
    model: &Model,
    e: &Experiment,
    threads: usize,
    out: &Path,
) -> anyhow::Result<BTreeMap<(DiskShape, u32), EmbreeRun>> {
    anyhow::ensure!(bench.is_file(), "{}: no Embree bench there (see shared/bench/embree)", bench.display());
    let prepared: PathBuf = out.join(format!("{}.prepared.ply", model.name));
    pointray_io::write_ply(&prepared, &model.cloud)?;
    let points = e.points(&model.name);
    let mut runs = BTreeMap::new();
    for (shape, geom) in [(DiskShape::Oriented, "oriented"), (DiskShape::RayFacing, "disc")] {
        let mut distances: Vec<f32> =
            points.iter().filter(|p| p.surface.shape() == shape).map(|p| p.distance).collect();
        distances.sort_by(f32::total_cmp);
        distances.dedup();
        if distances.is_empty() {
            continue;
        }
        let list = |v: Vec3| format!("{},{},{}", v.x, v.y, v.z);
        let dist = distances.iter().map(f32::to_string).collect::<Vec<_>>().join(",");
        let mut command = std::process::Command::new(bench);
        command.arg(&prepared).args(["--geom", geom, "--threads", &threads.to_string(), "--dist", &dist]);
        command.args(["--size", &format!("{}x{}", e.width, e.height), "--fov", &e.camera.fov.to_string()]);
        command.args(["--view", &list(model.view_dir), "--up", &list(model.up)]);
        command.args(["--reps", &e.repeats.to_string(), "--retries", &e.retries.to_string()]);
        if e.camera.crop_to_model {
            command.arg("--crop");
        }
        let output = command.output().with_context(|| format!("{}: cannot run", bench.display()))?;
        anyhow::ensure!(
            output.status.success(),
            "{} failed: {}",
            bench.display(),
            String::from_utf8_lossy(&output.stderr).trim()
        );
        for line in String::from_utf8_lossy(&output.stdout).lines().filter(|l| l.starts_with('{')) {
            let v: serde_json::Value = serde_json::from_str(line).context("Embree bench output")?;
            let number = |key: &str| v[key].as_f64().with_context(|| format!("Embree bench output lacks {key}"));
            let k = number("k")? as f32;
            runs.insert(
                (shape, k.to_bits()),
                EmbreeRun {
                    mrays_per_second: number("mrays_s")?,
                    build_seconds: number("build_s")?,
                    rays: number("rays")? as u64,
                    other_load_cores: number("other_cores")?,
                },
            );
        }
    }
    std::fs::remove_file(&prepared).ok();
    Ok(runs)
}
