//! OFF meshes (Geomview's Object File Format, what many mesh tools and datasets write):
//!
//! ```text
//! [C][N]OFF            header keyword (C: vertex colours, N: vertex normals)
//! nv nf ne             counts (may share the keyword's line); `#` starts a comment
//! x y z [nx ny nz] [r g b [a]]     nv vertex lines
//! n i1 ... in [colour]             nf faces, 0-based vertex indices
//! ```
//!
//! Colours are `0..=255` if any exceeds 1, else `0..=1`. As a point cloud, the vertices with
//! their normals and colours; as a mesh, the faces split into fans of triangles.

use std::path::Path;

use glam::{DVec3, Vec3};

use crate::builder::{Attributes, CloudBuilder, PointRecord};
use crate::ply::{Mesh, MeshFile};
use crate::text::{data_lines, first_word, split_values};
use crate::{FileInfo, IoError, LoadedCloud};

/// Whether the first data line is an OFF keyword.
pub(crate) fn looks_like_off(bytes: &[u8]) -> bool {
    first_word(bytes).is_some_and(|k| keyword(k).is_some())
}

/// The attributes a keyword announces: (normals, colours).
fn keyword(token: &str) -> Option<(bool, bool)> {
    match token {
        "OFF" => Some((false, false)),
        "NOFF" => Some((true, false)),
        "COFF" => Some((false, true)),
        "CNOFF" => Some((true, true)),
        _ => None,
    }
}

/// The vertices as a cloud.
pub(crate) fn parse(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    let off = read(path, bytes, false)?;
    Ok(LoadedCloud { cloud: off.mesh.vertices, info: off.info })
}

/// The mesh: vertices and triangles.
pub(crate) fn parse_mesh(path: &Path, bytes: &[u8]) -> Result<Mesh, IoError> {
    Ok(read(path, bytes, true)?.mesh)
}

fn read(path: &Path, bytes: &[u8], faces: bool) -> Result<MeshFile, IoError> {
    let mut comments = Vec::new();
    let mut lines = data_lines(path, bytes, &mut comments);
    let mut data = || lines.next().transpose();
    let (line, first) = data()?.ok_or_else(|| IoError::invalid(path, "empty file"))?;
    let mut tokens = split_values(first);
    let (normals, colors) = keyword(tokens.remove(0)).ok_or_else(|| {
        IoError::at_line(path, line, "not an OFF file: the first line must be OFF, COFF, NOFF or CNOFF")
    })?;
    let (line, counts) = if tokens.is_empty() {
        data()?.ok_or_else(|| IoError::invalid(path, "the file ends before the vertex and face counts"))?
    } else {
        (line, first.split_once(char::is_whitespace).map_or("", |(_, rest)| rest))
    };
    let counts = split_values(counts);
    let count = |i: usize| counts.get(i).and_then(|c| c.parse::<usize>().ok());
    let (Some(vertices), Some(face_count)) = (count(0), count(1)) else {
        return Err(IoError::at_line(path, line, "expected the counts: vertices faces [edges]"));
    };
    // Each vertex line takes at least six bytes ("0 0 0\n"), each face eight ("3 0 1 2\n").
    if vertices > bytes.len() / 6 || face_count > bytes.len() / 8 {
        let message = format!("{vertices} vertices and {face_count} faces cannot fit in {} bytes", bytes.len());
        return Err(IoError::at_line(path, line, message));
    }
    let attributes = Attributes { normals, colors, ..Attributes::default() };
    let mut builder = CloudBuilder::new(vertices, attributes);
    let columns = 3 + 3 * usize::from(normals) + 3 * usize::from(colors);
    for _ in 0..vertices {
        let (line, text) =
            data()?.ok_or_else(|| IoError::invalid(path, format!("the file ends before its {vertices} vertices")))?;
        let v = numbers(path, line, text)?;
        if v.len() < columns {
            return Err(IoError::at_line(
                path,
                line,
                format!("expected {columns} values for a vertex, got {}", v.len()),
            ));
        }
        let at = |i: usize| Vec3::new(v[i] as f32, v[i + 1] as f32, v[i + 2] as f32);
        builder.push(&PointRecord {
            position: DVec3::new(v[0], v[1], v[2]),
            normal: if normals { at(3) } else { Vec3::ZERO },
            color: if colors { at(3 + 3 * usize::from(normals)).to_array() } else { [0.0; 3] },
            ..PointRecord::default()
        });
    }
    let mut triangles = Vec::new();
    let mut skipped_faces = 0;
    for _ in 0..if faces { face_count } else { 0 } {
        let (line, text) =
            data()?.ok_or_else(|| IoError::invalid(path, format!("the file ends before its {face_count} faces")))?;
        let v = numbers(path, line, text)?;
        let n = v.first().copied().unwrap_or(-1.0);
        if !(n >= 0.0 && n.fract() == 0.0 && (n as usize) < v.len()) {
            return Err(IoError::at_line(path, line, "a face starts with its vertex count, then as many indices"));
        }
        let corners: Vec<u32> = v[1..=n as usize]
            .iter()
            .map(|&i| index(i, vertices).map_err(|m| IoError::at_line(path, line, m)))
            .collect::<Result<_, _>>()?;
        if corners.len() < 3 {
            skipped_faces += 1;
        }
        triangles.extend(crate::ply::fan(&corners));
    }
    let mut vertices_cloud = builder.finish();
    crate::builder::scale_colors_to_unit(&mut vertices_cloud);
    let format = format!("{} text", first.split_whitespace().next().unwrap_or("OFF"));
    drop(lines);
    let info = FileInfo {
        format,
        elements: vec![("vertex".into(), vertices), ("face".into(), face_count)],
        vertex_properties: property_names(normals, colors),
        comments,
        file_bytes: bytes.len() as u64,
        up: None,
        sun: None,
    };
    Ok(MeshFile { mesh: Mesh { vertices: vertices_cloud, triangles, skipped_faces }, info })
}

fn numbers(path: &Path, line: usize, text: &str) -> Result<Vec<f64>, IoError> {
    split_values(text)
        .iter()
        .map(|t| t.parse::<f64>().map_err(|_| IoError::at_line(path, line, format!("{t:?} is not a number"))))
        .collect()
}

/// A 0-based vertex index, checked.
fn index(value: f64, vertices: usize) -> Result<u32, String> {
    if value >= 0.0 && value < vertices as f64 && value.fract() == 0.0 {
        Ok(value as u32)
    } else {
        Err(format!("vertex index {value} is not one of the {vertices} vertices"))
    }
}

fn property_names(normals: bool, colors: bool) -> Vec<String> {
    let mut names = vec!["x", "y", "z"];
    if normals {
        names.extend(["nx", "ny", "nz"]);
    }
    if colors {
        names.extend(["red", "green", "blue"]);
    }
    names.into_iter().map(String::from).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_coloured_square_as_two_triangles() {
        let text = b"COFF\n# a square\n4 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n1 1 0 0 0 255 255\n0 1 0 255 255 255 255\n4 0 1 2 3\n";
        let mesh = parse_mesh(Path::new("sq.off"), text).unwrap();
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        let cloud = parse(Path::new("sq.off"), text).unwrap();
        assert_eq!(cloud.cloud.len(), 4);
        assert_eq!(cloud.cloud.colors.as_ref().unwrap()[1], [0.0, 1.0, 0.0]);
        assert_eq!(cloud.info.elements[1], ("face".to_string(), 1));
    }

    #[test]
    fn counts_may_share_the_keyword_line_and_bad_faces_are_named() {
        let mesh = parse_mesh(Path::new("t.off"), b"OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").unwrap();
        assert_eq!(mesh.triangles, vec![[0, 1, 2]]);
        let bad = parse_mesh(Path::new("t.off"), b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n").unwrap_err();
        assert_eq!(bad.to_string(), "t.off: line 6: vertex index 7 is not one of the 3 vertices");
        let short = parse_mesh(Path::new("t.off"), b"OFF\n3 1 0\n0 0 0\n1 0\n").unwrap_err();
        assert!(short.to_string().contains("line 4: expected 3 values"), "{short}");
        let huge = parse(Path::new("t.off"), b"OFF\n1000000000 0 0\n").unwrap_err();
        assert!(huge.to_string().contains("cannot fit"), "{huge}");
    }
}
