//! `pointray render --turntable N`: N frames with the camera turned about the up axis
//! (`Scene::turntable`), written as OUT_0000.png, OUT_0001.png, … beside `-o OUT.png`.

use std::path::{Path, PathBuf};

use pointray::scene::Scene;
use pointray::settings::Settings;

use crate::args::RenderArgs;
use crate::failure;

/// Renders and writes the frames.
pub fn run(a: &RenderArgs, scene: &Scene, settings: &Settings, quiet: bool) -> anyhow::Result<()> {
    let views = scene.turntable(settings, a.turntable);
    for (k, view) in views.iter().enumerate() {
        let job = scene.job(view).map_err(|e| failure::usage(super::render::flag_error(e)))?;
        let bar = crate::progress::bar(job.config.region.pixel_count(), "render", quiet);
        let frame = job.render(&|n| bar.inc(n))?;
        bar.finish_and_clear();
        let path = frame_path(&a.output, k);
        super::render::write_images(a, &path, view, &frame)?;
    }
    if !quiet {
        eprintln!(
            "wrote {} frames, {} to {}",
            views.len(),
            frame_path(&a.output, 0).display(),
            frame_path(&a.output, views.len() - 1).display()
        );
    }
    Ok(())
}

/// `OUT.png` → `OUT_0007.png` for frame 7.
fn frame_path(output: &Path, k: usize) -> PathBuf {
    let stem = output.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let extension = output.extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or_default();
    output.with_file_name(format!("{stem}_{k:04}.{extension}"))
}
