//! Level of detail in the nodes (thesis ch. 3; QSplat's node payload, RECONSTRUCTION A3–A7).
//!
//! For each child of each node: a bounding sphere, a normal cone and a representative splat.
//! The representative's area-weighted sums are merged up the tree from the leaves; the sphere,
//! the cone and the representative's radius are computed from the disks below the child
//! directly, in one pass, not merged from the grandchildren as QSplat does: the merge bounds
//! bounds, and its spheres and cones only grow with the depth. A child covers a contiguous
//! run of leaf blocks (the build keeps every subtree contiguous, see [`Disks`]), so this pass
//! costs O(n · depth). It took four passes before: loading the prepared dragon and building its BVH
//! went from 2.73 to 2.53 billion instructions (callgrind).
//!
//! * Sphere: centred on the child's box, radius to the farthest point of any disk below.
//! * Cone: the area-weighted mean normal as axis, the widest angle to any normal below.
//! * Representative: an oriented disk at the area-weighted mean centre, with the cone's axis
//!   as normal, the area-weighted mean colour, and a radius between covering every disk below
//!   and matching their spread (see `accel::representative`).

use std::ops::Range;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::lanes::Lanes;
use super::{Bvh, LEAF, LOD_SLOTS_SHIFT, Node, SLOTS, SPHERE_NODE, WIDTH, leaf_blocks, leaf_size, leaf_splats};
use crate::accel::Accel;
use crate::accel::block::{BLOCK, SplatBlock};
use crate::accel::representative::{Frame, Moments, Representative, Spread, along_and_off};
use crate::splat::footprint::Aggregate;
use crate::splat::{DiskShape, Splat};

/// What the multiresolution traversal knows of a node's eight children besides their boxes and
/// representatives, eight lanes side by side like [`Node`]'s planes. A child's bounding sphere
/// is centred on its box, and its normal cone's axis is its representative's normal, so neither
/// is stored again (they took 192 of this record's 256 bytes: 6 bytes a splat of the dragon).
/// Unused slots have radius 0 and a cone that never culls.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct NodeLod {
    /// Bounding sphere radii.
    pub(crate) radius: Lanes,
    /// The cosine of the normal cones' half-angles (−1: the normals below point every way).
    pub(crate) cos_angle: Lanes,
}

/// What the footprint prefilter (`splat::footprint`) knows of each child's disks beyond its
/// representative: the radius of a disk of their summed area, and the length of their
/// area-weighted mean normal (1 where they agree; shorter where they spread, Toksvig's
/// measure of roughness). Eight lanes, like [`NodeLod`]; unused slots hold zeros.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct NodeAggregate {
    pub(crate) area_radius: Lanes,
    pub(crate) agreement: Lanes,
}

impl NodeAggregate {
    pub(crate) fn get(&self, slot: usize) -> Aggregate {
        Aggregate { area_radius: self.area_radius[slot], agreement: self.agreement[slot], disk: false }
    }
}

/// The bounds every node uses for its children.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NodeBounds {
    /// Boxes everywhere: the foundation's BVH.
    Boxes,
    /// Boxes above this depth of the 8-wide tree (the root is depth 0), spheres from it down
    /// (the thesis's mixed volumes).
    SpheresFrom(u32),
    /// Per node, whichever of the children's spheres or boxes has the smaller total surface
    /// area: the one a random ray is less likely to enter (the SAH's measure).
    Auto,
}

/// Leaves of at most this many splats are never replaced by their representative.
const ALWAYS_FULL_LEAF: usize = 4;

/// The splats as the build left them: in blocks, block `b` holding `counts[b]` of them in its
/// first lanes. A subtree's leaves take a contiguous run of blocks (the build writes them depth
/// first), so its splats are the lanes in use of a block range. Read from the blocks, the
/// level-of-detail build needs no second copy of the splats (a 20-million-point torus's
/// render peaked at 1.76 GB with one, `/usr/bin/time`).
pub(super) struct Disks<'a> {
    pub(super) blocks: &'a [SplatBlock],
    pub(super) counts: &'a [u8],
}

impl Disks<'_> {
    fn moments(&self, blocks: Range<usize>) -> Moments {
        let mut m = Moments::default();
        for b in blocks {
            m.add_block(&self.blocks[b], usize::from(self.counts[b]));
        }
        m
    }
}

/// Block range below a child reference.
fn child_range(child: u32, node_range: &[Range<usize>]) -> Range<usize> {
    if child & LEAF != 0 { leaf_blocks(child) } else { node_range[child as usize].clone() }
}

/// The block range below every node. Children are stored after their parent, so one pass
/// from the back sees every child before its parent.
pub(super) fn node_ranges(nodes: &[Node]) -> Vec<Range<usize>> {
    let mut ranges = vec![0..0; nodes.len()];
    for k in (0..nodes.len()).rev() {
        let n = &nodes[k];
        let (mut lo, mut hi) = (usize::MAX, 0);
        for i in (0..WIDTH).filter(|i| n.used & (1 << i) != 0) {
            let r = child_range(n.child[i], &ranges);
            (lo, hi) = (lo.min(r.start), hi.max(r.end));
        }
        ranges[k] = lo.min(hi)..hi;
    }
    ranges
}

/// Bounding sphere, cone and representative of one child.
pub(super) struct ChildLod {
    aggregate: Aggregate,
    radius: f32,
    cos_angle: f32,
    rep: Splat,
}

/// Distance from `p` to the farthest point of the disk `s` (of its ball, for ray-facing disks).
fn farthest(p: DVec3, s: &Splat, disks: DiskShape) -> f64 {
    let d = (s.center.as_dvec3() - p).to_array();
    farthest_of(d, s.normal.as_dvec3().to_array(), f64::from(s.radius), disks)
}

/// [`farthest`] for a disk `d` away, with normal `n` and radius `r`.
#[inline(always)]
fn farthest_of(d: [f64; 3], n: [f64; 3], r: f64, disks: DiskShape) -> f64 {
    if disks == DiskShape::RayFacing {
        return (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() + r;
    }
    let (h, in_plane) = along_and_off(d, n);
    (h * h + (in_plane + r) * (in_plane + r)).sqrt()
}

/// Rounds a bound up a little, so that f32 storage never makes it smaller than exact.
fn round_up(x: f64) -> f32 {
    (x * (1.0 + 1e-6)) as f32 + f32::MIN_POSITIVE
}

/// The child's bounds and representative from its disks and their moments, in one pass over
/// its blocks, lane by lane. Inlined, with the blocks' passes (`Moments::add_block`,
/// `Spread::add_block`), by force: left to the inliner, an unrelated change elsewhere in the
/// crate flipped their lane loops between vectorised and not, the 1M torus's load and build
/// between 4.61 and 4.80 billion instructions (callgrind); forced, 4.54.
#[inline(always)]
fn child_lod(box_center: Vec3, disks: &Disks, blocks: Range<usize>, moments: &Moments, shape: DiskShape) -> ChildLod {
    let mut pass = ChildPass::new(box_center, &disks.blocks[blocks.start], moments, shape);
    for b in blocks {
        pass.add(&disks.blocks[b], usize::from(disks.counts[b]));
    }
    pass.finish(moments)
}

/// [`child_lod`]'s pass over a child's blocks, which a build out of core feeds a window of
/// blocks at a time (`super::streamed`): the same operations in the same order.
pub(super) struct ChildPass {
    frame: Frame,
    center: DVec3,
    axis: DVec3,
    shape: DiskShape,
    far: f64,
    spread: Spread,
    min_cos: f64,
}

impl ChildPass {
    /// The pass for a child whose box has centre `box_center`, whose blocks start with
    /// `first`, and whose disks have `moments`.
    #[inline(always)]
    pub(super) fn new(box_center: Vec3, first: &SplatBlock, moments: &Moments, shape: DiskShape) -> Self {
        let frame = moments.frame(first.splat(0).normal);
        let (center, axis) = (box_center.as_dvec3(), frame.normal().as_dvec3());
        Self { frame, center, axis, shape, far: 0.0, spread: Spread::default(), min_cos: 1.0 }
    }

    /// The child's next block, holding `count` disks.
    #[inline(always)]
    pub(super) fn add(&mut self, block: &SplatBlock, count: usize) {
        let (far_lanes, cos_lanes) = (farthest_lanes(self.center, block, self.shape), cos_lanes(self.axis, block));
        // Compares, not `f64::max`, whose NaN rules cost four instructions a lane: no value
        // here is NaN, and neither the bounds nor the cone depend on a zero's sign.
        for i in 0..count {
            self.far = if far_lanes[i] > self.far { far_lanes[i] } else { self.far };
            self.min_cos = if cos_lanes[i] < self.min_cos { cos_lanes[i] } else { self.min_cos };
        }
        self.spread.add_block(&self.frame, block, count);
    }

    #[inline(always)]
    pub(super) fn finish(self, moments: &Moments) -> ChildLod {
        let Representative { splat: rep, coherent } = self.frame.representative(&self.spread);
        let cos_angle = if coherent {
            // A little wider than measured: rounding must never make the cone exclude a normal.
            (self.min_cos - 1e-5).max(-1.0) as f32
        } else {
            -1.0 // normals that cancel out: a cone that never culls
        };
        ChildLod { aggregate: moments.aggregate(), radius: round_up(self.far), cos_angle, rep }
    }
}

/// [`farthest`] from `p` for each lane of `block`, in the same operations: written over lanes,
/// the compiler vectorizes it. With [`Spread::add_block`] and plain compares for the extremes,
/// `child_lod` took 578 million instructions of the 1-million-point torus's build, where it
/// took 779 splat by splat (callgrind).
#[inline(always)]
fn farthest_lanes(p: DVec3, block: &SplatBlock, shape: DiskShape) -> [f64; BLOCK] {
    let [cx, cy, cz] = block.centers_f64();
    let [nx, ny, nz] = block.normals_f64();
    let r = block.radii().map(f64::from);
    let mut far = [0.0; BLOCK];
    // The shape's branch outside the loop, by hand: left to the compiler, the lane loop was
    // vectorised or not with unrelated changes (the dragon's build 0.058 or 0.066 s).
    let mut lanes = |shape: DiskShape| {
        for i in 0..BLOCK {
            far[i] = farthest_of([cx[i] - p.x, cy[i] - p.y, cz[i] - p.z], [nx[i], ny[i], nz[i]], r[i], shape);
        }
    };
    match shape {
        DiskShape::Oriented => lanes(DiskShape::Oriented),
        DiskShape::RayFacing => lanes(DiskShape::RayFacing),
    }
    far
}

/// The cosine between `axis` and each lane's normal.
#[inline(always)]
fn cos_lanes(axis: DVec3, block: &SplatBlock) -> [f64; BLOCK] {
    let [nx, ny, nz] = block.normals_f64();
    let mut cos = [0.0; BLOCK];
    for i in 0..BLOCK {
        cos[i] = nx[i] * axis.x + ny[i] * axis.y + nz[i] * axis.z;
    }
    cos
}

/// The moments of the disks below every node: its leaf children's summed in parallel, then its
/// inner children's merged in from the leaves up (children are stored after their parent).
/// Serially, this took a sixth of the dragon's level-of-detail build.
fn node_moments(nodes: &[Node], disks: &Disks, ranges: &[Range<usize>]) -> Vec<Moments> {
    let leaves = |n: &Node| {
        let mut m = Moments::default();
        for i in (0..WIDTH).filter(|i| n.used & (1 << i) != 0 && n.child[*i] & LEAF != 0) {
            m.merge(&disks.moments(child_range(n.child[i], ranges)));
        }
        m
    };
    let mut moments: Vec<Moments> = nodes.par_iter().map(leaves).collect();
    for k in (0..nodes.len()).rev() {
        let n = &nodes[k];
        let (this, below) = moments.split_at_mut(k + 1);
        for i in (0..WIDTH).filter(|i| n.used & (1 << i) != 0 && n.child[*i] & LEAF == 0) {
            this[k].merge(&below[n.child[i] as usize - k - 1]);
        }
    }
    moments
}

/// A node's level-of-detail payload: its children's spheres and cones, their representatives
/// (child `i` in lane `i`) and aggregates.
pub(super) struct Payload {
    pub(super) lod: NodeLod,
    pub(super) representatives: SplatBlock,
    pub(super) aggregate: NodeAggregate,
}

/// Level-of-detail payload of every node (`lod[k]` for `nodes[k]`, and so on). Also sets every
/// node's level-of-detail slots and `min_radius`.
pub(super) fn build(nodes: &mut [Node], disks: &Disks, shape: DiskShape) -> Lod {
    let ranges = node_ranges(nodes);
    let moments = node_moments(nodes, disks, &ranges);
    // Unzipped straight into the two arrays: collected as pairs and then split, the pairs took
    // 256 bytes a node beside both. A node a job: a node's pass costs its splats, the root all
    // of them, and rayon's default jobs of a quarter of the nodes left one thread idle (the
    // dragon's build 0.0575 → 0.0555 s, two threads, medians of nine alternating runs).
    let (lod, (reps, aggregates)): (Vec<NodeLod>, (Vec<SplatBlock>, Vec<NodeAggregate>)) = nodes
        .par_iter()
        .with_max_len(1)
        .map(|n| {
            let p = node_lod(n, disks, &ranges, &moments, shape);
            (p.lod, (p.representatives, p.aggregate))
        })
        .unzip();
    let root = moments.into_iter().next().unwrap_or_default();
    for (n, l) in nodes.iter_mut().zip(&lod) {
        mark_lod_slots(n, l);
    }
    Lod { lod, representatives: reps, aggregates, root }
}

/// A tree's level-of-detail arrays (node by node), and the moments of the disks below its root.
pub(super) struct Lod {
    pub(super) lod: Vec<NodeLod>,
    pub(super) representatives: Vec<SplatBlock>,
    pub(super) aggregates: Vec<NodeAggregate>,
    pub(super) root: Moments,
}

/// The level-of-detail payload and the representatives of one node's children. Never inlined:
/// inside the parallel iterator's closure, its lane loops were vectorised or not as unrelated
/// code elsewhere changed (the dragon's build 0.061 or 0.066 s).
#[inline(never)]
fn node_lod(n: &Node, disks: &Disks, ranges: &[Range<usize>], moments: &[Moments], shape: DiskShape) -> Payload {
    let children: [Option<ChildLod>; WIDTH] = std::array::from_fn(|i| {
        (n.used & (1 << i) != 0).then(|| {
            let below = child_range(n.child[i], ranges);
            // A leaf child's moments are summed again here (`node_moments` summed them
            // into its parent's): one pass over the leaves, where keeping them would
            // take a `Moments` per leaf.
            let leaf_moments;
            let m = match n.child[i] {
                child if child & LEAF != 0 => {
                    leaf_moments = disks.moments(below.clone());
                    &leaf_moments
                }
                child => &moments[child as usize],
            };
            child_lod(n.child_bounds(i).center(), disks, below, m, shape)
        })
    });
    payload(&children)
}

/// A node's payload from its children's (`None` for unused slots).
pub(super) fn payload(children: &[Option<ChildLod>; WIDTH]) -> Payload {
    let lane = |f: &dyn Fn(&ChildLod) -> f32, unused: f32| {
        Lanes::from_array(std::array::from_fn(|i| children[i].as_ref().map_or(unused, f)))
    };
    let lod = NodeLod { radius: lane(&|c| c.radius, 0.0), cos_angle: lane(&|c| c.cos_angle, -1.0) };
    let unused = Splat { center: Vec3::ZERO, radius: 0.0, normal: Vec3::Z, color: 0 };
    let reps: [Splat; WIDTH] = std::array::from_fn(|i| children[i].as_ref().map_or(unused, |c| c.rep));
    let aggregate = NodeAggregate {
        area_radius: lane(&|c| c.aggregate.area_radius, 0.0),
        agreement: lane(&|c| c.aggregate.agreement, 0.0),
    };
    Payload { lod, representatives: SplatBlock::new(&reps), aggregate }
}

/// Sets the children of `n` a ray may replace by their representatives and its `min_radius`,
/// from its spheres `l`.
pub(super) fn mark_lod_slots(n: &mut Node, l: &NodeLod) {
    // A leaf of a few splats costs about what its representative does to test: it is never
    // replaced, and full detail there is free.
    let coarse: Vec<usize> = (0..WIDTH)
        .filter(|&i| n.used & (1 << i) != 0 && (n.child[i] & LEAF == 0 || leaf_size(n.child[i]) > ALWAYS_FULL_LEAF))
        .collect();
    n.used = n.used & !(SLOTS << LOD_SLOTS_SHIFT) | coarse.iter().fold(0, |m, i| m | 1 << i) << LOD_SLOTS_SHIFT;
    n.min_radius = coarse.iter().map(|&i| l.radius[i]).fold(f32::INFINITY, f32::min);
}

/// Marks the nodes that test their children's spheres rather than their boxes.
pub(super) fn choose_node_bounds(nodes: &mut [Node], lod: &[NodeLod], choice: NodeBounds) {
    choose_node_bounds_below(nodes, lod, choice, 0);
}

/// [`choose_node_bounds`] for a subtree (its nodes in `nodes`, children after their parents,
/// the root first) whose root lies `root_depth` levels down.
pub(super) fn choose_node_bounds_below(nodes: &mut [Node], lod: &[NodeLod], choice: NodeBounds, root_depth: u32) {
    let mut depth = vec![root_depth; nodes.len()];
    for k in 0..nodes.len() {
        let n = &nodes[k];
        for i in (0..WIDTH).filter(|i| n.used & (1 << i) != 0 && n.child[*i] & LEAF == 0) {
            // (A chunked tree's top leaves its chunks' nodes out: `super::streamed`.)
            let below = depth[k] + 1;
            if let Some(d) = depth.get_mut(n.child[i] as usize) {
                *d = below;
            }
        }
    }
    for (k, n) in nodes.iter_mut().enumerate() {
        let spheres = match choice {
            NodeBounds::Boxes => false,
            NodeBounds::SpheresFrom(level) => depth[k] >= level,
            NodeBounds::Auto => {
                let used = (0..WIDTH).filter(|i| n.used & (1 << i) != 0);
                let sphere_area: f32 =
                    used.clone().map(|i| 4.0 * std::f32::consts::PI * lod[k].radius[i].powi(2)).sum();
                let box_area: f32 = used.map(|i| 2.0 * n.child_bounds(i).half_area()).sum();
                sphere_area < box_area
            }
        };
        n.used = (n.used & !SPHERE_NODE) | if spheres { SPHERE_NODE } else { 0 };
        // Finite, so that culling rays (reach +∞) take the step at every node.
        n.multires_below = if spheres { f32::NEG_INFINITY } else { n.min_radius.min(f32::MAX) };
    }
}

/// Checks the level-of-detail invariants: each child's sphere (about its box's centre) contains
/// every disk below it, and its cone (about its representative's normal) every normal below it.
pub(super) fn check_invariants(bvh: &Bvh) -> Result<(), String> {
    fn splats_below(bvh: &Bvh, child: u32) -> Vec<Splat> {
        let child = if Bvh::is_treelet(child) { bvh.enter(child).expect("a whole treelet") } else { child };
        if child & LEAF != 0 {
            return leaf_splats(child).map(|j| bvh.splat(j)).collect();
        }
        let n = &bvh.nodes[child as usize];
        (0..WIDTH).filter(|i| n.used & (1 << i) != 0).flat_map(|i| splats_below(bvh, n.child[i])).collect()
    }
    for (k, n) in bvh.nodes.iter().enumerate() {
        let l = &bvh.lod[k];
        for i in (0..WIDTH).filter(|i| n.used & (1 << i) != 0) {
            // As the traversal finds them: the box's centre and the representative's normal.
            let (center, axis) = (n.child_bounds(i).center(), bvh.representative(k, i).normal);
            for s in &splats_below(bvh, n.child[i]) {
                let far = farthest(center.as_dvec3(), s, bvh.shape);
                if far > f64::from(l.radius[i]) {
                    return Err(format!("node {k} child {i}: sphere {center} r {} misses {s:?} ({far})", l.radius[i]));
                }
                if s.normal.dot(axis) < l.cos_angle[i] {
                    return Err(format!("node {k} child {i}: cone {axis} cos {} misses {s:?}", l.cos_angle[i]));
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_lod_is_one_cache_line() {
        assert_eq!(size_of::<NodeLod>(), 64);
    }

    #[test]
    fn farthest_point_of_a_disk() {
        let s = Splat { center: Vec3::new(3.0, 0.0, 0.0), radius: 1.0, normal: Vec3::Z, color: 0 };
        assert!((farthest(DVec3::ZERO, &s, DiskShape::Oriented) - 4.0).abs() < 1e-12);
        let s = Splat { normal: Vec3::X, ..s };
        assert!((farthest(DVec3::ZERO, &s, DiskShape::Oriented) - 10f64.sqrt()).abs() < 1e-12);
        assert!((farthest(DVec3::ZERO, &s, DiskShape::RayFacing) - 4.0).abs() < 1e-12);
    }

    #[test]
    fn representative_of_one_disk_is_the_disk() {
        let s = Splat { center: Vec3::new(1.0, 2.0, 3.0), radius: 0.5, normal: Vec3::Y, color: 0x00_80_40_20 };
        let disks = Disks { blocks: &[SplatBlock::new(&[s])], counts: &[1] };
        let c = child_lod(s.center, &disks, 0..1, &disks.moments(0..1), DiskShape::Oriented);
        assert_eq!(c.rep, s);
        assert!(c.cos_angle > 0.9999 && (c.radius - 0.5).abs() < 1e-5);
    }

    /// The block-lane moments, bounds and spread against the scalar functions, disk by disk,
    /// bit for bit.
    #[test]
    fn child_lod_equals_the_scalar_bounds() {
        let splats: Vec<Splat> = (0..21)
            .map(|i| {
                let t = i as f32 * 0.37;
                let normal = Vec3::new(t.sin(), 0.6 + 0.1 * t.cos(), (2.0 * t).cos()).normalize();
                Splat {
                    center: Vec3::new(t.cos() * 3.1, t * 0.21, (t * 1.7).sin()),
                    radius: 0.05 + 0.01 * t,
                    normal,
                    color: 0,
                }
            })
            .collect();
        let blocks: Vec<SplatBlock> = splats.chunks(BLOCK).map(SplatBlock::new).collect();
        let counts: Vec<u8> = splats.chunks(BLOCK).map(|c| c.len() as u8).collect();
        let disks = Disks { blocks: &blocks, counts: &counts };
        // The splats as the blocks hold them (rounded: these are not snapped).
        let splats: Vec<Splat> = (0..splats.len()).map(|i| blocks[i / BLOCK].splat(i % BLOCK)).collect();
        let box_center = Vec3::new(0.3, 2.0, -0.1);
        for shape in [DiskShape::Oriented, DiskShape::RayFacing] {
            let lanes = child_lod(box_center, &disks, 0..blocks.len(), &disks.moments(0..blocks.len()), shape);
            let frame = Moments::of(splats.iter()).frame(splats[0].normal);
            let axis = frame.normal().as_dvec3();
            let mut spread = Spread::default();
            splats.iter().for_each(|s| spread.add(&frame, s));
            let far = splats.iter().map(|s| farthest(box_center.as_dvec3(), s, shape)).fold(0.0, f64::max);
            let min_cos = splats.iter().map(|s| s.normal.as_dvec3().dot(axis)).fold(1.0, f64::min);
            assert_eq!(lanes.radius.to_bits(), round_up(far).to_bits());
            assert_eq!(lanes.cos_angle.to_bits(), ((min_cos - 1e-5).max(-1.0) as f32).to_bits());
            assert_eq!(lanes.rep, frame.representative(&spread).splat);
        }
    }

    #[test]
    fn opposite_normals_never_cull() {
        let a = Splat { center: Vec3::ZERO, radius: 0.5, normal: Vec3::Z, color: 0 };
        let b = Splat { normal: -Vec3::Z, ..a };
        let disks = Disks { blocks: &[SplatBlock::new(&[a, b])], counts: &[2] };
        assert_eq!(child_lod(Vec3::ZERO, &disks, 0..1, &disks.moments(0..1), DiskShape::Oriented).cos_angle, -1.0);
    }
}
