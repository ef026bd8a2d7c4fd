//! `pointray bench EXPERIMENT.toml`: measures an experiment's matrix on its models (thesis
//! E1: accelerator × surface scheme × level of detail × camera distance), with an Embree bench
//! beside it when the experiment names one, and writes JSON lines and CSV.
//!
//! Each model is loaded and preprocessed once, each accelerator variant built once. Each point
//! renders one untimed frame, which gives the image and the counters, then timed frames,
//! measured again when other processes were busy. Every image is compared with the
//! full-detail image of its scheme (and with the reference scheme's, if one is named). Embree
//! then traces the same pixels, timed with as many frames as pointray's full detail took.

pub mod experiment;
pub mod machine;
mod plot;
pub mod report;

use std::collections::BTreeMap;
use std::collections::btree_map::Entry;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::Vec3;
use pointray::PointCloud;
use pointray::film::{Film, ToneMap};
use pointray::metrics::compare_rgb8;
use pointray::settings::Settings;
use pointray::splat::DiskShape;
use pointray::splat::scheme::SurfaceKind;
use pointray::{Frame, Scene, render};
use serde::{Deserialize, Serialize};

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
    /// `git describe` of the checkout the bench ran in (it is meant to run in pointray's).
    pub checkout: Option<String>,
    pub machine: Machine,
    pub threads: usize,
    pub width: u32,
    pub height: u32,
    pub repeats: u32,
    pub min_seconds: f64,
    pub max_other_load: f64,
    pub retries: u32,
    pub shadows: bool,
    pub crop_to_model: bool,
    pub fov: f32,
    pub reference: Option<SurfaceKind>,
    #[serde(default)]
    pub converged_spp: Option<u32>,
    /// The Embree bench's file name, if one ran.
    pub embree: Option<String>,
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
    /// Samples a pixel (runs before the key have one).
    #[serde(default = "one_sample")]
    pub spp: u32,
    /// Through the footprint prefilter.
    #[serde(default)]
    pub prefilter: bool,
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
    /// The same against the scheme's converged image (full detail, the experiment's
    /// `converged_spp` samples a pixel), if the experiment asks for one.
    #[serde(default)]
    pub psnr_converged_db: Option<f64>,
    #[serde(default)]
    pub flip_converged: Option<f64>,
    /// Cores other processes kept busy during the kept attempt's timed frames.
    pub other_load_cores: Option<f64>,
    pub attempts: u32,
    /// The Embree bench on the same prepared cloud, camera and pixels (its oriented discs
    /// beside SJ, PSS and first-hit, its ray-facing discs beside RFD): rays per second, the
    /// rays it traced, its build time, and the cores other processes kept busy meanwhile.
    pub embree_mrays_per_second: Option<f64>,
    pub embree_rays: Option<u64>,
    pub embree_build_seconds: Option<f64>,
    pub embree_other_load_cores: Option<f64>,
    /// pointray's rays per second over Embree's.
    pub speed_vs_embree: Option<f64>,
    /// The Embree version its bench reports (`pointray-embree` does; older runs lack it).
    #[serde(default)]
    pub embree_version: Option<String>,
    pub image: Option<String>,
}

fn one_sample() -> u32 {
    1
}

pub fn run(a: &BenchArgs, quiet: bool) -> anyhow::Result<()> {
    let experiment = experiment::load(&a.experiment)?;
    let threads = if a.threads == 0 { std::thread::available_parallelism().map_or(1, |n| n.get()) } else { a.threads };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().context("cannot start the threads")?;
    pool.install(|| run_experiment(a, &experiment, threads, quiet))
}

fn run_experiment(a: &BenchArgs, e: &Experiment, threads: usize, quiet: bool) -> anyhow::Result<()> {
    // "." rather than "": a bench named by a bare file name is run from there, not looked up.
    let folder = a.experiment.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if let Some(unknown) = a.models.iter().find(|name| !e.models.iter().any(|m| &m.name == *name)) {
        let e = anyhow::anyhow!("--models: no model named {unknown:?} in {}", a.experiment.display());
        return Err(crate::failure::usage(e));
    }
    let models: Vec<&ModelSpec> =
        e.models.iter().filter(|m| a.models.is_empty() || a.models.contains(&m.name)).collect();
    let planned: usize = models.iter().map(|m| e.points(&m.name).len()).sum();
    if a.dry_run {
        for m in &models {
            for p in e.points(&m.name) {
                let (accel, surface) = (p.accel.name(), p.surface.name());
                let (lod, distance, spp) = (p.lod_threshold, p.distance, p.spp);
                let prefilter = if p.prefilter { " prefilter" } else { "" };
                println!("{} {accel} {surface} lod {lod} distance {distance} spp {spp}{prefilter}", m.name);
            }
        }
        println!("{planned} points");
        return Ok(());
    }
    let embree = e.embree.as_ref().map(|bench| folder.join(bench));
    if let Some(bench) = &embree {
        anyhow::ensure!(bench.is_file(), "{}: no Embree bench there (see experiments/README.md)", bench.display());
    }
    std::fs::create_dir_all(a.out.join("images")).with_context(|| format!("{}: cannot create", a.out.display()))?;
    // Written as measured, and renamed when complete: a run that fails leaves the last
    // complete results in place.
    let partial = a.out.join("results.jsonl.partial");
    let mut jsonl = std::io::BufWriter::new(
        std::fs::File::create(&partial).with_context(|| format!("{}: cannot create", partial.display()))?,
    );
    let header = Header {
        kind: "header".into(),
        title: e.title.clone(),
        experiment: a.experiment.display().to_string(),
        pointray: env!("CARGO_PKG_VERSION").into(),
        checkout: git_describe(),
        machine: Machine::describe(),
        threads,
        width: e.width,
        height: e.height,
        repeats: e.repeats,
        min_seconds: e.min_seconds,
        max_other_load: e.max_other_load,
        retries: e.retries,
        shadows: e.shadows,
        crop_to_model: e.camera.crop_to_model,
        fov: e.camera.fov,
        reference: e.reference,
        converged_spp: e.converged_spp,
        embree: embree.as_ref().and_then(|b| b.file_name()).map(|n| n.to_string_lossy().into_owned()),
    };
    let mut line = |record: &dyn erased::Line| -> anyhow::Result<()> {
        writeln!(jsonl, "{}", record.json()?)?;
        jsonl.flush()?;
        Ok(())
    };
    line(&header)?;
    let mut records = Vec::new();
    let bar = crate::progress::bar(planned as u64, "bench", quiet);
    for spec in models {
        let mut model = load_model(spec, e, folder, a, quiet)?;
        line(&model.record)?;
        let mut measured = measure_model(e, &model, &a.out, &|| bar.inc(1))?;
        if let Some(bench) = &embree {
            beside_embree(bench, &mut model, e, threads, &a.out, &mut measured)?;
        }
        for record in measured {
            line(&record)?;
            records.push(record);
        }
    }
    bar.finish_and_clear();
    jsonl.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    let jsonl_path = a.out.join("results.jsonl");
    std::fs::rename(&partial, &jsonl_path).with_context(|| format!("{}: cannot write", jsonl_path.display()))?;
    let csv_path = a.out.join("results.csv");
    pointray_io::atomic_write(&csv_path, |w| {
        let mut csv = csv::Writer::from_writer(w);
        records.iter().try_for_each(|r| csv.serialize(r)).map_err(std::io::Error::other)?;
        csv.flush()
    })?;
    if !quiet {
        eprintln!("{} points measured; wrote {} and {}", records.len(), jsonl_path.display(), csv_path.display());
    }
    if let Some(path) = &a.report {
        let figures = a.figures.clone().unwrap_or_else(|| default_figures(path));
        report::write_report(&a.out, path, &figures, &command_line())?;
    }
    Ok(())
}

/// JSON lines of different record types through one writer.
mod erased {
    pub trait Line {
        fn json(&self) -> serde_json::Result<String>;
    }

    impl<T: serde::Serialize> Line for T {
        fn json(&self) -> serde_json::Result<String> {
            serde_json::to_string(self)
        }
    }
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

fn git_describe() -> Option<String> {
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

fn load_model(spec: &ModelSpec, e: &Experiment, folder: &Path, a: &BenchArgs, quiet: bool) -> anyhow::Result<Model> {
    let config = a.preprocess.config();
    config.check().map_err(|e| crate::failure::usage(crate::commands::render::flag_error(e)))?;
    let spinner = crate::progress::spinner("read", quiet);
    let stage = |s: &str| spinner.set_message(s.to_string());
    let (cloud, source, points_read, preprocess, load_seconds) = match spec.source(folder)? {
        Source::Cloud(path) => {
            let p =
                pointray_io::source::read_prepared(std::slice::from_ref(&path), &config, &Default::default(), &stage)?;
            (p.cloud, path.display().to_string(), p.points_read, p.preprocess, p.read_seconds)
        }
        Source::Mesh { path, points } => {
            let t = Instant::now();
            let normals = pointray::mesh_sampling::SampleNormals::Smooth;
            let mut cloud = crate::commands::sample::sample_mesh(&path, points as usize, 1, normals, quiet)?.cloud;
            let seconds = t.elapsed().as_secs_f64();
            let source = format!("{} ({points} points sampled)", path.display());
            let stats = pointray_io::source::prepare(&mut cloud, &config, &source, &stage)
                .map_err(|e| anyhow::anyhow!("{source}: {e}"))?;
            (cloud, source, points as usize, stats, seconds)
        }
    };
    spinner.finish_and_clear();
    let radii = cloud.radii.as_deref().unwrap_or_default();
    let mean_radius = radii.iter().map(|&r| f64::from(r)).sum::<f64>() / radii.len().max(1) as f64;
    let record = ModelRecord {
        kind: "model".into(),
        model: spec.name.clone(),
        source,
        points_read,
        points: cloud.len(),
        load_seconds,
        preprocess_seconds: preprocess.seconds.total(),
        bounds_diagonal: cloud.bounds().diagonal(),
        mean_radius,
    };
    Ok(Model {
        name: spec.name.clone(),
        view_dir: Vec3::from(spec.view_dir.unwrap_or(e.camera.view_dir)),
        up: Vec3::from(spec.up.unwrap_or(e.camera.up)),
        cloud,
        record,
    })
}

/// The settings of a point of the matrix: the experiment's camera and frame, Whitted shading
/// under a headlight, the work counted.
fn settings(e: &Experiment, model: &Model, p: &Point) -> Settings {
    Settings {
        width: e.width,
        height: e.height,
        accel: p.accel.kind(),
        sphere_from_level: p.accel.node_bounds(),
        surface: p.surface,
        lod_threshold: p.lod_threshold,
        prefilter: p.prefilter,
        spp: p.spp,
        view_dir: Some(model.view_dir),
        up: Some(model.up),
        distance: Some(p.distance),
        fov: e.camera.fov,
        crop_to_model: e.camera.crop_to_model,
        shadows: e.shadows,
        max_depth: 0,
        seed: 1,
        count_work: true,
        ..Settings::default()
    }
}

/// The film's region as sRGB8, the pixels its comparisons and images hold.
fn region_srgb8(film: &Film) -> Vec<u8> {
    let srgb8 = ToneMap::CLAMP.encoder();
    film.rgb.iter().flat_map(|c| c.map(&srgb8)).collect()
}

/// A scene built for one variant and disk shape, with what the build cost.
struct Built {
    scene: Scene,
    seconds: f64,
}

/// The full-detail images a point is compared with, shared by every accelerator (they agree
/// there), each of the frame's region as sRGB8.
#[derive(Default)]
struct FullDetail {
    /// By (distance, scheme, samples a pixel).
    own: BTreeMap<(u32, SurfaceKind, u32), Vec<u8>>,
    /// The converged images, by (distance, scheme).
    converged: BTreeMap<(u32, SurfaceKind), Vec<u8>>,
}

impl FullDetail {
    /// Renders what `p` is compared with and has not been rendered yet: its scheme's full
    /// detail at its samples a pixel, the reference scheme's, and the converged images.
    fn render_for(&mut self, e: &Experiment, model: &Model, p: &Point, scene: &Scene) -> anyhow::Result<()> {
        let full = |surface, spp| Point { surface, spp, lod_threshold: 0.0, prefilter: false, ..*p };
        let distance = p.distance.to_bits();
        // The reference scheme's disks are oriented (`experiment::check`), which every
        // accelerator's bounds hold.
        for q in std::iter::once(full(p.surface, p.spp)).chain(e.reference.map(|r| full(r, p.spp))) {
            if let Entry::Vacant(entry) = self.own.entry((distance, q.surface, q.spp)) {
                entry.insert(region_srgb8(&render(scene, &settings(e, model, &q))?.film));
            }
        }
        if let (Some(spp), Entry::Vacant(entry)) = (e.converged_spp, self.converged.entry((distance, p.surface))) {
            entry.insert(region_srgb8(&render(scene, &settings(e, model, &full(p.surface, spp)))?.film));
        }
        Ok(())
    }
}

fn measure_model(e: &Experiment, model: &Model, out: &Path, tick: &dyn Fn()) -> anyhow::Result<Vec<PointRecord>> {
    let mut built: Option<((AccelVariant, DiskShape), Built)> = None;
    let mut full_detail = FullDetail::default();
    let mut records = Vec::new();
    for p in e.points(&model.name) {
        let key = (p.accel, p.surface.shape());
        if built.as_ref().is_none_or(|(k, _)| *k != key) {
            // One accelerator in memory at a time: the next replaces it.
            drop(built.take());
            let scene = Scene::build(model.cloud.clone().into(), &settings(e, model, &p))?;
            built = Some((key, Built { seconds: scene.build_seconds(), scene }));
        }
        let (_, built) = built.as_ref().expect("built above");
        full_detail.render_for(e, model, &p, &built.scene)?;
        records.push(measure_point(e, model, &p, built, &full_detail, out)?);
        tick();
    }
    Ok(records)
}

#[allow(clippy::too_many_arguments)]
fn measure_point(
    e: &Experiment,
    model: &Model,
    p: &Point,
    built: &Built,
    full_detail: &FullDetail,
    out: &Path,
) -> anyhow::Result<PointRecord> {
    let job = built.scene.job(&settings(e, model, p))?;
    let region = job.config.region;
    let t = Instant::now();
    let Frame { film, stats, .. } = job.render(&|_| {})?;
    let first_seconds = t.elapsed().as_secs_f64();
    let image = region_srgb8(&film);
    let (w, h) = (region.width(), region.height());
    let distance = p.distance.to_bits();
    let own_full = &full_detail.own[&(distance, p.surface, p.spp)];
    let own = compare_rgb8(&image, own_full);
    let flip = crate::perceptual::flip_mean(own_full, &image, w, h);
    let against =
        |other: &[u8]| (compare_rgb8(&image, other).psnr_db, crate::perceptual::flip_mean(other, &image, w, h));
    let reference = e.reference.and_then(|r| full_detail.own.get(&(distance, r, p.spp))).map(|r| against(r));
    let converged = full_detail.converged.get(&(distance, p.surface)).map(|c| against(c));
    let frames = e.repeats.max((e.min_seconds / first_seconds.max(1e-6)).ceil().min(1000.0) as u32);
    // The counts are the first frame's; the timed frames count nothing.
    let timed = job.uncounted();

    // Timed frames; again while other processes were busy, keeping the quietest attempt.
    let mut best: Option<(Vec<f64>, Option<f64>)> = None;
    let mut attempts = 0;
    while attempts <= e.retries {
        attempts += 1;
        let load = LoadSample::now();
        let times: Vec<f64> = (0..frames)
            .map(|_| {
                let t = Instant::now();
                let _ = timed.render(&|_| {});
                t.elapsed().as_secs_f64()
            })
            .collect();
        let other = load.other_cores_since();
        if best.as_ref().is_none_or(|(_, o)| other.unwrap_or(0.0) < o.unwrap_or(0.0)) {
            best = Some((times, other));
        }
        if other.is_none_or(|o| o <= e.max_other_load) {
            break;
        }
    }
    let (mut times, other_load_cores) = best.expect("one attempt at least");
    times.sort_by(f64::total_cmp);
    let seconds = pointray::stats::median(&times);

    let (accel, surface) = (p.accel.name(), p.surface.name());
    let samples = if p.spp == 1 { String::new() } else { format!("_spp{}", p.spp) };
    let prefilter = if p.prefilter { "_prefilter" } else { "" };
    let image_name =
        format!("{}_{accel}_{surface}_d{}_t{}{samples}{prefilter}.png", model.name, p.distance, p.lod_threshold);
    pointray_io::write_png(&out.join("images").join(&image_name), w, h, &image)?;
    let per_ray = |n: u64| n as f64 / stats.rays.max(1) as f64;
    Ok(PointRecord {
        kind: "point".into(),
        model: model.name.clone(),
        points: model.cloud.len(),
        accel: p.accel.name(),
        surface: p.surface,
        lod_threshold: p.lod_threshold,
        distance: p.distance,
        spp: p.spp,
        prefilter: p.prefilter,
        pixels: region.pixel_count(),
        rays: stats.rays,
        frames,
        render_seconds: seconds,
        render_seconds_min: times[0],
        render_seconds_max: times[times.len() - 1],
        mrays_per_second: stats.rays as f64 / seconds / 1e6,
        hit_fraction: stats.hit_fraction(),
        nodes_visited_per_ray: stats.nodes_visited_per_ray(),
        box_tests_per_ray: per_ray(stats.traversal.box_tests),
        sphere_tests_per_ray: per_ray(stats.traversal.sphere_tests),
        splat_tests_per_ray: stats.splat_tests_per_ray(),
        lod_stops_per_ray: per_ray(stats.traversal.lod_stops),
        build_seconds: built.seconds,
        accel_bytes: built.scene.memory_bytes(),
        psnr_db: own.psnr_db,
        differing_pixels: own.differing_pixels,
        flip,
        psnr_reference_db: reference.and_then(|r| r.0),
        flip_reference: reference.map(|r| r.1),
        psnr_converged_db: converged.and_then(|c| c.0),
        flip_converged: converged.map(|c| c.1),
        other_load_cores,
        attempts,
        embree_mrays_per_second: None,
        embree_rays: None,
        embree_build_seconds: None,
        embree_other_load_cores: None,
        speed_vs_embree: None,
        embree_version: None,
        image: Some(format!("images/{image_name}")),
    })
}

/// Runs the Embree bench on the model as pointray prepared it, written re-centred (Embree
/// works in f32), with the experiment's camera and pixels: once per disk shape and distance
/// that the model's points use, timed with as many frames as pointray's first full-detail
/// point there took. Fills in the Embree columns of `records`.
fn beside_embree(
    bench: &Path,
    model: &mut Model,
    e: &Experiment,
    threads: usize,
    out: &Path,
    records: &mut [PointRecord],
) -> anyhow::Result<()> {
    let prepared = tempfile::Builder::new()
        .prefix(&format!("{}.", model.name))
        .suffix(".ply")
        .tempfile_in(out)
        .with_context(|| format!("{}: cannot create a file", out.display()))?;
    let origin = std::mem::replace(&mut model.cloud.origin, glam::DVec3::ZERO);
    let written = pointray_io::write_ply(prepared.path(), &model.cloud);
    model.cloud.origin = origin;
    written?;
    let mut runs: BTreeMap<(DiskShape, u32), EmbreeRun> = BTreeMap::new();
    for r in records.iter() {
        let key = (r.surface.shape(), r.distance.to_bits());
        if runs.contains_key(&key) {
            continue;
        }
        // As many frames as pointray's full-detail point at this distance (or this point's).
        let frames = records
            .iter()
            .find(|f| f.surface.shape() == key.0 && f.distance == r.distance && f.lod_threshold == 0.0)
            .map_or(r.frames, |f| f.frames);
        let run = run_embree(bench, prepared.path(), key.0, r.distance, frames, model, e, threads)?;
        runs.insert(key, run);
    }
    for r in records.iter_mut() {
        let run = &runs[&(r.surface.shape(), r.distance.to_bits())];
        r.embree_mrays_per_second = Some(run.mrays_per_second);
        r.embree_rays = Some(run.rays);
        r.embree_build_seconds = Some(run.build_seconds);
        r.embree_other_load_cores = run.other_load_cores;
        // Camera rays a second against Embree's (it counts only those, its shadow rays timed
        // with them): pointray's rays count its shadow rays too.
        let camera_rays = (r.pixels * u64::from(r.spp)) as f64;
        r.speed_vs_embree = Some(camera_rays / r.render_seconds / 1e6 / run.mrays_per_second);
        r.embree_version.clone_from(&run.version);
    }
    Ok(())
}

/// One of Embree's measurements: a geometry at a distance.
struct EmbreeRun {
    mrays_per_second: f64,
    build_seconds: f64,
    rays: u64,
    other_load_cores: Option<f64>,
    version: Option<String>,
}

#[allow(clippy::too_many_arguments)]
fn run_embree(
    bench: &Path,
    cloud: &Path,
    shape: DiskShape,
    distance: f32,
    frames: u32,
    model: &Model,
    e: &Experiment,
    threads: usize,
) -> anyhow::Result<EmbreeRun> {
    let list = |v: Vec3| format!("{},{},{}", v.x, v.y, v.z);
    let geom = match shape {
        DiskShape::Oriented => "oriented",
        DiskShape::RayFacing => "disc",
    };
    let mut command = std::process::Command::new(bench);
    command.arg(cloud).args(["--geom", geom, "--threads", &threads.to_string(), "--dist", &distance.to_string()]);
    command.args(["--size", &format!("{}x{}", e.width, e.height), "--fov", &e.camera.fov.to_string()]);
    command.args(["--view", &list(model.view_dir), "--up", &list(model.up), "--reps", &frames.to_string()]);
    if e.camera.crop_to_model {
        command.arg("--crop");
    }
    if e.shadows {
        // The same work as pointray's frames: a shadow ray from each hit.
        command.arg("--shadows");
    }
    let load = LoadSample::now();
    let output = command.output().with_context(|| format!("{}: cannot run", bench.display()))?;
    let other_load_cores = load.other_cores_since();
    let failed = || format!("{} on {} at distance {distance}", bench.display(), model.name);
    anyhow::ensure!(output.status.success(), "{} failed: {}", failed(), String::from_utf8_lossy(&output.stderr).trim());
    let stdout = String::from_utf8_lossy(&output.stdout);
    let line = stdout.lines().rfind(|l| l.starts_with('{')).with_context(|| format!("{}: no JSON line", failed()))?;
    let v: serde_json::Value = serde_json::from_str(line).with_context(failed)?;
    let number = |key: &str| v[key].as_f64().with_context(|| format!("{}: no {key:?} in its output", failed()));
    Ok(EmbreeRun {
        mrays_per_second: number("mrays_s")?,
        build_seconds: number("build_s")?,
        rays: number("rays")? as u64,
        other_load_cores,
        version: v["embree_version"].as_str().map(str::to_string),
    })
}
