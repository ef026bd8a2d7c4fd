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
//!   is a whole number in `0..=255` (`117` or `117.0`) and the triple is not unit length, else
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
    parse(path, &bytes, None)
}

/// What one column of a text file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Column {
    X,
    Y,
    Z,
    Nx,
    Ny,
    Nz,
    Red,
    Green,
    Blue,
    /// Not kept (splats are opaque), nor parsed.
    Alpha,
    Intensity,
    Classification,
    ReturnNumber,
    GpsTime,
    /// Not kept, nor parsed.
    Skip,
}

/// The columns of a text file, in order: detected from the first line, or given (`--columns
/// x,y,z,r,g,b,a`; names: `x y z`, `nx ny nz`, `r g b` or `red green blue`, `a`/`alpha`,
/// `i`/`intensity`, `c`/`class`/`classification`, `return`/`return_number`, `t`/`gps_time`, and
/// `_`/`skip` for a column to ignore).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TextColumns(Vec<Column>);

impl std::str::FromStr for TextColumns {
    type Err = String;

    fn from_str(names: &str) -> Result<Self, String> {
        let names: Vec<&str> = names.split(',').map(str::trim).collect();
        let columns = names.iter().map(|name| column_named(name)).collect::<Result<Vec<_>, _>>()?;
        let count = |c: Column| columns.iter().filter(|&&k| k == c).count();
        for (c, name) in columns.iter().zip(&names).filter(|(c, _)| **c != Column::Skip) {
            if count(*c) > 1 {
                return Err(format!("'{name}' is named twice"));
            }
        }
        for (group, what) in [
            ([Column::X, Column::Y, Column::Z], "x, y and z are needed"),
            ([Column::Nx, Column::Ny, Column::Nz], "nx, ny and nz go together"),
            ([Column::Red, Column::Green, Column::Blue], "r, g and b go together"),
        ] {
            let present = group.iter().filter(|&&c| count(c) == 1).count();
            if present != 3 && (present != 0 || group[0] == Column::X) {
                return Err(what.to_string());
            }
        }
        Ok(Self(columns))
    }
}

fn column_named(name: &str) -> Result<Column, String> {
    Ok(match name.to_ascii_lowercase().as_str() {
        "x" => Column::X,
        "y" => Column::Y,
        "z" => Column::Z,
        "nx" => Column::Nx,
        "ny" => Column::Ny,
        "nz" => Column::Nz,
        "r" | "red" => Column::Red,
        "g" | "green" => Column::Green,
        "b" | "blue" => Column::Blue,
        "a" | "alpha" => Column::Alpha,
        "i" | "intensity" => Column::Intensity,
        "c" | "class" | "classification" => Column::Classification,
        "return" | "return_number" => Column::ReturnNumber,
        "t" | "gps_time" => Column::GpsTime,
        "_" | "skip" => Column::Skip,
        other => {
            return Err(format!("unknown column '{other}' (x, y, z, nx, ny, nz, r, g, b, a, i, c, return, t or _)"));
        }
    })
}

impl TextColumns {
    fn of(names: &str) -> Self {
        names.parse().expect("a valid layout")
    }

    fn count(&self) -> usize {
        self.0.len()
    }

    fn has(&self, column: Column) -> bool {
        self.0.contains(&column)
    }

    fn attributes(&self) -> Attributes {
        Attributes {
            normals: self.has(Column::Nx),
            radii: false,
            colors: self.has(Column::Red),
            scan: ScanFields {
                intensity: self.has(Column::Intensity),
                classification: self.has(Column::Classification),
                return_number: self.has(Column::ReturnNumber),
                gps_time: self.has(Column::GpsTime),
            },
        }
    }

    fn property_names(&self) -> Vec<String> {
        let name = |c: &Column| match c {
            Column::Red => "red".to_string(),
            Column::Green => "green".to_string(),
            Column::Blue => "blue".to_string(),
            Column::Skip => "_".to_string(),
            Column::ReturnNumber => "return_number".to_string(),
            Column::GpsTime => "gps_time".to_string(),
            other => format!("{other:?}").to_lowercase(),
        };
        self.0.iter().map(name).collect()
    }

    /// Decides from the first data line (`pts`: the file is PTS by its extension or count);
    /// see the module doc.
    fn detect(tokens: &[&str], pts: bool) -> Result<Self, String> {
        let layout = match tokens.len() {
            3 => "x,y,z",
            4 => "x,y,z,i",
            7 if !pts && tokens[3..].iter().all(|t| byte_value(t).is_some()) && byte_value(tokens[6]) == Some(255) => {
                "x,y,z,r,g,b,a"
            }
            7 => "x,y,z,i,r,g,b",
            6 if looks_like_rgb(&tokens[3..]) => "x,y,z,r,g,b",
            6 => "x,y,z,nx,ny,nz",
            9 => "x,y,z,nx,ny,nz,r,g,b",
            n => {
                return Err(format!(
                    "{n} values on the first line: no layout of 3, 4, 6, 7 or 9 (x y z [nx ny nz] [r g b], or x y z \
                     intensity [r g b]) fits; name the columns (--columns, e.g. x,y,z,i,r,g,b,_)"
                ));
            }
        };
        Ok(Self::of(layout))
    }

    /// One line's point; colours are left raw (the caller scales them once the whole file is
    /// seen).
    fn record(&self, values: &[&str]) -> Result<PointRecord, String> {
        let mut record = PointRecord::default();
        let (mut position, mut normal, mut scan) = ([0.0f64; 3], [0.0f32; 3], [None; 4]);
        for (index, (column, token)) in self.0.iter().zip(values).enumerate() {
            if matches!(column, Column::Skip | Column::Alpha) {
                continue;
            }
            let value = token.parse::<f64>().map_err(|_| {
                format!("bad value '{}' in column {}", token.chars().take(40).collect::<String>(), index + 1)
            })?;
            match column {
                Column::X => position[0] = value,
                Column::Y => position[1] = value,
                Column::Z => position[2] = value,
                Column::Nx => normal[0] = value as f32,
                Column::Ny => normal[1] = value as f32,
                Column::Nz => normal[2] = value as f32,
                Column::Red => record.color[0] = value as f32,
                Column::Green => record.color[1] = value as f32,
                Column::Blue => record.color[2] = value as f32,
                Column::Intensity => scan[0] = Some(value),
                Column::Classification => scan[1] = Some(value),
                Column::ReturnNumber => scan[2] = Some(value),
                Column::GpsTime => scan[3] = Some(value),
                Column::Skip | Column::Alpha => {}
            }
        }
        record.position = DVec3::from_array(position);
        record.normal = Vec3::from_array(normal);
        record.set_scan(scan);
        Ok(record)
    }
}

/// A whole number in `0..=255`, written as an integer or a float (`117`, `117.0`).
fn byte_value(token: &str) -> Option<u8> {
    let value: f64 = token.parse().ok()?;
    (value.fract() == 0.0 && (0.0..=255.0).contains(&value)).then_some(value as u8)
}

fn looks_like_rgb(tokens: &[&str]) -> bool {
    let channels: Option<Vec<u8>> = tokens.iter().map(|t| byte_value(t)).collect();
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

/// Reads XYZ text, its columns `given` or detected from the first line.
pub(crate) fn parse(path: &Path, bytes: &[u8], given: Option<&TextColumns>) -> Result<LoadedCloud, IoError> {
    // The columns, once the first point's line is seen.
    let mut layout: Option<TextColumns> = None;
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
        if layout.is_none() {
            let columns = match given {
                Some(columns) => columns.clone(),
                None => TextColumns::detect(&values, pts).map_err(error)?,
            };
            builder = CloudBuilder::new(bytes.len() / (columns.count() * 6), columns.attributes());
            layout = Some(columns);
        }
        let layout = layout.as_ref().expect("set at the first point");
        if values.len() != layout.count() {
            let names = layout.property_names().join(" ");
            return Err(error(format!("expected {} values ({names}), found {}", layout.count(), values.len())));
        }
        builder.push(&layout.record(&values).map_err(error)?);
    }

    let layout = layout.or(given.cloned()).unwrap_or_else(|| TextColumns::of("x,y,z"));
    let mut cloud = builder.finish();
    crate::builder::scale_colors_to_unit(&mut cloud);
    let info = FileInfo {
        format: "XYZ text".into(),
        elements: vec![("point".into(), cloud.len())],
        vertex_properties: layout.property_names(),
        comments,
        file_bytes: bytes.len() as u64,
        up: None,
        sun: None,
    };
    Ok(LoadedCloud { cloud, info })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn six_columns_are_colour_only_for_byte_triples_that_are_not_unit_vectors() {
        let detect = |tokens: &[&str]| TextColumns::detect(tokens, false);
        let layout = |names: &str| Ok(TextColumns::of(names));
        assert_eq!(detect(&["0", "0", "0", "255", "128", "0"]), layout("x,y,z,r,g,b"));
        assert_eq!(detect(&["0", "0", "0", "0", "0", "1"]), layout("x,y,z,nx,ny,nz"));
        assert_eq!(detect(&["0", "0", "0", "117.0", "73.0", "49.0"]), layout("x,y,z,r,g,b"));
        assert_eq!(detect(&["0", "0", "0", "0.0", "1.0", "0.0"]), layout("x,y,z,nx,ny,nz"));
        assert_eq!(detect(&["0", "0", "0", "0.5", "0.5", "0.7"]), layout("x,y,z,nx,ny,nz"));
        assert_eq!(detect(&["0", "0", "0", "256", "0", "0"]), layout("x,y,z,nx,ny,nz"));
        assert_eq!(detect(&["0", "0", "0", "1"]), layout("x,y,z,i"));
        assert!(detect(&["0", "0", "0", "1", "2"]).unwrap_err().contains("--columns"));
    }

    #[test]
    fn named_columns_are_checked() {
        let layout: TextColumns = "X,y,z,_,Intensity,r,g,b,c".parse().unwrap();
        let record = layout.record(&["1", "2", "3", "99", "7.5", "10", "20", "30", "6"]).unwrap();
        assert_eq!((record.position, record.color), (DVec3::new(1.0, 2.0, 3.0), [10.0, 20.0, 30.0]));
        assert_eq!((record.intensity, record.classification), (7.5, 6));
        assert_eq!(layout.property_names().join(" "), "x y z _ intensity red green blue classification");
        for (bad, message) in [
            ("x,y", "x, y and z are needed"),
            ("x,y,z,r,g", "r, g and b go together"),
            ("x,y,z,nx", "nx, ny and nz go together"),
            ("x,y,z,x", "'x' is named twice"),
            ("x,y,z,w", "unknown column 'w'"),
        ] {
            let e = bad.parse::<TextColumns>().unwrap_err();
            assert!(e.starts_with(message), "{bad}: {e}");
        }
        assert!("x,y,z,_,_".parse::<TextColumns>().is_ok(), "several columns may be skipped");
    }

    #[test]
    fn seven_columns_ending_in_an_opaque_byte_are_rgba_unless_the_file_is_pts() {
        let (rgba, irgb) = (Ok(TextColumns::of("x,y,z,r,g,b,a")), Ok(TextColumns::of("x,y,z,i,r,g,b")));
        let tokens = ["1", "2", "3", "10", "20", "30", "255"];
        assert_eq!(TextColumns::detect(&tokens, false), rgba);
        assert_eq!(TextColumns::detect(&tokens, true), irgb);
        let pts = ["1", "2", "3", "-1024", "255", "0", "51"];
        assert_eq!(TextColumns::detect(&pts, false), irgb);
        let translucent = ["1", "2", "3", "10", "20", "30", "128"];
        assert_eq!(TextColumns::detect(&translucent, false), irgb);
        // CloudCompare may write the channels as floats.
        let floats = ["1", "2", "3", "117.0", "73.0", "49.0", "255.0"];
        assert_eq!(TextColumns::detect(&floats, false), rgba);
        let fractions = ["1", "2", "3", "117.5", "73.0", "49.0", "255.0"];
        assert_eq!(TextColumns::detect(&fractions, false), irgb);
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
