//! Acceleration structures over splats, behind one interface.
//!
//! An accelerator knows the geometry of the disks but not how they become a surface: it walks
//! the ray front to back, tests the disks it meets exactly (as the visitor's [`DiskShape`]),
//! and hands every crossing to a [`SplatVisitor`] (the surface scheme of `splat::scheme`),
//! which decides what a hit is and how far the walk must still go (`t_max`). The same walk serves closest-hit, the SJ window and
//! shadow rays. Level of detail hooks in here too: rays carry their footprint (`Ray::cone`) and
//! a threshold, and a multiresolution accelerator hands the visitor a node's representative
//! splat instead of descending when the node is smaller than the footprint.
//!
//! * [`BruteForce`]: every splat, every ray — the test oracle (no level of detail).
//! * [`Bvh`]: binned-SAH bounding volume hierarchy with level of detail, bounding spheres and
//!   normal cones in its nodes (thesis ch. 3).
//! * [`KdTree`]: binned-SAH kd-tree with level of detail in its inner nodes (thesis ch. 4).

pub(crate) mod block;
mod brute;
pub mod bvh;
pub mod isa;
pub mod kdtree;
mod packet;
mod representative;
pub mod stored;

pub use brute::BruteForce;
pub use bvh::{Bvh, BvhParams, NodeBounds};
pub use kdtree::{KdTree, KdTreeParams};

use crate::math::{Aabb, Ray, RayCone};
use crate::splat::oriented_disk::DiskHit;
use crate::splat::{DiskShape, Splat};
use glam::Vec3;

/// A ray's crossing of one disk, as an accelerator hands it to a visitor: where (`t`, and
/// `dist2`, the squared distance from the disk's centre, as `splat::oriented_disk::intersect`
/// or `ray_facing_disk` finds them), which disk (`splat`, what [`Accel::splat`] takes), and what
/// the SJ window blends of it: radius, normal and colour, handed over from the leaf block the
/// test just read (32 bytes, one AVX move when the window shifts it). Fetched again at the
/// blend through the splat's index, they cost 16 instructions a crossing to decode the index
/// alone (callgrind on the dragon, SJ: 1,113 → 1,092 instructions a pixel with them here).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    pub t: f32,
    pub dist2: f32,
    pub splat: u32,
    pub radius: f32,
    pub normal: Vec3,
    /// Packed as in [`Splat::color`] (material in the top byte).
    pub color: u32,
}

impl Crossing {
    #[inline(always)]
    pub fn new(splat: u32, disk: &Splat, hit: DiskHit) -> Self {
        Self { t: hit.t, dist2: hit.dist2, splat, radius: disk.radius, normal: disk.normal, color: disk.color }
    }

    /// The crossed disk's material (the colour's top byte, as [`Splat::material`]).
    #[inline(always)]
    pub fn material(&self) -> u8 {
        crate::splat::material_of(self.color)
    }
}

/// Receives the crossings an accelerator finds along a ray.
pub trait SplatVisitor {
    /// Nodes and splats beyond this ray parameter cannot matter any more.
    fn t_max(&self) -> f32;
    /// The ray crosses a disk within `[ray.t_min, self.t_max()]`, found by the exact test of
    /// `SHAPE`. An accelerator whose `REPEATS_SPLATS` is true may hand the same splat over more
    /// than once; a visitor used with it must then change nothing on the second visit.
    fn hit(&mut self, ray: &Ray, crossing: Crossing);
    /// True once the answer is known (any-hit queries stop early).
    fn done(&self) -> bool {
        false
    }
    /// The disks the accelerator tests for this visitor; its bounds must hold them
    /// (`Accel::shape`).
    const SHAPE: DiskShape = DiskShape::Oriented;
}

/// Tests one disk exactly, as `V::SHAPE`, against the visitor's current `t_max`, and hands a
/// crossing over: the scalar path (brute force, the kd-tree, representatives).
#[inline(always)]
pub(crate) fn test_disk<V: SplatVisitor>(ray: &Ray, splat: &Splat, index: u32, visitor: &mut V) {
    if let Some(h) = V::SHAPE.intersect(ray, splat, visitor.t_max()) {
        visitor.hit(ray, Crossing::new(index, splat, h));
    }
}

/// Work counters of traversals; summed over rays and threads (integers, so the sums do not
/// depend on the thread count).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TraversalStats {
    /// Nodes whose children's bounds were tested.
    pub nodes_visited: u64,
    /// Child bounding boxes tested (slab tests).
    pub box_tests: u64,
    /// Child bounding spheres tested.
    pub sphere_tests: u64,
    /// Ray–disk tests: every disk tested (brute force), the disks of the blocks the BVH tested
    /// eight at a time, or of the packets the kd-tree pre-filtered; representatives included.
    pub splat_tests: u64,
    /// Subtrees replaced by their representative splat (level of detail).
    pub lod_stops: u64,
    /// Subtrees skipped because all their disks face away from the ray's origin.
    pub culled: u64,
    /// Point-set surface projection steps (`splat::pss`), each a radius query.
    pub pss_steps: u64,
    /// Point-set surface hits that fell back to the seed (no convergence).
    pub pss_fallbacks: u64,
    /// Made by [`TraversalStats::uncounted`].
    #[serde(skip)]
    uncounted: bool,
}

impl TraversalStats {
    /// Counters the BVH leaves at zero: it then runs a traversal compiled without counting,
    /// for frames whose statistics nobody reads (benchmark frames). On the dragon, first hit:
    /// 811 → 786 instructions a pixel and 2–5 % more rays a second (alternating runs).
    pub fn uncounted() -> Self {
        Self { uncounted: true, ..Self::default() }
    }

    /// Whether traversals count into these.
    pub fn counting(&self) -> bool {
        !self.uncounted
    }
}

impl std::ops::AddAssign for TraversalStats {
    fn add_assign(&mut self, o: Self) {
        self.nodes_visited += o.nodes_visited;
        self.box_tests += o.box_tests;
        self.sphere_tests += o.sphere_tests;
        self.splat_tests += o.splat_tests;
        self.lod_stops += o.lod_stops;
        self.culled += o.culled;
        self.pss_steps += o.pss_steps;
        self.pss_fallbacks += o.pss_fallbacks;
    }
}

/// An acceleration structure over splats. It owns its splats, in whatever order suits it.
pub trait Accel: Send + Sync {
    /// Whether `traverse` may hand a visitor the same splat more than once (a kd-tree does,
    /// once per cell a disk straddles). Visitors that would count a splat twice look for
    /// repeats only then, so the others pay nothing for it.
    const REPEATS_SPLATS: bool = false;

    fn name(&self) -> &'static str;
    /// The splat a visitor was handed as index `index`: an input splat or a level-of-detail
    /// representative. Indices are the accelerator's own (it may store its splats in any
    /// order, with gaps); a copy, not a reference, so that it may store them in any form.
    /// Every accelerator holds its input splats snapped as the BVH's compact blocks store them
    /// (centres moved by at most a 2,048th of their radius, normals by 2⁻¹⁵ a component;
    /// `block::snap`), so that all find the same hits.
    fn splat(&self, index: u32) -> Splat;
    /// Whether `index` is a level-of-detail representative rather than an input splat.
    fn is_representative(&self, index: u32) -> bool;
    /// How many input splats the accelerator holds.
    fn splat_count(&self) -> usize;
    /// Bounds of all the disks.
    fn bounds(&self) -> Aabb;
    /// The 99th percentile of the input splats' radii: how wide a disk a search that starts
    /// from one crossing plans for. The SJ window collects this many window widths past its
    /// first crossing, so that a nearer, wider first crossing found later seldom needs a
    /// second walk; the few wider disks beyond it (stray points) cannot make every ray's
    /// walk longer.
    fn wide_radius(&self) -> f32;
    /// How many disks cover a point of the surface, on average (≥ 1): what turns the disks'
    /// summed area into the area they cover, for the footprint prefilter.
    fn coverage_density(&self) -> f32;
    /// Hands `visitor` every disk, or representative of disks narrower than `tau` times the
    /// beam's radius, that `beam` may overlap before `visitor.t_cut()`, nearest subtrees
    /// first (`splat::footprint`).
    fn gather<V: crate::splat::footprint::FootprintVisitor>(
        &self,
        beam: &crate::splat::footprint::Beam,
        tau: f32,
        visitor: &mut V,
        stats: &mut TraversalStats,
    );
    /// Whether `traverse` may hand this ray level-of-detail representatives. A representative
    /// may reach outside its subtree's bounds, so a walk that starts past `t_min` can miss one
    /// that crosses the ray later; the SJ window's completing walk asks.
    fn may_stop_at_representatives(&self, ray: &Ray) -> bool;
    /// The footprint, scaled by τ, that a ray must grow wider than before it leaves the model
    /// for `traverse` to hand it a representative (∞ without level of detail).
    fn lod_floor(&self) -> f32;
    /// Whether any ray from `origin` with a footprint no wider than `cone`'s, at threshold
    /// `tau`, may be handed a representative: [`Self::may_stop_at_representatives`] for all of
    /// them at once. A ray leaves the model's box no farther than its farthest corner, where
    /// the footprint is widest, so false means that each such ray takes full detail anyway;
    /// a renderer then gives its camera rays τ = 0, the same hits without the per-ray test
    /// (the dragon close up at τ = 1, first hits: 722 → 709 instructions a pixel, callgrind).
    fn may_stop_at_representatives_from(&self, origin: Vec3, cone: RayCone, tau: f32) -> bool {
        let b = self.bounds();
        if tau <= 0.0 || b.is_empty() {
            return false;
        }
        // An origin on a face's plane can give a ray parallel to it an exit of 0·∞ = NaN,
        // which the traversal takes for ∞.
        let on_plane = (0..3).any(|k| origin[k] == b.min[k] || origin[k] == b.max[k]);
        // A thousandth wider than the corner: rounding must not make a ray's exit the farther.
        let far = (b.min - origin).abs().max((b.max - origin).abs()).length() * (1.0 + 1.0 / 1024.0);
        on_plane || !far.is_finite() || tau * cone.width_at(far) > self.lod_floor()
    }
    /// The disks the bounds were built to hold: a visitor of another shape may miss hits
    /// unless it is held too ([`DiskShape::holds`]).
    fn shape(&self) -> DiskShape;
    /// Calls `f` with every input splat (its index, as [`Accel::splat`] takes it, and itself)
    /// whose centre lies within `radius` of `center`, once each, in no particular order (the
    /// point-set surface's neighbourhoods). Representatives are not included.
    fn for_each_near<F: FnMut(u32, Splat)>(&self, center: Vec3, radius: f32, stats: &mut TraversalStats, f: F);
    /// Bytes of the structure with its splats (and their representatives).
    fn memory_bytes(&self) -> usize;
    /// Hands the visitor every splat the ray may cross in `[ray.t_min, visitor.t_max()]`,
    /// roughly front to back, until the visitor is `done`.
    fn traverse<V: SplatVisitor>(&self, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats);
}

/// Cases for the tests of the lane kernels (`block`, `packet`).
#[cfg(test)]
pub(crate) mod lane_cases {
    use glam::Vec3;
    use rand::{RngExt, SeedableRng};

    use crate::math::{Ray, RayCone};
    use crate::splat::Splat;

    /// `rounds` sets of 1 to `max_lanes` random disks around the origin (round `i` has
    /// `1 + i % max_lanes`), each with a ray from around them, a `t_min` up to 0.5 and a
    /// `t_max` (∞ half the time).
    pub(crate) fn random_disks_and_rays(seed: u64, max_lanes: usize, rounds: usize) -> Vec<(Vec<Splat>, Ray, f32)> {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let mut v =
            |lo: f32, hi: f32| Vec3::new(rng.random_range(lo..hi), rng.random_range(lo..hi), rng.random_range(lo..hi));
        (0..rounds)
            .map(|round| {
                let splats = (0..1 + round % max_lanes)
                    .map(|_| Splat {
                        center: v(-1.0, 1.0),
                        radius: v(0.05, 1.0).x,
                        normal: v(-1.0, 1.0).normalize(),
                        color: 0,
                    })
                    .collect();
                let origin = v(-3.0, 3.0);
                let ray = Ray::new(origin, v(-1.0, 1.0) - origin, RayCone::default()).with_t_min(v(0.0, 0.5).x);
                let t_max = if v(0.0, 1.0).x < 0.5 { f32::INFINITY } else { v(0.5, 6.0).x };
                (splats, ray, t_max)
            })
            .collect()
    }
}
