//! A file's bytes for the parsers: memory-mapped, so that a multi-gigabyte binary PLY is
//! parsed straight from the page cache without a second copy in memory.

use std::fs::File;
use std::io::Read;
use std::path::Path;

use std::sync::Arc;

use pointray::accel::stored::StableBytes;

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
    let bytes = match regular.then(|| map(&file, memmap2::Advice::Sequential)).and_then(Result::ok) {
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

/// `path` memory-mapped for reading where it lies, as bytes a scene keeps (a `.prs` file's
/// arrays), to be read through first (the kernel reads ahead); none where it is no regular
/// file or cannot be mapped.
pub(crate) fn map_stable(path: &Path) -> Result<Option<Arc<StableMap>>, IoError> {
    let file = File::open(path).map_err(|e| IoError::io(path, e))?;
    let regular = file.metadata().map_err(|e| IoError::io(path, e))?.is_file();
    let map = regular.then(|| map(&file, memmap2::Advice::Sequential)).and_then(Result::ok);
    Ok(map.map(|map| Arc::new(StableMap(map))))
}

/// `file` (open for reading) mapped, as bytes a scene may keep.
pub(crate) fn map_for_reading(file: &File) -> std::io::Result<StableMap> {
    map(file, memmap2::Advice::Random).map(StableMap)
}

/// A map lent to a scene as its arrays.
pub(crate) struct StableMap(memmap2::Mmap);

impl StableMap {
    /// From now on read only the pages asked for, as a traversal asks for them.
    pub(crate) fn read_as_asked(&self) {
        #[cfg(unix)]
        let _ = self.0.advise(memmap2::Advice::Random);
    }
}

// SAFETY: a map's slice is the same address and length for as long as it lives (it is never
// remapped), and it is read-only here; that no one else writes the file meanwhile is the
// documented risk of `map` below, which a scene file shares with every mapped input.
#[allow(unsafe_code)]
unsafe impl StableBytes for StableMap {
    fn bytes(&self) -> &[u8] {
        &self.0
    }
}

#[allow(unsafe_code)]
fn map(file: &File, advice: memmap2::Advice) -> std::io::Result<memmap2::Mmap> {
    // SAFETY: the slice is valid only while no one changes the file: another process writing
    // to it during a parse breaks the guarantees of `&[u8]` (undefined behaviour; in practice
    // wrong values), and truncating it ends this process with SIGBUS. pointray never writes
    // a file it reads (outputs are new files renamed into place, so a scene file prepared
    // again leaves the mapped one whole), and a map lives no longer than one parse, or a scene
    // file's than its scene; for everything else this is the documented risk of reading a file
    // that another program is rewriting. (memmap2 maps an empty file as an empty slice.)
    let map = unsafe { memmap2::Mmap::map(file) }?;
    #[cfg(unix)]
    let _ = map.advise(advice);
    Ok(map)
}
