//! `pointray prepare`: preprocess once, write a binary PLY with normals, radii, colours, scan
//! attributes, the data's up axis and its sun; or, to a `.prs` output, the scene built from it
//! (a BVH with its level of detail, `docs/prs.md`), which a render maps instead of building.

use crate::args::PrepareArgs;

pub fn run(a: &PrepareArgs, quiet: bool) -> anyhow::Result<()> {
    super::check_output_path(&a.output)?;
    let config = a.preprocess.config();
    config.check().map_err(|e| crate::failure::usage(super::render::flag_error(e)))?;
    if a.output.extension().is_some_and(|e| e.eq_ignore_ascii_case("prs")) {
        return scene_file(a, &config, quiet);
    }
    if a.build.settings() != pointray::Settings::default() {
        return Err(crate::failure::usage(anyhow::anyhow!(
            "{}: the render's flags (--surface, --color-by, --classes, a clip, --sphere-from-level) apply to a scene file \
             (-o NAME.prs), not to a prepared PLY",
            a.output.display()
        )));
    }
    let spinner = crate::progress::spinner("read", quiet);
    let stage = |s: &str| spinner.set_message(s.to_string());
    let prepared = pointray_io::source::read_prepared(&a.inputs, &config, &a.read.options(), &stage)?;
    let axes = pointray_io::Axes { up: prepared.up.map(|u| u.to_array()), sun: prepared.sun.map(|s| s.to_array()) };
    let (cloud, stats) = (prepared.cloud, prepared.preprocess);
    spinner.finish_and_clear();
    crate::progress::spinning("write", quiet, || pointray_io::write_ply_with_axes(&a.output, &cloud, axes))
        .map_err(crate::failure::output)?;
    if !quiet {
        eprintln!(
            "{}: {} {}, normals {}, radii {}, wrote {}",
            pointray_io::set_name(&a.inputs).display(),
            cloud.len(),
            if cloud.len() == 1 { "point" } else { "points" },
            if stats.computed_normals { "computed" } else { "from file" },
            if stats.computed_radii { "computed" } else { "from file" },
            a.output.display()
        );
    }
    Ok(())
}

/// Bytes a point takes preparing a cloud with normals and radii in memory (the 30-million-point
/// torus peaked at 2.35 GB: 78 a point).
const BYTES_A_POINT: u64 = 90;

/// The memory budget without `--memory-budget`: half the physical memory (unbounded where the
/// system does not say).
fn default_budget() -> u64 {
    let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
    let total_kb = meminfo
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:")?.trim().strip_suffix("kB")?.trim().parse::<u64>().ok());
    total_kb.map_or(u64::MAX, |kb| kb * 1024 / 2)
}

/// `prepare IN -o OUT.prs`: the scene a render of IN with the same build flags builds, stored.
fn scene_file(a: &PrepareArgs, config: &pointray::preprocess::PreprocessConfig, quiet: bool) -> anyhow::Result<()> {
    // The points the headers give, or as many as fit the files at 28 bytes (a binary PLY's least).
    let size: u64 = a.inputs.iter().map(|i| std::fs::metadata(i).map_or(0, |m| m.len())).sum();
    let points = pointray_io::prepare::points_in(&a.inputs).map_or(size / 28, |n| n as u64);
    let name = pointray_io::set_name(&a.inputs);
    let need = points * BYTES_A_POINT;
    match a.memory_budget {
        // Asked for: out of core or refused, naming why.
        Some(budget) if need > budget => return out_of_core(a, config, quiet),
        // By default, within half this machine's memory where it can be done.
        None if need > default_budget() => match out_of_core_refusal(a, config) {
            None => return out_of_core(a, config, quiet),
            Some(why) => tracing::warn!(
                "{}: preparing it takes more than half this machine's memory; it is prepared in memory ({why})",
                name.display()
            ),
        },
        _ => {}
    }
    let spinner = crate::progress::spinner("read", quiet);
    let stage = |s: &str| spinner.set_message(s.to_string());
    let source = pointray_io::source::load_tiles(&a.inputs, config, &a.read.options(), &stage)?;
    stage("build");
    let settings = a.build.settings();
    settings.check().map_err(|e| crate::failure::usage(super::render::flag_error(e)))?;
    let scene = pointray::Scene::build(source.parts, &settings).map_err(|e| match e {
        pointray::scene::SceneError::Settings(e) => super::render::flag_error(e).context(name.display().to_string()),
        e => anyhow::anyhow!("{}: {e}", name.display()),
    })?;
    spinner.finish_and_clear();
    crate::progress::spinning("write", quiet, || pointray_io::prs::write_prs(&a.output, &scene))
        .map_err(crate::failure::output)?;
    if !quiet {
        let bytes = std::fs::metadata(&a.output).map(|m| m.len()).unwrap_or(0);
        let per_point = bytes as f64 / scene.points().max(1) as f64;
        eprintln!(
            "{}: {} points in a BVH, wrote {} ({bytes} bytes, {per_point:.1} a point)",
            name.display(),
            scene.points(),
            a.output.display()
        );
    }
    Ok(())
}

/// Why [`out_of_core`] would refuse `a`, if it would.
fn out_of_core_refusal(a: &PrepareArgs, config: &pointray::preprocess::PreprocessConfig) -> Option<String> {
    if a.build.settings() != pointray::Settings::default() {
        return Some("out of core, only the default build settings are prepared for now".into());
    }
    pointray_io::prepare::out_of_core_refusal(&a.inputs, config)
}

/// `prepare IN -o OUT.prs --memory-budget SIZE` for a cloud larger than the budget.
fn out_of_core(a: &PrepareArgs, config: &pointray::preprocess::PreprocessConfig, quiet: bool) -> anyhow::Result<()> {
    if a.build.settings() != pointray::Settings::default() {
        return Err(crate::failure::usage(anyhow::anyhow!(
            "{}: out of core (--memory-budget), only the default build settings are prepared for now",
            a.output.display()
        )));
    }
    let bar = crate::progress::bar(0, "", quiet);
    // A bar a pass, its ETA the pass's.
    let progress = |p: &pointray_io::prepare::Progress| {
        if bar.message() != p.stage {
            bar.reset();
            bar.set_message(p.stage.to_string());
        }
        bar.set_length(p.total as u64);
        bar.set_position(p.done as u64);
    };
    let options = pointray_io::prepare::OutOfCore { preprocess: *config, ..Default::default() };
    let done = pointray_io::prepare::prepare_out_of_core(&a.inputs, &a.output, &options, &progress)?;
    bar.finish_and_clear();
    if !quiet {
        let bytes = std::fs::metadata(&a.output).map(|m| m.len()).unwrap_or(0);
        eprintln!(
            "{}: {} points in {} chunks, out of core, wrote {} ({bytes} bytes, {:.1} a point)",
            pointray_io::set_name(&a.inputs).display(),
            done.points,
            done.chunks,
            a.output.display(),
            bytes as f64 / done.points.max(1) as f64
        );
    }
    Ok(())
}
