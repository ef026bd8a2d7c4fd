pub mod compare;
pub mod info;
pub mod prepare;
pub mod render;

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use pointray::PointCloud;
use pointray::preprocess::{PreprocessConfig, PreprocessStats, preprocess};

use crate::args::PreprocessArgs;

/// Refuses an output path that cannot be written, before any work is done: a directory, or a
/// file in a directory that does not exist. (Writes are atomic, so a failure later leaves no
/// partial file either; this only saves a wasted render.)
pub fn check_output_path(path: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(!path.is_dir(), "{}: is a directory, not an output file", path.display());
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    anyhow::ensure!(parent.is_dir(), "{}: directory {} does not exist", path.display(), parent.display());
    Ok(())
}

/// Reads a cloud file, with the file name in any error.
pub fn load(path: &Path) -> anyhow::Result<(pointray_io::LoadedCloud, f64)> {
    let t = Instant::now();
    let loaded = pointray_io::read_cloud(path)?;
    tracing::info!("read {} points from {} in {:.3} s", loaded.cloud.len(), path.display(), t.elapsed().as_secs_f64());
    Ok((loaded, t.elapsed().as_secs_f64()))
}

pub fn preprocess_config(a: &PreprocessArgs) -> anyhow::Result<PreprocessConfig> {
    anyhow::ensure!(a.k_normals >= 3, "--k-normals must be at least 3 (a plane needs 3 points)");
    anyhow::ensure!(a.k_radius >= 1, "--k-radius must be at least 1");
    anyhow::ensure!(a.radius_scale > 0.0 && a.radius_scale.is_finite(), "--radius-scale must be positive");
    Ok(PreprocessConfig {
        k_normals: a.k_normals,
        k_radius: a.k_radius,
        radius_scale: a.radius_scale,
        ..PreprocessConfig::standard()
    })
}

/// Fills in what the cloud lacks; with `recompute`, replaces what it has.
pub fn prepare_cloud(cloud: &mut PointCloud, a: &PreprocessArgs, quiet: bool) -> anyhow::Result<PreprocessStats> {
    let config = preprocess_config(a)?;
    if a.recompute {
        cloud.normals = None;
        cloud.radii = None;
    }
    let spinner = crate::progress::spinner("preprocess", quiet);
    let stats = preprocess(cloud, &config);
    spinner.finish_and_clear();
    anyhow::ensure!(!cloud.is_empty(), "the cloud has no (finite) points");
    cloud.check_lengths().map_err(anyhow::Error::msg).context("preprocessing left inconsistent attributes")?;
    Ok(stats)
}
