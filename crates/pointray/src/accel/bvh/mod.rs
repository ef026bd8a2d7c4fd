//! Bounding volume hierarchy over splats: binned SAH build, eight children per node.
//!
//! The build makes a binary SAH tree and collapses it into an 8-wide one (as Embree's BVH8;
//! near the leaves, each node's children chosen for the least SAH cost, `build::Slots`):
//! each node stores the boxes of its up to eight children side by side (`lanes`), so one
//! traversal step tests eight boxes and never fetches a child the ray misses, and the tree is
//! a third as deep as the binary one. The build puts the splats in leaf order and stores them
//! in blocks of eight disks for the leaf kernel (`accel::block`); a leaf is a run of blocks.
//!
//! It is also the multiresolution BVH of thesis ch. 3: every child slot carries a bounding
//! sphere, a normal cone and a representative splat (`lod`), so a ray whose footprint is wider
//! than a subtree takes its representative instead of descending, back-facing subtrees can be
//! culled, and nodes deep down can bound their children by spheres instead of boxes. With
//! level of detail off, culling off and boxes only, the traversal is the full-detail one.

mod build;
mod chunk;
mod gather;
pub(crate) mod lanes;
mod lod;
mod stored;
mod streamed;
pub(super) mod traverse;
mod treelet;
mod two_level;

pub use build::{BvhParams, TooLarge};
pub use chunk::{CHUNK_SPLATS, Cell, ChunkPlan};
pub use lod::NodeBounds;
pub use stored::{ARRAY_ALIGN, ARRAYS, BvhMeta, BvhStoredError};
pub use streamed::{Finished, Sink, Spill, Spilled, StreamedBvh, StreamedError};
pub use two_level::{PART_SPLATS, Part, TwoLevel, part_offset};

use glam::Vec3;

use lanes::{Lanes, Wide};

use crate::accel::Accel;
use crate::accel::block::{BLOCK, SplatBlock};
use crate::accel::stored::Stored;
use crate::math::Aabb;
use crate::splat::footprint::{Beam, FootprintVisitor, coverage_density, density_stride};
use crate::splat::{DiskShape, Splat};

/// The disks of a block (its lanes of radius above 0).
pub(crate) fn block_disks(block: &SplatBlock) -> impl Iterator<Item = Splat> + '_ {
    (0..BLOCK).map(|i| block.splat(i)).filter(|s| s.radius > 0.0)
}

/// A child reference is a node index, or for a leaf
/// `LEAF | (splats − 1) << FIRST_BITS | first block`: one word on the traversal stack says
/// everything about a child. A leaf's splats fill its blocks in order, so they are the splat
/// indices `BLOCK · first block ..` on, one after another.
const LEAF: u32 = 1 << 31;
const FIRST_BITS: u32 = 27;
/// Most splats a leaf can hold (its splat count takes the four bits between `LEAF` and the
/// first block).
pub(crate) const MAX_LEAF_SIZE: usize = 16;
/// Most blocks a BVH can hold: a leaf reference names its first in `FIRST_BITS`.
const MAX_BLOCKS: usize = 1 << FIRST_BITS;
const SPLAT_BITS: u32 = FIRST_BITS + 1;
/// Most splats a BVH can index (2²⁸ ≈ 268 million), where its leaves fill at least half their
/// blocks on average (SAH leaves of 8 to 16 splats fill them; `Bvh::try_build` says if not).
pub const MAX_SPLATS: usize = 1 << SPLAT_BITS;

fn leaf_ref(first_block: usize, splats: usize) -> u32 {
    debug_assert!((1..=MAX_LEAF_SIZE).contains(&splats) && first_block < MAX_BLOCKS);
    LEAF | ((splats - 1) as u32) << FIRST_BITS | first_block as u32
}

/// The number of splats in a leaf.
#[inline(always)]
fn leaf_size(child: u32) -> usize {
    ((child & !LEAF) >> FIRST_BITS) as usize + 1
}

/// The block range of a leaf reference.
#[inline(always)]
fn leaf_blocks(child: u32) -> std::ops::Range<usize> {
    let first = (child & ((1 << FIRST_BITS) - 1)) as usize;
    first..first + (leaf_size(child) - 1) / BLOCK + 1
}

/// The splat indices of a leaf reference.
fn leaf_splats(child: u32) -> std::ops::Range<u32> {
    let first = (leaf_blocks(child).start * BLOCK) as u32;
    first..first + leaf_size(child) as u32
}

/// From this depth of the binary build tree on, splits are object medians (see `build_node`),
/// which bounds the depth of any tree by this plus log₂ n.
pub(crate) const MEDIAN_SPLIT_DEPTH: usize = 88;

/// The deepest an 8-wide tree can be: each of its levels takes at least one level of the
/// binary build tree, whose depth median splits bound.
pub(crate) const MAX_DEPTH: usize = MEDIAN_SPLIT_DEPTH + SPLAT_BITS as usize;

/// Children per node.
pub(crate) const WIDTH: usize = lanes::LANES;

/// An inner node: the bounds of its up to eight children and how to reach them.
///
/// Structure of arrays: `planes[k]` holds the eight children's minima along axis `k`,
/// `planes[3 + k]` the maxima, so one subtract and multiply per plane give the slab distances
/// of all eight. Unused slots have empty bounds (minimum +∞, maximum −∞).
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct Node {
    pub(crate) planes: [Lanes; 6],
    /// Inner child: its node index. Leaf child: see [`leaf_ref`].
    pub(crate) child: [u32; WIDTH],
    /// Bit i set iff slot i holds a child. Traversal masks hits with it: a ray with NaN
    /// components "enters" even empty boxes, and must not follow an unused slot. Plus the flag
    /// [`SPHERE_NODE`], and from bit [`LOD_SLOTS_SHIFT`] the children a ray may replace by their
    /// representatives: all but leaves of at most four splats, whose test costs no more than
    /// the representative's.
    pub(crate) used: u32,
    /// The smallest bounding-sphere radius of those children: where a ray's footprint stays
    /// narrower, no child can stop it, and the level-of-detail test is skipped.
    pub(crate) min_radius: f32,
    /// The multiresolution step runs at this node for rays whose reach (see `traverse`) is
    /// above this: `min_radius`, or −∞ for sphere nodes, which always need it. One compare per
    /// node decides.
    pub(crate) multires_below: f32,
    /// To the 64-byte boundary, written out: a scene file stores nodes as their bytes.
    pub(crate) pad: [u32; 5],
}

/// Flag in `Node::used`: the node tests its children's bounding spheres, not their boxes.
pub(crate) const SPHERE_NODE: u32 = 1 << WIDTH;
/// The bits of `Node::used` that mark slots in use.
pub(crate) const SLOTS: u32 = (1 << WIDTH) - 1;
/// Where the mask of children that may stop a ray starts in `Node::used`.
pub(crate) const LOD_SLOTS_SHIFT: u32 = 16;

impl Node {
    pub(crate) fn new(b: &[Aabb]) -> Self {
        debug_assert!(b.len() <= WIDTH);
        let get = |i: usize| b.get(i).copied().unwrap_or(Aabb::EMPTY);
        let lo = |k: usize| Lanes::from_array(std::array::from_fn(|i| get(i).min[k]));
        let hi = |k: usize| Lanes::from_array(std::array::from_fn(|i| get(i).max[k]));
        Self {
            planes: [lo(0), lo(1), lo(2), hi(0), hi(1), hi(2)],
            child: [0; WIDTH],
            used: (1 << b.len()) - 1,
            min_radius: f32::INFINITY,
            multires_below: f32::INFINITY,
            pad: [0; 5],
        }
    }

    pub(crate) fn child_bounds(&self, i: usize) -> Aabb {
        let p = &self.planes;
        Aabb::new(Vec3::new(p[0][i], p[1][i], p[2][i]), Vec3::new(p[3][i], p[4][i], p[5][i]))
    }
}

/// The BVH and the splats it indexes, reordered so that each leaf is a contiguous range.
pub struct Bvh {
    pub(crate) nodes: Stored<Node>,
    /// Per node, its children's spheres and cones.
    pub(crate) lod: Stored<lod::NodeLod>,
    /// The splats, in leaf order, in blocks for the leaf kernel (see [`SplatBlock`]): the
    /// only copy (a second, as an array of [`Splat`]s, was 32 bytes a splat that only the
    /// visitors' look-ups read).
    pub(crate) blocks: Stored<SplatBlock>,
    /// The representative splats, a block per node: child `i` of node `k` in lane `i` of
    /// block `k`, with index `BLOCK·blocks.len() + WIDTH·k + i` for a visitor, which gets one
    /// index space for both (`WIDTH` = `BLOCK`), and one way to fetch either.
    pub(crate) representatives: Stored<SplatBlock>,
    /// Per node, what the footprint prefilter knows of its children's disks.
    pub(crate) aggregates: Stored<lod::NodeAggregate>,
    /// The subtrees below the top (see [`treelet`]), whose nodes follow the top's `top_nodes`.
    pub(crate) treelets: Stored<treelet::Treelet>,
    pub(crate) top_nodes: usize,
    /// A stored tree's checks of its treelets, made as walks enter them, shared by its clones
    /// (none in memory).
    pub(crate) lazy: Option<std::sync::Arc<treelet::Lazy>>,
    /// The number of input splats.
    pub(crate) splat_count: usize,
    pub(crate) bounds: Aabb,
    pub(crate) depth: usize,
    pub(crate) node_bounds: NodeBounds,
    /// Whether full-detail rays may take the loop without the multiresolution steps: boxes
    /// everywhere, and a tree in memory (a stored top's treelet references are entered in the
    /// other loop alone).
    pub(crate) plain_walk: bool,
    /// See [`Bvh::sphere_node_count`].
    pub(crate) sphere_nodes: usize,
    /// The 5th percentile of `Node::min_radius` (`representative::LOD_FLOOR_QUANTILE`): a ray whose
    /// footprint, scaled by τ, stays below it all through the model takes the full-detail
    /// traversal, forgoing stops only at nodes among the smallest 5 %, where they would save
    /// little. Close up, that keeps level of detail free.
    pub(crate) lod_floor: f32,
    /// See [`super::Accel::wide_radius`].
    pub(crate) wide_radius: f32,
    /// See [`super::Accel::coverage_density`]: found when first asked (the prefilter's), not at
    /// every build (4,096 searches: the dragon's build took 0.069 s with them, 0.063 without,
    /// medians of `--bench-builds 9`, two runs each). Boxed: held inline, the lock moved the
    /// fields the traversal reads, and the dragon's first hits took 702 instructions a pixel
    /// where they take 699 (callgrind; SJ 1,000 and 1,004).
    pub(crate) coverage_density: Box<std::sync::OnceLock<f32>>,
    /// The disks the bounds hold.
    pub(crate) shape: DiskShape,
}

impl Bvh {
    /// The same tree: a stored one's arrays and treelet checks shared, one in memory's copied.
    /// (A method, not `Clone`: with `Clone` derived the dragon's first hits took 702
    /// instructions a pixel, this way 700, code generation moving in the full-detail loop.)
    #[inline(never)]
    pub(crate) fn share(&self) -> Bvh {
        Bvh {
            nodes: self.nodes.clone(),
            lod: self.lod.clone(),
            blocks: self.blocks.clone(),
            representatives: self.representatives.clone(),
            aggregates: self.aggregates.clone(),
            treelets: self.treelets.clone(),
            lazy: self.lazy.clone(),
            coverage_density: self.coverage_density.clone(),
            ..*self
        }
    }

    /// Index (for [`crate::accel::Accel::splat`]) of the representative of child `slot` of
    /// node `node`.
    #[inline(always)]
    pub(crate) fn representative_index(&self, node: usize, slot: usize) -> u32 {
        (self.blocks.len() * BLOCK + WIDTH * node + slot) as u32
    }

    pub(crate) fn representative(&self, node: usize, slot: usize) -> Splat {
        self.representatives[node].splat(slot)
    }

    /// Bytes per node: its boxes and child references, its spheres and cones, and its
    /// children's representative splats and aggregates.
    pub const NODE_BYTES: usize =
        size_of::<Node>() + size_of::<lod::NodeLod>() + size_of::<SplatBlock>() + size_of::<lod::NodeAggregate>();

    /// Which bounds the nodes test.
    pub fn node_bounds(&self) -> NodeBounds {
        self.node_bounds
    }

    /// Nodes that test their children's spheres (counted when chosen: a stored tree's report
    /// reads no node).
    pub fn sphere_node_count(&self) -> usize {
        self.sphere_nodes
    }

    /// Chooses the bounds the nodes test anew (cheap: the spheres are already there).
    ///
    /// # Panics
    /// On a stored tree (`from_stored`), whose bounds are its file's.
    pub fn set_node_bounds(&mut self, choice: NodeBounds) {
        assert!(self.lazy.is_none(), "a stored tree keeps the bounds it was stored with");
        let lod = &self.lod;
        self.nodes.modify(|nodes| lod::choose_node_bounds(nodes, lod, choice));
        self.node_bounds = choice;
        self.plain_walk = choice == NodeBounds::Boxes;
        self.sphere_nodes = self.nodes.iter().filter(|n| n.used & SPHERE_NODE != 0).count();
    }

    /// Every input splat with its index, in no particular order (a stored tree's treelets
    /// checked on the way, any damaged left out, see [`Bvh::damage`]).
    pub fn splats(&self) -> impl Iterator<Item = (u32, Splat)> + '_ {
        let mut leaves = Vec::new();
        self.for_each_near(self.bounds.center(), f32::INFINITY, &mut super::TraversalStats::uncounted(), |j, _| {
            leaves.push(j);
        });
        leaves.into_iter().map(|j| (j, self.splat(j)))
    }

    /// [`Accel::coverage_density`] found from the splats (a stored tree keeps it in its
    /// file's metadata: this is what a build out of core stores). Sampled a block at a time
    /// ([`Self::coverage_samples`]), a few hundred blocks read: taken from a walk of the tree,
    /// the samples read every block, and preparing 200 million points out of core mapped the
    /// whole 7 GB file for them (6.2 GB resident at the peak).
    pub fn measure_coverage_density(&self) -> f32 {
        coverage_density(self, self.coverage_samples())
    }

    /// The disks [`Self::measure_coverage_density`] samples: those of every k-th block, about
    /// 4,096 (all of a tree of fewer, as every accelerator samples them; an unused lane has
    /// radius 0).
    pub fn coverage_samples(&self) -> impl Iterator<Item = Splat> + '_ {
        let blocks = &self.blocks;
        let sampled = (0..blocks.len()).step_by(density_stride(self.splat_count));
        sampled.flat_map(move |b| block_disks(&blocks[b]))
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    pub fn depth(&self) -> usize {
        self.depth
    }
}

impl super::Accel for Bvh {
    fn name(&self) -> &'static str {
        "bvh"
    }

    #[inline(always)]
    fn splat(&self, index: u32) -> Splat {
        // Both kinds are blocks, so a look-up is one gather from one of two arrays. (With the
        // representatives as splats the two paths met in a copy on the stack: 8 stores for
        // every crossing the SJ blend reads; the same speed either way, alternating runs.)
        let (i, splats) = (index as usize, self.blocks.len() * BLOCK);
        let (blocks, i) = if i < splats { (&self.blocks, i) } else { (&self.representatives, i - splats) };
        blocks[i / BLOCK].splat(i % BLOCK)
    }

    fn is_representative(&self, index: u32) -> bool {
        index as usize >= self.blocks.len() * BLOCK
    }

    fn splat_count(&self) -> usize {
        self.splat_count
    }

    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn wide_radius(&self) -> f32 {
        self.wide_radius
    }

    fn coverage_density(&self) -> f32 {
        *self.coverage_density.get_or_init(|| self.measure_coverage_density())
    }

    fn gather<V: FootprintVisitor>(&self, beam: &Beam, tau: f32, visitor: &mut V, stats: &mut super::TraversalStats) {
        gather::gather(self, beam, tau, visitor, stats);
    }

    fn may_stop_at_representatives(&self, ray: &crate::math::Ray) -> bool {
        traverse::lod_reach(self, ray) > 0.0
    }

    fn lod_floor(&self) -> f32 {
        self.lod_floor
    }

    fn shape(&self) -> DiskShape {
        self.shape
    }

    fn for_each_near<F: FnMut(u32, Splat)>(
        &self,
        center: Vec3,
        radius: f32,
        stats: &mut super::TraversalStats,
        mut f: F,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let r2 = radius * radius;
        let mut stack = vec![0u32];
        while let Some(child) = stack.pop() {
            // A stored top's treelet: its root (see `treelet`), none if damaged.
            let Some(child) = (if Bvh::is_treelet(child) { self.enter(child) } else { Some(child) }) else { continue };
            if child & LEAF != 0 {
                for j in leaf_splats(child) {
                    let s = self.splat(j);
                    stats.splat_tests += 1;
                    if (s.center - center).length_squared() <= r2 {
                        f(j, s);
                    }
                }
                continue;
            }
            let n = &self.nodes[child as usize];
            stats.nodes_visited += 1;
            // Squared distance from the centre to each child's box (unused slots: infinite).
            let gap = |axis: usize| {
                let c = Lanes::splat(center[axis]);
                (n.planes[axis] - c).max(c - n.planes[3 + axis]).max(Lanes::ZERO)
            };
            let (gx, gy, gz) = (gap(0), gap(1), gap(2));
            let mut near = Lanes::bitmask((gx * gx + gy * gy + gz * gz).cmple(Lanes::splat(r2))) & (n.used & SLOTS);
            while near != 0 {
                stack.push(n.child[near.trailing_zeros() as usize]);
                near &= near - 1;
            }
        }
    }

    fn memory_bytes(&self) -> usize {
        self.nodes.len() * Self::NODE_BYTES + self.blocks.len() * size_of::<SplatBlock>()
    }

    fn traverse<V: super::SplatVisitor>(
        &self,
        ray: &crate::math::Ray,
        visitor: &mut V,
        stats: &mut super::TraversalStats,
    ) {
        crate::accel::isa::bvh_traverse(self, ray, visitor, stats);
    }
}

/// Checks the structure's invariants: every child box contains the bounds of every splat below
/// it, every splat belongs to exactly one leaf, and the level-of-detail payload bounds what is
/// below it (see `lod::check_invariants`). For tests; O(n log n).
pub fn check_invariants(bvh: &Bvh) -> Result<(), String> {
    fn walk(bvh: &Bvh, node: usize, seen: &mut [bool]) -> Result<Vec<Aabb>, String> {
        let n = &bvh.nodes[node];
        let mut all = Vec::new();
        for i in 0..WIDTH {
            let boxed = n.child_bounds(i);
            if n.used & SLOTS & (1 << i) == 0 {
                if !boxed.is_empty() {
                    return Err(format!("node {node}: unused slot {i} has bounds"));
                }
                continue;
            }
            let child = if Bvh::is_treelet(n.child[i]) {
                bvh.enter(n.child[i]).ok_or(format!("node {node} child {i}: a damaged treelet"))?
            } else {
                n.child[i]
            };
            let below = if child & LEAF != 0 {
                let mut b = Vec::new();
                for j in leaf_splats(child) {
                    let flag = seen.get_mut(j as usize).ok_or(format!("leaf of node {node} points past the splats"))?;
                    if std::mem::replace(flag, true) {
                        return Err(format!("splat {j} is in two leaves"));
                    }
                    b.push(bvh.splat(j).bounds_as(bvh.shape));
                }
                b
            } else {
                walk(bvh, child as usize, seen)?
            };
            if let Some(bad) = below.iter().find(|b| !boxed.contains_box(b)) {
                return Err(format!("node {node} child {i}: {boxed:?} does not contain {bad:?}"));
            }
            all.extend(below);
        }
        Ok(all)
    }
    if bvh.nodes.is_empty() {
        return if bvh.splat_count == 0 { Ok(()) } else { Err("splats but no root node".into()) };
    }
    // The traversal's stack holds enough for this depth and no more.
    if bvh.depth > MAX_DEPTH {
        return Err(format!("depth {} beyond {MAX_DEPTH}", bvh.depth));
    }
    let mut seen = vec![false; bvh.blocks.len() * BLOCK];
    walk(bvh, 0, &mut seen)?;
    let held = seen.iter().filter(|s| **s).count();
    if held != bvh.splat_count {
        return Err(format!("the leaves hold {held} splats of {}", bvh.splat_count));
    }
    // The lanes no leaf holds must be disks no ray can hit.
    if let Some(j) = (0..seen.len()).find(|&j| !seen[j] && bvh.blocks[j / BLOCK].splat(j % BLOCK).radius != 0.0) {
        return Err(format!("lane {j} lies outside the leaves but holds a disk"));
    }
    lod::check_invariants(bvh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_and_block_sizes() {
        assert_eq!(size_of::<Node>(), 256);
        assert_eq!(size_of::<SplatBlock>(), 176);
    }
}
