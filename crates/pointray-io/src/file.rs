//! A file's bytes for the parsers: memory-mapped, so that a multi-gigabyte binary PLY is
//! parsed straight from the page cache without a second copy in memory.

use std::fs::File;
use std::io::Read;
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

/// Opens `path` and maps it. Pipes and other files that cannot be mapped are read, unless
/// `regular_only` (a scan set's scans: a `.conf` line must not make us read `/dev/zero` or
/// wait on a FIFO). An empty file is an error.
pub(crate) fn read_file(path: &Path, regular_only: bool) -> Result<FileBytes, IoError> {
    let io_error = |e| IoError::io(path, e);
    let mut file = File::open(path).map_err(io_error)?;
    let regular = file.metadata().map_err(io_error)?.is_file();
    if regular_only && !regular {
        return Err(IoError::invalid(path, "not a regular file"));
    }
    let bytes = match regular.then(|| map(&file)).and_then(Result::ok) {
        Some(map) => FileBytes::Mapped(map),
        None => {
            let mut bytes = Vec::new();
            file.read_to_end(&mut bytes).map_err(io_error)?;
            FileBytes::Read(bytes)
        }
    };
    if bytes.is_empty() {
        return Err(IoError::invalid(path, "file is empty"));
    }
    Ok(bytes)
}

#[allow(unsafe_code)]
fn map(file: &File) -> std::io::Result<memmap2::Mmap> {
    // SAFETY: the slice is valid only while no one changes the file: another process writing
    // to it during a parse breaks the guarantees of `&[u8]` (undefined behaviour; in practice
    // wrong values), and truncating it ends this process with SIGBUS. pointray never writes
    // a file it reads (outputs are new files renamed into place), and a map lives no longer
    // than one parse; for everything else this is the documented risk of reading a file that
    // another program is rewriting. (memmap2 maps an empty file as an empty slice.)
    let map = unsafe { memmap2::Mmap::map(file) }?;
    #[cfg(unix)]
    let _ = map.advise(memmap2::Advice::Sequential);
    Ok(map)
}
