//! Binned SAH build (Wald 2007): at each node, bin the primitives' centroids into `bins`
//! slots along each axis, sweep the bins for the split with the least surface-area cost, and
//! recurse on both halves in parallel.

use arrayvec::ArrayVec;
use glam::{Vec3, Vec3A, Vec4};
use rayon::join;
use rayon::prelude::*;

use super::{Bvh, MAX_LEAF_SIZE, MAX_SPLATS, MEDIAN_SPLIT_DEPTH, Node, NodeBounds, WIDTH, leaf_ref};
use crate::accel::block::{BLOCK, SplatBlock, grid_step, leaf_span, snap};
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
    /// Above this many splats the tree is built a chunk of at most this many at a time (see
    /// [`super::ChunkPlan`]; [`super::CHUNK_SPLATS`]).
    pub chunk_splats: usize,
    /// Above this many splats a scene is two-level: parts of at most this many, each a BVH
    /// in a frame of its own (see [`super::TwoLevel`]; [`super::PART_SPLATS`]).
    pub part_splats: usize,
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
            chunk_splats: super::CHUNK_SPLATS,
            part_splats: super::PART_SPLATS,
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

    /// [`Aabb::half_area`], in the same operations.
    #[inline(always)]
    fn half_area(self) -> f32 {
        if self.min.cmpgt(self.max).any() {
            return 0.0;
        }
        let e = self.max - self.min;
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    fn aabb(self) -> Aabb {
        Aabb::new(self.min.into(), self.max.into())
    }

    /// The longest side (−∞ for an empty box).
    fn widest(self) -> f32 {
        (self.max - self.min).max_element()
    }
}

/// A primitive during the build: its bounds and the splat it stands for, in 32 bytes, the
/// corners in SIMD lanes as the inner loops use them (with three floats a corner, loading one
/// into lanes took four instructions: the 1-million-point torus's build 3.58 → 3.40 billion
/// instructions, callgrind). The splat's index rides in the lower corner's fourth lane, as
/// the bits of a float with bit 30 set: a normal number between 2 and 2³³, which no lane's
/// arithmetic slows down, where a bare index would be subnormal. The upper corner's fourth lane
/// holds the splat's grid step (`block::grid_step`), which decides how wide a leaf may be.
#[derive(Clone, Copy)]
struct Prim {
    min: Vec4,
    max: Vec4,
}

/// Set in a [`Prim`]'s index lane; indices take the bits below it.
const INDEX_TAG: u32 = 1 << 30;
const _: () = assert!(MAX_SPLATS <= 1 << 28, "an index lane must stay a normal number below 2^33");

impl Prim {
    fn new(bounds: Aabb, index: u32, grid_step: f32) -> Prim {
        debug_assert!((index as usize) < MAX_SPLATS);
        Prim { min: bounds.min.extend(f32::from_bits(index | INDEX_TAG)), max: bounds.max.extend(grid_step) }
    }

    fn grid_step(&self) -> f32 {
        self.max.w
    }

    fn index(&self) -> u32 {
        self.min.w.to_bits() & !INDEX_TAG
    }

    #[inline(always)]
    fn bounds(&self) -> Box3 {
        Box3 { min: Vec3A::from_vec4(self.min), max: Vec3A::from_vec4(self.max) }
    }

    /// The centre of the bounds, `Aabb::center` lane by lane.
    #[inline(always)]
    fn centroid(&self) -> Vec3A {
        Vec3A::from_vec4((self.min + self.max) * 0.5)
    }
}

enum BuildNode {
    Leaf {
        bounds: Aabb,
        first: usize,
        count: usize,
    },
    /// `slots[j − 1]`: the least SAH cost of the subtree as at most j children of an 8-wide
    /// node (see [`Slots`]); `blocks`, the leaf blocks below.
    Inner {
        bounds: Aabb,
        children: Box<[BuildNode; 2]>,
        slots: Slots,
        blocks: usize,
    },
}

impl BuildNode {
    fn bounds(&self) -> Aabb {
        match self {
            BuildNode::Leaf { bounds, .. } | BuildNode::Inner { bounds, .. } => *bounds,
        }
    }

    /// The least SAH cost of the subtree as at most 1, 2, … 8 children of a wide node.
    fn slots(&self, params: &BvhParams) -> Slots {
        match self {
            BuildNode::Leaf { bounds, count, .. } => {
                Slots([bounds.half_area() * blocks(*count) * params.intersection_cost; WIDTH])
            }
            BuildNode::Inner { slots, .. } => *slots,
        }
    }

    /// The leaf blocks below.
    fn block_count(&self) -> usize {
        match self {
            BuildNode::Leaf { count, .. } => count.div_ceil(BLOCK),
            BuildNode::Inner { blocks, .. } => *blocks,
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
    /// as soon as it is used, so that the peak is the input splats beside the blocks made from
    /// them (with the representatives apart and the leaf blocks counted ahead, a render of a
    /// 2-million-point torus peaked at 274 MB where it took 408 MB, `/usr/bin/time`; with the
    /// splats kept only in blocks and the level of detail read from them, a 20-million-point
    /// torus's render 1.72 → 1.59 GB; with 32-byte primitives and the blocks gathered from the
    /// input, 1.67 GB, for a build 10 % faster).
    pub fn build(input: Vec<Splat>, params: &BvhParams) -> Bvh {
        Self::build_with_ids(input, params).0
    }

    /// [`Self::try_build_with_ids`], which cannot fail below 2²⁷ splats (a block each at worst).
    ///
    /// # Panics
    /// Where that fails, and with parameters out of range.
    pub fn build_with_ids(input: Vec<Splat>, params: &BvhParams) -> (Bvh, Vec<u32>) {
        Self::try_build_with_ids(input, params).unwrap_or_else(|e| panic!("{e}"))
    }

    /// [`Self::build`], with each index's input splat (`ids[index]`, for the indices
    /// [`crate::accel::Accel::splat`] takes; `u32::MAX` for the gaps in partly filled blocks
    /// and the representatives past them): what a ray query needs to name the splat it hit.
    /// An error with more than [`MAX_SPLATS`] splats, or leaves in more blocks than a leaf
    /// reference can name.
    ///
    /// # Panics
    /// With parameters out of range.
    pub fn try_build_with_ids(input: Vec<Splat>, params: &BvhParams) -> Result<(Bvh, Vec<u32>), TooLarge> {
        assert!((2..=MAX_BINS).contains(&params.bins) && (1..=MAX_LEAF_SIZE).contains(&params.max_leaf_size));
        assert!(params.chunk_splats > 0);
        if input.len() > MAX_SPLATS {
            return Err(TooLarge::Splats(input.len()));
        }
        if input.len() > params.chunk_splats {
            return Ok(super::chunk::build(input, params)?.finish(params));
        }
        Self::build_whole(input, params)
    }

    /// [`Self::try_build_with_ids`] of `input` in the order of `plan`'s chunks (a run of each
    /// chunk's splats after another; its chunk limit `params`'): a part of a two-level scene,
    /// whose chunks are those of the scene's plan. A plan of one chunk builds the tree whole.
    pub(super) fn try_build_planned(
        input: Vec<Splat>,
        plan: &super::ChunkPlan,
        params: &BvhParams,
    ) -> Result<(Bvh, Vec<u32>), TooLarge> {
        if input.len() > MAX_SPLATS {
            return Err(TooLarge::Splats(input.len()));
        }
        match plan.chunks() {
            [_] => Self::build_whole(input, params),
            _ => Ok(super::chunk::build_planned(input, plan, params)?.finish(params)),
        }
    }

    /// The tree over `input` built at once (no chunks).
    fn build_whole(mut input: Vec<Splat>, params: &BvhParams) -> Result<(Bvh, Vec<u32>), TooLarge> {
        snap(&mut input);
        // The serial flattening (in `Tree::build`) beside the serial quantile.
        let (tree, wide_radius) = join(|| Tree::build(&input, params, 0), || wide_radius(&input));
        let tree = tree?;
        drop(input);
        Ok(Tree { wide_radius, ..tree }.finish(params))
    }
}

/// A built tree before its level of detail: nodes (children after their parents, depth first),
/// leaf blocks, and the input's index of each block slot.
pub(super) struct Tree {
    pub(super) nodes: Vec<Node>,
    pub(super) blocks: Vec<SplatBlock>,
    /// The splats in each block.
    pub(super) counts: Vec<u8>,
    pub(super) ids: Vec<u32>,
    pub(super) bounds: Aabb,
    pub(super) depth: usize,
    pub(super) splat_count: usize,
    pub(super) wide_radius: f32,
    /// The nodes first in `nodes` that stay in the top whatever they hold: a chunked tree's
    /// octree nodes (`super::chunk`), which its chunks' treelets never include.
    pub(super) octree_nodes: usize,
}

impl Tree {
    /// The tree over `input` (snapped), its root `depth` levels of a binary tree down (see
    /// [`MEDIAN_SPLIT_DEPTH`]); `wide_radius` left for the caller.
    pub(super) fn build(input: &[Splat], params: &BvhParams, depth: usize) -> Result<Tree, TooLarge> {
        let mut prims = prims_of(input, params);
        let extent = Extent::of(&prims);
        let root = build_node(&mut prims, extent, 0, params, depth);
        if root.block_count() > super::MAX_BLOCKS {
            return Err(TooLarge::Blocks(root.block_count()));
        }
        // The leaf order alone (4 bytes a splat), so that the primitives (32) are gone before
        // the blocks are made.
        let order: Vec<u32> = prims.iter().map(Prim::index).collect();
        drop(prims);
        let bounds = root.bounds();
        let mut nodes = Vec::with_capacity(input.len() / params.max_leaf_size.max(2) + 1);
        let mut spans = Vec::with_capacity(root.block_count());
        let depth = match root {
            BuildNode::Leaf { count: 0, .. } => 0, // no splats: no nodes
            root => flatten(root, &mut nodes, &mut spans, params),
        };
        // The capacity guessed above is about twice the 8-wide tree's nodes: 8 bytes a splat.
        nodes.shrink_to_fit();
        // The blocks in parallel, each gathering its splats from the input in leaf order; from
        // then on they are the only copy of the splats. (Gathered first into a vector in leaf
        // order and made into blocks from there, the 1-million-point torus's build took 3 %
        // longer and the 20-million-point one 6.6 s, not 6.0; the render's peak, the input, the
        // order and the blocks side by side, is 1.67 GB, 30 MB more.)
        let blocks: Vec<SplatBlock> = spans
            .par_iter()
            .map(|&(first, count)| {
                let splats: ArrayVec<Splat, BLOCK> =
                    order[first..first + count].iter().map(|&i| input[i as usize]).collect();
                let block = SplatBlock::new(&splats);
                debug_assert!(
                    splats.iter().enumerate().all(|(i, s)| block.splat(i).bits() == s.bits()),
                    "a lossy block"
                );
                block
            })
            .collect();
        let mut ids = vec![u32::MAX; blocks.len() * BLOCK];
        for (b, &(first, count)) in spans.iter().enumerate() {
            ids[b * BLOCK..b * BLOCK + count].copy_from_slice(&order[first..first + count]);
        }
        let counts: Vec<u8> = spans.iter().map(|&(_, count)| count as u8).collect();
        let splat_count = input.len();
        Ok(Tree { nodes, blocks, counts, ids, bounds, depth, splat_count, wide_radius: 0.0, octree_nodes: 0 })
    }

    /// The level of detail, the treelets: the BVH, and the input's index of each block slot.
    pub(super) fn finish(self, params: &BvhParams) -> (Bvh, Vec<u32>) {
        let Tree { mut nodes, blocks, counts, ids, bounds, depth, splat_count, wide_radius, octree_nodes } = self;
        let disks = super::lod::Disks { blocks: &blocks, counts: &counts };
        let lod = super::lod::build(&mut nodes, &disks, params.shape);
        drop(counts);
        let lod_floor = radius_quantile(nodes.iter().map(|n| n.min_radius).collect(), LOD_FLOOR_QUANTILE);
        let cut = super::treelet::partition(nodes, lod, octree_nodes.max(1));
        let mut bvh = Bvh {
            nodes: cut.nodes.into(),
            lod: cut.lod.into(),
            blocks: blocks.into(),
            representatives: cut.representatives.into(),
            aggregates: cut.aggregates.into(),
            treelets: cut.treelets.into(),
            top_nodes: cut.top,
            lazy: None,
            splat_count,
            bounds,
            depth,
            node_bounds: NodeBounds::Boxes,
            plain_walk: true,
            sphere_nodes: 0,
            lod_floor,
            wide_radius,
            coverage_density: Box::default(),
            shape: params.shape,
        };
        bvh.set_node_bounds(params.node_bounds);
        (bvh, ids)
    }
}

/// Why a BVH cannot index a cloud.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TooLarge {
    #[error("{0} splats is more than a BVH indexes ({MAX_SPLATS})")]
    Splats(usize),
    #[error("the leaves take {0} blocks of eight splats, more than a BVH names (2^27): the splats are too scattered")]
    Blocks(usize),
    #[error("the splats and their representatives take {0} indices, more than a scene names (2^32)")]
    Indices(u64),
}

/// The costs by which the binary build tree is collapsed into an 8-wide one: entry j − 1 is the
/// least SAH cost of a subtree as at most j children of a wide node, each child a leaf or the
/// root of a wide node of its own (a traversal step where a ray enters it, plus its children).
/// Found bottom-up as the build returns (a dynamic programme over the binary tree), then
/// followed top-down by [`flatten`] near the leaves. Opening the largest child until there
/// are eight, all the way down, left the 1-million-point torus with 32,668 nodes, half of them
/// with two children: 14,584 now, and 30.3 bytes a splat where that took 39.3.
#[derive(Clone, Copy, Debug)]
struct Slots([f32; WIDTH]);

impl Slots {
    /// An inner node's costs from its children's (`area`: its half surface area).
    fn of_inner(area: f32, l: &Slots, r: &Slots, params: &BvhParams) -> Slots {
        let shared: [f32; WIDTH] =
            std::array::from_fn(|i| if i == 0 { f32::INFINITY } else { Self::split(l, r, i + 1).1 });
        let own = area * params.traversal_cost + shared[WIDTH - 1];
        Slots(shared.map(|cost| own.min(cost)))
    }

    /// The cheapest sharing of `j ≥ 2` slots between children with costs `l` and `r`: the
    /// slots the left one takes (the fewest among equals, one where costs are NaN), and the cost.
    fn split(l: &Slots, r: &Slots, j: usize) -> (usize, f32) {
        let cost = |k: usize| l.0[k - 1] + r.0[j - k - 1];
        (2..j).fold((1, cost(1)), |best, k| if cost(k) < best.1 { (k, cost(k)) } else { best })
    }
}

/// Subtrees of more blocks than this take the largest child first (see [`flatten`]).
const LARGEST_FIRST_ABOVE: usize = 64;

/// The build's primitives for `splats`, in their order.
fn prims_of(splats: &[Splat], params: &BvhParams) -> Vec<Prim> {
    splats
        .par_iter()
        .enumerate()
        .map(|(i, s)| Prim::new(s.bounds_as(params.shape), i as u32, grid_step(s.radius)))
        .collect()
}

/// Writes the 8-wide node for `node` and, depth first, the nodes below it; returns the depth.
///
/// Near the leaves (subtrees of at most [`LARGEST_FIRST_ABOVE`] blocks), a node's children are
/// the binary subtrees the costs of [`Slots`] pick, which fills the nodes. Above, the child
/// with the largest surface is opened until there are eight: the children stay of like size,
/// and so do their representatives, which is where level of detail stops distant rays. (The
/// dragon's distant samples, callgrind: chosen by the slots all the way up, 1,219 instructions
/// at 16 diagonals and 1,178 at 2, for 3 % fewer nodes; this way, 1,199 and 1,157; the largest
/// child first everywhere, 1,189 and 1,147.) A root that is a single leaf becomes a node with
/// one child. `spans` gets each leaf block's first splat and splat count, in block order.
fn flatten(node: BuildNode, nodes: &mut Vec<Node>, spans: &mut Vec<(usize, usize)>, params: &BvhParams) -> usize {
    // On the stack: allocated, the two vectors took a fifth of the time `flatten` took.
    let mut children: ArrayVec<BuildNode, WIDTH> = ArrayVec::new();
    match node {
        BuildNode::Inner { children: pair, blocks, .. } if blocks > LARGEST_FIRST_ABOVE => {
            children.extend(*pair);
            open_largest(&mut children);
        }
        BuildNode::Inner { children: pair, .. } => share(*pair, WIDTH, &mut children, params),
        leaf => children.push(leaf),
    }
    let at = nodes.len();
    let bounds: ArrayVec<Aabb, WIDTH> = children.iter().map(BuildNode::bounds).collect();
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
                depth = depth.max(1 + flatten(inner, nodes, spans, params));
            }
        }
    }
    depth
}

/// Opens the inner child with the largest surface until there are eight children (SAH-wise,
/// the child most likely to be entered is the one worth replacing by its children).
fn open_largest(children: &mut ArrayVec<BuildNode, WIDTH>) {
    while children.len() < WIDTH {
        let largest = children
            .iter()
            .enumerate()
            .filter(|(_, c)| matches!(c, BuildNode::Inner { .. }))
            .max_by(|(_, a), (_, b)| a.bounds().half_area().total_cmp(&b.bounds().half_area()))
            .map(|(i, _)| i);
        let Some(i) = largest else { break };
        let BuildNode::Inner { children: pair, .. } = children.swap_remove(i) else { unreachable!() };
        children.extend(*pair);
    }
}

/// Adds the children `node` becomes when it may take `j` slots: itself (a leaf, or the root
/// of a wide node below) where that costs least, else its children's, shared as [`Slots`] found.
fn gather(node: BuildNode, j: usize, children: &mut ArrayVec<BuildNode, WIDTH>, params: &BvhParams) {
    match node {
        BuildNode::Inner { children: pair, slots, .. } if j > 1 && slots.0[j - 1] < slots.0[0] => {
            share(*pair, j, children, params);
        }
        node => children.push(node),
    }
}

/// [`gather`]s a binary node's two children into `j` slots, shared as [`Slots`] found.
fn share([l, r]: [BuildNode; 2], j: usize, children: &mut ArrayVec<BuildNode, WIDTH>, params: &BvhParams) {
    let (k, _) = Slots::split(&l.slots(params), &r.slots(params), j);
    gather(l, k, children, params);
    gather(r, j - k, children, params);
}

/// The bounds of a node's primitives and of their centroids.
#[derive(Clone, Copy)]
struct Extent {
    bounds: Box3,
    centroids: Box3,
}

impl Extent {
    const EMPTY: Extent = Extent { bounds: Box3::EMPTY, centroids: Box3::EMPTY };

    /// Both bounds in one pass (in parallel chunks for many primitives).
    fn of(prims: &[Prim]) -> Extent {
        let pass = |prims: &[Prim]| {
            prims.iter().fold(Extent::EMPTY, |e, p| Extent {
                bounds: e.bounds.union(p.bounds()),
                centroids: e.centroids.grow(p.centroid()),
            })
        };
        let union = |a: Extent, b: Extent| Extent {
            bounds: a.bounds.union(b.bounds),
            centroids: a.centroids.union(b.centroids),
        };
        over_chunks(prims, pass, || Extent::EMPTY, union)
    }
}

/// Builds the subtree over `prims` (of extent `extent`), which start at `offset` in the final
/// splat order.
fn build_node(prims: &mut [Prim], extent: Extent, offset: usize, params: &BvhParams, depth: usize) -> BuildNode {
    let bounds = extent.bounds.aabb();
    let n = prims.len();
    let leaf = || BuildNode::Leaf { bounds, first: offset, count: n };
    // A leaf's blocks hold their centres exactly only within a span of its finest grid
    // (`block::leaf_span`); wider ones (a few strays) are split whatever the cost.
    let too_wide = || {
        let finest = prims.iter().map(Prim::grid_step).fold(f32::INFINITY, f32::min);
        extent.centroids.widest() > leaf_span(finest)
    };
    let must_split = n > params.max_leaf_size || n > 1 && too_wide();
    // A split costs more than a traversal step, so a leaf that costs no more stays a leaf:
    // the same tree without binning it (with the default costs, every node of up to 16 splats;
    // loading the prepared dragon and building its BVH 2.54 → 2.28 billion instructions).
    if n <= 1 || !must_split && blocks(n) * params.intersection_cost <= params.traversal_cost {
        return leaf();
    }
    let split = if depth >= MEDIAN_SPLIT_DEPTH {
        // Pathological distributions (SAH peeling one primitive at a time) end here: object
        // median splits bound the remaining depth by log2(n).
        None
    } else {
        best_sah_split(prims, &bounds, &extent.centroids.aabb(), params)
    };
    // The halves' extents: an SAH split has them from the partition, and from its bins where
    // it binned every primitive, with no further pass over the primitives (the 1-million-point
    // torus's build 3.73 → 3.61 billion instructions, the same tree).
    let (mid, halves) = match split {
        Some(s) if s.cost < blocks(n) * params.intersection_cost || must_split => {
            let (mid, halves) = match s.bounds {
                Some(bounds) => partition::<false>(prims, &s, bounds),
                None => partition::<true>(prims, &s, [Box3::EMPTY; 2]),
            };
            (mid, Some(halves))
        }
        None if must_split => (median_split(prims), None),
        _ => return leaf(),
    };
    let (mid, halves) = if mid == 0 || mid == n { (median_split(prims), None) } else { (mid, halves) };
    let (left, right) = prims.split_at_mut(mid);
    let [l_extent, r_extent] = halves.unwrap_or_else(|| [Extent::of(left), Extent::of(right)]);
    let (l, r) = if n >= PARALLEL_THRESHOLD {
        join(
            || build_node(left, l_extent, offset, params, depth + 1),
            || build_node(right, r_extent, offset + mid, params, depth + 1),
        )
    } else {
        (
            build_node(left, l_extent, offset, params, depth + 1),
            build_node(right, r_extent, offset + mid, params, depth + 1),
        )
    };
    let slots = Slots::of_inner(bounds.half_area(), &l.slots(params), &r.slots(params), params);
    let blocks = l.block_count() + r.block_count();
    BuildNode::Inner { bounds, children: Box::new([l, r]), slots, blocks }
}

struct Split {
    binning: Binning,
    axis: usize,
    /// The first bin on the right, in every lane.
    bin: Vec3A,
    cost: f32,
    /// The bounds of the primitives on either side, where all were binned: the union of their
    /// bins' bounds.
    bounds: Option<[Box3; 2]>,
}

impl Split {
    /// Whether a centroid's bin lies left of the split: ⌊v⌋ < b exactly when v < b for the
    /// finite, non-negative positions binning gives (a NaN is clamped to the last bin by the
    /// same operations). Compared in lanes, without converting v to an integer, which Rust's
    /// saturating `as usize` does in ~15 instructions, a primitive at every level (loading the
    /// prepared dragon and building its BVH: 2.22 → 2.12 billion instructions, callgrind),
    /// and without picking the axis's lane, which took a branch a primitive.
    #[inline(always)]
    fn goes_left(&self, c: Vec3A) -> bool {
        self.binning.position(c).cmplt(self.bin).bitmask() >> self.axis & 1 != 0
    }
}

/// Blocks a leaf of `n` splats is tested as (see `accel::block`).
fn blocks(n: usize) -> f32 {
    n.div_ceil(BLOCK) as f32
}

/// Nodes of at least twice this many primitives choose their split from about this many of
/// them, evenly strided: the rest only move the split's cost a little, and at the top of the
/// tree binning all took most of the build. (The 1-million-point torus's build, two threads,
/// medians of alternating runs: 0.1347 s binning all against 0.1279 binning every fourth
/// primitive of nodes of more than 1,024; in another set, 0.1228 so against 0.119 from 1,024
/// of them and 0.116 from 256. The dragon's first hits, 256² crop, 694.8 instructions a pixel
/// binning all, 698.4 from 256, 695–697 from 1,024 or 2,048 (which built the torus 3 %
/// slower), as unrelated code moved the count.)
const SAMPLES: usize = 1024;

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
#[derive(Clone, Copy)]
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
    /// (c − lo)·scale on the three axes at once, at most `last`: the centroids lie at or above
    /// `lo`, so the clamp before the conversion to a bin is the clamp after it.
    #[inline(always)]
    fn position(&self, c: Vec3A) -> Vec3A {
        ((c - self.lo) * self.scale).min(self.last)
    }

    /// All three axes in one pass, into `bins`.
    fn bin(&self, prims: &[Prim], stride: usize, bins: &mut Bins) {
        for p in prims.iter().step_by(stride) {
            let b = floor_small(self.position(p.centroid()));
            for axis in 0..3 {
                let b = b[axis] as usize % MAX_BINS;
                bins.boxes[axis][b] = bins.boxes[axis][b].union(p.bounds());
                bins.counts[axis][b] += 1;
            }
        }
    }

    /// [`Binning::bin`] of many primitives, in parallel chunks ([`over_chunks`]).
    fn bin_in_chunks(&self, prims: &[Prim], stride: usize) -> Bins {
        let chunk = |c: &[Prim]| {
            let mut bins = Bins::empty();
            self.bin(c, stride, &mut bins);
            bins
        };
        over_chunks(prims, chunk, Bins::empty, Bins::merge)
    }
}

/// ⌊v⌋ lane by lane for 0 ≤ v < 2²³, in float arithmetic: adding and subtracting 2²³ rounds
/// to the nearest integer, one less where that went up; adding 2²³ again leaves the integer in
/// the low bits. Rust's saturating `as u32` and the bounds checks after it took 24
/// instructions for the three lanes, this 15, a primitive at every level of the build (the
/// 1-million-point torus's build 3.40 → 3.25 billion instructions).
#[inline(always)]
fn floor_small(v: Vec3A) -> [u32; 3] {
    const TWO_23: f32 = 8_388_608.0;
    let m = Vec3A::splat(TWO_23);
    let round = (v + m) - m;
    let floor = round - Vec3A::select(round.cmpgt(v), Vec3A::ONE, Vec3A::ZERO);
    (floor + m).to_array().map(|x| x.to_bits() - TWO_23.to_bits())
}

/// The cheapest binned SAH split over all three axes, or `None` when all centroids coincide.
/// One pass over the primitives (or a sample of them, see [`SAMPLES`]) bins all three axes at
/// once (`cb`: the centroids' bounds).
fn best_sah_split(prims: &[Prim], bounds: &Aabb, cb: &Aabb, params: &BvhParams) -> Option<Split> {
    let bins = params.bins;
    let lo = cb.min;
    let extent = cb.extent();
    let scale = Vec3::select(extent.cmpgt(Vec3::ZERO), Vec3::splat(bins as f32) / extent, Vec3::ZERO);
    let binning = Binning { lo: Vec3A::from(lo), scale: Vec3A::from(scale), last: Vec3A::splat((bins - 1) as f32) };
    // Binned in place (returned, the 3.8 kB of bins were copied at every node) and swept as
    // lanes: the torus's build 3.15 → 3.00 billion instructions.
    let n = prims.len();
    let stride = (n / SAMPLES).max(1);
    let mut found = Bins::empty();
    if n >= PARALLEL_BINNING {
        found = binning.bin_in_chunks(prims, stride);
    } else {
        binning.bin(prims, stride, &mut found);
    }
    // Counted, not ⌈n / stride⌉: in parallel chunks each chunk strides from its own start.
    let sampled: usize = found.counts[0][..bins].iter().sum();
    let Bins { boxes: bin_boxes, counts: bin_counts } = &found;
    let parent_area = bounds.half_area().max(f32::MIN_POSITIVE);
    let mut best: Option<(f32, usize, usize)> = None;
    let mut right_area = [0f32; MAX_BINS];
    for axis in (0..3).filter(|&a| extent[a] > 0.0) {
        let (bin_boxes, bin_counts) = (&bin_boxes[axis], &bin_counts[axis]);
        // Sweep from the right for the areas of the right-hand sides …
        let mut acc = Box3::EMPTY;
        for b in (1..bins).rev() {
            acc = acc.union(bin_boxes[b]);
            right_area[b] = acc.half_area();
        }
        // … then from the left, pricing every split plane between bin b-1 and b.
        let (mut left, mut left_count) = (Box3::EMPTY, 0usize);
        for b in 1..bins {
            left = left.union(bin_boxes[b - 1]);
            left_count += bin_counts[b - 1];
            let right_count = sampled - left_count;
            if left_count == 0 || right_count == 0 {
                continue;
            }
            let cost = params.traversal_cost
                + params.intersection_cost
                    * (left.half_area() * blocks(left_count * stride) + right_area[b] * blocks(right_count * stride))
                    / parent_area;
            if best.as_ref().is_none_or(|&(c, ..)| cost < c) {
                best = Some((cost, axis, b));
            }
        }
    }
    let (cost, axis, bin) = best?;
    // Every primitive binned, the sides' bounds are their bins'.
    let bounds = (stride == 1).then(|| {
        let side = |bins: &[Box3]| bins.iter().fold(Box3::EMPTY, |b, &c| b.union(c));
        let (left, right) = bin_boxes[axis][..bins].split_at(bin);
        [side(left), side(right)]
    });
    Some(Split { binning, axis, bin: Vec3A::splat(bin as f32), cost, bounds })
}

/// Moves the primitives that `split` sends left to the front, swapping in one forward pass
/// (the leaves' order, and so the blocks', follows from it); returns how many there are and
/// both sides' extents: the bounds measured if `BOUNDS`, else `bounds`.
fn partition<const BOUNDS: bool>(prims: &mut [Prim], split: &Split, bounds: [Box3; 2]) -> (usize, [Extent; 2]) {
    let mut i = 0;
    let [mut left, mut right] = bounds.map(|bounds| Extent { bounds, centroids: Box3::EMPTY });
    // Two arms, not one through a reference to either side, which kept the sides in memory (132
    // million instructions more in the 1M torus's build, callgrind).
    for j in 0..prims.len() {
        let p = prims[j];
        let c = p.centroid();
        if split.goes_left(c) {
            left.centroids = left.centroids.grow(c);
            if BOUNDS {
                left.bounds = left.bounds.union(p.bounds());
            }
            prims.swap(i, j);
            i += 1;
        } else {
            right.centroids = right.centroids.grow(c);
            if BOUNDS {
                right.bounds = right.bounds.union(p.bounds());
            }
        }
    }
    (i, [left, right])
}

/// Splits at the median centroid along the widest axis of the centroids (ties by index), so
/// that both halves are non-empty whatever the input.
fn median_split(prims: &mut [Prim]) -> usize {
    let cb = prims.iter().fold(Box3::EMPTY, |b, p| b.grow(p.centroid())).aabb();
    let axis = cb.extent().max_position();
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| {
        a.centroid()[axis].total_cmp(&b.centroid()[axis]).then(a.index().cmp(&b.index()))
    });
    mid
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_small_is_the_floor() {
        let mut values = vec![0.0f32, 0.25, 0.5, 0.75, 15.0, 31.0, 31.999_998];
        for k in 1..32 {
            let k = k as f32;
            values.extend([k, k.next_down(), k.next_up(), k - 0.5, k + 0.5]);
        }
        for v in values {
            let [a, b, c] = floor_small(Vec3A::new(v, v * 0.5, v.next_down().max(0.0)));
            assert_eq!([a, b, c], [v as u32, (v * 0.5) as u32, v.next_down().max(0.0) as u32], "{v}");
        }
    }

    /// A dense patch beside a sparse one, with disks 100 times wider: each splat's own grid
    /// lets the sparse leaves be as wide as their disks. (On one grid for the whole set, from
    /// the median radius, the sparse leaves were split down to single splats: 107 bytes a splat
    /// where this takes 33.)
    #[test]
    fn sparse_regions_keep_their_leaves() {
        let disk =
            |x: f32, y: f32, radius: f32| Splat { center: Vec3::new(x, y, 0.0), radius, normal: Vec3::Z, color: 0 };
        let dense = (0..10_000).map(|i| disk((i % 100) as f32 * 0.01, (i / 100) as f32 * 0.01, 0.012));
        let sparse = (0..10_000).map(|i| disk(10.0 + (i % 100) as f32, (i / 100) as f32, 1.2));
        let splats: Vec<Splat> = dense.chain(sparse).collect();
        let n = splats.len();
        let bvh = Bvh::build(splats, &BvhParams::standard());
        // Leaves of about eight splats under 8-wide nodes: one node for every 40 splats or so;
        // single-splat leaves in the sparse half would take one for every 13.
        assert!(bvh.nodes.len() < n / 25, "{} nodes for {n} splats", bvh.nodes.len());
    }

    /// Splats on a sphere (a Fibonacci lattice), `n` of them, overlapping as a scan's do.
    fn sphere(n: usize) -> Vec<Splat> {
        let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
        let point = |i: usize| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let (s, c) = (golden * i as f32).sin_cos();
            Vec3::new(c * (1.0 - z * z).sqrt(), s * (1.0 - z * z).sqrt(), z)
        };
        let radius = 2.0 / (n as f32).sqrt();
        (0..n).map(|i| Splat { center: point(i), radius, normal: point(i), color: 0 }).collect()
    }

    /// The wide tree of `splats`: its nodes, and the least SAH cost [`Slots`] found for it.
    fn collapse(splats: &[Splat], params: &BvhParams) -> (Vec<Node>, f32) {
        let mut prims = prims_of(splats, params);
        let extent = Extent::of(&prims);
        let root = build_node(&mut prims, extent, 0, params, 0);
        let cost = root.slots(params).0[0];
        let (mut nodes, mut spans) = (Vec::new(), Vec::new());
        flatten(root, &mut nodes, &mut spans, params);
        (nodes, cost)
    }

    fn used(n: &Node) -> impl Iterator<Item = usize> + '_ {
        (0..WIDTH).filter(move |i| n.used & (1 << i) != 0)
    }

    /// Below [`LARGEST_FIRST_ABOVE`] blocks, the wide tree costs what the slots said: the SAH
    /// of its nodes (a traversal step each) and leaves (a test a block), summed again from the
    /// nodes written.
    #[test]
    fn a_small_tree_costs_what_the_slots_found() {
        let params = BvhParams::standard();
        // Few enough splats for one subtree of at most 64 blocks (checked below).
        let splats = sphere(480);
        let (nodes, expected) = collapse(&splats, &params);
        let leaf_refs =
            || nodes.iter().flat_map(|n| used(n).map(|i| n.child[i])).filter(|c| c & super::super::LEAF != 0);
        let blocks_below: usize = leaf_refs().map(|c| super::super::leaf_blocks(c).len()).sum();
        assert!(nodes.len() > 3 && blocks_below <= LARGEST_FIRST_ABOVE, "{} nodes, {blocks_below} blocks", nodes.len());
        let area = |n: &Node| used(n).map(|i| n.child_bounds(i)).fold(Aabb::EMPTY, Aabb::union).half_area();
        let leaves: f32 = nodes
            .iter()
            .flat_map(|n| used(n).map(move |i| (n.child_bounds(i), n.child[i])))
            .filter(|&(_, c)| c & super::super::LEAF != 0)
            .map(|(b, c)| b.half_area() * blocks(super::super::leaf_size(c)) * params.intersection_cost)
            .sum();
        let steps: f32 = nodes.iter().map(|n| area(n) * params.traversal_cost).sum();
        let found = steps + leaves;
        assert!((found - expected).abs() <= 1e-4 * expected, "the wide tree costs {found}, the slots said {expected}");
    }

    /// The wide nodes are nearly full. (The largest child first all the way down left 3.7
    /// children a node on this sphere.)
    #[test]
    fn the_collapse_fills_nodes() {
        let (nodes, _) = collapse(&sphere(20_000), &BvhParams::standard());
        let children: usize = nodes.iter().map(|n| used(n).count()).sum();
        let per_node = children as f64 / nodes.len() as f64;
        assert!(per_node > 6.0, "{per_node:.2} children a node");
    }

    /// A split chosen from a sample still moves every primitive, and the partition measures
    /// both sides' bounds exactly; binned in parallel chunks too, whose strides start anew in
    /// each chunk. There a stray splat, sampled and alone in the last bin of every axis, makes
    /// the sweep's right side one sample: counted as ⌈n / stride⌉ (with a stride that does not
    /// divide the chunks), the sample was two short and the count overflowed (debug builds).
    #[test]
    fn a_sampled_split_measures_both_sides() {
        let params = BvhParams::standard();
        for n in [3 * SAMPLES, PARALLEL_BINNING + 12_345] {
            let mut splats = sphere(n - 1);
            splats.insert(0, Splat { center: Vec3::splat(10.0), radius: 0.01, normal: Vec3::Z, color: 0 });
            let mut prims = prims_of(&splats, &params);
            let extent = Extent::of(&prims);
            let cb = extent.centroids.aabb();
            let split = best_sah_split(&prims, &extent.bounds.aabb(), &cb, &params).expect("a split");
            assert!(split.bounds.is_none(), "a sample's bins give no bounds");
            let (mid, halves) = partition::<true>(&mut prims, &split, [Box3::EMPTY; 2]);
            assert!(0 < mid && mid < n);
            let (left, right) = prims.split_at(mid);
            for (side, half) in [left, right].into_iter().zip(halves) {
                let exact = Extent::of(side);
                assert_eq!((half.bounds.aabb(), half.centroids.aabb()), (exact.bounds.aabb(), exact.centroids.aabb()));
            }
            let left_ok = left.iter().all(|p| split.goes_left(p.centroid()));
            assert!(left_ok && !right.iter().any(|p| split.goes_left(p.centroid())));
        }
    }

    #[test]
    fn a_prim_keeps_its_index_bounds_and_grid() {
        let b = Aabb::new(Vec3::new(-1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.5));
        for index in [0, 1, 12_345, (1 << 23) - 1, 1 << 23, MAX_SPLATS as u32 - 1] {
            let p = Prim::new(b, index, 0.125);
            assert_eq!((p.index(), p.grid_step()), (index, 0.125));
            assert!(p.min.w.is_normal());
            assert_eq!(p.bounds().aabb(), b);
            assert_eq!(Vec3::from(p.centroid()), b.center());
        }
    }

    #[test]
    fn box_areas_are_the_aabb_areas() {
        let boxes = [
            Aabb::new(Vec3::new(0.1, -2.0, 3.3), Vec3::new(1.7, 0.25, 9.0)),
            Aabb::new(Vec3::ONE, Vec3::ONE),
            Aabb::EMPTY,
            Aabb::new(Vec3::new(0.0, 1.0, 0.0), Vec3::new(1.0, 0.0, 1.0)),
        ];
        for b in boxes {
            let lanes = Box3 { min: b.min.into(), max: b.max.into() };
            assert_eq!(lanes.half_area().to_bits(), b.half_area().to_bits(), "{b:?}");
        }
    }
}
