pub mod animation;
pub mod compare;
pub mod info;
pub mod prepare;
pub mod render;
pub mod sample;
pub mod view;

use std::path::Path;
use std::time::Instant;

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
pub fn load(
    path: &Path,
    read: &pointray_io::ReadOptions,
    quiet: bool,
) -> anyhow::Result<(pointray_io::LoadedCloud, f64)> {
    let t = Instant::now();
    let loaded = crate::progress::spinning("read", quiet, || pointray_io::read_cloud_with(path, read))?;
    tracing::info!("read {} points from {} in {:.3} s", loaded.cloud.len(), path.display(), t.elapsed().as_secs_f64());
    Ok((loaded, t.elapsed().as_secs_f64()))
}

/// The process's peak resident set so far (`VmHWM` in `/proc/self/status`); `None` where the
/// system does not say.
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.trim_start_matches("VmHWM:").trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kib * 1024)
}
