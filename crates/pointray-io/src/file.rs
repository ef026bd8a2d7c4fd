//! A file's bytes for the parsers: memory-mapped, so that a multi-gigabyte binary PLY is
//! parsed straight from the page cache without a second copy in memory.

use std::fs::File;
use std::path::Path;

use crate::IoError;

/// The whole content of a file: mapped where the system allows it, else read.
pub(crate) enum FileBytes {
    Mapped(memmap2::Mmap),
    Read(Vec<u8>),
}

impl AsRef<[u8]> for FileBytes {
    fn as_ref(&self) -> &[u8] {
        match self {
            FileBytes::Mapped(map) => map,
            FileBytes::Read(bytes) => bytes,
        }
    }
}

impl std::ops::Deref for FileBytes {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        self.as_ref()
    }
}

/// Opens `path` and maps it; pipes and other files that cannot be mapped are read. An
/// empty file is an error.
pub(crate) fn read_file(path: &Path) -> Result<FileBytes, IoError> {
    let io_error = |e| IoError::io(path, e);
    let file = File::open(path).map_err(io_error)?;
    let regular = file.metadata().map_err(io_error)?.is_file();
    let bytes = match regular.then(|| map(&file)).and_then(Result::ok) {
        Some(map) => FileBytes::Mapped(map),
        None => FileBytes::Read(std::fs::read(path).map_err(io_error)?),
    };
    if bytes.is_empty() {
        return Err(IoError::invalid(path, "file is empty"));
    }
    Ok(bytes)
}

#[allow(unsafe_code)]
fn map(file: &File) -> std::io::Result<memmap2::Mmap> {
    // SAFETY: the map is only read, and lives no longer than one parse. The one hazard is
    // another process truncating the file while it is parsed, which ends this process with
    // SIGBUS; a file that changes while it is read cannot be read correctly any other way
    // either. (memmap2 maps an empty file as an empty slice.)
    let map = unsafe { memmap2::Mmap::map(file) }?;
    #[cfg(unix)]
    let _ = map.advise(memmap2::Advice::Sequential);
    Ok(map)
}
