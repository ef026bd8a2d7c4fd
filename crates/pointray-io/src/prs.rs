//! The prepared scene file (`.prs`, `docs/prs.md`): a scene's BVH, splats and level-of-detail
//! data included, in one file laid out to be memory-mapped, so that a render opens it without
//! a build and reads only what its view needs.
//!
//! Layout (little-endian): a 64-byte header; each part's arrays ([`SCENE_ARRAYS`]; one part,
//! or a two-level scene's several) on page boundaries ([`PAGE`]); then the index (a 32-byte
//! entry an array: name, offset, length) and the scene's metadata as JSON. The header's CRC covers the header, the index and the metadata, which are
//! checked at open; the arrays carry their own CRCs, a treelet's checked as a walk first enters
//! it (`pointray::accel::Bvh::from_stored`), the ids' as a query first names a point.

use std::io::Read;
use std::path::Path;
use std::sync::Arc;

use pointray::Scene;
use pointray::accel::stored::{AlignedBytes, StableBytes};
use pointray::scene::{PartRanges, SCENE_ARRAYS, SceneMeta, StoredScene};

use crate::IoError;
use crate::fetched::{FETCH_GRAIN, FetchedFile, RangeReader};

/// The file's first bytes: PNG's pattern (a high byte, then line ends and a DOS end-of-file
/// that a text-mode transfer would change).
pub const MAGIC: [u8; 8] = *b"\x89PRS\r\n\x1a\n";

/// The format this build writes and reads (2: a scene in parts).
pub const VERSION: u32 = 2;

/// Arrays start on multiples of this (a memory page; also every element's alignment).
pub const PAGE: usize = 4096;

const HEADER: usize = 64;
const ENTRY: usize = 32;

/// Writes `scene` to `path` (all or nothing).
pub fn write_prs(path: &Path, scene: &Scene) -> Result<(), IoError> {
    let (parts, meta) = scene.stored().map_err(|e| IoError::invalid(path, format!("cannot store the scene: {e}")))?;
    let mut ranges: Vec<PartRanges> = Vec::new();
    for arrays in &parts {
        ranges.push(layout(arrays.each_ref().map(|a| a.len()), arrays_end(&ranges)));
    }
    let (header, index) = tail(path, &ranges, &meta)?;
    crate::atomic_write(path, |w| {
        let zeros = vec![0; PAGE];
        w.write_all(&header[..HEADER])?;
        let mut written = HEADER;
        for (array, range) in parts.iter().flatten().zip(ranges.iter().flatten()) {
            w.write_all(&zeros[..range.start - written])?;
            w.write_all(array)?;
            written = range.end;
        }
        w.write_all(&zeros[..arrays_end(&ranges) - written])?;
        w.write_all(&index)
    })
}

/// Where a part's arrays of these byte lengths lie in a scene file: each on a page boundary,
/// from `at` (a page boundary).
pub(crate) fn layout(lengths: [usize; 7], mut at: usize) -> PartRanges {
    lengths.map(|len| {
        let start = at;
        at = (start + len).next_multiple_of(PAGE);
        start..start + len
    })
}

/// Where the arrays after these parts start (the index, after the last part): the page after
/// the last array, or after the header's page.
pub(crate) fn arrays_end(ranges: &[PartRanges]) -> usize {
    ranges.last().map_or(PAGE, |r| r[6].end.next_multiple_of(PAGE))
}

/// The header (its 64 bytes) and what follows the arrays (the index, then the metadata) of a
/// scene file whose arrays lie in `ranges`.
pub(crate) fn tail(path: &Path, ranges: &[PartRanges], meta: &SceneMeta) -> Result<(Vec<u8>, Vec<u8>), IoError> {
    let meta = serde_json::to_vec(meta).map_err(|e| IoError::invalid(path, format!("cannot store the scene: {e}")))?;
    let mut index = Vec::new();
    for (name, range) in ranges.iter().flat_map(|r| SCENE_ARRAYS.iter().zip(r)) {
        index.extend_from_slice(&name_field(name));
        index.extend_from_slice(&(range.start as u64).to_le_bytes());
        index.extend_from_slice(&(range.len() as u64).to_le_bytes());
    }
    let index_at = arrays_end(ranges);
    let meta_at = index_at + index.len();
    let end = meta_at + meta.len();
    let mut header = Vec::with_capacity(HEADER);
    header.extend_from_slice(&MAGIC);
    header.extend_from_slice(&VERSION.to_le_bytes());
    header.extend_from_slice(&(PAGE as u32).to_le_bytes());
    for value in [index_at, index.len(), meta_at, meta.len(), end] {
        header.extend_from_slice(&(value as u64).to_le_bytes());
    }
    let crc = header_crc(&header, &index, &meta);
    header.extend_from_slice(&crc.to_le_bytes());
    header.resize(HEADER, 0);
    index.extend_from_slice(&meta);
    Ok((header, index))
}

/// Whether `path` is a regular file that starts as a scene file does (a pipe is never read
/// here: its bytes are the cloud reader's).
pub fn is_prs(path: &Path) -> bool {
    let mut start = [0; 8];
    let file = std::fs::File::open(path).ok().filter(|f| f.metadata().is_ok_and(|m| m.is_file()));
    file.is_some_and(|mut f| f.read_exact(&mut start).is_ok() && start == MAGIC)
}

/// Opens the scene file at `path`: mapped, its header, index and metadata checked, and the
/// top of its tree; the rest is read (and checked) where a view needs it.
pub fn open_prs(path: &Path) -> Result<StoredScene, IoError> {
    let map = crate::file::map_stable(path)?;
    let bytes: Arc<dyn StableBytes> = match &map {
        Some(map) => Arc::clone(map) as Arc<dyn StableBytes>,
        None => {
            let mut read = Vec::new();
            std::fs::File::open(path).and_then(|mut f| f.read_to_end(&mut read)).map_err(|e| IoError::io(path, e))?;
            Arc::new(AlignedBytes::copy_of(&read))
        }
    };
    if let Some(map) = &map {
        map.read_as_asked();
    }
    open_bytes(path, bytes)
}

/// Opens the scene file `name` (a URL, say, as errors name it) of `len` bytes that `reader`
/// reads by ranges, fetching what opening checks; the rest is fetched (and checked) where a
/// view or a query reads it (`crate::fetched`).
pub fn open_prs_fetched(name: &str, len: u64, reader: Box<dyn RangeReader>) -> Result<StoredScene, IoError> {
    open_in_grains(name, len, reader, FETCH_GRAIN)
}

fn open_in_grains(name: &str, len: u64, reader: Box<dyn RangeReader>, grain: u64) -> Result<StoredScene, IoError> {
    let path = Path::new(name);
    let bytes = FetchedFile::new(len, reader, grain).map_err(|e| IoError::io(path, e))?;
    open_bytes(path, Arc::new(bytes))
}

fn open_bytes(path: &Path, bytes: Arc<dyn StableBytes>) -> Result<StoredScene, IoError> {
    let invalid = |message: String| IoError::invalid(path, message);
    let (meta, ranges) = check(&*bytes).map_err(invalid)?;
    StoredScene::new(meta, bytes, ranges).map_err(|e| invalid(format!("not a scene pointray can render: {e}")))
}

/// The metadata and the arrays' ranges of a scene file's bytes (the header, index and
/// metadata fetched, where they are), everything checked but the scene's own structure; the
/// problem otherwise.
fn check(source: &dyn StableBytes) -> Result<(SceneMeta, Vec<PartRanges>), String> {
    let bytes = source.bytes();
    let unread = |e: String| format!("could not be read: {e}");
    source.fetch(std::slice::from_ref(&(0..HEADER.min(bytes.len())))).map_err(unread)?;
    if bytes.len() < HEADER || bytes[..8] != MAGIC {
        return Err("not a pointray scene file (.prs)".into());
    }
    // The arrays are the little-endian machine's own bytes, read in place.
    if cfg!(target_endian = "big") {
        return Err("scene files are read on little-endian machines only: render the cloud".into());
    }
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"));
    let version = u32_at(8);
    if version != VERSION {
        return Err(format!("scene file format {version}; this pointray reads format {VERSION}: prepare it again"));
    }
    let [index_at, index_len, meta_at, meta_len, end] = [16, 24, 32, 40, 48].map(u64_at);
    if end != bytes.len() as u64 {
        return Err(format!("truncated or extended: {} bytes where the header says {end}", bytes.len()));
    }
    let span = |at: u64, len: u64| {
        let start = usize::try_from(at).ok().filter(|&s| s <= bytes.len());
        start.and_then(|s| Some(s..s.checked_add(usize::try_from(len).ok()?)?)).filter(|r| r.end <= bytes.len())
    };
    let (Some(index), Some(meta)) = (span(index_at, index_len), span(meta_at, meta_len)) else {
        return Err("its header points outside the file".into());
    };
    source.fetch(&[index.clone(), meta.clone()]).map_err(unread)?;
    let (index, meta) = (&bytes[index], &bytes[meta]);
    if header_crc(&bytes[..56], index, meta) != u32_at(56) {
        return Err("its header, index or metadata is damaged (CRC mismatch)".into());
    }
    let ranges = arrays(bytes, index)?;
    let meta: SceneMeta = serde_json::from_slice(meta).map_err(|e| format!("its metadata: {e}"))?;
    Ok((meta, ranges))
}

/// The arrays the index names (each part's in turn), where it says.
fn arrays(bytes: &[u8], index: &[u8]) -> Result<Vec<PartRanges>, String> {
    let part = SCENE_ARRAYS.len() * ENTRY;
    if index.is_empty() || !index.len().is_multiple_of(part) {
        return Err(format!("its index holds {} bytes, not a multiple of {part}", index.len()));
    }
    index.chunks(part).map(|entries| part_arrays(bytes, entries)).collect()
}

/// A part's arrays, where its index `entries` say.
fn part_arrays(bytes: &[u8], entries: &[u8]) -> Result<PartRanges, String> {
    let mut ranges: PartRanges = Default::default();
    for (i, name) in SCENE_ARRAYS.iter().enumerate() {
        let entry = &entries[i * ENTRY..(i + 1) * ENTRY];
        if entry[..16] != name_field(name) {
            return Err(format!(
                "its index names {:?} where the {name} array belongs",
                String::from_utf8_lossy(&entry[..16])
            ));
        }
        let field = |at: usize| usize::try_from(u64::from_le_bytes(entry[at..at + 8].try_into().expect("8 bytes")));
        let (start, len) = (field(16).unwrap_or(usize::MAX), field(24).unwrap_or(usize::MAX));
        let range = start..start.saturating_add(len);
        if start % PAGE != 0 || range.end > bytes.len() {
            return Err(format!("the {name} array lies at {start}, {len} bytes: outside the file or off a page"));
        }
        ranges[i] = range;
    }
    Ok(ranges)
}

/// An array's name as its index entry holds it: zero-padded to 16 bytes.
fn name_field(name: &str) -> [u8; 16] {
    let mut field = [0; 16];
    field[..name.len()].copy_from_slice(name.as_bytes());
    field
}

/// The CRC of the header's first 56 bytes, the index and the metadata.
fn header_crc(header: &[u8], index: &[u8], meta: &[u8]) -> u32 {
    let mut crc = crc32fast::Hasher::new();
    crc.update(&header[..56]);
    crc.update(index);
    crc.update(meta);
    crc.finalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use pointray::preprocess::{PreprocessConfig, preprocess};
    use pointray::{Settings, render};

    fn scene() -> Scene {
        let mut cloud = pointray::demo::demo_cloud(3_000, 7);
        preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        Scene::build(pointray::demo::demo_scene_parts(cloud), &Settings::default()).unwrap()
    }

    fn image(scene: &Scene) -> Vec<u8> {
        let settings = Settings { width: 40, height: 32, ..Settings::default() };
        render(scene, &settings).unwrap().srgb8(settings.tone_map())
    }

    /// The demo cloud of `points` as a two-level scene of parts and chunks of at most
    /// `part_splats` and `chunk_splats`.
    fn scene_in_parts(points: usize, chunk_splats: usize, part_splats: usize) -> Scene {
        let mut cloud = pointray::demo::demo_cloud(points, 9);
        preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        let limits = pointray::scene::BuildLimits { chunk_splats, part_splats };
        let parts = pointray::demo::demo_scene_parts(cloud);
        Scene::build_with_limits(parts, &Settings::default(), limits).unwrap()
    }

    fn opened(path: &Path) -> Result<Scene, IoError> {
        let parts = pointray::SceneParts { stored: Some(open_prs(path)?), ..Default::default() };
        Ok(Scene::build(parts, &Settings::default()).expect("a checked scene builds"))
    }

    #[test]
    fn a_scene_file_renders_the_scene_it_stores() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("demo.prs");
        let scene = scene();
        write_prs(&path, &scene).unwrap();
        assert!(is_prs(&path));
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes[..8], MAGIC);
        assert_eq!(image(&opened(&path).unwrap()), image(&scene));
    }

    /// A two-level scene (here parts of at most 1,000 splats) is stored part by part, each
    /// in its frame, and renders and answers queries as it did.
    #[test]
    fn a_scene_in_parts_is_stored_part_by_part() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("parts.prs");
        let scene = scene_in_parts(6_000, 500, 1_000);
        write_prs(&path, &scene).unwrap();
        let meta = open_prs(&path).unwrap().meta().clone();
        assert!(meta.parts.len() >= 4, "{} parts", meta.parts.len());
        assert!(meta.parts.iter().all(|p| p.offset != [0.0; 3]));
        let back = opened(&path).unwrap();
        assert_eq!(image(&back), image(&scene));
        let center = scene.origin() + scene.bounds().center().as_dvec3();
        let rays: Vec<_> = (0..64)
            .map(|i| {
                (center + glam::DVec3::new((i % 8) as f64 - 3.5, 10.0, (i / 8) as f64 - 3.5) * 0.2, -glam::Vec3::Y)
            })
            .collect();
        let hits = back.intersect(&rays, &Settings::default()).unwrap();
        assert!(hits.iter().flatten().count() > 10);
        assert_eq!(hits, scene.intersect(&rays, &Settings::default()).unwrap());
    }

    /// Damage to the header, index, metadata or top is refused at open, with the file's name
    /// and what is wrong; damage below the top when a render or a query first reads it.
    #[test]
    fn damaged_truncated_and_foreign_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("good.prs");
        write_prs(&good, &scene()).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let damaged = |name: &str, edit: &dyn Fn(&mut Vec<u8>)| {
            let mut damaged = bytes.clone();
            edit(&mut damaged);
            let path = dir.path().join(name);
            std::fs::write(&path, &damaged).unwrap();
            path
        };
        let refused = |name: &str, edit: &dyn Fn(&mut Vec<u8>)| {
            let message = opened(&damaged(name, edit)).err().expect("refused").to_string();
            assert!(message.contains(name), "{message}");
            message
        };
        let field = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()) as usize;
        let (index_at, meta_at) = (field(16), field(32));
        let array = |i: usize| {
            field(index_at + i * ENTRY + 16)..field(index_at + i * ENTRY + 16) + field(index_at + i * ENTRY + 24)
        };
        assert!(refused("cut.prs", &|b| b.truncate(b.len() - 100)).contains("truncated"));
        assert!(refused("short.prs", &|b| b.truncate(40)).contains("not a pointray scene file"));
        assert!(refused("root.prs", &|b| b[PAGE + 3] ^= 1).contains("top is damaged"));
        assert!(refused("meta.prs", &|b| b[meta_at + 5] ^= 1).contains("CRC"));
        assert!(refused("index.prs", &|b| b[index_at + 20] ^= 1).contains("CRC"));
        let newer = refused("newer.prs", &|b| b[8] = 3);
        assert!(newer.contains("format 3") && newer.contains("prepare it again"), "{newer}");
        assert!(!is_prs(&dir.path().join("missing.prs")));
        std::fs::write(dir.path().join("cloud.prs"), "ply\nformat ascii 1.0\n").unwrap();
        assert!(!is_prs(&dir.path().join("cloud.prs")));
        // Every block damaged: the render that reads them fails, as the query reading the ids.
        let blocks = array(2);
        let scene =
            opened(&damaged("blocks.prs", &|b| (blocks.start..blocks.end).step_by(176).for_each(|i| b[i + 3] ^= 1)))
                .expect("the top is whole");
        let err = render(&scene, &Settings { width: 40, height: 32, ..Settings::default() }).unwrap_err().to_string();
        assert!(err.contains("damaged") && err.contains("CRC"), "{err}");
        let ids = array(6);
        let scene = opened(&damaged("ids.prs", &|b| b[ids.end - 1] ^= 1)).expect("the top is whole");
        assert_eq!(image(&scene), image(&self::scene()), "a render reads no id");
        let center = scene.origin() + scene.bounds().center().as_dvec3();
        let err = scene.intersect(&[(center + glam::DVec3::Y * 10.0, -glam::Vec3::Y)], &Settings::default());
        assert!(err.is_err_and(|e| e.to_string().contains("ids")));
    }

    /// A scene file's bytes served by ranges from memory, as a remote store would serve them:
    /// the ranges asked for recorded, and every request failing while `down`.
    #[derive(Clone, Default)]
    struct Served {
        bytes: Arc<Vec<u8>>,
        asked: Arc<std::sync::Mutex<Vec<std::ops::Range<u64>>>>,
        down: Arc<std::sync::atomic::AtomicBool>,
    }

    impl RangeReader for Served {
        fn read(&self, ranges: &[std::ops::Range<u64>]) -> Result<Vec<Vec<u8>>, String> {
            if self.down.load(std::sync::atomic::Ordering::Relaxed) {
                return Err("503 Service Unavailable".into());
            }
            self.asked.lock().unwrap().extend_from_slice(ranges);
            Ok(ranges.iter().map(|r| self.bytes[r.start as usize..r.end as usize].to_vec()).collect())
        }
    }

    impl Served {
        fn set_down(&self, down: bool) {
            self.down.store(down, std::sync::atomic::Ordering::Relaxed);
        }

        /// The bytes asked for so far, checking that no byte was asked for twice.
        fn asked_once(&self) -> u64 {
            let mut asked = self.asked.lock().unwrap().clone();
            asked.sort_by_key(|r| r.start);
            assert!(asked.windows(2).all(|w| w[0].end <= w[1].start), "a byte fetched twice");
            asked.iter().map(|r| r.end - r.start).sum()
        }

        /// The scene this file is, fetched a page at a time (small beside a 64 kB grain).
        fn open(&self) -> Result<Scene, IoError> {
            let name = "https://example.org/parts.prs";
            let stored = open_in_grains(name, self.bytes.len() as u64, Box::new(self.clone()), PAGE as u64)?;
            let parts = pointray::SceneParts { stored: Some(stored), ..Default::default() };
            Ok(Scene::build(parts, &Settings::default()).expect("a checked scene builds"))
        }
    }

    /// Fetched by ranges (an object store, an HTTP server), a scene file opens with its top
    /// alone, a distant view reads a few treelets, and every render and query is the mapped
    /// file's, no byte fetched twice; what cannot be fetched fails the open, or the render and
    /// the scene's later renders, as damage does, until the file is opened again.
    #[test]
    fn a_scene_file_fetched_by_ranges_is_the_mapped_one_read_as_needed() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("parts.prs");
        write_prs(&path, &scene_in_parts(40_000, 5_000, 20_000)).unwrap();
        let served = Served { bytes: Arc::new(std::fs::read(&path).unwrap()), ..Served::default() };
        let (mapped, remote) = (opened(&path).unwrap(), served.open().unwrap());
        let (file, at_open) = (served.bytes.len() as u64, served.asked_once());
        assert!(at_open < file / 4, "opening fetched {at_open} of {file} bytes");
        let far = Settings { width: 24, height: 24, distance: Some(5.0), ..Settings::default() };
        assert_eq!(image_with(&remote, &far), image_with(&mapped, &far));
        let after_far = served.asked_once();
        // Some treelets, not all (here 173 kB at open, 497 kB of 1.6 MB after the view).
        assert!(after_far > at_open && after_far < file / 2, "a far view fetched {after_far} of {file}");
        let close = Settings { width: 48, height: 40, lod_threshold: 0.0, ..Settings::default() };
        assert_eq!(image_with(&remote, &close), image_with(&mapped, &close));
        let center = mapped.origin() + mapped.bounds().center().as_dvec3();
        let rays = [(center + glam::DVec3::Y * 10.0, -glam::Vec3::Y), (center + glam::DVec3::X * 10.0, -glam::Vec3::X)];
        let hits = remote.intersect(&rays, &Settings::default()).unwrap();
        assert!(hits.iter().flatten().count() == 2);
        assert_eq!(hits, mapped.intersect(&rays, &Settings::default()).unwrap());
        assert!(served.asked_once() > after_far);
        // Stored again straight after its open, it is fetched whole first: the same file.
        let again = Served { bytes: Arc::clone(&served.bytes), ..Served::default() };
        write_prs(&dir.path().join("again.prs"), &again.open().unwrap()).unwrap();
        assert!(std::fs::read(dir.path().join("again.prs")).unwrap() == *served.bytes, "the file, byte for byte");
        assert_eq!(again.asked_once(), file);
        // The source down midway: the render fails, naming what it could not read, and so does
        // every later render of that scene (kept as damage); opened again, it is whole.
        let midway = Served { bytes: Arc::clone(&served.bytes), ..Served::default() };
        let scene = midway.open().unwrap();
        midway.set_down(true);
        let err = render(&scene, &close).unwrap_err().to_string();
        assert!(err.contains("could not be read: 503"), "{err}");
        midway.set_down(false);
        let again = render(&scene, &close).unwrap_err().to_string();
        assert!(again.contains("could not be read: 503"), "{again}");
        assert_eq!(image_with(&midway.open().unwrap(), &close), image_with(&mapped, &close));
        // Down at open; not a scene file.
        let down = Served { bytes: Arc::clone(&served.bytes), ..Served::default() };
        down.set_down(true);
        let err = down.open().err().expect("refused").to_string();
        assert!(err.contains("https://example.org/parts.prs") && err.contains("503"), "{err}");
        let foreign = Served { bytes: Arc::new(b"ply\nformat ascii 1.0\n".repeat(8)), ..Served::default() };
        let err = foreign.open().err().expect("refused").to_string();
        assert!(err.contains("not a pointray scene file"), "{err}");
    }

    fn image_with(scene: &Scene, settings: &Settings) -> Vec<u8> {
        render(scene, settings).unwrap().srgb8(settings.tone_map())
    }

    #[test]
    fn only_what_a_lone_cloud_makes_is_stored() {
        let dir = tempfile::tempdir().unwrap();
        let mut cloud = pointray::demo::demo_cloud(1_000, 8);
        preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        let settings = Settings { accel: pointray::settings::AccelKind::Brute, ..Settings::default() };
        let scene = Scene::build(cloud.into(), &settings).unwrap();
        let path = dir.path().join("brute.prs");
        let err = write_prs(&path, &scene).unwrap_err().to_string();
        assert!(err.contains("only a BVH") && err.contains("brute.prs"), "{err}");
        assert!(!path.exists(), "no partial file");
    }
}
