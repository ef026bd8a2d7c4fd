//! The BVH as a scene file keeps it (`pointray_io::prs`): its five arrays as bytes and its
//! scalars as [`BvhMeta`]; and back, from bytes that stay mapped, checked so that no stored
//! value can send a traversal out of its arrays or past its stack ([`Bvh::from_stored`]).

use std::ops::Range;
use std::sync::Arc;

use super::lod::{NodeAggregate, NodeLod};
use super::{Bvh, LEAF, MAX_DEPTH, MAX_SPLATS, Node, SLOTS, WIDTH, leaf_blocks};
use crate::accel::Accel;
use crate::accel::block::{BLOCK, SplatBlock};
use crate::accel::stored::{StableBytes, Stored, StoredError};
use crate::math::Aabb;
use crate::splat::DiskShape;

use super::lod::NodeBounds;

/// The BVH's scalars.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BvhMeta {
    pub splat_count: usize,
    /// The splats' bounds: minimum, maximum.
    pub bounds: [[f32; 3]; 2],
    pub depth: usize,
    pub node_bounds: NodeBounds,
    pub shape: DiskShape,
    pub lod_floor: f32,
    pub wide_radius: f32,
    /// Found when the file was written, so that a prefiltered render of it reads no splat to
    /// find it.
    pub coverage_density: f32,
}

/// The BVH's arrays, in the order [`Bvh::arrays`] gives them and [`Bvh::from_stored`] takes them.
pub const ARRAYS: [&str; 5] = ["nodes", "lod", "blocks", "representatives", "aggregates"];

/// The largest alignment of the arrays' elements: where each must start in a file.
pub const ARRAY_ALIGN: usize = 64;

/// Why stored bytes are not a BVH.
#[derive(Debug, thiserror::Error)]
pub enum BvhStoredError {
    #[error("the {array} array: {source}")]
    Array { array: &'static str, source: StoredError },
    #[error("{0}")]
    Structure(String),
}

impl Bvh {
    /// The arrays' bytes (named as [`ARRAYS`]) and the scalars, to store.
    pub fn arrays(&self) -> ([&[u8]; 5], BvhMeta) {
        let b = self.bounds;
        let meta = BvhMeta {
            splat_count: self.splat_count,
            bounds: [b.min.to_array(), b.max.to_array()],
            depth: self.depth,
            node_bounds: self.node_bounds,
            shape: self.shape,
            lod_floor: self.lod_floor,
            wide_radius: self.wide_radius,
            coverage_density: self.coverage_density(),
        };
        let arrays = [
            self.nodes.as_bytes(),
            self.lod.as_bytes(),
            self.blocks.as_bytes(),
            self.representatives.as_bytes(),
            self.aggregates.as_bytes(),
        ];
        (arrays, meta)
    }

    /// The BVH whose arrays lie in `ranges` (in [`ARRAYS`]' order) of `bytes`, as
    /// [`Self::arrays`] gave them. Checked: the arrays' lengths agree, every child a node names
    /// lies after it and within the arrays, and no path is deeper than the traversals' stacks
    /// allow; the bounds, spheres and disks are taken as they are (a damaged value there draws
    /// wrong, which the file's checksums are for).
    pub fn from_stored(
        meta: BvhMeta,
        bytes: Arc<dyn StableBytes>,
        ranges: [Range<usize>; 5],
    ) -> Result<Bvh, BvhStoredError> {
        let [nodes, lod, blocks, representatives, aggregates] = ranges;
        let array = |i: usize, e: StoredError| BvhStoredError::Array { array: ARRAYS[i], source: e };
        let nodes = Stored::<Node>::from_bytes(Arc::clone(&bytes), nodes).map_err(|e| array(0, e))?;
        let lod = Stored::<NodeLod>::from_bytes(Arc::clone(&bytes), lod).map_err(|e| array(1, e))?;
        let blocks = Stored::<SplatBlock>::from_bytes(Arc::clone(&bytes), blocks).map_err(|e| array(2, e))?;
        let representatives =
            Stored::<SplatBlock>::from_bytes(Arc::clone(&bytes), representatives).map_err(|e| array(3, e))?;
        let aggregates = Stored::<NodeAggregate>::from_bytes(bytes, aggregates).map_err(|e| array(4, e))?;
        let [lo, hi] = meta.bounds;
        let bvh = Bvh {
            nodes,
            lod,
            blocks,
            representatives,
            aggregates,
            splat_count: meta.splat_count,
            bounds: Aabb::new(lo.into(), hi.into()),
            depth: meta.depth,
            node_bounds: meta.node_bounds,
            lod_floor: meta.lod_floor,
            wide_radius: meta.wide_radius,
            coverage_density: Box::new(meta.coverage_density.into()),
            shape: meta.shape,
        };
        check_structure(&bvh).map_err(BvhStoredError::Structure)?;
        Ok(bvh)
    }
}

/// What [`Bvh::from_stored`] checks (one pass over the nodes).
fn check_structure(bvh: &Bvh) -> Result<(), String> {
    let n = bvh.nodes.len();
    if [bvh.lod.len(), bvh.representatives.len(), bvh.aggregates.len()] != [n; 3] {
        return Err(format!(
            "{n} nodes but {} spheres, {} representative blocks and {} aggregates",
            bvh.lod.len(),
            bvh.representatives.len(),
            bvh.aggregates.len()
        ));
    }
    let (splats, capacity) = (bvh.splat_count, bvh.blocks.len() * BLOCK);
    if splats > MAX_SPLATS || splats > capacity || capacity > MAX_SPLATS + BLOCK || (n == 0) != (splats == 0) {
        return Err(format!("{splats} splats in {} blocks and {n} nodes", bvh.blocks.len()));
    }
    if bvh.depth > MAX_DEPTH {
        return Err(format!("depth {} beyond {MAX_DEPTH}", bvh.depth));
    }
    // Depth first, parents before children: each node's depth is known when it is reached.
    let mut depth = vec![u8::MAX; n];
    if let Some(root) = depth.first_mut() {
        *root = 1;
    }
    for (k, node) in bvh.nodes.iter().enumerate() {
        let d = depth[k];
        if d == u8::MAX {
            return Err(format!("node {k} has no parent before it"));
        }
        for i in (0..WIDTH).filter(|&i| node.used & SLOTS & (1 << i) != 0) {
            let child = node.child[i];
            if child & LEAF != 0 {
                if leaf_blocks(child).end > bvh.blocks.len() {
                    return Err(format!("node {k} child {i}: a leaf past the {} blocks", bvh.blocks.len()));
                }
                continue;
            }
            let c = child as usize;
            if c <= k || c >= n {
                return Err(format!("node {k} child {i}: node {c}, not after it among {n}"));
            }
            if usize::from(d) >= MAX_DEPTH {
                return Err(format!("node {c} lies deeper than {MAX_DEPTH} levels"));
            }
            depth[c] = d + 1;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::BvhParams;
    use crate::accel::stored::AlignedBytes;
    use crate::splat::Splat;
    use glam::Vec3;

    /// The arrays laid end to end, each on a 64-byte boundary, as a file would hold them.
    fn laid_out(bvh: &Bvh) -> (Arc<dyn StableBytes>, [Range<usize>; 5], BvhMeta) {
        let (arrays, meta) = bvh.arrays();
        let mut bytes = Vec::new();
        let ranges = arrays.map(|a| {
            bytes.resize(bytes.len().next_multiple_of(ARRAY_ALIGN), 0);
            let start = bytes.len();
            bytes.extend_from_slice(a);
            start..bytes.len()
        });
        (Arc::new(AlignedBytes::copy_of(&bytes)), ranges, meta)
    }

    fn sheet(n: usize) -> Vec<Splat> {
        (0..n * n)
            .map(|i| Splat {
                center: Vec3::new((i % n) as f32, (i / n) as f32, ((i * 7) % 5) as f32 * 0.1),
                radius: 0.8,
                normal: Vec3::Z,
                color: 0xff00_8040 + i as u32,
            })
            .collect()
    }

    #[test]
    fn a_stored_bvh_is_the_bvh_it_was() {
        let bvh = Bvh::build(sheet(40), &BvhParams::standard());
        let (bytes, ranges, meta) = laid_out(&bvh);
        let back = Bvh::from_stored(meta.clone(), bytes, ranges).expect("a BVH's own arrays");
        assert_eq!(back.arrays(), bvh.arrays());
        assert_eq!(meta.coverage_density, bvh.coverage_density());
        super::super::check_invariants(&back).expect("its invariants");
        let hits = |b: &Bvh| {
            let ray = crate::math::Ray::new(Vec3::new(10.3, 20.6, 5.0), -Vec3::Z, Default::default());
            let mut stats = crate::accel::TraversalStats::uncounted();
            crate::splat::scheme::intersect(b, &ray, &crate::splat::scheme::SurfaceScheme::sj(), &mut stats)
                .map(|h| (h.t.to_bits(), h.splat))
        };
        assert!(hits(&bvh).is_some());
        assert_eq!(hits(&back), hits(&bvh));
    }

    #[test]
    fn stored_bytes_that_are_no_bvh_are_refused() {
        let bvh = Bvh::build(sheet(30), &BvhParams::standard());
        let (arrays, _) = bvh.arrays();
        type Edit<'a> = dyn Fn(&mut Vec<u8>, &mut [Range<usize>; 5], &mut BvhMeta) + 'a;
        let refused = |edit: &Edit<'_>| {
            let (bytes, mut ranges, mut meta) = laid_out(&bvh);
            let mut raw = bytes.bytes().to_vec();
            edit(&mut raw, &mut ranges, &mut meta);
            Bvh::from_stored(meta, Arc::new(AlignedBytes::copy_of(&raw)), ranges).err().map(|e| e.to_string())
        };
        assert_eq!(refused(&|_, _, _| ()), None, "untouched");
        // A node's first child pointing back at the root (a cycle).
        let child0 = std::mem::offset_of!(Node, child);
        let err = refused(&|raw, r, _| raw[r[0].start + child0..][..4].copy_from_slice(&0u32.to_le_bytes()));
        assert!(err.as_deref().is_some_and(|e| e.contains("not after it")), "{err:?}");
        // A leaf past the blocks.
        let leaf = LEAF | (arrays[2].len() / size_of::<SplatBlock>()) as u32;
        let err = refused(&|raw, r, _| raw[r[0].start + child0..][..4].copy_from_slice(&leaf.to_le_bytes()));
        assert!(err.as_deref().is_some_and(|e| e.contains("past the")), "{err:?}");
        // Arrays of different lengths, a ragged one, a depth beyond the stack.
        let err = refused(&|_, r, _| r[1].end -= 64);
        assert!(err.as_deref().is_some_and(|e| e.contains("spheres")), "{err:?}");
        let err = refused(&|_, r, _| r[2].end -= 1);
        assert!(err.as_deref().is_some_and(|e| e.contains("blocks array")), "{err:?}");
        let err = refused(&|_, _, m| m.depth = MAX_DEPTH + 1);
        assert!(err.as_deref().is_some_and(|e| e.contains("depth")), "{err:?}");
        let err = refused(&|_, _, m| m.splat_count += 1000);
        assert!(err.as_deref().is_some_and(|e| e.contains("splats in")), "{err:?}");
    }
}
