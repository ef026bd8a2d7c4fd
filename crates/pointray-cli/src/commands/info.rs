//! `pointray info`: what a file holds.

use std::io::{self, Write};

use crate::args::InfoArgs;

pub fn run(a: &InfoArgs, quiet: bool) -> anyhow::Result<()> {
    if pointray_io::prs::is_prs(&a.input) {
        return scene_file(a);
    }
    let (loaded, seconds) = super::load(&a.input, &a.read.options(), quiet)?;
    let (info, cloud) = (&loaded.info, &loaded.cloud);
    let mut out = io::stdout().lock();
    writeln!(out, "file:        {}", a.input.display())?;
    writeln!(out, "format:      {}", info.format)?;
    writeln!(out, "size:        {} bytes (read in {:.3} s)", info.file_bytes, seconds)?;
    for (name, count) in &info.elements {
        writeln!(out, "element:     {name} {count}")?;
    }
    writeln!(out, "properties:  {}", info.vertex_properties.join(", "))?;
    for c in &info.comments {
        writeln!(out, "comment:     {c}")?;
    }
    if let Some([x, y, z]) = info.up {
        writeln!(out, "up:          {x},{y},{z} (given by the file)")?;
    }
    if let Some([x, y, z]) = info.sun {
        writeln!(out, "sun:         {x},{y},{z} (towards it; the default light)")?;
    }
    writeln!(out, "points:      {}", cloud.len())?;
    let has = |b: bool| if b { "yes" } else { "no" };
    writeln!(out, "normals:     {}", has(cloud.normals.is_some()))?;
    writeln!(out, "radii:       {}", has(cloud.radii.is_some()))?;
    writeln!(out, "colours:     {}", has(cloud.colors.is_some()))?;
    let non_finite = cloud.positions.iter().filter(|p| !p.is_finite()).count();
    if non_finite > 0 {
        writeln!(out, "non-finite:  {non_finite} points (dropped when rendering)")?;
    }
    let finite: Vec<_> = cloud.positions.iter().copied().filter(|p| p.is_finite()).collect();
    let b = pointray::math::Aabb::from_points(finite);
    if !b.is_empty() {
        let o = cloud.origin;
        let lo = o + b.min.as_dvec3();
        let hi = o + b.max.as_dvec3();
        writeln!(out, "bounds min:  {:.6} {:.6} {:.6}", lo.x, lo.y, lo.z)?;
        writeln!(out, "bounds max:  {:.6} {:.6} {:.6}", hi.x, hi.y, hi.z)?;
        writeln!(out, "diagonal:    {:.6}", b.diagonal())?;
    }
    out.flush()?;
    Ok(())
}

/// What a scene file (`.prs`) holds, from its metadata (its arrays checked on the way).
fn scene_file(a: &InfoArgs) -> anyhow::Result<()> {
    let start = std::time::Instant::now();
    let stored = pointray_io::prs::open_prs(&a.input)?;
    let seconds = start.elapsed().as_secs_f64();
    let (meta, bytes) = (stored.meta(), std::fs::metadata(&a.input)?.len());
    let mut out = io::stdout().lock();
    writeln!(out, "file:        {}", a.input.display())?;
    writeln!(out, "format:      pointray scene file, format {}", pointray_io::prs::VERSION)?;
    writeln!(
        out,
        "size:        {bytes} bytes, {:.1} a point (opened and checked in {seconds:.3} s)",
        bytes as f64 / meta.points.max(1) as f64
    )?;
    writeln!(out, "points:      {}", meta.points)?;
    if meta.parts.len() > 1 {
        let most = meta.parts.iter().map(|p| p.bvh.splat_count).max().unwrap_or(0);
        writeln!(out, "parts:       {} (each a BVH in its own frame; the largest {most} splats)", meta.parts.len())?;
    }
    let b = &meta.build;
    writeln!(out, "build:       {}", serde_json::to_string(b)?)?;
    let [x, y, z] = meta.up;
    writeln!(out, "up:          {x},{y},{z}")?;
    let o = glam::DVec3::from(meta.origin);
    let [lo, hi] = meta.bounds.map(|c| o + glam::Vec3::from(c).as_dvec3());
    writeln!(out, "bounds min:  {:.6} {:.6} {:.6}", lo.x, lo.y, lo.z)?;
    writeln!(out, "bounds max:  {:.6} {:.6} {:.6}", hi.x, hi.y, hi.z)?;
    writeln!(out, "diagonal:    {:.6}", (hi - lo).length())?;
    out.flush()?;
    Ok(())
}
