//! The two-level scene: a cloud of more than `BvhParams::part_splats` splats is cut into
//! parts, the cells of the Morton octree the chunk plan splits (`ChunkPlan::parts`) that hold
//! at most that many. Each part is a BVH of its own, its positions relative to the centre of its
//! points' bounds (`Part::offset`, from the scene's origin; moved there from the cloud's `f64`
//! coordinates where it keeps them, `PointCloud::residuals`, so that a part keeps the precision
//! of its own extent), under a small tree of eight-wide nodes over
//! the parts' boxes. A BVH indexes at most 2²⁸ splats (its leaf references name a block in 27 bits); the
//! parts lift that cap to the visitors' index space, 2³² lanes (3.7 billion splats at the 1.17
//! a splat a torus of 300 million takes), and each part can be stored, mapped and checked on its
//! own.
//!
//! Index space: the parts' block lanes one after another (part `p`'s from `Part::lanes`), then
//! their representatives (part `p`'s from `TwoLevel::lanes + Part::reps`), so that, as in one
//! BVH, an index past the block lanes is a representative and the input's ids are indexed by
//! the block lanes alone.
//!
//! A ray walks the parts its top boxes meet, nearest first, each in the part's frame (its
//! origin moved by the offset; the cone and `t` unchanged), and the visitor gets every
//! crossing with the scene's index and the scene's ray: a visitor never sees a part's frame.
//! A scene of one part is the plain [`Bvh`] (no top, no moved rays): only clouds above the
//! limit pay the walk of the top. The top's nodes are the BVH's (`Node`), tested eight boxes at a
//! time as the BVH tests them: on the 30 M torus cut into 8 parts (a close view at 256²,
//! callgrind), the parts cost 97 instructions a pixel over the lone tree, where a binary top
//! tested a box at a time cost 267.

use std::sync::OnceLock;

use arrayvec::ArrayVec;
use glam::Vec3;

use super::build::{BvhParams, TooLarge};
use super::chunk::{in_chunk_order, plan_of};
use super::lanes::{Lanes, Wide};
use super::traverse::SlabRay;
use super::{Bvh, LEAF, Node, NodeBounds, SLOTS, WIDTH};
use crate::accel::block::BLOCK;
use crate::accel::{Accel, Crossing, SplatVisitor, TraversalStats};
use crate::math::{Aabb, Ray};
use crate::splat::footprint::{Aggregate, Beam, Candidates, FootprintVisitor};
use crate::splat::{DiskShape, Splat};

/// The most splats a part holds (`BvhParams::part_splats`): a fourth of what one BVH can
/// index, so that no part's blocks come near the cap however its leaves fill them.
pub const PART_SPLATS: usize = 1 << 26;

/// A part of a two-level scene: its BVH, in the frame `offset` away from the scene's.
pub struct Part {
    pub bvh: Bvh,
    pub offset: Vec3,
    /// Its first block lane in the scene's index space, and its first representative lane
    /// counted from [`TwoLevel::lanes`].
    lanes: u32,
    reps: u32,
    /// Its bounds in the scene's frame, widened past the rounding of the move.
    bounds: Aabb,
}

impl Part {
    /// A scene's index of this part's index `local`.
    #[inline(always)]
    fn global(&self, local: u32, lanes: u32) -> u32 {
        let blocks = (self.bvh.blocks.len() * BLOCK) as u32;
        if local < blocks { self.lanes + local } else { lanes + self.reps + (local - blocks) }
    }

    /// `splat` of this part in the scene's frame.
    #[inline(always)]
    fn in_scene(&self, mut splat: Splat) -> Splat {
        splat.center += self.offset;
        splat
    }
}

/// The top's walk: the nodes and parts to visit, with their entries; eight for each of its
/// levels (eleven at most, for 2³² parts).
type Stack = ArrayVec<(f32, u32), { 8 * 11 }>;

/// Parts of one scene under a top (see the module).
pub struct TwoLevel {
    parts: Vec<Part>,
    /// Nodes as the BVH's over the parts' boxes (a child `LEAF | part`), the root first; none
    /// without parts.
    top: Vec<Node>,
    /// All parts' block lanes: the first representative's index.
    lanes: u32,
    bounds: Aabb,
    splat_count: usize,
    wide_radius: f32,
    lod_floor: f32,
    coverage_density: OnceLock<f32>,
    shape: DiskShape,
}

impl TwoLevel {
    /// The two-level scene of `input` (more than `params.part_splats` splats), and for each
    /// part, each of its block lanes' input splat (`u32::MAX` for the gaps), as
    /// [`Bvh::try_build_with_ids`] gives them of one tree. Each centre is moved into its part's
    /// frame with its `residuals`' (`PointCloud::residuals`) where they are given.
    pub fn try_build_with_ids(
        input: Vec<Splat>,
        residuals: Option<&[Vec3]>,
        params: &BvhParams,
    ) -> Result<(TwoLevel, Vec<Vec<u32>>), TooLarge> {
        assert!(params.part_splats >= params.chunk_splats, "parts hold whole chunks");
        assert!(residuals.is_none_or(|r| r.len() == input.len()), "a residual a splat");
        let plan = plan_of(&input, params.chunk_splats);
        let (input, order) = in_chunk_order(input, &plan);
        let residual = |at: usize| {
            let from = order.as_ref().map_or(at, |o| o[at] as usize);
            residuals.map_or(Vec3::ZERO, |r| r[from])
        };
        let (mut parts, mut ids, mut first) = (Vec::new(), Vec::new(), 0);
        let cells = plan.parts(params.part_splats);
        let lone = cells.len() == 1;
        for (cell, chunks) in cells {
            // A lone part (a cell that cannot split) stays in the scene's frame, its splats as
            // given, as a lone BVH's.
            let range = first..first + cell.count;
            let (splats, offset) = if lone {
                (input[range].to_vec(), Vec3::ZERO)
            } else {
                let offset = part_offset(Aabb::from_points(input[range.clone()].iter().map(|s| s.center)));
                (range.map(|at| moved(&input[at], residual(at), offset)).collect(), offset)
            };
            let (bvh, mut part_ids) = Bvh::try_build_planned(splats, &chunks, params)?;
            for id in part_ids.iter_mut().filter(|id| **id != u32::MAX) {
                let at = first + *id as usize;
                *id = order.as_ref().map_or(at as u32, |o| o[at]);
            }
            parts.push((bvh, offset));
            ids.push(part_ids);
            first += cell.count;
        }
        Ok((TwoLevel::new(parts)?, ids))
    }

    /// The scene of these parts (each BVH with its offset), in the order of their index spaces.
    pub fn new(parts: Vec<(Bvh, Vec3)>) -> Result<TwoLevel, TooLarge> {
        let lanes: u64 = parts.iter().map(|(b, _)| (b.blocks.len() * BLOCK) as u64).sum();
        let reps: u64 = parts.iter().map(|(b, _)| (b.representatives.len() * BLOCK) as u64).sum();
        if lanes + reps >= u64::from(u32::MAX) {
            return Err(TooLarge::Indices(lanes + reps));
        }
        let (mut at_lane, mut at_rep) = (0u32, 0u32);
        let parts: Vec<Part> = parts
            .into_iter()
            .map(|(bvh, offset)| {
                let (lanes, reps) = (at_lane, at_rep);
                at_lane += (bvh.blocks.len() * BLOCK) as u32;
                at_rep += (bvh.representatives.len() * BLOCK) as u32;
                let bounds = scene_box(bvh.bounds, offset);
                Part { bvh, offset, lanes, reps, bounds }
            })
            .collect();
        let mut top = Vec::with_capacity(parts.len() / (WIDTH - 1) + 1);
        if !parts.is_empty() {
            let (root, bounds) = top_node(&parts, 0..parts.len(), &mut top);
            // A lone part: a root of one child.
            if root & LEAF != 0 {
                let mut node = Node::new(&[bounds]);
                node.child[0] = root;
                top.push(node);
            }
        }
        let of = |f: fn(&Bvh) -> f32| parts.iter().map(move |p| f(&p.bvh));
        Ok(TwoLevel {
            lanes: at_lane,
            bounds: parts.iter().fold(Aabb::EMPTY, |b, p| b.union(p.bounds)),
            splat_count: parts.iter().map(|p| p.bvh.splat_count).sum(),
            wide_radius: of(|b| b.wide_radius).fold(0.0, f32::max),
            lod_floor: of(|b| b.lod_floor).fold(f32::INFINITY, f32::min),
            coverage_density: OnceLock::new(),
            shape: parts.first().map_or(DiskShape::Oriented, |p| p.bvh.shape),
            parts,
            top,
        })
    }

    /// The same scene, each part's arrays and checks shared (`Bvh::share`).
    pub(crate) fn share(&self) -> TwoLevel {
        let parts = self.parts.iter().map(|p| Part { bvh: p.bvh.share(), ..*p }).collect();
        TwoLevel { parts, top: self.top.clone(), coverage_density: self.coverage_density.clone(), ..*self }
    }

    /// A scene of one part as that part's BVH (in the scene's frame), else itself.
    pub fn into_lone(mut self) -> Result<Bvh, TwoLevel> {
        match self.parts.len() {
            1 if self.parts[0].offset == Vec3::ZERO => Ok(self.parts.pop().expect("one part").bvh),
            _ => Err(self),
        }
    }

    pub fn parts(&self) -> &[Part] {
        &self.parts
    }

    /// The part an index of the scene's lies in, and its index there.
    #[inline(always)]
    pub fn locate(&self, index: u32) -> (usize, u32) {
        if index < self.lanes {
            let p = self.parts.partition_point(|p| p.lanes <= index) - 1;
            (p, index - self.parts[p].lanes)
        } else {
            let r = index - self.lanes;
            let p = self.parts.partition_point(|p| p.reps <= r) - 1;
            let part = &self.parts[p];
            (p, (part.bvh.blocks.len() * BLOCK) as u32 + r - part.reps)
        }
    }

    /// The first damage a walk found in a stored part's treelets.
    pub fn damage(&self) -> Option<&str> {
        self.parts.iter().find_map(|p| p.bvh.damage())
    }

    pub fn node_count(&self) -> usize {
        self.parts.iter().map(|p| p.bvh.node_count()).sum()
    }

    pub fn sphere_node_count(&self) -> usize {
        self.parts.iter().map(|p| p.bvh.sphere_node_count()).sum()
    }

    pub fn node_bounds(&self) -> NodeBounds {
        self.parts.first().map_or(NodeBounds::Boxes, |p| p.bvh.node_bounds())
    }

    /// Calls `part` with each part `children` says the walk enters, nearest first, until
    /// `done(visitor)`: `children` pushes a top node's children entered before
    /// `t_max(visitor)`, each with its entry, onto the stack it is given.
    #[inline(always)]
    fn walk<V: ?Sized>(
        &self,
        t_min: f32,
        children: impl Fn(&Node, f32, &mut Stack),
        visitor: &mut V,
        t_max: impl Fn(&V) -> f32,
        done: impl Fn(&V) -> bool,
        mut part: impl FnMut(&Part, &mut V),
    ) {
        if self.top.is_empty() {
            return;
        }
        let mut stack = Stack::new();
        stack.push((t_min, 0));
        while let Some((t, n)) = stack.pop() {
            if done(visitor) {
                return;
            }
            if t > t_max(visitor) {
                continue;
            }
            if n & LEAF != 0 {
                part(&self.parts[(n & !LEAF) as usize], visitor);
                continue;
            }
            let below = stack.len();
            children(&self.top[n as usize], t_max(visitor), &mut stack);
            // The farthest first, so that the nearest is walked first. (Pushed in place and
            // sorted there: handed back in a list of their own, the copies cost 87 of the 184
            // instructions a pixel the top took: 30 M torus in 8 parts, close, callgrind.)
            stack[below..].sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
        }
    }
}

/// The children of `node` whose boxes the segment from `origin` (with `inv_dir`) enters within
/// `[t0, t1]`, each widened by `widen` of its box, with their entries (a scalar test a child:
/// for the beam's walk, whose boxes widen as they lie farther).
fn widened_children(
    node: &Node,
    (origin, inv_dir): (Vec3, Vec3),
    (t0, t1): (f32, f32),
    widen: impl Fn(&Aabb) -> f32,
    stack: &mut Stack,
) {
    let slots = (0..WIDTH).filter(|&i| node.used & SLOTS & (1 << i) != 0);
    let entered = slots.filter_map(|i| {
        let b = node.child_bounds(i);
        let w = widen(&b);
        let (lo, hi) = ((b.min - w - origin) * inv_dir, (b.max + w - origin) * inv_dir);
        let near = lo.min(hi).max_element().max(t0);
        let far = lo.max(hi).min_element().min(t1);
        // NaN (an origin on a face's plane, parallel to it) enters: the part decides.
        match near.partial_cmp(&far) {
            Some(std::cmp::Ordering::Greater) => None,
            _ => Some((near, node.child[i])),
        }
    });
    stack.extend(entered);
}

/// Where the frame of a part whose points' centres lie in `points` is: their centre (not their
/// cell's, which may lie far from them: the plan's cells are as long as the cloud's bounds on
/// each axis), rounded to a multiple of the power of two at or above a 1,024th of their extent,
/// so that the splats' grids ([`crate::accel::block`]'s snapping, far finer) are the scene's,
/// moved.
pub fn part_offset(points: Aabb) -> Vec3 {
    let x = points.extent().max_element() / 1024.0;
    if !x.is_normal() {
        return points.center();
    }
    // From the bits: the exponent of `x`, one up unless `x` is a power of two.
    let bits = x.to_bits();
    let step = f32::from_bits(((bits >> 23) + u32::from(bits & 0x7f_ffff != 0)) << 23);
    (points.center() / step).round() * step
}

/// `splat` moved into the frame `offset` away, its centre with the `residual` it rounded off,
/// rounded once (without one, as `f32` subtracts: within a cloud, the difference of two of its
/// `f32`s is exact in `f64`).
fn moved(splat: &Splat, residual: Vec3, offset: Vec3) -> Splat {
    Splat { center: crate::cloud::moved_precisely(splat.center, residual, offset), ..*splat }
}

/// A part's `bounds` in the scene's frame: moved by `offset`, widened by a few units in the
/// last place of the largest coordinate, so that no rounding of the move (or of a ray's) can
/// make a ray that meets the part's own box miss this one.
fn scene_box(bounds: Aabb, offset: Vec3) -> Aabb {
    if bounds.is_empty() {
        return bounds;
    }
    let (lo, hi) = (bounds.min + offset, bounds.max + offset);
    let largest = lo.abs().max(hi.abs()).max(offset.abs()).max(bounds.extent()).max_element();
    let slack = largest * 8.0 * f32::EPSILON;
    Aabb::new(lo - slack, hi + slack)
}

/// Appends the top's node over `range` of `parts` (its children eighths of the range in
/// Morton order, so that each lies together) and its subtrees; its reference, and the bounds.
fn top_node(parts: &[Part], range: std::ops::Range<usize>, top: &mut Vec<Node>) -> (u32, Aabb) {
    if range.len() == 1 {
        return (LEAF | range.start as u32, parts[range.start].bounds);
    }
    let at = top.len();
    top.push(Node::new(&[]));
    let step = range.len().div_ceil(WIDTH);
    let children: ArrayVec<(u32, Aabb), WIDTH> = (range.start..range.end)
        .step_by(step)
        .map(|first| top_node(parts, first..(first + step).min(range.end), top))
        .collect();
    let boxes: ArrayVec<Aabb, WIDTH> = children.iter().map(|c| c.1).collect();
    let mut node = Node::new(&boxes);
    for (i, (child, _)) in children.iter().enumerate() {
        node.child[i] = *child;
    }
    top[at] = node;
    (at as u32, boxes.iter().fold(Aabb::EMPTY, |b, c| b.union(*c)))
}

/// A visitor of the scene's seen from a part: the crossings handed on with the scene's index
/// and ray.
struct InPart<'a, V> {
    visitor: &'a mut V,
    ray: &'a Ray,
    part: &'a Part,
    lanes: u32,
}

impl<V: SplatVisitor> SplatVisitor for InPart<'_, V> {
    const SHAPE: DiskShape = V::SHAPE;

    #[inline(always)]
    fn t_max(&self) -> f32 {
        self.visitor.t_max()
    }

    #[inline(always)]
    fn hit(&mut self, _: &Ray, crossing: Crossing) {
        let splat = self.part.global(crossing.splat, self.lanes);
        self.visitor.hit(self.ray, Crossing { splat, ..crossing });
    }

    #[inline(always)]
    fn done(&self) -> bool {
        self.visitor.done()
    }
}

/// A footprint visitor of the scene's seen from a part: disks and candidates moved back into
/// the scene's frame, indices the scene's.
struct BeamInPart<'a, V> {
    visitor: &'a mut V,
    part: &'a Part,
    lanes: u32,
}

impl<V: FootprintVisitor> FootprintVisitor for BeamInPart<'_, V> {
    fn t_cut(&self) -> f32 {
        self.visitor.t_cut()
    }

    fn add(&mut self, index: u32, splat: &Splat, aggregate: Aggregate) {
        self.visitor.add(self.part.global(index, self.lanes), &self.part.in_scene(*splat), aggregate);
    }

    fn screen(&self, candidates: &Candidates) -> u32 {
        let center = std::array::from_fn(|k| candidates.center[k].map(|c| c + self.part.offset[k]));
        self.visitor.screen(&Candidates { center, normal: candidates.normal, area_radius: candidates.area_radius })
    }
}

impl Accel for TwoLevel {
    fn name(&self) -> &'static str {
        "bvh"
    }

    #[inline(always)]
    fn splat(&self, index: u32) -> Splat {
        let (p, local) = self.locate(index);
        let part = &self.parts[p];
        part.in_scene(part.bvh.splat(local))
    }

    fn is_representative(&self, index: u32) -> bool {
        index >= self.lanes
    }

    fn splat_count(&self) -> usize {
        self.splat_count
    }

    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn wide_radius(&self) -> f32 {
        self.wide_radius
    }

    /// The parts' densities, weighted by their splats.
    fn coverage_density(&self) -> f32 {
        *self.coverage_density.get_or_init(|| {
            let weighted: f64 =
                self.parts.iter().map(|p| p.bvh.coverage_density() as f64 * p.bvh.splat_count as f64).sum();
            (weighted / self.splat_count.max(1) as f64) as f32
        })
    }

    fn gather<V: FootprintVisitor>(&self, beam: &Beam, tau: f32, visitor: &mut V, stats: &mut TraversalStats) {
        // A top box widened by the beam's radius at its farthest corner holds every disk the
        // beam may overlap inside it.
        let far = |b: &Aabb| beam.radius((b.min - beam.origin).abs().max((b.max - beam.origin).abs()).length());
        let segment = (beam.origin, beam.dir.recip());
        let children = |node: &Node, t_max: f32, stack: &mut Stack| {
            widened_children(node, segment, (beam.t_min, t_max), far, stack)
        };
        let lanes = self.lanes;
        self.walk(
            beam.t_min,
            children,
            visitor,
            |v| v.t_cut().min(beam.t_max),
            |_| false,
            |part, visitor| {
                let local = Beam { origin: beam.origin - part.offset, ..*beam };
                part.bvh.gather(&local, tau, &mut BeamInPart { visitor, part, lanes }, stats);
            },
        );
    }

    fn may_stop_at_representatives(&self, ray: &Ray) -> bool {
        self.parts.iter().any(|p| p.bvh.may_stop_at_representatives(&Ray { origin: ray.origin - p.offset, ..*ray }))
    }

    fn lod_floor(&self) -> f32 {
        self.lod_floor
    }

    fn shape(&self) -> DiskShape {
        self.shape
    }

    fn for_each_near<F: FnMut(u32, Splat)>(&self, center: Vec3, radius: f32, stats: &mut TraversalStats, mut f: F) {
        for part in &self.parts {
            let gap = (part.bounds.min - center).max(center - part.bounds.max).max(Vec3::ZERO);
            if gap.length_squared() <= radius * radius {
                part.bvh.for_each_near(center - part.offset, radius, stats, |j, s| {
                    f(part.global(j, self.lanes), part.in_scene(s))
                });
            }
        }
    }

    fn memory_bytes(&self) -> usize {
        self.parts.iter().map(|p| p.bvh.memory_bytes()).sum::<usize>() + self.top.len() * size_of::<Node>()
    }

    fn traverse<V: SplatVisitor>(&self, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
        let lanes = self.lanes;
        // The parts' boxes eight at a time, as the BVH's nodes test theirs.
        let slab = SlabRay::<Lanes>::new(ray);
        let children = |node: &Node, t_max: f32, stack: &mut Stack| {
            let (near, mut mask) = slab.entries(node, ray.t_min, t_max);
            let near = near.to_array();
            while mask != 0 {
                let i = mask.trailing_zeros() as usize;
                stack.push((near[i], node.child[i]));
                mask &= mask - 1;
            }
        };
        self.walk(
            ray.t_min,
            children,
            visitor,
            |v| v.t_max(),
            |v| v.done(),
            |part, visitor| {
                let local = Ray { origin: ray.origin - part.offset, ..*ray };
                part.bvh.traverse(&local, &mut InPart { visitor, ray, part, lanes }, stats);
            },
        );
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};

    use glam::DVec3;

    use super::*;
    use crate::accel::BruteForce;
    use crate::math::RayCone;
    use crate::splat::scheme::{self, SurfaceScheme};

    /// `n` disks on a torus (radii 3 and 1) far from the origin, where the parts' frames
    /// matter, in a fixed shuffled order.
    fn torus(n: usize) -> Vec<Splat> {
        let at = |i: usize| {
            let (u, v) = (i as f32 * 0.618_034 % 1.0, (i as f32 + 0.5) / n as f32);
            let (a, b) = (u * std::f32::consts::TAU, v * std::f32::consts::TAU);
            let normal = Vec3::new(a.cos() * b.cos(), a.sin() * b.cos(), b.sin());
            let ring = Vec3::new(a.cos(), a.sin(), 0.0) * 3.0;
            let center = Vec3::new(1_000.0, -500.0, 250.0) + ring + normal;
            Splat { center, radius: 12.0 / (n as f32).sqrt(), normal, color: i as u32 }
        };
        (0..n).map(|i| at(i * 7_919 % n)).collect()
    }

    fn rays(bounds: &Aabb, n: usize, seed: u64) -> Vec<Ray> {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let mut unit =
            || Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let (c, size) = (bounds.center(), bounds.diagonal());
        (0..n)
            .map(|_| {
                let origin = c + unit().normalize_or(Vec3::X) * size;
                let target = c + unit() * 0.5 * bounds.extent();
                Ray::new(origin, target - origin, RayCone::default())
            })
            .collect()
    }

    fn params() -> BvhParams {
        BvhParams { chunk_splats: 700, part_splats: 2_000, ..BvhParams::standard() }
    }

    #[test]
    fn a_scene_in_parts_finds_the_hits_each_part_finds_in_its_own_frame() {
        let splats = torus(20_000);
        let (scene, ids) = TwoLevel::try_build_with_ids(splats.clone(), None, &params()).unwrap();
        // More parts than a top node holds: a top of two levels.
        assert!(scene.parts.len() > WIDTH && scene.top.len() > 1, "{} parts", scene.parts.len());
        assert_eq!(scene.splat_count(), splats.len());
        // Each part's splats, in its frame, as an oracle of its own.
        let oracles: Vec<BruteForce> =
            scene.parts.iter().map(|p| BruteForce::new(p.bvh.splats().map(|(_, s)| s).collect())).collect();
        let first_hit = SurfaceScheme::first_hit();
        let mut hits = 0;
        for (i, ray) in rays(&scene.bounds(), 3_000, 5).iter().enumerate() {
            let stats = &mut TraversalStats::default();
            let nearest = scene.parts.iter().zip(&oracles).filter_map(|(part, oracle)| {
                let local = Ray { origin: ray.origin - part.offset, ..*ray };
                scheme::intersect(oracle, &local, &first_hit, stats)
                    .map(|h| (h.t, part.in_scene(oracle.splat(h.splat))))
            });
            let expected = nearest.min_by(|a, b| a.0.total_cmp(&b.0));
            let found = scheme::intersect(&scene, ray, &first_hit, stats).map(|h| (h.t, scene.splat(h.splat)));
            assert_eq!(
                found.map(|(t, s)| (t.to_bits(), s.bits())),
                expected.map(|(t, s)| (t.to_bits(), s.bits())),
                "ray {i}"
            );
            hits += usize::from(found.is_some());
            let sj = SurfaceScheme::sj();
            let occluded = scene.parts.iter().zip(&oracles).any(|(part, oracle)| {
                let local = Ray { origin: ray.origin - part.offset, ..*ray };
                scheme::occluded(oracle, &local, 5.0, &sj, stats)
            });
            assert_eq!(scheme::occluded(&scene, ray, 5.0, &sj, stats), occluded, "ray {i}: occlusion");
        }
        assert!(hits > 1_000, "{hits} hits");
        // Every input splat named once by the ids, as the scene's index holds it.
        let mut seen = vec![false; splats.len()];
        for (p, part_ids) in ids.iter().enumerate() {
            for (lane, &id) in part_ids.iter().enumerate().filter(|(_, id)| **id != u32::MAX) {
                assert!(!std::mem::replace(&mut seen[id as usize], true), "splat {id} twice");
                let index = scene.parts[p].lanes + lane as u32;
                assert_eq!(scene.locate(index), (p, lane as u32));
                assert!((scene.splat(index).center - splats[id as usize].center).length() < 1e-3);
            }
        }
        assert!(seen.iter().all(|&s| s));
    }

    #[test]
    fn a_scene_in_parts_finds_the_scenes_hits_up_to_the_rounding_of_its_frames() {
        let splats = torus(20_000);
        let (scene, ids) = TwoLevel::try_build_with_ids(splats.clone(), None, &params()).unwrap();
        let brute = BruteForce::new(splats.clone());
        let (mut same, mut hits) = (0, 0);
        for (i, ray) in rays(&scene.bounds(), 2_000, 6).iter().enumerate() {
            let stats = &mut TraversalStats::default();
            for scheme in [SurfaceScheme::first_hit(), SurfaceScheme::sj()] {
                let (a, b) =
                    (scheme::intersect(&brute, ray, &scheme, stats), scheme::intersect(&scene, ray, &scheme, stats));
                let (Some(a), Some(b)) = (a, b) else {
                    assert_eq!(a.is_some(), b.is_some(), "ray {i} {scheme:?}");
                    continue;
                };
                let (p, lane) = scene.locate(b.splat);
                hits += 1;
                if ids[p][lane as usize] != a.splat {
                    // Another of the overlapping disks there.
                    assert!((a.t - b.t).abs() <= 2.0 * a.radius, "ray {i} {scheme:?}: {} vs {}", a.t, b.t);
                    continue;
                }
                // Snapped in each frame, a disk's centre moves by up to a 2,048th of its radius
                // either way: its plane's distance along the ray by that over the cosine.
                let apart = (a.t - b.t).abs() * ray.dir.dot(a.normal).abs();
                assert!(apart <= a.radius / 1_024.0, "ray {i} {scheme:?}: {} vs {}", a.t, b.t);
                assert!(a.normal.dot(b.normal) > 0.9999, "ray {i} {scheme:?}");
                same += 1;
            }
        }
        // A crossing of two disks within the rounding may be found on either.
        assert!(hits > 1_000 && same * 100 >= hits * 99, "{same} of {hits} hits on the same disk");
    }

    #[test]
    fn each_part_keeps_the_precision_of_its_own_frame() {
        // Two sites 200 km apart in UTM coordinates, a centimetre between points, each point
        // placed to a hundredth of a millimetre.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        let world: Vec<DVec3> = (0..6_000)
            .map(|i: usize| {
                let site = DVec3::new(if i.is_multiple_of(2) { 400_000.0 } else { 600_000.0 }, 5_000_000.0, 30.0);
                let (x, z) = ((i / 2 % 60) as f64 * 0.01, (i / 120) as f64 * 0.01);
                site + DVec3::new(x, 0.0, z) + DVec3::splat(rng.random_range(0.0..1e3)).round() * 1e-5
            })
            .collect();
        let cloud = crate::PointCloud::from_world_positions(&world);
        let splats: Vec<Splat> =
            cloud.positions.iter().map(|&center| Splat { center, radius: 0.01, normal: Vec3::Y, color: 0 }).collect();
        // How far each part puts its points from the world's (less the centres' snapping:
        // a 2,048th of the radius).
        let worst = |residuals: Option<&[Vec3]>| {
            let (scene, ids) = TwoLevel::try_build_with_ids(splats.clone(), residuals, &params()).unwrap();
            assert!(scene.parts.len() > 2, "{} parts", scene.parts.len());
            let mut worst = 0.0f64;
            for (part, ids) in scene.parts.iter().zip(&ids) {
                for (lane, s) in part.bvh.splats() {
                    let placed = cloud.origin + part.offset.as_dvec3() + s.center.as_dvec3();
                    worst = worst.max((placed - world[ids[lane as usize] as usize]).length());
                }
            }
            worst
        };
        let rounded = worst(None);
        let precise = worst(cloud.residuals.as_deref());
        assert!(rounded > 1e-3, "the cloud's f32 positions round by {rounded}");
        assert!(precise < 0.01 / 2_048.0 * 1.8, "{precise}");
    }

    #[test]
    fn a_scene_of_no_part_is_met_by_no_ray_and_one_of_one_part_is_that_part() {
        let scene = TwoLevel::new(Vec::new()).unwrap();
        let ray = Ray::new(Vec3::ZERO, Vec3::X, RayCone::default());
        let first_hit = SurfaceScheme::first_hit();
        assert!(scheme::intersect(&scene, &ray, &first_hit, &mut TraversalStats::default()).is_none());
        let splats = torus(3_000);
        let offset = Vec3::new(1_000.0, -500.0, 250.0);
        let part = Bvh::build(splats.iter().map(|s| moved(s, Vec3::ZERO, offset)).collect(), &BvhParams::standard());
        let lone = Bvh::build(splats.iter().map(|s| moved(s, Vec3::ZERO, offset)).collect(), &BvhParams::standard());
        let scene = TwoLevel::new(vec![(part, offset)]).unwrap();
        let mut hits = 0;
        for ray in rays(&scene.bounds(), 500, 7) {
            let stats = &mut TraversalStats::default();
            let local = Ray { origin: ray.origin - offset, ..ray };
            let a = scheme::intersect(&lone, &local, &first_hit, stats).map(|h| (h.t.to_bits(), h.splat));
            let b = scheme::intersect(&scene, &ray, &first_hit, stats).map(|h| (h.t.to_bits(), h.splat));
            assert_eq!(a, b);
            hits += usize::from(a.is_some());
        }
        assert!(hits > 100, "{hits} hits");
    }

    #[test]
    fn the_parts_hold_whole_chunks_of_at_most_the_limit() {
        let splats = torus(20_000);
        let plan = plan_of(&splats, 700);
        let parts = plan.parts(3_000);
        assert_eq!(parts.iter().map(|(c, _)| c.count).sum::<usize>(), splats.len());
        assert_eq!(parts.iter().flat_map(|(_, p)| p.chunks().to_vec()).collect::<Vec<_>>(), plan.chunks());
        // What a plan with the parts' limit makes, from passes over the codes.
        let direct = plan_of(&splats, 3_000);
        assert_eq!(parts.iter().map(|(c, _)| *c).collect::<Vec<_>>(), direct.chunks());
        // Each part's centre is its cell's: every splat within half the cell of it.
        let mut sorted = splats.clone();
        sorted.sort_by_key(|s| plan.chunk_of(plan.code(s.center)));
        let mut first = 0;
        for (cell, _) in &parts {
            let (center, half) = (cell.center(&plan.bounds()), plan.bounds().extent() / (2u32 << cell.level) as f32);
            let inside = |s: &Splat| ((s.center - center).abs() - half).max_element() <= 1e-4;
            assert!(sorted[first..first + cell.count].iter().all(inside), "cell {cell:?}");
            first += cell.count;
        }
    }
}
