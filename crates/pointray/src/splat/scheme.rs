//! Surface schemes: how the disks a ray crosses become one surface hit.
//!
//! * [`SurfaceKind::FirstHit`]: the nearest disk, with its own normal and colour (flat
//!   shaded disks, like Embree's oriented-disc points; for like-for-like comparisons).
//! * [`SurfaceKind::Sj`]: Schaufler & Jensen (2000): after the first hit at t₀, every disk the
//!   ray crosses within `[t₀, t₀ + δ]` is collected and position, normal and colour are
//!   blended with weights wᵢ = rᵢ − dᵢ, dᵢ being the in-plane distance of the crossing from the
//!   disk's centre. This is SJ's Eq. 1. The thesis's Eq. 2.6 as printed weights by dᵢ itself,
//!   which would favour the disks crossed farthest from their centres; RECONSTRUCTION.md (A2)
//!   records that discrepancy and we follow SJ deliberately.
//!
//! δ = `window × r₀` (r₀ the first disk's radius): disks of one smooth surface cross the ray
//! within a fraction of r of each other, while a surface behind it is farther away. Only disks
//! facing the same way as the first one are blended, so the back side of a thin part (closer
//! than δ) never leaks into the front.
//!
//! A window must also be *covered*: Σ(1 − dᵢ/rᵢ) ≥ `min_coverage`. A lone disk crossed near its
//! rim, sticking out past an edge or a silhouette, otherwise shows as a speck with a normal
//! from elsewhere; a weakly covered window is skipped and the ray goes on behind it.

use glam::Vec3;

use super::{Splat, oriented_disk};
use crate::accel::{Accel, SplatVisitor, TraversalStats};
use crate::math::Ray;

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SurfaceKind {
    Sj,
    FirstHit,
}

impl SurfaceKind {
    pub fn name(self) -> &'static str {
        match self {
            SurfaceKind::Sj => "sj",
            SurfaceKind::FirstHit => "first-hit",
        }
    }
}

/// The surface scheme with its parameters.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct SurfaceScheme {
    pub kind: SurfaceKind,
    /// SJ window δ in units of the first disk's radius.
    pub window: f32,
    /// SJ: least coverage Σ(1 − dᵢ/rᵢ) a window must have to count as surface. On a covered
    /// surface about eight disks overlap a point and the sum is near 2.5; a lone disk crossed at
    /// its rim, sticking out past an edge or a silhouette, scores near 0, and the ray goes on
    /// behind it.
    pub min_coverage: f32,
}

impl SurfaceScheme {
    pub fn sj() -> Self {
        Self { kind: SurfaceKind::Sj, window: 1.0, min_coverage: 0.15 }
    }

    pub fn first_hit() -> Self {
        Self { kind: SurfaceKind::FirstHit, window: 0.0, min_coverage: 0.0 }
    }

    pub fn of_kind(kind: SurfaceKind) -> Self {
        match kind {
            SurfaceKind::Sj => Self::sj(),
            SurfaceKind::FirstHit => Self::first_hit(),
        }
    }
}

/// A ray's meeting with the surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceHit {
    pub t: f32,
    pub position: Vec3,
    /// Unit shading normal, turned to face the ray's origin (splats are two-sided).
    pub normal: Vec3,
    /// Linear RGB colour (albedo).
    pub color: [f32; 3],
    /// Radius of the nearest disk: the local sampling scale, used for self-intersection offsets.
    pub radius: f32,
    /// Index of the nearest disk, as [`Accel::splat`] takes it (a level-of-detail
    /// representative when `≥ accel.splats().len()`).
    pub splat: u32,
    /// Number of disks blended (1 for first-hit).
    pub blended: u32,
}

/// Closest hit along `ray` with the given scheme.
pub fn intersect<A: Accel + ?Sized>(
    accel: &A,
    ray: &Ray,
    scheme: &SurfaceScheme,
    stats: &mut TraversalStats,
) -> Option<SurfaceHit> {
    match scheme.kind {
        SurfaceKind::FirstHit => {
            let mut v = Nearest { t_max: f32::INFINITY, best: None, best_key: [0; 8] };
            accel.traverse(ray, &mut v, stats);
            let (t, i) = v.best?;
            let s = accel.splat(i);
            Some(SurfaceHit {
                t,
                position: ray.at(t),
                normal: facing(s.normal, ray.dir),
                color: s.color_linear(),
                radius: s.radius,
                splat: i,
                blended: 1,
            })
        }
        SurfaceKind::Sj => {
            let mut ray = *ray;
            let mut weak = None;
            for _ in 0..MAX_WEAK_WINDOWS {
                let mut v = SjWindow::new(scheme.window, A::REPEATS_SPLATS);
                accel.traverse(&ray, &mut v, stats);
                if v.grew {
                    // Crossings beyond an earlier, shorter end were turned away: collect the
                    // final window again, now that its extent is known.
                    v = SjWindow::fixed(scheme.window, A::REPEATS_SPLATS, v.end);
                    accel.traverse(&ray, &mut v, stats);
                }
                // Nothing behind a weak window: it was the surface after all (a thinly covered
                // spot), not a disk sticking out in front of one.
                let Some((hit, coverage)) = v.blend(&ray, accel) else { return weak };
                if coverage >= scheme.min_coverage {
                    return Some(hit);
                }
                weak.get_or_insert(hit);
                ray.t_min = v.end;
            }
            // Weak windows all the way: keep the first rather than open a hole.
            weak
        }
    }
}

/// Most windows an SJ ray skips as too weakly covered before it settles for one.
const MAX_WEAK_WINDOWS: usize = 4;

/// Whether anything lies on `ray` before `t_max` (shadow rays). Any disk counts: a blocker
/// needs no interpolation.
pub fn occluded<A: Accel + ?Sized>(accel: &A, ray: &Ray, t_max: f32, stats: &mut TraversalStats) -> bool {
    let mut v = AnyHit { t_max, hit: false };
    accel.traverse(ray, &mut v, stats);
    v.hit
}

fn facing(n: Vec3, dir: Vec3) -> Vec3 {
    if n.dot(dir) > 0.0 { -n } else { n }
}

/// Total order on splats by their contents, to break exact ties in `t` the same way whatever
/// order an accelerator visits them in (coincident duplicates occur in real scans).
fn tie_key(s: &Splat) -> [u32; 8] {
    let (c, n) = (s.center, s.normal);
    let b = f32::to_bits;
    [b(c.x), b(c.y), b(c.z), b(s.radius), b(n.x), b(n.y), b(n.z), s.color]
}

struct Nearest {
    t_max: f32,
    best: Option<(f32, u32)>,
    best_key: [u32; 8],
}

impl SplatVisitor for Nearest {
    fn t_max(&self) -> f32 {
        self.t_max
    }

    #[inline(always)]
    fn visit(&mut self, ray: &Ray, splat: &Splat, index: u32) {
        let Some(h) = oriented_disk::intersect(ray, splat, self.t_max) else { return };
        let better = match self.best {
            Some((t, _)) => h.t < t || (h.t == t && tie_key(splat) < self.best_key),
            None => true,
        };
        if better {
            self.t_max = h.t;
            self.best = Some((h.t, index));
            self.best_key = tie_key(splat);
        }
    }
}

struct AnyHit {
    t_max: f32,
    hit: bool,
}

impl SplatVisitor for AnyHit {
    fn t_max(&self) -> f32 {
        self.t_max
    }

    #[inline(always)]
    fn visit(&mut self, ray: &Ray, splat: &Splat, _index: u32) {
        if oriented_disk::intersect(ray, splat, self.t_max).is_some() {
            self.hit = true;
        }
    }

    fn done(&self) -> bool {
        self.hit
    }
}

/// Most disks a window holds; on a smooth surface a ray crosses a handful (about the mean
/// overlap, πr²·density). Past the cap the farthest crossing is dropped; only then can the
/// order in which disks arrive matter (with more than this many crossings, ties for last).
const WINDOW_CAPACITY: usize = 24;

#[derive(Clone, Copy, Default)]
struct Crossing {
    t: f32,
    dist2: f32,
    index: u32,
}

/// Collects the disks crossed within `[t₀, t₀ + δ]` of the nearest crossing t₀ found so far.
/// The accelerator culls against `t_max() = t₀ + δ`, so it keeps delivering every disk that
/// may still belong to the window, and the window shrinks as nearer crossings turn up.
struct SjWindow {
    window: f32,
    end: f32,
    /// Nearest crossing so far (the window's start).
    first_t: f32,
    /// The end is known in advance and never moves (a second pass).
    fixed: bool,
    /// The end moved outwards during the walk (a tie at the first crossing with a wider disk,
    /// or a nearer first crossing with a wider disk): crossings may have been turned away
    /// against the shorter end, so the window must be collected again.
    grew: bool,
    /// The accelerator may hand a splat over again (`Accel::REPEATS_SPLATS`): repeats are
    /// looked for and ignored.
    repeats: bool,
    len: usize,
    crossings: [Crossing; WINDOW_CAPACITY],
}

impl SjWindow {
    fn new(window: f32, repeats: bool) -> Self {
        Self {
            window,
            end: f32::INFINITY,
            first_t: f32::INFINITY,
            fixed: false,
            grew: false,
            repeats,
            len: 0,
            crossings: [Crossing::default(); WINDOW_CAPACITY],
        }
    }

    /// A window that collects every crossing up to `end`.
    fn fixed(window: f32, repeats: bool, end: f32) -> Self {
        Self { end, fixed: true, ..Self::new(window, repeats) }
    }

    /// The blended hit and the window's coverage Σ(1 − dᵢ/rᵢ) over the blended disks.
    fn blend<A: Accel + ?Sized>(&mut self, ray: &Ray, accel: &A) -> Option<(SurfaceHit, f32)> {
        let list = &mut self.crossings[..self.len];
        // Sum in a fixed order (by t, then by splat contents) so that every accelerator, which
        // visits disks in its own order, blends to the same bits.
        list.sort_unstable_by(|a, b| {
            a.t.total_cmp(&b.t).then_with(|| tie_key(accel.splat(a.index)).cmp(&tie_key(accel.splat(b.index))))
        });
        let first = *list.first()?;
        let first_splat = accel.splat(first.index);
        // Blend the disks facing the same way as the first: the back of a thin part may lie
        // within the window.
        let side = first_splat.normal.dot(ray.dir) > 0.0;
        let (mut wsum, mut t, mut n, mut c) = (0.0f32, 0.0f32, Vec3::ZERO, Vec3::ZERO);
        let mut blended = 0;
        let mut coverage = 0.0;
        for x in list.iter() {
            let s = accel.splat(x.index);
            if (s.normal.dot(ray.dir) > 0.0) != side {
                continue;
            }
            // SJ Eq. 1: wᵢ = rᵢ − dᵢ. Positive for every accepted crossing (dᵢ < rᵢ).
            let w = s.radius - x.dist2.sqrt();
            coverage += w / s.radius;
            wsum += w;
            t += w * x.t;
            n += w * s.normal;
            c += w * Vec3::from(s.color_linear());
            blended += 1;
        }
        let (t, n, c) = if wsum > 0.0 && n.length_squared() > 0.0 {
            (t / wsum, n.normalize(), c / wsum)
        } else {
            // Crossings exactly on the rims carry no weight: fall back to the first disk.
            (first.t, first_splat.normal, Vec3::from(first_splat.color_linear()))
        };
        let hit = SurfaceHit {
            t,
            position: ray.at(t),
            normal: facing(n, ray.dir),
            color: c.to_array(),
            radius: first_splat.radius,
            splat: first.index,
            blended: blended.max(1),
        };
        Some((hit, coverage))
    }
}

impl SplatVisitor for SjWindow {
    fn t_max(&self) -> f32 {
        self.end
    }

    #[inline]
    fn visit(&mut self, ray: &Ray, splat: &Splat, index: u32) {
        let Some(h) = oriented_disk::intersect(ray, splat, self.end) else { return };
        let first_t = self.first_t;
        if !self.fixed && h.t <= first_t {
            self.first_t = h.t;
            // The window reaches `window` radii past the first crossing; of disks tied for
            // first, the widest decides, whatever order they arrive in.
            let end = h.t + self.window * splat.radius;
            let end = if h.t == first_t { end.max(self.end) } else { end };
            if end > self.end {
                self.grew |= self.end.is_finite();
            } else {
                let mut kept = 0;
                for i in 0..self.len {
                    if self.crossings[i].t <= end {
                        self.crossings[kept] = self.crossings[i];
                        kept += 1;
                    }
                }
                self.len = kept;
            }
            self.end = end;
        }
        // A kd-tree hands a disk that straddles cells over once per cell. (The window's start
        // and end above are the same for a repeat.)
        if self.repeats && self.crossings[..self.len].iter().any(|c| c.index == index) {
            return;
        }
        let c = Crossing { t: h.t, dist2: h.dist2, index };
        if self.len < WINDOW_CAPACITY {
            self.crossings[self.len] = c;
            self.len += 1;
        } else if let Some(far) = self.crossings.iter_mut().max_by(|a, b| a.t.total_cmp(&b.t))
            && c.t < far.t
        {
            *far = c;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::BruteForce;
    use crate::math::RayCone;

    /// A densely covered plane z = 0 and one disk floating at z = 0.5 in front of it.
    fn plane_and_lone_disk() -> BruteForce {
        let mut splats = Vec::new();
        for i in -20..=20 {
            for j in -20..=20 {
                let center = Vec3::new(i as f32 * 0.05, j as f32 * 0.05, 0.0);
                splats.push(Splat { center, radius: 0.1, normal: Vec3::Z, color: 0 });
            }
        }
        splats.push(Splat { center: Vec3::new(0.0, 0.0, 0.5), radius: 0.2, normal: Vec3::Z, color: 0 });
        BruteForce::new(splats)
    }

    fn hit_z(accel: &BruteForce, x: f32, scheme: SurfaceScheme) -> f32 {
        let ray = Ray::new(Vec3::new(x, 0.0, 3.0), -Vec3::Z, RayCone::default());
        intersect(accel, &ray, &scheme, &mut TraversalStats::default()).unwrap().position.z
    }

    /// Three disks on one ray in every order: the window and the blend must not depend on the
    /// order (the BVH and brute force visit disks in different orders).
    #[test]
    fn sj_window_does_not_depend_on_visiting_order() {
        let disk = |z: f32, r: f32| Splat { center: Vec3::new(0.0, 0.0, z), radius: r, normal: Vec3::Z, color: 0 };
        // The nearest disk (z = 1.05) is wide, so its window reaches the disk at z = 0.5,
        // which a narrow disk found first (z = 1) would have cut off. And a tie at z = 1.05.
        let cases = [
            vec![disk(1.0, 0.1), disk(0.5, 0.3), disk(1.05, 1.0)],
            vec![disk(1.05, 0.1), disk(0.5, 0.3), disk(1.05, 1.0)],
        ];
        let ray = Ray::new(Vec3::new(0.01, 0.0, 10.0), -Vec3::Z, RayCone::default());
        let scheme = SurfaceScheme { min_coverage: 0.0, ..SurfaceScheme::sj() };
        for splats in cases {
            let mut results = Vec::new();
            for order in [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]] {
                let accel = BruteForce::new(order.iter().map(|&i| splats[i]).collect());
                let hit = intersect(&accel, &ray, &scheme, &mut TraversalStats::default()).unwrap();
                results.push((hit.t.to_bits(), hit.blended));
            }
            assert_eq!(results[0].1, 3, "the wide first disk's window holds all three");
            assert!(results.iter().all(|r| *r == results[0]), "{results:?}");
        }
    }

    #[test]
    fn sj_skips_a_lone_disk_crossed_at_its_rim_but_keeps_one_crossed_centrally() {
        let accel = plane_and_lone_disk();
        // Crossed at d/r = 0.95: coverage 0.05, below the threshold.
        assert!((hit_z(&accel, 0.19, SurfaceScheme::first_hit()) - 0.5).abs() < 1e-5);
        assert!(hit_z(&accel, 0.19, SurfaceScheme::sj()).abs() < 1e-5);
        // Crossed at d/r = 0.25: a surface, even alone.
        assert!((hit_z(&accel, 0.05, SurfaceScheme::sj()) - 0.5).abs() < 1e-5);
        // With no threshold SJ keeps the rim hit.
        let lax = SurfaceScheme { min_coverage: 0.0, ..SurfaceScheme::sj() };
        assert!((hit_z(&accel, 0.19, lax) - 0.5).abs() < 1e-5);
    }
}
