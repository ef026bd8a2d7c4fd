//! Front-to-back traversal: test a node's eight child bounds at once, go on with the nearest
//! child hit, and keep the others on a stack with their entry distances, so that they can be
//! culled later when the visitor's `t_max` has shrunk below them.
//!
//! The multiresolution steps (thesis ch. 3) come between testing the children and descending:
//! children whose normal cone faces away from the ray's origin are dropped, and children whose
//! bounding sphere is smaller than the ray's footprint hand their representative splat to the
//! visitor instead of being entered. Rays that use none of it (and trees without sphere nodes)
//! run the full-detail loop, compiled without those steps.

use super::lanes::{Wide, dot3};
use super::lod::NodeLod;
use arrayvec::ArrayVec;

use super::{Bvh, LEAF, LOD_SLOTS_SHIFT, MAX_DEPTH, Node, SLOTS, SPHERE_NODE, WIDTH, leaf_blocks, leaf_size};
use crate::accel::block::{BLOCK, LeafKernel, SplatBlock};
use crate::accel::{Crossing, SplatVisitor, TraversalStats};
use crate::math::Ray;

/// The ray in the form the eight-wide tests want: per axis the origin, direction and negated
/// inverse direction splatted to all lanes, and the footprint scaled by the level-of-detail
/// threshold.
pub(super) struct SlabRay<W> {
    origin: [W; 3],
    dir: [W; 3],
    /// −1/d per axis, held within ±[`MAX_INV_DIR`]: finite, so no slab distance is NaN (0·∞)
    /// and [`Self::entries`] needs no rule for one.
    neg_inv_dir: [W; 3],
    /// τ·width0 and τ·spread: a child is below the footprint when R < lod0 + lod_spread·t.
    lod0: W,
    lod_spread: W,
}

impl<W: Wide> SlabRay<W> {
    #[inline(always)]
    pub(super) fn new(ray: &Ray) -> Self {
        let tau = ray.lod_threshold;
        Self {
            origin: std::array::from_fn(|k| W::splat(ray.origin[k])),
            dir: std::array::from_fn(|k| W::splat(ray.dir[k])),
            // `max` then `min`, not `clamp`, which keeps NaN and so compiles to branches (8
            // instructions a ray, callgrind); a NaN direction becomes finite here, and its ray
            // still crosses no disk.
            #[allow(clippy::manual_clamp)]
            neg_inv_dir: std::array::from_fn(|k| W::splat((-ray.inv_dir[k]).max(-MAX_INV_DIR).min(MAX_INV_DIR))),
            lod0: W::splat(tau * ray.cone.width0),
            lod_spread: W::splat(tau * ray.cone.spread),
        }
    }

    /// The children's sphere centres, their boxes' centres, seen from the ray's origin, c − o:
    /// found once for the sphere test, the footprint and the cone. (As the build computes
    /// them, to the bit; NaN in unused slots, which every test masks off.)
    #[inline(always)]
    fn to_centers(&self, node: &Node) -> [W; 3] {
        // Written out: through `array::from_fn` the closure, compiled without the instruction
        // set's features, was called rather than inlined (and the loads in it too).
        let p = &node.planes;
        let half = W::splat(0.5);
        [
            (W::load(&p[0]) + W::load(&p[3])) * half - self.origin[0],
            (W::load(&p[1]) + W::load(&p[4])) * half - self.origin[1],
            (W::load(&p[2]) + W::load(&p[5])) * half - self.origin[2],
        ]
    }

    /// Distances along the ray of the projections of the children's sphere centres.
    #[inline(always)]
    fn center_distances(&self, oc: &[W; 3]) -> W {
        dot3(oc, &self.dir)
    }

    /// Like [`Self::entries`] for the children's bounding spheres (QSplat's test, A4), given
    /// their centres' distances `tc`. The entry distance is tc − R, a little before the true
    /// one, which saves a square root and only delays culling. The radii are widened by a few
    /// ulps of the distance, the rounding error of the perpendicular distance, so that a disk
    /// touching its sphere is never missed (hits must not depend on the bounds chosen).
    #[inline(always)]
    fn sphere_entries(&self, lod: &NodeLod, oc: &[W; 3], tc: W, used: u32, t0: f32, t1: f32) -> (W, u32) {
        let perp: [W; 3] = std::array::from_fn(|k| oc[k] - tc * self.dir[k]);
        let r = W::load(&lod.radius) + tc.abs() * W::splat(1.0 / 262_144.0);
        let near = (tc - r).max(W::splat(t0));
        let far = (tc + r).min(W::splat(t1));
        (near, W::bitmask(dot3(&perp, &perp).cmple(r * r) & near.cmple(far)) & used)
    }

    /// Children whose bounding sphere is narrower than the footprint at its centre, scaled by
    /// the threshold: R < τ·(width0 + spread·tc).
    #[inline(always)]
    fn below_footprint(&self, lod: &NodeLod, tc: W) -> u32 {
        W::bitmask(W::load(&lod.radius).cmplt(self.lod0 + self.lod_spread * tc.max(W::splat(0.0))))
    }

    /// Children all of whose disks face away from the ray's origin from every point of their
    /// sphere (RECONSTRUCTION A7, with the origin as the eye). With v = o − c at angle φ to the
    /// cone's axis and s = v·axis, the largest v·n over a cone of half-angle θ ≤ 90° is
    /// |v|·cos(φ − θ) = s·cos θ + √(|v|² − s²)·sin θ, and the subtree faces away when that is
    /// below −R. Squared to avoid the roots: R + s·cos θ < 0 and
    /// (|v|² − s²)·sin²θ < (R + s·cos θ)². Cones of 90° or more never cull. Computed from
    /// `oc` = −v: with s' = oc·axis = −s, R + s·cos θ is R − s'·cos θ to the bit.
    #[inline(always)]
    fn facing_away(&self, lod: &NodeLod, reps: &SplatBlock, oc: &[W; 3]) -> u32 {
        // The cones' axes are the representatives' normals.
        let axis = [0, 1, 2].map(|k| W::load(&reps.normal_node_lanes(k)));
        let s = dot3(oc, &axis);
        let cos = W::load(&lod.cos_angle);
        // A slightly larger sphere: rounding must not cull a subtree that just faces the ray.
        let gap = W::load(&lod.radius) * W::splat(1.0 + 1.0 / 1024.0) - s * cos;
        let zero = W::splat(0.0);
        let spread = (dot3(oc, oc) - s * s).max(zero) * (W::splat(1.0) - cos * cos);
        W::bitmask(gap.cmplt(zero) & spread.cmplt(gap * gap) & cos.cmpgt(zero))
    }

    /// Entry distances of the eight children of `node` within `[t0, t1]`, and a bit mask of
    /// the children the ray enters.
    ///
    /// Each axis gives the distances to both planes, (o − p)·(−1/d), which is (p − o)/d to the
    /// bit, and the nearer is the entry: no per-ray choice of near and far planes, whose
    /// indices cost a load and a shift per plane (callgrind on the dragon, then with 4-wide
    /// nodes: 62 → 50 instructions a node). Unused slots (minimum +∞, maximum −∞) come out
    /// entered and are masked off.
    #[inline(always)]
    pub(super) fn entries(&self, node: &Node, t0: f32, t1: f32) -> (W, u32) {
        let slab = |k: usize| {
            let lo = (self.origin[k] - W::load(&node.planes[k])) * self.neg_inv_dir[k];
            let hi = (self.origin[k] - W::load(&node.planes[3 + k])) * self.neg_inv_dir[k];
            (lo.min(hi), lo.max(hi))
        };
        let ((near0, far0), (near1, far1), (near2, far2)) = (slab(0), slab(1), slab(2));
        let near = near0.max(near1).max(near2).max(W::splat(t0));
        let far = far0.min(far1).min(far2).min(W::splat(t1));
        (near, W::bitmask(near.cmple(far)) & node.used & SLOTS)
    }
}

/// The largest |1/d| a slab test multiplies by (2⁶⁴): a ray parallel to an axis gets entry and
/// exit distances of ±(p − o)·2⁶⁴ instead of ±∞, finite, and the same verdict wherever the
/// origin is not within 2⁻⁶⁴·t of the plane (where it enters, which costs a visit, never a
/// hit). Clamping the ray's own inverse costs two instructions an axis where raising |d|
/// before dividing cost seven.
const MAX_INV_DIR: f32 = 18_446_744_073_709_551_616.0;

/// Children in use: a table, as the x86-64 baseline has no `popcnt` and `count_ones` would
/// cost a dozen instructions per node.
#[inline(always)]
fn slot_count(used: u32) -> u64 {
    const COUNT: [u8; 1 << WIDTH] = {
        let mut count = [0; 1 << WIDTH];
        let mut i = 0;
        while i < count.len() {
            count[i] = (i as u32).count_ones() as u8;
            i += 1;
        }
        count
    };
    u64::from(COUNT[(used & SLOTS) as usize])
}

/// Widens the visitor's `t_max` for culling by a few ulps: a box's entry distance and the hit
/// distance of a disk lying on the box's face are rounded differently, and a box must never be
/// culled against a hit it may tie with (accelerators must find the same nearest disk).
#[inline(always)]
fn cull_limit(t_max: f32) -> f32 {
    t_max * (1.0 + 1.0 / 65536.0)
}

/// Entries the traversal stack holds: each level of the tree pushes at most WIDTH − 1, and no
/// tree is deeper than [`MAX_DEPTH`].
const STACK_ENTRIES: usize = (WIDTH - 1) * MAX_DEPTH + 1;

/// A traversal's stack: (child reference, entry distance). On the thread's stack and left
/// uninitialised (an `ArrayVec`), so that a ray pays for neither a memset of it (a zeroed
/// array of 64 entries cost 3 % of the dragon's first-hit rays a second) nor a thread-local
/// taken out and put back (a `Cell<Vec>`: 32 instructions a ray, callgrind).
type Stack = ArrayVec<(u32, f32), STACK_ENTRIES>;

/// Inlined into each instruction-set build of `accel::isa`, which calls it, with `multires`,
/// which runs [`multires_walk`] for the same instruction set as a function of its own.
#[inline(always)]
pub(crate) fn traverse<V: SplatVisitor, K: LeafKernel>(
    bvh: &Bvh,
    ray: &Ray,
    visitor: &mut V,
    stats: &mut TraversalStats,
    kernel: K,
    multires: impl Fn(&mut V, &mut TraversalStats, &Levels),
) {
    if bvh.nodes.is_empty() {
        return;
    }
    debug_assert!(bvh.depth <= MAX_DEPTH);
    let mut stack = Stack::new();
    if stats.counting() {
        dispatch::<V, K, true>(bvh, ray, visitor, stats, &mut stack, kernel, &multires);
    } else {
        dispatch::<V, K, false>(bvh, ray, visitor, stats, &mut stack, kernel, &multires);
    }
}

/// Full-detail rays through a tree of boxes take the loop without the multiresolution steps;
/// the others `multires`, the loop with them.
///
/// The walk counts its work in a local, which can live in registers, and adds it to `stats`
/// once, if `COUNT`; otherwise the local is never read and the compiler drops the counting
/// from that instance (on the dragon, first hit: 811 → 786 instructions a pixel and 2–5 % more
/// rays a second, alternating runs). With the choice a run-time test here, between a local
/// that was added and one that was not, a change to the multiresolution steps moved the
/// first-hit count by up to 17 instructions a pixel (callgrind), in code they never run.
#[inline(always)]
fn dispatch<V: SplatVisitor, K: LeafKernel, const COUNT: bool>(
    bvh: &Bvh,
    ray: &Ray,
    visitor: &mut V,
    stats: &mut TraversalStats,
    stack: &mut Stack,
    kernel: K,
    multires: &impl Fn(&mut V, &mut TraversalStats, &Levels),
) {
    let lod_reach = lod_reach(bvh, ray);
    let lod = lod_reach > 0.0;
    // A node takes the multiresolution step when `reach` exceeds its `multires_below`: always
    // for culling rays, at sphere nodes, and where a child may be narrower than the footprint.
    let reach = if ray.cull_backfaces { f32::INFINITY } else { lod_reach };
    let levels = Levels { lod_reach, reach };
    let mut counts = TraversalStats::default();
    if lod || ray.cull_backfaces || !bvh.plain_walk {
        multires(visitor, stats, &levels);
    } else {
        traverse_from::<V, K, false>(bvh, ray, visitor, &mut counts, stack, &levels, kernel);
    }
    if COUNT {
        *stats += counts;
    }
}

/// The multiresolution loop, for `traverse`'s `multires`: compiled as a function of its own
/// (per instruction set), so that the full-detail loop's registers and stack frame are its
/// own. Inlined into one function, a change to either moved the other's instruction counts
/// by up to 27 a pixel, in code it never ran; apart, the dragon's first hits took 703 → 693
/// instructions a pixel and SJ 968 → 959, and its distant samples (SJ, 64 a pixel, level of
/// detail) 1,202 → 1,233, the price of the call (callgrind).
#[inline(always)]
pub(crate) fn multires_walk<V: SplatVisitor, K: LeafKernel>(
    bvh: &Bvh,
    ray: &Ray,
    visitor: &mut V,
    stats: &mut TraversalStats,
    levels: &Levels,
    kernel: K,
) {
    let mut stack = Stack::new();
    // Counted in a local, as `dispatch` does. The two arms call the same loop, and the second
    // never reads the local, so the compiler drops the counting from that copy: one arm
    // adding the counts only when asked cost the distant samples 1,166 → 1,204 instructions
    // each (callgrind), a counted loop for the uncounted ones too.
    let mut counts = TraversalStats::default();
    if stats.counting() {
        traverse_from::<V, K, true>(bvh, ray, visitor, &mut counts, &mut stack, levels, kernel);
        *stats += counts;
    } else {
        traverse_from::<V, K, true>(bvh, ray, visitor, &mut counts, &mut stack, levels, kernel);
    }
}

/// The widest the ray's footprint gets (scaled by τ) before it leaves the model: subtrees no
/// narrower than this never stop it. 0 where no subtree can: τ = 0, or close up, where only
/// the smallest nodes could (below `lod_floor`), and the ray takes the full-detail loop.
#[inline(always)]
pub(super) fn lod_reach(bvh: &Bvh, ray: &Ray) -> f32 {
    if ray.lod_threshold <= 0.0 {
        return 0.0;
    }
    let b = &bvh.bounds;
    let exit = ((b.min - ray.origin) * ray.inv_dir).max((b.max - ray.origin) * ray.inv_dir).min_element();
    let reach = ray.lod_threshold * ray.cone.width_at(if exit.is_nan() { f32::INFINITY } else { exit });
    if reach > bvh.lod_floor { reach } else { 0.0 }
}

/// Where the multiresolution steps apply, per ray (see `dispatch`).
pub(crate) struct Levels {
    /// Children narrower than this may stop the ray (0: none).
    lod_reach: f32,
    /// Nodes whose `multires_below` is under this take the multiresolution step.
    reach: f32,
}

/// The traversal proper, with `stack` large enough for the tree: entries are (child
/// reference, entry distance).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn traverse_from<V: SplatVisitor, K: LeafKernel, const MULTIRES: bool>(
    bvh: &Bvh,
    ray: &Ray,
    visitor: &mut V,
    stats: &mut TraversalStats,
    stack: &mut Stack,
    levels: &Levels,
    kernel: K,
) {
    // Made here, in each instance of the loop, so that the full-detail one computes only the
    // lanes it reads, not the direction's and the footprint's (726 → 722 instructions a pixel
    // on the dragon, first hits, callgrind).
    let slab = &SlabRay::<K::Lanes>::new(ray);
    let mut current = (0, ray.t_min);
    loop {
        let (child, entry) = current;
        if entry <= cull_limit(visitor.t_max()) {
            if child & LEAF != 0 {
                stats.splat_tests += leaf_size(child) as u64;
                let blocks = leaf_blocks(child);
                let first = blocks.start;
                // One counter over the leaf's blocks (zipped with their index range, the SJ
                // window's walk took 950 instructions a pixel where this takes 912, callgrind).
                for (j, block) in bvh.blocks[blocks].iter().enumerate() {
                    let b = first + j;
                    let hits = kernel.hits(block, V::SHAPE, ray, visitor.t_max());
                    let mut lanes = hits.mask;
                    while lanes != 0 {
                        let lane = lanes.trailing_zeros() as usize;
                        lanes &= lanes - 1;
                        // An earlier lane may have narrowed the walk since the block was tested:
                        // this is then the scalar test against the new t_max (its range check on
                        // t·den, 2⁻¹⁶ wide, holds wherever t does but where t_max·den underflows).
                        if hits.t[lane] <= visitor.t_max() {
                            let index = (b * BLOCK + lane) as u32;
                            visitor.hit(ray, Crossing::new(index, &block.splat(lane), hits.hit(lane)));
                        }
                    }
                }
                if visitor.done() {
                    return;
                }
            } else {
                let k = child as usize;
                // Past the nodes: a stored top's treelet, entered at its root (checked the
                // first time), or walked as empty if damaged. Stored trees take the
                // multiresolution loop only (see `dispatch`), so that the full-detail one keeps
                // its bounds check's panic path (a branch on to the stack there cost the dragon's
                // first hits 699 → 707 instructions a pixel, callgrind).
                let node = match bvh.nodes.get(k) {
                    Some(node) => node,
                    None if MULTIRES => match bvh.enter(child) {
                        Some(root) => {
                            current = (root, entry);
                            continue;
                        }
                        None => match stack.pop() {
                            Some(next) => {
                                current = next;
                                continue;
                            }
                            None => return,
                        },
                    },
                    None => unreachable!("a treelet reference in the full-detail loop"),
                };
                stats.nodes_visited += 1;
                let t1 = cull_limit(visitor.t_max());
                let (t, mut mask) = if MULTIRES && node.multires_below < levels.reach {
                    match multires_children(bvh, slab, ray, k, t1, levels.lod_reach, visitor, stats, kernel) {
                        Some(children) => children,
                        None => return, // the visitor is done
                    }
                } else {
                    stats.box_tests += slot_count(node.used);
                    slab.entries(node, ray.t_min, t1)
                };
                // An array, not a vector: indexing a vector register by a run-time lane
                // compiles to a jump table (7 instructions a child, callgrind).
                let t = t.to_array();
                if mask.is_power_of_two() {
                    // One child hit (the common case deep in the tree): no stack traffic.
                    let i = mask.trailing_zeros() as usize;
                    current = (node.child[i], t[i]);
                    continue;
                }
                if mask != 0 {
                    // Go on with the nearest child hit and push the second nearest last, so
                    // that it is popped next; the others, below it, need no order (each entry
                    // is culled by its own distance when popped). The two nearest so far stay
                    // in registers and each newcomer is ranked against them by selects, not
                    // branches (a branch here missed 1.2 times a ray in cachegrind's simulated
                    // predictor). Against the nearest alone on top of an unordered stack: on
                    // the dragon, first hit, 4.72 → 4.55 nodes and 21.5 → 19.9 disks a ray,
                    // 833 → 811 instructions a pixel, and in alternating runs 2 % more rays a
                    // second (the 1M torus 10 %). A full insertion sort of the children (4.54
                    // nodes) cost more than it saved on the dragon (−1.5 %).
                    let next = |mask: &mut u32| {
                        let i = mask.trailing_zeros() as usize;
                        *mask &= *mask - 1;
                        (node.child[i], t[i])
                    };
                    let (a, b) = (next(&mut mask), next(&mut mask));
                    let (mut nearest, mut second) = if b.1 < a.1 { (b, a) } else { (a, b) };
                    while mask != 0 {
                        let c = next(&mut mask);
                        let nearer = c.1 < nearest.1;
                        let (lo, hi) = if nearer { (c, nearest) } else { (nearest, c) };
                        let closer = hi.1 < second.1;
                        stack.push(if closer { second } else { hi });
                        second = if closer { hi } else { second };
                        nearest = lo;
                    }
                    stack.push(second);
                    current = nearest;
                    continue;
                }
            }
        }
        match stack.pop() {
            Some(entry) => current = entry,
            None => return,
        }
    }
}

/// The children of node `k` that the ray must enter, with their entry distances, after the
/// multiresolution steps: spheres instead of boxes for sphere nodes, culling of subtrees that
/// face away, and representatives handed to the visitor for subtrees narrower than the
/// footprint. `None` when the visitor is done. Inlined into the multiresolution loop only
/// (the full-detail one is a separate instance, see `dispatch`), so that it is compiled for
/// each instruction set of `accel::isa` with the rest of the traversal.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn multires_children<V: SplatVisitor, K: LeafKernel>(
    bvh: &Bvh,
    slab: &SlabRay<K::Lanes>,
    ray: &Ray,
    k: usize,
    t1: f32,
    lod_reach: f32,
    visitor: &mut V,
    stats: &mut TraversalStats,
    kernel: K,
) -> Option<(K::Lanes, u32)> {
    let node = &bvh.nodes[k];
    let node_lod = &bvh.lod[k];
    let slots = slot_count(node.used);
    let spheres = node.used & SPHERE_NODE != 0;
    let lod = node.min_radius < lod_reach;
    let oc = slab.to_centers(node);
    let tc = if spheres || lod { slab.center_distances(&oc) } else { K::Lanes::splat(0.0) };
    let (t, mut mask) = if spheres {
        stats.sphere_tests += slots;
        slab.sphere_entries(node_lod, &oc, tc, node.used & SLOTS, ray.t_min, t1)
    } else {
        stats.box_tests += slots;
        slab.entries(node, ray.t_min, t1)
    };
    if mask != 0 && ray.cull_backfaces {
        let away = slab.facing_away(node_lod, &bvh.representatives[k], &oc) & mask;
        stats.culled += u64::from(away.count_ones());
        mask &= !away;
    }
    // The block of representatives is tested only where one stands in (it was tested wherever
    // one might: the dragon at distance 16, SJ, 1,207 → 1,186 instructions a sample).
    let coarse = if lod { slab.below_footprint(node_lod, tc) & mask & (node.used >> LOD_SLOTS_SHIFT) } else { 0 };
    if coarse != 0 {
        // Subtrees narrower than the footprint: their representative stands in.
        mask &= !coarse;
        stats.lod_stops += u64::from(coarse.count_ones());
        stats.splat_tests += u64::from(coarse.count_ones());
        // All of them in one test of the node's block of representatives, where each was a
        // scalar test (the dragon at distance 16, SJ: 1,230 → 1,197 instructions a sample,
        // callgrind, with both loops in one function).
        let reps = &bvh.representatives[k];
        let hits = kernel.hits(reps, V::SHAPE, ray, visitor.t_max());
        let mut lanes = hits.mask & coarse;
        while lanes != 0 {
            let i = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            // As at a leaf: an earlier lane may have narrowed the walk.
            if hits.t[i] <= visitor.t_max() {
                let index = bvh.representative_index(k, i);
                visitor.hit(ray, Crossing::new(index, &reps.splat(i), hits.hit(i)));
            }
        }
        if visitor.done() {
            return None;
        }
    }
    Some((t, mask))
}
