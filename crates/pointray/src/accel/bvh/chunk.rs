//! Chunks: a BVH over more than [`CHUNK_SPLATS`] splats (`BvhParams::chunk_splats`) is built a
//! chunk at a time. The splats'
//! Morton codes (`math::morton`, over the bounds of their centres) make an octree whose cells
//! split while they hold more than [`CHUNK_SPLATS`]; the cells that stay whole are the chunks,
//! each built as a tree of its own (binned SAH), and the octree's cells above them become the
//! top nodes. A build holds one chunk's primitives at a time, and a build out of core (a chunk
//! read from disk at a time, `pointray_io::prepare`) makes the same tree: the plan needs only
//! passes over the codes, and the chunks are runs of the Morton order the preprocessing sorts
//! points in, so each chunk's splats come in the order an in-memory build gives them.

use arrayvec::ArrayVec;
use glam::Vec3;
use rayon::prelude::*;

use super::build::{BvhParams, TooLarge, Tree};
use super::{LEAF, MAX_BLOCKS, Node, WIDTH};
use crate::accel::block::snap;
use crate::accel::representative::wide_radius;
use crate::math::{Aabb, morton};
use crate::splat::Splat;

/// The most splats a chunk holds (unless one finest Morton cell holds more): at some 150 bytes
/// a splat while it is built, 600 MB.
pub const CHUNK_SPLATS: usize = 1 << 22;

/// Levels of the Morton octree: 21 of three bits, the 63 bits of a code.
const LEVELS: u32 = 21;

/// A cell of the Morton octree: the codes whose first `3·level` bits are `prefix`, `count` of
/// them in the cloud.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cell {
    pub level: u32,
    pub prefix: u64,
    pub count: usize,
}

impl Cell {
    /// How far a code is shifted to give its cell's prefix at `level`.
    fn shift(level: u32) -> u32 {
        3 * (LEVELS - level)
    }

    /// The least code in the cell.
    pub fn first_code(&self) -> u64 {
        self.prefix.checked_shl(Self::shift(self.level)).unwrap_or(0)
    }

    /// Which of the cell's eight children `code` (one of its codes) lies in.
    fn child_of(&self, code: u64) -> usize {
        (code >> Self::shift(self.level + 1) & 7) as usize
    }

    /// The centre of the cell's box, in the frame of the `bounds` whose codes made it (as
    /// `math::morton::encode` divides them: each axis in 2²¹ steps).
    pub fn center(&self, bounds: &Aabb) -> Vec3 {
        let mut at = [0u64; 3];
        for l in (0..self.level).rev() {
            let step = self.prefix >> (3 * l) & 7;
            for (k, a) in at.iter_mut().enumerate() {
                *a = *a << 1 | (step >> k & 1);
            }
        }
        let cells = (1u64 << self.level) as f32;
        let unit = Vec3::new(at[0] as f32 + 0.5, at[1] as f32 + 0.5, at[2] as f32 + 0.5) / cells;
        bounds.min + unit * bounds.extent()
    }
}

/// The chunks of a cloud: the cells of its Morton octree that hold at most [`CHUNK_SPLATS`]
/// splats and whose parents hold more, in Morton order.
#[derive(Clone, Debug)]
pub struct ChunkPlan {
    bounds: Aabb,
    chunks: Vec<Cell>,
}

impl ChunkPlan {
    /// The plan for `count` splats whose centres lie in `bounds`, in chunks of at most
    /// `most` (`BvhParams::chunk_splats`): `pass` calls its argument with the [`Self::code`]
    /// of every splat, once each time it is called (a pass over the cloud for each octree
    /// level split; the codes in any order).
    pub fn new(bounds: Aabb, count: usize, most: usize, mut pass: impl FnMut(&mut dyn FnMut(u64))) -> ChunkPlan {
        let root = Cell { level: 0, prefix: 0, count };
        let (mut chunks, mut open) = (Vec::new(), Vec::new());
        if count > most {
            open.push(root)
        } else {
            chunks.push(root)
        }
        while let Some(level) = open.first().map(|c: &Cell| c.level) {
            // The open cells are of one level, in the order of their prefixes.
            let mut counts = vec![[0usize; 8]; open.len()];
            pass(&mut |code| {
                let prefix = code.checked_shr(Cell::shift(level)).unwrap_or(0);
                if let Ok(i) = open.binary_search_by_key(&prefix, |c| c.prefix) {
                    counts[i][open[i].child_of(code)] += 1;
                }
            });
            let mut next = Vec::new();
            for (cell, counts) in open.iter().zip(&counts) {
                for (j, &count) in counts.iter().enumerate().filter(|(_, n)| **n > 0) {
                    let child = Cell { level: level + 1, prefix: cell.prefix << 3 | j as u64, count };
                    if count > most && child.level < LEVELS { next.push(child) } else { chunks.push(child) }
                }
            }
            open = next;
        }
        chunks.sort_unstable_by_key(Cell::first_code);
        ChunkPlan { bounds, chunks }
    }

    /// The Morton code of a splat's centre: what the plan splits and [`Self::chunk_of`] takes.
    pub fn code(&self, center: Vec3) -> u64 {
        morton::encode(center, &self.bounds)
    }

    /// The chunk holding `code`.
    pub fn chunk_of(&self, code: u64) -> usize {
        self.chunks.partition_point(|c| c.first_code() <= code) - 1
    }

    pub fn chunks(&self) -> &[Cell] {
        &self.chunks
    }

    /// The bounds whose Morton codes the plan splits.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The chunks grouped into the parts of a two-level scene (`super::two_level`): the
    /// octree's cells that hold at most `most` splats (`BvhParams::part_splats`, at least the
    /// chunks' limit) and whose parents hold more, each with the plan of its chunks (over the
    /// same bounds), in Morton order. Found from the chunks' counts alone (a cell's count is its
    /// chunks'), it is the plan [`Self::new`] makes with `most`, so no pass over the splats.
    pub fn parts(&self, most: usize) -> Vec<(Cell, ChunkPlan)> {
        let mut parts = Vec::new();
        self.group(&self.chunks, 0, most, &mut parts);
        parts
    }

    /// [`Self::parts`] of `chunks`, every one below one cell of `level`.
    fn group(&self, chunks: &[Cell], level: u32, most: usize, parts: &mut Vec<(Cell, ChunkPlan)>) {
        let prefix = chunks[0].first_code().checked_shr(Cell::shift(level)).unwrap_or(0);
        let cell = Cell { level, prefix, count: chunks.iter().map(|c| c.count).sum() };
        if cell.count <= most || chunks.len() == 1 {
            parts.push((cell, ChunkPlan { bounds: self.bounds, chunks: chunks.to_vec() }));
            return;
        }
        // Several chunks: each lies in a child of this cell.
        let mut start = 0;
        for end in 1..=chunks.len() {
            if end == chunks.len()
                || cell.child_of(chunks[end].first_code()) != cell.child_of(chunks[start].first_code())
            {
                self.group(&chunks[start..end], level + 1, most, parts);
                start = end;
            }
        }
    }

    /// The octree's nodes above the chunks (see [`Top`]).
    pub(super) fn top(&self) -> Top {
        let mut top = Top { nodes: Vec::new(), depths: vec![0; self.chunks.len()], root: Child::Chunk(0) };
        top.root = top.subtree(&self.chunks, 0, 0, 0);
        top
    }
}

/// A top node's child: another top node or a chunk's root.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Child {
    Node(usize),
    Chunk(usize),
}

/// The octree's cells above the chunks that hold more than one non-empty child (one with a
/// single child passes it up), depth first, parents before their children: the top nodes of a
/// chunked BVH, before every chunk's nodes.
pub(super) struct Top {
    pub(super) nodes: Vec<ArrayVec<Child, WIDTH>>,
    /// The top nodes above each chunk: where its build starts (see `MEDIAN_SPLIT_DEPTH`).
    pub(super) depths: Vec<usize>,
    pub(super) root: Child,
}

impl Top {
    /// The subtree over `chunks` (the chunks from `first` on, all below one cell of `level`),
    /// `depth` top nodes down.
    fn subtree(&mut self, chunks: &[Cell], first: usize, level: u32, depth: usize) -> Child {
        if let [_] = chunks {
            self.depths[first] = depth;
            return Child::Chunk(first);
        }
        let parent =
            Cell { level, prefix: chunks[0].first_code().checked_shr(Cell::shift(level)).unwrap_or(0), count: 0 };
        let mut groups: ArrayVec<(usize, usize), WIDTH> = ArrayVec::new();
        for (i, c) in chunks.iter().enumerate() {
            match groups.last_mut() {
                Some((start, end))
                    if parent.child_of(chunks[*start].first_code()) == parent.child_of(c.first_code()) =>
                {
                    *end = i + 1
                }
                _ => groups.push((i, i + 1)),
            }
        }
        if let [(start, end)] = groups[..] {
            return self.subtree(&chunks[start..end], first + start, level + 1, depth);
        }
        let at = self.nodes.len();
        self.nodes.push(ArrayVec::new());
        for (start, end) in groups {
            let child = self.subtree(&chunks[start..end], first + start, level + 1, depth + 1);
            self.nodes[at].push(child);
        }
        Child::Node(at)
    }
}

/// The chunked build of `input` (more than `params.chunk_splats` splats) in memory: each chunk's
/// tree made and appended in turn, the top's nodes first.
pub(super) fn build(input: Vec<Splat>, params: &BvhParams) -> Result<Tree, TooLarge> {
    let plan = plan_of(&input, params.chunk_splats);
    let (input, order) = in_chunk_order(input, &plan);
    let mut tree = build_planned(input, &plan, params)?;
    if let Some(order) = order {
        tree.ids.iter_mut().filter(|id| **id != u32::MAX).for_each(|id| *id = order[*id as usize]);
    }
    Ok(tree)
}

/// The chunk plan of `input` (over its centres' bounds), chunks of at most `most` splats.
pub(super) fn plan_of(input: &[Splat], most: usize) -> ChunkPlan {
    let bounds = Aabb::from_points(input.iter().map(|s| s.center));
    ChunkPlan::new(bounds, input.len(), most, |f| input.iter().for_each(|s| f(morton::encode(s.center, &bounds))))
}

/// The chunked build of `input`, in the order of `plan`'s chunks (a run of each chunk's
/// splats after another), its ids their places in `input`.
pub(super) fn build_planned(mut input: Vec<Splat>, plan: &ChunkPlan, params: &BvhParams) -> Result<Tree, TooLarge> {
    snap(&mut input);
    let wide_radius = wide_radius(&input);
    let top = plan.top();
    let mut merged = Merge::new(&top, input.len());
    let mut first = 0;
    for (c, cell) in plan.chunks().iter().enumerate() {
        let mut tree = Tree::build(&input[first..first + cell.count], params, top.depths[c])?;
        tree.ids.iter_mut().filter(|id| **id != u32::MAX).for_each(|id| *id += first as u32);
        merged.append(tree, top.depths[c])?;
        first += cell.count;
    }
    drop(input);
    Ok(Tree { wide_radius, ..merged.finish(&top) })
}

/// `input` in the order of its chunks (stable), and where each came from if that moved any.
pub(super) fn in_chunk_order(input: Vec<Splat>, plan: &ChunkPlan) -> (Vec<Splat>, Option<Vec<u32>>) {
    let chunk: Vec<u32> = input.par_iter().map(|s| plan.chunk_of(plan.code(s.center)) as u32).collect();
    // Sorted by the preprocessing, the input is in chunk order already.
    if chunk.windows(2).all(|w| w[0] <= w[1]) {
        return (input, None);
    }
    let mut next: Vec<usize> = plan
        .chunks()
        .iter()
        .scan(0, |at, c| {
            let first = *at;
            *at += c.count;
            Some(first)
        })
        .collect();
    let mut order = vec![0u32; input.len()];
    for (i, &c) in chunk.iter().enumerate() {
        order[next[c as usize]] = i as u32;
        next[c as usize] += 1;
    }
    let sorted = order.iter().map(|&i| input[i as usize]).collect();
    (sorted, Some(order))
}

/// A chunked tree assembled chunk by chunk: the top's nodes (filled in last), then each
/// chunk's nodes and blocks appended, their references moved past what came before.
struct Merge {
    tree: Tree,
    /// Each chunk's root and bounds, as appended.
    roots: Vec<(u32, Aabb)>,
}

impl Merge {
    fn new(top: &Top, splats: usize) -> Merge {
        let tree = Tree {
            nodes: vec![Node::new(&[]); top.nodes.len()],
            blocks: Vec::new(),
            counts: Vec::new(),
            ids: Vec::new(),
            bounds: Aabb::EMPTY,
            depth: 0,
            splat_count: splats,
            wide_radius: 0.0,
            octree_nodes: top.nodes.len(),
        };
        Merge { tree, roots: Vec::new() }
    }

    /// Appends the next chunk's tree (its ids the input's already), `depth` top nodes down.
    fn append(&mut self, chunk: Tree, depth: usize) -> Result<(), TooLarge> {
        let (node_offset, block_offset) = (self.tree.nodes.len() as u32, self.tree.blocks.len() as u32);
        if self.tree.blocks.len() + chunk.blocks.len() > MAX_BLOCKS {
            return Err(TooLarge::Blocks(self.tree.blocks.len() + chunk.blocks.len()));
        }
        self.roots.push((node_offset, chunk.bounds));
        self.tree.nodes.extend(chunk.nodes.iter().map(|n| moved(n, node_offset, block_offset)));
        self.tree.blocks.extend_from_slice(&chunk.blocks);
        self.tree.counts.extend_from_slice(&chunk.counts);
        self.tree.ids.extend_from_slice(&chunk.ids);
        self.tree.bounds = self.tree.bounds.union(chunk.bounds);
        self.tree.depth = self.tree.depth.max(depth + chunk.depth);
        Ok(())
    }

    /// The tree, its top's nodes made from the chunks' bounds.
    fn finish(mut self, top: &Top) -> Tree {
        top_nodes(top, &self.roots, &mut self.tree.nodes);
        self.tree
    }
}

/// Writes the top's nodes (the first `top.nodes.len()` of `nodes`) over the chunks' `roots`.
pub(super) fn top_nodes(top: &Top, roots: &[(u32, Aabb)], nodes: &mut [Node]) {
    let mut bounds = vec![Aabb::EMPTY; top.nodes.len()];
    // Children after their parents: from the back, every child's bounds are known.
    for k in (0..top.nodes.len()).rev() {
        let children: ArrayVec<(u32, Aabb), WIDTH> = top.nodes[k]
            .iter()
            .map(|&c| match c {
                Child::Node(i) => (i as u32, bounds[i]),
                Child::Chunk(c) => roots[c],
            })
            .collect();
        let boxes: ArrayVec<Aabb, WIDTH> = children.iter().map(|c| c.1).collect();
        nodes[k] = Node::new(&boxes);
        for (i, (child, b)) in children.iter().enumerate() {
            nodes[k].child[i] = *child;
            bounds[k] = bounds[k].union(*b);
        }
    }
}

/// `node` with its children moved past `nodes` nodes and `blocks` blocks.
fn moved(node: &Node, nodes: u32, blocks: u32) -> Node {
    let mut node = *node;
    for i in (0..WIDTH).filter(|i| node.used & (1 << i) != 0) {
        node.child[i] += if node.child[i] & LEAF != 0 { blocks } else { nodes };
    }
    node
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::Accel;
    use crate::accel::bvh::Bvh;

    /// `n` disks on a sphere (a golden spiral), shuffled by a fixed stride.
    fn sphere(n: usize) -> Vec<Splat> {
        let at = |i: usize| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let phi = i as f32 * 2.399_963;
            let r = (1.0 - z * z).sqrt();
            let p = Vec3::new(r * phi.cos(), r * phi.sin(), z);
            Splat { center: p * 10.0, radius: 0.05, normal: p, color: i as u32 }
        };
        (0..n).map(|i| at(i * 7_919 % n)).collect()
    }

    #[test]
    fn the_plan_covers_every_splat_once_in_chunks_of_at_most_the_limit() {
        let splats = sphere(30_000);
        let plan = plan_of(&splats, 1_000);
        let chunks = plan.chunks();
        assert!(chunks.len() > 30, "{} chunks", chunks.len());
        assert!(chunks.windows(2).all(|w| w[0].first_code() < w[1].first_code()), "Morton order");
        assert!(chunks.iter().all(|c| c.count <= 1_000 && c.count > 0));
        let mut counted = vec![0; chunks.len()];
        for s in &splats {
            counted[plan.chunk_of(plan.code(s.center))] += 1;
        }
        assert_eq!(counted, chunks.iter().map(|c| c.count).collect::<Vec<_>>());
        let top = plan.top();
        assert!(top.nodes.iter().all(|n| n.len() >= 2), "a top node of one child");
        assert_eq!(top.root, Child::Node(0));
        assert!(top.depths.iter().all(|&d| d >= 1));
    }

    #[test]
    fn a_cell_that_cannot_split_stays_one_chunk() {
        let splats = vec![Splat { center: Vec3::ONE, radius: 0.1, normal: Vec3::Z, color: 0 }; 50];
        let plan = plan_of(&splats, 8);
        assert_eq!(plan.chunks().len(), 1);
        assert_eq!(plan.chunks()[0].level, LEVELS);
        assert_eq!(plan.top().root, Child::Chunk(0));
    }

    #[test]
    fn a_chunked_build_names_each_input_splat_once() {
        let splats = sphere(20_000);
        let params = BvhParams { chunk_splats: 700, ..BvhParams::standard() };
        let (bvh, ids) = Bvh::build_with_ids(splats.clone(), &params);
        let mut snapped = splats.clone();
        snap(&mut snapped);
        let mut seen = vec![false; splats.len()];
        for (slot, &id) in ids.iter().enumerate().filter(|(_, id)| **id != u32::MAX) {
            assert!(!std::mem::replace(&mut seen[id as usize], true), "splat {id} twice");
            assert_eq!(bvh.splat(slot as u32).bits(), snapped[id as usize].bits(), "slot {slot}");
        }
        assert!(seen.iter().all(|&s| s));
        // The blocks hold the chunks one after another.
        let plan = plan_of(&splats, 700);
        let chunk_of = |id: u32| plan.chunk_of(plan.code(splats[id as usize].center));
        let chunks: Vec<usize> = ids.iter().filter(|id| **id != u32::MAX).map(|&id| chunk_of(id)).collect();
        assert!(chunks.windows(2).all(|w| w[0] <= w[1]) && chunks.last() == Some(&(plan.chunks().len() - 1)));
        let whole = Bvh::build(splats.clone(), &BvhParams::standard());
        assert_eq!(bvh.splat_count, whole.splat_count);
        assert_eq!(bvh.bounds, whole.bounds);
        assert_eq!(bvh.wide_radius, whole.wide_radius);
    }
}
