//! `pointray render` of an animation: a scene file's `[animation]` (a camera path through
//! keyframes, or an orbit) or `--turntable N`, its frames (`--frames A..B`, all by default)
//! written as OUT_0007.png, or into the #s of `-o out_####.png`; `-o out.mp4` encodes them as
//! they come (`pointray_io::video`), or writes them as PNGs beside it where ffmpeg is missing.

use std::ops::Range;
use std::path::{Path, PathBuf};

use pointray::camera_path::Animation;
use pointray::scene::Scene;
use pointray::settings::Settings;
use pointray_io::video::{self, Mp4Writer};

use crate::args::RenderArgs;
use crate::failure;

/// Renders and writes the frames `a.frames` picks.
pub fn run(
    a: &RenderArgs,
    scene: &Scene,
    settings: &Settings,
    animation: &Animation,
    quiet: bool,
) -> anyhow::Result<()> {
    if a.stats.is_some() || !a.aov.is_empty() || a.bench_frames > 0 {
        let e = anyhow::anyhow!("--stats, --aov and --bench-frames are a single frame's, not an animation's");
        return Err(failure::usage(e));
    }
    let frames = picked(a.frames.clone(), animation.frames())?;
    let video = is_mp4(&a.output);
    let program = if video { ffmpeg() } else { None };
    let png_of = |k: u32| frame_path(&a.output.with_extension(if video { "png" } else { ext(&a.output) }), k);
    let mut encoder = None;
    for k in frames.clone() {
        let view = animation.frame(scene, settings, k);
        let job = scene.job(&view).map_err(|e| failure::usage(super::render::flag_error(e)))?;
        let bar = crate::progress::bar(job.config.region.pixel_count(), "render", quiet);
        let frame = job.render(&|n| bar.inc(n))?;
        bar.finish_and_clear();
        let Some(program) = &program else {
            super::render::write_images(a, &png_of(k), &view, &frame)?;
            continue;
        };
        if encoder.is_none() {
            let writer = Mp4Writer::create(program, &a.output, frame.width, frame.height, a.fps);
            encoder = Some(writer.map_err(failure::output)?);
        }
        let writer = encoder.as_mut().expect("made above");
        writer.push(&frame.srgb8(view.tone_map())).map_err(failure::output)?;
    }
    if let Some(writer) = encoder {
        writer.finish().map_err(failure::output)?;
    }
    if !quiet {
        let wrote = match &program {
            Some(_) => a.output.display().to_string(),
            None => format!("{} to {}", png_of(frames.start).display(), png_of(frames.end - 1).display()),
        };
        eprintln!("wrote {} frames, {wrote}", frames.len());
    }
    Ok(())
}

/// The frames `asked` names of an animation of `frames` (all without), or why not.
fn picked(asked: Option<Range<u32>>, frames: u32) -> anyhow::Result<Range<u32>> {
    let range = asked.unwrap_or(0..frames);
    if range.is_empty() || range.end > frames {
        let e = anyhow::anyhow!("--frames {}..{}: the animation has frames 0..{frames}", range.start, range.end);
        return Err(failure::usage(e));
    }
    Ok(range)
}

/// `--frames A..B` (B exclusive) or `K`.
pub fn parse_frames(text: &str) -> Result<Range<u32>, String> {
    let number = |s: &str| s.trim().parse::<u32>().map_err(|_| format!("{s:?} is not a frame number"));
    match text.split_once("..") {
        Some((a, b)) => Ok(number(a)?..number(b)?),
        None => number(text).map(|k| k..k.saturating_add(1)),
    }
}

/// Whether `output` names a video.
pub fn is_mp4(output: &Path) -> bool {
    output.extension().is_some_and(|e| e.eq_ignore_ascii_case("mp4"))
}

/// Whether the flags ask for an animation's frames: `--frames`, or an output of numbered
/// frames (#s) or a video.
pub fn asked(a: &RenderArgs) -> bool {
    let numbered = a.output.file_name().is_some_and(|n| n.to_string_lossy().contains('#'));
    a.frames.is_some() || numbered || is_mp4(&a.output)
}

/// The refusal of frames asked for without an animation.
pub fn missing() -> anyhow::Error {
    anyhow::anyhow!("--frames, -o with #s and -o .mp4 need an animation: a scene file's [animation] or --turntable N")
}

fn ext(path: &Path) -> &str {
    path.extension().and_then(|e| e.to_str()).unwrap_or("png")
}

/// `OUT.png` → `OUT_0007.png` for frame 7; `out_####.png` → `out_0007.png` (as many digits as
/// #s at least).
pub fn frame_path(output: &Path, k: u32) -> PathBuf {
    let name = output.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    if let Some(at) = name.find('#') {
        let width = name[at..].chars().take_while(|&c| c == '#').count();
        let name = format!("{}{k:0width$}{}", &name[..at], &name[at + width..]);
        return output.with_file_name(name);
    }
    let stem = output.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    output.with_file_name(format!("{stem}_{k:04}.{}", ext(output)))
}

/// The ffmpeg to encode with, if it runs (a warning where it does not, `-q` or not, since the
/// video asked for is not made: the frames go beside the output as PNGs).
fn ffmpeg() -> Option<String> {
    let program = video::ffmpeg();
    if program.is_none() {
        eprintln!("warning: {}: writing the frames as PNGs", video::NO_FFMPEG);
    }
    program
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_named_by_number() {
        assert_eq!(frame_path(Path::new("d/turn.png"), 7), Path::new("d/turn_0007.png"));
        assert_eq!(frame_path(Path::new("d/out_##.exr"), 7), Path::new("d/out_07.exr"));
        assert_eq!(frame_path(Path::new("out_##.png"), 123), Path::new("out_123.png"));
        assert_eq!(parse_frames("3..10"), Ok(3..10));
        assert_eq!(parse_frames("4"), Ok(4..5));
        assert!(parse_frames("a..2").unwrap_err().contains("\"a\""));
        assert!(picked(Some(3..12), 10).is_err() && picked(Some(5..5), 10).is_err());
        assert_eq!(picked(None, 10).unwrap(), 0..10);
    }
}
