//! Ascii PLY bodies: one record per line, values separated by whitespace.

use std::path::Path;

use super::header::{Element, PropertyKind};
use super::vertex::VertexLayout;
use crate::IoError;
use crate::builder::CloudBuilder;
use crate::text::{Lines, as_text};

/// Skips the elements before the vertex element line by line, then parses the vertices.
/// Blank lines between records are tolerated; elements after the vertices are not read.
pub(crate) fn read_vertices(
    path: &Path,
    lines: &mut Lines<'_>,
    elements: &[Element],
    vertex_index: usize,
    layout: &VertexLayout,
) -> Result<CloudBuilder, IoError> {
    skip_elements(path, lines, &elements[..vertex_index])?;
    let vertex = elements.get(vertex_index).ok_or_else(|| IoError::invalid(path, "no 'vertex' element"))?;
    ensure_room(path, lines, vertex)?;
    let mut values = vec![0.0; vertex.properties.len()];
    let mut builder = CloudBuilder::new(vertex.count, layout.attributes());
    for index in 0..vertex.count {
        let (line_number, line) = next_record(path, lines, vertex, index)?;
        let error = |message: String| IoError::at_line(path, line_number, format!("vertex {index}: {message}"));
        let text = as_text(line).ok_or_else(|| error("line is not text".into()))?;
        parse_record(text, vertex, &mut values, None).map_err(error)?;
        builder.push(&layout.record(&values));
    }
    Ok(builder)
}

/// From the start of element `from`, skips to element `target` and hands the items of list
/// property `list` of each of its records to `visit`, which may refuse them.
pub(crate) fn for_each_list(
    path: &Path,
    lines: &mut Lines<'_>,
    elements: &[Element],
    (from, target, list): (usize, usize, usize),
    mut visit: impl FnMut(usize, &[f64]) -> Result<(), String>,
) -> Result<(), IoError> {
    skip_elements(path, lines, &elements[from..target])?;
    let element = &elements[target];
    ensure_room(path, lines, element)?;
    let mut values = vec![0.0; element.properties.len()];
    let mut items = Vec::new();
    for index in 0..element.count {
        let (line_number, line) = next_record(path, lines, element, index)?;
        let error =
            |message: String| IoError::at_line(path, line_number, format!("{} {index}: {message}", element.name));
        let text = as_text(line).ok_or_else(|| error("line is not text".into()))?;
        parse_record(text, element, &mut values, Some((list, &mut items))).map_err(error)?;
        visit(index, &items).map_err(error)?;
    }
    Ok(())
}

/// Steps over the records of `elements`, a line each (none for an element without properties).
fn skip_elements(path: &Path, lines: &mut Lines<'_>, elements: &[Element]) -> Result<(), IoError> {
    for element in elements {
        ensure_room(path, lines, element)?;
        if element.properties.is_empty() {
            continue;
        }
        for index in 0..element.count {
            next_record(path, lines, element, index)?;
        }
    }
    Ok(())
}

/// Every record takes at least one character and a line break, so a count beyond half the
/// remaining bytes is corrupt; refusing it early avoids a huge allocation.
fn ensure_room(path: &Path, lines: &Lines<'_>, element: &Element) -> Result<(), IoError> {
    let remaining = lines.remaining();
    if element.properties.is_empty() || element.count <= remaining / 2 + 1 {
        return Ok(());
    }
    Err(IoError::at_line(
        path,
        lines.next_line_number(),
        format!("element '{}' declares {} records, but only {remaining} bytes remain", element.name, element.count),
    ))
}

fn next_record<'a>(
    path: &Path,
    lines: &mut Lines<'a>,
    element: &Element,
    index: usize,
) -> Result<(usize, &'a [u8]), IoError> {
    lines.next_non_blank().ok_or_else(|| {
        IoError::at_line(
            path,
            lines.next_line_number().saturating_sub(1).max(1),
            format!("file ends inside {} {index} of {}", element.name, element.count),
        )
    })
}

/// Fills `values[i]` with scalar property `i`, and `list.1` with the items of list property
/// `list.0` when given; other lists are counted and stepped over.
fn parse_record(
    text: &str,
    element: &Element,
    values: &mut [f64],
    mut list: Option<(usize, &mut Vec<f64>)>,
) -> Result<(), String> {
    let has_lists = element.fixed_size().is_none();
    let mut tokens = text.split_ascii_whitespace();
    let mut found = 0;
    let ends_early = |property: &str, found: usize| {
        if has_lists {
            format!("line ends inside property '{property}'")
        } else {
            format!("expected {} values, found {found}", element.properties.len())
        }
    };
    for (index, property) in element.properties.iter().enumerate() {
        let token = tokens.next().ok_or_else(|| ends_early(&property.name, found))?;
        found += 1;
        match property.kind {
            PropertyKind::Scalar(_) => {
                let value = token
                    .parse::<f64>()
                    .map_err(|_| format!("bad value '{}' for property '{}'", clip(token), property.name))?;
                if let Some(slot) = values.get_mut(index) {
                    *slot = value;
                }
            }
            PropertyKind::List { .. } => {
                let length = token
                    .parse::<u64>()
                    .map_err(|_| format!("bad list length '{}' for property '{}'", clip(token), property.name))?;
                let mut items = list.as_mut().filter(|(wanted, _)| *wanted == index).map(|(_, items)| items);
                if let Some(items) = items.as_mut() {
                    items.clear();
                }
                for _ in 0..length {
                    let item = tokens.next().ok_or_else(|| ends_early(&property.name, found))?;
                    found += 1;
                    if let Some(items) = items.as_mut() {
                        let value = item
                            .parse::<f64>()
                            .map_err(|_| format!("bad value '{}' in list '{}'", clip(item), property.name))?;
                        items.push(value);
                    }
                }
            }
        }
    }
    let extra = tokens.count();
    if extra > 0 {
        return Err(if has_lists {
            format!("{extra} values after the last property")
        } else {
            format!("expected {} values, found {}", element.properties.len(), found + extra)
        });
    }
    Ok(())
}

fn clip(token: &str) -> &str {
    match token.char_indices().nth(40) {
        Some((end, _)) => &token[..end],
        None => token,
    }
}
