//! Front-to-back kd-tree traversal with a small stack (as in pbrt): at an inner node the ray
//! goes on into the child on its origin's side and stacks the other with the part of its
//! interval behind the plane; at a leaf every referenced splat goes to the visitor. A cell
//! that starts beyond the visitor's `t_max` ends the walk.
//!
//! The cells' intervals are widened by a relative `SLACK` at each plane, so that a hit point
//! lying on a plane, up to rounding, is looked for on both sides: which cell holds it must not
//! depend on how the plane's distance was rounded.

use super::KdTree;
use super::build::MAX_DEPTH;
use crate::accel::packet::{DiskLanes, LANES, PacketRay};
use crate::accel::{SplatVisitor, TraversalStats, test_disk};
use crate::math::Ray;
use glam::Vec3A;

/// Relative widening of the cells' intervals; far above the few ulps by which a plane's
/// distance and a disk's hit distance can disagree.
const SLACK: f32 = 1.0 / 65536.0;

/// Disks remembered per ray as tested, direct-mapped by index (one compare per disk): a splat
/// straddling several cells is met in nearby leaves, so few entries catch most repeats. The
/// visitors ignore repeats (`REPEATS_SPLATS`), so one the mailbox misses costs a test, not a
/// wrong answer.
const MAILBOX: usize = 16;

pub(super) fn traverse<V: SplatVisitor>(tree: &KdTree, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
    if tree.nodes.is_empty() {
        return;
    }
    let Some((t0, t1)) = clip(tree, ray) else { return };
    let mut counts = TraversalStats::default();
    // Each inner level stacks at most one cell. (Zeroing this array costs fewer instructions
    // than borrowing a stack kept per thread.)
    let stack = &mut [(0u32, 0f32, 0f32); MAX_DEPTH + 1];
    if let Some(lod_reach) = lod_reach(tree, ray, t1) {
        walk::<V, true>(tree, ray, (t0, t1), lod_reach, visitor, &mut counts, stack);
    } else {
        walk::<V, false>(tree, ray, (t0, t1), 0.0, visitor, &mut counts, stack);
    }
    *stats += counts;
}

/// The widest the footprint gets (scaled by τ) before the ray leaves the model at `t1`: wider
/// representatives never stop it. `None` where none can: τ = 0, or close up, where that is
/// below nearly all of them (`lod_floor`), and the ray takes the full-detail loop.
fn lod_reach(tree: &KdTree, ray: &Ray, t1: f32) -> Option<f32> {
    let reach = ray.lod_threshold * ray.cone.width_at(t1);
    (ray.lod_threshold > 0.0 && reach > tree.lod_floor).then_some(reach)
}

/// [`lod_reach`] for a ray not yet clipped to the tree (`None` also when it misses it).
pub(super) fn multires_reach(tree: &KdTree, ray: &Ray) -> Option<f32> {
    let (_, t1) = clip(tree, ray)?;
    lod_reach(tree, ray, t1)
}

/// The walk over the cells the ray crosses in `(t0, t1)`; with `MULTIRES`, inner nodes whose
/// representative is narrower than the ray's footprint stop it (only representatives narrower
/// than `lod_reach` can).
#[inline(always)]
fn walk<V: SplatVisitor, const MULTIRES: bool>(
    tree: &KdTree,
    ray: &Ray,
    (mut t0, mut t1): (f32, f32),
    lod_reach: f32,
    visitor: &mut V,
    counts: &mut TraversalStats,
    stack: &mut [(u32, f32, f32); MAX_DEPTH + 1],
) {
    // Per-axis ray data in arrays of four, indexed by `axis & 3`: no bounds checks.
    let pad = |v: glam::Vec3| [v.x, v.y, v.z, 0.0];
    let (origin, dir, inv_dir) = (pad(ray.origin), pad(ray.dir), pad(ray.inv_dir));
    let (lod0, lod_spread) = (ray.lod_threshold * ray.cone.width0, ray.lod_threshold * ray.cone.spread);
    let packet_ray = PacketRay::new(ray);
    let mut sp = 0;
    let mut node = 0;
    let mut mailbox = [u32::MAX; MAILBOX];
    // Cells that start beyond this cannot hold a hit that matters; it only shrinks, and only
    // at a leaf.
    let mut limit = visitor.t_max() * (1.0 + SLACK);
    // A cell's t0 only changes when it comes off the stack, so that is where it is checked.
    if t0 <= limit {
        loop {
            let n = tree.nodes[node];
            if !n.is_leaf() {
                let stop = MULTIRES && {
                    let rep = &tree.reps[node];
                    // One compare rules out most nodes: those wider than any footprint the ray has.
                    rep.radius < lod_reach && rep.radius > 0.0 && {
                        let tc = (rep.center - ray.origin).dot(ray.dir).max(0.0);
                        rep.radius < lod0 + lod_spread * tc
                    }
                };
                if !stop {
                    counts.nodes_visited += 1;
                    let (axis, split) = (n.axis() & 3, n.split());
                    let t_split = (split - origin[axis]) * inv_dir[axis];
                    let below_first = origin[axis] < split || (origin[axis] == split && dir[axis] <= 0.0);
                    let (first, second) = if below_first { (node + 1, n.above()) } else { (n.above(), node + 1) };
                    // The interval is already widened, so it is compared as it is.
                    if t_split > t1 || t_split <= 0.0 {
                        node = first; // the plane lies beyond the interval, or behind the origin
                    } else if t_split < t0 {
                        node = second;
                    } else {
                        stack[sp] = (second as u32, t0.max(t_split * (1.0 - SLACK)), t1);
                        sp += 1;
                        node = first;
                        t1 = t1.min(t_split * (1.0 + SLACK));
                    }
                    continue;
                }
                counts.lod_stops += 1;
                counts.splat_tests += 1;
                test_disk(ray, &tree.reps[node], tree.padding() + node as u32, visitor);
                if visitor.done() {
                    return;
                }
            } else {
                // Counted for the whole leaf here, less the packets left untested on an early exit.
                let count = n.ref_count();
                counts.splat_tests += count as u64;
                for (packet, index) in tree.refs[n.padded_refs()].chunks_exact(LANES).enumerate() {
                    let disk = |i: usize| &tree.disks[index[i] as usize];
                    let disks = DiskLanes::new([disk(0), disk(1), disk(2), disk(3)]);
                    // Padding lanes hold a disk no ray hits.
                    let mut lanes = packet_ray.candidates_as(V::SHAPE, &disks, ray.t_min, visitor.t_max());
                    while lanes != 0 {
                        let r = index[lanes.trailing_zeros() as usize];
                        lanes &= lanes - 1;
                        // Mailbox: a disk straddling the cells just crossed was tested already.
                        let slot = &mut mailbox[r as usize % MAILBOX];
                        if *slot == r {
                            continue;
                        }
                        *slot = r;
                        test_disk(ray, &tree.disks[r as usize], r, visitor);
                    }
                    if visitor.done() {
                        counts.splat_tests -= count.saturating_sub((packet + 1) * LANES) as u64;
                        return;
                    }
                }
            }
            limit = visitor.t_max() * (1.0 + SLACK);
            // The next cell on the stack that starts within the limit.
            loop {
                if sp == 0 {
                    return;
                }
                sp -= 1;
                let next;
                (next, t0, t1) = stack[sp];
                if t0 <= limit {
                    node = next as usize;
                    break;
                }
            }
        }
    }
}

/// The ray's interval inside the root cell, from `ray.t_min` on and widened by `SLACK`; `None`
/// if it misses. An axis along which the ray runs in a face's plane (0 × ∞) does not limit
/// the interval.
fn clip(tree: &KdTree, ray: &Ray) -> Option<(f32, f32)> {
    let (origin, inv_dir) = (Vec3A::from(ray.origin), Vec3A::from(ray.inv_dir));
    let a = (Vec3A::from(tree.bounds.min) - origin) * inv_dir;
    let b = (Vec3A::from(tree.bounds.max) - origin) * inv_dir;
    let flat = a.is_nan_mask() | b.is_nan_mask();
    let near = Vec3A::select(flat, Vec3A::NEG_INFINITY, a.min(b)).max_element();
    let far = Vec3A::select(flat, Vec3A::INFINITY, a.max(b)).min_element();
    let (t0, t1) = (near.max(ray.t_min) * (1.0 - SLACK), far * (1.0 + SLACK));
    (t0 <= t1).then_some((t0, t1))
}
