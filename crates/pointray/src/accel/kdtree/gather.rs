//! The footprint prefilter's walk through the kd-tree (`splat::footprint`), as the BVH's
//! (`bvh::gather`): a beam through the cells, nearer child first, handing the visitor each
//! representative of a cell narrower than the threshold and each disk of the leaves it
//! reaches, until the visitor's layers are opaque.
//!
//! A cell does not bound its disks, and a disk straddling cells is referenced by each, so a
//! cell stands for the disks *centred* in it (half-open cells, as `for_each_near` takes them):
//! a leaf hands over only those, each disk once, and a representative stands for the area of
//! those below it ([`GatherData`]). The beam enters a cell where it passes within the sphere
//! about those disks' centres grown by the widest, so that none of them can reach into the
//! beam from a cell it misses.

use arrayvec::ArrayVec;
use glam::Vec3;

use super::build::MAX_DEPTH;
use super::{KdTree, with};
use crate::accel::TraversalStats;
use crate::accel::representative::Moments;
use crate::math::Aabb;
use crate::splat::footprint::{Aggregate, Beam, FootprintVisitor};

/// What the gather needs beyond the tree, found when the prefilter first asks, per node: the
/// aggregate of the disks centred in its cell (leaves: unused), the bounds of their centres
/// (a cell may hold much empty space, or be a slab that is never narrow) and the widest of
/// them.
pub(super) struct GatherData {
    aggregates: Vec<Aggregate>,
    centres: Vec<Aabb>,
    widest: Vec<f32>,
}

impl GatherData {
    /// One pass up the tree: a leaf's disks' moments, merged into their ancestors'.
    pub(super) fn of(tree: &KdTree) -> Self {
        let n = tree.nodes.len();
        let aggregates = vec![Aggregate { area_radius: 0.0, agreement: 1.0, disk: false }; n];
        let mut data = Self { aggregates, centres: vec![Aabb::EMPTY; n], widest: vec![0.0; n] };
        if n > 0 {
            data.moments(tree, 0, tree.bounds);
        }
        data
    }

    /// The moments of the disks centred in node `k`'s `cell`, its data stored on the way.
    fn moments(&mut self, tree: &KdTree, k: usize, cell: Aabb) -> Moments {
        let n = tree.nodes[k];
        if n.is_leaf() {
            let refs = &tree.refs[n.padded_refs()][..n.ref_count()];
            let owned = || refs.iter().map(|&r| &tree.disks[r as usize]).filter(|s| tree.owns(&cell, s.center));
            self.centres[k] = Aabb::from_points(owned().map(|s| s.center));
            self.widest[k] = owned().fold(0.0, |w, s| w.max(s.radius));
            return Moments::of(owned());
        }
        let (below, above) = children(n.axis(), n.split(), cell);
        let mut m = self.moments(tree, k + 1, below);
        m.merge(&self.moments(tree, n.above(), above));
        self.aggregates[k] = m.aggregate();
        self.centres[k] = self.centres[k + 1].union(self.centres[n.above()]);
        self.widest[k] = self.widest[k + 1].max(self.widest[n.above()]);
        m
    }
}

/// The cells below and above `split` along `axis`.
fn children(axis: usize, split: f32, cell: Aabb) -> (Aabb, Aabb) {
    (Aabb { max: with(cell.max, axis, split), ..cell }, Aabb { min: with(cell.min, axis, split), ..cell })
}

pub(super) fn gather<V: FootprintVisitor>(
    tree: &KdTree,
    beam: &Beam,
    tau: f32,
    visitor: &mut V,
    stats: &mut TraversalStats,
) {
    if tree.nodes.is_empty() {
        return;
    }
    let data = tree.gather_data();
    // Depth first, a level pushing two and popping one: the stack holds at most one cell a
    // level besides the current one.
    let mut stack = ArrayVec::<(u32, Aabb), { MAX_DEPTH + 2 }>::new();
    stack.push((0, tree.bounds));
    while let Some((k, cell)) = stack.pop() {
        let (k, centres) = (k as usize, &data.centres[k as usize]);
        if centres.is_empty() {
            continue;
        }
        let radius = 0.5 * centres.extent().length();
        let Some(tc) = enters(beam, centres.center(), radius + data.widest[k], visitor.t_cut()) else { continue };
        let n = tree.nodes[k];
        if n.is_leaf() {
            for &r in &tree.refs[n.padded_refs()][..n.ref_count()] {
                let s = tree.disks[r as usize];
                if tree.owns(&cell, s.center) {
                    stats.splat_tests += 1;
                    visitor.add(r, &s, Aggregate::disk(s.radius));
                }
            }
            continue;
        }
        stats.nodes_visited += 1;
        // Narrow where the sphere about its disks' centres is within τ beam radii (as wide as a
        // BVH's child, whose sphere bounds its disks, with their radius: a kd-tree's leaves
        // hold two disks, and a cut counting their radii opened them one by one).
        if radius < tau * beam.radius(tc) {
            stats.lod_stops += 1;
            visitor.add(tree.padding() + k as u32, &tree.reps[k], data.aggregates[k]);
            continue;
        }
        let (axis, split) = (n.axis(), n.split());
        let (below, above) = children(axis, split, cell);
        let (below, above) = ((k as u32 + 1, below), (n.above() as u32, above));
        // The nearer side last, so that it comes off the stack first.
        let (near, far) = if beam.origin[axis] < split { (below, above) } else { (above, below) };
        stack.push(far);
        stack.push(near);
    }
}

/// Where along the beam a sphere about `center` of radius `radius` lies, if the beam enters
/// it between its start and `t_cut`.
#[inline(always)]
fn enters(beam: &Beam, center: Vec3, radius: f32, t_cut: f32) -> Option<f32> {
    let oc = center - beam.origin;
    let tc = oc.dot(beam.dir);
    let off2 = (oc - tc * beam.dir).length_squared();
    let reach = radius + beam.radius(tc + radius);
    (tc + radius >= beam.t_min && tc - radius <= t_cut.min(beam.t_max) && off2 <= reach * reach).then_some(tc)
}
