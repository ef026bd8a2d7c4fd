//! Outward votes from views round the model: the scanner's rule, for a cloud without a
//! scanner position.
//!
//! A closed surface seen from outside shows its outer side, so a point that is the nearest
//! surface along a view direction `d` (seen from far away, in parallel projection) has its
//! outward normal facing `d`. From each of [`VIEWS`] directions spread evenly over the
//! sphere, every point marks its cell of a depth buffer with its depth; a point within
//! [`DEPTH_SLACK`] radii of the nearest depth in the 3 × 3 cells round its own is seen and
//! votes `n·d`. Where the views agree on a point, the vote orients it and it seeds the spanning
//! tree that orients the rest (inner folds, the backs of ears: `orient::orient_normals_from`).
//! An open surface (terrain, a sheet, a room) is seen from both sides, its votes cancel, and
//! it keeps the spanning tree's orientation alone.
//!
//! The spanning tree alone goes wrong where it crosses between facing sheets (a robe's folds);
//! the views see through no sheet and settle those points. `scripts/orientation_check.py`,
//! normals against the mesh's own: the Happy Buddha (res3) 0.86 % → 0.53 %, the dragon (res3)
//! 0.60 → 0.58 %, (res2) 0.09 → 0.09 %, the bunny 0 → 0. The settings below are each the best
//! of a sweep on those meshes (first in a Python model of this, then here).

use glam::Vec3;
use rayon::prelude::*;

/// View directions, on a Fibonacci lattice over the sphere (64: the Buddha's wrong normals
/// 175 rather than 170, the bunny's 17 rather than 0).
pub const VIEWS: usize = 128;

/// A depth-buffer cell is this many median radii wide (0.7 and 1.0: the Buddha's wrong
/// normals 199 and 197 rather than 170, the bunny's 41 and 22 rather than 0).
const CELL: f32 = 0.5;

/// A point is seen when within this many of its radii of the nearest depth round it: less
/// than a thin part's thickness, so the far side of a fold is not taken as seen (0.7 and 1.0
/// let the far side of the Buddha's robe vote with the near one: 10–30 % more wrong normals
/// in the Python model).
const DEPTH_SLACK: f32 = 0.5;

/// Cells round a point's own that may hide it: 3 × 3 cells, about a disk's width. Wider
/// windows hid more of the Buddha's folds (2 cells at 0.5 or 0.7 radii a cell: 195 and 207
/// wrong normals; 3 cells: 231; 1 cell of 0.8 radii: 198).
const REACH: usize = 1;

/// The depth buffer's side at most, in cells (a survey's extent over its point spacing would
/// be millions).
const MAX_SIDE: usize = 2048;

/// Points that vote at most: a bigger cloud votes with every n-th point (n the smallest that
/// fits), each standing for n points, √n times as wide. Its surfaces are sampled finely
/// enough for that: the dragon (res2, 100k points) has the same 89 wrong normals with every
/// 4th voting; the full dragon's 435k orient in 0.46 s (0.29 s without views).
const MAX_VOTERS: usize = 1 << 17;

/// Votes are summed in 1/1024ths, as integers: the same sums whatever the threads' order.
const FIXED_ONE: f32 = 1024.0;

/// What the views said of one point: Σ n·d and Σ |n·d| over the views that saw it, and how
/// many did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Vote {
    pub facing: i32,
    pub weight: i32,
    pub views: i32,
}

impl Vote {
    /// How far the views agree, from −1 (all saw its back) to 1 (all its front); 0 unseen.
    pub fn agreement(&self) -> f32 {
        if self.weight == 0 { 0.0 } else { self.facing as f32 / self.weight as f32 }
    }

    /// Seen squarely by about half a view at least.
    pub fn seen(&self) -> bool {
        self.weight as f32 >= 0.5 * FIXED_ONE
    }

    /// Seen, by [`SETTLED_VIEWS`] views at least that agree on its side
    /// ([`SETTLED_AGREEMENT`]): its normal is set by them.
    pub fn settles(&self) -> bool {
        self.seen() && self.views >= SETTLED_VIEWS && self.agreement().abs() >= SETTLED_AGREEMENT
    }

    /// Seen, by views three to one for one side: a normal facing the other way is doubtful.
    pub fn clearly_seen(&self) -> bool {
        self.seen() && self.agreement().abs() >= 0.5
    }
}

/// The agreement from which the views set a normal (on the Buddha 0.8, 0.9 and 0.97 gave
/// the same errors within 3 %; an open sheet's views cancel to near 0).
const SETTLED_AGREEMENT: f32 = 0.9;

/// The views that must see a point to set its normal. A single view saw the inside of the
/// Stanford bunny's shell through the holes in its base (in a Python model of this: 24
/// normals turned wrongly with one view, 4 with two, 3 with three, where two cost the Buddha
/// 2 of its corrections and three 18).
const SETTLED_VIEWS: i32 = 2;

/// Whether the views see a closed shape: most of the points they see, they settle. Closed
/// scans score 0.88–1.0 (the Stanford bunny, dragon, Buddha and scan set, the Igea); open ones
/// are seen from both sides and keep the spanning tree's orientation (the Autzen survey 0.12,
/// whose ground under the trees is seen from below only; one range scan 0.0002; the demo, two
/// shapes on an open floor, 0.34).
pub fn looks_closed(votes: &[Vote]) -> bool {
    let seen = votes.iter().filter(|v| v.seen()).count();
    let settled = votes.iter().filter(|v| v.settles()).count();
    settled as f64 >= 0.5 * seen as f64 && seen > 0
}

/// The views' depth slack is in units of the distance to this nearest neighbour (the default
/// splat radius).
pub const FOOTPRINT_K: usize = 8;

/// The votes of [`VIEWS`] views on every point's `normals` (see the module notes); `radii`
/// are the disks' radii (any positive estimate of the point spacing). Points that do not vote
/// (a big cloud's, see [`MAX_VOTERS`]) get a default (unseen) vote.
pub fn outward_votes(points: &[Vec3], normals: &[Vec3], radii: &[f32]) -> Vec<Vote> {
    votes_of_some(points, normals, radii, MAX_VOTERS)
}

/// [`outward_votes`] with at most `most` voters.
fn votes_of_some(points: &[Vec3], normals: &[Vec3], radii: &[f32], most: usize) -> Vec<Vote> {
    let n = points.len();
    if n == 0 {
        return Vec::new();
    }
    let stride = n.div_ceil(most);
    let voters: Vec<usize> = (0..n).step_by(stride).collect();
    let widen = (stride as f32).sqrt();
    let (centre, half) = bounding_sphere(points);
    let mut sorted: Vec<f32> = voters.iter().map(|&i| radii[i] * widen).collect();
    let middle = sorted.len() / 2;
    let median = *sorted.select_nth_unstable_by(middle, f32::total_cmp).1;
    let cell = (CELL * median).max(2.0 * half / (MAX_SIDE - 8) as f32).max(f32::MIN_POSITIVE);
    let grid = Grid { centre, half, cell, side: (2.0 * half / cell).ceil() as usize + 8 };
    // Each thread sums every `threads`-th view's votes apart (integers: the same sums in any
    // order); one accumulator a thread, where rayon's fold made one a split.
    let threads = rayon::current_num_threads().min(VIEWS);
    let sums = (0..threads)
        .into_par_iter()
        .map(|first| {
            let mut sums = vec![Vote::default(); voters.len()];
            for view in (first..VIEWS).step_by(threads) {
                let d = fibonacci(view, VIEWS);
                let seen = grid.seen_from(d, &voters, points, |i| radii[i] * widen);
                for ((sum, &i), _) in sums.iter_mut().zip(&voters).zip(&seen).filter(|(_, seen)| **seen) {
                    let c = normals[i].dot(d);
                    sum.facing += (c * FIXED_ONE).round() as i32;
                    sum.weight += (c.abs() * FIXED_ONE).round() as i32;
                    sum.views += 1;
                }
            }
            sums
        })
        .reduce_with(|mut a, b| {
            for (a, b) in a.iter_mut().zip(&b) {
                (a.facing, a.weight, a.views) = (a.facing + b.facing, a.weight + b.weight, a.views + b.views);
            }
            a
        })
        .expect("one thread at least");
    let mut votes = vec![Vote::default(); n];
    for (sum, &i) in sums.iter().zip(&voters) {
        votes[i] = *sum;
    }
    votes
}

/// The `i`-th of `count` directions spread evenly over the unit sphere.
fn fibonacci(i: usize, count: usize) -> Vec3 {
    let golden = std::f32::consts::PI * (1.0 + 5f32.sqrt());
    let z = 1.0 - 2.0 * (i as f32 + 0.5) / count as f32;
    let ring = (1.0 - z * z).max(0.0).sqrt();
    let phi = golden * (i as f32 + 0.5);
    Vec3::new(ring * phi.cos(), ring * phi.sin(), z)
}

/// The bounding box's centre and half its diagonal.
fn bounding_sphere(points: &[Vec3]) -> (Vec3, f32) {
    let (lo, hi) = points.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    ((lo + hi) * 0.5, (hi - lo).length() * 0.5)
}

/// A square depth buffer perpendicular to a view, big enough for the bounding sphere.
struct Grid {
    centre: Vec3,
    half: f32,
    cell: f32,
    side: usize,
}

impl Grid {
    /// Which of the `voters` are seen from direction `d` (see the module notes); `radius(i)`
    /// scales each one's depth slack.
    fn seen_from(&self, d: Vec3, voters: &[usize], points: &[Vec3], radius: impl Fn(usize) -> f32) -> Vec<bool> {
        let (a, b) = d.any_orthonormal_pair();
        let to_grid = |p: Vec3| {
            let q = p - self.centre;
            ((q.dot(a) + self.half) / self.cell + 4.0, (q.dot(b) + self.half) / self.cell + 4.0, q.dot(d))
        };
        let side = self.side;
        let cell_of = |u: f32, v: f32| u as usize * side + v as usize;
        // Each point marks its own cell; a point is then seen if nothing within `REACH` cells
        // of its own lies nearer the viewer by more than the slack, without drawing disks
        // (drawn as disks, the Buddha's figures were the same, the bunny's 15 wrong rather
        // than 0, and the dragon's votes took 4.5 times as long).
        let mut depth = vec![f32::NEG_INFINITY; side * side];
        for &i in voters {
            let (u, v, z) = to_grid(points[i]);
            let cell = &mut depth[cell_of(u, v)];
            *cell = cell.max(z);
        }
        voters
            .iter()
            .map(|&i| {
                let (u, v, z) = to_grid(points[i]);
                let centre = cell_of(u, v);
                let reach = REACH as isize;
                let nearest = (-reach..=reach)
                    .flat_map(|du| (-reach..=reach).map(move |dv| (centre as isize + du * side as isize + dv) as usize))
                    .fold(f32::NEG_INFINITY, |m, c| m.max(depth[c]));
                z >= nearest - DEPTH_SLACK * radius(i)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sphere of `n` points with outward normals.
    fn sphere(n: usize) -> (Vec<Vec3>, Vec<Vec3>) {
        let points: Vec<Vec3> = (0..n).map(|i| fibonacci(i, n)).collect();
        (points.clone(), points)
    }

    #[test]
    fn the_views_see_a_sphere_from_outside_and_say_which_normals_point_in() {
        let (points, mut normals) = sphere(4000);
        for n in normals.iter_mut().step_by(3) {
            *n = -*n;
        }
        let radii = vec![0.06; points.len()];
        let votes = outward_votes(&points, &normals, &radii);
        for (i, vote) in votes.iter().enumerate() {
            assert!(vote.seen(), "{i}: {vote:?}");
            let expected = if i % 3 == 0 { -1.0 } else { 1.0 };
            assert!(vote.agreement() * expected > 0.99, "{i}: {vote:?}");
        }
    }

    #[test]
    fn the_inner_of_two_nested_spheres_is_hidden_and_a_sheet_is_seen_from_both_sides() {
        let (outer, _) = sphere(4000);
        let inner: Vec<Vec3> = outer.iter().map(|p| *p * 0.5).collect();
        let points: Vec<Vec3> = outer.iter().chain(&inner).copied().collect();
        let normals = points.clone();
        let votes = outward_votes(&points, &normals, &vec![0.06; points.len()]);
        assert!(votes[4000..].iter().all(|v| *v == Vote::default()), "the inner sphere was seen");
        // A flat square sheet: its votes from above and below cancel.
        let sheet: Vec<Vec3> =
            (0..60 * 60).map(|i| Vec3::new((i % 60) as f32 / 60.0, (i / 60) as f32 / 60.0, 0.0)).collect();
        let votes = outward_votes(&sheet, &vec![Vec3::Z; sheet.len()], &vec![0.03; sheet.len()]);
        for (i, v) in votes.iter().enumerate() {
            assert!(v.seen() && !v.settles(), "{i}: {v:?}");
        }
    }

    #[test]
    fn a_big_cloud_votes_with_every_nth_point_and_the_sums_do_not_depend_on_the_threads() {
        let n = 4010;
        let points: Vec<Vec3> = (0..n).map(|i| fibonacci(i, n)).collect();
        let radii = vec![0.09; n];
        let votes = votes_of_some(&points, &points, &radii, 2000);
        assert!(votes.iter().step_by(3).all(|v| v.seen() && v.agreement() > 0.99));
        assert!(votes[1] == Vote::default() && votes[2] == Vote::default());
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        assert_eq!(one.install(|| votes_of_some(&points, &points, &radii, 2000)), votes);
    }
}
