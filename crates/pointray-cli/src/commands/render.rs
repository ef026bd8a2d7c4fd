//! `pointray render`: the input (a cloud, a scene file, or the built-in demo) read and prepared
//! by `pointray_io::source`, built and rendered by the library (`pointray::scene`), then the
//! PNG or EXR, the AOVs and the statistics written.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use pointray::camera_path::Animation;
use pointray::frame::{Frame, FrameReport};
use pointray::scene::{RenderJob, Scene, SceneError, SceneParts};
use pointray::settings::{Settings, SettingsError};
use pointray_io::source::Source;
use serde::Serialize;

use crate::args::RenderArgs;
use crate::failure;

/// What `--stats` writes: the library's report of the frame, with what the command measured
/// around it.
#[derive(Serialize)]
struct StatsReport {
    input: String,
    /// Points the reader returned (a PCD's NaN points are already dropped there).
    points_read: usize,
    threads: usize,
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
    mrays_per_second: f64,
    primary_mrays_per_second: f64,
    /// The process's peak resident memory (load, preprocessing, build and render), where the
    /// system tells it (Linux).
    peak_memory_bytes: Option<u64>,
    peak_memory_bytes_per_point: Option<f64>,
    #[serde(flatten)]
    frame: FrameReport,
}

#[derive(Serialize)]
struct PreprocessSeconds {
    total: f64,
    #[serde(flatten)]
    stages: pointray::preprocess::StageSeconds,
}

pub fn run(a: &RenderArgs, quiet: bool) -> anyhow::Result<()> {
    check_outputs(a)?;
    a.settings().check().map_err(|e| failure::usage(flag_error(e)))?;
    a.preprocess.config().check().map_err(|e| failure::usage(flag_error(e)))?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads.unwrap_or(0)).build()?;
    pool.install(|| run_in_pool(a, quiet, pool.current_num_threads()))
}

/// A setting out of range, named by its flag.
pub fn flag_error(e: SettingsError) -> anyhow::Error {
    // Lists are repeated flags of one item each.
    let flag = match e.option {
        "clip_planes" => "clip-plane".to_string(),
        "aovs" => "aov".to_string(),
        option => option.replace('_', "-"),
    };
    anyhow::anyhow!("--{flag} {}", e.problem)
}

/// Refuses, before any work, an output that cannot be written or whose format is unknown.
fn check_outputs(a: &RenderArgs) -> anyhow::Result<()> {
    let format = a.output.extension().map(|e| e.to_ascii_lowercase());
    if !format.is_some_and(|e| e == "png" || e == "exr" || e == "mp4") {
        let e = anyhow::anyhow!("-o {}: the extension chooses the format, .png, .exr or .mp4", a.output.display());
        return Err(failure::usage(e));
    }
    super::check_output_path(&a.output)?;
    // Only a scene file can hold an animation: without one, frames asked for are refused now.
    let scene_file = matches!(a.inputs.as_slice(), [path] if pointray_io::source::is_scene(path));
    if super::animation::asked(a) && a.turntable == 0 && !scene_file {
        return Err(failure::usage(super::animation::missing()));
    }
    if a.bit_depth != 8 && is_exr(&a.output) {
        return Err(failure::usage(anyhow::anyhow!("--bit-depth is the PNG's; an EXR holds floats")));
    }
    if let Some(stats) = &a.stats {
        super::check_output_path(stats)?;
    }
    // An EXR holds the AOVs as layers; beside a PNG each is a PNG of its own.
    for aov in a.aov.iter().filter(|_| !is_exr(&a.output)) {
        super::check_output_path(&aov_path(&a.output, aov.name()))?;
    }
    Ok(())
}

fn run_in_pool(a: &RenderArgs, quiet: bool, threads: usize) -> anyhow::Result<()> {
    // Read first: a bad map fails before the cloud's work.
    let env_map = pointray_io::source::environment_map(&a.settings())?;
    let (source, input_name) = load_input(a, quiet)?;
    let settings = match (&source.settings, a.inputs.as_slice()) {
        (Some(scene), [path]) => crate::scene::settings(path, scene, a)?,
        _ => a.settings(),
    };
    let (points_read, preprocess, load_seconds) = (source.points_read, source.preprocess.clone(), source.load_seconds);
    let source_animation = source.animation.clone();
    let (mut scene, builds) = build(source.parts, &settings, a.bench_builds, quiet).context(input_name.clone())?;
    scene.set_environment_map(env_map);
    tracing::info!("built {} over {} splats in {:.3} s", scene.accel_name(), scene.points(), builds[0]);
    // A scene file's animation is rendered where the flags ask for frames; else its camera's view.
    let animation = match a.turntable {
        0 => source_animation.filter(|_| super::animation::asked(a)),
        n => Some(Animation::orbit(n).map_err(|e| failure::usage(flag_error(e)))?),
    };
    match animation {
        Some(animation) => return super::animation::run(a, &scene, &settings, &animation, quiet).context(input_name),
        None if super::animation::asked(a) => return Err(failure::usage(super::animation::missing())),
        None => {}
    }
    let job = scene.job(&settings).map_err(|e| failure::usage(flag_error(e).context(input_name.clone())))?;
    let (frame, render_seconds, render_seconds_min) =
        render_frames(&job, a.bench_frames, quiet).with_context(|| input_name.clone())?;
    write_images(a, &a.output, &settings, &frame)?;
    let stats = &frame.stats;
    let mrays = stats.rays as f64 / render_seconds / 1e6;
    if !quiet {
        let r = frame.film.region;
        eprintln!(
            "{input_name}: {} points, {} {}x{} px, {render_seconds:.3} s ({mrays:.2} Mrays/s), hits {:.1}%, wrote {}",
            scene.points(),
            scene.accel_name(),
            r.width(),
            r.height(),
            stats.hit_fraction() * 100.0,
            a.output.display()
        );
    }
    let Some(path) = &a.stats else { return Ok(()) };
    let peak_memory_bytes = super::peak_memory_bytes();
    let report = StatsReport {
        input: input_name,
        points_read,
        threads,
        load_seconds,
        preprocess_seconds: PreprocessSeconds { total: preprocess.seconds.total(), stages: preprocess.seconds },
        preprocess,
        build_seconds: pointray::stats::median(&builds),
        build_seconds_min: builds[0],
        timed_builds: a.bench_builds,
        render_seconds,
        render_seconds_min,
        timed_frames: a.bench_frames,
        mrays_per_second: mrays,
        primary_mrays_per_second: stats.primary_rays as f64 / render_seconds / 1e6,
        peak_memory_bytes,
        peak_memory_bytes_per_point: peak_memory_bytes.map(|b| b as f64 / points_read.max(1) as f64),
        frame: job.report(&frame),
    };
    let json = serde_json::to_string_pretty(&report)?;
    pointray_io::atomic_write(path, |w| w.write_all(json.as_bytes())).map_err(failure::output)
}

/// The input read and prepared (the demo made and prepared), and its name for messages.
fn load_input(a: &RenderArgs, quiet: bool) -> anyhow::Result<(Source, String)> {
    let config = a.preprocess.config();
    let spinner = crate::progress::spinner("read", quiet);
    let stage = |s: &str| spinner.set_message(s.to_string());
    let loaded = match a.inputs.as_slice() {
        [] => (
            pointray_io::source::demo(a.demo_points, a.seed, &config, &stage).map_err(anyhow::Error::msg)?,
            "demo".into(),
        ),
        paths => (
            pointray_io::source::load_tiles(paths, &config, &a.read.options(), &stage)?,
            pointray_io::set_name(paths).display().to_string(),
        ),
    };
    spinner.finish_and_clear();
    Ok(loaded)
}

/// The scene, built `timed` times (`--bench-builds`: the first build in a process pays for its
/// fresh memory), each from a copy made before its clock starts, the last from the parts
/// themselves; and the builds' seconds, fastest first.
fn build(parts: SceneParts, settings: &Settings, timed: u32, quiet: bool) -> anyhow::Result<(Scene, Vec<f64>)> {
    let build = |parts| {
        crate::progress::spinning("build", quiet, || Scene::build(parts, settings)).map_err(|e| match e {
            // A colour or class flag the cloud cannot give: named as the flag.
            SceneError::Settings(e) => flag_error(e),
            e => e.into(),
        })
    };
    let mut seconds = Vec::new();
    for _ in 1..timed {
        seconds.push(build(parts.clone())?.build_seconds());
    }
    let scene = build(parts)?;
    seconds.push(scene.build_seconds());
    seconds.sort_by(f64::total_cmp);
    Ok((scene, seconds))
}

/// One frame for the image, then `timed` benchmark frames into one film, as a renderer showing
/// frame after frame would (they count no work: the statistics' counts are the first
/// frame's). The frame, and the median and least seconds of the timed frames (the first
/// frame's when there are none).
fn render_frames(job: &RenderJob, timed: u32, quiet: bool) -> Result<(Frame, f64, f64), pointray::RenderError> {
    let bar = crate::progress::bar(job.config.region.pixel_count(), "render", quiet);
    let t = Instant::now();
    let frame = job.render(&|n| bar.inc(n))?;
    let first_seconds = t.elapsed().as_secs_f64();
    bar.finish_and_clear();
    let (uncounted, mut times) = (job.uncounted(), Vec::new());
    let mut scratch = None;
    for _ in 0..timed {
        let scratch = scratch.get_or_insert_with(|| uncounted.film());
        let t = Instant::now();
        let _ = uncounted.render_into(scratch, &|_| {});
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    match times.len() {
        0 => Ok((frame, first_seconds, first_seconds)),
        _ => Ok((frame, pointray::stats::median(&times), times[0])),
    }
}

/// The PNG at `out` and the AOVs beside it as PNGs, or the EXR with the AOVs as layers.
pub(super) fn write_images(a: &RenderArgs, out: &Path, settings: &Settings, frame: &Frame) -> anyhow::Result<()> {
    let (w, h) = (frame.width, frame.height);
    if is_exr(out) {
        let channels = frame.float_channels(&settings.aovs);
        return pointray_io::write_exr(out, w, h, channels).map_err(failure::output);
    }
    let tone = settings.tone_map();
    match (a.transparent, a.bit_depth) {
        (true, 16) => pointray_io::write_png16_rgba(out, w, h, &frame.srgba16(tone)),
        (true, _) => pointray_io::write_png_rgba(out, w, h, &frame.srgba8(tone)),
        (false, 16) => pointray_io::write_png16(out, w, h, &frame.srgb16(tone)),
        (false, _) => pointray_io::write_png(out, w, h, &frame.srgb8(tone)),
    }
    .map_err(failure::output)?;
    // The AOVs asked for (not the alpha that --transparent records for itself).
    let mut written = Vec::new();
    for &aov in &a.aov {
        if !written.contains(&aov) {
            let path = aov_path(out, aov.name());
            pointray_io::image::write_png(&path, w, h, &frame.aov_rgb8(aov)).map_err(failure::output)?;
            written.push(aov);
        }
    }
    Ok(())
}

fn is_exr(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"))
}

/// Where an extra image goes: beside the output, `NAME.png` → `NAME.KIND.png`.
fn aov_path(output: &Path, kind: &str) -> PathBuf {
    let stem = output.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    output.with_file_name(format!("{stem}.{kind}.png"))
}
