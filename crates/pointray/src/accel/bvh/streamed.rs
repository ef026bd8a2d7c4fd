//! The chunked BVH (`super::chunk`) built out of core: its chunks added one at a time, each
//! built, given its level of detail and cut into treelets at once, the treelets' arrays handed
//! to a [`Spill`] (files, for `pointray_io::prepare`); the top (the octree's nodes and each
//! chunk's nodes above its treelets) kept in memory, its level of detail found in one more pass
//! over the spilled blocks. Then every array goes to a [`Sink`] as a scene file stores it: the
//! same bytes [`Bvh::arrays`] gives of the tree [`Bvh::build_with_ids`] makes in memory, while
//! memory holds one chunk's build and the top.
//!
//! Node numbers: the top's nodes come first, the octree's, then each chunk's top nodes in
//! turn; the treelets' nodes follow, chunk after chunk, numbered here from the first treelet
//! node and moved past the top when written, once its size is known.

use std::io;
use std::ops::Range;

use super::build::{BvhParams, TooLarge, Tree};
use super::chunk::{Child, ChunkPlan, Top, top_nodes};
use super::lod::{self, ChildLod, ChildPass, Disks, NodeAggregate, NodeLod};
use super::treelet::{self, Treelet, treelet_ref};
use super::{Bvh, BvhMeta, LEAF, Node, SPHERE_NODE, WIDTH};
use crate::accel::block::{BLOCK, SplatBlock, snap};
use crate::accel::representative::{LOD_FLOOR_QUANTILE, Moments, WIDE_QUANTILE, radius_quantile};
use crate::math::Aabb;
use crate::math::select::select_in_passes;
use crate::splat::Splat;
use crate::splat::footprint::density_stride;

/// The arrays a build spills, each appended to in turn and read back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spilled {
    Nodes,
    Lod,
    Representatives,
    Aggregates,
    Blocks,
    Ids,
    /// Every splat's radius, for [`crate::accel::Accel::wide_radius`].
    Radii,
}

/// Where an out-of-core build keeps the arrays it made (temporary files).
pub trait Spill {
    fn append(&mut self, array: Spilled, bytes: &[u8]) -> io::Result<()>;
    /// Reads `buf.len()` bytes from `offset` of `array`.
    fn read_at(&mut self, array: Spilled, offset: usize, buf: &mut [u8]) -> io::Result<()>;
}

/// Where the stored arrays go: array `array` of `scene::SCENE_ARRAYS` (the BVH's, then the
/// ids), `bytes` at byte `offset` of it.
pub trait Sink {
    fn write_at(&mut self, array: usize, offset: usize, bytes: &[u8]) -> io::Result<()>;
}

#[derive(Debug, thiserror::Error)]
pub enum StreamedError {
    #[error(transparent)]
    TooLarge(#[from] TooLarge),
    #[error(transparent)]
    Io(#[from] io::Error),
}

/// What [`StreamedBvh::finish`] gives: the BVH's scalars (its `coverage_density` NaN, to be
/// found from the stored tree and `coverage_samples`, `footprint::coverage_counts`), the ids'
/// CRC.
pub struct Finished {
    pub meta: BvhMeta,
    pub ids_crc: u32,
    pub coverage_samples: Vec<Splat>,
}

/// Blocks read at a time from a spill (a window of 11 MB).
const WINDOW: usize = 1 << 16;

/// A BVH being built a chunk at a time (see the module).
pub struct StreamedBvh {
    params: BvhParams,
    plan: ChunkPlan,
    top: Top,
    /// The next chunk to add, and the splats added so far (the next one's id, counted on from
    /// `id_base`).
    next: usize,
    first_id: usize,
    /// Added to the ids counted on ([`Self::starting_at`]).
    id_base: usize,
    /// The top's arrays: the octree's nodes (made by `finish`), then each chunk's top nodes.
    nodes: Vec<Node>,
    lod: Vec<NodeLod>,
    representatives: Vec<SplatBlock>,
    aggregates: Vec<NodeAggregate>,
    /// Their nodes and roots numbered from the first treelet node.
    treelets: Vec<Treelet>,
    /// Each chunk's root as its parent names it, its bounds, blocks and moments.
    roots: Vec<(u32, Aabb)>,
    chunk_blocks: Vec<Range<usize>>,
    moments: Vec<Moments>,
    /// Every block's splat count, every node's `min_radius`.
    counts: Vec<u8>,
    min_radii: Vec<f32>,
    spilled_nodes: usize,
    bounds: Aabb,
    depth: usize,
    sphere_nodes: usize,
}

impl StreamedBvh {
    /// A build of the splats `plan` covers, with `params` (whose `chunk_splats` made the plan).
    pub fn new(plan: ChunkPlan, params: &BvhParams) -> StreamedBvh {
        let top = plan.top();
        let empty = Node::new(&[]);
        let t = top.nodes.len();
        StreamedBvh {
            params: *params,
            plan,
            next: 0,
            first_id: 0,
            id_base: 0,
            nodes: vec![empty; t],
            lod: vec![bytemuck::Zeroable::zeroed(); t],
            representatives: vec![bytemuck::Zeroable::zeroed(); t],
            aggregates: vec![bytemuck::Zeroable::zeroed(); t],
            treelets: Vec::new(),
            roots: Vec::new(),
            chunk_blocks: Vec::new(),
            moments: Vec::new(),
            counts: Vec::new(),
            min_radii: Vec::new(),
            spilled_nodes: 0,
            bounds: Aabb::EMPTY,
            depth: 0,
            sphere_nodes: 0,
            top,
        }
    }

    pub fn plan(&self) -> &ChunkPlan {
        &self.plan
    }

    /// This build with its unnamed splats' ids counted on from `first` (a part of a two-level
    /// scene, whose ids count on from the parts before it).
    pub fn starting_at(self, first: usize) -> StreamedBvh {
        StreamedBvh { id_base: first, ..self }
    }

    /// Builds the next chunk from its splats (in the input's order), keeps its top and spills
    /// the rest. Their ids are `names` (one a splat), or without, counted on from the chunks
    /// before.
    ///
    /// # Panics
    /// With more or fewer splats (or names) than the plan gives the chunk, or past the last chunk.
    pub fn add_chunk(
        &mut self,
        mut splats: Vec<Splat>,
        names: Option<&[u32]>,
        spill: &mut dyn Spill,
    ) -> Result<(), StreamedError> {
        let c = self.next;
        assert_eq!(splats.len(), self.plan.chunks()[c].count, "chunk {c}'s splats");
        assert!(names.is_none_or(|n| n.len() == splats.len()), "a name a splat");
        snap(&mut splats);
        let radii: Vec<f32> = splats.iter().map(|s| s.radius).collect();
        spill.append(Spilled::Radii, bytemuck::cast_slice(&radii))?;
        drop(radii);
        let depth = self.top.depths[c];
        let mut tree = Tree::build(&splats, &self.params, depth)?;
        drop(splats);
        let blocks = self.counts.len();
        if blocks + tree.blocks.len() > super::MAX_BLOCKS {
            return Err(TooLarge::Blocks(blocks + tree.blocks.len()).into());
        }
        for id in tree.ids.iter_mut().filter(|id| **id != u32::MAX) {
            *id = names.map_or((*id as usize + self.id_base + self.first_id) as u32, |n| n[*id as usize]);
        }
        let lod = lod::build(&mut tree.nodes, &Disks { blocks: &tree.blocks, counts: &tree.counts }, self.params.shape);
        lod::choose_node_bounds_below(&mut tree.nodes, &lod.lod, self.params.node_bounds, depth as u32);
        self.sphere_nodes += tree.nodes.iter().filter(|n| n.used & SPHERE_NODE != 0).count();
        self.min_radii.extend(tree.nodes.iter().map(|n| n.min_radius));
        self.moments.push(lod.root.clone());
        // A chunk's root is in the top only as the whole tree's (no octree above it).
        let always = usize::from(self.top.nodes.is_empty());
        let cut = treelet::partition(std::mem::take(&mut tree.nodes), lod, always);
        let (top_at, tree_at, t0) = (self.nodes.len() as u32, self.spilled_nodes as u32, self.treelets.len());
        let node_at = |k: u32| if (k as usize) < cut.top { top_at + k } else { tree_at + k - cut.top as u32 };
        let moved = |c: u32| if c & LEAF != 0 { c + blocks as u32 } else { node_at(c) };
        let mut nodes: Vec<Node> = cut.nodes.iter().map(|n| with_children(n, moved)).collect();
        for (t, treelet) in cut.treelets.iter().enumerate() {
            if treelet.parent != u32::MAX {
                nodes[treelet.parent as usize].child[treelet.slot as usize] = treelet_ref(t0 + t);
            }
            self.treelets.push(Treelet {
                root: moved(treelet.root),
                parent: if treelet.parent == u32::MAX { u32::MAX } else { top_at + treelet.parent },
                slot: treelet.slot,
                nodes: treelet.nodes.map(|k| k - cut.top as u32 + tree_at),
                blocks: treelet.blocks.map(|b| b + blocks as u32),
                crc: 0,
            });
        }
        let root = if cut.top > 0 { top_at } else { treelet_ref(t0) };
        self.roots.push((root, tree.bounds));
        let split = cut.top;
        spill.append(Spilled::Nodes, bytemuck::cast_slice(&nodes[split..]))?;
        spill.append(Spilled::Lod, bytemuck::cast_slice(&cut.lod[split..]))?;
        spill.append(Spilled::Representatives, bytemuck::cast_slice(&cut.representatives[split..]))?;
        spill.append(Spilled::Aggregates, bytemuck::cast_slice(&cut.aggregates[split..]))?;
        spill.append(Spilled::Blocks, bytemuck::cast_slice(&tree.blocks))?;
        spill.append(Spilled::Ids, bytemuck::cast_slice(&tree.ids))?;
        self.nodes.extend_from_slice(&nodes[..split]);
        self.lod.extend_from_slice(&cut.lod[..split]);
        self.representatives.extend_from_slice(&cut.representatives[..split]);
        self.aggregates.extend_from_slice(&cut.aggregates[..split]);
        self.spilled_nodes += nodes.len() - split;
        self.chunk_blocks.push(blocks..blocks + tree.blocks.len());
        self.counts.extend_from_slice(&tree.counts);
        self.bounds = self.bounds.union(tree.bounds);
        self.depth = self.depth.max(depth + tree.depth);
        self.first_id += self.plan.chunks()[c].count;
        self.next += 1;
        Ok(())
    }

    /// The byte length of each stored array (as [`Sink`] numbers them), once every chunk is in.
    pub fn lengths(&self) -> [usize; 7] {
        let nodes = self.nodes.len() + self.spilled_nodes;
        let blocks = self.counts.len();
        [
            nodes * size_of::<Node>(),
            nodes * size_of::<NodeLod>(),
            blocks * size_of::<SplatBlock>(),
            nodes * size_of::<SplatBlock>(),
            nodes * size_of::<NodeAggregate>(),
            self.treelets.len() * size_of::<Treelet>(),
            blocks * BLOCK * size_of::<u32>(),
        ]
    }

    /// The top's level of detail, then every array written to `sink`.
    ///
    /// # Panics
    /// Before every chunk is added.
    pub fn finish(mut self, spill: &mut dyn Spill, sink: &mut dyn Sink) -> Result<Finished, StreamedError> {
        assert_eq!(self.next, self.plan.chunks().len(), "chunks missing");
        top_nodes(&self.top, &self.roots, &mut self.nodes[..self.top.nodes.len()]);
        for k in 0..self.top.nodes.len() {
            for i in (0..WIDTH).filter(|&i| self.nodes[k].used & (1 << i) != 0) {
                let child = self.nodes[k].child[i];
                if Bvh::is_treelet(child) {
                    let t = (child - treelet_ref(0)) as usize;
                    (self.treelets[t].parent, self.treelets[t].slot) = (k as u32, i as u32);
                }
            }
        }
        self.top_lod(spill)?;
        let lod_floor = radius_quantile(std::mem::take(&mut self.min_radii), LOD_FLOOR_QUANTILE);
        let wide_radius = spilled_quantile(spill, self.first_id, WIDE_QUANTILE)?;
        let top = self.nodes.len() as u32;
        for t in &mut self.treelets {
            t.nodes = t.nodes.map(|k| k + top);
            t.root = if t.root & LEAF != 0 { t.root } else { t.root + top };
        }
        let ids_crc = self.write(spill, sink, top)?;
        let meta = BvhMeta {
            splat_count: self.first_id,
            bounds: [self.bounds.min.to_array(), self.bounds.max.to_array()],
            depth: self.depth,
            node_bounds: self.params.node_bounds,
            shape: self.params.shape,
            lod_floor,
            wide_radius,
            coverage_density: f32::NAN,
            sphere_nodes: self.sphere_nodes,
            top_nodes: self.nodes.len(),
            top_crc: super::stored::top_crc(
                &self.nodes,
                &self.lod,
                &self.representatives,
                &self.aggregates,
                &self.treelets,
            ),
        };
        let coverage_samples = self.coverage_samples(spill)?;
        Ok(Finished { meta, ids_crc, coverage_samples })
    }

    /// [`Bvh::coverage_samples`] of the tree, read from the spilled blocks. (From the stored
    /// tree, mapped, the reads of 4,096 blocks left 670 MB of the 30-million-point file
    /// resident.)
    fn coverage_samples(&self, spill: &mut dyn Spill) -> io::Result<Vec<Splat>> {
        let mut block: SplatBlock = bytemuck::Zeroable::zeroed();
        let mut samples = Vec::new();
        for b in (0..self.counts.len()).step_by(density_stride(self.first_id)) {
            spill.read_at(Spilled::Blocks, b * size_of::<SplatBlock>(), bytemuck::bytes_of_mut(&mut block))?;
            samples.extend(super::block_disks(&block));
        }
        Ok(samples)
    }

    /// The octree's nodes' level of detail: their moments from the chunks' up, then one pass
    /// over the spilled blocks for every child's bounds and representative.
    fn top_lod(&mut self, spill: &mut dyn Spill) -> io::Result<()> {
        let t = self.top.nodes.len();
        let (mut moments, mut ranges) = (vec![Moments::default(); t], vec![0..0; t]);
        let child_of = |c: Child, moments: &[Moments], ranges: &[Range<usize>]| match c {
            Child::Node(i) => (moments[i].clone(), ranges[i].clone()),
            Child::Chunk(c) => (self.moments[c].clone(), self.chunk_blocks[c].clone()),
        };
        // Each child's pass, in the order of its blocks.
        let mut passes: Vec<(usize, usize, Moments, Range<usize>)> = Vec::new();
        for k in (0..t).rev() {
            let (mut m, mut lo, mut hi) = (Moments::default(), usize::MAX, 0);
            for (i, &c) in self.top.nodes[k].iter().enumerate() {
                let (cm, r) = child_of(c, &moments, &ranges);
                m.merge(&cm);
                (lo, hi) = (lo.min(r.start), hi.max(r.end));
                passes.push((k, i, cm, r));
            }
            (moments[k], ranges[k]) = (m, lo..hi);
        }
        passes.sort_by_key(|p| p.3.start);
        let mut running: Vec<Option<ChildPass>> = (0..passes.len()).map(|_| None).collect();
        let total = self.counts.len();
        let mut window = vec![bytemuck::Zeroable::zeroed(); WINDOW.min(total)];
        for start in (0..total).step_by(WINDOW) {
            let end = (start + WINDOW).min(total);
            let blocks = &mut window[..end - start];
            spill.read_at(Spilled::Blocks, start * size_of::<SplatBlock>(), bytemuck::cast_slice_mut(blocks))?;
            for (p, (k, i, m, r)) in passes.iter().enumerate().filter(|(_, p)| p.3.start < end && p.3.end > start) {
                for b in r.start.max(start)..r.end.min(end) {
                    let block = &blocks[b - start];
                    let pass = running[p].get_or_insert_with(|| {
                        ChildPass::new(self.nodes[*k].child_bounds(*i).center(), block, m, self.params.shape)
                    });
                    pass.add(block, usize::from(self.counts[b]));
                }
            }
        }
        let mut children: Vec<[Option<ChildLod>; WIDTH]> = (0..t).map(|_| Default::default()).collect();
        for ((k, i, m, _), pass) in passes.into_iter().zip(running) {
            children[k][i] = Some(pass.expect("every child has blocks").finish(&m));
        }
        for (k, children) in children.iter().enumerate() {
            let p = lod::payload(children);
            (self.lod[k], self.representatives[k], self.aggregates[k]) = (p.lod, p.representatives, p.aggregate);
            lod::mark_lod_slots(&mut self.nodes[k], &p.lod);
            self.min_radii.push(self.nodes[k].min_radius);
        }
        lod::choose_node_bounds_below(&mut self.nodes[..t], &self.lod[..t], self.params.node_bounds, 0);
        self.sphere_nodes += self.nodes[..t].iter().filter(|n| n.used & SPHERE_NODE != 0).count();
        Ok(())
    }

    /// Every array to `sink`: the top's, then the spilled ones (their nodes moved past the
    /// `top` nodes), each treelet's CRC found on the way; the ids' CRC.
    fn write(&mut self, spill: &mut dyn Spill, sink: &mut dyn Sink, top: u32) -> io::Result<u32> {
        let mut crcs: Vec<crc32fast::Hasher> = self.treelets.iter().map(|_| crc32fast::Hasher::new()).collect();
        let spilled = [Spilled::Nodes, Spilled::Lod, Spilled::Representatives, Spilled::Aggregates];
        let tops: [&[u8]; 4] = [
            bytemuck::cast_slice(&self.nodes),
            bytemuck::cast_slice(&self.lod),
            bytemuck::cast_slice(&self.representatives),
            bytemuck::cast_slice(&self.aggregates),
        ];
        // In the order a treelet's CRC takes them (`Bvh::treelet_crc`).
        for (array, (spilled, top_bytes)) in [0, 1, 3, 4].into_iter().zip(spilled.into_iter().zip(tops)) {
            sink.write_at(array, 0, top_bytes)?;
            let moved = |bytes: &mut [u8]| {
                if spilled == Spilled::Nodes {
                    let nodes: &mut [Node] = bytemuck::cast_slice_mut(bytes);
                    for n in nodes {
                        *n = with_children(n, |c| if c & LEAF != 0 { c } else { c + top });
                    }
                }
            };
            let runs = self.treelets.iter().map(|t| (t.nodes[0] - top) as usize..(t.nodes[1] - top) as usize);
            let (at, size) = (top_bytes.len(), element_size(spilled));
            copy(spill, spilled, sink, array, at, self.spilled_nodes, size, runs, &mut crcs, moved)?;
        }
        let runs = self.treelets.iter().map(|t| t.blocks[0] as usize..t.blocks[1] as usize);
        copy(spill, Spilled::Blocks, sink, 2, 0, self.counts.len(), size_of::<SplatBlock>(), runs, &mut crcs, |_| {})?;
        for (t, crc) in self.treelets.iter_mut().zip(crcs) {
            t.crc = crc.finalize();
        }
        sink.write_at(5, 0, bytemuck::cast_slice(&self.treelets))?;
        let mut ids = crc32fast::Hasher::new();
        let slots = self.counts.len() * BLOCK;
        let mut window = vec![0u8; WINDOW * BLOCK * 4];
        for start in (0..slots).step_by(WINDOW * BLOCK) {
            let bytes = &mut window[..((start + WINDOW * BLOCK).min(slots) - start) * 4];
            spill.read_at(Spilled::Ids, start * 4, bytes)?;
            ids.update(bytes);
            sink.write_at(6, start * 4, bytes)?;
        }
        Ok(ids.finalize())
    }
}

/// [`radius_quantile`] of the `n` spilled radii, in two passes over them
/// (`math::select::select_in_passes`). (Held in memory, the radii of 200 million points took
/// 800 MB.)
fn spilled_quantile(spill: &mut dyn Spill, n: usize, quantile: f64) -> io::Result<f32> {
    let at = |n: usize| Some([((n.checked_sub(1)?) as f64 * quantile) as usize]);
    let selected = select_in_passes(at, |f| each_radius(spill, n, f))?;
    Ok(selected.map_or(f32::INFINITY, |[r]| r))
}

/// Calls `f` with each of the `n` spilled radii.
fn each_radius(spill: &mut dyn Spill, n: usize, f: &mut dyn FnMut(f32)) -> io::Result<()> {
    let mut window = vec![0f32; WINDOW * BLOCK];
    for start in (0..n).step_by(window.len()) {
        let radii = &mut window[..(n - start).min(WINDOW * BLOCK)];
        spill.read_at(Spilled::Radii, start * 4, bytemuck::cast_slice_mut(radii))?;
        radii.iter().for_each(|&r| f(r));
    }
    Ok(())
}

fn element_size(array: Spilled) -> usize {
    match array {
        Spilled::Nodes => size_of::<Node>(),
        Spilled::Lod => size_of::<NodeLod>(),
        Spilled::Representatives | Spilled::Blocks => size_of::<SplatBlock>(),
        Spilled::Aggregates => size_of::<NodeAggregate>(),
        Spilled::Ids | Spilled::Radii => size_of::<u32>(),
    }
}

/// Copies `count` elements of `size` bytes of spilled array `from` to `sink` array `to` from
/// byte `at` on, a window at a time, `moved` applied to each window; each treelet's CRC (in
/// `crcs`) is fed the elements of its run (`runs`, in order, element indices of `from`).
#[allow(clippy::too_many_arguments)]
fn copy(
    spill: &mut dyn Spill,
    from: Spilled,
    sink: &mut dyn Sink,
    to: usize,
    at: usize,
    count: usize,
    size: usize,
    runs: impl Iterator<Item = Range<usize>>,
    crcs: &mut [crc32fast::Hasher],
    moved: impl Fn(&mut [u8]),
) -> io::Result<()> {
    let mut runs = runs.enumerate().peekable();
    // Of nodes, for their alignment (`moved` sees nodes in it).
    let mut window: Vec<Node> = vec![bytemuck::Zeroable::zeroed(); (WINDOW * size).div_ceil(size_of::<Node>())];
    let window: &mut [u8] = bytemuck::cast_slice_mut(&mut window);
    for start in (0..count).step_by(WINDOW) {
        let end = (start + WINDOW).min(count);
        let bytes = &mut window[..(end - start) * size];
        spill.read_at(from, start * size, bytes)?;
        moved(bytes);
        sink.write_at(to, at + start * size, bytes)?;
        // The runs lie in order: feed each the part of it in this window.
        while let Some((t, run)) = runs.peek() {
            let (lo, hi) = (run.start.max(start), run.end.min(end));
            if lo < hi {
                crcs[*t].update(&bytes[(lo - start) * size..(hi - start) * size]);
            }
            if run.end <= end {
                runs.next();
            } else {
                break;
            }
        }
    }
    Ok(())
}

/// `node` with each child reference mapped by `f`.
fn with_children(node: &Node, f: impl Fn(u32) -> u32) -> Node {
    let mut node = *node;
    for i in (0..WIDTH).filter(|i| node.used & (1 << i) != 0) {
        if !Bvh::is_treelet(node.child[i]) {
            node.child[i] = f(node.child[i]);
        }
    }
    node
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::NodeBounds;
    use crate::math::morton;
    use glam::Vec3;

    /// Spilled arrays in memory.
    #[derive(Default)]
    struct Vecs([Vec<u8>; 7]);

    #[test]
    fn the_spilled_quantile_is_the_quantile() {
        let radii: Vec<f32> = (0..100_003u32).map(|i| ((i * 7_919) % 100_003) as f32 * 1e-3 + 0.5).collect();
        let mut spill = Vecs::default();
        spill.append(Spilled::Radii, bytemuck::cast_slice(&radii)).unwrap();
        for q in [0.0, 0.5, 0.99, 1.0] {
            let want = radius_quantile(radii.clone(), q);
            assert_eq!(spilled_quantile(&mut spill, radii.len(), q).unwrap(), want, "{q}");
        }
    }

    impl Spill for Vecs {
        fn append(&mut self, array: Spilled, bytes: &[u8]) -> io::Result<()> {
            self.0[array as usize].extend_from_slice(bytes);
            Ok(())
        }

        fn read_at(&mut self, array: Spilled, offset: usize, buf: &mut [u8]) -> io::Result<()> {
            buf.copy_from_slice(&self.0[array as usize][offset..offset + buf.len()]);
            Ok(())
        }
    }

    impl Sink for Vecs {
        fn write_at(&mut self, array: usize, offset: usize, bytes: &[u8]) -> io::Result<()> {
            let a = &mut self.0[array];
            a.resize(a.len().max(offset + bytes.len()), 0);
            a[offset..offset + bytes.len()].copy_from_slice(bytes);
            Ok(())
        }
    }

    /// `n` disks on a wavy sheet with a sphere above it, in Morton order (as preprocessing
    /// leaves a cloud).
    fn scene(n: usize) -> Vec<Splat> {
        let mut splats: Vec<Splat> = (0..n)
            .map(|i| {
                let (u, v) = ((i % 200) as f32 * 0.05, (i / 200) as f32 * 0.05);
                let center = if i % 3 == 0 {
                    let (a, b) = (u * 0.7, v * 1.3);
                    Vec3::new(5.0 + a.cos() * b.sin(), 5.0 + a.sin() * b.sin(), 3.0 + b.cos())
                } else {
                    Vec3::new(u, v, (u * 1.7).sin() * 0.3)
                };
                Splat {
                    center,
                    radius: 0.04 + (i % 7) as f32 * 0.003,
                    normal: Vec3::new(0.1, 0.2, 1.0).normalize(),
                    color: i as u32,
                }
            })
            .collect();
        let bounds = Aabb::from_points(splats.iter().map(|s| s.center));
        splats.sort_by_key(|s| morton::encode(s.center, &bounds));
        splats
    }

    /// The build of `splats` out of core, each named `name` of its index.
    fn streamed(splats: &[Splat], params: &BvhParams, name: Option<fn(u32) -> u32>) -> (Vecs, Finished) {
        let bounds = Aabb::from_points(splats.iter().map(|s| s.center));
        let codes = |f: &mut dyn FnMut(u64)| splats.iter().for_each(|s| f(morton::encode(s.center, &bounds)));
        let plan = ChunkPlan::new(bounds, splats.len(), params.chunk_splats, codes);
        let mut build = StreamedBvh::new(plan.clone(), params);
        let mut spill = Vecs::default();
        let mut first = 0;
        for cell in plan.chunks() {
            let names: Option<Vec<u32>> = name.map(|f| (first as u32..(first + cell.count) as u32).map(f).collect());
            build.add_chunk(splats[first..first + cell.count].to_vec(), names.as_deref(), &mut spill).unwrap();
            first += cell.count;
        }
        let mut sink = Vecs::default();
        let lengths = build.lengths();
        let finished = build.finish(&mut spill, &mut sink).unwrap();
        assert_eq!(sink.0.each_ref().map(Vec::len), lengths);
        (sink, finished)
    }

    #[test]
    fn a_build_out_of_core_stores_the_bytes_of_the_build_in_memory() {
        let splats = scene(60_000);
        // Chunks of 6,000, and of 1,000 (octree nodes over fewer splats than a treelet holds).
        let variants = [(NodeBounds::Boxes, 6_000), (NodeBounds::SpheresFrom(2), 6_000), (NodeBounds::Auto, 1_000)];
        for (node_bounds, chunk_splats) in variants {
            let params = BvhParams { chunk_splats, node_bounds, ..BvhParams::standard() };
            let (bvh, ids) = Bvh::build_with_ids(splats.clone(), &params);
            let (arrays, meta) = bvh.arrays();
            let (sink, Finished { meta: streamed_meta, ids_crc, coverage_samples }) = streamed(&splats, &params, None);
            let samples: Vec<Splat> = bvh.coverage_samples().collect();
            assert!(samples.len() > 3_000 && samples.iter().zip(&coverage_samples).all(|(a, b)| a.bits() == b.bits()));
            assert_eq!(samples.len(), coverage_samples.len());
            assert!(meta.top_nodes > 8 && bvh.treelets.len() > 20, "{} top nodes", meta.top_nodes);
            for (i, array) in arrays.iter().enumerate() {
                assert!(array[..] == sink.0[i][..], "{node_bounds:?}: array {} differs", super::super::ARRAYS[i]);
            }
            assert!(bytemuck::cast_slice::<u32, u8>(&ids) == &sink.0[6][..], "ids differ");
            assert_eq!(ids_crc, crc32fast::hash(bytemuck::cast_slice(&ids)));
            assert_eq!(BvhMeta { coverage_density: meta.coverage_density, ..streamed_meta }, meta);
            // Named (as a cloud whose points were filtered names them: by their former index).
            let (sink, _) = streamed(&splats, &params, Some(|i| 3 * i + 1));
            let named: Vec<u32> = ids.iter().map(|&i| if i == u32::MAX { i } else { 3 * i + 1 }).collect();
            assert!(bytemuck::cast_slice::<u32, u8>(&named) == &sink.0[6][..], "named ids differ");
        }
    }
}
