//! A scene file that is no local file (on an object store, an HTTP server: the Python
//! package's fsspec reader), fetched by ranges as the scene reads it: opening fetches the
//! header, index, metadata and the tree's top, a view the treelets it enters, a query the ids
//! (`StableBytes::fetch`; `docs/prs.md`). What arrives is written into a sparse temporary file
//! (in `TMPDIR`) as long as the source, mapped as a local scene file is, so that the traversal
//! reads it as it reads any: on a disk the kernel may drop its pages and read them back; on a
//! tmpfs they stay in memory.

use std::fs::File;
use std::ops::Range;
use std::sync::{Condvar, Mutex, MutexGuard};

use pointray::accel::stored::StableBytes;

use crate::file::{StableMap, map_for_reading};

/// What a fetch rounds its ranges out to (multiples of it): neighbouring treelets lie near
/// in the file and a view enters several, so that one request brings what would have been
/// several. Measured over HTTP on this machine (`scripts/fetched_scene.py`): the dragon at
/// 512², 374 requests for 12.1 MB in 1.9 s byte-exact, 0.30 s for 13.6 MB at 64 kB, 0.16 s for
/// 13.1 MB at 256 kB; a distant view of the 300-million-point torus (10.7 GB) 1.1 MB past the
/// top byte-exact, 3.5 MB at 64 kB, 9.2 MB at 256 kB.
pub(crate) const FETCH_GRAIN: u64 = 64 << 10;

/// Where a scene file's bytes come from, by ranges.
pub trait RangeReader: Send + Sync {
    /// The bytes of each of `ranges`, in order (each as long as its range), or the problem.
    fn read(&self, ranges: &[Range<u64>]) -> Result<Vec<Vec<u8>>, String>;
}

/// A source's bytes, fetched as asked for (see the module).
pub(crate) struct FetchedFile {
    map: StableMap,
    /// What fetches round their ranges out to ([`FETCH_GRAIN`] but in tests).
    grain: u64,
    file: File,
    reader: Box<dyn RangeReader>,
    state: Mutex<Fetching>,
    arrived: Condvar,
}

/// Which bytes a fetch has claimed (is fetching or fetched) and which are present.
#[derive(Default)]
struct Fetching {
    claimed: RangeSet,
    present: RangeSet,
}

impl FetchedFile {
    /// A source of `len` bytes read through `reader` in multiples of `grain`, none fetched yet.
    pub(crate) fn new(len: u64, reader: Box<dyn RangeReader>, grain: u64) -> std::io::Result<Self> {
        let file = tempfile::tempfile()?;
        file.set_len(len)?;
        let map = map_for_reading(&file)?;
        map.read_as_asked();
        Ok(Self { map, grain, file, reader, state: Mutex::default(), arrived: Condvar::new() })
    }

    fn lock(&self) -> MutexGuard<'_, Fetching> {
        self.state.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Reads `ranges` from the source into the file.
    fn read_into(&self, ranges: &[Range<u64>]) -> Result<(), String> {
        let read = self.reader.read(ranges)?;
        if read.len() != ranges.len() {
            return Err(format!("{} ranges asked for, {} returned", ranges.len(), read.len()));
        }
        for (range, bytes) in ranges.iter().zip(&read) {
            if bytes.len() as u64 != range.end - range.start {
                let (start, end, len) = (range.start, range.end, bytes.len());
                return Err(format!("bytes {start}..{end} asked for, {len} returned (the file changed?)"));
            }
            write_at(&self.file, bytes, range.start).map_err(|e| format!("the local copy: {e}"))?;
        }
        Ok(())
    }
}

// SAFETY: `bytes` is the map of `file` made in `new`, which is never remapped, resized or
// truncated (the file is this value's own, unnamed). The one writer is `fetch`, which writes
// only bytes it holds the claim on (claims, taken under the lock, never overlap), marks them
// present once written and never writes a present byte again; a failed fetch lets its claim
// go, and the next writes those bytes anew, still unread. `fetch` returns once every byte asked
// for is present. Readers ask for bytes before they read them and read them only once the
// fetch returned: the top at open (`Bvh::from_stored`), a treelet behind the `OnceLock` of
// its check, which runs after its fetch (`Bvh::enter`), the ids behind theirs, a scene stored
// again after every treelet's and the ids' checks (`Scene::stored`); so no read meets a write.
#[allow(unsafe_code)]
unsafe impl StableBytes for FetchedFile {
    fn bytes(&self) -> &[u8] {
        self.map.bytes()
    }

    fn fetch(&self, ranges: &[Range<usize>]) -> Result<(), String> {
        let len = self.bytes().len();
        if let Some(r) = ranges.iter().find(|r| r.start > r.end || r.end > len) {
            return Err(format!("bytes {}..{} lie outside the file's {len}", r.start, r.end));
        }
        let grain = self.grain;
        let down = |at: usize| at as u64 / grain * grain;
        let up = |at: usize| (at as u64).div_ceil(grain).saturating_mul(grain).min(len as u64);
        let wanted: Vec<Range<u64>> =
            ranges.iter().filter(|r| !r.is_empty()).map(|r| down(r.start)..up(r.end)).collect();
        loop {
            let mut state = self.lock();
            let mine = loop {
                if state.present.missing(&wanted).is_empty() {
                    return Ok(());
                }
                let unclaimed = state.claimed.missing(&wanted);
                if !unclaimed.is_empty() {
                    break unclaimed;
                }
                // Another fetch is bringing what is left.
                state = self.arrived.wait(state).unwrap_or_else(std::sync::PoisonError::into_inner);
            };
            mine.iter().for_each(|r| state.claimed.insert(r.clone()));
            drop(state);
            // A reader that panics must not leave its claim for others to wait on forever.
            let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.read_into(&mine)));
            let result = read.unwrap_or_else(|_| Err("the reader panicked".into()));
            let mut state = self.lock();
            for r in &mine {
                match result {
                    Ok(()) => state.present.insert(r.clone()),
                    Err(_) => state.claimed.remove(r.clone()),
                }
            }
            self.arrived.notify_all();
            result?;
        }
    }
}

#[cfg(unix)]
fn write_at(file: &File, bytes: &[u8], at: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::write_all_at(file, bytes, at)
}

#[cfg(windows)]
fn write_at(file: &File, mut bytes: &[u8], mut at: u64) -> std::io::Result<()> {
    while !bytes.is_empty() {
        let n = std::os::windows::fs::FileExt::seek_write(file, bytes, at)?;
        (bytes, at) = (&bytes[n..], at + n as u64);
    }
    Ok(())
}

/// Disjoint ranges, sorted, none empty and no two touching.
#[derive(Default, Debug, PartialEq)]
struct RangeSet(Vec<Range<u64>>);

impl RangeSet {
    fn insert(&mut self, r: Range<u64>) {
        if r.is_empty() {
            return;
        }
        // The ranges touching or overlapping `r` are merged with it.
        let first = self.0.partition_point(|s| s.end < r.start);
        let last = self.0.partition_point(|s| s.start <= r.end);
        let merged = self.0[first..last].iter().fold(r, |m, s| m.start.min(s.start)..m.end.max(s.end));
        self.0.splice(first..last, [merged]);
    }

    fn remove(&mut self, r: Range<u64>) {
        if r.is_empty() {
            return;
        }
        let first = self.0.partition_point(|s| s.end <= r.start);
        let last = self.0.partition_point(|s| s.start < r.end);
        if first >= last {
            return;
        }
        let (lo, hi) = (self.0[first].start, self.0[last - 1].end);
        let kept: Vec<_> = [lo..r.start, r.end..hi].into_iter().filter(|k| !k.is_empty()).collect();
        self.0.splice(first..last, kept);
    }

    /// The parts of `ranges` outside the set (merged where they touch).
    fn missing(&self, ranges: &[Range<u64>]) -> Vec<Range<u64>> {
        let mut out = RangeSet::default();
        for r in ranges {
            let mut at = r.start;
            for s in &self.0[self.0.partition_point(|s| s.end <= r.start)..] {
                if s.start >= r.end {
                    break;
                }
                if s.start > at {
                    out.insert(at..s.start);
                }
                at = at.max(s.end);
            }
            if at < r.end {
                out.insert(at..r.end);
            }
        }
        out.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering::Relaxed};

    /// Bytes `i % 251` served slowly, counting what is asked for; the `fail`th request fails.
    struct Slow {
        asked: Arc<AtomicU64>,
        requests: AtomicUsize,
        fail: usize,
    }

    impl RangeReader for Slow {
        fn read(&self, ranges: &[Range<u64>]) -> Result<Vec<Vec<u8>>, String> {
            std::thread::sleep(std::time::Duration::from_millis(2));
            if self.requests.fetch_add(1, Relaxed) == self.fail {
                return Err("timed out".into());
            }
            self.asked.fetch_add(ranges.iter().map(|r| r.end - r.start).sum(), Relaxed);
            Ok(ranges.iter().map(|r| r.clone().map(|i| (i % 251) as u8).collect()).collect())
        }
    }

    /// Threads asking at once for overlapping ranges get the source's bytes, each fetched
    /// once; a failed fetch fails its caller alone and is fetched again by the next.
    #[test]
    fn overlapping_fetches_from_many_threads_read_each_byte_once() {
        let asked = Arc::new(AtomicU64::new(0));
        let reader = Slow { asked: Arc::clone(&asked), requests: AtomicUsize::new(0), fail: 3 };
        let file = FetchedFile::new(100_000, Box::new(reader), 100).unwrap();
        let failed = AtomicUsize::new(0);
        std::thread::scope(|s| {
            for t in 0..8usize {
                let (file, failed) = (&file, &failed);
                s.spawn(move || {
                    for k in 0..20 {
                        let at = (t * 3_000 + k * 1_700) % 90_000;
                        let ranges = [at..at + 5_000, (at + 7_000) % 90_000..(at + 7_000) % 90_000 + 100];
                        match file.fetch(&ranges) {
                            Ok(()) => ranges.iter().flat_map(|r| r.clone()).for_each(|i| {
                                assert_eq!(file.bytes()[i], (i % 251) as u8, "byte {i}");
                            }),
                            Err(e) => {
                                assert_eq!(e, "timed out");
                                failed.fetch_add(1, Relaxed);
                            }
                        }
                    }
                });
            }
        });
        assert_eq!(failed.load(Relaxed), 1);
        let present = &file.lock().present;
        let fetched: u64 = present.0.iter().map(|r| r.end - r.start).sum();
        assert_eq!(asked.load(Relaxed), fetched, "no byte fetched twice");
        assert!(fetched > 50_000, "{fetched}");
        assert!(file.fetch(std::slice::from_ref(&(99_000..100_001))).is_err_and(|e| e.contains("outside")));
    }

    #[test]
    fn a_range_set_merges_splits_and_finds_what_it_lacks() {
        let mut set = RangeSet::default();
        set.insert(10..20);
        set.insert(30..40);
        set.insert(20..25);
        assert_eq!(set.0, vec![10..25, 30..40]);
        assert_eq!(set.missing(std::slice::from_ref(&(0..50))), vec![0..10, 25..30, 40..50]);
        assert_eq!(set.missing(&[12..18, 32..33]), Vec::<Range<u64>>::new());
        assert_eq!(set.missing(&[24..31, 5..11]), vec![5..10, 25..30]);
        set.insert(22..35);
        assert_eq!(set.0, vec![10..40]);
        set.remove(15..18);
        assert_eq!(set.0, vec![10..15, 18..40]);
        set.remove(0..12);
        set.remove(39..50);
        assert_eq!(set.0, vec![12..15, 18..39]);
        set.remove(14..19);
        assert_eq!(set.0, vec![12..14, 19..39]);
        set.remove(0..100);
        assert_eq!(set.0, Vec::<Range<u64>>::new());
        set.remove(0..100);
        set.insert(5..5);
        assert_eq!(set, RangeSet::default());
    }
}
