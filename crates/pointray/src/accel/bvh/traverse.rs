//! Front-to-back traversal: test both children's boxes, visit the nearer first, keep the
//! farther on a stack with its entry distance so it can be culled later when the visitor's
//! `t_max` has shrunk below it.

use glam::Vec3A;

use super::{Bvh, LEAF, MAX_DEPTH, Node};
use crate::accel::{SplatVisitor, TraversalStats};
use crate::math::Ray;

/// Entry distances of both children of `node` (infinity when the ray misses the box).
#[inline(always)]
fn child_entries(node: &Node, o: Vec3A, inv: Vec3A, t0: f32, t1: f32) -> [f32; 2] {
    std::array::from_fn(|i| {
        let lo = Vec3A::new(node.min_x[i], node.min_y[i], node.min_z[i]);
        let hi = Vec3A::new(node.max_x[i], node.max_y[i], node.max_z[i]);
        crate::accel::slab(lo, hi, o, inv, t0, t1).unwrap_or(f32::INFINITY)
    })
}

pub(super) fn traverse<V: SplatVisitor>(bvh: &Bvh, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
    if bvh.nodes.is_empty() {
        return;
    }
    let o = Vec3A::from(ray.origin);
    let inv = Vec3A::from(ray.inv_dir);
    // (child reference, leaf count, entry distance)
    let mut stack = [(0u32, 0u16, 0f32); MAX_DEPTH + 2];
    let mut sp = 0;
    let mut current = (0u32, 0u16, ray.t_min);
    loop {
        let (child, count, entry) = current;
        if entry <= visitor.t_max() {
            if child & LEAF != 0 {
                let first = (child & !LEAF) as usize;
                for i in first..first + count as usize {
                    stats.splat_tests += 1;
                    visitor.visit(ray, &bvh.splats[i], i as u32);
                }
                if visitor.done() {
                    return;
                }
            } else {
                let node = &bvh.nodes[child as usize];
                stats.nodes_visited += 2;
                let t = child_entries(node, o, inv, ray.t_min, visitor.t_max());
                let (near, far) = if t[0] <= t[1] { (0, 1) } else { (1, 0) };
                if t[near] < f32::INFINITY {
                    if t[far] < f32::INFINITY {
                        stack[sp] = (node.child[far], node.count[far], t[far]);
                        sp += 1;
                    }
                    current = (node.child[near], node.count[near], t[near]);
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
