//! E57 (ASTM E2807), what terrestrial laser scanners export: several scans, each with its pose,
//! in Cartesian or spherical coordinates, as floats or scaled integers, with colour and
//! intensity and per-point validity flags. Read with the `e57` crate: every scan's valid
//! points, its pose applied and spherical coordinates converted (each scanner's position kept
//! to orient its points' normals); colours and intensity
//! normalised by the file's limits (a scan without colour shows its intensity as grey; the
//! intensity is kept as a scan attribute too); pages with a bad CRC refused.

use std::io::Cursor;
use std::path::Path;

use glam::DVec3;

use crate::builder::{Attributes, CloudBuilder, PointRecord, ScanFields};
use crate::{FileInfo, IoError, LoadedCloud};

/// The signature E57 files start with.
pub(crate) fn looks_like_e57(bytes: &[u8]) -> bool {
    bytes.starts_with(b"ASTM-E57")
}

pub(crate) fn parse(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    // A malformed file must end in an error that names it, whatever the decoder does.
    std::panic::catch_unwind(|| decode(path, bytes))
        .unwrap_or_else(|_| Err(IoError::invalid(path, "corrupt E57 data: the decoder failed")))
}

fn decode(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    let error = |e: e57::Error| IoError::invalid(path, format!("not a readable E57 file: {e}"));
    let mut reader = e57::E57Reader::new(Cursor::new(bytes)).map_err(error)?;
    let scans = reader.pointclouds();
    // A scan without colour shows its intensity as grey (the crate's conversion), as scanners'
    // own viewers do; the intensity is kept besides.
    let colors = scans.iter().any(|s| s.has_color() || s.has_intensity());
    let scan_fields = ScanFields { intensity: scans.iter().any(|s| s.has_intensity()), ..ScanFields::default() };
    let mut builder = CloudBuilder::new(0, Attributes { colors, scan: scan_fields, ..Attributes::default() });
    let mut skipped = 0u64;
    // Which scan each point came from, for the scanners' viewpoints.
    let mut scan_of: Vec<u16> = Vec::new();
    for (index, scan) in scans.iter().enumerate() {
        let in_scan = |e: e57::Error| IoError::invalid(path, format!("scan {}: {e}", index + 1));
        for point in reader.pointcloud_simple(scan).map_err(in_scan)? {
            let point = point.map_err(in_scan)?;
            let e57::CartesianCoordinate::Valid { x, y, z } = point.cartesian else {
                skipped += 1; // invalid, or a direction without a range
                continue;
            };
            let color = point.color.map_or([0.5; 3], |c| [c.red, c.green, c.blue]);
            let intensity = point.intensity.unwrap_or(0.0);
            builder.push(&PointRecord { position: DVec3::new(x, y, z), color, intensity, ..PointRecord::default() });
            scan_of.push(index as u16); // (wraps past 65,535 scans, whose viewpoints are not kept)
        }
    }
    if skipped > 0 {
        tracing::info!("{}: {skipped} points without a valid position left out", path.display());
    }
    let points = builder.len();
    let mut cloud = builder.finish();
    // Each scan's scanner position orients its points' normals towards it, where every scan is
    // a scanner's (its points in spherical coordinates or on a row-and-column grid: a pose on
    // Cartesian points alone may place no scanner); otherwise the spanning tree orients them.
    let scanners: Option<Vec<DVec3>> = scans
        .iter()
        .map(|scan| {
            // A scanner's scan without a pose stands at the origin.
            let scanner = scan.has_spherical() || scan.has_row_column();
            let t = scan.transform.as_ref().map(|t| &t.translation);
            scanner.then(|| t.map_or(DVec3::ZERO, |t| DVec3::new(t.x, t.y, t.z)))
        })
        .collect();
    if let Some(scanners) = scanners.filter(|s| !s.is_empty() && s.len() <= usize::from(u16::MAX)) {
        cloud.viewpoints = scanners.iter().map(|p| (*p - cloud.origin).as_vec3()).collect();
        cloud.viewpoint_of = (scanners.len() > 1).then_some(scan_of);
    }
    let mut properties = vec!["x".to_string(), "y".into(), "z".into()];
    if colors {
        properties.extend(["red".into(), "green".into(), "blue".into()]);
    }
    properties.extend(scan_fields.names());
    let info = FileInfo {
        format: format!("E57, {} {}", scans.len(), if scans.len() == 1 { "scan" } else { "scans" }),
        elements: vec![("point".into(), points)],
        vertex_properties: properties,
        comments: scans.iter().filter_map(|s| s.name.clone()).collect(),
        file_bytes: bytes.len() as u64,
        // Scanners level their scans: the world's z is up.
        up: Some([0.0, 0.0, 1.0]),
        sun: None,
    };
    Ok(LoadedCloud { cloud, info })
}
