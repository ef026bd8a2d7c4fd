//! Wavefront OBJ meshes: `v x y z [w]` or `v x y z r g b` (the common vertex-colour extension)
//! vertices and `f` faces of `v`, `v/vt`, `v//vn` or `v/vt/vn` corners, 1-based or negative
//! (counted back from the last vertex read). Texture coordinates, normals (given per corner,
//! not per vertex), groups, materials and the rest are read past. As a point cloud, the
//! vertices with any colours; as a mesh, the faces split into fans of triangles.

use std::path::Path;

use glam::DVec3;

use crate::builder::{Attributes, CloudBuilder, PointRecord};
use crate::ply::{Mesh, MeshFile};
use crate::text::{data_lines, first_word, split_values};
use crate::{FileInfo, IoError, LoadedCloud};

/// The keywords an OBJ file's first data line may start with.
const KEYWORDS: [&str; 10] = ["v", "vn", "vt", "vp", "f", "o", "g", "s", "mtllib", "usemtl"];

/// Whether the first data line starts with an OBJ keyword.
pub(crate) fn looks_like_obj(bytes: &[u8]) -> bool {
    first_word(bytes).is_some_and(|k| KEYWORDS.contains(&k))
}

/// The vertices as a cloud.
pub(crate) fn parse(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    let obj = read(path, bytes, false)?;
    Ok(LoadedCloud { cloud: obj.mesh.vertices, info: obj.info })
}

/// The mesh: vertices and triangles.
pub(crate) fn parse_mesh(path: &Path, bytes: &[u8]) -> Result<Mesh, IoError> {
    Ok(read(path, bytes, true)?.mesh)
}

fn read(path: &Path, bytes: &[u8], faces: bool) -> Result<MeshFile, IoError> {
    // Vertices with colours or without, decided by the first; the builder is made then.
    let mut builder: Option<CloudBuilder> = None;
    let (mut triangles, mut skipped_faces, mut face_count) = (Vec::new(), 0, 0);
    let mut corners = Vec::new();
    let mut comments = Vec::new();
    for data_line in data_lines(path, bytes, &mut comments) {
        let (number, data) = data_line?;
        let error = |message: String| IoError::at_line(path, number, message);
        let mut tokens = data.split_whitespace();
        match tokens.next() {
            Some("v") => {
                let values = numbers(&split_values(data)[1..]).map_err(error)?;
                if !matches!(values.len(), 3 | 4 | 6) {
                    return Err(error(format!(
                        "a vertex has 3, 4 or 6 values (x y z [w] or x y z r g b), not {}",
                        values.len()
                    )));
                }
                let colors = values.len() == 6;
                let b = builder.get_or_insert_with(|| {
                    CloudBuilder::new(bytes.len() / 8, Attributes { colors, ..Attributes::default() })
                });
                if colors != b.has_colors() {
                    return Err(error("some vertices have colours and others not".into()));
                }
                let color = if colors { [values[3], values[4], values[5]].map(|c| c as f32) } else { [0.0; 3] };
                b.push(&PointRecord {
                    position: DVec3::new(values[0], values[1], values[2]),
                    color,
                    ..PointRecord::default()
                });
            }
            Some("f") if faces => {
                face_count += 1;
                let vertices = builder.as_ref().map_or(0, CloudBuilder::len);
                corners.clear();
                for corner in tokens {
                    corners.push(vertex_index(corner, vertices).map_err(error)?);
                }
                if corners.len() < 3 {
                    skipped_faces += 1;
                }
                triangles.extend(crate::ply::fan(&corners));
            }
            Some("f") => face_count += 1,
            _ => {}
        }
    }
    let builder = builder.unwrap_or_else(|| CloudBuilder::new(0, Attributes::default()));
    let colors = builder.has_colors();
    let mut vertices = builder.finish();
    crate::builder::scale_colors_to_unit(&mut vertices);
    let mut names = vec!["x".to_string(), "y".into(), "z".into()];
    if colors {
        names.extend(["red".into(), "green".into(), "blue".into()]);
    }
    let info = FileInfo {
        format: "OBJ text".into(),
        elements: vec![("vertex".into(), vertices.len()), ("face".into(), face_count)],
        vertex_properties: names,
        comments,
        file_bytes: bytes.len() as u64,
        up: None,
        sun: None,
    };
    Ok(MeshFile { mesh: Mesh { vertices, triangles, skipped_faces }, info })
}

fn numbers(tokens: &[&str]) -> Result<Vec<f64>, String> {
    tokens.iter().map(|t| t.parse::<f64>().map_err(|_| format!("{t:?} is not a number"))).collect()
}

/// A face corner's vertex (`v`, `v/vt`, `v//vn`, `v/vt/vn`; 1-based, or negative from the
/// end), 0-based and checked against the `vertices` read so far.
fn vertex_index(corner: &str, vertices: usize) -> Result<u32, String> {
    let v = corner.split('/').next().unwrap_or("");
    let i: i64 = v.parse().map_err(|_| format!("{corner:?} is not a face corner (v, v/vt, v//vn or v/vt/vn)"))?;
    let index = if i < 0 { vertices as i64 + i } else { i - 1 };
    if i == 0 || index < 0 || index >= vertices as i64 {
        return Err(format!("vertex {i} is not one of the {vertices} vertices read so far"));
    }
    Ok(index as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_corners_of_every_form_and_negative_indices() {
        let text = b"# a square\no square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1 4//1\nf -4 -3/1 -2/1/1\n";
        let mesh = parse_mesh(Path::new("sq.obj"), text).unwrap();
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 2]]);
        let cloud = parse(Path::new("sq.obj"), text).unwrap();
        assert_eq!((cloud.cloud.len(), cloud.cloud.colors.is_none()), (4, true));
        assert_eq!(cloud.info.elements, vec![("vertex".to_string(), 4), ("face".to_string(), 2)]);
        assert!(looks_like_obj(text) && !looks_like_obj(b"0 0 0\n"));
    }

    #[test]
    fn vertex_colours_and_errors_are_named_by_line() {
        let cloud = parse(Path::new("c.obj"), b"v 0 0 0 1 0.5 0\nv 1 0 0 0 0 1\n").unwrap();
        assert_eq!(cloud.cloud.colors.unwrap()[0], [1.0, 0.5, 0.0]);
        let bad = parse_mesh(Path::new("c.obj"), b"v 0 0 0\nv 1 0 0\nf 1 2 3\n").unwrap_err();
        assert_eq!(bad.to_string(), "c.obj: line 3: vertex 3 is not one of the 2 vertices read so far");
        let mixed = parse(Path::new("c.obj"), b"v 0 0 0 1 1 1\nv 1 0 0\n").unwrap_err();
        assert!(mixed.to_string().contains("line 2: some vertices"), "{mixed}");
        let word = parse(Path::new("c.obj"), b"v 0 zero 0\n").unwrap_err();
        assert!(word.to_string().contains("line 1: \"zero\" is not a number"), "{word}");
    }
}
