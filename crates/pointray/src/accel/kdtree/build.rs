//! Binned SAH kd-tree build. At each node the splats' boxes (clipped to the cell) are binned
//! by their minimum and maximum along each axis; the bin boundaries, and the planes that cut
//! the empty space off the cell, are priced by the surface area heuristic, with a bonus for
//! cutting off empty space. Children are built in parallel.

use glam::{Vec3, Vec3A};
use rayon::join;
use rayon::prelude::*;

use super::{KdNode, KdTree};
use crate::accel::packet::{LANES, NO_DISK};
use crate::accel::representative::{LOD_FLOOR_QUANTILE, radius_quantile, representative, wide_radius};
use crate::math::Aabb;
use crate::splat::{DiskShape, Splat};

/// Build parameters, with named presets.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct KdTreeParams {
    /// Bins per axis, 2 to [`MAX_BINS`] (candidate planes: the bin boundaries).
    pub bins: usize,
    /// SAH cost of one traversal step, relative to `intersection_cost`.
    pub traversal_cost: f32,
    /// SAH cost of one ray–disk test.
    pub intersection_cost: f32,
    /// Fraction of the cost forgiven to a split that leaves one side empty (0–1).
    pub empty_bonus: f32,
    /// A node with at most this many references is a leaf.
    pub max_leaf_size: usize,
    /// Deepest level; `None`: 8 + 1.3·log₂ n (pbrt's rule).
    pub max_depth: Option<usize>,
    /// The disks the cells must hold: ray-facing disks need the splats' balls.
    pub shape: DiskShape,
}

/// Hard limit on the depth, which the traversal stack is sized for.
pub(super) const MAX_DEPTH: usize = 64;

/// Most bins per axis (the counters live on the stack).
pub const MAX_BINS: usize = 64;

/// Below this many references a node's children are built on the current thread.
const PARALLEL_MIN: usize = 4096;

impl KdTreeParams {
    /// The default.
    pub fn standard() -> Self {
        Self {
            bins: 32,
            traversal_cost: 1.0,
            // Disks are tested four at a time: one costs about half a traversal step. The same
            // instructions per camera ray as 1.5 (dragon, callgrind), a quarter less memory on
            // the dragon and half on the 1M torus, a quicker build; 10 % more disk tests for
            // random rays through a sphere (docs/kdtree.md).
            intersection_cost: 0.5,
            empty_bonus: 0.5,
            max_leaf_size: 2,
            max_depth: None,
            shape: DiskShape::Oriented,
        }
    }

    /// Quicker build: fewer candidate planes.
    pub fn fast() -> Self {
        Self { bins: 8, ..Self::standard() }
    }

    /// A shallow tree with large leaves (depth at most 6): tests that big leaves and many
    /// straddling references are handled.
    pub fn shallow() -> Self {
        Self { max_depth: Some(6), ..Self::standard() }
    }

    /// Every preset, for tests and benchmarks.
    pub fn presets() -> [(&'static str, KdTreeParams); 3] {
        [("standard", Self::standard()), ("fast", Self::fast()), ("shallow", Self::shallow())]
    }
}

/// A splat's box, padded by a few ulps of its coordinates and a little of its radius: the
/// rounding of the tight box must not leave out a point the disk test accepts.
pub(super) fn padded_bounds(s: &Splat, shape: DiskShape) -> Aabb {
    let b = s.bounds_as(shape);
    let pad = b.min.abs().max(b.max.abs()) * (8.0 * f32::EPSILON) + Vec3::splat(s.radius * 1e-4);
    Aabb::new(b.min - pad, b.max + pad)
}

/// On which sides of the plane `split` along `axis` a box is referenced: below if it reaches
/// below the plane, above if it reaches above, both if it lies in the plane. Half-open, so
/// that a plane through the content's boundary cuts off an empty cell.
#[inline]
pub(super) fn sides(b: &Aabb, axis: usize, split: f32) -> (bool, bool) {
    (b.min[axis] < split || b.max[axis] <= split, b.max[axis] > split || b.min[axis] >= split)
}

enum BuildNode {
    Leaf(Vec<u32>),
    Inner { axis: usize, split: f32, rep: Splat, children: Box<[BuildNode; 2]> },
}

impl KdTree {
    pub fn build(mut splats: Vec<Splat>, params: &KdTreeParams) -> Self {
        // As every accelerator stores them, so that all find the same hits.
        crate::accel::block::snap(&mut splats);
        assert!((2..=MAX_BINS).contains(&params.bins), "the build needs 2 to {MAX_BINS} bins");
        assert!(splats.len() <= u32::MAX as usize, "too many splats for a kd-tree");
        let boxes: Vec<Aabb> = splats.par_iter().map(|s| padded_bounds(s, params.shape)).collect();
        let bounds = boxes.iter().fold(Aabb::EMPTY, |b, s| b.union(*s));
        let with_padding = |mut splats: Vec<Splat>| {
            splats.push(NO_DISK);
            splats
        };
        if splats.is_empty() {
            let (nodes, refs, reps, disks) = (Vec::new(), Vec::new(), Vec::new(), with_padding(splats));
            let (lod_floor, wide_radius) = (f32::INFINITY, f32::INFINITY);
            let shape = params.shape;
            let (coverage_density, gather_data) = Default::default();
            return Self {
                nodes,
                refs,
                disks,
                reps,
                lod_floor,
                wide_radius,
                bounds,
                depth: 0,
                shape,
                coverage_density,
                gather_data,
            };
        }
        let n = splats.len();
        let max_depth =
            params.max_depth.unwrap_or_else(|| (8.0 + 1.3 * (n as f64).log2()).round() as usize).min(MAX_DEPTH);
        let input = Input { splats: &splats, boxes: &boxes, max_depth, params };
        let root = build_node(&input, bounds, (0..n as u32).collect(), 0);
        let (mut nodes, mut refs, mut reps) = (Vec::new(), Vec::new(), Vec::new());
        let depth = flatten(root, n as u32, &mut nodes, &mut refs, &mut reps);
        // Leaves index their references with u32 (padding included).
        assert!(refs.len() <= u32::MAX as usize, "too many splat references for a kd-tree");
        // The visitor knows representatives by index after the splats.
        assert!(n + nodes.len() <= u32::MAX as usize, "too many splats for a kd-tree");
        let radii = reps.iter().map(|r| r.radius).filter(|&r| r > 0.0).collect();
        let lod_floor = radius_quantile(radii, LOD_FLOOR_QUANTILE);
        let wide_radius = wide_radius(&splats);
        let disks = with_padding(splats);
        let (coverage_density, gather_data) = Default::default();
        let shape = params.shape;
        Self { nodes, refs, disks, reps, lod_floor, wide_radius, bounds, depth, shape, coverage_density, gather_data }
    }
}

/// Appends `node` depth first (the child below right after its parent), with its
/// representative (none for a leaf), and each leaf's references padded with `padding` to
/// whole packets; returns its depth.
fn flatten(
    node: BuildNode,
    padding: u32,
    nodes: &mut Vec<KdNode>,
    refs: &mut Vec<u32>,
    reps: &mut Vec<Splat>,
) -> usize {
    match node {
        BuildNode::Leaf(r) => {
            nodes.push(KdNode::leaf(refs.len(), r.len()));
            reps.push(NO_DISK);
            let end = refs.len() + r.len().next_multiple_of(LANES);
            refs.extend(r);
            refs.resize(end, padding);
            1
        }
        BuildNode::Inner { axis, split, rep, children } => {
            let k = nodes.len();
            nodes.push(KdNode::leaf(0, 0));
            reps.push(rep);
            let [below, above] = *children;
            let d_below = flatten(below, padding, nodes, refs, reps);
            nodes[k] = KdNode::inner(axis, split, nodes.len());
            let d_above = flatten(above, padding, nodes, refs, reps);
            1 + d_below.max(d_above)
        }
    }
}

/// What every node of the build reads.
struct Input<'a> {
    splats: &'a [Splat],
    boxes: &'a [Aabb],
    max_depth: usize,
    params: &'a KdTreeParams,
}

fn build_node(input: &Input, cell: Aabb, refs: Vec<u32>, depth: usize) -> BuildNode {
    let (boxes, p) = (input.boxes, input.params);
    let n = refs.len();
    if n <= p.max_leaf_size || depth >= input.max_depth {
        return BuildNode::Leaf(refs);
    }
    let Some((axis, split, cost)) = best_split(boxes, cell, &refs, p) else {
        return BuildNode::Leaf(refs);
    };
    if cost >= p.intersection_cost * n as f32 {
        return BuildNode::Leaf(refs);
    }
    let (mut below, mut above) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for &r in &refs {
        let (b, a) = sides(&boxes[r as usize], axis, split);
        if b {
            below.push(r);
        }
        if a {
            above.push(r);
        }
    }
    if below.len() == n && above.len() == n {
        return BuildNode::Leaf(refs); // the plane separates nothing
    }
    // The representative stands for every disk that reaches into the cell, not only those
    // centred in it: a cell does not bound its disks, and a surface crossing the cell may be
    // made of disks centred outside it.
    let rep = representative(refs.iter().map(|&r| &input.splats[r as usize])).splat;
    drop(refs);
    let mut cell_below = cell;
    cell_below.max[axis] = split;
    let mut cell_above = cell;
    cell_above.min[axis] = split;
    let go = |r, c| build_node(input, c, r, depth + 1);
    let children = if n >= PARALLEL_MIN {
        let (b, a) = join(|| go(below, cell_below), || go(above, cell_above));
        [b, a]
    } else {
        [go(below, cell_below), go(above, cell_above)]
    };
    BuildNode::Inner { axis, split, rep, children: Box::new(children) }
}

/// The cheapest plane by the SAH: (axis, position, cost); `None` when the cell is flat.
fn best_split(boxes: &[Aabb], cell: Aabb, refs: &[u32], p: &KdTreeParams) -> Option<(usize, f32, f32)> {
    let area = cell.half_area();
    if area.is_nan() || area <= 0.0 {
        return None;
    }
    // The content: the references' boxes clipped to the cell.
    let content = refs.iter().fold(Aabb::EMPTY, |b, &r| b.union(boxes[r as usize]));
    let lo = Vec3A::from(content.min.max(cell.min));
    let hi = Vec3A::from(content.max.min(cell.max));
    let n = refs.len() as f32;
    let extent = cell.extent();
    let price = |axis: usize, split: f32, below: f32, above: f32| {
        // Half the surface of a cell of depth d along `axis` is d·(u + v) + u·v.
        let (u, v) = (extent[(axis + 1) % 3], extent[(axis + 2) % 3]);
        let (area_below, area_above) =
            ((split - cell.min[axis]) * (u + v) + u * v, (cell.max[axis] - split) * (u + v) + u * v);
        let bonus = if below == 0.0 || above == 0.0 { p.empty_bonus } else { 0.0 };
        p.traversal_cost + p.intersection_cost * (1.0 - bonus) * (area_below * below + area_above * above) / area
    };
    let bins = p.bins;
    let mut best: Option<(usize, f32, f32)> = None;
    let mut consider = |axis: usize, split: f32, cost: f32| {
        if split > cell.min[axis] && split < cell.max[axis] && best.is_none_or(|b| cost < b.2) {
            best = Some((axis, split, cost));
        }
    };
    // One pass bins every axis at once: per box, the bins of its (clipped) start and end. On
    // an axis with no extent the bins are meaningless and unused.
    let (mut starts, mut ends) = ([[0u32; MAX_BINS]; 3], [[0u32; MAX_BINS]; 3]);
    let scale = Vec3A::select(hi.cmpgt(lo), Vec3A::splat(bins as f32) / (hi - lo), Vec3A::ZERO);
    let last = Vec3A::splat((bins - 1) as f32);
    let bin = |x: Vec3A| ((x - lo) * scale).min(last).as_ivec3();
    for &r in refs {
        let b = &boxes[r as usize];
        let (start, end) = (bin(Vec3A::from(b.min).max(lo)), bin(Vec3A::from(b.max).min(hi)));
        for axis in 0..3 {
            starts[axis][start[axis] as usize] += 1;
            ends[axis][end[axis] as usize] += 1;
        }
    }
    for axis in 0..3 {
        let (l, h) = (lo[axis], hi[axis]);
        // Planes that cut the empty space off the cell.
        consider(axis, l, price(axis, l, 0.0, n));
        consider(axis, h, price(axis, h, n, 0.0));
        if (h - l).is_nan() || h <= l {
            continue;
        }
        // Plane i (between bins i − 1 and i): boxes starting in a bin below i reach below it,
        // boxes ending in bin i or above reach above it.
        let mut below = 0u32;
        let mut above = refs.len() as u32;
        for i in 1..bins {
            below += starts[axis][i - 1];
            above -= ends[axis][i - 1];
            let split = l + (h - l) * (i as f32 / bins as f32);
            consider(axis, split, price(axis, split, below as f32, above as f32));
        }
    }
    best
}
