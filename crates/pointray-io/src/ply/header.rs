//! The PLY header: format line, elements and their properties, comments.

use std::path::Path;

use crate::IoError;
use crate::text::Lines;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Encoding {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

impl Encoding {
    fn parse(word: &str) -> Option<Self> {
        match word {
            "ascii" => Some(Self::Ascii),
            "binary_little_endian" => Some(Self::BinaryLittleEndian),
            "binary_big_endian" => Some(Self::BinaryBigEndian),
            _ => None,
        }
    }

    pub(crate) fn name(self) -> &'static str {
        match self {
            Self::Ascii => "ascii",
            Self::BinaryLittleEndian => "binary_little_endian",
            Self::BinaryBigEndian => "binary_big_endian",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    /// Both the classic names and the sized aliases of PLY 1.0.
    fn parse(word: &str) -> Option<Self> {
        Some(match word {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    pub(crate) fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    pub(crate) fn is_integer(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }

    /// Largest value of an integer type, used to normalise integer colours to `[0, 1]`.
    pub(crate) fn integer_max(self) -> Option<f64> {
        match self {
            Self::I8 => Some(i8::MAX.into()),
            Self::U8 => Some(u8::MAX.into()),
            Self::I16 => Some(i16::MAX.into()),
            Self::U16 => Some(u16::MAX.into()),
            Self::I32 => Some(i32::MAX.into()),
            Self::U32 => Some(u32::MAX.into()),
            Self::F32 | Self::F64 => None,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum PropertyKind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
pub(crate) struct Property {
    pub name: String,
    pub kind: PropertyKind,
    /// The declaration as written after `property`, whitespace normalised (for `FileInfo`).
    pub declaration: String,
}

#[derive(Clone, Debug)]
pub(crate) struct Element {
    pub name: String,
    pub count: usize,
    pub properties: Vec<Property>,
}

impl Element {
    /// Record size when no property is a list.
    pub(crate) fn fixed_size(&self) -> Option<usize> {
        self.properties
            .iter()
            .map(|p| match p.kind {
                PropertyKind::Scalar(s) => Some(s.size()),
                PropertyKind::List { .. } => None,
            })
            .sum()
    }

    /// Smallest possible binary record: lists count only their length field.
    pub(crate) fn min_size(&self) -> usize {
        self.properties
            .iter()
            .map(|p| match p.kind {
                PropertyKind::Scalar(s) => s.size(),
                PropertyKind::List { count, .. } => count.size(),
            })
            .sum()
    }
}

#[derive(Clone, Debug)]
pub(crate) struct Header {
    pub encoding: Encoding,
    pub version: String,
    pub elements: Vec<Element>,
    /// `comment` texts, and `obj_info` lines kept whole (prefixed `obj_info `).
    pub comments: Vec<String>,
    /// Byte offset of the first body byte.
    pub body_start: usize,
    /// Line number of the first body line (for ascii error messages).
    pub body_first_line: usize,
}

impl Header {
    pub(crate) fn format_name(&self) -> String {
        format!("PLY {} {}", self.encoding.name(), self.version)
    }
}

pub(crate) fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header, IoError> {
    let mut lines = Lines::new(bytes, 1);
    let error = |line: usize, message: String| IoError::at_line(path, line, message);

    match lines.next() {
        Some((_, b"ply")) => {}
        _ => {
            return Err(error(1, "not a PLY file: the first line is not 'ply'".into()));
        }
    }
    let mut format: Option<(Encoding, String)> = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut comments = Vec::new();

    for (number, raw) in lines.by_ref() {
        let line = String::from_utf8_lossy(raw);
        let mut words = line.split_ascii_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        match keyword {
            "end_header" => {
                let Some((encoding, version)) = format else {
                    return Err(error(number, "end_header before any 'format' line".into()));
                };
                return Ok(Header {
                    encoding,
                    version,
                    elements,
                    comments,
                    body_start: lines.offset(),
                    body_first_line: lines.next_line_number(),
                });
            }
            "comment" => comments.push(rest_after_keyword(&line, keyword).to_string()),
            "obj_info" => comments.push(line.trim().to_string()),
            "format" => format = Some(parse_format(words.collect()).map_err(|m| error(number, m))?),
            "element" => elements.push(parse_element(words.collect()).map_err(|m| error(number, m))?),
            "property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(error(number, "property before any element".into()));
                };
                let property = parse_property(words.collect()).map_err(|m| error(number, m))?;
                element.properties.push(property);
            }
            other => {
                return Err(error(number, format!("unknown header keyword '{}'", clip(other))));
            }
        }
    }
    let last_line = lines.next_line_number().saturating_sub(1).max(1);
    Err(error(last_line, "file ends before 'end_header'".into()))
}

fn rest_after_keyword<'a>(line: &'a str, keyword: &str) -> &'a str {
    line.trim_start().strip_prefix(keyword).unwrap_or("").trim()
}

fn parse_format(words: Vec<&str>) -> Result<(Encoding, String), String> {
    let [encoding, version] = words[..] else {
        return Err("expected 'format <encoding> 1.0'".into());
    };
    let encoding = Encoding::parse(encoding).ok_or_else(|| {
        format!("unknown PLY encoding '{}' (expected ascii, binary_little_endian or binary_big_endian)", clip(encoding))
    })?;
    if version != "1.0" && version != "1" {
        return Err(format!("unsupported PLY version '{}' (only 1.0 is known)", clip(version)));
    }
    Ok((encoding, "1.0".to_string()))
}

fn parse_element(words: Vec<&str>) -> Result<Element, String> {
    let [name, count] = words[..] else {
        return Err("expected 'element <name> <count>'".into());
    };
    let count = count
        .parse::<u64>()
        .ok()
        .and_then(|c| usize::try_from(c).ok())
        .ok_or_else(|| format!("bad element count '{}' for element '{}'", clip(count), clip(name)))?;
    Ok(Element { name: name.to_string(), count, properties: Vec::new() })
}

fn parse_property(words: Vec<&str>) -> Result<Property, String> {
    let scalar = |word: &str| Scalar::parse(word).ok_or_else(|| format!("unknown property type '{}'", clip(word)));
    let (name, kind) = match words[..] {
        ["list", count, item, name] => {
            let count = scalar(count)?;
            if !count.is_integer() {
                return Err(format!("list '{}' has a non-integer count type", clip(name)));
            }
            (name, PropertyKind::List { count, item: scalar(item)? })
        }
        ["list", ..] => {
            return Err("expected 'property list <count type> <item type> <name>'".into());
        }
        [ty, name] => (name, PropertyKind::Scalar(scalar(ty)?)),
        _ => return Err("expected 'property <type> <name>'".into()),
    };
    Ok(Property { name: name.to_string(), kind, declaration: words.join(" ") })
}

/// Keeps echoed garbage short in messages.
fn clip(word: &str) -> String {
    const MAX: usize = 40;
    match word.char_indices().nth(MAX) {
        Some((end, _)) => format!("{}...", &word[..end]),
        None => word.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Header, IoError> {
        parse_header(Path::new("t.ply"), text.as_bytes())
    }

    #[test]
    fn reads_elements_properties_and_comments() {
        let header = parse(
            "ply\r\nformat binary_big_endian 1.0\r\ncomment hello  world\r\nobj_info num_cols 3\r\n\
             element vertex 2\r\nproperty float32 x\r\nproperty list uint8 int vertex_indices\r\n\
             element face 0\r\nend_header\r\nBODY",
        )
        .unwrap();
        assert_eq!(header.encoding, Encoding::BinaryBigEndian);
        assert_eq!(header.comments, vec!["hello  world", "obj_info num_cols 3"]);
        assert_eq!(header.elements.len(), 2);
        let vertex = &header.elements[0];
        assert_eq!((vertex.name.as_str(), vertex.count), ("vertex", 2));
        assert_eq!(vertex.properties[1].declaration, "list uint8 int vertex_indices");
        assert_eq!(vertex.fixed_size(), None);
        assert_eq!(vertex.min_size(), 5);
        assert_eq!(header.body_first_line, 10);
        assert_eq!(
            &"ply\r\nformat binary_big_endian 1.0\r\ncomment hello  world\r\nobj_info num_cols 3\r\n\
             element vertex 2\r\nproperty float32 x\r\nproperty list uint8 int vertex_indices\r\n\
             element face 0\r\nend_header\r\nBODY"[header.body_start..],
            "BODY"
        );
    }

    #[test]
    fn rejects_bad_headers_with_line_numbers() {
        let cases = [
            ("ply\nformat ascii 2.0\nend_header\n", "line 2: unsupported PLY version"),
            ("ply\nformat ascii 1.0\nproperty float x\nend_header\n", "line 3: property before any element"),
            (
                "ply\nformat ascii 1.0\nelement v 1\nproperty float3 x\nend_header\n",
                "line 4: unknown property type 'float3'",
            ),
            ("ply\nformat ascii 1.0\nelement v -1\nend_header\n", "line 3: bad element count '-1'"),
            ("ply\nformat ascii 1.0\nelement v 1\nproperty list float int i\nend_header\n", "non-integer count"),
            ("ply\nformat ascii 1.0\nelement v 1\n", "line 3: file ends before 'end_header'"),
            ("ply\nelement v 1\nend_header\n", "line 3: end_header before any 'format' line"),
            ("ply\nformat ascii 1.0\nbogus\nend_header\n", "line 3: unknown header keyword 'bogus'"),
        ];
        for (text, expected) in cases {
            let message = parse(text).unwrap_err().to_string();
            assert!(message.starts_with("t.ply: "), "{message}");
            assert!(message.contains(expected), "{message:?} lacks {expected:?}");
        }
    }
}
