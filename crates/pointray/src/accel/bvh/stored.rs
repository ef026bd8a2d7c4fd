//! The BVH as a scene file keeps it (`pointray_io::prs`): its arrays as bytes (its top's nodes
//! naming their treelets, see [`super::treelet`]) and its scalars as [`BvhMeta`]; and back, from
//! bytes that stay mapped. The top is checked when the tree is made (its CRC, and that its nodes
//! lead only to top nodes after them and to treelets); each treelet when a walk first enters it,
//! so that opening reads the top alone and a view the treelets it enters.

use std::borrow::Cow;
use std::ops::Range;
use std::sync::Arc;

use super::lod::{NodeAggregate, NodeLod};
use super::treelet::{Treelet, treelet_ref};
use super::{Bvh, MAX_DEPTH, MAX_SPLATS, Node};
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
    /// Nodes that test their children's spheres.
    pub sphere_nodes: usize,
    /// The nodes above the treelets, first in the node arrays.
    pub top_nodes: usize,
    /// CRC-32 of the top's bytes in the node arrays (nodes, spheres, representatives,
    /// aggregates) and of the treelet table.
    pub top_crc: u32,
}

/// The BVH's arrays, in the order [`Bvh::arrays`] gives them and [`Bvh::from_stored`] takes them.
pub const ARRAYS: [&str; 6] = ["nodes", "lod", "blocks", "representatives", "aggregates", "treelets"];

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
    /// The arrays' bytes (named as [`ARRAYS`]) and the scalars, to store: the top's nodes name
    /// their treelets, and each treelet carries its CRC.
    pub fn arrays(&self) -> ([Cow<'_, [u8]>; 6], BvhMeta) {
        let stored_top = self.lazy.is_some();
        let mut treelets = self.treelets.to_vec();
        let mut nodes: Cow<'_, [Node]> = Cow::Borrowed(&self.nodes);
        if !stored_top {
            let top = &mut nodes.to_mut()[..self.top_nodes];
            for (t, treelet) in treelets.iter_mut().enumerate() {
                top[treelet.parent as usize].child[treelet.slot as usize] = treelet_ref(t);
                treelet.crc = self.treelet_crc(treelet);
            }
        }
        let top = self.top_nodes;
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
            sphere_nodes: self.sphere_nodes,
            top_nodes: top,
            top_crc: top_crc(
                &nodes[..top],
                &self.lod[..top],
                &self.representatives[..top],
                &self.aggregates[..top],
                &treelets,
            ),
        };
        let arrays = [
            node_bytes(nodes),
            Cow::Borrowed(self.lod.as_bytes()),
            Cow::Borrowed(self.blocks.as_bytes()),
            Cow::Borrowed(self.representatives.as_bytes()),
            Cow::Borrowed(self.aggregates.as_bytes()),
            Cow::Owned(bytemuck::cast_slice(&treelets).to_vec()),
        ];
        (arrays, meta)
    }

    /// The BVH whose arrays lie in `ranges` (in [`ARRAYS`]' order) of `bytes`, as
    /// [`Self::arrays`] gave them. Checked now: the arrays' lengths agree, the top's CRC, and
    /// that its nodes lead only to top nodes after them and to the treelets the table names.
    /// Each treelet is checked as a walk first enters it (its CRC, its children within it and
    /// after their parents, its depth); a damaged one is walked as empty, and the damage told
    /// by [`Bvh::damage`].
    pub fn from_stored(
        meta: BvhMeta,
        bytes: Arc<dyn StableBytes>,
        ranges: [Range<usize>; 6],
    ) -> Result<Bvh, BvhStoredError> {
        let [nodes, lod, blocks, representatives, aggregates, treelets] = ranges;
        fetch_top(&*bytes, &meta, [&nodes, &lod, &representatives, &aggregates], &treelets)?;
        let array = |i: usize, e: StoredError| BvhStoredError::Array { array: ARRAYS[i], source: e };
        let nodes = Stored::<Node>::from_bytes(Arc::clone(&bytes), nodes).map_err(|e| array(0, e))?;
        let lod = Stored::<NodeLod>::from_bytes(Arc::clone(&bytes), lod).map_err(|e| array(1, e))?;
        let blocks = Stored::<SplatBlock>::from_bytes(Arc::clone(&bytes), blocks).map_err(|e| array(2, e))?;
        let representatives =
            Stored::<SplatBlock>::from_bytes(Arc::clone(&bytes), representatives).map_err(|e| array(3, e))?;
        let aggregates =
            Stored::<NodeAggregate>::from_bytes(Arc::clone(&bytes), aggregates).map_err(|e| array(4, e))?;
        let treelets = Stored::<Treelet>::from_bytes(bytes, treelets).map_err(|e| array(5, e))?;
        let [lo, hi] = meta.bounds;
        let mut bvh = Bvh {
            nodes,
            lod,
            blocks,
            representatives,
            aggregates,
            treelets,
            top_nodes: meta.top_nodes,
            lazy: None,
            splat_count: meta.splat_count,
            bounds: Aabb::new(lo.into(), hi.into()),
            depth: meta.depth,
            node_bounds: meta.node_bounds,
            plain_walk: false,
            sphere_nodes: meta.sphere_nodes,
            lod_floor: meta.lod_floor,
            wide_radius: meta.wide_radius,
            coverage_density: Box::new(meta.coverage_density.into()),
            shape: meta.shape,
        };
        check_top(&bvh, meta.top_crc).map_err(BvhStoredError::Structure)?;
        bvh.lazy = Some(Arc::new(bvh.lazy_checks().map_err(BvhStoredError::Structure)?));
        Ok(bvh)
    }
}

/// Has `bytes` fetch what opening reads (`StableBytes::fetch`): the treelet table and the
/// top's nodes, spheres, representatives and aggregates, the first `top_nodes` of each array.
fn fetch_top(
    bytes: &dyn StableBytes,
    meta: &BvhMeta,
    node_arrays: [&Range<usize>; 4],
    treelets: &Range<usize>,
) -> Result<(), BvhStoredError> {
    let sizes = [size_of::<Node>(), size_of::<NodeLod>(), size_of::<SplatBlock>(), size_of::<NodeAggregate>()];
    let top = |(range, size): (&Range<usize>, usize)| {
        range.start..range.end.min(range.start.saturating_add(meta.top_nodes.saturating_mul(size)))
    };
    let mut ranges: Vec<Range<usize>> = node_arrays.into_iter().zip(sizes).map(top).collect();
    ranges.push(treelets.clone());
    bytes.fetch(&ranges).map_err(|e| BvhStoredError::Structure(format!("its top could not be read: {e}")))
}

fn node_bytes(nodes: Cow<'_, [Node]>) -> Cow<'_, [u8]> {
    match nodes {
        Cow::Borrowed(n) => Cow::Borrowed(bytemuck::cast_slice(n)),
        Cow::Owned(n) => Cow::Owned(bytemuck::cast_slice(&n).to_vec()),
    }
}

/// The CRC of a top: its nodes (as stored, naming their treelets), spheres, representatives
/// and aggregates, then the treelet table.
pub(super) fn top_crc(
    nodes: &[Node],
    lod: &[NodeLod],
    reps: &[SplatBlock],
    aggregates: &[NodeAggregate],
    treelets: &[Treelet],
) -> u32 {
    let mut crc = crc32fast::Hasher::new();
    crc.update(bytemuck::cast_slice(nodes));
    crc.update(bytemuck::cast_slice(lod));
    crc.update(bytemuck::cast_slice(reps));
    crc.update(bytemuck::cast_slice(aggregates));
    crc.update(bytemuck::cast_slice(treelets));
    crc.finalize()
}

/// What [`Bvh::from_stored`] checks of the arrays' lengths and the top's bytes.
fn check_top(bvh: &Bvh, crc: u32) -> Result<(), String> {
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
    let top = bvh.top_nodes;
    if bvh.depth > MAX_DEPTH || top > n || (top == 0) != (n == 0) {
        return Err(format!("depth {} (at most {MAX_DEPTH}), {top} top nodes of {n}", bvh.depth));
    }
    let stored =
        top_crc(&bvh.nodes[..top], &bvh.lod[..top], &bvh.representatives[..top], &bvh.aggregates[..top], &bvh.treelets);
    if stored != crc {
        return Err("its top is damaged (CRC mismatch)".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::BvhParams;
    use crate::accel::stored::AlignedBytes;
    use crate::math::{Ray, RayCone};
    use crate::splat::Splat;
    use crate::splat::scheme::{SurfaceScheme, intersect};
    use glam::Vec3;

    /// The arrays laid end to end, each on a 64-byte boundary, as a file would hold them.
    fn laid_out(bvh: &Bvh) -> (Vec<u8>, [Range<usize>; 6], BvhMeta) {
        let (arrays, meta) = bvh.arrays();
        let mut bytes = Vec::new();
        let ranges = arrays.map(|a| {
            bytes.resize(bytes.len().next_multiple_of(ARRAY_ALIGN), 0);
            let start = bytes.len();
            bytes.extend_from_slice(&a);
            start..bytes.len()
        });
        (bytes, ranges, meta)
    }

    fn stored(bvh: &Bvh) -> Bvh {
        let (bytes, ranges, meta) = laid_out(bvh);
        Bvh::from_stored(meta, Arc::new(AlignedBytes::copy_of(&bytes)), ranges).expect("a BVH's own arrays")
    }

    /// A wavy sheet of `n`² disks in the unit square at z ≈ 0.
    fn sheet(n: usize) -> Vec<Splat> {
        let step = 1.0 / n as f32;
        (0..n * n)
            .map(|i| Splat {
                center: Vec3::new((i % n) as f32 * step, (i / n) as f32 * step, ((i * 7) % 5) as f32 * 0.1 * step),
                radius: 0.8 * step,
                normal: Vec3::Z,
                color: 0xff00_8040 + i as u32,
            })
            .collect()
    }

    /// First hits of a grid of rays down onto the sheet, at full detail or with a wide footprint.
    fn hits(bvh: &Bvh, lod: bool) -> Vec<Option<(u32, u32)>> {
        let cone = if lod { RayCone { width0: 0.4, spread: 0.0 } } else { RayCone::default() };
        (0..400)
            .map(|i| {
                let mut ray = Ray::new(
                    Vec3::new((i % 20) as f32 / 20.0 + 0.01, (i / 20) as f32 / 20.0 + 0.01, 1.0),
                    -Vec3::Z,
                    cone,
                );
                ray.lod_threshold = if lod { 1.0 } else { 0.0 };
                let mut stats = crate::accel::TraversalStats::uncounted();
                intersect(bvh, &ray, &SurfaceScheme::sj(), &mut stats).map(|h| (h.t.to_bits(), h.splat))
            })
            .collect()
    }

    fn checked(bvh: &Bvh) -> usize {
        bvh.lazy.as_ref().map_or(0, |l| l.checked())
    }

    #[test]
    fn a_stored_bvh_walks_as_the_bvh_it_was_reading_the_treelets_it_enters() {
        let bvh = Bvh::build(sheet(300), &BvhParams::standard());
        assert!(bvh.treelets.len() > 20, "{} treelets", bvh.treelets.len());
        let back = stored(&bvh);
        assert_eq!(checked(&back), 0, "opening reads the top alone");
        // Wide footprints stop above the treelets.
        let far = hits(&back, true);
        assert!(checked(&back) < bvh.treelets.len() / 4, "{} of {} treelets read", checked(&back), bvh.treelets.len());
        assert_eq!(far, hits(&bvh, true));
        assert!(far.iter().flatten().count() > 300);
        assert_eq!(hits(&back, false), hits(&bvh, false));
        super::super::check_invariants(&back).expect("its invariants");
        assert_eq!(back.damage(), None);
        let (again, meta) = back.arrays();
        let (first, _) = bvh.arrays();
        assert!(again == first && meta == bvh.arrays().1, "stored again, the same bytes");
        assert_eq!(meta.coverage_density, bvh.coverage_density());
    }

    /// A dense sheet with a few disks far off: leaves right under the top.
    fn sheet_and_strays() -> Vec<Splat> {
        let mut splats = sheet(120);
        for i in 0..3 {
            let center = Vec3::new(5.0 + i as f32, -4.0, 2.0 * i as f32);
            splats.push(Splat { center, radius: 0.05, normal: Vec3::Z, color: 0xff20_4060 });
        }
        splats
    }

    #[test]
    fn lone_leaves_under_the_top_are_treelets_too() {
        let bvh = Bvh::build(sheet_and_strays(), &BvhParams::standard());
        assert!(bvh.treelets.iter().any(|t| t.root & super::super::LEAF != 0), "a lone leaf");
        let back = stored(&bvh);
        let ray = Ray::new(Vec3::new(6.0, -4.0, 5.0), -Vec3::Z, RayCone::default());
        let hit = |b: &Bvh| intersect(b, &ray, &SurfaceScheme::sj(), &mut crate::accel::TraversalStats::uncounted());
        assert!(hit(&bvh).is_some_and(|h| h.t > 2.5 && h.t < 3.5), "the stray at z = 2");
        assert_eq!(hit(&back).map(|h| (h.t.to_bits(), h.splat)), hit(&bvh).map(|h| (h.t.to_bits(), h.splat)));
        assert_eq!(back.check_all(), Ok(()));
    }

    #[test]
    fn every_treelet_is_a_run_of_the_arrays_below_the_top() {
        for bvh in
            [Bvh::build(sheet(200), &BvhParams::standard()), Bvh::build(sheet_and_strays(), &BvhParams::standard())]
        {
            every_treelet_is_a_run(&bvh);
        }
    }

    fn every_treelet_is_a_run(bvh: &Bvh) {
        let top = bvh.top_nodes;
        let (mut nodes, mut blocks) = (top, 0);
        for t in bvh.treelets.iter() {
            assert_eq!((t.node_range().start, t.block_range().start), (nodes, blocks), "{t:?}");
            (nodes, blocks) = (t.node_range().end, t.block_range().end);
            assert!(t.block_range().len() * crate::accel::block::BLOCK <= 2 * super::super::treelet::TREELET_SPLATS);
            assert_eq!(bvh.nodes[t.parent as usize].child[t.slot as usize], t.root);
        }
        assert_eq!((nodes, blocks), (bvh.nodes.len(), bvh.blocks.len()));
    }

    #[test]
    fn a_damaged_treelet_is_found_when_entered_and_walked_as_empty() {
        let bvh = Bvh::build(sheet(300), &BvhParams::standard());
        let (bytes, ranges, meta) = laid_out(&bvh);
        // Damage the blocks of the treelet under the ray at (0.51, 0.51).
        let ray = |b: &Bvh| {
            let ray = Ray::new(Vec3::new(0.51, 0.51, 1.0), -Vec3::Z, RayCone::default());
            intersect(b, &ray, &SurfaceScheme::sj(), &mut crate::accel::TraversalStats::uncounted()).map(|h| h.splat)
        };
        let hit = ray(&bvh).expect("the sheet") as usize / crate::accel::block::BLOCK;
        let t = bvh.treelets.iter().position(|t| t.block_range().contains(&hit)).unwrap();
        let mut raw = bytes.clone();
        raw[ranges[2].start + hit * size_of::<SplatBlock>() + 3] ^= 1;
        let back = Bvh::from_stored(meta, Arc::new(AlignedBytes::copy_of(&raw)), ranges).expect("the top is whole");
        assert_eq!(hits(&back, true).len(), 400, "far rays need not enter it");
        assert_ne!(ray(&back), ray(&bvh), "walked as empty");
        let damage = back.damage().expect("found");
        assert!(damage.contains(&format!("treelet {t}")) && damage.contains("CRC"), "{damage}");
        assert!(back.check_all().is_err());
    }

    /// Recomputes every CRC of laid-out arrays after an edit, as a hostile writer would: what
    /// is left to catch is the structure.
    fn reseal(raw: &mut [u8], r: &[Range<usize>; 6], meta: &mut BvhMeta) {
        let sizes = [size_of::<Node>(), size_of::<NodeLod>(), 0, size_of::<SplatBlock>(), size_of::<NodeAggregate>()];
        let part = |raw: &[u8], i: usize, range: Range<usize>, size: usize| {
            raw[r[i].start + range.start * size..][..range.len() * size].to_vec()
        };
        let mut treelets: Vec<Treelet> =
            raw[r[5].clone()].chunks(size_of::<Treelet>()).map(bytemuck::pod_read_unaligned).collect();
        for t in &mut treelets {
            let mut crc = crc32fast::Hasher::new();
            for i in [0, 1, 3, 4] {
                crc.update(&part(raw, i, t.node_range(), sizes[i]));
            }
            crc.update(&part(raw, 2, t.block_range(), size_of::<SplatBlock>()));
            t.crc = crc.finalize();
        }
        raw[r[5].clone()].copy_from_slice(bytemuck::cast_slice(&treelets));
        let mut crc = crc32fast::Hasher::new();
        for i in [0, 1, 3, 4] {
            crc.update(&part(raw, i, 0..meta.top_nodes, sizes[i]));
        }
        crc.update(&raw[r[5].clone()]);
        meta.top_crc = crc.finalize();
    }

    #[test]
    fn a_treelet_whose_structure_is_bad_is_damage_not_a_panic() {
        let bvh = Bvh::build(sheet(200), &BvhParams::standard());
        let t = bvh.treelets.iter().find(|t| t.node_range().len() > 1).copied().expect("a treelet of nodes");
        let at = |k: usize, i: usize| k * size_of::<Node>() + std::mem::offset_of!(Node, child) + 4 * i;
        let slot = |k: usize| {
            (0..8).find(|&i| bvh.nodes[k].used & (1 << i) != 0 && bvh.nodes[k].child[i] & super::super::LEAF == 0)
        };
        let k = t.node_range().start;
        let i = slot(k).expect("the root has an inner child");
        for (what, child) in [
            ("a cycle", k as u32),
            ("past the nodes", bvh.nodes.len() as u32 + 5),
            ("a leaf outside", super::super::LEAF | 3),
        ] {
            let (mut raw, ranges, mut meta) = laid_out(&bvh);
            raw[ranges[0].start + at(k, i)..][..4].copy_from_slice(&child.to_le_bytes());
            reseal(&mut raw, &ranges, &mut meta);
            let back = Bvh::from_stored(meta, Arc::new(AlignedBytes::copy_of(&raw)), ranges).expect("the top is whole");
            assert!(back.check_all().is_err_and(|e| e.contains("treelet")), "{what}");
            hits(&back, false);
            assert!(back.damage().is_some(), "{what}");
        }
    }

    #[test]
    fn stored_bytes_that_are_no_bvh_are_refused() {
        let bvh = Bvh::build(sheet(200), &BvhParams::standard());
        type Edit<'a> = dyn Fn(&mut Vec<u8>, &mut [Range<usize>; 6], &mut BvhMeta) + 'a;
        let refused = |edit: &Edit<'_>| {
            let (mut raw, mut ranges, mut meta) = laid_out(&bvh);
            edit(&mut raw, &mut ranges, &mut meta);
            Bvh::from_stored(meta, Arc::new(AlignedBytes::copy_of(&raw)), ranges).err().map(|e| e.to_string())
        };
        assert_eq!(refused(&|_, _, _| ()), None, "untouched");
        // The root's first child: damaged bytes, then the same with the CRC made to match.
        let child0 = std::mem::offset_of!(Node, child);
        let err = refused(&|raw, r, _| raw[r[0].start + child0] ^= 1);
        assert!(err.as_deref().is_some_and(|e| e.contains("top is damaged")), "{err:?}");
        let cycle = |raw: &mut Vec<u8>, r: &mut [Range<usize>; 6], m: &mut BvhMeta| {
            raw[r[0].start + child0..][..4].copy_from_slice(&0u32.to_le_bytes());
            let top = |i: usize, size: usize| &raw[r[i].start..r[i].start + m.top_nodes * size];
            let (n, l, rep, a) = (top(0, 256), top(1, 64), top(3, 176), top(4, 64));
            let mut crc = crc32fast::Hasher::new();
            for part in [n, l, rep, a, &raw[r[5].clone()]] {
                crc.update(part);
            }
            m.top_crc = crc.finalize();
        };
        let err = refused(&cycle);
        assert!(err.as_deref().is_some_and(|e| e.contains("no top node after it")), "{err:?}");
        // Arrays of different lengths, a ragged one, a depth beyond the stack, too many splats.
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
