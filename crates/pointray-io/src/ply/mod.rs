//! PLY 1.0, our own reader and writer: ascii, binary_little_endian and binary_big_endian.
//!
//! Reading keeps only the `vertex` element: `x y z` (required), normals (`nx ny nz` or
//! `normal_x normal_y normal_z`), `radius`, colours (`red green blue`, `diffuse_red ...` or
//! `r g b`; integer types divided by their maximum, floats clamped to `[0, 1]`). Other vertex
//! properties, list properties and other elements are stepped over. Coordinates are read as
//! `f64` and recentred (see [`pointray::PointCloud`]). Non-finite coordinates are kept, not
//! refused: the core drops them, and a reader that fails on one NaN is no help.

mod ascii;
mod binary;
mod header;
mod mesh;
mod vertex;

pub use mesh::{Mesh, parse_mesh};
pub(crate) use mesh::{MeshFile, fan};

use std::path::Path;

use pointray::PointCloud;

use crate::builder::CloudBuilder;
use crate::builder::PointRecord;
use crate::text::Lines;
use crate::{Axes, FileInfo, IoError, LoadedCloud, atomic_write};
use binary::{Body, ByteOrder};
use header::{Encoding, Header, parse_header};
use vertex::VertexLayout;

/// Reads a PLY file whatever its extension.
pub fn read_ply(path: &Path) -> Result<LoadedCloud, IoError> {
    let bytes = crate::file::read_file(path, false)?;
    parse(path, &bytes)
}

/// Parses a whole PLY file already in memory.
pub(crate) fn parse(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    let header = parse_header(path, bytes)?;
    let vertex_index = vertex_element(path, &header)?;
    let (builder, _) = read_vertex_element(path, bytes, &header, vertex_index)?;
    tracing::debug!(path = %path.display(), points = builder.len(), format = %header.format_name(), "read PLY");
    let info = file_info(&header, vertex_index, bytes.len());
    let mut cloud = builder.finish();
    // A sensor's position, as `write_ply` keeps a depth frame's.
    if let Some(v) = header.comments.iter().find_map(|c| triple_comment(c, "viewpoint ")) {
        cloud.viewpoints = vec![(glam::DVec3::from(v) - cloud.origin).as_vec3()];
    }
    Ok(LoadedCloud { cloud, info })
}

/// A binary PLY's vertices read from the file in windows, as often as asked: for preparing a
/// cloud larger than memory (`crate::prepare`). Only fixed-size vertex records that come first
/// in the body.
pub(crate) struct VertexStream {
    path: std::path::PathBuf,
    layout: VertexLayout,
    records: binary::FixedRecords,
    start: usize,
    pub(crate) count: usize,
    pub(crate) info: FileInfo,
    /// A sensor's position in the file's coordinates (`comment viewpoint`).
    pub(crate) viewpoint: Option<[f64; 3]>,
}

impl VertexStream {
    pub(crate) fn open(path: &Path) -> Result<Self, IoError> {
        use std::io::Read;
        let mut file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        let file_bytes = file.metadata().map_err(|e| IoError::io(path, e))?.len();
        let mut head = Vec::new();
        file.by_ref().take(1 << 20).read_to_end(&mut head).map_err(|e| IoError::io(path, e))?;
        let unsupported = |what: &str| {
            let hint = "out of core, only binary PLY, LAS/LAZ and E57 files are read for now: prepare it without --memory-budget";
            IoError::invalid(path, format!("{what}: {hint}"))
        };
        if !(head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n")) {
            return Err(unsupported("not a PLY file"));
        }
        let header = parse_header(path, &head)?;
        let order = match header.encoding {
            Encoding::BinaryLittleEndian => ByteOrder::Little,
            Encoding::BinaryBigEndian => ByteOrder::Big,
            Encoding::Ascii => return Err(unsupported("an ASCII PLY")),
        };
        let vertex_index = vertex_element(path, &header)?;
        let vertex = &header.elements[vertex_index];
        let (0, Some(size)) = (vertex_index, vertex.fixed_size()) else {
            return Err(unsupported("its vertices are not the first element, of fixed size"));
        };
        if (header.body_start + vertex.count * size) as u64 > file_bytes {
            return Err(IoError::invalid(path, format!("truncated: {} vertices do not fit", vertex.count)));
        }
        let layout = VertexLayout::new(path, vertex)?;
        let records = binary::FixedRecords::new(vertex, size, &layout, order);
        let viewpoint = header.comments.iter().find_map(|c| triple_comment(c, "viewpoint "));
        let info = file_info(&header, vertex_index, file_bytes as usize);
        Ok(Self {
            path: path.to_path_buf(),
            layout,
            records,
            start: header.body_start,
            count: vertex.count,
            info,
            viewpoint,
        })
    }

    pub(crate) fn attributes(&self) -> crate::builder::Attributes {
        self.layout.attributes()
    }

    /// Calls `visit` with every vertex in file order, reading 8 MB at a time.
    pub(crate) fn for_each(&mut self, mut visit: impl FnMut(&PointRecord)) -> Result<(), IoError> {
        use std::io::{Read, Seek, SeekFrom};
        let io = |e| IoError::io(&self.path, e);
        let mut file = std::fs::File::open(&self.path).map_err(io)?;
        file.seek(SeekFrom::Start(self.start as u64)).map_err(io)?;
        let size = self.records.size;
        let per_window = ((8 << 20) / size.max(1)).max(1);
        let mut window = vec![0u8; per_window * size];
        let mut left = self.count;
        while left > 0 {
            let n = left.min(per_window);
            file.read_exact(&mut window[..n * size]).map_err(|e| IoError::io(&self.path, e))?;
            for record in window[..n * size].chunks_exact(size) {
                visit(&self.records.decode(record, &self.layout));
            }
            left -= n;
        }
        Ok(())
    }
}

fn vertex_element(path: &Path, header: &Header) -> Result<usize, IoError> {
    header
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| IoError::invalid(path, "no 'vertex' element in the header"))
}

/// Where a reader of the body stands: its lines (ascii), or the body and a byte offset.
enum Rest<'a> {
    Ascii(Lines<'a>),
    Binary(Body<'a>, usize),
}

/// The body from its first record.
fn body_start<'a>(path: &'a Path, bytes: &'a [u8], header: &Header) -> Rest<'a> {
    match header.encoding {
        Encoding::Ascii => {
            Rest::Ascii(Lines::new(bytes.get(header.body_start..).unwrap_or_default(), header.body_first_line))
        }
        Encoding::BinaryLittleEndian | Encoding::BinaryBigEndian => {
            let order = if header.encoding == Encoding::BinaryBigEndian { ByteOrder::Big } else { ByteOrder::Little };
            Rest::Binary(Body { path, bytes, order }, header.body_start)
        }
    }
}

/// The vertex element's points, and the body after it.
fn read_vertex_element<'a>(
    path: &'a Path,
    bytes: &'a [u8],
    header: &Header,
    vertex_index: usize,
) -> Result<(CloudBuilder, Rest<'a>), IoError> {
    let layout = VertexLayout::new(path, &header.elements[vertex_index])?;
    match body_start(path, bytes, header) {
        Rest::Ascii(mut lines) => {
            let builder = ascii::read_vertices(path, &mut lines, &header.elements, vertex_index, &layout)?;
            Ok((builder, Rest::Ascii(lines)))
        }
        Rest::Binary(body, start) => {
            let (builder, end) = body.read_vertices(start, &header.elements, vertex_index, &layout)?;
            Ok((builder, Rest::Binary(body, end)))
        }
    }
}

fn file_info(header: &Header, vertex_index: usize, file_bytes: usize) -> FileInfo {
    let vertex_properties = header
        .elements
        .get(vertex_index)
        .map(|v| v.properties.iter().map(|p| p.declaration.clone()).collect())
        .unwrap_or_default();
    FileInfo {
        format: header.format_name(),
        elements: header.elements.iter().map(|e| (e.name.clone(), e.count)).collect(),
        vertex_properties,
        comments: header.comments.clone(),
        file_bytes: file_bytes as u64,
        up: header.comments.iter().find_map(|c| direction_comment(c, "up ")),
        sun: header.comments.iter().find_map(|c| direction_comment(c, "sun ")),
    }
}

/// The direction of a `comment KEY X Y Z` line ([`write_ply_with_axes`]), if it is one.
fn direction_comment(comment: &str, key: &str) -> Option<[f32; 3]> {
    let d = triple_comment(comment, key)?.map(|v| v as f32);
    (d.iter().all(|v| v.is_finite()) && d != [0.0; 3]).then_some(d)
}

/// The three finite numbers of a `comment KEY X Y Z` line (`key` with its space).
fn triple_comment(comment: &str, key: &str) -> Option<[f64; 3]> {
    let values: Vec<f64> =
        comment.strip_prefix(key)?.split_whitespace().map(str::parse).collect::<Result<_, _>>().ok()?;
    let values: [f64; 3] = values.try_into().ok()?;
    values.iter().all(|v| v.is_finite()).then_some(values)
}

/// Writes a binary little-endian PLY with `x y z`, then `nx ny nz`, `radius` and
/// `red green blue` (uchar) and the scan attributes when the cloud has them, and a single
/// sensor's position as `comment viewpoint X Y Z`.
///
/// Coordinates are world coordinates (`origin + position`): `double` when the origin lies
/// farther from zero than the cloud is wide (a survey's: a `float` would keep fewer bits of a
/// coordinate than the cloud's own f32 offsets), else `float`, which then keeps about as many
/// (a mesh sampled near the origin: 24 bytes a point, not 36). The file appears only when
/// complete (see [`atomic_write`]).
pub fn write_ply(path: &Path, cloud: &PointCloud) -> Result<(), IoError> {
    write_ply_with_axes(path, cloud, Axes::default())
}

/// [`write_ply`], naming the data's up axis and sun in `comment up X Y Z` and `comment sun X Y
/// Z` lines, which the reader gives back as [`FileInfo::up`] and [`FileInfo::sun`] (a prepared
/// survey keeps its +z and its sun).
pub fn write_ply_with_axes(path: &Path, cloud: &PointCloud, axes: Axes) -> Result<(), IoError> {
    cloud
        .check_lengths()
        .map_err(|message| IoError::invalid(path, format!("cannot write an inconsistent cloud: {message}")))?;
    let far = cloud.origin.abs().max_element() > f64::from(cloud.bounds().diagonal());
    let world_doubles = far || cloud.residuals.is_some();
    let header = write_header(cloud, world_doubles, axes);
    atomic_write(path, |out| {
        out.write_all(header.as_bytes())?;
        let mut record = Vec::with_capacity(64);
        for index in 0..cloud.len() {
            record.clear();
            encode_vertex(cloud, index, world_doubles, &mut record);
            out.write_all(&record)?;
        }
        Ok(())
    })
}

fn write_header(cloud: &PointCloud, world_doubles: bool, axes: Axes) -> String {
    let mut header = String::from("ply\nformat binary_little_endian 1.0\ncomment written by pointray-io\n");
    for (key, axis) in [("up", axes.up), ("sun", axes.sun)] {
        if let Some([x, y, z]) = axis {
            header += &format!("comment {key} {x} {y} {z}\n");
        }
    }
    // One sensor's position (a depth frame's; a cloud of several scans keeps none).
    if let ([v], None) = (cloud.viewpoints.as_slice(), &cloud.viewpoint_of) {
        let [x, y, z] = (cloud.origin + v.as_dvec3()).to_array();
        header += &format!("comment viewpoint {x} {y} {z}\n");
    }
    header += &format!("element vertex {}\n", cloud.len());
    let coordinate_type = if world_doubles { "double" } else { "float" };
    for axis in ["x", "y", "z"] {
        header += &format!("property {coordinate_type} {axis}\n");
    }
    if cloud.normals.is_some() {
        header += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    if cloud.radii.is_some() {
        header += "property float radius\n";
    }
    if cloud.colors.is_some() {
        header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    let scan = &cloud.scan;
    let scan_properties = [
        (scan.intensity.is_some(), "float intensity"),
        (scan.classification.is_some(), "uchar classification"),
        (scan.return_number.is_some(), "uchar return_number"),
        (scan.gps_time.is_some(), "double gps_time"),
    ];
    for (_, property) in scan_properties.iter().filter(|(has, _)| *has) {
        header += &format!("property {property}\n");
    }
    header += "end_header\n";
    header
}

fn encode_vertex(cloud: &PointCloud, index: usize, world_doubles: bool, record: &mut Vec<u8>) {
    if index >= cloud.len() {
        return;
    }
    let world = cloud.world_position(index);
    if world_doubles {
        for value in world.to_array() {
            record.extend_from_slice(&value.to_le_bytes());
        }
    } else {
        for value in world.as_vec3().to_array() {
            record.extend_from_slice(&value.to_le_bytes());
        }
    }
    if let Some(normal) = cloud.normals.as_ref().and_then(|n| n.get(index)) {
        for value in normal.to_array() {
            record.extend_from_slice(&value.to_le_bytes());
        }
    }
    if let Some(radius) = cloud.radii.as_ref().and_then(|r| r.get(index)) {
        record.extend_from_slice(&radius.to_le_bytes());
    }
    if let Some(color) = cloud.colors.as_ref().and_then(|c| c.get(index)) {
        // `as u8` saturates and maps NaN to 0.
        record.extend(color.map(|channel| (channel.clamp(0.0, 1.0) * 255.0).round() as u8));
    }
    let scan = &cloud.scan;
    if let Some(intensity) = scan.intensity.as_ref().and_then(|v| v.get(index)) {
        record.extend_from_slice(&intensity.to_le_bytes());
    }
    record.extend(scan.classification.as_ref().and_then(|v| v.get(index)));
    record.extend(scan.return_number.as_ref().and_then(|v| v.get(index)));
    if let Some(time) = scan.gps_time.as_ref().and_then(|v| v.get(index)) {
        record.extend_from_slice(&time.to_le_bytes());
    }
}
