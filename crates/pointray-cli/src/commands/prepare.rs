//! `pointray prepare`: preprocess once, write a binary PLY with normals, radii, colours, scan
//! attributes, the data's up axis and its sun.

use crate::args::PrepareArgs;

pub fn run(a: &PrepareArgs, quiet: bool) -> anyhow::Result<()> {
    super::check_output_path(&a.output)?;
    let config = a.preprocess.config();
    config.check().map_err(|e| crate::failure::usage(super::render::flag_error(e)))?;
    let spinner = crate::progress::spinner("read", quiet);
    let stage = |s: &str| spinner.set_message(s.to_string());
    let prepared = pointray_io::source::read_prepared(&a.input, &config, &a.read.options(), &stage)?;
    let axes = pointray_io::Axes { up: prepared.up.map(|u| u.to_array()), sun: prepared.sun.map(|s| s.to_array()) };
    let (cloud, stats) = (prepared.cloud, prepared.preprocess);
    spinner.finish_and_clear();
    crate::progress::spinning("write", quiet, || pointray_io::write_ply_with_axes(&a.output, &cloud, axes))
        .map_err(crate::failure::output)?;
    if !quiet {
        eprintln!(
            "{}: {} {}, normals {}, radii {}, wrote {}",
            a.input.display(),
            cloud.len(),
            if cloud.len() == 1 { "point" } else { "points" },
            if stats.computed_normals { "computed" } else { "from file" },
            if stats.computed_radii { "computed" } else { "from file" },
            a.output.display()
        );
    }
    Ok(())
}
