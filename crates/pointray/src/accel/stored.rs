//! The arrays an accelerator reads and never resizes, built in memory or borrowed from bytes
//! that something else keeps (a memory-mapped scene file, `pointray_io::prs`), behind one slice
//! type, so that a traversal reads either at the cost of a `Vec`'s: a pointer and a length.
//!
//! Borrowed arrays are checked once, when made (length, alignment); their element types are
//! plain data (`bytemuck::AnyBitPattern`), so any bytes are a value, and whatever structure
//! they must have (child indices in range, a bounded depth) their owner checks
//! (`Bvh::from_stored`). A safe view through `bytemuck::try_cast_slice` at every access would
//! repeat both checks in the traversal's inner loop: this module is the one place where the
//! pointer is kept instead (`unsafe`, with what makes it sound beside each block).

use std::ops::Range;
use std::ptr::NonNull;
use std::sync::Arc;

use bytemuck::{AnyBitPattern, NoUninit};

/// Bytes that stay where they are, unchanged, as long as their owner lives: a memory map, a
/// buffer never resized; or a file fetched by ranges as it is read (a scene file on an object
/// store or HTTP server), whose bytes arrive where [`StableBytes::fetch`] is asked for them.
///
/// # Safety
/// Every call of [`StableBytes::bytes`] on one value returns the same slice (address and
/// length), valid for as long as the value lives, and nothing writes to those bytes meanwhile,
/// but `fetch`: it may write bytes it has not yet made present (from zero to their value),
/// never a present one, and returns once those asked for are present. Readers of fetched bytes ask for them first (`Bvh::from_stored`
/// for the top, `Bvh::enter` for a treelet, the ids' check, `Scene::stored` for everything),
/// behind a `OnceLock` that orders the fetch before every read.
#[allow(unsafe_code)]
pub unsafe trait StableBytes: Send + Sync {
    fn bytes(&self) -> &[u8];

    /// Makes `ranges` of the bytes present before their first read; the problem where they
    /// cannot be had. Bytes at hand (a map, a buffer) need nothing.
    fn fetch(&self, _ranges: &[Range<usize>]) -> Result<(), String> {
        Ok(())
    }
}

/// An array of `T` that an accelerator reads: its own, or a range of shared bytes.
pub struct Stored<T> {
    ptr: NonNull<T>,
    len: usize,
    owner: Owner<T>,
}

/// What keeps a [`Stored`] array's memory alive.
enum Owner<T> {
    Vec(Vec<T>),
    Bytes(Arc<dyn StableBytes>),
}

/// Why bytes are not an array of the type asked for.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum StoredError {
    #[error("bytes {start}..{end} lie outside the {len} bytes given")]
    OutOfRange { start: usize, end: usize, len: usize },
    #[error("{len} bytes are not a whole number of {size}-byte elements")]
    Length { len: usize, size: usize },
    #[error("byte {start} is not {align}-byte aligned")]
    Alignment { start: usize, align: usize },
}

impl<T: AnyBitPattern> Stored<T> {
    /// The elements in `range` of `owner`'s bytes (where it is a whole number of them, aligned).
    pub fn from_bytes(owner: Arc<dyn StableBytes>, range: Range<usize>) -> Result<Self, StoredError> {
        let bytes = owner.bytes();
        let (start, end) = (range.start, range.end);
        let within = bytes.get(range).ok_or(StoredError::OutOfRange { start, end, len: bytes.len() })?;
        let elements: &[T] = bytemuck::try_cast_slice(within).map_err(|e| match e {
            bytemuck::PodCastError::TargetAlignmentGreaterAndInputNotAligned => {
                StoredError::Alignment { start, align: align_of::<T>() }
            }
            _ => StoredError::Length { len: end - start, size: size_of::<T>() },
        })?;
        let (ptr, len) = (NonNull::from(elements).cast(), elements.len());
        Ok(Self { ptr, len, owner: Owner::Bytes(owner) })
    }
}

impl<T> Stored<T> {
    /// Where `elements` of this array lie in the bytes it borrows (none for its own), for
    /// [`StableBytes::fetch`].
    pub(crate) fn byte_range(&self, elements: Range<usize>) -> Option<Range<usize>> {
        let Owner::Bytes(owner) = &self.owner else { return None };
        let start = self.ptr.as_ptr() as usize - owner.bytes().as_ptr() as usize;
        Some(start + elements.start * size_of::<T>()..start + elements.end * size_of::<T>())
    }

    /// The bytes this array borrows, if any.
    pub(crate) fn owner(&self) -> Option<&Arc<dyn StableBytes>> {
        match &self.owner {
            Owner::Bytes(owner) => Some(owner),
            Owner::Vec(_) => None,
        }
    }
}

impl<T: NoUninit> Stored<T> {
    /// The array's bytes, as a scene file stores them.
    pub fn as_bytes(&self) -> &[u8] {
        bytemuck::cast_slice(self)
    }
}

impl<T> From<Vec<T>> for Stored<T> {
    fn from(mut vec: Vec<T>) -> Self {
        let (ptr, len) = (NonNull::new(vec.as_mut_ptr()).expect("a Vec's pointer is never null"), vec.len());
        Self { ptr, len, owner: Owner::Vec(vec) }
    }
}

impl<T> std::ops::Deref for Stored<T> {
    type Target = [T];

    #[inline(always)]
    #[allow(unsafe_code)]
    fn deref(&self) -> &[T] {
        // SAFETY: `ptr` and `len` describe the whole of the owner's elements, which `self`
        // keeps alive: a `Vec`'s heap buffer, which stays put when the `Vec` moves and which
        // nothing resizes (`modify` lends it as `&mut [T]`, then takes the pointer anew), or
        // `len` elements that `from_bytes` checked to lie, aligned, within bytes that
        // `StableBytes` promises stay valid and unchanged while their owner lives.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), self.len) }
    }
}

impl<T: Clone> Stored<T> {
    /// Lets `change` change the elements: in place where they are this array's own, else
    /// (borrowed) in a copy made its own first.
    pub fn modify<R>(&mut self, change: impl FnOnce(&mut [T]) -> R) -> R {
        if let Owner::Bytes(_) = self.owner {
            *self = Self::from(self.to_vec());
        }
        let Owner::Vec(vec) = &mut self.owner else { unreachable!("made its own above") };
        let changed = change(vec.as_mut_slice());
        // Taken again after the change, so that no use of the `&mut` outlives the pointer.
        self.ptr = NonNull::new(vec.as_mut_ptr()).expect("a Vec's pointer is never null");
        changed
    }
}

impl<T: Clone> Clone for Stored<T> {
    fn clone(&self) -> Self {
        match &self.owner {
            Owner::Vec(vec) => Self::from(vec.clone()),
            Owner::Bytes(bytes) => Self { ptr: self.ptr, len: self.len, owner: Owner::Bytes(Arc::clone(bytes)) },
        }
    }
}

impl<T: std::fmt::Debug> std::fmt::Debug for Stored<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

// SAFETY: a `Stored<T>` is a `&[T]` into memory it owns (a `Vec<T>`, which is `Send` and
// `Sync` as `T` is) or shares immutably (`StableBytes` is `Send + Sync` and unchanging): sending
// or sharing it sends or shares `T`s only for reading, or (`modify`) through `&mut self`.
#[allow(unsafe_code)]
unsafe impl<T: Send + Sync> Send for Stored<T> {}
// SAFETY: as for `Send`.
#[allow(unsafe_code)]
unsafe impl<T: Sync> Sync for Stored<T> {}

/// Bytes in a `Vec` of 64-byte-aligned chunks, for arrays of any of the accelerators' types
/// (tests, and scene files read into memory where they cannot be mapped).
pub struct AlignedBytes {
    chunks: Vec<Chunk>,
    len: usize,
}

#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
struct Chunk([u8; 64]);

impl AlignedBytes {
    /// A copy of `bytes`, starting on a 64-byte boundary.
    pub fn copy_of(bytes: &[u8]) -> Self {
        let mut chunks = vec![Chunk([0; 64]); bytes.len().div_ceil(64)];
        bytemuck::cast_slice_mut::<Chunk, u8>(&mut chunks)[..bytes.len()].copy_from_slice(bytes);
        Self { chunks, len: bytes.len() }
    }
}

// SAFETY: the chunks are never resized or written after `copy_of`, and `bytes` always returns
// the first `len` bytes of their one buffer.
#[allow(unsafe_code)]
unsafe impl StableBytes for AlignedBytes {
    fn bytes(&self) -> &[u8] {
        &bytemuck::cast_slice::<Chunk, u8>(&self.chunks)[..self.len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shared(values: &[u32]) -> Arc<dyn StableBytes> {
        Arc::new(AlignedBytes::copy_of(bytemuck::cast_slice(values)))
    }

    #[test]
    fn an_array_reads_the_same_from_a_vec_and_from_bytes() {
        let values: Vec<u32> = (0..100).map(|i| i * 7).collect();
        let owned = Stored::from(values.clone());
        let borrowed = Stored::<u32>::from_bytes(shared(&values), 40..400).expect("aligned and whole");
        assert_eq!(&*owned, &values[..]);
        assert_eq!(&*borrowed, &values[10..]);
        assert_eq!(borrowed.as_bytes(), bytemuck::cast_slice::<u32, u8>(&values[10..]));
        // Clones and moves read the same.
        let moved = [owned.clone(), borrowed.clone()];
        assert_eq!((&*moved[0], &*moved[1]), (&values[..], &values[10..]));
        // Sent to another thread, read there.
        let sum = std::thread::spawn(move || borrowed.iter().map(|&v| u64::from(v)).sum::<u64>()).join().unwrap();
        assert_eq!(sum, values[10..].iter().map(|&v| u64::from(v)).sum::<u64>());
    }

    #[test]
    fn bytes_out_of_range_unaligned_or_ragged_are_refused() {
        let bytes = shared(&[1, 2, 3, 4]);
        let err = |r: Range<usize>| Stored::<u32>::from_bytes(Arc::clone(&bytes), r).err();
        assert_eq!(err(0..20), Some(StoredError::OutOfRange { start: 0, end: 20, len: 16 }));
        assert_eq!(err(2..10), Some(StoredError::Alignment { start: 2, align: 4 }));
        assert_eq!(err(4..10), Some(StoredError::Length { len: 6, size: 4 }));
        assert_eq!(err(16..16).map(|_| ()), None, "an empty array is an array");
    }

    #[test]
    fn changing_a_borrowed_array_changes_a_copy() {
        let bytes = shared(&[1, 2, 3, 4]);
        let mut a = Stored::<u32>::from_bytes(Arc::clone(&bytes), 0..16).unwrap();
        a.modify(|a| a[0] = 9);
        assert_eq!(&*a, &[9, 2, 3, 4]);
        assert_eq!(bytes.bytes()[0], 1, "the shared bytes are untouched");
        let mut b = Stored::from(vec![5u32, 6]);
        b.modify(|b| b[1] = 7);
        assert_eq!(&*b, &[5, 7]);
    }
}
