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

use glam::{Vec3, Vec4};

use crate::math::Aabb;
use crate::splat::Splat;

/// A child reference is a node index, or for a leaf `LEAF | (count − 1) << FIRST_BITS | first`:
/// one word on the traversal stack says everything about a child.
const LEAF: u32 = 1 << 31;
const FIRST_BITS: u32 = 27;
/// Most splats a leaf can hold (its count takes the 4 bits between `LEAF` and the index).
pub(crate) const MAX_LEAF_SIZE: usize = 16;
/// Most splats a BVH can index (2²⁷ ≈ 134 million).
pub const MAX_SPLATS: usize = 1 << FIRST_BITS;

fn leaf_ref(first: usize, count: usize) -> u32 {
    debug_assert!((1..=MAX_LEAF_SIZE).contains(&count) && first < MAX_SPLATS);
    LEAF | ((count - 1) as u32) << FIRST_BITS | first as u32
}

/// The splat range of a leaf reference.
#[inline(always)]
fn leaf_range(child: u32) -> std::ops::Range<usize> {
    let first = (child & ((1 << FIRST_BITS) - 1)) as usize;
    let count = ((child & !LEAF) >> FIRST_BITS) as usize + 1;
    first..first + count
}

/// The deepest a build may go: traversal stacks are sized from it.
pub(crate) const MAX_DEPTH: usize = 96;

/// An inner node: the bounds of its two children and how to reach them.
///
/// Per axis one `Vec4` holds `[lo₀, lo₁, hi₀, hi₁]` (child 0 and 1), so that one SSE
/// subtract and multiply per axis give the slab distances of both children at once.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Node {
    pub(crate) bounds: [Vec4; 3],
    /// Inner child: its node index. Leaf child: see [`leaf_ref`].
    pub(crate) child: [u32; 2],
}

impl Node {
    pub(crate) fn new(b: [Aabb; 2]) -> Self {
        let axis = |k: usize| Vec4::new(b[0].min[k], b[1].min[k], b[0].max[k], b[1].max[k]);
        Self { bounds: [axis(0), axis(1), axis(2)], child: [0; 2] }
    }

    pub(crate) fn child_bounds(&self, i: usize) -> Aabb {
        let [x, y, z] = self.bounds;
        Aabb::new(Vec3::new(x[i], y[i], z[i]), Vec3::new(x[i + 2], y[i + 2], z[i + 2]))
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

    fn traverse<V: super::SplatVisitor>(
        &self,
        ray: &crate::math::Ray,
        visitor: &mut V,
        stats: &mut super::TraversalStats,
    ) {
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
                let range = if boxed.is_empty() { 0..0 } else { leaf_range(n.child[i]) };
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
        return if bvh.splats.is_empty() { Ok(()) } else { Err("splats but no root node".into()) };
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
