//! `pointray compare`: how far two renders are apart.

use std::io::{self, Write};

use anyhow::Context;
use pointray::metrics::{self, compare_rgb8};

use crate::args::CompareArgs;

pub fn run(a: &CompareArgs) -> anyhow::Result<()> {
    let (wa, ha, rgb_a) = pointray_io::read_png(&a.a)?;
    let (wb, hb, rgb_b) = pointray_io::read_png(&a.b)?;
    anyhow::ensure!(
        (wa, ha) == (wb, hb),
        "the images differ in size: {} is {wa}x{ha}, {} is {wb}x{hb}",
        a.a.display(),
        a.b.display()
    );
    let (rgb_a, rgb_b) = match a.region {
        None => (rgb_a, rgb_b),
        Some(r) => {
            if r.x1 > wa || r.y1 > ha {
                let e =
                    anyhow::anyhow!("--region {},{},{},{} lies outside the {wa}x{ha} images", r.x0, r.y0, r.x1, r.y1);
                return Err(crate::failure::usage(e));
            }
            (crop(&rgb_a, wa, r), crop(&rgb_b, wa, r))
        }
    };
    let (w, h) = a.region.map_or((wa, ha), |r| (r.width(), r.height()));
    let speckles = match &a.speckles {
        None => None,
        Some(mask) => Some(speckles(&rgb_a, &rgb_b, (wa, ha), mask, a.region)?),
    };
    let diff = compare_rgb8(&rgb_a, &rgb_b);
    let flip = crate::perceptual::flip_mean(&rgb_a, &rgb_b, w, h);
    let mut out = io::stdout().lock();
    if a.json {
        #[derive(serde::Serialize)]
        struct Comparison {
            #[serde(flatten)]
            diff: pointray::metrics::ImageDiff,
            /// Mean FLIP error of the second image against the first (0: the same).
            flip_mean: f64,
            #[serde(skip_serializing_if = "Option::is_none")]
            speckles: Option<Speckles>,
        }
        serde_json::to_writer(&mut out, &Comparison { diff, flip_mean: flip, speckles })
            .context("cannot encode the comparison as JSON")?;
        writeln!(out)?;
    } else {
        let psnr = diff.psnr_db.map_or_else(|| "inf".to_string(), |p| format!("{p:.2}"));
        writeln!(
            out,
            "PSNR {psnr} dB, RMSE {:.4}, max diff {}, {} of {} pixels differ, mean FLIP {flip:.4}",
            diff.rmse, diff.max_abs_diff, diff.differing_pixels, diff.pixels
        )?;
        if let Some(s) = speckles {
            writeln!(
                out,
                "{} dark speckles in the first, {} of them not in the second, {} with no trace there",
                s.first, s.not_in_second, s.without_trace_in_second
            )?;
        }
    }
    out.flush()?;
    Ok(())
}

/// The first image's isolated dark speckles (`metrics::dark_speckles`), how many of them the
/// second lacks (is not itself as dark there against its neighbours), and of those how many it
/// shows no trace of (`metrics::darkness_share` below `metrics::SPECKLE_TRACE`).
#[derive(serde::Serialize)]
struct Speckles {
    first: usize,
    not_in_second: usize,
    without_trace_in_second: usize,
}

/// Counts [`Speckles`] in `a` and `b` (the images, `size` before any `region` was cut from
/// them), the foreground read from `mask`, an image of the same size.
fn speckles(
    a: &[u8],
    b: &[u8],
    (width, height): (u32, u32),
    mask: &std::path::Path,
    region: Option<pointray::camera::Region>,
) -> anyhow::Result<Speckles> {
    let (wm, hm, rgb_mask) = pointray_io::read_png(mask)?;
    anyhow::ensure!(
        (wm, hm) == (width, height),
        "the foreground {} is {wm}x{hm}, the images {width}x{height}",
        mask.display()
    );
    let rgb_mask = match region {
        Some(r) => crop(&rgb_mask, width, r),
        None => rgb_mask,
    };
    let foreground: Vec<bool> = rgb_mask.chunks_exact(3).map(|p| p.iter().any(|&c| c != 0)).collect();
    let w = region.map_or(width, |r| r.width()) as usize;
    let drop = metrics::SPECKLE_DROP;
    let first = metrics::dark_speckles(a, w, &foreground, drop);
    let in_second = metrics::dark_speckles(b, w, &foreground, drop);
    let lacking: Vec<usize> = first.iter().copied().filter(|i| in_second.binary_search(i).is_err()).collect();
    let without_trace = lacking.iter().filter(|&&i| metrics::darkness_share(a, b, w, i) < metrics::SPECKLE_TRACE);
    Ok(Speckles { first: first.len(), not_in_second: lacking.len(), without_trace_in_second: without_trace.count() })
}

/// The RGB8 pixels of `region` of a `width`-wide image, row by row.
fn crop(rgb: &[u8], width: u32, region: pointray::camera::Region) -> Vec<u8> {
    let row = |y: u32| {
        let start = (y as usize * width as usize + region.x0 as usize) * 3;
        &rgb[start..start + region.width() as usize * 3]
    };
    (region.y0..region.y1).flat_map(row).copied().collect()
}
