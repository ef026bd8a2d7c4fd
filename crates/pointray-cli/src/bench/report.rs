//! `pointray report`: the Markdown report of a bench run, with its figures and image pairs,
//! in the order of the thesis's experiments. Every number comes from the run's JSON lines; the
//! hand-written `## Discussion` of an earlier report at the same path is kept.

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use pointray::splat::scheme::SurfaceKind;

use super::plot::{Legend, LineChart, Series};
use super::{Header, ModelRecord, PointRecord};

/// A bench run as its JSON lines hold it.
pub struct Run {
    pub header: Header,
    pub models: Vec<ModelRecord>,
    pub points: Vec<PointRecord>,
}

pub fn read_run(results: &Path) -> anyhow::Result<Run> {
    let path = results.join("results.jsonl");
    let text = std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    let parse_error = |n: usize| format!("{}: line {}", path.display(), n + 1);
    let (n, first) = lines.next().with_context(|| format!("{}: empty", path.display()))?;
    let header: Header = serde_json::from_str(first).with_context(|| parse_error(n))?;
    let (mut models, mut points) = (Vec::new(), Vec::new());
    for (n, line) in lines {
        let kind: serde_json::Value = serde_json::from_str(line).with_context(|| parse_error(n))?;
        match kind["kind"].as_str() {
            Some("model") => models.push(serde_json::from_str(line).with_context(|| parse_error(n))?),
            Some("point") => points.push(serde_json::from_str(line).with_context(|| parse_error(n))?),
            _ => anyhow::bail!("{}: not a model or a point", parse_error(n)),
        }
    }
    Ok(Run { header, models, points })
}

/// Writes `report` (Markdown) and its figures and images in `figures` from the run in
/// `results`; `command` is the command line that does so, quoted in the report.
pub fn write_report(results: &Path, report: &Path, figures: &Path, command: &str) -> anyhow::Result<()> {
    let run = read_run(results)?;
    std::fs::create_dir_all(figures.join("images")).with_context(|| format!("{}: cannot create", figures.display()))?;
    let link = |file: &str| {
        let relative = figures.strip_prefix(report.parent().unwrap_or(Path::new(""))).unwrap_or(figures);
        format!("{}/{file}", relative.display())
    };
    let mut md = String::new();
    let mut outputs = format!("--out {} --report {}", results.display(), report.display());
    if figures != super::default_figures(report) {
        outputs += &format!(" --figures {}", figures.display());
    }
    header(&mut md, &run, &outputs, command);
    models(&mut md, &run);
    for accel in ["bvh", "kdtree"] {
        lod_against_distance(&mut md, &run, accel, figures, &link)?;
    }
    improvement_table(&mut md, &run, figures, &link)?;
    bounding_volumes(&mut md, &run);
    schemes(&mut md, &run);
    converged_quality(&mut md, &run);
    equal_quality(&mut md, &run);
    image_pairs(&mut md, &run, results, figures, &link)?;
    let kept = std::fs::read_to_string(report)
        .ok()
        .and_then(|old| old.find("\n## Discussion").map(|i| old[i..].to_string()))
        .unwrap_or_default();
    let text = md + &kept;
    pointray_io::atomic_write(report, |w| w.write_all(text.as_bytes()))?;
    Ok(())
}

/// `outputs` are the bench's options that write this run and report again.
fn header(md: &mut String, run: &Run, outputs: &str, command: &str) {
    let h = &run.header;
    let m = &h.machine;
    let memory = m.memory_bytes.map_or(String::new(), |b| format!(", {:.0} GiB", b as f64 / (1u64 << 30) as f64));
    let _ = writeln!(md, "# Results: {}\n", h.title);
    let _ = writeln!(
        md,
        "Regenerate the measurements, this report and its figures with `pointray bench {} {outputs}` (the \
         `## Discussion` below is kept); this file was written by `{command}`.\n",
        h.experiment
    );
    let crop = if h.crop_to_model {
        "only the pixels of the model's projected bounding box traced"
    } else {
        "the whole frame traced"
    };
    let rays = if h.shadows { "camera and shadow rays" } else { "camera rays only, shaded by a headlight" };
    let reference = h.reference.map_or(String::new(), |r| format!(", and with the {} scheme's", r.name()));
    let _ = writeln!(
        md,
        "Measured on {} UTC with pointray {} (checkout {}) on {} ({} cores{memory}, {}), {} threads: {}×{} pixels, \
         a vertical field of view of {}°, {crop}; {rays}. Each point renders one untimed frame, then times at least \
         {} frames and {} s and keeps the median; while other processes kept more than {} cores busy the frames \
         were timed again, up to {} times, and the quietest attempt kept. Each image is compared with the \
         full-detail image of the same scheme over the traced pixels (PSNR; FLIP, NVIDIA's perceptual difference, \
         0 for the same image){reference}.",
        m.date,
        h.pointray,
        h.checkout.as_deref().unwrap_or("unknown"),
        m.cpu.as_deref().unwrap_or("an unknown processor"),
        m.cores,
        m.os,
        h.threads,
        h.width,
        h.height,
        h.fov,
        h.repeats,
        h.min_seconds,
        h.max_other_load,
        h.retries,
    );
    if let Some(embree) = &h.embree {
        let version = run.points.iter().find_map(|p| p.embree_version.as_deref());
        let embree = match version {
            Some(v) => format!("`{embree}` (Embree {v})"),
            None => format!("`{embree}`"),
        };
        let _ = writeln!(
            md,
            "\n{embree} traced the same pixels of the same preprocessed cloud after each model, with its \
             oriented discs beside SJ, PSS and first-hit and its ray-facing discs beside RFD, timed with as many \
             frames as pointray's full-detail point at that distance."
        );
    }
    let busy: Vec<&PointRecord> =
        run.points.iter().filter(|p| p.other_load_cores.is_some_and(|o| o > h.max_other_load)).collect();
    if !busy.is_empty() {
        let _ = writeln!(
            md,
            "\n{} of {} points stayed above the load limit after every attempt (their `other_load_cores` in the \
             JSON lines); treat their times with care.",
            busy.len(),
            run.points.len()
        );
    }
    md.push('\n');
}

fn models(md: &mut String, run: &Run) {
    let _ = writeln!(md, "## Models\n");
    let _ = writeln!(md, "| model | points | source | load s | preprocess s |");
    let _ = writeln!(md, "|---|---:|---|---:|---:|");
    for m in &run.models {
        // The file's name, with " (N points sampled)" for a mesh: both in the last component.
        let source = Path::new(&m.source).file_name().map_or(m.source.clone(), |f| f.to_string_lossy().into_owned());
        let _ = writeln!(
            md,
            "| {} | {} | {source} | {:.2} | {:.2} |",
            m.model,
            thousands(m.points as u64),
            m.load_seconds,
            m.preprocess_seconds
        );
    }
    md.push('\n');
}

/// The points of one model, accelerator and scheme at one sample a pixel (the thesis's
/// experiments; more samples are the quality experiments').
fn select<'a>(run: &'a Run, model: &str, accel: &str, surface: SurfaceKind) -> Vec<&'a PointRecord> {
    let of =
        |p: &&PointRecord| p.model == model && p.accel == accel && p.surface == surface && p.spp == 1 && !p.prefilter;
    run.points.iter().filter(of).collect()
}

fn sorted_set(values: impl Iterator<Item = f32>) -> Vec<f32> {
    let mut v: Vec<f32> = values.collect();
    v.sort_by(f32::total_cmp);
    v.dedup();
    v
}

fn find<'a>(points: &[&'a PointRecord], lod: f32, distance: f32) -> Option<&'a PointRecord> {
    points.iter().copied().find(|p| p.lod_threshold == lod && p.distance == distance)
}

fn ms(seconds: f64) -> String {
    let ms = seconds * 1e3;
    if ms >= 100.0 {
        format!("{ms:.0}")
    } else if ms >= 10.0 {
        format!("{ms:.1}")
    } else {
        format!("{ms:.2}")
    }
}

fn psnr(p: Option<f64>) -> String {
    p.map_or("=".into(), |db| format!("{db:.1}"))
}

fn thousands(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// Thesis figures 3.6–3.8 and 4.6–4.12: render time, nodes visited and splat tests against
/// the camera distance, with and without level of detail, per model.
fn lod_against_distance(
    md: &mut String,
    run: &Run,
    accel: &str,
    figures: &Path,
    link: &dyn Fn(&str) -> String,
) -> anyhow::Result<()> {
    let models: Vec<&ModelRecord> =
        run.models.iter().filter(|m| !select(run, &m.model, accel, SurfaceKind::Sj).is_empty()).collect();
    if models.is_empty() {
        return Ok(());
    }
    let title = if accel == "bvh" { "the BVH (thesis ch. 3)" } else { "the SAH kd-tree (thesis ch. 4)" };
    let _ = writeln!(md, "## Level of detail against distance: {title}\n");
    let _ = writeln!(
        md,
        "SJ surface. Render time per frame in ms; in brackets the time saved against full detail. Nodes and splat tests \
         are per ray, at full detail → at the largest threshold. PSNR and FLIP compare the least and the largest \
         threshold's images with full detail (= identical). The Embree columns give its time on the same pixels \
         and pointray's speed over Embree's (rays per second), at full detail and at the largest threshold.\n"
    );
    for m in models {
        let points = select(run, &m.model, accel, SurfaceKind::Sj);
        let lods = sorted_set(points.iter().map(|p| p.lod_threshold));
        let distances = sorted_set(points.iter().map(|p| p.distance));
        let top = *lods.last().expect("points");
        let least = lods.iter().copied().find(|l| *l > 0.0).unwrap_or(top);
        let _ = writeln!(md, "### {} ({} points), {accel}\n", m.model, thousands(m.points as u64));
        let mut head = "| distance | pixels |".to_string();
        let mut rule = "|---:|---:|".to_string();
        for lod in &lods {
            head += &if *lod == 0.0 { " full detail ms |".to_string() } else { format!(" τ = {lod} ms |") };
            rule += "---:|";
        }
        head += &format!(
            " nodes/ray | splat tests/ray | PSNR dB, τ = {least} / {top} | FLIP, τ = {least} / {top} | Embree ms | speed vs Embree |"
        );
        rule += "---|---|---:|---:|---:|---|";
        let _ = writeln!(md, "{head}\n{rule}");
        for &d in &distances {
            let full = find(&points, 0.0, d);
            let last = find(&points, top, d);
            let first = find(&points, least, d);
            let mut row = format!("| {d} | {} |", full.or(last).map_or(0, |p| p.pixels));
            for &lod in &lods {
                row += &match (find(&points, lod, d), full) {
                    (Some(p), Some(f)) if lod > 0.0 => {
                        format!(
                            " {} ({:+.0} %) |",
                            ms(p.render_seconds),
                            100.0 * (1.0 - p.render_seconds / f.render_seconds)
                        )
                    }
                    (Some(p), _) => format!(" {} |", ms(p.render_seconds)),
                    (None, _) => " |".into(),
                };
            }
            let pair = |f: fn(&PointRecord) -> f64| match (full, last) {
                (Some(a), Some(b)) => format!("{:.1} → {:.1}", f(a), f(b)),
                _ => String::new(),
            };
            let embree_ms = full.and_then(embree_seconds);
            let ratios = match (full.and_then(|p| p.speed_vs_embree), last.and_then(|p| p.speed_vs_embree)) {
                (Some(a), Some(b)) => format!("{a:.2}× → {b:.2}×"),
                _ => String::new(),
            };
            row += &format!(
                " {} | {} | {} | {} | {} | {ratios} |",
                pair(|p| p.nodes_visited_per_ray),
                pair(|p| p.splat_tests_per_ray),
                match (first, last) {
                    (Some(a), Some(b)) => format!("{} / {}", psnr(a.psnr_db), psnr(b.psnr_db)),
                    _ => String::new(),
                },
                match (first, last) {
                    (Some(a), Some(b)) => format!("{:.3} / {:.3}", a.flip, b.flip),
                    _ => String::new(),
                },
                embree_ms.map_or(String::new(), ms),
            );
            let _ = writeln!(md, "{row}");
        }
        md.push('\n');
        // The figure: time against distance per threshold, and Embree's.
        let mut series: Vec<Series> = lods
            .iter()
            .map(|&lod| Series {
                label: if lod == 0.0 { "full detail".into() } else { format!("τ = {lod} px") },
                points: points
                    .iter()
                    .filter(|p| p.lod_threshold == lod)
                    .map(|p| (f64::from(p.distance), p.render_seconds * 1e3))
                    .collect(),
            })
            .collect();
        let embree: Vec<(f64, f64)> = points
            .iter()
            .filter(|p| p.lod_threshold == 0.0)
            .filter_map(|p| Some((f64::from(p.distance), embree_seconds(p)? * 1e3)))
            .collect();
        if !embree.is_empty() {
            series.push(Series { label: "Embree (oriented discs)".into(), points: embree });
        }
        let stem = format!("time_{accel}_{}", m.model);
        LineChart {
            title: format!("{}: render time, {accel}", m.model),
            x_desc: "camera distance (bounding-box diagonals)".into(),
            y_desc: "ms per frame".into(),
            series,
            legend: Legend::UpperRight,
        }
        .write(&figures.join(&stem))?;
        let nodes = LineChart {
            title: format!("{}: work per ray, {accel}", m.model),
            x_desc: "camera distance (bounding-box diagonals)".into(),
            y_desc: "per ray".into(),
            series: [0.0, top]
                .iter()
                .flat_map(|&lod| {
                    let of = |f: fn(&PointRecord) -> f64| -> Vec<(f64, f64)> {
                        points
                            .iter()
                            .filter(|p| p.lod_threshold == lod)
                            .map(|p| (f64::from(p.distance), f(p)))
                            .collect()
                    };
                    let name = if lod == 0.0 { "full detail".to_string() } else { format!("τ = {lod}") };
                    [
                        Series { label: format!("nodes, {name}"), points: of(|p| p.nodes_visited_per_ray) },
                        Series { label: format!("splat tests, {name}"), points: of(|p| p.splat_tests_per_ray) },
                    ]
                })
                .collect(),
            legend: Legend::UpperRight,
        };
        let work = format!("work_{accel}_{}", m.model);
        nodes.write(&figures.join(&work))?;
        let _ = writeln!(
            md,
            "![render time]({}) ![work per ray]({})\n",
            link(&format!("{stem}.svg")),
            link(&format!("{work}.svg"))
        );
    }
    Ok(())
}

/// Thesis tables 3.1, 3.2 and 4.1: the percentage level of detail saves, per model, for each
/// accelerator, threshold and distance.
fn improvement_table(md: &mut String, run: &Run, figures: &Path, link: &dyn Fn(&str) -> String) -> anyhow::Result<()> {
    let sj: Vec<&PointRecord> = run
        .points
        .iter()
        .filter(|p| p.surface == SurfaceKind::Sj && (p.accel == "bvh" || p.accel == "kdtree"))
        .collect();
    let distances = sorted_set(sj.iter().map(|p| p.distance));
    let lods: Vec<f32> = sorted_set(sj.iter().map(|p| p.lod_threshold)).into_iter().filter(|l| *l > 0.0).collect();
    if lods.is_empty() || distances.is_empty() {
        return Ok(());
    }
    let _ = writeln!(md, "## Percentage improvement from level of detail\n");
    let _ = writeln!(md, "Render time saved against full detail (SJ), per model, accelerator and threshold.\n");
    let mut head = "| model | accelerator | τ |".to_string();
    let mut rule = "|---|---|---:|".to_string();
    for d in &distances {
        head += &format!(" distance {d} |");
        rule += "---:|";
    }
    let _ = writeln!(md, "{head}\n{rule}");
    for m in &run.models {
        for accel in ["bvh", "kdtree"] {
            let points: Vec<&PointRecord> =
                sj.iter().copied().filter(|p| p.model == m.model && p.accel == accel).collect();
            for &lod in &lods {
                if !points.iter().any(|p| p.lod_threshold == lod) {
                    continue;
                }
                let mut row = format!("| {} | {accel} | {lod} |", m.model);
                for &d in &distances {
                    row += &match (find(&points, 0.0, d), find(&points, lod, d)) {
                        (Some(f), Some(p)) => {
                            format!(" {:+.0} % |", 100.0 * (1.0 - p.render_seconds / f.render_seconds))
                        }
                        _ => " |".into(),
                    };
                }
                let _ = writeln!(md, "{row}");
            }
        }
    }
    md.push('\n');
    // The figure: the speed-up at the least threshold against distance, per model.
    let lod = lods[0];
    for accel in ["bvh", "kdtree"] {
        let series: Vec<Series> = run
            .models
            .iter()
            .map(|m| {
                let of: Vec<&PointRecord> =
                    sj.iter().copied().filter(|p| p.model == m.model && p.accel == accel).collect();
                let points = distances
                    .iter()
                    .filter_map(|&d| {
                        Some((f64::from(d), find(&of, 0.0, d)?.render_seconds / find(&of, lod, d)?.render_seconds))
                    })
                    .collect();
                Series { label: m.model.clone(), points }
            })
            .filter(|s| !s.points.is_empty())
            .collect();
        if series.is_empty() {
            continue;
        }
        let stem = format!("speedup_{accel}");
        LineChart {
            title: format!("speed-up from level of detail, τ = {lod}, {accel}"),
            x_desc: "camera distance (bounding-box diagonals)".into(),
            y_desc: "time at full detail / time with LoD".into(),
            series,
            legend: Legend::UpperLeft,
        }
        .write(&figures.join(&stem))?;
        let _ = write!(md, "![speed-up, {accel}]({}) ", link(&format!("{stem}.svg")));
    }
    md.push_str("\n\n");
    Ok(())
}

/// Thesis ch. 3: boxes, spheres, and the two mixed, per model and distance.
fn bounding_volumes(md: &mut String, run: &Run) {
    let variants: BTreeSet<&str> =
        run.points.iter().filter(|p| p.accel.starts_with("bvh-")).map(|p| p.accel.as_str()).collect();
    if variants.is_empty() {
        return;
    }
    let _ = writeln!(md, "## Bounding volumes: boxes, spheres and mixed (thesis ch. 3)\n");
    let _ = writeln!(
        md,
        "SJ, render time per frame in ms at full detail and, after the slash, at the threshold shown; the build \
         time and size of each variant. `bvh` has boxes only, `bvh-spheres` spheres only, `bvh-mixed-L` boxes \
         above level L and spheres from it, `bvh-auto` whichever has the smaller surface area per node. The last \
         row is Embree's oriented discs on the same pixels (it has no level of detail).\n"
    );
    for m in &run.models {
        let points: Vec<&PointRecord> = run
            .points
            .iter()
            .filter(|p| p.model == m.model && p.surface == SurfaceKind::Sj && p.accel.starts_with("bvh") && p.spp == 1)
            .collect();
        let accels: BTreeSet<&str> = points.iter().map(|p| p.accel.as_str()).collect();
        if accels.len() < 2 {
            continue;
        }
        let distances = sorted_set(points.iter().filter(|p| p.accel != "bvh").map(|p| p.distance));
        let lod = sorted_set(points.iter().filter(|p| p.accel != "bvh").map(|p| p.lod_threshold))
            .last()
            .copied()
            .unwrap_or(0.0);
        let _ = writeln!(md, "### {}\n", m.model);
        let mut head = "| volumes |".to_string();
        let mut rule = "|---|".to_string();
        for d in &distances {
            head += &format!(" distance {d}, τ = 0 / {lod} |");
            rule += "---:|";
        }
        let _ = writeln!(md, "{head} build s | MB |\n{rule}---:|---:|");
        for accel in &accels {
            let of: Vec<&PointRecord> = points.iter().copied().filter(|p| p.accel == *accel).collect();
            let mut row = format!("| {accel} |");
            for &d in &distances {
                let cell = |lod: f32| find(&of, lod, d).map_or("–".into(), |p| ms(p.render_seconds));
                row += &format!(" {} / {} |", cell(0.0), cell(lod));
            }
            if let Some(p) = of.first() {
                row += &format!(" {:.3} | {:.1} |", p.build_seconds, p.accel_bytes as f64 / 1e6);
            }
            let _ = writeln!(md, "{row}");
        }
        let boxes: Vec<&PointRecord> = points.iter().copied().filter(|p| p.accel == "bvh").collect();
        if boxes.iter().any(|p| p.embree_mrays_per_second.is_some()) {
            let mut row = "| Embree |".to_string();
            for &d in &distances {
                row += &format!(" {} |", find(&boxes, 0.0, d).and_then(embree_seconds).map_or("–".into(), ms));
            }
            let build = boxes.iter().find_map(|p| p.embree_build_seconds);
            let _ = writeln!(md, "{row} {} | |", build.map_or(String::new(), |b| format!("{b:.3}")));
        }
        md.push('\n');
    }
}

/// Embree's time for a frame of `p`'s pixels, from its rate.
fn embree_seconds(p: &PointRecord) -> Option<f64> {
    // Embree's rays are its camera rays, one a pixel (its shadow rays timed with them).
    p.embree_mrays_per_second.zip(p.embree_rays).map(|(r, rays)| rays as f64 / (r * 1e6))
}

/// Thesis ch. 2 and 4: SJ against RFD and PSS, at full detail.
fn schemes(md: &mut String, run: &Run) {
    let points: Vec<&PointRecord> = run
        .points
        .iter()
        .filter(|p| p.accel == "bvh" && p.lod_threshold == 0.0 && p.spp == 1 && !p.prefilter)
        .collect();
    let kinds: BTreeSet<SurfaceKind> = points.iter().map(|p| p.surface).collect();
    if kinds.len() < 2 {
        return;
    }
    let reference = run.header.reference.map_or("—".to_string(), |r| r.name().to_uppercase());
    let _ = writeln!(md, "## Surface schemes (thesis ch. 2 and 4)\n");
    let _ = writeln!(
        md,
        "BVH, full detail. Render time in ms and rays per second; the image against the {reference} image \
         (PSNR dB / FLIP); Embree's time on the same pixels and pointray's speed over Embree's (its oriented discs \
         beside SJ, PSS and first-hit, its ray-facing discs beside RFD).\n"
    );
    let _ = writeln!(
        md,
        "| model | scheme | distance | ms | Mrays/s | vs {reference}: PSNR / FLIP | Embree ms | speed vs Embree |"
    );
    let _ = writeln!(md, "|---|---|---:|---:|---:|---|---:|---:|");
    for m in &run.models {
        // Only the distances at which the schemes were measured side by side.
        let of_model: Vec<&PointRecord> = points.iter().copied().filter(|p| p.model == m.model).collect();
        let shared = |d: f32| of_model.iter().filter(|p| p.distance == d).count() >= 2;
        for kind in &kinds {
            for p in of_model.iter().filter(|p| p.surface == *kind && shared(p.distance)) {
                let versus = match p.flip_reference {
                    _ if Some(p.surface) == run.header.reference => "(the reference)".into(),
                    Some(flip) => format!("{} / {flip:.3}", psnr(p.psnr_reference_db)),
                    None => String::new(),
                };
                let _ = writeln!(
                    md,
                    "| {} | {} | {} | {} | {:.2} | {versus} | {} | {} |",
                    m.model,
                    kind.name(),
                    p.distance,
                    ms(p.render_seconds),
                    p.mrays_per_second,
                    embree_seconds(p).map_or(String::new(), ms),
                    p.speed_vs_embree.map_or(String::new(), |r| format!("{r:.2}×"))
                );
            }
        }
    }
    md.push('\n');
}

/// Issue 21's equal quality: each image against its scheme's converged image (full detail at
/// many samples a pixel), full detail at each number of samples beside level of detail at one,
/// per model, scheme and distance; and each one's frame time.
fn converged_quality(md: &mut String, run: &Run) {
    let Some(converged) = run.header.converged_spp else { return };
    let _ = writeln!(md, "## Quality against the converged image\n");
    let _ = writeln!(
        md,
        "Each image against full detail at {converged} samples a pixel of the same scheme and view, over the \
         traced pixels: PSNR dB and, in brackets, FLIP (0 for the same image); then the median frame in ms. Full \
         detail at 1, 2, 4, … samples a pixel beside level of detail at one, plain or prefiltered (`--prefilter`: \
         each pixel's footprint gathered): level of detail as prefiltering is as good as the full-detail column \
         it matches, at its own cost.\n"
    );
    for m in &run.models {
        let points: Vec<&PointRecord> =
            // (An image equal to the converged one has no PSNR, but a FLIP of 0.)
            run.points.iter().filter(|p| p.model == m.model && p.flip_converged.is_some()).collect();
        let mut columns: Vec<(String, SurfaceKind, f32, u32, bool)> = Vec::new();
        for p in &points {
            let column = (p.accel.clone(), p.surface, p.lod_threshold, p.spp, p.prefilter);
            if !columns.contains(&column) {
                columns.push(column);
            }
        }
        columns.sort_by(|a, b| (&a.0, a.1, a.2, a.3, a.4).partial_cmp(&(&b.0, b.1, b.2, b.3, b.4)).expect("finite"));
        if columns.is_empty() {
            continue;
        }
        let _ = writeln!(md, "### {} ({} points)\n", m.model, thousands(m.points as u64));
        let mut head = "| distance | pixels |".to_string();
        for (accel, surface, lod, spp, prefilter) in &columns {
            let detail = if *lod == 0.0 { "full detail".to_string() } else { format!("τ = {lod}") };
            let prefilter = if *prefilter { ", prefiltered" } else { "" };
            head += &format!(" {accel} {}, {detail}, {spp} spp{prefilter} |", surface.name());
        }
        let _ = writeln!(md, "{head}\n|---:|---:|{}", "---|".repeat(columns.len()));
        for d in sorted_set(points.iter().map(|p| p.distance)) {
            let mut row = String::new();
            let mut pixels = 0;
            for (accel, surface, lod, spp, prefilter) in &columns {
                let p = points.iter().find(|p| {
                    p.distance == d
                        && p.accel == *accel
                        && p.surface == *surface
                        && p.lod_threshold == *lod
                        && p.spp == *spp
                        && p.prefilter == *prefilter
                });
                row += &p.map_or(" – |".into(), |p| {
                    pixels = p.pixels;
                    let flip = p.flip_converged.expect("selected above");
                    format!(" {} ({flip:.3}), {} ms |", psnr(p.psnr_converged_db), ms(p.render_seconds))
                });
            }
            let _ = writeln!(md, "| {d} | {} |{row}", thousands(pixels));
        }
        md.push('\n');
    }
}

/// The prefilter's speed-up against Embree at equal quality: the most samples a pixel of full
/// detail (BVH, the same scheme) that its one-sample image is at least as close to the converged
/// image as, times Embree's one-sample frame over its own.
fn equal_quality(md: &mut String, run: &Run) {
    let prefiltered: Vec<&PointRecord> =
        run.points.iter().filter(|p| p.prefilter && p.psnr_converged_db.is_some()).collect();
    if prefiltered.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "## Equal quality against Embree
"
    );
    let _ = writeln!(
        md,
        "Each prefiltered image beside the most samples a pixel of full detail (BVH, same scheme and view) it is at \
         least as close to the converged image as (PSNR); Embree's one-sample frame on the same pixels; the speed-up \
         at equal quality is those samples × Embree's frame / the prefilter's (– where it is not as close as one \
         sample).\n"
    );
    let _ = writeln!(
        md,
        "| model | accel | distance | prefiltered dB, ms | full detail it matches | Embree 1 spp ms | speed-up |"
    );
    let _ = writeln!(md, "|---|---|---:|---|---|---:|---:|");
    for p in prefiltered {
        let full: Vec<&PointRecord> = run
            .points
            .iter()
            .filter(|f| {
                (f.model == p.model && f.distance == p.distance && f.surface == p.surface)
                    && (f.accel == "bvh" && f.lod_threshold == 0.0 && !f.prefilter)
            })
            .collect();
        let matched = full
            .iter()
            .filter(|f| f.psnr_converged_db.is_some_and(|db| db <= p.psnr_converged_db.unwrap_or(f64::INFINITY)))
            .max_by_key(|f| f.spp);
        let embree = full.iter().find(|f| f.spp == 1).and_then(|f| embree_seconds(f));
        let matches = matched.map_or("–".into(), |f| {
            format!("{} spp ({} dB, {} ms)", f.spp, psnr(f.psnr_converged_db), ms(f.render_seconds))
        });
        let speed_up = matched
            .zip(embree)
            .map_or("–".into(), |(f, e)| format!("{:.1}×", f64::from(f.spp) * e / p.render_seconds));
        let _ = writeln!(
            md,
            "| {} | {} | {} | {}, {} | {matches} | {} | {speed_up} |",
            p.model,
            p.accel,
            p.distance,
            psnr(p.psnr_converged_db),
            ms(p.render_seconds),
            embree.map_or("–".into(), ms)
        );
    }
    md.push('\n');
}

/// What level of detail does to the picture: full detail beside the largest threshold, for
/// each model at the farthest distance whose crop still has 64 × 64 pixels.
fn image_pairs(
    md: &mut String,
    run: &Run,
    results: &Path,
    figures: &Path,
    link: &dyn Fn(&str) -> String,
) -> anyhow::Result<()> {
    let _ = writeln!(md, "## Images: full detail and level of detail\n");
    let _ = writeln!(
        md,
        "BVH, SJ, the largest threshold; each pair at the farthest distance whose crop still has 64 × 64 pixels \
         (shown enlarged; the nearest if none has).\n"
    );
    let _ = writeln!(md, "| model | distance | full detail | level of detail | PSNR dB | FLIP |");
    let _ = writeln!(md, "|---|---:|---|---|---:|---:|");
    for m in &run.models {
        let points = select(run, &m.model, "bvh", SurfaceKind::Sj);
        let top = sorted_set(points.iter().map(|p| p.lod_threshold)).last().copied().unwrap_or(0.0);
        // The farthest with 64 × 64 pixels, or else the nearest.
        let key = |p: &PointRecord| (p.pixels >= 64 * 64, if p.pixels >= 64 * 64 { p.distance } else { -p.distance });
        let Some(worst) = points
            .iter()
            .filter(|p| p.lod_threshold == top && top > 0.0)
            .max_by(|a, b| key(a).partial_cmp(&key(b)).expect("finite distances"))
        else {
            continue;
        };
        let full_image = run
            .points
            .iter()
            .find(|p| {
                p.model == m.model
                    && p.surface == SurfaceKind::Sj
                    && p.lod_threshold == 0.0
                    && p.spp == 1
                    && p.distance == worst.distance
            })
            .and_then(|p| p.image.clone());
        let (Some(full_image), Some(lod_image)) = (full_image, worst.image.clone()) else { continue };
        let mut cells = Vec::new();
        for image in [full_image, lod_image] {
            let name = Path::new(&image).file_name().context("image name")?.to_string_lossy().into_owned();
            std::fs::copy(results.join(&image), figures.join("images").join(&name))
                .with_context(|| format!("{}: cannot copy", results.join(&image).display()))?;
            cells.push(format!("<img src=\"{}\" width=\"240\">", link(&format!("images/{name}"))));
        }
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} (τ = {}) | {} | {:.3} |",
            m.model,
            worst.distance,
            cells[0],
            cells[1],
            worst.lod_threshold,
            psnr(worst.psnr_db),
            worst.flip
        );
    }
    md.push('\n');
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_grouped_by_thousands() {
        assert_eq!(thousands(0), "0");
        assert_eq!(thousands(999), "999");
        assert_eq!(thousands(35_947), "35,947");
        assert_eq!(thousands(10_000_000), "10,000,000");
    }
}
