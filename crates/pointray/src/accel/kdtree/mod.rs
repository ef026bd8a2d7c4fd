//! Kd-tree over splats, built by the surface area heuristic (thesis ch. 4, RECONSTRUCTION A8).
//!
//! Unlike a BVH, a kd-tree partitions space: each inner node splits its cell by one
//! axis-aligned plane, and a splat whose (tight, padded) box straddles the plane is referenced
//! on both sides. A leaf lists the splats whose boxes overlap its cell, so a ray walking the
//! leaves it crosses, front to back, meets every disk it hits in the leaf that holds the hit
//! point, and may stop as soon as the next cell starts beyond the visitor's `t_max`. A splat
//! straddling several cells can be handed to the visitor more than once (`REPEATS_SPLATS`).
//!
//! Level of detail: every inner node carries a representative splat of the disks that reach
//! into its cell (`accel::representative`, as for the BVH's nodes); a ray whose footprint,
//! scaled by the threshold, is wider than the representative's own radius (a cell does not
//! bound its disks) tests it instead of descending, the BVH's rule. The footprint prefilter's
//! beams walk it too (`gather.rs`), with what they need found when first asked.

mod build;
mod gather;
mod traverse;

pub use build::{KdTreeParams, MAX_BINS};

use crate::accel::packet::LANES;
use crate::accel::{Accel, SplatVisitor, TraversalStats};
use crate::math::{Aabb, Ray};
use crate::splat::footprint::{Beam, FootprintVisitor, coverage_density, density_stride};
use crate::splat::{DiskShape, Splat};
use glam::Vec3;

/// A node in 8 bytes (as in pbrt): an inner node holds its split position and, in `bits`, the
/// axis (0–2) and the index of the child above the plane (the child below follows the node);
/// a leaf has axis field 3, its reference count in the rest of `bits`, and in `data` the index
/// of its first reference. A leaf's references are padded to whole packets of [`LANES`].
#[derive(Clone, Copy, Debug)]
struct KdNode {
    data: u32,
    bits: u32,
}

const LEAF_AXIS: u32 = 3;

impl KdNode {
    fn inner(axis: usize, split: f32, above: usize) -> Self {
        debug_assert!(axis < 3 && above < (1 << 30));
        Self { data: split.to_bits(), bits: axis as u32 | (above as u32) << 2 }
    }

    fn leaf(first: usize, count: usize) -> Self {
        debug_assert!(count < (1 << 30) && first <= u32::MAX as usize);
        Self { data: first as u32, bits: LEAF_AXIS | (count as u32) << 2 }
    }

    #[inline(always)]
    fn axis(self) -> usize {
        (self.bits & 3) as usize
    }

    #[inline(always)]
    fn is_leaf(self) -> bool {
        self.bits & 3 == LEAF_AXIS
    }

    #[inline(always)]
    fn split(self) -> f32 {
        f32::from_bits(self.data)
    }

    #[inline(always)]
    fn above(self) -> usize {
        (self.bits >> 2) as usize
    }

    /// References in the leaf, not counting the padding.
    #[inline(always)]
    fn ref_count(self) -> usize {
        (self.bits >> 2) as usize
    }

    /// The leaf's references with their padding.
    #[inline(always)]
    fn padded_refs(self) -> std::ops::Range<usize> {
        self.data as usize..self.data as usize + self.ref_count().next_multiple_of(LANES)
    }
}

/// The kd-tree and the splats it references (in input order: a kd-tree needs no reordering).
pub struct KdTree {
    nodes: Vec<KdNode>,
    /// The leaves' splat indices, each leaf a contiguous run padded with [`KdTree::padding`]
    /// to whole packets: the traversal gathers four at a time without checking how many remain.
    refs: Vec<u32>,
    /// The splats, then at index [`KdTree::padding`] a disk no ray hits (`packet::NO_DISK`).
    disks: Vec<Splat>,
    /// Per node, its representative (radius 0 for leaves);
    /// the visitor knows node k's as splat `padding() + k`.
    reps: Vec<Splat>,
    /// A small quantile of the representatives' radii (see `representative::radius_quantile`).
    lod_floor: f32,
    /// See [`Accel::wide_radius`].
    wide_radius: f32,
    /// The root cell: the union of the splats' padded boxes.
    bounds: Aabb,
    depth: usize,
    /// The disks the cells hold.
    shape: DiskShape,
    /// See [`Accel::coverage_density`]; found when first asked, as the prefilter's other
    /// needs ([`gather::GatherData`]), which renders without it never pay for.
    coverage_density: std::sync::OnceLock<f32>,
    gather_data: std::sync::OnceLock<gather::GatherData>,
}

impl KdTree {
    /// Bytes per node: the node and its representative.
    pub const NODE_BYTES: usize = size_of::<KdNode>() + size_of::<Splat>();

    /// The index that pads the leaves: a disk no ray hits.
    fn padding(&self) -> u32 {
        (self.disks.len() - 1) as u32
    }

    /// The input splats, in input order.
    pub fn splats(&self) -> &[Splat] {
        &self.disks[..self.padding() as usize]
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Splat references in the leaves (at least the number of splats: straddlers count once
    /// per leaf; padding does not count).
    pub fn reference_count(&self) -> usize {
        self.nodes.iter().filter(|n| n.is_leaf()).map(|n| n.ref_count()).sum()
    }

    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Whether `cell` holds the point `p`: cells are half-open, [min, max) (a centre on a plane
    /// belongs above it, and the build references it there), except at the root's far faces,
    /// so that each centre lies in one leaf's cell.
    fn owns(&self, cell: &Aabb, p: Vec3) -> bool {
        (0..3).all(|a| p[a] >= cell.min[a] && (p[a] < cell.max[a] || cell.max[a] == self.bounds.max[a]))
    }

    fn gather_data(&self) -> &gather::GatherData {
        self.gather_data.get_or_init(|| gather::GatherData::of(self))
    }
}

impl Accel for KdTree {
    const REPEATS_SPLATS: bool = true;

    fn name(&self) -> &'static str {
        "kdtree"
    }

    fn splat(&self, index: u32) -> Splat {
        let (i, n) = (index as usize, self.padding() as usize);
        if i < n { self.disks[i] } else { self.reps[i - n] }
    }

    fn is_representative(&self, index: u32) -> bool {
        index >= self.padding()
    }

    fn splat_count(&self) -> usize {
        self.splats().len()
    }

    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn wide_radius(&self) -> f32 {
        self.wide_radius
    }

    fn may_stop_at_representatives(&self, ray: &Ray) -> bool {
        traverse::multires_reach(self, ray).is_some()
    }

    fn lod_floor(&self) -> f32 {
        self.lod_floor
    }

    fn shape(&self) -> DiskShape {
        self.shape
    }

    fn for_each_near<F: FnMut(u32, Splat)>(&self, center: Vec3, radius: f32, stats: &mut TraversalStats, mut f: F) {
        if self.nodes.is_empty() {
            return;
        }
        let r2 = radius * radius;
        // A splat straddling cells is listed in each; it is reported from the one cell that
        // holds its centre.
        let mut stack = vec![(0usize, self.bounds)];
        while let Some((k, cell)) = stack.pop() {
            let n = self.nodes[k];
            if n.is_leaf() {
                for &r in &self.refs[n.padded_refs()][..n.ref_count()] {
                    let s = self.disks[r as usize];
                    stats.splat_tests += 1;
                    if (s.center - center).length_squared() <= r2 && self.owns(&cell, s.center) {
                        f(r, s);
                    }
                }
                continue;
            }
            stats.nodes_visited += 1;
            let (a, split) = (n.axis(), n.split());
            // Pruned with a little more than the radius: the distance test is rounded
            // differently, and a splat at the edge must not fall in a pruned cell.
            let reach = radius * (1.0 + 1e-5) + center[a].abs() * f32::EPSILON;
            if center[a] - reach <= split {
                stack.push((k + 1, Aabb { max: with(cell.max, a, split), ..cell }));
            }
            if center[a] + reach >= split {
                stack.push((n.above(), Aabb { min: with(cell.min, a, split), ..cell }));
            }
        }
    }

    fn coverage_density(&self) -> f32 {
        *self.coverage_density.get_or_init(|| {
            coverage_density(self, self.splats().iter().copied().step_by(density_stride(self.splat_count())))
        })
    }

    fn gather<V: FootprintVisitor>(&self, beam: &Beam, tau: f32, visitor: &mut V, stats: &mut TraversalStats) {
        gather::gather(self, beam, tau, visitor, stats);
    }

    fn memory_bytes(&self) -> usize {
        self.nodes.len() * Self::NODE_BYTES + self.refs.len() * size_of::<u32>() + self.disks.len() * size_of::<Splat>()
    }

    fn traverse<V: SplatVisitor>(&self, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
        traverse::traverse(self, ray, visitor, stats);
    }
}

/// Checks the kd-tree's invariants: every leaf whose cell a splat's padded box reaches into
/// (by the build's rule, `build::sides`) references that splat, so no ray can miss it there,
/// and every split lies in its cell.
pub fn check_invariants(tree: &KdTree) -> Result<(), String> {
    if tree.nodes.is_empty() {
        return if tree.splats().is_empty() { Ok(()) } else { Err("no nodes for a non-empty tree".into()) };
    }
    for (i, s) in tree.splats().iter().enumerate() {
        let b = build::padded_bounds(s, tree.shape);
        let mut cells = vec![(0usize, tree.bounds)];
        while let Some((k, cell)) = cells.pop() {
            let n = tree.nodes[k];
            if n.is_leaf() {
                if !tree.refs[n.padded_refs()][..n.ref_count()].contains(&(i as u32)) {
                    return Err(format!("leaf {k} {cell:?}: splat {i} {b:?} touches it but is not referenced"));
                }
                continue;
            }
            let (a, split) = (n.axis(), n.split());
            if !(cell.min[a] <= split && split <= cell.max[a]) {
                return Err(format!("node {k}: split {split} on axis {a} outside its cell {cell:?}"));
            }
            let (below, above) = build::sides(&b, a, split);
            if below {
                cells.push((k + 1, Aabb { max: with(cell.max, a, split), ..cell }));
            }
            if above {
                cells.push((n.above(), Aabb { min: with(cell.min, a, split), ..cell }));
            }
        }
    }
    Ok(())
}

/// `v` with component `axis` set to `x`.
fn with(mut v: glam::Vec3, axis: usize, x: f32) -> glam::Vec3 {
    v[axis] = x;
    v
}
