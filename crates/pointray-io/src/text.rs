//! Line splitting shared by the text formats (PLY header, ascii PLY body, XYZ).

/// Splits bytes into lines, numbering them from `first_line`. `\r\n` and `\n` both end a
/// line; the final line needs no terminator. Works on bytes so that a binary body after a
/// PLY header, or garbage, never has to be valid UTF-8.
pub(crate) struct Lines<'a> {
    rest: &'a [u8],
    next_line: usize,
    /// Byte offset of `rest` within the slice the iterator was made from.
    offset: usize,
}

impl<'a> Lines<'a> {
    pub(crate) fn new(bytes: &'a [u8], first_line: usize) -> Self {
        Self { rest: bytes, next_line: first_line, offset: 0 }
    }

    /// Number the next line returned will have (or would have, at the end).
    pub(crate) fn next_line_number(&self) -> usize {
        self.next_line
    }

    /// Bytes consumed so far.
    pub(crate) fn offset(&self) -> usize {
        self.offset
    }

    /// Bytes not yet consumed.
    pub(crate) fn remaining(&self) -> usize {
        self.rest.len()
    }

    /// The next line that is not blank, for formats that tolerate stray empty lines.
    pub(crate) fn next_non_blank(&mut self) -> Option<(usize, &'a [u8])> {
        self.find(|(_, line)| !line.iter().all(u8::is_ascii_whitespace))
    }
}

impl<'a> Iterator for Lines<'a> {
    /// (1-based line number, line without its terminator)
    type Item = (usize, &'a [u8]);

    fn next(&mut self) -> Option<Self::Item> {
        if self.rest.is_empty() {
            return None;
        }
        let (line, consumed) = match self.rest.iter().position(|&b| b == b'\n') {
            Some(end) => (&self.rest[..end], end + 1),
            None => (self.rest, self.rest.len()),
        };
        self.rest = &self.rest[consumed..];
        self.offset += consumed;
        let number = self.next_line;
        self.next_line += 1;
        Some((number, line.strip_suffix(b"\r").unwrap_or(line)))
    }
}

/// A line as text, or `None` when it is not UTF-8 (then it cannot hold numbers anyway).
pub(crate) fn as_text(line: &[u8]) -> Option<&str> {
    std::str::from_utf8(line).ok()
}

/// The values of a line, split at commas and whitespace.
pub(crate) fn split_values(text: &str) -> Vec<&str> {
    text.split(|c: char| c == ',' || c.is_ascii_whitespace()).filter(|t| !t.is_empty()).collect()
}

/// The data lines of a text format, as (line number, the data before any `#`): blank and
/// comment lines skipped, whole-line comments collected into `comments`, a line that is not
/// UTF-8 an error naming it.
pub(crate) fn data_lines<'a>(
    path: &'a std::path::Path,
    bytes: &'a [u8],
    comments: &'a mut Vec<String>,
) -> impl Iterator<Item = Result<(usize, &'a str), crate::IoError>> + 'a {
    Lines::new(bytes, 1).filter_map(move |(number, line)| {
        let Some(text) = as_text(line) else {
            return Some(Err(crate::IoError::at_line(path, number, "line is not text")));
        };
        if let Some(comment) = text.trim_start().strip_prefix('#') {
            comments.push(comment.trim().to_string());
            return None;
        }
        data_part(text).map(|data| Ok((number, data)))
    })
}

/// The first word of the first data line: the keyword a text format opens with.
pub(crate) fn first_word(bytes: &[u8]) -> Option<&str> {
    let first = Lines::new(bytes, 1).find_map(|(_, line)| as_text(line).and_then(data_part))?;
    first.split_whitespace().next()
}

/// The data part of a line (before any `#`), or `None` for blank and comment-only lines.
pub(crate) fn data_part(text: &str) -> Option<&str> {
    let data = text.split('#').next().unwrap_or("").trim();
    (!data.is_empty()).then_some(data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_lf_and_crlf_and_unterminated_last_line() {
        let lines: Vec<_> = Lines::new(b"a\r\nb\n\nc", 1).collect();
        assert_eq!(lines, vec![(1, &b"a"[..]), (2, &b"b"[..]), (3, &b""[..]), (4, &b"c"[..])]);
    }

    #[test]
    fn skips_blank_lines_on_request() {
        let mut lines = Lines::new(b"\n  \r\nx\n", 10);
        assert_eq!(lines.next_non_blank(), Some((12, &b"x"[..])));
        assert_eq!(lines.next_non_blank(), None);
        assert_eq!(lines.offset(), 7);
    }
}
