//! `pointray prepare`: preprocess once, write a binary PLY with normals, radii and colours.

use crate::args::PrepareArgs;

pub fn run(a: &PrepareArgs, quiet: bool) -> anyhow::Result<()> {
    super::check_output_path(&a.output)?;
    let (loaded, _) = super::load(&a.input, quiet)?;
    let mut cloud = loaded.cloud;
    let stats = super::prepare_cloud(&mut cloud, &a.preprocess, &a.input.display().to_string(), quiet)?;
    crate::progress::spinning("write", quiet, || pointray_io::write_ply(&a.output, &cloud))
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
