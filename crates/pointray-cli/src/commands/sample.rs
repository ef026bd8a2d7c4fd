//! `pointray sample`: a dense point cloud from a triangle mesh.

use std::time::Instant;

use anyhow::Context;
use pointray::PointCloud;
use pointray::mesh_sampling::{SampleNormals, sample_surface};

use crate::args::{NormalsArg, SampleArgs};
use crate::failure;
use crate::progress::spinning;

pub fn run(a: &SampleArgs, quiet: bool) -> anyhow::Result<()> {
    // No more than `render` can index: a larger cloud could be written but never rendered.
    let max = pointray::accel::bvh::MAX_SPLATS;
    if a.points == 0 || a.points > max as u64 {
        return Err(failure::usage(anyhow::anyhow!("--points must be between 1 and {max}")));
    }
    super::check_output_path(&a.output)?;
    let t = Instant::now();
    let mesh = spinning("read", quiet, || pointray_io::read_mesh(&a.input))?;
    let read_seconds = t.elapsed().as_secs_f64();
    if mesh.skipped_faces > 0 {
        let n = mesh.skipped_faces;
        let faces = if n == 1 { "face" } else { "faces" };
        tracing::warn!("{}: {n} {faces} with fewer than 3 vertices left out", a.input.display());
    }

    let t = Instant::now();
    let normals = match a.normals {
        NormalsArg::Smooth => SampleNormals::Smooth,
        NormalsArg::Face => SampleNormals::Face,
    };
    let samples = spinning("sample", quiet, || {
        sample_surface(&mesh.vertices.positions, &mesh.triangles, a.points as usize, a.seed, normals)
    });
    let samples = samples.with_context(|| format!("{}: sampling", a.input.display()))?;
    let sample_seconds = t.elapsed().as_secs_f64();
    if samples.empty_triangles > 0 {
        let n = samples.empty_triangles;
        let triangles = if n == 1 { "triangle has" } else { "triangles have" };
        tracing::warn!("{}: {n} {triangles} no area or a non-finite vertex; no points on them", a.input.display());
    }

    let t = Instant::now();
    let area = samples.area;
    let cloud = PointCloud {
        positions: samples.positions,
        normals: Some(samples.normals),
        origin: mesh.vertices.origin,
        ..PointCloud::default()
    };
    drop(mesh.vertices);
    spinning("write", quiet, || pointray_io::write_ply(&a.output, &cloud)).map_err(failure::output)?;
    let write_seconds = t.elapsed().as_secs_f64();
    if !quiet {
        eprintln!(
            "{}: {} triangles, area {area:.6}; {} points in {:.2} s (read {read_seconds:.2} s, sample \
             {sample_seconds:.2} s, write {:.2} s), wrote {}",
            a.input.display(),
            mesh.triangles.len(),
            cloud.len(),
            read_seconds + sample_seconds + write_seconds,
            write_seconds,
            a.output.display()
        );
    }
    Ok(())
}
