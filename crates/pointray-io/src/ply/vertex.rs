//! Which vertex properties carry position, normal, radius, colour and scan attributes, and how to turn a
//! record's raw values into a [`PointRecord`].

use std::path::Path;

use glam::{DVec3, Vec3};

use super::header::{Element, PropertyKind, Scalar};
use crate::IoError;
use crate::builder::{Attributes, PointRecord, ScanFields, scan_columns};

const NORMAL_NAMES: [[&str; 3]; 2] = [["nx", "ny", "nz"], ["normal_x", "normal_y", "normal_z"]];
/// Full names first; the short `r g b` only count when all three are present, since a lone
/// `r` is as likely a range or reflectance as a red channel.
const COLOR_NAMES: [[&str; 3]; 2] = [["red", "green", "blue"], ["diffuse_red", "diffuse_green", "diffuse_blue"]];
const SHORT_COLOR_NAMES: [&str; 3] = ["r", "g", "b"];

/// A scalar vertex property the reader needs: its index in the record and its type.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Field {
    pub index: usize,
    pub scalar: Scalar,
}

#[derive(Clone, Debug)]
pub(crate) struct VertexLayout {
    pub position: [Field; 3],
    pub normal: Option<[Field; 3]>,
    pub radius: Option<Field>,
    pub color: Option<[Field; 3]>,
    /// Intensity, classification, return number and GPS time, in that order
    /// ([`scan_columns`]' names).
    pub scan: [Option<Field>; 4],
}

impl VertexLayout {
    pub(crate) fn new(path: &Path, vertex: &Element) -> Result<Self, IoError> {
        let invalid = |message: String| IoError::invalid(path, message);
        let position = find_triple(vertex, ["x", "y", "z"])
            .map_err(invalid)?
            .ok_or_else(|| invalid("vertex element has no 'x y z' properties".into()))?;
        let normal = first_triple(vertex, &NORMAL_NAMES).map_err(invalid)?;
        let color = match first_triple(vertex, &COLOR_NAMES).map_err(invalid)? {
            Some(full) => Some(full),
            None => find_triple(vertex, SHORT_COLOR_NAMES).unwrap_or(None),
        };
        let radius = find_field(vertex, "radius").map_err(invalid)?;
        // A list of a scan attribute's name is not one: left alone.
        let scan = scan_columns(vertex.properties.iter().map(|p| p.name.as_str())).map(|index| {
            index.and_then(|index| match vertex.properties[index].kind {
                PropertyKind::Scalar(scalar) => Some(Field { index, scalar }),
                PropertyKind::List { .. } => None,
            })
        });
        Ok(Self { position, normal, radius, color, scan })
    }

    pub(crate) fn attributes(&self) -> Attributes {
        Attributes {
            normals: self.normal.is_some(),
            radii: self.radius.is_some(),
            colors: self.color.is_some(),
            scan: ScanFields::of(&self.scan),
        }
    }

    /// Every field the reader decodes, for readers that only decode what they need.
    pub(crate) fn used_fields(&self) -> Vec<Field> {
        let mut fields = self.position.to_vec();
        fields.extend(self.normal.iter().flatten());
        fields.extend(self.radius);
        fields.extend(self.color.iter().flatten());
        fields.extend(self.scan.iter().flatten());
        fields
    }

    /// `values[i]` is the value of scalar property `i` of this record.
    pub(crate) fn record(&self, values: &[f64]) -> PointRecord {
        let get = |field: Field| values.get(field.index).copied().unwrap_or(0.0);
        let [x, y, z] = self.position.map(get);
        let mut record = PointRecord { position: DVec3::new(x, y, z), ..PointRecord::default() };
        if let Some(normal) = self.normal {
            let [nx, ny, nz] = normal.map(get);
            record.normal = Vec3::new(nx as f32, ny as f32, nz as f32);
        }
        if let Some(radius) = self.radius {
            record.radius = get(radius) as f32;
        }
        if let Some(color) = self.color {
            record.color = color.map(|field| color_channel(get(field), field.scalar));
        }
        record.set_scan(self.scan.map(|f| f.map(get)));
        record
    }
}

/// Integer channels are divided by their type's maximum (uchar by 255, ushort by 65535);
/// float channels are taken as is. Either way clamped to `[0, 1]`, NaN becomes 0.
fn color_channel(value: f64, scalar: Scalar) -> f32 {
    let unit = match scalar.integer_max() {
        Some(max) => value / max,
        None => value,
    };
    if unit.is_nan() { 0.0 } else { unit.clamp(0.0, 1.0) as f32 }
}

fn first_triple(vertex: &Element, schemes: &[[&str; 3]]) -> Result<Option<[Field; 3]>, String> {
    for names in schemes {
        if let Some(triple) = find_triple(vertex, *names)? {
            return Ok(Some(triple));
        }
    }
    Ok(None)
}

/// All three properties, none of them, or an error naming what is missing.
fn find_triple(vertex: &Element, names: [&str; 3]) -> Result<Option<[Field; 3]>, String> {
    let found = [find_field(vertex, names[0])?, find_field(vertex, names[1])?, find_field(vertex, names[2])?];
    match found {
        [Some(a), Some(b), Some(c)] => Ok(Some([a, b, c])),
        [None, None, None] => Ok(None),
        _ => {
            let missing: Vec<&str> = names.iter().zip(&found).filter(|(_, f)| f.is_none()).map(|(n, _)| *n).collect();
            Err(format!("vertex element has only part of '{}': '{}' missing", names.join(" "), missing.join(" ")))
        }
    }
}

/// The first scalar property with this name; a list of that name is an error.
fn find_field(vertex: &Element, name: &str) -> Result<Option<Field>, String> {
    let Some((index, property)) = vertex.properties.iter().enumerate().find(|(_, p)| p.name == name) else {
        return Ok(None);
    };
    match property.kind {
        PropertyKind::Scalar(scalar) => Ok(Some(Field { index, scalar })),
        PropertyKind::List { .. } => Err(format!("vertex property '{name}' is a list, expected a number")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_colours_are_normalised_and_floats_clamped() {
        assert_eq!(color_channel(255.0, Scalar::U8), 1.0);
        assert_eq!(color_channel(65535.0, Scalar::U16), 1.0);
        assert_eq!(color_channel(1.5, Scalar::F32), 1.0);
        assert_eq!(color_channel(-0.5, Scalar::F64), 0.0);
        assert_eq!(color_channel(f64::NAN, Scalar::F64), 0.0);
    }
}
