//! Front-to-back traversal: test both children's boxes at once, visit the nearer first, keep
//! the farther on a stack with its entry distance so it can be culled later when the
//! visitor's `t_max` has shrunk below it.

use glam::{Vec4, Vec4Swizzles};

use super::{Bvh, LEAF, MAX_DEPTH, Node, leaf_range};
use crate::accel::{SplatVisitor, TraversalStats};
use crate::math::Ray;

/// The ray in the form the two-box slab test wants: per axis the origin and inverse
/// direction splatted to four lanes, and whether the axis runs backwards (then the near
/// plane of each box is its `hi` side).
struct SlabRay {
    origin: [Vec4; 3],
    inv_dir: [Vec4; 3],
    backwards: [bool; 3],
}

impl SlabRay {
    fn new(ray: &Ray) -> Self {
        Self {
            origin: std::array::from_fn(|k| Vec4::splat(ray.origin[k])),
            inv_dir: std::array::from_fn(|k| Vec4::splat(ray.inv_dir[k])),
            backwards: std::array::from_fn(|k| ray.inv_dir[k] < 0.0),
        }
    }

    /// Entry distances of both children of `node` within `[t0, t1]`; infinity for a miss.
    #[inline(always)]
    fn entries(&self, node: &Node, t0: f32, t1: f32) -> [f32; 2] {
        // Lanes: [near₀, near₁, far₀, far₁] per axis.
        let t = |k: usize| {
            let b = if self.backwards[k] { node.bounds[k].zwxy() } else { node.bounds[k] };
            (b - self.origin[k]) * self.inv_dir[k]
        };
        let (tx, ty, tz) = (t(0), t(1), t(2));
        let near = tx.max(ty).max(tz).max(Vec4::splat(t0));
        let far = tx.min(ty).min(tz).min(Vec4::splat(t1)).zwxy();
        let hit = near.cmple(far);
        [if hit.test(0) { near.x } else { f32::INFINITY }, if hit.test(1) { near.y } else { f32::INFINITY }]
    }
}

/// Widens the visitor's `t_max` for culling by a few ulps: a box's entry distance and the hit
/// distance of a disk lying on the box's face are rounded differently, and a box must never be
/// culled against a hit it may tie with (accelerators must find the same nearest disk).
#[inline(always)]
fn cull_limit(t_max: f32) -> f32 {
    t_max * (1.0 + 1.0 / 65536.0)
}

pub(super) fn traverse<V: SplatVisitor>(bvh: &Bvh, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
    if bvh.nodes.is_empty() {
        return;
    }
    let slab = SlabRay::new(ray);
    // (child reference, entry distance)
    let mut stack = [(0u32, 0f32); MAX_DEPTH + 2];
    let mut sp = 0;
    let mut current = (0u32, ray.t_min);
    loop {
        let (child, entry) = current;
        if entry <= cull_limit(visitor.t_max()) {
            if child & LEAF != 0 {
                for i in leaf_range(child) {
                    stats.splat_tests += 1;
                    visitor.visit(ray, &bvh.splats[i], i as u32);
                }
                if visitor.done() {
                    return;
                }
            } else {
                let node = &bvh.nodes[child as usize];
                stats.nodes_visited += 2;
                let t = slab.entries(node, ray.t_min, cull_limit(visitor.t_max()));
                let (near, far) = if t[0] <= t[1] { (0, 1) } else { (1, 0) };
                if t[near] < f32::INFINITY {
                    if t[far] < f32::INFINITY {
                        stack[sp] = (node.child[far], t[far]);
                        sp += 1;
                    }
                    current = (node.child[near], t[near]);
                    continue;
                }
            }
        }
        if sp == 0 {
            return;
        }
        sp -= 1;
        current = stack[sp];
    }
}
