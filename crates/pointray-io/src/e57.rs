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
    guarded(path, || decode(path, bytes))
}

fn decode(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    let error = |e: e57::Error| IoError::invalid(path, format!("not a readable E57 file: {e}"));
    let mut reader = e57::E57Reader::new(Cursor::new(bytes)).map_err(error)?;
    let scans = Scans::of(&reader.pointclouds());
    let attributes = Attributes { colors: scans.colors, scan: scans.fields, ..Attributes::default() };
    let mut builder = CloudBuilder::new(0, attributes);
    // Which scan each point came from, for the scanners' viewpoints.
    let mut scan_of: Vec<u16> = Vec::new();
    let skipped = each_point(path, &mut reader, &mut |r| {
        builder.push(r);
        scan_of.push(r.viewpoint);
    })?;
    if skipped > 0 {
        tracing::info!("{}: {skipped} points without a valid position left out", path.display());
    }
    let points = builder.len();
    let mut cloud = builder.finish();
    if let Some(scanners) = &scans.scanners {
        cloud.viewpoints = scanners.iter().map(|p| (*p - cloud.origin).as_vec3()).collect();
        cloud.viewpoint_of = (scanners.len() > 1).then_some(scan_of);
    }
    let info = scans.info(bytes.len() as u64, points);
    Ok(LoadedCloud { cloud, info })
}

/// What an E57 file's scans say of their points.
struct Scans {
    /// A scan without colour shows its intensity as grey (the crate's conversion), as scanners'
    /// own viewers do; the intensity is kept besides.
    colors: bool,
    fields: ScanFields,
    /// Each scan's scanner, which orients its points' normals towards it, where every scan is a
    /// scanner's (its points in spherical coordinates or on a row-and-column grid: a pose on
    /// Cartesian points alone may place no scanner); otherwise the spanning tree orients them.
    scanners: Option<Vec<DVec3>>,
    /// The points the headers count (the invalid ones too).
    records: u64,
    count: usize,
    names: Vec<String>,
}

impl Scans {
    fn of(scans: &[e57::PointCloud]) -> Self {
        let scanners: Option<Vec<DVec3>> = scans
            .iter()
            .map(|scan| {
                // A scanner's scan without a pose stands at the origin.
                let scanner = scan.has_spherical() || scan.has_row_column();
                let t = scan.transform.as_ref().map(|t| &t.translation);
                scanner.then(|| t.map_or(DVec3::ZERO, |t| DVec3::new(t.x, t.y, t.z)))
            })
            .collect();
        Self {
            colors: scans.iter().any(|s| s.has_color() || s.has_intensity()),
            fields: ScanFields { intensity: scans.iter().any(|s| s.has_intensity()), ..ScanFields::default() },
            scanners: scanners.filter(|s| !s.is_empty() && s.len() <= usize::from(u16::MAX)),
            records: scans.iter().map(|s| s.records).sum(),
            count: scans.len(),
            names: scans.iter().filter_map(|s| s.name.clone()).collect(),
        }
    }

    fn info(&self, file_bytes: u64, points: usize) -> FileInfo {
        let mut properties = vec!["x".to_string(), "y".into(), "z".into()];
        if self.colors {
            properties.extend(["red".into(), "green".into(), "blue".into()]);
        }
        properties.extend(self.fields.names());
        let scans = self.count;
        FileInfo {
            format: format!("E57, {scans} {}", if scans == 1 { "scan" } else { "scans" }),
            elements: vec![("point".into(), points)],
            vertex_properties: properties,
            comments: self.names.clone(),
            file_bytes,
            // Scanners level their scans: the world's z is up.
            up: Some([0.0, 0.0, 1.0]),
            sun: None,
        }
    }
}

/// Calls `visit` with each valid point of every scan in turn, its pose applied, `viewpoint` its
/// scan's number; returns how many were left out (invalid, or a direction without a range).
fn each_point<R: std::io::Read + std::io::Seek>(
    path: &Path,
    reader: &mut e57::E57Reader<R>,
    visit: &mut dyn FnMut(&PointRecord),
) -> Result<u64, IoError> {
    let mut skipped = 0;
    for (index, scan) in reader.pointclouds().iter().enumerate() {
        let in_scan = |e: e57::Error| IoError::invalid(path, format!("scan {}: {e}", index + 1));
        for point in reader.pointcloud_simple(scan).map_err(in_scan)? {
            let point = point.map_err(in_scan)?;
            let e57::CartesianCoordinate::Valid { x, y, z } = point.cartesian else {
                skipped += 1;
                continue;
            };
            visit(&PointRecord {
                position: DVec3::new(x, y, z),
                color: point.color.map_or([0.5; 3], |c| [c.red, c.green, c.blue]),
                intensity: point.intensity.unwrap_or(0.0),
                // (Wraps past 65,535 scans, whose viewpoints are not kept.)
                viewpoint: index as u16,
                ..PointRecord::default()
            });
        }
    }
    Ok(skipped)
}

/// An E57 file read in passes (out of core), a point at a time from the file.
pub(crate) struct E57Stream {
    path: std::path::PathBuf,
    /// The points its scans' headers count, the invalid ones too (left out as they are read).
    pub(crate) count: usize,
    pub(crate) info: FileInfo,
    pub(crate) colors: bool,
    pub(crate) fields: ScanFields,
    /// Each scan's scanner (see [`Scans`]), in the file's coordinates.
    pub(crate) scanners: Vec<DVec3>,
}

impl E57Stream {
    pub(crate) fn open(path: &Path) -> Result<Self, IoError> {
        let file_bytes = std::fs::metadata(path).map_err(|e| IoError::io(path, e))?.len();
        let scans = guarded(path, || Ok(Scans::of(&reader(path)?.pointclouds())))?;
        let count = usize::try_from(scans.records).map_err(|_| IoError::invalid(path, "too many points"))?;
        Ok(Self {
            path: path.to_path_buf(),
            count,
            info: scans.info(file_bytes, count),
            colors: scans.colors,
            fields: scans.fields,
            scanners: scans.scanners.unwrap_or_default(),
        })
    }

    /// Calls `visit` with every valid point in file order.
    pub(crate) fn for_each(&mut self, visit: impl FnMut(&PointRecord)) -> Result<(), IoError> {
        let path = &self.path;
        let mut visit = visit;
        guarded(path, || each_point(path, &mut reader(path)?, &mut visit).map(drop))
    }
}

fn reader(path: &Path) -> Result<e57::E57Reader<std::io::BufReader<std::fs::File>>, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    e57::E57Reader::new(std::io::BufReader::with_capacity(1 << 20, file))
        .map_err(|e| IoError::invalid(path, format!("not a readable E57 file: {e}")))
}

/// `work`'s result, or an error naming `path` if the decoder panics on malformed data.
fn guarded<T>(path: &Path, work: impl FnOnce() -> Result<T, IoError>) -> Result<T, IoError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(work))
        .unwrap_or_else(|_| Err(IoError::invalid(path, "corrupt E57 data: the decoder failed")))
}
