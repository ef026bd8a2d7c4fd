//! XYZ text: one point per line, `x y z [nx ny nz] [r g b]`, or in the PTS layout (Leica and
//! others) `x y z intensity [r g b]`.
//!
//! Rules, chosen to be predictable rather than clever:
//! - values are separated by whitespace and/or commas; `#` starts a comment (whole-line
//!   comments are kept in [`FileInfo::comments`]); blank lines are skipped;
//! - a first data line holding a single integer is a point count (the `.pts` convention)
//!   and is skipped;
//! - the first data line fixes the column count for the whole file: 3 = position,
//!   9 = position + normal + colour, 6 = position + colour if each of its last three values
//!   is an integer literal in `0..=255` and the triple is not unit length, else
//!   position + normal; 4 = position + intensity, 7 = position + intensity + colour (PTS; the
//!   intensity is kept as a scan attribute), except that 7 columns whose last four are whole
//!   numbers in `0..=255` (`117` or `117.0`) ending in an opaque 255, in a file that is not
//!   PTS (no `.pts` extension, no point count), are position + colour + alpha (CloudCompare's
//!   `x y z R G B A` export, with integer or float channels);
//! - colours are `0..=255` if any colour value in the file exceeds 1, else `0..=1`;
//!   clamped to `[0, 1]` either way;
//! - non-finite coordinates (`nan`, `inf`) are kept, as for PLY.

use std::path::Path;

use glam::{DVec3, Vec3};

use crate::builder::{Attributes, CloudBuilder, PointRecord, ScanFields};
use crate::text::{Lines, as_text, data_lines, data_part, split_values};
use crate::{FileInfo, IoError, LoadedCloud};

/// Reads an XYZ file whatever its extension.
pub fn read_xyz(path: &Path) -> Result<LoadedCloud, IoError> {
    let bytes = crate::file::read_file(path, false)?;
    parse(path, &bytes)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Columns {
    Position,
    PositionNormal,
    PositionColor,
    PositionNormalColor,
    PositionIntensity,
    PositionIntensityColor,
    PositionColorAlpha,
}

impl Columns {
    fn count(self) -> usize {
        match self {
            Self::Position => 3,
            Self::PositionIntensity => 4,
            Self::PositionNormal | Self::PositionColor => 6,
            Self::PositionIntensityColor | Self::PositionColorAlpha => 7,
            Self::PositionNormalColor => 9,
        }
    }

    fn attributes(self) -> Attributes {
        let intensity = matches!(self, Self::PositionIntensity | Self::PositionIntensityColor);
        Attributes {
            normals: matches!(self, Self::PositionNormal | Self::PositionNormalColor),
            radii: false,
            colors: !matches!(self, Self::Position | Self::PositionNormal | Self::PositionIntensity),
            scan: ScanFields { intensity, ..ScanFields::default() },
        }
    }

    fn property_names(self) -> Vec<String> {
        let attributes = self.attributes();
        let mut names = vec!["x", "y", "z"];
        if attributes.scan.intensity {
            names.push("intensity");
        }
        if attributes.normals {
            names.extend(["nx", "ny", "nz"]);
        }
        if attributes.colors {
            names.extend(["red", "green", "blue"]);
        }
        if self == Self::PositionColorAlpha {
            names.push("alpha");
        }
        names.into_iter().map(String::from).collect()
    }

    /// Decides from the first data line (`pts`: the file is PTS by its extension or count);
    /// see the module doc.
    fn from_first_line(tokens: &[&str], pts: bool) -> Result<Self, String> {
        match tokens.len() {
            3 => Ok(Self::Position),
            4 => Ok(Self::PositionIntensity),
            7 if !pts && tokens[3..].iter().all(|t| byte_value(t).is_some()) && byte_value(tokens[6]) == Some(255) => {
                Ok(Self::PositionColorAlpha)
            }
            7 => Ok(Self::PositionIntensityColor),
            6 if looks_like_rgb(&tokens[3..]) => Ok(Self::PositionColor),
            6 => Ok(Self::PositionNormal),
            9 => Ok(Self::PositionNormalColor),
            n => Err(format!(
                "expected 3, 4, 6, 7 or 9 values (x y z [nx ny nz] [r g b], or x y z intensity [r g b]), found {n}"
            )),
        }
    }
}

/// A whole number in `0..=255`, written as an integer or a float (`117`, `117.0`).
fn byte_value(token: &str) -> Option<u8> {
    let value: f64 = token.parse().ok()?;
    (value.fract() == 0.0 && (0.0..=255.0).contains(&value)).then_some(value as u8)
}

fn looks_like_rgb(tokens: &[&str]) -> bool {
    let channels: Option<Vec<u8>> = tokens.iter().map(|t| t.parse::<u8>().ok()).collect();
    match channels {
        Some(channels) => channels.iter().map(|&c| f64::from(c).powi(2)).sum::<f64>() != 1.0,
        None => false,
    }
}

/// Whether the content plausibly is XYZ text: the first data line is all numbers, at least
/// three of them (or a lone `.pts` point count).
pub(crate) fn looks_like_xyz(bytes: &[u8]) -> bool {
    for (_, line) in Lines::new(bytes, 1) {
        let Some(text) = as_text(line) else {
            return false;
        };
        let Some(data) = data_part(text) else {
            continue;
        };
        let values = split_values(data);
        let numeric = values.iter().all(|v| v.parse::<f64>().is_ok());
        let pts_count = values.len() == 1 && values[0].parse::<u64>().is_ok();
        return numeric && (values.len() >= 3 || pts_count);
    }
    false
}

pub(crate) fn parse(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    let mut columns: Option<Columns> = None;
    let mut builder = CloudBuilder::new(0, Attributes::default());
    let mut comments = Vec::new();
    let mut seen_data = false;
    let mut pts = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("pts"));

    for data_line in data_lines(path, bytes, &mut comments) {
        let (number, data) = data_line?;
        let error = |message: String| IoError::at_line(path, number, message);
        let values = split_values(data);
        let first_data_line = !seen_data;
        seen_data = true;
        if first_data_line && values.len() == 1 && values[0].parse::<u64>().is_ok() {
            pts = true;
            continue; // `.pts` point count
        }
        let layout = match columns {
            Some(layout) => layout,
            None => {
                let layout = Columns::from_first_line(&values, pts).map_err(error)?;
                builder = CloudBuilder::new(bytes.len() / (layout.count() * 6), layout.attributes());
                *columns.insert(layout)
            }
        };
        if values.len() != layout.count() {
            return Err(error(format!("expected {} values, found {}", layout.count(), values.len())));
        }
        builder.push(&parse_point(&values, layout).map_err(error)?);
    }

    let layout = columns.unwrap_or(Columns::Position);
    let mut cloud = builder.finish();
    crate::builder::scale_colors_to_unit(&mut cloud);
    let info = FileInfo {
        format: "XYZ text".into(),
        elements: vec![("point".into(), cloud.len())],
        vertex_properties: layout.property_names(),
        comments,
        file_bytes: bytes.len() as u64,
        up: None,
    };
    Ok(LoadedCloud { cloud, info })
}

/// Colours are left raw here; the caller scales them once the whole file is seen.
fn parse_point(values: &[&str], layout: Columns) -> Result<PointRecord, String> {
    let mut numbers = [0.0f64; 9];
    for (column, (slot, token)) in numbers.iter_mut().zip(values).enumerate() {
        *slot = token.parse::<f64>().map_err(|_| {
            format!("bad value '{}' in column {}", token.chars().take(40).collect::<String>(), column + 1)
        })?;
    }
    let triple = |start: usize| [numbers[start], numbers[start + 1], numbers[start + 2]];
    let as_vec3 = |[x, y, z]: [f64; 3]| Vec3::new(x as f32, y as f32, z as f32);
    let mut record = PointRecord { position: DVec3::from_array(triple(0)), ..PointRecord::default() };
    match layout {
        Columns::Position => {}
        Columns::PositionIntensity => record.intensity = numbers[3] as f32,
        Columns::PositionIntensityColor => {
            record.intensity = numbers[3] as f32;
            record.color = as_vec3(triple(4)).to_array();
        }
        Columns::PositionNormal => record.normal = as_vec3(triple(3)),
        Columns::PositionColor | Columns::PositionColorAlpha => record.color = as_vec3(triple(3)).to_array(),
        Columns::PositionNormalColor => {
            record.normal = as_vec3(triple(3));
            record.color = as_vec3(triple(6)).to_array();
        }
    }
    Ok(record)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn six_columns_are_colour_only_for_byte_triples_that_are_not_unit_vectors() {
        assert_eq!(Columns::from_first_line(&["0", "0", "0", "255", "128", "0"], false), Ok(Columns::PositionColor));
        assert_eq!(Columns::from_first_line(&["0", "0", "0", "0", "0", "1"], false), Ok(Columns::PositionNormal));
        assert_eq!(Columns::from_first_line(&["0", "0", "0", "0.5", "0.5", "0.7"], false), Ok(Columns::PositionNormal));
        assert_eq!(Columns::from_first_line(&["0", "0", "0", "256", "0", "0"], false), Ok(Columns::PositionNormal));
        assert_eq!(Columns::from_first_line(&["0", "0", "0", "1"], false), Ok(Columns::PositionIntensity));
        assert!(Columns::from_first_line(&["0", "0", "0", "1", "2"], false).is_err());
    }

    #[test]
    fn seven_columns_ending_in_an_opaque_byte_are_rgba_unless_the_file_is_pts() {
        let rgba = ["1", "2", "3", "10", "20", "30", "255"];
        assert_eq!(Columns::from_first_line(&rgba, false), Ok(Columns::PositionColorAlpha));
        assert_eq!(Columns::from_first_line(&rgba, true), Ok(Columns::PositionIntensityColor));
        let pts = ["1", "2", "3", "-1024", "255", "0", "51"];
        assert_eq!(Columns::from_first_line(&pts, false), Ok(Columns::PositionIntensityColor));
        let translucent = ["1", "2", "3", "10", "20", "30", "128"];
        assert_eq!(Columns::from_first_line(&translucent, false), Ok(Columns::PositionIntensityColor));
        // CloudCompare may write the channels as floats.
        let floats = ["1", "2", "3", "117.0", "73.0", "49.0", "255.0"];
        assert_eq!(Columns::from_first_line(&floats, false), Ok(Columns::PositionColorAlpha));
        let fractions = ["1", "2", "3", "117.5", "73.0", "49.0", "255.0"];
        assert_eq!(Columns::from_first_line(&fractions, false), Ok(Columns::PositionIntensityColor));
    }

    #[test]
    fn sniffing_accepts_numbers_and_rejects_words() {
        assert!(looks_like_xyz(b"# scan\n\n1 2 3\n"));
        assert!(looks_like_xyz(b"1,2,3,4,5,6\n"));
        assert!(looks_like_xyz(b"1200\n1 2 3\n"));
        assert!(!looks_like_xyz(b"hello world 3\n"));
        assert!(!looks_like_xyz(b"1 2\n"));
        assert!(!looks_like_xyz(b""));
    }
}
