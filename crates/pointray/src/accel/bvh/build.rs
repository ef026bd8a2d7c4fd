//! Binned SAH build (Wald 2007): at each node, bin the primitives' centroids into `bins`
//! slots along each axis, sweep the bins for the split with the least surface-area cost, and
//! recurse on both halves in parallel.

use glam::{Vec3, Vec3A};
use rayon::join;
use rayon::prelude::*;

use super::{Bvh, MAX_LEAF_SIZE, MAX_SPLATS, MEDIAN_SPLIT_DEPTH, Node, NodeBounds, WIDTH, leaf_ref};
use crate::accel::block::{BLOCK, SplatBlock};
use crate::accel::representative::{LOD_FLOOR_QUANTILE, radius_quantile, wide_radius};
use crate::math::Aabb;
use crate::splat::{DiskShape, Splat};

/// Build parameters, with named presets (as in obvhs).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct BvhParams {
    /// Centroid bins per axis.
    pub bins: usize,
    /// A node with more splats than this is always split.
    pub max_leaf_size: usize,
    /// SAH cost of one traversal step (eight box tests), relative to `intersection_cost`.
    pub traversal_cost: f32,
    /// SAH cost of testing one block of up to eight disks (leaves are priced in blocks, as
    /// they are tested).
    pub intersection_cost: f32,
    /// Which bounds the nodes test (it changes no hit, only the work).
    pub node_bounds: NodeBounds,
    /// The disks the bounds hold: ray-facing disks need the splats' balls.
    pub shape: DiskShape,
}

impl BvhParams {
    /// The default: 16 bins, leaves of up to 16 splats, a traversal step priced at two
    /// leaf-block tests. Measured with callgrind on the dragon with blocks of eight (first hit):
    /// leaves of 8 or 16 and traversal costs of 1, 2 or 4 all within 0.3 % of each other.
    pub fn standard() -> Self {
        Self {
            bins: 16,
            max_leaf_size: 16,
            traversal_cost: 2.0,
            intersection_cost: 1.0,
            node_bounds: NodeBounds::Boxes,
            shape: DiskShape::Oriented,
        }
    }

    /// Quicker build, somewhat slower rays.
    pub fn fast() -> Self {
        Self { bins: 8, max_leaf_size: 16, traversal_cost: 1.0, intersection_cost: 1.0, ..Self::standard() }
    }

    /// Slower build, small leaves.
    pub fn precise() -> Self {
        Self { bins: 32, max_leaf_size: 4, traversal_cost: 1.0, intersection_cost: 1.0, ..Self::standard() }
    }

    /// Every preset, for tests and benchmarks.
    pub fn presets() -> [(&'static str, BvhParams); 3] {
        [("standard", Self::standard()), ("fast", Self::fast()), ("precise", Self::precise())]
    }
}

/// A box with its corners in SIMD lanes, for the build's inner loops: one instruction a union
/// where [`Aabb`] takes six. With it (and the two bounds found in one pass) loading the
/// prepared dragon and building its BVH went from 3.15 to 2.70 billion instructions
/// (callgrind), the same tree.
#[derive(Clone, Copy)]
struct Box3 {
    min: Vec3A,
    max: Vec3A,
}

impl Box3 {
    const EMPTY: Box3 = Box3 { min: Vec3A::INFINITY, max: Vec3A::NEG_INFINITY };

    #[inline(always)]
    fn union(self, o: Box3) -> Box3 {
        Box3 { min: self.min.min(o.min), max: self.max.max(o.max) }
    }

    #[inline(always)]
    fn grow(self, p: Vec3A) -> Box3 {
        Box3 { min: self.min.min(p), max: self.max.max(p) }
    }

    fn aabb(self) -> Aabb {
        Aabb::new(self.min.into(), self.max.into())
    }
}

/// A primitive during the build: its bounds and the splat it stands for. The corners are
/// stored as three floats each (28 bytes a primitive, where `Box3` would pad to 48: 400 MB
/// more at 20 million splats) and loaded into lanes as they are used.
#[derive(Clone, Copy)]
struct Prim {
    min: Vec3,
    max: Vec3,
    index: u32,
}

impl Prim {
    #[inline(always)]
    fn bounds(&self) -> Box3 {
        Box3 { min: self.min.into(), max: self.max.into() }
    }

    /// The centre of the bounds, `Aabb::center` lane by lane.
    #[inline(always)]
    fn centroid(&self) -> Vec3A {
        (Vec3A::from(self.min) + Vec3A::from(self.max)) * 0.5
    }
}

enum BuildNode {
    Leaf { bounds: Aabb, first: usize, count: usize },
    Inner { bounds: Aabb, children: Box<[BuildNode; 2]> },
}

impl BuildNode {
    fn bounds(&self) -> Aabb {
        match self {
            BuildNode::Leaf { bounds, .. } | BuildNode::Inner { bounds, .. } => *bounds,
        }
    }

    /// The leaf blocks below.
    fn block_count(&self) -> usize {
        match self {
            BuildNode::Leaf { count, .. } => count.div_ceil(BLOCK),
            BuildNode::Inner { children, .. } => children[0].block_count() + children[1].block_count(),
        }
    }
}

/// Below this many primitives a subtree is built on the current thread.
const PARALLEL_THRESHOLD: usize = 8 * 1024;

impl Bvh {
    /// # Panics
    /// With more than [`MAX_SPLATS`] splats, or parameters out of range.
    ///
    /// Memory: each array is allocated once at its final size and every temporary is dropped
    /// as soon as it is used, so that the peak is the splats in leaf order beside the blocks
    /// made from them (with the representatives apart and the leaf blocks counted ahead, a
    /// render of a 2-million-point torus peaked at 274 MB where it took 408 MB,
    /// `/usr/bin/time`; with the splats kept only in blocks and the level of detail read from
    /// them, a 20-million-point torus's render 1.72 → 1.59 GB).
    pub fn build(input: Vec<Splat>, params: &BvhParams) -> Bvh {
        assert!((2..=MAX_BINS).contains(&params.bins) && (1..=MAX_LEAF_SIZE).contains(&params.max_leaf_size));
        assert!(input.len() <= MAX_SPLATS, "a BVH indexes at most {MAX_SPLATS} splats");
        let mut prims: Vec<Prim> = input
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let b = s.bounds_as(params.shape);
                Prim { min: b.min, max: b.max, index: i as u32 }
            })
            .collect();
        let root = build_node(&mut prims, 0, params, 0);
        // The leaf order alone (4 bytes a splat) before the gather, so that the primitives (28)
        // are gone by then; and gone after it: kept in the BVH, it was 80 MB of a 20-million-point
        // render's peak that nothing read.
        let order: Vec<u32> = prims.iter().map(|p| p.index).collect();
        drop(prims);
        let splats: Vec<Splat> = order.par_iter().map(|&i| input[i as usize]).collect();
        drop((input, order));
        let bounds = root.bounds();
        let mut nodes = Vec::with_capacity(splats.len() / params.max_leaf_size.max(2) + 1);
        let mut spans = Vec::with_capacity(root.block_count());
        let depth = match root {
            BuildNode::Leaf { count: 0, .. } => 0, // no splats: no nodes
            root => flatten(root, &mut nodes, &mut spans),
        };
        // The capacity guessed above is about twice the 8-wide tree's nodes: 8 bytes a splat.
        nodes.shrink_to_fit();
        let (wide_radius, splat_count) = (wide_radius(&splats), splats.len());
        // The blocks in parallel (serially they took an eighth of the dragon's build); from then
        // on they are the only copy of the splats.
        let blocks: Vec<SplatBlock> =
            spans.par_iter().map(|&(first, count)| SplatBlock::new(&splats[first..first + count])).collect();
        let counts: Vec<u8> = spans.iter().map(|&(_, count)| count as u8).collect();
        drop(spans);
        drop(splats);
        let disks = super::lod::Disks { blocks: &blocks, counts: &counts };
        let (lod, representatives) = super::lod::build(&mut nodes, &disks, params.shape);
        drop(counts);
        let lod_floor = radius_quantile(nodes.iter().map(|n| n.min_radius).collect(), LOD_FLOOR_QUANTILE);
        let mut bvh = Bvh {
            nodes,
            lod,
            blocks,
            representatives,
            splat_count,
            bounds,
            depth,
            node_bounds: NodeBounds::Boxes,
            lod_floor,
            wide_radius,
            shape: params.shape,
        };
        bvh.set_node_bounds(params.node_bounds);
        bvh
    }
}

/// Writes the 8-wide node for `node` and, depth first, the nodes below it; returns the depth.
///
/// The node's children are found by opening binary inner nodes, the largest surface first,
/// until there are eight (SAH-wise, the child most likely to be entered is the one worth
/// replacing by its children). A root that is a single leaf becomes a node with one child.
/// `spans` gets each leaf block's first splat and splat count, in the order of the blocks.
fn flatten(node: BuildNode, nodes: &mut Vec<Node>, spans: &mut Vec<(usize, usize)>) -> usize {
    let mut children = vec![node];
    while children.len() < WIDTH {
        let widest = children
            .iter()
            .enumerate()
            .filter(|(_, c)| matches!(c, BuildNode::Inner { .. }))
            .max_by(|(_, a), (_, b)| a.bounds().half_area().total_cmp(&b.bounds().half_area()))
            .map(|(i, _)| i);
        let Some(i) = widest else { break };
        let BuildNode::Inner { children: pair, .. } = children.swap_remove(i) else { unreachable!() };
        children.extend(*pair);
    }
    let at = nodes.len();
    let bounds: Vec<Aabb> = children.iter().map(BuildNode::bounds).collect();
    nodes.push(Node::new(&bounds));
    let mut depth = 1;
    for (i, c) in children.into_iter().enumerate() {
        match c {
            BuildNode::Leaf { first, count, .. } => {
                let first_block = spans.len();
                spans.extend(
                    (first..first + count).step_by(BLOCK).map(|start| (start, BLOCK.min(first + count - start))),
                );
                nodes[at].child[i] = leaf_ref(first_block, count);
            }
            inner @ BuildNode::Inner { .. } => {
                nodes[at].child[i] = nodes.len() as u32;
                depth = depth.max(1 + flatten(inner, nodes, spans));
            }
        }
    }
    depth
}

/// Builds the subtree over `prims`, which start at `offset` in the final splat order.
fn build_node(prims: &mut [Prim], offset: usize, params: &BvhParams, depth: usize) -> BuildNode {
    // The bounds and the centroids' bounds in one pass.
    let bounds_of = |prims: &[Prim]| {
        prims.iter().fold((Box3::EMPTY, Box3::EMPTY), |(b, c), p| (b.union(p.bounds()), c.grow(p.centroid())))
    };
    let union = |(b0, c0): (Box3, Box3), (b1, c1): (Box3, Box3)| (b0.union(b1), c0.union(c1));
    let (bounds, centroids) = over_chunks(prims, bounds_of, || (Box3::EMPTY, Box3::EMPTY), union);
    let bounds = bounds.aabb();
    let n = prims.len();
    let leaf = || BuildNode::Leaf { bounds, first: offset, count: n };
    // A split costs more than a traversal step, so a leaf that costs no more stays a leaf:
    // the same tree without binning it (with the default costs, every node of up to 16 splats;
    // loading the prepared dragon and building its BVH 2.54 → 2.28 billion instructions).
    if n <= 1 || n <= params.max_leaf_size && blocks(n) * params.intersection_cost <= params.traversal_cost {
        return leaf();
    }
    let split = if depth >= MEDIAN_SPLIT_DEPTH {
        // Pathological distributions (SAH peeling one primitive at a time) end here: object
        // median splits bound the remaining depth by log2(n).
        None
    } else {
        best_sah_split(prims, &bounds, &centroids.aabb(), params)
    };
    let mid = match split {
        Some(s) if s.cost < blocks(n) * params.intersection_cost || n > params.max_leaf_size => {
            partition(prims, |p| s.goes_left(p.centroid()))
        }
        None if n > params.max_leaf_size => median_split(prims),
        _ => return leaf(),
    };
    let mid = if mid == 0 || mid == n { median_split(prims) } else { mid };
    let (left, right) = prims.split_at_mut(mid);
    let (l, r) = if n >= PARALLEL_THRESHOLD {
        join(|| build_node(left, offset, params, depth + 1), || build_node(right, offset + mid, params, depth + 1))
    } else {
        (build_node(left, offset, params, depth + 1), build_node(right, offset + mid, params, depth + 1))
    };
    BuildNode::Inner { bounds, children: Box::new([l, r]) }
}

struct Split {
    axis: usize,
    bin: usize,
    lo: f32,
    scale: f32,
    cost: f32,
}

impl Split {
    /// Whether a centroid's bin, ⌊v⌋ for v = (c − lo)·scale, capped at the last, lies left of
    /// the split: for the finite, non-negative values binning gives, ⌊v⌋ < b exactly when
    /// v < b, and a NaN goes left, as its conversion to bin 0 sent it. The same partitions
    /// without converting v to an integer, which Rust's saturating `as usize` does in ~15
    /// instructions, a primitive at every level (loading the prepared dragon and building its
    /// BVH: 2.22 → 2.12 billion instructions, callgrind; the torus's build 4 % faster,
    /// alternating runs).
    #[inline(always)]
    fn goes_left(&self, c: Vec3A) -> bool {
        let v = (c[self.axis] - self.lo) * self.scale;
        v < self.bin as f32 || v.is_nan()
    }
}

/// Blocks a leaf of `n` splats is tested as (see `accel::block`).
fn blocks(n: usize) -> f32 {
    n.div_ceil(BLOCK) as f32
}

/// Most bins per axis (the binning arrays live on the stack).
pub(crate) const MAX_BINS: usize = 32;

/// Nodes of this many primitives and more are binned, and their bounds found, in parallel
/// chunks: the top of the tree holds every primitive and has only one node to work on. The
/// union of boxes and the sum of counts do not depend on the chunks: the same tree. (The
/// dragon's build 0.094 → 0.092 s, 2 threads, medians of five.)
const PARALLEL_BINNING: usize = 64 * 1024;

/// `pass` over all of `prims`: serially, or, from [`PARALLEL_BINNING`] primitives on, over
/// chunks in parallel, the results merged (`empty` is `merge`'s identity).
fn over_chunks<T: Send>(
    prims: &[Prim],
    pass: impl Fn(&[Prim]) -> T + Sync + Send,
    empty: impl Fn() -> T + Sync + Send,
    merge: impl Fn(T, T) -> T + Sync + Send,
) -> T {
    if prims.len() >= PARALLEL_BINNING {
        prims.par_chunks(PARALLEL_BINNING / 2).map(pass).reduce(empty, merge)
    } else {
        pass(prims)
    }
}

/// Where a centroid falls: bin ⌊(c − lo)·scale⌋ per axis, at most `last`.
struct Binning {
    lo: Vec3A,
    scale: Vec3A,
    last: Vec3A,
}

/// Per axis and bin, the bounds and the number of the primitives whose centroids fall there.
struct Bins {
    boxes: [[Box3; MAX_BINS]; 3],
    counts: [[usize; MAX_BINS]; 3],
}

impl Bins {
    fn empty() -> Self {
        Bins { boxes: [[Box3::EMPTY; MAX_BINS]; 3], counts: [[0; MAX_BINS]; 3] }
    }

    fn merge(mut self, other: Bins) -> Bins {
        for axis in 0..3 {
            for b in 0..MAX_BINS {
                self.boxes[axis][b] = self.boxes[axis][b].union(other.boxes[axis][b]);
                self.counts[axis][b] += other.counts[axis][b];
            }
        }
        self
    }
}

impl Binning {
    /// All three axes in one pass.
    fn bin(&self, prims: &[Prim]) -> Bins {
        let mut bins = Bins::empty();
        for p in prims {
            // ⌊(c − lo)·scale⌋ on the three axes at once: the centroids lie at or above `lo`, so the
            // clamp before the conversion is the clamp after it.
            let b = ((p.centroid() - self.lo) * self.scale).min(self.last).as_uvec3();
            for axis in 0..3 {
                let b = b[axis] as usize;
                bins.boxes[axis][b] = bins.boxes[axis][b].union(p.bounds());
                bins.counts[axis][b] += 1;
            }
        }
        bins
    }
}

/// The cheapest binned SAH split over all three axes, or `None` when all centroids coincide.
/// One pass over the primitives bins all three axes at once (`cb`: the centroids' bounds).
fn best_sah_split(prims: &[Prim], bounds: &Aabb, cb: &Aabb, params: &BvhParams) -> Option<Split> {
    let bins = params.bins;
    let lo = cb.min;
    let extent = cb.extent();
    let scale = Vec3::select(extent.cmpgt(Vec3::ZERO), Vec3::splat(bins as f32) / extent, Vec3::ZERO);
    let binning = Binning { lo: Vec3A::from(lo), scale: Vec3A::from(scale), last: Vec3A::splat((bins - 1) as f32) };
    let Bins { boxes: bin_boxes, counts: bin_counts } =
        over_chunks(prims, |c| binning.bin(c), Bins::empty, Bins::merge);
    let bin_bounds = bin_boxes.map(|axis| axis.map(Box3::aabb));
    let parent_area = bounds.half_area().max(f32::MIN_POSITIVE);
    let mut best: Option<Split> = None;
    let mut right_area = [0f32; MAX_BINS];
    for axis in (0..3).filter(|&a| extent[a] > 0.0) {
        let (bin_bounds, bin_counts) = (&bin_bounds[axis], &bin_counts[axis]);
        // Sweep from the right for the areas of the right-hand sides …
        let mut acc = Aabb::EMPTY;
        for b in (1..bins).rev() {
            acc = acc.union(bin_bounds[b]);
            right_area[b] = acc.half_area();
        }
        // … then from the left, pricing every split plane between bin b-1 and b.
        let (mut left, mut left_count) = (Aabb::EMPTY, 0usize);
        for b in 1..bins {
            left = left.union(bin_bounds[b - 1]);
            left_count += bin_counts[b - 1];
            let right_count = prims.len() - left_count;
            if left_count == 0 || right_count == 0 {
                continue;
            }
            let cost = params.traversal_cost
                + params.intersection_cost
                    * (left.half_area() * blocks(left_count) + right_area[b] * blocks(right_count))
                    / parent_area;
            if best.as_ref().is_none_or(|s| cost < s.cost) {
                best = Some(Split { axis, bin: b, lo: lo[axis], scale: scale[axis], cost });
            }
        }
    }
    best
}

/// Moves the elements satisfying `left` to the front; returns how many there are.
fn partition(prims: &mut [Prim], left: impl Fn(&Prim) -> bool) -> usize {
    let mut i = 0;
    for j in 0..prims.len() {
        if left(&prims[j]) {
            prims.swap(i, j);
            i += 1;
        }
    }
    i
}

/// Splits at the median centroid along the widest axis of the centroids (ties by index), so
/// that both halves are non-empty whatever the input.
fn median_split(prims: &mut [Prim]) -> usize {
    let cb = prims.iter().fold(Box3::EMPTY, |b, p| b.grow(p.centroid())).aabb();
    let axis = cb.extent().max_position();
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| {
        a.centroid()[axis].total_cmp(&b.centroid()[axis]).then(a.index.cmp(&b.index))
    });
    mid
}
