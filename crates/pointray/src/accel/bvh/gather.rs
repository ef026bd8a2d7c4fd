//! The footprint prefilter's walk (`splat::footprint`): a beam through the tree, nearest
//! subtrees first, handing the visitor each representative of a subtree narrower than the
//! threshold and each disk of the leaves it reaches, until the visitor's layers are opaque.
//!
//! Each node tests its eight children's bounding spheres against the beam at once: a child is
//! entered where its sphere comes within the beam's radius of the axis (the radius where the
//! sphere ends, the beam widening with depth) between `t_min` and the visitor's cut.

use arrayvec::ArrayVec;

use super::lanes::{Lanes, Wide, dot3};
use super::{Bvh, LEAF, MAX_DEPTH, SLOTS, WIDTH, leaf_blocks, leaf_splats};
use crate::accel::TraversalStats;
use crate::accel::block::{BLOCK, SplatBlock};
use crate::splat::footprint::{Aggregate, Beam, Candidates, FootprintVisitor};

/// Children waiting, with the depth where their spheres begin: each level pushes at most
/// WIDTH, and no tree is deeper than [`MAX_DEPTH`].
type Stack = ArrayVec<(u32, f32), { WIDTH * MAX_DEPTH + 1 }>;

pub(super) fn gather<V: FootprintVisitor>(
    bvh: &Bvh,
    beam: &Beam,
    tau: f32,
    visitor: &mut V,
    stats: &mut TraversalStats,
) {
    if bvh.nodes.is_empty() {
        return;
    }
    let mut stack = Stack::new();
    stack.push((0, beam.t_min));
    while let Some((child, entry)) = stack.pop() {
        if entry > visitor.t_cut() {
            continue;
        }
        // A stored top's treelet: its root (see `treelet`), none if damaged.
        let Some(child) = (if Bvh::is_treelet(child) { bvh.enter(child) } else { Some(child) }) else { continue };
        if child & LEAF != 0 {
            leaf(bvh, child, visitor, stats);
            continue;
        }
        let k = child as usize;
        stats.nodes_visited += 1;
        stats.sphere_tests += u64::from((bvh.nodes[k].used & SLOTS).count_ones());
        let (entries, mut enter, coarse) = children(bvh, k, beam, tau, visitor.t_cut());
        let mut reps = coarse & enter;
        enter &= !coarse;
        stats.lod_stops += u64::from(reps.count_ones());
        if reps != 0 {
            reps &= visitor.screen(&candidates(&bvh.representatives[k], bvh.aggregates[k].area_radius.to_array()));
        }
        while reps != 0 {
            let i = reps.trailing_zeros() as usize;
            reps &= reps - 1;
            let index = bvh.representative_index(k, i);
            visitor.add(index, &bvh.representatives[k].splat(i), bvh.aggregates[k].get(i));
        }
        // Farthest pushed first, so that the nearest is walked next: an insertion sort of at
        // most eight, by hand, as `Footprint` sorts its pieces.
        let first = stack.len();
        while enter != 0 {
            let i = enter.trailing_zeros() as usize;
            enter &= enter - 1;
            let entry = (bvh.nodes[k].child[i], entries[i]);
            let mut at = stack.len();
            stack.push(entry);
            while at > first && stack[at - 1].1 < entry.1 {
                stack[at] = stack[at - 1];
                at -= 1;
            }
            stack[at] = entry;
        }
    }
}

/// Hands `visitor` the disks of leaf `child` that pass its screen.
fn leaf<V: FootprintVisitor>(bvh: &Bvh, child: u32, visitor: &mut V, stats: &mut TraversalStats) {
    let splats = leaf_splats(child);
    stats.splat_tests += u64::from(splats.end - splats.start);
    for b in leaf_blocks(child) {
        let block = &bvh.blocks[b];
        let first = (b * BLOCK) as u32;
        let used = (splats.end - first).min(BLOCK as u32);
        let mut lanes = visitor.screen(&candidates(block, *block.radii())) & ((1 << used) - 1);
        while lanes != 0 {
            let i = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            let s = block.splat(i);
            visitor.add(first + i as u32, &s, Aggregate::disk(s.radius));
        }
    }
}

/// A block's eight lanes as the visitor screens them.
#[inline(always)]
fn candidates(block: &SplatBlock, area_radius: [f32; BLOCK]) -> Candidates {
    // Written out: `array::map` here was a call per candidate block (callgrind).
    let center = [block.center_lanes(0), block.center_lanes(1), block.center_lanes(2)];
    let normal = [block.normal_lanes(0), block.normal_lanes(1), block.normal_lanes(2)];
    Candidates { center, normal, area_radius }
}

/// Leaves stand as their representatives up to this many times the threshold: opened, a leaf
/// hands the gather its 8 to 16 disks (screened eight at once). The dragon against 256 rays a
/// pixel, at 16 diagonals: 5.2 ms a frame and 34.8 dB at 1, 2.4 ms and 34.7 dB at 1.5, 1.9 ms
/// and 34.2 dB at 2.5; at 8 diagonals 13.6 ms and 36.5 dB, 12.0 and 36.2, 6.0 and 35.6. Whole
/// leaves (6, with a cut of 0.2) made 8 diagonals 2.4× cheaper at 35.3 dB, but the Happy Buddha,
/// whose sparse leaves span pixels, fell from 27.5 to 24.4 dB at 16 (`docs/RESULTS.md`). 1.5
/// keeps the dragon at 16 diagonals as close as 8 rays a pixel.
const LEAF_SLACK: f32 = 1.5;

/// Node `k`'s children all of whose disks face away from the beam: their normal cones (about
/// the representatives' normals, half-angle θ < 90°) lie within 90° − θ of its direction, so
/// that every normal n below has n·d > 0 and the visitor would drop every piece they give. A
/// shadow beam so skips the lit surface it leaves, a camera's the far side of what it meets.
/// The dragon at 16 diagonals (callgrind, `footprint_radiance`, four frames): 345 → 321 million
/// instructions, the same image.
#[inline(always)]
fn facing_away(bvh: &Bvh, k: usize, dir: &[Lanes; 3]) -> u32 {
    let reps = &bvh.representatives[k];
    let axis = [0, 1, 2].map(|a| reps.normal_node_lanes(a));
    let (s, cos) = (dot3(&axis, dir), bvh.lod[k].cos_angle);
    // s > sin θ, squared, with a margin for the normals' rounding.
    let margin = Lanes::splat(FACING_MARGIN);
    Lanes::bitmask(
        s.cmpgt(Lanes::ZERO) & cos.cmpgt(Lanes::ZERO) & (s * s).cmpgt(Lanes::splat(1.0) - cos * cos + margin),
    )
}

/// [`facing_away`]'s margin on sin²: some 0.06° near a cone's edge.
const FACING_MARGIN: f32 = 1e-3;

/// For node `k`'s children: where their spheres begin along the beam, those the beam enters
/// before `t_cut`, and those narrower than `tau` beam radii that a representative may stand in
/// for.
#[inline(always)]
fn children(bvh: &Bvh, k: usize, beam: &Beam, tau: f32, t_cut: f32) -> ([f32; WIDTH], u32, u32) {
    let node = &bvh.nodes[k];
    let radius = bvh.lod[k].radius;
    let p = &node.planes;
    let half = Lanes::splat(0.5);
    let oc: [Lanes; 3] = std::array::from_fn(|a| (p[a] + p[3 + a]) * half - Lanes::splat(beam.origin[a]));
    let dir = [0, 1, 2].map(|a| Lanes::splat(beam.dir[a]));
    let tc = dot3(&oc, &dir);
    let off2 = dot3(&oc, &oc) - tc * tc;
    let (r0, spread) = (Lanes::splat(beam.r0), Lanes::splat(beam.spread));
    let reach = radius + r0 + spread * (tc + radius).max(Lanes::ZERO);
    let entry = tc - radius;
    let enter = Lanes::bitmask(
        off2.cmple(reach * reach)
            & Lanes::splat(beam.t_min).cmple(tc + radius)
            & entry.cmple(Lanes::splat(t_cut.min(beam.t_max))),
    ) & node.used
        & SLOTS
        & !facing_away(bvh, k, &dir);
    let narrow = Lanes::splat(tau) * (r0 + spread * tc.max(Lanes::ZERO));
    // Every child has a representative, small leaves too (which rays never take: their
    // disks cost a ray no more to test); to a beam, a leaf's disks are as many pieces.
    let leaves = (0..WIDTH).fold(0u32, |m, i| m | u32::from(node.child[i] & LEAF != 0) << i);
    let leaf_narrow = narrow * Lanes::splat(LEAF_SLACK);
    let coarse =
        (Lanes::bitmask(radius.cmplt(narrow)) | Lanes::bitmask(radius.cmplt(leaf_narrow)) & leaves) & node.used & SLOTS;
    (entry.to_array(), enter, coarse)
}
