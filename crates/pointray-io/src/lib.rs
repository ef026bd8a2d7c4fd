//! File formats for pointray: point clouds in (PLY, LAS/LAZ, PCD, XYZ text, Stanford scan sets), rendered
//! images out and back in (PNG).
//!
//! Every file is memory-mapped (or read, where it cannot be) and parsed from the byte slice; every error names
//! the file and, where there is one, the line or byte offset (see [`IoError`]). No input
//! makes a reader panic or allocate more than the file could describe.

pub mod env_map;
pub mod error;
pub mod image;
mod las;
mod obj;
mod off;
mod pcd;
pub mod ply;
pub mod prepare;
pub mod prs;
mod scanset;
pub mod scene;
pub mod source;
mod tiles;
pub mod video;
pub mod xyz;

mod builder;
mod e57;
pub mod fetched;
mod file;
mod text;

use std::io::Write;
use std::path::{Path, PathBuf};

pub use env_map::read_env_map;
pub use error::IoError;
use file::{FileBytes, read_file};
pub use image::{
    decode_png, encode_png, read_png, write_exr, write_png, write_png_rgba, write_png16, write_png16_rgba,
};
pub use ply::{Mesh, read_ply, write_ply, write_ply_with_axes};
pub use tiles::{read_tiles, set_name};
pub use xyz::{Column, TextColumns, read_xyz};

/// What a reader cannot learn from the file itself.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadOptions {
    /// The file is XYZ-like text with these columns (`--columns`), rather than whatever the
    /// content and the first line suggest.
    pub columns: Option<TextColumns>,
}

/// A cloud and what its file said about itself.
#[derive(Clone, Debug)]
pub struct LoadedCloud {
    pub cloud: pointray::PointCloud,
    pub info: FileInfo,
}

/// The file's description of itself, for `info`-style reporting.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FileInfo {
    /// e.g. `"PLY binary_little_endian 1.0"`, `"PLY ascii 1.0"`, `"XYZ text"`.
    pub format: String,
    /// Element names and counts in file order; `[("point", n)]` for XYZ.
    pub elements: Vec<(String, usize)>,
    /// Vertex property declarations as in the header, e.g. `"float x"`,
    /// `"list uchar int vertex_indices"`; bare column names for XYZ.
    pub vertex_properties: Vec<String>,
    /// PLY `comment` texts and whole `obj_info` lines; whole-line `#` comments for XYZ.
    pub comments: Vec<String>,
    pub file_bytes: u64,
    /// The up axis the file gives, where it gives one: +z for LAS, LAZ and E57 (surveys in
    /// east, north and height, levelled scans), a prepared PLY's `comment up`.
    pub up: Option<[f32; 3]>,
    /// The direction towards a default sun, where the data has a geography: [`SURVEY_SUN`] over
    /// an airborne survey (LAS, LAZ), a prepared PLY's `comment sun`.
    pub sun: Option<[f32; 3]>,
}

/// The sun a survey (x east, y north, z up) is lit by unless told otherwise: from the north-west
/// at 45°, the hillshade convention of GIS, so that relief reads as raised. (Not E57's scans,
/// which may be rooms.)
pub const SURVEY_SUN: [f32; 3] = [-0.5, 0.5, std::f32::consts::FRAC_1_SQRT_2];

/// What a prepared PLY records of the data beside its points (`comment up`, `comment sun`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Axes {
    pub up: Option<[f32; 3]>,
    pub sun: Option<[f32; 3]>,
}

/// Extensions taken as XYZ text even when the first line would not tell.
const XYZ_EXTENSIONS: [&str; 7] = ["xyz", "txt", "pts", "csv", "asc", "xyzn", "xyzrgb"];

/// Reads a PLY, LAS/LAZ, PCD or XYZ file or a Stanford scan set (`.conf`), recognised by
/// content: a file starting with the `ply` line is PLY; one starting with `LASF` is LAS or LAZ;
/// one whose header starts with `VERSION` or `FIELDS` is PCD; one whose first data line starts
/// with `camera` or `bmesh` a scan set, whose scans are read and merged; otherwise XYZ when the
/// extension says so or the first data line is all numbers.
pub fn read_cloud(path: &Path) -> Result<LoadedCloud, IoError> {
    read_cloud_with(path, &ReadOptions::default())
}

/// [`read_cloud`] told what the file does not say ([`ReadOptions`]).
pub fn read_cloud_with(path: &Path, options: &ReadOptions) -> Result<LoadedCloud, IoError> {
    if let Some(columns) = &options.columns {
        let bytes = read_file(path, false)?;
        let binary = bytes.starts_with(b"ply") || las::looks_like_las(&bytes) || pcd::looks_like_pcd(&bytes);
        if binary || e57::looks_like_e57(&bytes) {
            return Err(IoError::invalid(path, "text columns were named, but this is a PLY, LAS/LAZ, PCD or E57 file"));
        }
        return xyz::parse(path, &bytes, Some(columns));
    }
    read_any(path, true)
}

/// [`read_cloud`] for a file already in memory: `path` names it in errors, and gives the
/// extension hint and the folder a scan set's scans are read from.
pub fn parse_cloud(path: &Path, bytes: &[u8]) -> Result<LoadedCloud, IoError> {
    if bytes.is_empty() {
        return Err(IoError::invalid(path, "file is empty"));
    }
    parse_any(path, FileBytes::Read(bytes.to_vec()), true)
}

/// `read_cloud`, for a file named on the command line (`scan_sets`) or for a scan set's scan,
/// which must be a regular file holding a single cloud.
fn read_any(path: &Path, scan_sets: bool) -> Result<LoadedCloud, IoError> {
    parse_any(path, read_file(path, !scan_sets)?, scan_sets)
}

fn parse_any(path: &Path, bytes: FileBytes, scan_sets: bool) -> Result<LoadedCloud, IoError> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        return ply::parse(path, &bytes);
    }
    if las::looks_like_las(&bytes) {
        return las::parse(path, bytes);
    }
    if pcd::looks_like_pcd(&bytes) {
        return pcd::parse(path, &bytes);
    }
    if scanset::looks_like_conf(&bytes) {
        if !scan_sets {
            return Err(IoError::invalid(path, "a scan set cannot list another scan set"));
        }
        return scanset::parse(path, &bytes);
    }
    if e57::looks_like_e57(&bytes) {
        return e57::parse(path, &bytes);
    }
    if off::looks_like_off(&bytes) {
        return off::parse(path, &bytes);
    }
    if obj::looks_like_obj(&bytes) {
        return obj::parse(path, &bytes);
    }
    let extension = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    if extension.as_deref() == Some("ply") {
        return Err(IoError::invalid(path, "not a PLY file: it does not start with the line 'ply'"));
    }
    if extension.as_deref().is_some_and(|e| XYZ_EXTENSIONS.contains(&e)) || xyz::looks_like_xyz(&bytes) {
        return xyz::parse(path, &bytes, None);
    }
    Err(IoError::invalid(path, "unrecognised format: not PLY, LAS/LAZ, E57, PCD, OFF, OBJ, a scan set or XYZ text"))
}

/// Reads a triangle mesh: PLY (with a `face` element), OFF or OBJ, recognised by content.
/// Errors name the file, and the face and its line or byte offset for a vertex index that is
/// not an index of a vertex in the file.
pub fn read_mesh(path: &Path) -> Result<Mesh, IoError> {
    parse_mesh(path, &read_file(path, false)?)
}

/// [`read_mesh`] for a file already in memory (`path` names it in errors).
pub fn parse_mesh(path: &Path, bytes: &[u8]) -> Result<Mesh, IoError> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        ply::parse_mesh(path, bytes)
    } else if off::looks_like_off(bytes) {
        off::parse_mesh(path, bytes)
    } else if obj::looks_like_obj(bytes) {
        obj::parse_mesh(path, bytes)
    } else {
        Err(IoError::invalid(path, "not a mesh: PLY with faces, OFF or OBJ"))
    }
}

/// Writes `path` all or nothing: the closure writes (buffered) into a temporary file in the
/// same directory, which replaces `path` only after the closure succeeded and the data is
/// flushed and synced. On any failure the temporary file is removed and `path` is untouched,
/// so a crash or a full disk never leaves a half-written image or cloud behind. A process
/// ended by a signal runs no destructors: its handler calls
/// [`discard_unfinished_writes_then`].
pub fn atomic_write(path: &Path, write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<(), IoError> {
    atomic_file(path, |file| {
        let mut buffered = std::io::BufWriter::new(file);
        write(&mut buffered)?;
        buffered.flush()
    })
}

/// [`atomic_write`] for a writer that needs the file itself (to write at offsets, to map what
/// it wrote): the same guarantees.
pub fn atomic_file(path: &Path, write: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>) -> Result<(), IoError> {
    let io_error = |e: std::io::Error| IoError::io(path, e);
    let directory = match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    };
    let file_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let prefix = format!(".{file_name}.");
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".tmp");
    // The default 0600 would survive the rename; ask for what `File::create` gives.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    // Declared before the file so that it drops after it: the entry goes only once the
    // file is deleted or renamed.
    let mut registration = Unfinished(None);
    // Created and registered under the registry's lock, and renamed under it, so that an
    // interrupt finds every temporary file registered, and a write either pending or done.
    let mut temp = {
        let mut registry = registry();
        if registry.closed {
            return Err(io_error(interrupted()));
        }
        let temp = builder.tempfile_in(directory).map_err(io_error)?;
        registry.pending.push(temp.path().to_path_buf());
        registration.0 = Some(temp.path().to_path_buf());
        temp
    };
    write(temp.as_file_mut()).map_err(io_error)?;
    temp.as_file().sync_all().map_err(io_error)?;
    let mut registry = registry();
    if registry.closed {
        return Err(io_error(interrupted())); // its file is already gone
    }
    temp.persist(path).map_err(|e| io_error(e.error))?;
    if let Some(temp) = registration.0.take() {
        registry.pending.retain(|p| *p != temp);
    }
    Ok(())
}

/// A temporary directory beside the file `near` (a preparation's spilled data), removed when
/// dropped and, like an unfinished write's file, on an interrupt.
pub(crate) struct ScratchDir(Option<tempfile::TempDir>);

impl ScratchDir {
    pub(crate) fn beside(near: &Path) -> Result<Self, IoError> {
        let directory = near.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let mut registry = registry();
        if registry.closed {
            return Err(IoError::io(near, interrupted()));
        }
        let dir = tempfile::Builder::new()
            .prefix(".pointray-scratch.")
            .tempdir_in(directory)
            .map_err(|e| IoError::io(near, e))?;
        registry.pending.push(dir.path().to_path_buf());
        Ok(Self(Some(dir)))
    }

    pub(crate) fn path(&self) -> &Path {
        self.0.as_ref().expect("a scratch directory until dropped").path()
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let mut registry = registry();
        if let Some(dir) = self.0.take() {
            registry.pending.retain(|p| p != dir.path());
            if !registry.closed {
                drop(dir); // removed, under the lock as an interrupt would
            } else {
                std::mem::forget(dir); // an interrupt removed it
            }
        }
    }
}

/// The temporary files of [`atomic_write`]s in progress, and whether writing has stopped.
struct Registry {
    pending: Vec<PathBuf>,
    closed: bool,
}

static REGISTRY: std::sync::Mutex<Registry> = std::sync::Mutex::new(Registry { pending: Vec::new(), closed: false });

fn registry() -> std::sync::MutexGuard<'static, Registry> {
    // A writer that panicked leaves the registry as valid as before.
    REGISTRY.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn interrupted() -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::Interrupted, "interrupted: the process is ending")
}

/// One write's entry in [`REGISTRY`], removed when dropped.
struct Unfinished(Option<PathBuf>);

impl Drop for Unfinished {
    fn drop(&mut self) {
        if let Some(temp) = self.0.take() {
            registry().pending.retain(|p| *p != temp);
        }
    }
}

/// For a signal handler that ends the process: deletes the temporary file of every
/// [`atomic_write`] in progress (finished outputs are not touched), makes every later one
/// fail, and calls `exit` with the registry still locked, so that no write can finish, or fail
/// and report it, before the process ends.
pub fn discard_unfinished_writes_then(exit: impl FnOnce() -> std::convert::Infallible) -> ! {
    let mut registry = registry();
    for temp in registry.pending.drain(..) {
        let _ = if temp.is_dir() { std::fs::remove_dir_all(temp) } else { std::fs::remove_file(temp) };
    }
    registry.closed = true;
    match exit() {}
}
