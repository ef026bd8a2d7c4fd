//! The interpolation window of Schaufler & Jensen (2000), over oriented disks (`sj`) or
//! ray-facing disks (`rfd`): after the first crossing at t₀, every disk the ray crosses within
//! `[t₀, t₀ + δ]` is collected, and position, normal and colour are blended with weights
//! wᵢ = rᵢ − dᵢ (SJ's Eq. 1), dᵢ being the crossing's distance from the disk's centre: in the
//! disk's plane for an oriented disk, perpendicular to the ray for a ray-facing one.

use std::marker::PhantomData;

use arrayvec::ArrayVec;
use glam::{Vec3, Vec3A, Vec4};

use super::scheme::{SurfaceHit, facing, tie_key};
use super::{DiskShape, DiskTest, color_linear_in};
use crate::accel::{Accel, Crossing, SplatVisitor};
use crate::color::srgb8_to_linear_table;
use crate::math::Ray;

/// Most disks a window holds; on a smooth surface a ray crosses a handful (about the mean
/// overlap, πr²·density). Past the cap the farthest crossing is dropped; only then can the
/// order in which disks arrive matter (with more than this many crossings, ties for last).
const WINDOW_CAPACITY: usize = 24;

/// Collects the disks (of shape `D`) crossed within `[t₀, t₀ + δ]` of the nearest crossing t₀
/// found so far. The accelerator culls against `t_max() = collect_to` (at least t₀ + δ), so it
/// keeps delivering every disk that may still belong to the window, and the window shrinks as
/// nearer crossings turn up.
pub(crate) struct Window<D> {
    window: f32,
    /// The window's end: `window` radii of the first crossing past it.
    pub(crate) end: f32,
    /// How far crossings are collected (`t_max`): at least `end`, and at least `window` times
    /// `wide_radius` past the first crossing, so that a nearer first crossing found later,
    /// with a disk up to that wide, finds its window collected already.
    collect_to: f32,
    wide_radius: f32,
    /// The least `collect_to` so far: every crossing up to it has been collected.
    collected_to: f32,
    /// Nearest crossing so far (the window's start).
    pub(crate) first_t: f32,
    /// The end is final (the completing walk, see [`Self::start_completion`]).
    fixed: bool,
    /// The end moved past `collect_to` during the walk (a nearer first crossing with a disk
    /// wider than `wide_radius`, or a tie at the first crossing with one): crossings may have
    /// been turned away, so the window must be completed.
    pub(crate) grew: bool,
    /// The accelerator may hand a splat over again (`Accel::REPEATS_SPLATS`): repeats are
    /// looked for and ignored.
    repeats: bool,
    /// Kept in order of `t` as they arrive (crossings of equal `t` in arrival order, put in
    /// a fixed order by `blend`), so that pruning is a truncation and blending needs no sort:
    /// on the dragon this, the list's uninitialised storage and `hit` and the colour lookup
    /// inlined took SJ from 1,491 to 1,337 instructions a pixel (callgrind, 512²).
    crossings: ArrayVec<Crossing, WINDOW_CAPACITY>,
    /// Two crossings of equal `t` have been next to each other in the list (noted as they are
    /// inserted, the only time two become neighbours): only then does `blend` sort.
    ties: bool,
    disk: PhantomData<D>,
}

impl<D: DiskTest> Window<D> {
    pub(crate) fn new(window: f32, wide_radius: f32, repeats: bool) -> Self {
        Self {
            window,
            end: f32::INFINITY,
            collect_to: f32::INFINITY,
            wide_radius,
            collected_to: f32::INFINITY,
            first_t: f32::INFINITY,
            fixed: false,
            grew: false,
            repeats,
            crossings: ArrayVec::new(),
            ties: false,
            disk: PhantomData,
        }
    }

    /// Collects no crossing past `t` (before any has come): only a window that starts by then is
    /// wanted (it is still collected whole, past `t`, as a window that grew is).
    pub(crate) fn limit(&mut self, t: f32) {
        (self.collect_to, self.collected_to) = (t, t);
    }

    /// After a walk in which the window grew: fixes the window's end and returns the distance
    /// up to which every crossing is collected already. A second walk from there (the rest of
    /// the window, usually a short stretch) completes it; a crossing the first walk collected
    /// too is recognised and not taken twice.
    pub(crate) fn start_completion(&mut self) -> f32 {
        (self.fixed, self.repeats, self.collect_to) = (true, true, self.end);
        self.collected_to
    }

    /// Drops the crossings beyond `t`.
    fn keep_until(&mut self, t: f32) {
        let kept = self.crossings.iter().rposition(|c| c.t <= t).map_or(0, |i| i + 1);
        self.crossings.truncate(kept);
    }

    /// Inserts `c` after the crossings of no greater `t`; when the window is full, the
    /// farthest crossing makes room (or `c` is dropped, if it is the farthest).
    ///
    /// Out of line: inlined, it made the traversal's SJ instance a sixth larger and its cost
    /// moved with unrelated code (the dragon's SJ took 1,003 or 1,049 instructions a pixel as
    /// other crates changed). Out of line, 1,024 where inlined took 1,049, and the bunny 1,033
    /// where it took 1,060 (callgrind, `scripts/instructions_per_ray.py --size 256`).
    #[inline(never)]
    fn insert(&mut self, c: Crossing) {
        // Crossings in order are a push. Only about a quarter arrive so on the dragon (leaves
        // overlap), but shifting the others in costs less than sorting at the end did: SJ took
        // 1,380 instructions a pixel with the list sorted by `blend`, 1,322 so, and 1,335 with
        // the push folded into the shifting path below (callgrind).
        // A tie with the last, noted apart from the test below: as one read of the last `t`
        // for both, SJ took 12 instructions a pixel more (callgrind).
        if let Some(last) = self.crossings.last() {
            self.ties |= last.t == c.t;
        }
        if self.crossings.last().is_none_or(|last| last.t <= c.t) {
            if !self.crossings.is_full() {
                self.crossings.push(c);
            }
            return;
        }
        if self.crossings.is_full() {
            self.crossings.pop();
        }
        // Shift the later crossings up by one, as an insertion sort does.
        self.crossings.push(c);
        let list = &mut self.crossings[..];
        let mut i = list.len() - 1;
        while i > 0 && list[i - 1].t > c.t {
            list[i] = list[i - 1];
            i -= 1;
        }
        list[i] = c;
        self.ties |= i > 0 && list[i - 1].t == c.t;
    }

    /// The blended window (see [`Blend`]). With `tangent_planes`, each crossing's distance is
    /// moved onto its splat's tangent plane first (for ray-facing disks, whose crossings lie at
    /// the centres' projections). Always inlined into its one caller: out of line it cost the
    /// dragon's SJ 17 instructions a pixel (callgrind), as the render loop's crate changed.
    #[inline(always)]
    pub(crate) fn blend<A: Accel + ?Sized>(&mut self, ray: &Ray, accel: &A, tangent_planes: bool) -> Option<Blend> {
        // Crossings past the end were collected in case the window grew.
        self.keep_until(self.end);
        let list = &mut self.crossings[..];
        // Sum in a fixed order (by t, then by splat contents) so that every accelerator, which
        // visits disks in its own order, blends to the same bits. The list is in order of t
        // already; crossings of equal t are put in order of their splats. (A tie since dropped
        // leaves the order as it is.)
        if self.ties {
            list.sort_by(|a, b| {
                a.t.total_cmp(&b.t).then_with(|| tie_key(&accel.splat(a.splat)).cmp(&tie_key(&accel.splat(b.splat))))
            });
        }
        // Blend the disks facing the same way, and of one material: the back of a thin part may
        // lie within the window, and so may another cloud where two touch. The side facing the
        // viewer, if any disk does (the first such, and its material): at a silhouette the
        // window can begin with a far-side disk sticking out past the rim, whose normal points
        // away from the light. (Blending the first disk's side, the default renders had 80
        // dark speckles on the Happy Buddha, 20 on the bunny, 4 on Igea; so, 17, 7, 0, with
        // `min_coverage_facing_away` at 1 and before the thin-spot rule of `scheme::windowed`.)
        let away = |x: &Crossing| x.normal.dot(ray.dir) > 0.0;
        let lead = list.iter().position(|x| !away(x)).unwrap_or(0);
        let first = *list.get(lead)?;
        let side = away(&first);
        let material = first.material();
        let sums = if tangent_planes {
            blend_sums::<A, true>(list, accel, ray, side, material)
        } else {
            blend_sums::<A, false>(list, accel, ray, side, material)
        };
        let Sums { wsum, t, n, c, coverage, blended } = sums;
        let (n, c) = (Vec3::from(n), Vec3::from(c));
        let (t, n, c) = if wsum > 0.0 && n.length_squared() > 0.0 {
            // The colour and t divided in one vector instruction (each lane as `c / wsum`
            // and `t / wsum` divide it): a hit's chain of divisions is what it waits on.
            let [cx, cy, cz, t] = (Vec4::from((c, t)) / wsum).to_array();
            (t, n.normalize(), Vec3::new(cx, cy, cz))
        } else {
            // Crossings exactly on the rims carry no weight: fall back to the first disk.
            (first.t, first.normal, Vec3::from(color_linear_in(first.color, srgb8_to_linear_table())))
        };
        let hit = SurfaceHit {
            t,
            position: ray.at(t),
            normal: facing(n, ray.dir),
            color: c.to_array(),
            radius: first.radius,
            splat: first.splat,
            blended: blended.max(1),
        };
        Some(Blend { hit, coverage, facing_away: side })
    }
}

/// A window blended: the hit, the coverage Σ(1 − dᵢ/rᵢ) over the blended disks, and whether
/// they face away from the ray's origin (their oriented normals along the ray).
pub(crate) struct Blend {
    pub(crate) hit: SurfaceHit,
    pub(crate) coverage: f32,
    pub(crate) facing_away: bool,
}

/// The weighted sums of a window's crossings that face `side` and are of `material`.
struct Sums {
    wsum: f32,
    t: f32,
    n: Vec3A,
    c: Vec3A,
    coverage: f32,
    blended: u32,
}

/// The sums of [`Window::blend`], compiled once with and once without the tangent planes (only
/// they fetch a splat, for its centre), with the colour table fetched once, and the normal and
/// colour sums in SIMD lanes (the same sums, lane by lane). Eight crossings at a time, their
/// terms gathered into lanes and summed lane by lane, took 1,148 instructions a pixel where this
/// loop took 1,092 (callgrind on the dragon, SJ): with eight crossings a hit, the gathering
/// costs what the loop does.
#[inline(always)]
fn blend_sums<A: Accel + ?Sized, const TANGENT_PLANES: bool>(
    list: &[Crossing],
    accel: &A,
    ray: &Ray,
    side: bool,
    material: u8,
) -> Sums {
    let table = srgb8_to_linear_table();
    let mut sums = Sums { wsum: 0.0, t: 0.0, n: Vec3A::ZERO, c: Vec3A::ZERO, coverage: 0.0, blended: 0 };
    for x in list {
        if (x.normal.dot(ray.dir) > 0.0) != side || x.material() != material {
            continue;
        }
        // SJ Eq. 1: wᵢ = rᵢ − dᵢ. Positive for every accepted crossing (dᵢ < rᵢ).
        let w = x.radius - x.dist2.sqrt();
        sums.coverage += w / x.radius;
        sums.wsum += w;
        sums.t +=
            w * if TANGENT_PLANES { on_tangent_plane(ray, accel.splat(x.splat).center, x.normal, x.t) } else { x.t };
        sums.n += w * Vec3A::from(x.normal);
        sums.c += w * Vec3A::from(color_linear_in(x.color, table));
        sums.blended += 1;
    }
    sums
}

/// Where the ray crosses the splat's tangent plane (within r/|cos| of `t`, the crossing of its
/// ray-facing disk), not before `ray.t_min`; `t` itself where the plane is seen nearly edge-on
/// and the crossing would run off.
fn on_tangent_plane(ray: &Ray, center: Vec3, normal: Vec3, t: f32) -> f32 {
    const MIN_COS: f32 = 0.05;
    let den = ray.dir.dot(normal);
    if den.abs() < MIN_COS {
        return t;
    }
    ((center - ray.origin).dot(normal) / den).max(ray.t_min)
}

impl<D: DiskTest> SplatVisitor for Window<D> {
    const SHAPE: DiskShape = D::SHAPE;

    fn t_max(&self) -> f32 {
        self.collect_to
    }

    #[inline(always)]
    fn hit(&mut self, _ray: &Ray, h: Crossing) {
        let first_t = self.first_t;
        if !self.fixed && h.t <= first_t {
            self.first_t = h.t;
            // The window reaches `window` radii past the first crossing; of disks tied for
            // first, the widest decides, whatever order they arrive in.
            let end = h.t + self.window * h.radius;
            let end = if h.t == first_t { end.max(self.end) } else { end };
            // Crossings past `collect_to` so far were turned away.
            self.grew |= end > self.collect_to;
            let collect_to = end.max(h.t + self.window * self.wide_radius);
            if collect_to < self.collect_to {
                self.keep_until(collect_to);
            }
            self.end = end;
            self.collect_to = collect_to;
            self.collected_to = self.collected_to.min(collect_to);
        }
        // A kd-tree hands a disk that straddles cells over once per cell. (The window's start
        // and end above are the same for a repeat.)
        if self.repeats && self.crossings.iter().any(|c| c.splat == h.splat) {
            return;
        }
        self.insert(h);
    }
}
