//! LAS and LAZ (airborne and terrestrial LiDAR), through the `las` crate with its pure-Rust
//! LAZ decompressor. Coordinates come out of the crate scaled and offset in f64 (survey
//! coordinates are large: Oregon Lambert feet in the hundreds of thousands), and the builder
//! recentres them before anything becomes f32.
//!
//! Colours: LAS stores 16-bit channels, but many writers put 8-bit values in them (the autzen
//! scans: 40–236). If no channel of any point exceeds 255, the values are taken as 8-bit.

use std::io::Cursor;
use std::path::Path;

use glam::DVec3;

use crate::builder::{Attributes, CloudBuilder, PointRecord, ScanFields};
use crate::file::FileBytes;
use crate::{FileInfo, IoError, LoadedCloud};

/// Whether `bytes` start with the LAS signature (LAZ files carry it too).
pub(crate) fn looks_like_las(bytes: &[u8]) -> bool {
    bytes.starts_with(b"LASF")
}

/// A LAZ file names its chunk count in a table the decoder allocates for before reading a
/// point, and an allocation that fails aborts the process (no panic to catch): a count the file
/// cannot hold is refused here. (Header offsets: the point data's at byte 96, the format's
/// compression bit at 104; the point data starts with the table's offset, -1 for "in the last
/// 8 bytes"; the table with a version and the count.)
fn check_laz_chunk_table(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let u32_at = |at: usize| bytes.get(at..at + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    let i64_at = |at: usize| bytes.get(at..at + 8).map(|b| i64::from_le_bytes(b.try_into().expect("8 bytes")));
    if bytes.get(104).is_none_or(|format| format & 0x80 == 0) {
        return Ok(()); // not compressed
    }
    let Some(points_at) = u32_at(96) else { return Ok(()) };
    let table_at = match i64_at(points_at as usize) {
        Some(-1) => i64_at(bytes.len().saturating_sub(8)),
        other => other,
    };
    let chunks = table_at.and_then(|at| usize::try_from(at).ok()).and_then(|at| u32_at(at + 4));
    match chunks {
        Some(chunks) if chunks as usize > bytes.len() / 4 => Err(IoError::invalid(
            path,
            format!("corrupt LAZ: its chunk table claims {chunks} chunks, more than the file can hold"),
        )),
        _ => Ok(()),
    }
}

/// The header's point count times its record length, plus the offset of the point data,
/// must fit in 64 bits: the `las` crate computes the end of the points unchecked (a release
/// build wraps, a checked one panics; found by the `las` and `cloud` fuzz targets). Offsets:
/// the version at bytes 24 and 25, the point data's at 96, the record length at 105, the
/// legacy count at 107, and in a LAS 1.4 header the 64-bit count at 247.
fn check_point_extent(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let u64_at = |at: usize, n: usize| little_endian(bytes, at, n);
    let (Some(offset), Some(length), Some(legacy)) = (u64_at(96, 4), u64_at(105, 2), u64_at(107, 4)) else {
        return Ok(()); // too short: the crate reports the truncated header
    };
    // The crate reads the 64-bit count for version 1.4 exactly, whatever the header size says.
    let wide = (bytes[24..26] == [1, 4]).then(|| u64_at(247, 8)).flatten();
    let count = legacy.max(wide.unwrap_or(0));
    if count.checked_mul(length).and_then(|n| n.checked_add(offset)).is_none() {
        return Err(IoError::invalid(
            path,
            format!("the header declares {count} points of {length} bytes, more than any file can hold"),
        ));
    }
    Ok(())
}

/// A LAS 1.4 file's first extended VLR: the crate allocates its declared length (a 64-bit
/// field) before reading it, and a failed allocation aborts the process; found by the `las`
/// fuzz target. It reads one when the header (start at byte 235, count at 243) names one; the
/// record's length sits 20 bytes into it, its data 60 bytes in.
fn check_first_evlr(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let u64_at = |at: usize, n: usize| little_endian(bytes, at, n);
    if bytes.get(24..26) != Some(&[1, 4]) {
        return Ok(());
    }
    let (Some(start), Some(count)) = (u64_at(235, 8), u64_at(243, 4)) else { return Ok(()) };
    let record = usize::try_from(start).ok().filter(|_| count > 0 && start > 0);
    let Some(length) = record.and_then(|at| u64_at(at.checked_add(20)?, 8)) else {
        return Ok(()); // no record, or one past the end: the crate fails to read it
    };
    let room = (bytes.len() as u64).saturating_sub(start.saturating_add(60));
    if length > room {
        return Err(IoError::invalid(
            path,
            format!("the extended VLR at byte {start} declares {length} bytes; only {room} follow it"),
        ));
    }
    Ok(())
}

/// The unsigned little-endian integer of `n` ≤ 8 bytes at `at`, if the file holds them.
fn little_endian(bytes: &[u8], at: usize, n: usize) -> Option<u64> {
    let field = bytes.get(at..at.checked_add(n)?)?;
    Some(field.iter().rev().fold(0u64, |v, &byte| v << 8 | u64::from(byte)))
}

/// The point's ASPRS class code as the file stores it. The crate turns code 12 (overlap
/// points) into its overlap flag and "unclassified"; in the legacy point formats (0–5), which
/// have no overlap flag, the flag can only have come from code 12, which is given back.
fn class_code(point: &las::Point, extended: bool) -> u8 {
    if point.is_overlap && !extended { 12 } else { u8::from(point.classification) }
}

/// A point as the builder takes it: colours raw (16-bit channels, see [`color_scale`]).
fn record(point: &las::Point, extended: bool) -> PointRecord {
    let color = point.color.map_or([0; 3], |c| [c.red, c.green, c.blue]);
    PointRecord {
        position: DVec3::new(point.x, point.y, point.z),
        color: color.map(f32::from),
        intensity: f32::from(point.intensity),
        classification: class_code(point, extended),
        return_number: point.return_number,
        gps_time: point.gps_time.unwrap_or(0.0),
        ..PointRecord::default()
    }
}

/// What a file's colours are divided by, from its largest channel: 8-bit values in 16-bit
/// channels where none exceeds 255; none where every one is 0 (a point format with colour
/// whose writer had none to give, as laspy's plane.laz: black everywhere is no colour).
fn color_scale(max_channel: u16) -> Option<f32> {
    match max_channel {
        0 => None,
        1..=255 => Some(255.0),
        _ => Some(65535.0),
    }
}

/// Points decoded at a time: the header's count is not trusted for an allocation.
const BATCH: u64 = 1 << 16;

pub(crate) fn parse(path: &Path, bytes: FileBytes) -> Result<LoadedCloud, IoError> {
    // The LAZ decoder can panic on corrupt data (found by `mutations_never_panic`: an integer
    // overflow in its GPS-time model); a broken file must still end in an error that names it.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| decode(path, bytes)))
        .unwrap_or_else(|_| Err(IoError::invalid(path, "corrupt LAS/LAZ data: the decoder failed")))
}

fn decode(path: &Path, bytes: FileBytes) -> Result<LoadedCloud, IoError> {
    check_point_extent(path, &bytes)?;
    check_first_evlr(path, &bytes)?;
    check_laz_chunk_table(path, &bytes)?;
    let file_bytes = bytes.len() as u64;
    // The version as the file gives it (bytes 24 and 25): the reader reports the version its
    // header would be written as (a LAS 1.1 file with point format 3 read as 1.2).
    let version = (bytes.get(24).copied().unwrap_or(0), bytes.get(25).copied().unwrap_or(0));
    let mut reader = las::Reader::new(Cursor::new(bytes))
        .map_err(|e| IoError::invalid(path, format!("not a readable LAS file: {e}")))?;
    let header = reader.header().clone();
    let format = *header.point_format();
    let count = header.number_of_points();
    // Uncompressed records have a fixed size: a count the file cannot hold is refused outright.
    if !format.is_compressed && count.saturating_mul(u64::from(format.len())) > file_bytes {
        return Err(IoError::invalid(
            path,
            format!("the header declares {count} points of {} bytes, more than the file holds", format.len()),
        ));
    }
    // Every point format has intensity, a class and a return number (zero where the writer
    // recorded none); GPS time from format 1 on.
    let scan = ScanFields { intensity: true, classification: true, return_number: true, gps_time: format.has_gps_time };
    let attributes = Attributes { colors: format.has_color, scan, ..Attributes::default() };
    let mut builder = CloudBuilder::new(0, attributes);
    let mut max_channel = 0u16;
    let mut batch = las::PointDataBuilder::new().for_header(&header).build();
    while (builder.len() as u64) < count {
        let done = builder.len() as u64;
        let read = reader
            .fill_points(BATCH.min(count - done), &mut batch)
            .map_err(|e| IoError::invalid(path, format!("point {done} of {count}: {e}")))?;
        if read == 0 {
            return Err(IoError::invalid(path, format!("the file ends after {done} of its {count} points")));
        }
        for (i, point) in batch.points().enumerate() {
            let point =
                point.map_err(|e| IoError::invalid(path, format!("point {} of {count}: {e}", done + i as u64)))?;
            let record = record(&point, format.is_extended);
            max_channel = record.color.into_iter().fold(max_channel, |m, c| m.max(c as u16));
            builder.push(&record);
        }
    }
    let mut cloud = builder.finish();
    match (color_scale(max_channel), &mut cloud.colors) {
        (None, Some(_)) => {
            tracing::info!("{}: every colour is black; taken as none", path.display());
            cloud.colors = None;
        }
        (Some(scale), Some(colors)) => colors.iter_mut().for_each(|c| *c = c.map(|v| v / scale)),
        (_, None) => {}
    }
    let info = file_info(&format, version, cloud.len(), file_bytes);
    Ok(LoadedCloud { cloud, info })
}

/// What [`crate::read_cloud`] tells of a LAS file of `points` points.
fn file_info(format: &las::point::Format, version: (u8, u8), points: usize, file_bytes: u64) -> FileInfo {
    let scan = ScanFields { intensity: true, classification: true, return_number: true, gps_time: format.has_gps_time };
    FileInfo {
        format: format!(
            "{} {}.{}, point format {}",
            if format.is_compressed { "LAZ" } else { "LAS" },
            version.0,
            version.1,
            format.to_u8().map_or_else(|_| "?".to_string(), |n| n.to_string())
        ),
        elements: vec![("point".into(), points)],
        vertex_properties: ["x", "y", "z"]
            .into_iter()
            .chain(format.has_color.then_some(["red", "green", "blue"]).into_iter().flatten())
            .map(String::from)
            .chain(scan.names())
            .collect(),
        comments: Vec::new(),
        file_bytes,
        up: Some([0.0, 0.0, 1.0]),
        sun: Some(crate::SURVEY_SUN),
    }
}

/// A LAS or LAZ file's points read from the file in batches, as often as asked: for preparing a
/// cloud larger than memory (`crate::prepare`). Opening makes `parse`'s checks (the header and
/// the chunk table, mapped); each pass reads the file through the crate's reader.
pub(crate) struct LasStream {
    path: std::path::PathBuf,
    pub(crate) count: usize,
    pub(crate) info: FileInfo,
    extended: bool,
    has_color: bool,
    /// The colours' divisor ([`color_scale`]) once a pass has seen every point.
    scale: Option<Option<f32>>,
}

impl LasStream {
    pub(crate) fn open(path: &Path) -> Result<Self, IoError> {
        let bytes = crate::file::read_file(path, true)?;
        check_point_extent(path, &bytes)?;
        check_first_evlr(path, &bytes)?;
        check_laz_chunk_table(path, &bytes)?;
        let version = (bytes.get(24).copied().unwrap_or(0), bytes.get(25).copied().unwrap_or(0));
        let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        let header = las::Reader::new(std::io::BufReader::new(file))
            .map_err(|e| IoError::invalid(path, format!("not a readable LAS file: {e}")))?
            .header()
            .clone();
        let format = *header.point_format();
        let count = usize::try_from(header.number_of_points())
            .map_err(|_| IoError::invalid(path, "more points than this machine can count"))?;
        let info = file_info(&format, version, count, bytes.len() as u64);
        let (extended, has_color) = (format.is_extended, format.has_color);
        Ok(Self { path: path.to_path_buf(), count, info, extended, has_color, scale: None })
    }

    /// Whether the points have colours (known after the first pass).
    pub(crate) fn has_colors(&self) -> bool {
        self.has_color && self.scale.expect("a pass first").is_some()
    }

    /// Calls `visit` with every point in file order, its colour scaled once a pass has found
    /// the scale (raw before).
    pub(crate) fn for_each(&mut self, mut visit: impl FnMut(&PointRecord)) -> Result<(), IoError> {
        let path = self.path.clone();
        let invalid = |message: String| IoError::invalid(&path, message);
        let file = std::fs::File::open(&self.path).map_err(|e| IoError::io(&self.path, e))?;
        let scale = self.scale.flatten();
        let (extended, count) = (self.extended, self.count as u64);
        let mut max_channel = 0u16;
        // As `parse`: the LAZ decoder can panic on corrupt data.
        let pass = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| -> Result<(), IoError> {
            let mut reader = las::Reader::new(std::io::BufReader::with_capacity(1 << 20, file))
                .map_err(|e| invalid(format!("not a readable LAS file: {e}")))?;
            let mut batch = las::PointDataBuilder::new().for_header(reader.header()).build();
            let mut done = 0u64;
            while done < count {
                let read = reader
                    .fill_points(BATCH.min(count - done), &mut batch)
                    .map_err(|e| invalid(format!("point {done} of {count}: {e}")))?;
                if read == 0 {
                    return Err(invalid(format!("the file ends after {done} of its {count} points")));
                }
                for point in batch.points() {
                    let point = point.map_err(|e| invalid(format!("point {done} of {count}: {e}")))?;
                    let mut record = record(&point, extended);
                    max_channel = record.color.into_iter().fold(max_channel, |m, c| m.max(c as u16));
                    if let Some(scale) = scale {
                        record.color = record.color.map(|v| v / scale);
                    }
                    visit(&record);
                    done += 1;
                }
            }
            Ok(())
        }));
        pass.unwrap_or_else(|_| Err(invalid("corrupt LAS/LAZ data: the decoder failed".into())))?;
        self.scale.get_or_insert(color_scale(max_channel));
        Ok(())
    }
}
