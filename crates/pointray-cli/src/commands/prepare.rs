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

/// `prepare IN... -o OUT.prs`: the scene a render of IN with the same build flags builds,
/// stored; in memory or out of core as `--memory-budget` says (`pointray_io::prepare`).
fn scene_file(a: &PrepareArgs, config: &pointray::preprocess::PreprocessConfig, quiet: bool) -> anyhow::Result<()> {
    use pointray_io::prepare::{SceneFileError, SceneFileOptions, prepare_scene_file};
    let options = SceneFileOptions {
        preprocess: *config,
        read: a.read.options(),
        settings: a.build.settings(),
        memory_budget: a.memory_budget,
    };
    let progress = crate::progress::stages(quiet);
    let done = prepare_scene_file(&a.inputs, &a.output, &options, &|p| progress.show(p.stage, p.done, p.total));
    progress.finish();
    let name = pointray_io::set_name(&a.inputs);
    let done = done.map_err(|e| match e {
        SceneFileError::Settings(e) => {
            crate::failure::usage(super::render::flag_error(e).context(name.display().to_string()))
        }
        // A colour or class flag the cloud cannot give: named as the flag, as a render does.
        SceneFileError::Unmet(e) => super::render::flag_error(e).context(name.display().to_string()),
        SceneFileError::Input(e) => e.into(),
        SceneFileError::Output(e) => crate::failure::output(e),
    })?;
    if !quiet {
        let how = match (done.chunks, done.parts) {
            (Some(chunks), 1) => format!("in {chunks} chunks, out of core"),
            (Some(chunks), parts) => format!("in {parts} parts of {chunks} chunks, out of core"),
            (None, 1) => "in a BVH".to_string(),
            (None, parts) => format!("in {parts} parts"),
        };
        eprintln!(
            "{}: {} points {how}, wrote {} ({} bytes, {:.1} a point)",
            name.display(),
            done.points,
            a.output.display(),
            done.bytes,
            done.bytes as f64 / done.points.max(1) as f64
        );
    }
    Ok(())
}
