//! Binary PLY bodies (both byte orders), decoded from a byte slice of the whole file.

use crate::builder::PointRecord;
use std::path::Path;

use super::header::{Element, PropertyKind, Scalar};
use super::vertex::{Field, VertexLayout};
use crate::IoError;
use crate::builder::CloudBuilder;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ByteOrder {
    Little,
    Big,
}

/// Decodes one scalar at `at`; `None` when it would run past the end.
fn decode(bytes: &[u8], at: usize, scalar: Scalar, order: ByteOrder) -> Option<f64> {
    macro_rules! read {
        ($t:ty) => {{
            let end = at.checked_add(size_of::<$t>())?;
            let raw = bytes.get(at..end)?.try_into().ok()?;
            match order {
                ByteOrder::Little => <$t>::from_le_bytes(raw),
                ByteOrder::Big => <$t>::from_be_bytes(raw),
            }
        }};
    }
    Some(match scalar {
        Scalar::I8 => read!(i8).into(),
        Scalar::U8 => read!(u8).into(),
        Scalar::I16 => read!(i16).into(),
        Scalar::U16 => read!(u16).into(),
        Scalar::I32 => read!(i32).into(),
        Scalar::U32 => read!(u32).into(),
        Scalar::F32 => read!(f32).into(),
        Scalar::F64 => read!(f64),
    })
}

/// The body of one file being decoded.
pub(crate) struct Body<'a> {
    pub path: &'a Path,
    pub bytes: &'a [u8],
    pub order: ByteOrder,
}

impl Body<'_> {
    /// Skips the elements before the vertex element, then decodes the vertices. Returns them
    /// and the byte offset after them; elements after them are not looked at here.
    pub(crate) fn read_vertices(
        &self,
        body_start: usize,
        elements: &[Element],
        vertex_index: usize,
        layout: &VertexLayout,
    ) -> Result<(CloudBuilder, usize), IoError> {
        let mut pos = body_start;
        for element in elements.iter().take(vertex_index) {
            pos = self.skip_element(element, pos)?;
        }
        let vertex = elements.get(vertex_index).ok_or_else(|| IoError::invalid(self.path, "no 'vertex' element"))?;
        self.ensure_room(vertex, pos)?;
        match vertex.fixed_size() {
            Some(size) => Ok((self.read_fixed_vertices(vertex, pos, size, layout)?, pos + vertex.count * size)),
            None => self.read_variable_vertices(vertex, pos, layout),
        }
    }

    /// From `pos`, the start of element `from`, skips to element `target` and hands the items
    /// of list property `list` of each of its records to `visit`, which may refuse them.
    pub(crate) fn for_each_list(
        &self,
        mut pos: usize,
        elements: &[Element],
        (from, target, list): (usize, usize, usize),
        mut visit: impl FnMut(usize, &[f64]) -> Result<(), String>,
    ) -> Result<(), IoError> {
        for element in &elements[from..target] {
            pos = self.skip_element(element, pos)?;
        }
        let element = &elements[target];
        self.ensure_room(element, pos)?;
        let mut items = Vec::new();
        for index in 0..element.count {
            let start = pos;
            pos = self.walk_record(element, index, pos, None, Some((list, &mut items)))?;
            visit(index, &items).map_err(|message| {
                IoError::at_byte(self.path, start, format!("{} {index}: {message}", element.name))
            })?;
        }
        Ok(())
    }

    /// Refuses counts the rest of the file cannot hold, before anything is allocated.
    fn ensure_room(&self, element: &Element, pos: usize) -> Result<(), IoError> {
        let remaining = self.bytes.len().saturating_sub(pos);
        let min_size = element.min_size();
        if min_size == 0 || element.count.checked_mul(min_size).is_some_and(|n| n <= remaining) {
            return Ok(());
        }
        if element.fixed_size().is_some() {
            Err(self.truncated(element, remaining / min_size))
        } else {
            Err(IoError::at_byte(
                self.path,
                pos,
                format!(
                    "element '{}' declares {} records of at least {min_size} bytes, but only {remaining} bytes remain",
                    element.name, element.count
                ),
            ))
        }
    }

    fn truncated(&self, element: &Element, index: usize) -> IoError {
        IoError::at_byte(
            self.path,
            self.bytes.len(),
            format!("file ends inside {} {index} of {}", element.name, element.count),
        )
    }

    fn skip_element(&self, element: &Element, pos: usize) -> Result<usize, IoError> {
        self.ensure_room(element, pos)?;
        if let Some(size) = element.fixed_size() {
            // ensure_room proved count * size fits in the remaining bytes.
            return Ok(pos + element.count * size);
        }
        let mut pos = pos;
        for index in 0..element.count {
            pos = self.walk_record(element, index, pos, None, None)?;
        }
        Ok(pos)
    }

    /// Steps over one record that may contain lists, storing scalar values into `values`
    /// (indexed by property) and the items of list property `list.0` into `list.1`, when
    /// given. Returns the position after the record.
    fn walk_record(
        &self,
        element: &Element,
        index: usize,
        mut pos: usize,
        mut values: Option<&mut [f64]>,
        mut list: Option<(usize, &mut Vec<f64>)>,
    ) -> Result<usize, IoError> {
        for (property_index, property) in element.properties.iter().enumerate() {
            let start = pos;
            match property.kind {
                PropertyKind::Scalar(scalar) => {
                    let value =
                        decode(self.bytes, pos, scalar, self.order).ok_or_else(|| self.truncated(element, index))?;
                    if let Some(slot) = values.as_deref_mut().and_then(|v| v.get_mut(property_index)) {
                        *slot = value;
                    }
                    pos += scalar.size();
                }
                PropertyKind::List { count, item } => {
                    let length =
                        decode(self.bytes, pos, count, self.order).ok_or_else(|| self.truncated(element, index))?;
                    if length < 0.0 {
                        return Err(IoError::at_byte(
                            self.path,
                            start,
                            format!("{} {index}: negative length {length} for list '{}'", element.name, property.name),
                        ));
                    }
                    // Integer count types hold at most u32::MAX, exact in f64 and usize.
                    let items_start = pos + count.size();
                    pos = (length as usize)
                        .checked_mul(item.size())
                        .and_then(|n| n.checked_add(items_start))
                        .filter(|&end| end <= self.bytes.len())
                        .ok_or_else(|| self.truncated(element, index))?;
                    if let Some((_, items)) = list.as_mut().filter(|(wanted, _)| *wanted == property_index) {
                        items.clear();
                        // In bounds: the whole list was checked to end before the file does.
                        let decoded = (items_start..pos).step_by(item.size());
                        items.extend(decoded.filter_map(|at| decode(self.bytes, at, item, self.order)));
                    }
                }
            }
        }
        Ok(pos)
    }

    /// The fast path: every record has the same size, so each field sits at a fixed offset.
    fn read_fixed_vertices(
        &self,
        vertex: &Element,
        start: usize,
        size: usize,
        layout: &VertexLayout,
    ) -> Result<CloudBuilder, IoError> {
        let offsets = field_offsets(vertex, &layout.used_fields());
        let mut values = vec![0.0; vertex.properties.len()];
        let mut builder = CloudBuilder::new(vertex.count, layout.attributes());
        for index in 0..vertex.count {
            let base = start + index * size;
            for &(field, offset) in &offsets {
                let value = decode(self.bytes, base + offset, field.scalar, self.order)
                    .ok_or_else(|| self.truncated(vertex, index))?;
                if let Some(slot) = values.get_mut(field.index) {
                    *slot = value;
                }
            }
            builder.push(&layout.record(&values));
        }
        Ok(builder)
    }

    fn read_variable_vertices(
        &self,
        vertex: &Element,
        start: usize,
        layout: &VertexLayout,
    ) -> Result<(CloudBuilder, usize), IoError> {
        let mut values = vec![0.0; vertex.properties.len()];
        let mut builder = CloudBuilder::new(vertex.count, layout.attributes());
        let mut pos = start;
        for index in 0..vertex.count {
            pos = self.walk_record(vertex, index, pos, Some(&mut values), None)?;
            builder.push(&layout.record(&values));
        }
        Ok((builder, pos))
    }
}

/// A binary file's fixed-size vertex records, decoded one at a time (for reading a file in
/// windows, `super::VertexStream`).
pub(crate) struct FixedRecords {
    offsets: Vec<(Field, usize)>,
    order: ByteOrder,
    pub(crate) size: usize,
    values: Vec<f64>,
}

impl FixedRecords {
    pub(crate) fn new(vertex: &Element, size: usize, layout: &VertexLayout, order: ByteOrder) -> Self {
        let offsets = field_offsets(vertex, &layout.used_fields());
        Self { offsets, order, size, values: vec![0.0; vertex.properties.len()] }
    }

    /// The record in `bytes` (`size` of them), as [`VertexLayout::record`] makes it.
    pub(crate) fn decode(&mut self, bytes: &[u8], layout: &VertexLayout) -> PointRecord {
        for &(field, offset) in &self.offsets {
            let value = decode(bytes, offset, field.scalar, self.order).unwrap_or(f64::NAN);
            if let Some(slot) = self.values.get_mut(field.index) {
                *slot = value;
            }
        }
        layout.record(&self.values)
    }
}

/// Byte offset of each wanted field within a fixed-size record.
fn field_offsets(element: &Element, fields: &[Field]) -> Vec<(Field, usize)> {
    let mut offsets = Vec::with_capacity(element.properties.len());
    let mut offset = 0;
    for property in &element.properties {
        offsets.push(offset);
        if let PropertyKind::Scalar(scalar) = property.kind {
            offset += scalar.size();
        }
    }
    fields.iter().filter_map(|&field| Some((field, *offsets.get(field.index)?))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_both_byte_orders_and_refuses_to_run_past_the_end() {
        let bytes = [0x01, 0x02, 0x03, 0x04];
        assert_eq!(decode(&bytes, 0, Scalar::U16, ByteOrder::Little), Some(513.0));
        assert_eq!(decode(&bytes, 0, Scalar::U16, ByteOrder::Big), Some(258.0));
        assert_eq!(decode(&bytes, 3, Scalar::I8, ByteOrder::Big), Some(4.0));
        assert_eq!(decode(&bytes, 1, Scalar::F32, ByteOrder::Little), None);
        assert_eq!(decode(&bytes, usize::MAX, Scalar::F64, ByteOrder::Little), None);
    }
}
