//! `pointray sample`: a dense point cloud from a triangle mesh.

use std::time::Instant;

use anyhow::Context;
use pointray::PointCloud;
use pointray::mesh_sampling::{SampleNormals, Sampling, SurfaceMesh, sample_surface};

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
    let normals = match a.normals {
        NormalsArg::Smooth => SampleNormals::Smooth,
        NormalsArg::Face => SampleNormals::Face,
    };
    let sampled = sample_mesh(&a.input, a.points as usize, a.seed, normals, quiet)?;
    let (cloud, area, triangles) = (sampled.cloud, sampled.area, sampled.triangles);
    let (read_seconds, sample_seconds) = (sampled.read_seconds, t.elapsed().as_secs_f64() - sampled.read_seconds);

    let t = Instant::now();
    spinning("write", quiet, || pointray_io::write_ply(&a.output, &cloud)).map_err(failure::output)?;
    let write_seconds = t.elapsed().as_secs_f64();
    if !quiet {
        eprintln!(
            "{}: {} triangles, area {area:.6}; {} points in {:.2} s (read {read_seconds:.2} s, sample \
             {sample_seconds:.2} s, write {:.2} s), wrote {}",
            a.input.display(),
            triangles,
            cloud.len(),
            read_seconds + sample_seconds + write_seconds,
            write_seconds,
            a.output.display()
        );
    }
    Ok(())
}

/// A mesh's surface sampled with `points` points, and what it took.
pub struct SampledMesh {
    pub cloud: PointCloud,
    pub area: f64,
    pub triangles: usize,
    pub read_seconds: f64,
}

/// Reads the mesh at `path` and places `points` points on its triangles (deterministic for
/// `seed`, whatever the thread count), warning about faces and triangles it had to leave out.
pub fn sample_mesh(
    path: &std::path::Path,
    points: usize,
    seed: u64,
    normals: SampleNormals,
    quiet: bool,
) -> anyhow::Result<SampledMesh> {
    let t = Instant::now();
    let mesh = spinning("read", quiet, || pointray_io::read_mesh(path))?;
    let read_seconds = t.elapsed().as_secs_f64();
    if mesh.skipped_faces > 0 {
        let n = mesh.skipped_faces;
        let faces = if n == 1 { "face" } else { "faces" };
        tracing::warn!("{}: {n} {faces} with fewer than 3 vertices left out", path.display());
    }
    let surface = SurfaceMesh {
        vertices: &mesh.vertices.positions,
        triangles: &mesh.triangles,
        colors: mesh.vertices.colors.as_deref(),
    };
    let sampling = Sampling { count: points, seed, normals };
    let samples = spinning("sample", quiet, || sample_surface(&surface, &sampling));
    let samples = samples.with_context(|| format!("{}: sampling", path.display()))?;
    if samples.empty_triangles > 0 {
        let n = samples.empty_triangles;
        let triangles = if n == 1 { "triangle has" } else { "triangles have" };
        tracing::warn!("{}: {n} {triangles} no area or a non-finite vertex; no points on them", path.display());
    }
    let cloud = PointCloud {
        positions: samples.positions,
        normals: Some(samples.normals),
        colors: samples.colors,
        origin: mesh.vertices.origin,
        ..PointCloud::default()
    };
    Ok(SampledMesh { cloud, area: samples.area, triangles: mesh.triangles.len(), read_seconds })
}
