pub mod compare;
pub mod info;
pub mod prepare;
pub mod render;
pub mod sample;

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use pointray::PointCloud;
use pointray::preprocess::{PreprocessConfig, PreprocessStats, preprocess_with_progress};

use crate::args::PreprocessArgs;
use crate::failure;

/// Refuses an output path that cannot be written, before any work is done: a directory, or a
/// file in a directory that does not exist. (Writes are atomic, so a failure later leaves no
/// partial file either; this only saves a wasted render.)
pub fn check_output_path(path: &Path) -> anyhow::Result<()> {
    if path.is_dir() {
        return Err(failure::output(anyhow::anyhow!("{}: is a directory, not an output file", path.display())));
    }
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !parent.is_dir() {
        return Err(failure::output(anyhow::anyhow!(
            "{}: directory {} does not exist",
            path.display(),
            parent.display()
        )));
    }
    Ok(())
}

/// Reads a cloud file, with the file name in any error.
pub fn load(path: &Path, quiet: bool) -> anyhow::Result<(pointray_io::LoadedCloud, f64)> {
    let t = Instant::now();
    let loaded = crate::progress::spinning("read", quiet, || pointray_io::read_cloud(path))?;
    tracing::info!("read {} points from {} in {:.3} s", loaded.cloud.len(), path.display(), t.elapsed().as_secs_f64());
    Ok((loaded, t.elapsed().as_secs_f64()))
}

/// The preprocessing settings; bad values are usage errors.
pub fn preprocess_config(a: &PreprocessArgs) -> anyhow::Result<PreprocessConfig> {
    let check = |ok: bool, message: &str| if ok { Ok(()) } else { Err(failure::usage(anyhow::anyhow!("{message}"))) };
    check(a.k_normals >= 3, "--k-normals must be at least 3 (a plane needs 3 points)")?;
    check(a.k_radius >= 1, "--k-radius must be at least 1")?;
    // One message for both: two formatted ones here moved the SJ traversal by 45 instructions a
    // pixel (callgrind), which this crate compiles (the accelerators' generic code).
    let most = pointray::preprocess::MAX_NEIGHBOURS;
    if a.k_normals.max(a.k_radius) > most {
        let message = anyhow::anyhow!("--k-normals and --k-radius must be at most {most}");
        return Err(failure::usage(message));
    }
    check(a.radius_scale > 0.0 && a.radius_scale.is_finite(), "--radius-scale must be positive")?;
    Ok(PreprocessConfig {
        k_normals: a.k_normals,
        k_radius: a.k_radius,
        radius_scale: a.radius_scale,
        ..PreprocessConfig::standard()
    })
}

/// Fills in what the cloud lacks; with `recompute`, replaces what it has. What was dropped
/// or repaired is reported as warnings naming `input`.
pub fn prepare_cloud(
    cloud: &mut PointCloud,
    a: &PreprocessArgs,
    input: &str,
    quiet: bool,
) -> anyhow::Result<PreprocessStats> {
    let config = preprocess_config(a)?;
    if a.recompute {
        cloud.normals = None;
        cloud.radii = None;
    }
    let spinner = crate::progress::spinner("preprocess", quiet);
    let stats = preprocess_with_progress(cloud, &config, &|stage| spinner.set_message(format!("preprocess: {stage}")));
    spinner.finish_and_clear();
    let stats = stats.with_context(|| format!("{input}: preprocessing"))?;
    cloud.check_lengths().map_err(anyhow::Error::msg).context("preprocessing left inconsistent attributes")?;
    warn_about_repairs(input, &stats);
    Ok(stats)
}

/// One warning per kind of bad point the preprocessing dropped or repaired.
fn warn_about_repairs(input: &str, s: &PreprocessStats) {
    let clamped = format!(
        "over {} times the median of the neighbours' radii (stray points); clamped to that",
        pointray::preprocess::radii::MAX_OVER_NEIGHBOURS
    );
    // (count, what comes before it, the noun for one and for many, what comes after)
    let repairs = [
        (s.dropped_non_finite, "dropped ", "point", "points", "with a non-finite coordinate"),
        (s.dropped_duplicates, "dropped ", "point", "points", "at the exact position of an earlier point"),
        (s.invalid_normals, "", "normal was", "normals were", "zero or non-finite; estimated from the neighbours"),
        (s.invalid_radii, "", "radius was", "radii were", "zero, negative or non-finite; computed from the neighbours"),
        (s.clamped_radii, "", "radius was", "radii were", &clamped),
        (
            s.degenerate_normals,
            "",
            "normal has",
            "normals have",
            "no plane through their neighbours (collinear, or none); set to a fallback direction",
        ),
    ];
    for (n, before, one, many, after) in repairs {
        if n > 0 {
            tracing::warn!("{input}: {before}{n} {} {after}", if n == 1 { one } else { many });
        }
    }
    if s.turned_outward {
        tracing::warn!("{input}: the normals pointed into the shape; turned outward");
    }
}

/// The process's peak resident set so far (`VmHWM` in `/proc/self/status`); `None` where the
/// system does not say.
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.trim_start_matches("VmHWM:").trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kib * 1024)
}
