//! The one error type of this crate.
//!
//! Every message starts with the file's path, then the place in the file when one applies:
//! `line N` (1-based) for text formats, `byte N` (0-based offset) for binary PLY bodies.
//! Record numbers inside messages (`vertex 17 of 100`) are 0-based, like PLY face indices.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The operating system refused a read, write or rename. The `io::Error` is part of the
    /// message rather than `source()`, so error chains do not print it twice.
    #[error("{}: {io}", .path.display())]
    Io { path: PathBuf, io: std::io::Error },

    /// A text file (PLY header, ascii PLY body, XYZ) is malformed at this line.
    #[error("{}: line {line}: {message}", .path.display())]
    AtLine { path: PathBuf, line: usize, message: String },

    /// A binary PLY body is malformed or truncated at this byte offset.
    #[error("{}: byte {offset}: {message}", .path.display())]
    AtByte { path: PathBuf, offset: u64, message: String },

    /// A problem that has no single location: unrecognised format, missing vertex element,
    /// inconsistent data handed to a writer.
    #[error("{}: {message}", .path.display())]
    Invalid { path: PathBuf, message: String },
}

impl IoError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            IoError::Io { path, .. }
            | IoError::AtLine { path, .. }
            | IoError::AtByte { path, .. }
            | IoError::Invalid { path, .. } => path,
        }
    }

    pub(crate) fn io(path: &Path, io: std::io::Error) -> Self {
        IoError::Io { path: path.to_path_buf(), io }
    }

    pub(crate) fn at_line(path: &Path, line: usize, message: impl Into<String>) -> Self {
        IoError::AtLine { path: path.to_path_buf(), line, message: message.into() }
    }

    pub(crate) fn at_byte(path: &Path, offset: usize, message: impl Into<String>) -> Self {
        IoError::AtByte { path: path.to_path_buf(), offset: offset as u64, message: message.into() }
    }

    pub(crate) fn invalid(path: &Path, message: impl Into<String>) -> Self {
        IoError::Invalid { path: path.to_path_buf(), message: message.into() }
    }
}
