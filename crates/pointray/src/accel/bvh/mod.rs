//! Bounding volume hierarchy over splats: binned SAH build, two children per node.
//!
//! Each node stores the boxes of both its children (one 64-byte cache line), so a traversal
//! step tests two boxes from one line and never fetches a child the ray misses. Leaves are
//! ranges of the splat array, which the build reorders into leaf order.
//!
//! This is the full-detail BVH of the foundation; the multiresolution BVH of thesis ch. 3
//! (representative splats, bounding spheres, normal cones) grows out of it.

mod build;
mod traverse;

pub use build::BvhParams;

use glam::Vec3;

use crate::math::Aabb;
use crate::splat::Splat;

/// Marks a child reference as a leaf: the low bits are then the first splat's index.
const LEAF: u32 = 1 << 31;

/// The deepest a build may go: traversal stacks are sized from it.
pub(crate) const MAX_DEPTH: usize = 96;

/// An inner node: the bounds of its two children (structure of arrays, child 0 and 1 side by
/// side) and how to reach them.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Node {
    pub(crate) min_x: [f32; 2],
    pub(crate) min_y: [f32; 2],
    pub(crate) min_z: [f32; 2],
    pub(crate) max_x: [f32; 2],
    pub(crate) max_y: [f32; 2],
    pub(crate) max_z: [f32; 2],
    /// Inner child: its node index. Leaf child: `LEAF | first splat`.
    pub(crate) child: [u32; 2],
    /// Splats in a leaf child (0 for an inner child).
    pub(crate) count: [u16; 2],
}

impl Node {
    pub(crate) fn child_bounds(&self, i: usize) -> Aabb {
        Aabb::new(
            Vec3::new(self.min_x[i], self.min_y[i], self.min_z[i]),
            Vec3::new(self.max_x[i], self.max_y[i], self.max_z[i]),
        )
    }
}

/// The BVH and the splats it indexes, reordered so that each leaf is a contiguous range.
pub struct Bvh {
    pub(crate) nodes: Vec<Node>,
    pub(crate) splats: Vec<Splat>,
    pub(crate) bounds: Aabb,
    /// For each splat of `splats`, its index in the input the BVH was built from.
    pub(crate) input_index: Vec<u32>,
    pub(crate) depth: usize,
}

impl Bvh {
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Index in the build input of the splat at `i` in [`crate::accel::Accel::splats`].
    pub fn input_index(&self, i: u32) -> u32 {
        self.input_index[i as usize]
    }
}

impl super::Accel for Bvh {
    fn name(&self) -> &'static str {
        "bvh"
    }

    fn splats(&self) -> &[Splat] {
        &self.splats
    }

    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn memory_bytes(&self) -> usize {
        self.nodes.len() * size_of::<Node>() + self.input_index.len() * size_of::<u32>()
    }

    fn traverse<V: super::SplatVisitor>(&self, ray: &crate::math::Ray, visitor: &mut V, stats: &mut super::TraversalStats) {
        traverse::traverse(self, ray, visitor, stats);
    }
}

/// Checks the structure's invariants: every child box contains the bounds of every splat below
/// it, and every splat belongs to exactly one leaf. For tests; O(n log n).
pub fn check_invariants(bvh: &Bvh) -> Result<(), String> {
    fn walk(bvh: &Bvh, node: usize, seen: &mut [bool]) -> Result<Vec<Aabb>, String> {
        let n = &bvh.nodes[node];
        let mut all = Vec::new();
        for i in 0..2 {
            let boxed = n.child_bounds(i);
            let below = if n.child[i] & LEAF != 0 {
                let first = (n.child[i] & !LEAF) as usize;
                let range = first..first + n.count[i] as usize;
                let mut b = Vec::new();
                for j in range {
                    let flag = seen.get_mut(j).ok_or(format!("leaf of node {node} points past the splats"))?;
                    if std::mem::replace(flag, true) {
                        return Err(format!("splat {j} is in two leaves"));
                    }
                    b.push(bvh.splats[j].bounds());
                }
                b
            } else {
                walk(bvh, n.child[i] as usize, seen)?
            };
            if let Some(bad) = below.iter().find(|b| !boxed.contains_box(b)) {
                return Err(format!("node {node} child {i}: {boxed:?} does not contain {bad:?}"));
            }
            all.extend(below);
        }
        Ok(all)
    }
    if bvh.nodes.is_empty() {
        return Err("no root node".into());
    }
    let mut seen = vec![false; bvh.splats.len()];
    walk(bvh, 0, &mut seen)?;
    match seen.iter().position(|s| !s) {
        Some(j) => Err(format!("splat {j} is in no leaf")),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_is_one_cache_line() {
        assert_eq!(size_of::<Node>(), 64);
    }
}
