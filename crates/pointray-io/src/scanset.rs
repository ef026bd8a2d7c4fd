//! Stanford scan sets: a `.conf` file lists range scans with the rigid transform that
//! registers each, and they are merged into one cloud.
//!
//! ```text
//! camera tx ty tz qx qy qz qw          (ignored: the scanner's viewpoint)
//! bmesh bun045.ply tx ty tz qx qy qz qw
//! ```
//!
//! Scan paths are relative to the `.conf` file's folder. A scan's point p goes to
//! R(q)⁻¹·p + t, the quaternion's real part last (the identity is `0 0 0 1`): the file's
//! quaternion turns the world into the scan's frame, its translation is in world units. This
//! was checked on the bunny's ten scans, the only way of six that puts them together: their
//! merged bounding box has a diagonal of 0.273 (the zippered reconstruction's is 0.250),
//! against 0.592 for R·p + t, 0.576 for R⁻¹·(p − t) and 0.707–0.764 for the other three.
//! Points are transformed in double precision before the merged cloud is recentred; normals
//! are rotated; radii and colours are kept only if every scan has them.

use std::path::Path;

use glam::{DQuat, DVec3};

use crate::builder::merge;
use crate::text::{Lines, as_text, data_part, split_values};
use crate::{FileInfo, IoError, LoadedCloud, read_any};

/// Whether `bytes` look like a scan set: the first data line starts with `camera` or `bmesh`.
pub(crate) fn looks_like_conf(bytes: &[u8]) -> bool {
    for (_, line) in Lines::new(bytes, 1) {
        let Some(data) = as_text(line).and_then(data_part) else { continue };
        return matches!(split_values(data).first(), Some(&"camera" | &"bmesh"));
    }
    false
}

/// One registered scan.
struct Scan {
    file: String,
    line: usize,
    translation: DVec3,
    rotation: DQuat,
}

pub(crate) fn parse(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    let mut scans = Vec::new();
    for (number, line) in Lines::new(bytes, 1) {
        let error = |message: String| IoError::at_line(path, number, message);
        let text = as_text(line).ok_or_else(|| error("line is not text".into()))?;
        let Some(data) = data_part(text) else { continue };
        let values = split_values(data);
        let (file, numbers) = match values.as_slice() {
            ["camera", ..] => continue,
            ["bmesh", file, numbers @ ..] => (file.to_string(), numbers),
            [word, ..] => return Err(error(format!("expected 'camera' or 'bmesh', found '{word}'"))),
            [] => continue,
        };
        let numbers: Vec<f64> = numbers
            .iter()
            .map(|v| v.parse::<f64>().ok().filter(|x| x.is_finite()))
            .collect::<Option<_>>()
            .filter(|n: &Vec<f64>| n.len() == 7)
            .ok_or_else(|| error(format!("bmesh {file}: expected 7 finite numbers (tx ty tz qx qy qz qw)")))?;
        let rotation = DQuat::from_xyzw(numbers[3], numbers[4], numbers[5], numbers[6]);
        if !(rotation.length() > 0.5 && rotation.length() < 2.0) {
            return Err(error(format!("bmesh {file}: the quaternion is far from unit length")));
        }
        let translation = DVec3::new(numbers[0], numbers[1], numbers[2]);
        scans.push(Scan { file, line: number, translation, rotation: rotation.normalize() });
    }
    if scans.is_empty() {
        return Err(IoError::invalid(path, "the scan set lists no 'bmesh' scan"));
    }
    let folder = path.parent().unwrap_or(Path::new("."));
    let mut loaded = Vec::with_capacity(scans.len());
    for scan in &scans {
        let cloud = read_any(&folder.join(&scan.file), false)
            .map_err(|e| IoError::at_line(path, scan.line, format!("bmesh {}: {e}", scan.file)))?;
        loaded.push(cloud);
    }
    let (clouds, infos): (Vec<_>, Vec<_>) = loaded.into_iter().map(|l| (l.cloud, l.info)).unzip();
    let info = FileInfo {
        format: format!("Stanford scan set, {} scans", scans.len()),
        elements: scans.iter().zip(&clouds).map(|(s, c)| (s.file.clone(), c.len())).collect(),
        vertex_properties: infos[0].vertex_properties.clone(),
        comments: Vec::new(),
        file_bytes: bytes.len() as u64 + infos.iter().map(|i| i.file_bytes).sum::<u64>(),
        up: None,
        sun: None,
    };
    let to_world: Vec<DQuat> = scans.iter().map(|s| s.rotation.inverse()).collect();
    let cloud = merge(
        clouds,
        |k, world| to_world[k] * world + scans[k].translation,
        |k, normal| (to_world[k] * normal.as_dvec3()).as_vec3(),
    );
    Ok(LoadedCloud { cloud, info })
}
