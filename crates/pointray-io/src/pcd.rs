//! PCD, the Point Cloud Library's format: a text header (`FIELDS`, `SIZE`, `TYPE`, `COUNT`,
//! `WIDTH`, `HEIGHT`, `POINTS`, `DATA`), then the points as `ascii` lines, `binary` records, or
//! `binary_compressed`: two little-endian u32 sizes and an LZF block that holds the fields one
//! after another (all x, then all y, …).
//!
//! Read: `x y z` (required), `normal_x normal_y normal_z`, and colour packed in `rgb` or `rgba`
//! (0x00RRGGBB in a float's or a u32's bits). Organised clouds (a depth camera's grid) mark
//! missing pixels with NaN coordinates: those points are dropped and counted in a warning.

use std::path::Path;

use glam::{DVec3, Vec3};

use crate::builder::{Attributes, CloudBuilder, PointRecord, ScanFields, scan_columns};
use crate::text::{Lines, as_text, split_values};
use crate::{FileInfo, IoError, LoadedCloud};

/// Whether `bytes` start like a PCD header (after any `#` comment lines).
pub(crate) fn looks_like_pcd(bytes: &[u8]) -> bool {
    for (_, line) in Lines::new(bytes, 1) {
        let Some(text) = as_text(line).map(str::trim) else { return false };
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        return text.starts_with("VERSION") || text.starts_with("FIELDS");
    }
    false
}

#[derive(Clone, Debug)]
struct Field {
    name: String,
    /// Bytes per value: 1, 2, 4 or 8.
    size: usize,
    /// `F` (float), `U` (unsigned) or `I` (signed).
    kind: char,
    count: usize,
}

impl Field {
    fn bytes(&self) -> usize {
        self.size * self.count
    }

    /// The first value of this field in `raw` (little-endian), as f64; colours keep their bits.
    fn value(&self, raw: &[u8]) -> f64 {
        let mut b = [0u8; 8];
        b[..self.size].copy_from_slice(&raw[..self.size]);
        match (self.kind, self.size) {
            ('F', 4) => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            ('F', _) => f64::from_le_bytes(b),
            ('U', _) => u64::from_le_bytes(b) as f64,
            (_, size) => (i64::from_le_bytes(b) << (64 - 8 * size) >> (64 - 8 * size)) as f64,
        }
    }

    /// The packed colour's bits (a float or an unsigned field of 4 bytes).
    fn bits(&self, raw: &[u8]) -> u32 {
        u32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]])
    }
}

struct Header {
    fields: Vec<Field>,
    points: usize,
    /// The sensor's position (`VIEWPOINT`'s translation), for an organised frame (`HEIGHT` > 1)
    /// only: PCL writes `VIEWPOINT 0 0 0 1 0 0 0` into every file, frames or not. (Its rotation
    /// is not read: PCL's own mug frame says 180° about x, which its points do not have.)
    viewpoint: Option<[f64; 3]>,
    data: String,
    /// Byte offset of the body.
    body: usize,
    /// Line number of the first body line (ascii).
    body_line: usize,
}

fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header, IoError> {
    let mut lines = Lines::new(bytes, 1);
    let (mut names, mut sizes, mut types, mut counts) = (None, None, None, None);
    let (mut width, mut height, mut points, mut viewpoint) = (None, None, None, None);
    while let Some((number, line)) = lines.next() {
        let error = |message: String| IoError::at_line(path, number, message);
        let text = as_text(line).ok_or_else(|| error("header line is not text".into()))?.trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        let values = split_values(text);
        let Some((&key, rest)) = values.split_first() else { continue };
        let numbers = || -> Result<Vec<usize>, IoError> {
            rest.iter().map(|v| v.parse::<usize>().map_err(|_| error(format!("{key}: '{v}' is not a count")))).collect()
        };
        match key {
            "VERSION" => {
                // PCL writes 0.7 (".7" too); 0.5 and 0.6 lay out the same fields.
                let version = rest.first().and_then(|v| v.parse::<f64>().ok());
                if !version.is_some_and(|v| (0.5..=0.7).contains(&v)) {
                    return Err(error(format!("VERSION {}: only PCD 0.5 to 0.7 is read", rest.join(" "))));
                }
            }
            "VIEWPOINT" => {
                let t: Vec<f64> = rest.iter().take(3).filter_map(|v| v.parse().ok()).collect();
                viewpoint = <[f64; 3]>::try_from(t).ok().filter(|t| t.iter().all(|x| x.is_finite()));
            }
            "FIELDS" => names = Some(rest.iter().map(|s| s.to_string()).collect::<Vec<_>>()),
            "SIZE" => sizes = Some(numbers()?),
            "COUNT" => counts = Some(numbers()?),
            "TYPE" => types = Some(rest.iter().map(|s| s.chars().next().unwrap_or('?')).collect::<Vec<_>>()),
            "WIDTH" => width = numbers()?.first().copied(),
            "HEIGHT" => height = numbers()?.first().copied(),
            "POINTS" => points = numbers()?.first().copied(),
            "DATA" => {
                let names = names.ok_or_else(|| error("DATA before FIELDS".into()))?;
                let sizes = sizes.ok_or_else(|| error("no SIZE line".into()))?;
                let types = types.ok_or_else(|| error("no TYPE line".into()))?;
                let counts = counts.unwrap_or_else(|| vec![1; names.len()]);
                if sizes.len() != names.len() || types.len() != names.len() || counts.len() != names.len() {
                    return Err(error("FIELDS, SIZE, TYPE and COUNT differ in length".into()));
                }
                let mut fields = Vec::new();
                for (((name, size), kind), count) in names.into_iter().zip(sizes).zip(types).zip(counts) {
                    // No field holds more values than the file has bytes: the sums below fit.
                    let valid = matches!((kind, size), ('F', 4 | 8) | ('U' | 'I', 1 | 2 | 4 | 8))
                        && (1..=bytes.len()).contains(&count);
                    if !valid {
                        return Err(error(format!("field {name}: unsupported TYPE {kind} SIZE {size} COUNT {count}")));
                    }
                    fields.push(Field { name, size, kind, count });
                }
                let points = points.or(width.zip(height).and_then(|(w, h)| w.checked_mul(h)));
                let points = points.ok_or_else(|| error("no POINTS (nor WIDTH and HEIGHT)".into()))?;
                let data = rest.first().map(|s| s.to_ascii_lowercase()).unwrap_or_default();
                let viewpoint = viewpoint.filter(|_| height.is_some_and(|h| h > 1));
                return Ok(Header { fields, points, viewpoint, data, body: lines.offset(), body_line: number + 1 });
            }
            _ => return Err(error(format!("unknown header line '{key}'"))),
        }
    }
    Err(IoError::invalid(path, "the PCD header has no DATA line"))
}

pub(crate) fn parse(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    let header = parse_header(path, bytes)?;
    // PCL writes `x y z`, PDAL `X Y Z`.
    let find = |name: &str| header.fields.iter().position(|f| f.name.eq_ignore_ascii_case(name));
    let (Some(x), Some(y), Some(z)) = (find("x"), find("y"), find("z")) else {
        return Err(IoError::invalid(path, "the PCD file has no x, y and z fields"));
    };
    let normal = find("normal_x").zip(find("normal_y")).zip(find("normal_z")).map(|((a, b), c)| [a, b, c]);
    let color = find("rgb").or(find("rgba")).filter(|&c| header.fields[c].size == 4);
    // PDAL's separate channels, where there is no packed colour.
    let channels = find("red").zip(find("green")).zip(find("blue")).map(|((r, g), b)| [r, g, b]);
    let channels = channels.filter(|_| color.is_none());
    let scan = scan_columns(header.fields.iter().map(|f| f.name.as_str()));
    let record = header.fields.iter().try_fold(0usize, |sum, f| sum.checked_add(f.bytes()));
    let record = record.ok_or_else(|| IoError::invalid(path, "the PCD fields' sizes overflow"))?;
    let body = &bytes[header.body..];
    let n = header.points;
    // Every layout gives the raw bytes of field f of point i.
    let decompressed;
    let (row_major, data): (bool, &[u8]) = match header.data.as_str() {
        "binary" => (true, body),
        "binary_compressed" => {
            decompressed = decompress(path, header.body, body, n.checked_mul(record))?;
            (false, &decompressed)
        }
        "ascii" => (true, &[]),
        other => return Err(IoError::invalid(path, format!("unknown DATA '{other}'"))),
    };
    let mut ascii_values = Vec::new();
    if header.data == "ascii" {
        ascii_values = ascii_records(path, &header, body, n, color)?;
    } else if n.checked_mul(record).is_none_or(|total| total > data.len()) {
        return Err(IoError::invalid(
            path,
            format!(
                "the header declares {n} points of {record} bytes, more than the data holds ({} bytes)",
                data.len()
            ),
        ));
    }
    // Offsets of each field: within a record (row-major) or of its block (field after field).
    let offsets: Vec<usize> = header
        .fields
        .iter()
        .scan(0, |at, f| {
            let here = *at;
            *at += if row_major { f.bytes() } else { f.bytes() * n };
            Some(here)
        })
        .collect();
    let ascii_index: Vec<usize> =
        header.fields.iter().scan(0, |at, f| Some(std::mem::replace(at, *at + f.count))).collect();
    let per_point = ascii_index.last().map_or(0, |i| i + header.fields.last().map_or(0, |f| f.count));
    let raw = |i: usize, f: usize| {
        let field = &header.fields[f];
        let at = if row_major { i * record + offsets[f] } else { offsets[f] + i * field.bytes() };
        &data[at..at + field.size]
    };
    let value = |i: usize, f: usize| {
        if header.data == "ascii" {
            ascii_values[i * per_point + ascii_index[f]]
        } else {
            header.fields[f].value(raw(i, f))
        }
    };
    let bits = |i: usize, f: usize| {
        if header.data == "ascii" {
            ascii_values[i * per_point + ascii_index[f]] as u32 // already the bits (`ascii_records`)
        } else {
            header.fields[f].bits(raw(i, f))
        }
    };
    let colors = color.is_some() || channels.is_some();
    let attributes = Attributes { normals: normal.is_some(), colors, radii: false, scan: ScanFields::of(&scan) };
    let mut builder = CloudBuilder::new(n, attributes);
    let mut dropped = 0usize;
    for i in 0..n {
        let position = DVec3::new(value(i, x), value(i, y), value(i, z));
        if !position.is_finite() {
            dropped += 1;
            continue;
        }
        let normal = normal.map_or(Vec3::ZERO, |[a, b, c]| DVec3::new(value(i, a), value(i, b), value(i, c)).as_vec3());
        let color = match (color, channels) {
            (Some(c), _) => {
                let v = bits(i, c);
                [(v >> 16) & 255, (v >> 8) & 255, v & 255].map(|c| c as f32 / 255.0)
            }
            (None, Some(rgb)) => rgb.map(|f| value(i, f) as f32), // scaled below
            (None, None) => [0.0; 3],
        };
        let mut record = PointRecord { position, normal, color, ..PointRecord::default() };
        record.set_scan(scan.map(|f| f.map(|f| value(i, f))));
        builder.push(&record);
    }
    if dropped > 0 {
        tracing::warn!("{}: {dropped} of {n} points have no finite coordinates (NaN) and were dropped", path.display());
    }
    let info = FileInfo {
        format: format!("PCD {}", header.data),
        elements: vec![("point".into(), builder.len())],
        vertex_properties: header
            .fields
            .iter()
            .map(|f| format!("{} {}{} x{}", f.name, f.kind, f.size, f.count))
            .collect(),
        comments: (dropped > 0).then(|| format!("{dropped} NaN points dropped")).into_iter().collect(),
        file_bytes: bytes.len() as u64,
        // A frame is in its sensor's optical frame (PCL's: x right, y down, z ahead).
        up: header.viewpoint.map(|_| [0.0, -1.0, 0.0]),
        sun: None,
    };
    let mut cloud = builder.finish();
    if channels.is_some() {
        // By the values, not the fields' types: as in LAS, writers put 8-bit values in 16-bit
        // fields (PDAL's own autzen-utm.pcd: 16-bit channels holding 8-bit values).
        crate::builder::scale_colors_to_unit(&mut cloud);
    }
    cloud.viewpoints = header.viewpoint.map(|v| (glam::DVec3::from(v) - cloud.origin).as_vec3()).into_iter().collect();
    Ok(LoadedCloud { cloud, info })
}

/// The values of the ascii body, `n` lines of every field's values. The packed colour (field
/// `color`) becomes its bits: PCL writes it as an integer despite its float type, others as
/// the float whose bits hold it.
fn ascii_records(
    path: &Path,
    header: &Header,
    body: &[u8],
    n: usize,
    color: Option<usize>,
) -> Result<Vec<f64>, IoError> {
    let per_point: usize = header.fields.iter().map(|f| f.count).sum();
    let color_at = color.map(|c| header.fields[..c].iter().map(|f| f.count).sum::<usize>());
    let mut values = Vec::with_capacity(n.min(body.len() / (2 * per_point).max(1)) * per_point);
    let mut read = 0;
    for (number, line) in Lines::new(body, header.body_line) {
        if read == n {
            break;
        }
        let error = |message: String| IoError::at_line(path, number, message);
        let text = as_text(line).ok_or_else(|| error("line is not text".into()))?;
        let tokens = split_values(text);
        if tokens.is_empty() {
            continue;
        }
        if tokens.len() != per_point {
            return Err(error(format!("expected {per_point} values, found {}", tokens.len())));
        }
        for (k, t) in tokens.into_iter().enumerate() {
            let bad = || error(format!("'{t}' is not a number"));
            let value = if Some(k) == color_at {
                match t.parse::<u32>() {
                    Ok(bits) => f64::from(bits),
                    Err(_) => f64::from(t.parse::<f32>().map_err(|_| bad())?.to_bits()),
                }
            } else {
                t.parse::<f64>().map_err(|_| bad())?
            };
            values.push(value);
        }
        read += 1;
    }
    if read < n {
        return Err(IoError::invalid(path, format!("the header declares {n} points, the file holds {read}")));
    }
    Ok(values)
}

/// The LZF block of a `binary_compressed` body, checked against the header's size.
fn decompress(path: &Path, body_at: usize, body: &[u8], expected: Option<usize>) -> Result<Vec<u8>, IoError> {
    let error = |message: String| IoError::at_byte(path, body_at, message);
    if body.len() < 8 {
        return Err(error("binary_compressed: no sizes".into()));
    }
    let compressed = u32::from_le_bytes([body[0], body[1], body[2], body[3]]) as usize;
    let size = u32::from_le_bytes([body[4], body[5], body[6], body[7]]) as usize;
    let Some(expected) = expected else {
        return Err(error("binary_compressed: the header's points take more bytes than can be addressed".into()));
    };
    if size != expected {
        return Err(error(format!(
            "binary_compressed: {size} bytes uncompressed, the header's points need {expected}"
        )));
    }
    let input = body
        .get(8..8 + compressed)
        .ok_or_else(|| error(format!("binary_compressed: {compressed} bytes promised, fewer present")))?;
    // An LZF back-reference of 3 bytes makes at most 264: a larger ratio is not LZF.
    if size > compressed.saturating_mul(88) + 64 {
        return Err(error(format!("binary_compressed: {size} bytes cannot come from {compressed}")));
    }
    lzf_decompress(input, size).map_err(|e| IoError::at_byte(path, body_at + 8, format!("binary_compressed: {e}")))
}

/// LZF: a control byte below 32 copies that many plus one literal bytes; otherwise its top three
/// bits (7: plus the next byte) give a length less two, and its low five bits with the next
/// byte the distance less one, back into the output.
fn lzf_decompress(input: &[u8], size: usize) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(size);
    let mut i = 0;
    while i < input.len() {
        let control = usize::from(input[i]);
        i += 1;
        if control < 32 {
            let run = input.get(i..i + control + 1).ok_or("a literal run past the end")?;
            out.extend_from_slice(run);
            i += control + 1;
        } else {
            let mut length = control >> 5;
            if length == 7 {
                length += usize::from(*input.get(i).ok_or("a length past the end")?);
                i += 1;
            }
            let low = usize::from(*input.get(i).ok_or("a distance past the end")?);
            i += 1;
            let distance = ((control & 0x1f) << 8) + low + 1;
            let start = out.len().checked_sub(distance).ok_or("a back-reference before the start")?;
            for k in start..start + length + 2 {
                let byte = out[k];
                out.push(byte);
            }
        }
        if out.len() > size {
            return Err("more data than declared".into());
        }
    }
    if out.len() != size {
        return Err(format!("{} bytes decompressed, {size} declared", out.len()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::lzf_decompress;

    #[test]
    fn lzf_literals_and_back_references() {
        // "abc" as a literal run, then 5 bytes from 3 back ("abcab"), then a long reference
        // (length code 7 + 2 = 9, plus 2) from 1 back: eleven more "b"s.
        let input = [2, b'a', b'b', b'c', 3 << 5, 2, 7 << 5, 2, 0];
        let out = lzf_decompress(&input, 19).unwrap();
        assert_eq!(out, b"abcabcabbbbbbbbbbbb");
        assert!(lzf_decompress(&[0x20, 5], 2).unwrap_err().contains("before the start"));
        assert!(lzf_decompress(&[4, b'a'], 5).unwrap_err().contains("past the end"));
        assert!(lzf_decompress(&[0, b'a'], 2).unwrap_err().contains("declared"));
    }
}
