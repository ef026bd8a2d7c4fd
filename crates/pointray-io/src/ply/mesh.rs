//! Triangle meshes from PLY: the `vertex` element and the `vertex_indices` (or
//! `vertex_index`) lists of the `face` element, for `pointray sample`.

use std::path::Path;

use pointray::PointCloud;

use super::header::{Header, PropertyKind, parse_header};
use super::{Rest, ascii, body_start, read_vertex_element, vertex_element};
use crate::IoError;

/// A mesh as read: its vertices (with whatever attributes the file has, recentred like any
/// cloud) and its faces as triangles.
#[derive(Clone, Debug)]
pub struct Mesh {
    pub vertices: PointCloud,
    /// Polygons are split into fans of triangles around their first vertex.
    pub triangles: Vec<[u32; 3]>,
    /// Faces with fewer than three vertices, which cover nothing and are left out.
    pub skipped_faces: usize,
}

/// A mesh and what its file said about itself (the text mesh formats' readers' result).
pub(crate) struct MeshFile {
    pub mesh: Mesh,
    pub info: crate::FileInfo,
}

/// A PLY mesh in memory (`path` names it in errors); [`crate::read_mesh`] takes any mesh format.
pub fn parse_mesh(path: &Path, bytes: &[u8]) -> Result<Mesh, IoError> {
    if !(bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n")) {
        return Err(IoError::invalid(path, "not a PLY file: it does not start with the line 'ply'"));
    }
    let header = parse_header(path, bytes)?;
    let vertex_index = vertex_element(path, &header)?;
    let (face_index, list) = face_list(path, &header)?;
    let (builder, rest) = read_vertex_element(path, bytes, &header, vertex_index)?;
    let vertices = builder.len();
    if u32::try_from(vertices).is_err() {
        return Err(IoError::invalid(path, format!("{vertices} vertices: a mesh holds at most 2^32")));
    }

    // A capacity hint only: the header's count is not trusted beyond what the file's size allows.
    let mut triangles = Vec::with_capacity(header.elements[face_index].count.min(bytes.len() / 12));
    let mut skipped_faces = 0;
    let mut corners = Vec::new();
    let visit = |_: usize, items: &[f64]| {
        if items.len() < 3 {
            skipped_faces += 1;
            return Ok(());
        }
        let index = |value: f64| {
            if value >= 0.0 && value < vertices as f64 && value.fract() == 0.0 {
                Ok(value as u32)
            } else {
                Err(format!("vertex index {value} is not one of the {vertices} vertices"))
            }
        };
        corners.clear();
        for &item in items {
            corners.push(index(item)?);
        }
        triangles.extend(fan(&corners));
        Ok(())
    };
    let elements = &header.elements;
    // Faces after the vertices are read on from there; faces before them (the format allows
    // it), from the body's start again.
    let (rest, from) =
        if face_index > vertex_index { (rest, vertex_index + 1) } else { (body_start(path, bytes, &header), 0) };
    let which = (from, face_index, list);
    match rest {
        Rest::Ascii(mut lines) => ascii::for_each_list(path, &mut lines, elements, which, visit)?,
        Rest::Binary(body, end) => body.for_each_list(end, elements, which, visit)?,
    }
    Ok(Mesh { vertices: builder.finish(), triangles, skipped_faces })
}

/// A polygon's triangles: a fan around its first corner (none for fewer than three corners).
pub(crate) fn fan(corners: &[u32]) -> impl Iterator<Item = [u32; 3]> + '_ {
    corners.windows(2).skip(1).map(|w| [corners[0], w[0], w[1]])
}

/// The face element and its list of vertex indices.
fn face_list(path: &Path, header: &Header) -> Result<(usize, usize), IoError> {
    let face_index = header
        .elements
        .iter()
        .position(|e| e.name == "face")
        .ok_or_else(|| IoError::invalid(path, "no 'face' element: not a mesh"))?;
    let list = header.elements[face_index]
        .properties
        .iter()
        .position(|p| {
            matches!(p.kind, PropertyKind::List { .. }) && (p.name == "vertex_indices" || p.name == "vertex_index")
        })
        .ok_or_else(|| IoError::invalid(path, "the 'face' element has no 'vertex_indices' list"))?;
    Ok((face_index, list))
}
