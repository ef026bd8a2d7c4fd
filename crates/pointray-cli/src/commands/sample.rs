//! `pointray sample`: a dense point cloud from a triangle mesh.

use std::time::Instant;

use anyhow::Context;
use pointray::PointCloud;
use pointray::mesh_sampling::{SampleNormals, sample_surface};

use crate::args::{NormalsArg, SampleArgs};
use crate::failure;

pub fn run(a: &SampleArgs, quiet: bool) -> anyhow::Result<()> {
    if a.points == 0 || a.points > u64::from(u32::MAX) {
        return Err(failure::usage(anyhow::anyhow!("--points must be between 1 and {}", u32::MAX)));
    }
    super::check_output_path(&a.output)?;
    let t = Instant::now();
    let spinner = crate::progress::spinner("read", quiet);
    let mesh = pointray_io::read_mesh(&a.input);
    spinner.finish_and_clear();
    let mesh = mesh?;
    let read_seconds = t.elapsed().as_secs_f64();
    if mesh.skipped_faces > 0 {
        tracing::warn!("{}: {} faces with fewer than 3 vertices left out", a.input.display(), mesh.skipped_faces);
    }

    let t = Instant::now();
    let spinner = crate::progress::spinner("sample", quiet);
    let normals = match a.normals {
        NormalsArg::Smooth => SampleNormals::Smooth,
        NormalsArg::Face => SampleNormals::Face,
    };
    let samples = sample_surface(&mesh.vertices.positions, &mesh.triangles, a.points as usize, a.seed, normals);
    spinner.finish_and_clear();
    let samples = samples.with_context(|| format!("{}: sampling", a.input.display()))?;
    let sample_seconds = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let area = samples.area;
    let cloud = PointCloud {
        positions: samples.positions,
        normals: Some(samples.normals),
        origin: mesh.vertices.origin,
        ..PointCloud::default()
    };
    drop(mesh.vertices);
    let spinner = crate::progress::spinner("write", quiet);
    let written = pointray_io::write_ply(&a.output, &cloud);
    spinner.finish_and_clear();
    written.map_err(failure::output)?;
    if !quiet {
        eprintln!(
            "{}: {} triangles, area {area:.6}; {} points in {:.2} s (read {read_seconds:.2} s, sample \
             {sample_seconds:.2} s, write {:.2} s), wrote {}",
            a.input.display(),
            mesh.triangles.len(),
            cloud.len(),
            read_seconds + sample_seconds + t.elapsed().as_secs_f64(),
            t.elapsed().as_secs_f64(),
            a.output.display()
        );
    }
    Ok(())
}
