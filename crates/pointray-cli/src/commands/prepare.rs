//! `pointray prepare`: preprocess once, write a binary PLY with normals, radii and colours.

use crate::args::PrepareArgs;

pub fn run(a: &PrepareArgs, quiet: bool) -> anyhow::Result<()> {
    super::check_output_path(&a.output)?;
    let (loaded, _) = super::load(&a.input)?;
    let mut cloud = loaded.cloud;
    let stats = super::prepare_cloud(&mut cloud, &a.preprocess, quiet)
        .map_err(|e| e.context(format!("{}: preprocessing", a.input.display())))?;
    pointray_io::write_ply(&a.output, &cloud)?;
    if !quiet {
        eprintln!(
            "{}: {} points (dropped {} non-finite), normals {}, radii {}, wrote {}",
            a.input.display(),
            cloud.len(),
            stats.dropped_non_finite,
            if stats.computed_normals { "computed" } else { "from file" },
            if stats.computed_radii { "computed" } else { "from file" },
            a.output.display()
        );
    }
    Ok(())
}
