//! Acceleration structures over splats, behind one interface.
//!
//! An accelerator knows the geometry of the disks but not how they become a surface: it walks
//! the ray front to back and hands every splat whose bounds the ray may cross to a
//! [`SplatVisitor`] (the surface scheme of `splat::scheme`), which decides what a hit is and how
//! far the walk must still go (`t_max`). The same walk serves closest-hit, the SJ window and
//! shadow rays. Level of detail will hook in here: rays already carry their footprint
//! (`Ray::cone`), and a multiresolution accelerator will hand the visitor a node's
//! representative splat instead of descending when the node is smaller than the footprint.
//!
//! * [`BruteForce`]: every splat, every ray — the test oracle.
//! * [`Bvh`]: binned-SAH bounding volume hierarchy.

mod brute;
pub mod bvh;

pub use brute::BruteForce;
pub use bvh::{Bvh, BvhParams};

use crate::math::{Aabb, Ray};
use crate::splat::Splat;

/// Receives the splats an accelerator finds along a ray.
pub trait SplatVisitor {
    /// Nodes and splats beyond this ray parameter cannot matter any more.
    fn t_max(&self) -> f32;
    /// Tests one splat (`index` is its position in [`Accel::splats`]).
    fn visit(&mut self, ray: &Ray, splat: &Splat, index: u32);
    /// True once the answer is known (any-hit queries stop early).
    fn done(&self) -> bool {
        false
    }
}

/// Work counters of traversals; summed over rays and threads (integers, so the sums do not
/// depend on the thread count).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TraversalStats {
    /// Nodes whose bounds were tested.
    pub nodes_visited: u64,
    /// Ray–disk tests: splats handed to the visitor (brute force), or splats in the packets
    /// the BVH tested with its SIMD pre-filter.
    pub splat_tests: u64,
}

impl std::ops::AddAssign for TraversalStats {
    fn add_assign(&mut self, o: Self) {
        self.nodes_visited += o.nodes_visited;
        self.splat_tests += o.splat_tests;
    }
}

/// An acceleration structure over splats. It owns its splats, in whatever order suits it.
pub trait Accel: Send + Sync {
    fn name(&self) -> &'static str;
    fn splats(&self) -> &[Splat];
    /// Bounds of all the disks.
    fn bounds(&self) -> Aabb;
    /// Bytes of the structure itself, excluding the splats.
    fn memory_bytes(&self) -> usize;
    /// Hands the visitor every splat the ray may cross in `[ray.t_min, visitor.t_max()]`,
    /// roughly front to back, until the visitor is `done`.
    fn traverse<V: SplatVisitor>(&self, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats);
}
