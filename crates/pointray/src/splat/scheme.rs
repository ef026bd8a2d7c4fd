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
//! * [`SurfaceKind::Rfd`]: the thesis's ray-facing disks (RECONSTRUCTION A10) in the same
//!   window: a splat is met where the ray passes closest to its centre, within its radius;
//!   dᵢ is that distance. The position comes from the splats' tangent planes (or, with
//!   `tangent_planes` off, from the crossings themselves; `docs/surfaces.md` compares them).
//! * [`SurfaceKind::Pss`]: the moving least-squares surface of Adamson & Alexa (2003),
//!   reached by projection steps from the SJ hit ([`super::pss`]).
//!
//! δ = `window × r₀` (r₀ the first disk's radius): disks of one smooth surface cross the ray
//! within a fraction of r of each other, while a surface behind it is farther away. Only disks
//! facing the same way as the first one are blended, so the back side of a thin part (closer
//! than δ) never leaks into the front.
//!
//! A window must also be *covered*: Σ(1 − dᵢ/rᵢ) ≥ `min_coverage`. A lone disk crossed near its
//! rim, sticking out past an edge or a silhouette, otherwise shows as a speck with a normal
//! from elsewhere; a weakly covered window is skipped and the ray goes on behind it (where no
//! covered one follows, the best covered weak window facing the viewer is the surface). A window
//! whose disks face away from the viewer must be covered more (`min_coverage_facing_away`),
//! and gives way to a covered window facing the viewer close behind it (`OVERHANG`): seen from
//! outside, a closed surface faces the viewer where a ray first meets it.

use glam::Vec3;

use super::window::{Blend, Window};
use super::{DiskShape, DiskTest, Oriented, RayFacing, Splat, pss};
use crate::accel::{Accel, Crossing, SplatVisitor, TraversalStats};
use crate::math::Ray;

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum SurfaceKind {
    Sj,
    Rfd,
    Pss,
    FirstHit,
}

impl SurfaceKind {
    pub fn name(self) -> &'static str {
        match self {
            SurfaceKind::Sj => "sj",
            SurfaceKind::Rfd => "rfd",
            SurfaceKind::Pss => "pss",
            SurfaceKind::FirstHit => "first-hit",
        }
    }

    /// The disks the scheme's rays test: the accelerator's bounds must hold them.
    pub fn shape(self) -> DiskShape {
        match self {
            SurfaceKind::Rfd => DiskShape::RayFacing,
            SurfaceKind::Sj | SurfaceKind::Pss | SurfaceKind::FirstHit => DiskShape::Oriented,
        }
    }
}

/// The surface scheme with its parameters.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct SurfaceScheme {
    pub kind: SurfaceKind,
    /// SJ and RFD window δ in units of the first disk's radius.
    pub window: f32,
    /// SJ and RFD: least coverage Σ(1 − dᵢ/rᵢ) a window must have to count as surface. On a
    /// covered surface about eight disks overlap a point and the sum is near 2.5; a lone disk
    /// crossed at its rim, sticking out past an edge or a silhouette, scores near 0, and the
    /// ray goes on behind it.
    pub min_coverage: f32,
    /// SJ and RFD: the same for a window whose disks all face away from the ray's origin
    /// (their normals, which point out of the shape, along the ray). Seen from outside, a
    /// closed surface shows such a window only past a silhouette, where a disk of the far side
    /// sticks out beyond the rim, or through a gap in the near side; both show as dark specks
    /// (the normal, turned to the viewer, points away from the light) and cover little. With
    /// 1.0 rather than `min_coverage` (0.15), the default renders' dark speckles
    /// (`scripts/speckle_check.py`, 1024², before the thin-spot rule of `windowed`): the dragon
    /// 26 → 19, the bunny 19 → 7, the Happy Buddha 27 → 17, Igea 13 → 0, the Armadillo 48 → 28
    /// (2.0 took them lower still, but a wall of a closed room seen from inside faces away too,
    /// covered only about 2.5). A thin part seen from behind shows its own near side, which
    /// faces the viewer. A third case is often well covered: a crest's far side sticking out
    /// over its near side, which a covered window facing the viewer just behind it shows
    /// (`OVERHANG`).
    pub min_coverage_facing_away: f32,
    /// RFD: blend the crossings' distances moved onto each splat's tangent plane, rather than
    /// the distances of the centres' projections.
    pub tangent_planes: bool,
    /// PSS: the projection's settings.
    pub pss: pss::PssParams,
}

impl SurfaceScheme {
    pub fn sj() -> Self {
        Self {
            kind: SurfaceKind::Sj,
            window: 1.0,
            min_coverage: 0.15,
            min_coverage_facing_away: 1.0,
            tangent_planes: false,
            pss: pss::PssParams::standard(),
        }
    }

    /// RFD with a window of 2 r: the centres of one surface's splats project onto the ray up
    /// to about r before and after where it crosses the surface, so a window of r holds only the
    /// near half of them and tilts the normal (sphere: mean normal error 0.77° at r, 0.37° at 2 r,
    /// 0.26° at 3 r; SJ 0.24°). Positions from the tangent planes: 0.02 spacings off the sphere
    /// against 0.64 from the projections themselves (`tests/it/surfaces.rs`).
    pub fn rfd() -> Self {
        Self { kind: SurfaceKind::Rfd, window: 2.0, tangent_planes: true, ..Self::sj() }
    }

    pub fn pss() -> Self {
        Self { kind: SurfaceKind::Pss, ..Self::sj() }
    }

    pub fn first_hit() -> Self {
        Self {
            kind: SurfaceKind::FirstHit,
            window: 0.0,
            min_coverage: 0.0,
            min_coverage_facing_away: 0.0,
            ..Self::sj()
        }
    }

    pub fn of_kind(kind: SurfaceKind) -> Self {
        match kind {
            SurfaceKind::Sj => Self::sj(),
            SurfaceKind::Rfd => Self::rfd(),
            SurfaceKind::Pss => Self::pss(),
            SurfaceKind::FirstHit => Self::first_hit(),
        }
    }

    /// Secondary and shadow rays from a hit start this many of the hit's radii (times the
    /// shadow offset) off the surface and ignore crossings as near to their origin. A ray-facing
    /// disk of a neighbouring splat is met wherever the ray passes within its radius of the
    /// centre, so RFD rays leave twice as far (SJ advise 1–3 r). Measured in
    /// `tests/it/surfaces.rs`: starting 1 r off and ignoring 2 r, 4 of 4,096 pixels of a plane
    /// lit at 21° shadowed themselves; 2 r and 2 r, none, and 8 of 2,821 sphere pixels differ
    /// from the unshadowed image, at the terminator and the fringe outside the sphere.
    pub fn self_hit_radii(&self) -> f32 {
        if self.kind == SurfaceKind::Rfd { 2.0 } else { 1.0 }
    }

    /// Whether windows of `D`'s disks take their positions from the tangent planes: only
    /// ray-facing disks have a choice (`tangent_planes`).
    fn tangent_planes_for<D: DiskTest>(&self) -> bool {
        self.tangent_planes && D::SHAPE == DiskShape::RayFacing
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
    /// Index of the nearest disk, as [`Accel::splat`] takes it (perhaps a level-of-detail
    /// representative: [`Accel::is_representative`]).
    pub splat: u32,
    /// Number of disks blended (1 for first-hit; the neighbours of the last step for PSS).
    pub blended: u32,
}

/// Closest hit along `ray` with the given scheme.
///
/// # Panics
/// If the accelerator's bounds do not hold the scheme's disks (an RFD scheme needs an
/// accelerator built for ray-facing disks; see [`Accel::shape`]).
pub fn intersect<A: Accel + ?Sized>(
    accel: &A,
    ray: &Ray,
    scheme: &SurfaceScheme,
    stats: &mut TraversalStats,
) -> Option<SurfaceHit> {
    check_shape(accel, scheme);
    match scheme.kind {
        SurfaceKind::FirstHit => nearest(accel, ray, stats),
        SurfaceKind::Sj => windowed::<A, Oriented>(accel, ray, scheme, stats),
        SurfaceKind::Rfd => windowed::<A, RayFacing>(accel, ray, scheme, stats),
        SurfaceKind::Pss => {
            let seed = windowed::<A, Oriented>(accel, ray, scheme, stats)?;
            // A level-of-detail representative already stands for the surface at the ray's
            // footprint; projecting from it would gather the whole subtree (its bandwidth is
            // its radius).
            if accel.is_representative(seed.splat) {
                return Some(seed);
            }
            Some(pss::project(accel, ray, &seed, &scheme.pss, stats))
        }
    }
}

fn nearest<A: Accel + ?Sized>(accel: &A, ray: &Ray, stats: &mut TraversalStats) -> Option<SurfaceHit> {
    let mut v = Nearest { accel, t_max: f32::INFINITY, best: None };
    accel.traverse(ray, &mut v, stats);
    let (t, i) = (v.t_max, v.best?);
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

/// The SJ or RFD window, skipping weakly covered ones.
fn windowed<A: Accel + ?Sized, D: DiskTest>(
    accel: &A,
    ray: &Ray,
    scheme: &SurfaceScheme,
    stats: &mut TraversalStats,
) -> Option<SurfaceHit> {
    let tangent_planes = scheme.tangent_planes_for::<D>();
    let mut ray = *ray;
    // The weak window kept: the best covered of those facing the viewer, else the first.
    let mut weak: Option<Blend> = None;
    for _ in 0..MAX_WEAK_WINDOWS {
        let mut v = Window::<D>::new(scheme.window, accel.wide_radius(), A::REPEATS_SPLATS);
        walk_window(accel, &ray, &mut v, stats);
        // Nothing behind a weak window: it was the surface after all (a thinly covered spot),
        // not a disk sticking out in front of one.
        let Some(blend) = v.blend(&ray, accel, tangent_planes) else {
            // Spelled out: `return weak` copied all of an absent hit, field by field, for every
            // ray that missed (22 instructions).
            #[allow(clippy::manual_map)]
            return if let Some(w) = weak { Some(w.hit) } else { None };
        };
        let Blend { hit, coverage, facing_away } = blend;
        if coverage >= if facing_away { scheme.min_coverage_facing_away } else { scheme.min_coverage } {
            return match weak {
                // Past a thin spot facing the viewer, the inside of the shape: the ray went
                // between the near side's disks, and the thin spot was the surface.
                Some(thin) if facing_away && !thin.facing_away => Some(thin.hit),
                _ if facing_away => {
                    let until = v.first_t + OVERHANG * hit.radius;
                    Some(near_side_behind::<A, D>(accel, &ray.with_t_min(v.end), until, scheme, stats).unwrap_or(hit))
                }
                _ => Some(hit),
            };
        }
        if weak.as_ref().is_none_or(|kept| better_weak(&blend, kept)) {
            weak = Some(blend);
        }
        ray.t_min = v.end;
    }
    // Weak windows all the way: keep one rather than open a hole.
    weak.map(|w| w.hit)
}

/// Whether the weakly covered window `later`, met after `kept`, is the better surface where no
/// covered one follows: one
/// facing the viewer beats one facing away, and among those facing it the better covered
/// wins (a lone disk crossed at its rim in front of a crease, with a normal from one side of
/// it, loses to the disks behind it; the first wins ties), within [`OVERHANG`] radii of the
/// kept one (farther, it is another surface, and the nearer keeps the pixel from a hole). With
/// the first kept instead, such rims turned from the light were dark speckles that 16 rays a
/// pixel lack (the Happy Buddha 12 → 11, the Armadillo 18 → 17, `scripts/speckle_check.py`),
/// and the pixels the rule changes, taken together, come closer to that render (without the
/// reach, the Buddha's 59: squared error 292 k → 258 k).
fn better_weak(later: &Blend, kept: &Blend) -> bool {
    let near = later.hit.t - kept.hit.t <= OVERHANG * kept.hit.radius;
    near && !later.facing_away && (kept.facing_away || later.coverage > kept.coverage)
}

/// A covered window facing the viewer that begins on `ray` by `until`, past windows facing away
/// or weakly covered: the near side that a covered window facing away in front of it hides
/// (see [`OVERHANG`]). The walks collect nothing that begins past `until`. Rare, and out of
/// line: inlined, it cost every SJ ray.
#[inline(never)]
fn near_side_behind<A: Accel + ?Sized, D: DiskTest>(
    accel: &A,
    ray: &Ray,
    until: f32,
    scheme: &SurfaceScheme,
    stats: &mut TraversalStats,
) -> Option<SurfaceHit> {
    let tangent_planes = scheme.tangent_planes_for::<D>();
    let mut ray = *ray;
    for _ in 0..MAX_WEAK_WINDOWS {
        let mut v = Window::<D>::new(scheme.window, accel.wide_radius(), A::REPEATS_SPLATS);
        v.limit(until);
        walk_window(accel, &ray, &mut v, stats);
        let Blend { hit, coverage, facing_away } = v.blend(&ray, accel, tangent_planes)?;
        if !facing_away && coverage >= scheme.min_coverage {
            return Some(hit);
        }
        ray.t_min = v.end;
    }
    None
}

/// Collects the window that begins first on `ray` into `v`, whole. (Returned by value, the
/// window cost SJ 50 instructions a pixel more: a copy of its crossings.)
#[inline(always)]
fn walk_window<A: Accel + ?Sized, D: DiskTest>(accel: &A, ray: &Ray, v: &mut Window<D>, stats: &mut TraversalStats) {
    accel.traverse(ray, v, stats);
    if v.grew {
        // A nearer, wider first crossing turned up late (a level-of-detail representative, or a
        // disk wider than `wide_radius`), or the window reaches past its limit: crossings past an
        // earlier `collect_to` were turned away. Collect the rest of the final window. A
        // representative may reach outside its subtree's bounds, so for a ray that may stop at
        // one, a crossing of the rest may belong to a node that ends before it: that walk
        // starts at the ray's start.
        let collected = v.start_completion();
        let from = if accel.may_stop_at_representatives(ray) { ray.t_min } else { collected.max(ray.t_min) };
        accel.traverse(&ray.with_t_min(from), v, stats);
    }
}

/// How far behind the first crossing of a covered window facing away from the viewer, in radii
/// of its disk, a covered window facing the viewer shows that it is no surface: seen from
/// outside, a closed surface faces the viewer where a ray first meets it, and disks facing away
/// just in front of the near side are a crest's far side sticking out over it, hiding it from a
/// grazing ray. Farther, the sheet facing away may be a surface of its own (a room seen from
/// inside, an open scan from behind); the smallest reach that took the most speckles is kept.
/// Dark speckles that 16 rays a pixel lack (`scripts/speckle_check.py`, 1024²), swept with a
/// walk behind of one window: the Armadillo 34 without this, 33 at 2 radii, 21 at 4, 19 at 6,
/// 22 at 8 and 12; the Happy Buddha 14, 14, 15, 13, 11, 11; the dragon 13 and the bunny 6
/// throughout. Walking on past further windows facing away within reach, the Armadillo 18.
///
/// The walk behind collects nothing that begins past this reach, out of line: SJ on the
/// prepared dragon 1,007 instructions a pixel without the rule, 1,005 with it (callgrind,
/// `scripts/instructions_per_ray.py`). The Armadillo close up (distance 1, 512²) pays: 11 % of
/// its camera rays meet a covered window facing away and take the walk behind, 18.1 → 20.8
/// disk tests a ray (`render --stats`).
const OVERHANG: f32 = 6.0;

/// Most windows a ray skips as too weakly covered before it settles for one.
const MAX_WEAK_WINDOWS: usize = 4;

/// Panics unless the accelerator's bounds hold the scheme's disks.
fn check_shape<A: Accel + ?Sized>(accel: &A, scheme: &SurfaceScheme) {
    let needs = scheme.kind.shape();
    assert!(
        accel.shape().holds(needs),
        "the {} scheme needs an accelerator built for {needs:?} disks, not {:?}",
        scheme.kind.name(),
        accel.shape()
    );
}

/// Whether `crossing` only grazes its oriented disk: near the rim (d/r above [`SLIVER_RIM`]) of a
/// disk nearly in line with the ray (|n·d| below [`SLIVER_COS`]), a sliver of shadow that an
/// occlusion query (shadow rays, ambient-occlusion probes; every scheme, first-hit too) passes,
/// unless the disk is a representative. A body in the way blocks the ray through its other
/// disks too; a sliver alone is where the ray passes a blocker's outline as seen from the
/// light, and there a lone disk's rim, turned a little from the true outline, cast shadows that
/// the pixels beside did not have: dark speckles that 16 rays a pixel show no trace of (the
/// Happy Buddha's one, `scripts/speckle_check.py`).
#[inline(always)]
fn is_sliver(ray: &Ray, crossing: &Crossing) -> bool {
    let r = crossing.radius;
    crossing.dist2 > SLIVER_RIM * SLIVER_RIM * r * r && crossing.normal.dot(ray.dir).abs() < SLIVER_COS
}

/// How far out, over the radius, a crossing of a disk in line with the ray is a sliver (see
/// [`is_sliver`]). Swept (rim d/r, |n·d|) over the speckle check's scenes, the pixels each
/// setting changes against the 16-ray renders (squared error, before → after): (0.8, 0.1) took
/// every scene's closer (the demo 220 k → 113 k, the dragon 14 k → 12 k, the bunny 34.4 k →
/// 34.2 k, the Buddha 78 k → 35 k, Igea 31 k → 19 k); (0.9, 0.1) moved Igea's 3 further (6.2 k
/// → 7.0 k), (0.85, 0.15) and (0.9, 0.15) Igea's too (17 k → 18 k and more), (0.95, 0.2) the
/// dragon's (36 k → 47 k) and kept the speckle.
const SLIVER_RIM: f32 = 0.8;
/// Below this |n·d| a disk is in line with the ray (within 6°); see [`SLIVER_RIM`].
const SLIVER_COS: f32 = 0.1;

/// Whether anything lies on `ray` before `t_max` (shadow rays), as the scheme's disks. Any
/// disk counts, but for a sliver ([`is_sliver`]): a blocker needs no interpolation.
///
/// # Panics
/// As [`intersect`].
pub fn occluded<A: Accel + ?Sized>(
    accel: &A,
    ray: &Ray,
    t_max: f32,
    scheme: &SurfaceScheme,
    stats: &mut TraversalStats,
) -> bool {
    check_shape(accel, scheme);
    fn any<A: Accel + ?Sized, D: DiskTest>(accel: &A, ray: &Ray, t_max: f32, stats: &mut TraversalStats) -> bool {
        let mut v = AnyHit::<A, D> { accel, t_max, hit: false, disk: std::marker::PhantomData };
        accel.traverse(ray, &mut v, stats);
        v.hit
    }
    match scheme.kind.shape() {
        DiskShape::Oriented => any::<A, Oriented>(accel, ray, t_max, stats),
        DiskShape::RayFacing => any::<A, RayFacing>(accel, ray, t_max, stats),
    }
}

pub(crate) fn facing(n: Vec3, dir: Vec3) -> Vec3 {
    if n.dot(dir) > 0.0 { -n } else { n }
}

/// Total order on splats by their contents, to break exact ties in `t` the same way whatever
/// order an accelerator visits them in (coincident duplicates occur in real scans).
pub(crate) fn tie_key(s: &Splat) -> [u32; 8] {
    s.bits()
}

/// The nearest crossing, exact ties broken by [`tie_key`]. The keys are made only for a tie
/// (the best's from its index): kept for every new best, they cost a load of the splat and
/// eight words a hit (callgrind on the dragon, first hit: 841 → 826 instructions a pixel).
struct Nearest<'a, A: ?Sized> {
    accel: &'a A,
    /// The best crossing's distance (∞ before one).
    t_max: f32,
    /// The best crossing's splat.
    best: Option<u32>,
}

impl<A: Accel + ?Sized> SplatVisitor for Nearest<'_, A> {
    fn t_max(&self) -> f32 {
        self.t_max
    }

    #[inline(always)]
    fn hit(&mut self, _ray: &Ray, c: Crossing) {
        let better = match self.best {
            Some(best) => {
                c.t < self.t_max
                    || (c.t == self.t_max && tie_key(&self.accel.splat(c.splat)) < tie_key(&self.accel.splat(best)))
            }
            None => true,
        };
        if better {
            self.t_max = c.t;
            self.best = Some(c.splat);
        }
    }
}

struct AnyHit<'a, A: ?Sized, D> {
    accel: &'a A,
    t_max: f32,
    hit: bool,
    disk: std::marker::PhantomData<D>,
}

impl<A: Accel + ?Sized, D: DiskTest> SplatVisitor for AnyHit<'_, A, D> {
    const SHAPE: DiskShape = D::SHAPE;

    fn t_max(&self) -> f32 {
        self.t_max
    }

    #[inline(always)]
    fn hit(&mut self, ray: &Ray, crossing: Crossing) {
        // A ray-facing disk faces every ray: it has no slivers. Nor has a representative, the
        // one disk its subtree shows the ray (its normal may be any of a blob's).
        self.hit |= D::SHAPE == DiskShape::RayFacing
            || !is_sliver(ray, &crossing)
            || self.accel.is_representative(crossing.splat);
    }

    fn done(&self) -> bool {
        self.hit
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::BruteForce;
    use crate::math::RayCone;

    /// A densely covered plane z = `z` of disks with normal `normal`.
    fn plane(z: f32, normal: Vec3) -> Vec<Splat> {
        let mut splats = Vec::new();
        for i in -20..=20 {
            for j in -20..=20 {
                let center = Vec3::new(i as f32 * 0.05, j as f32 * 0.05, z);
                splats.push(Splat { center, radius: 0.1, normal, color: 0 });
            }
        }
        splats
    }

    /// A densely covered plane z = 0 and one disk floating at z = 0.5 in front of it.
    fn plane_and_lone_disk() -> BruteForce {
        plane_and_lone_disk_facing(Vec3::Z)
    }

    /// [`plane_and_lone_disk`] with the lone disk's normal `normal`.
    fn plane_and_lone_disk_facing(normal: Vec3) -> BruteForce {
        let mut splats = plane(0.0, Vec3::Z);
        splats.push(Splat { center: Vec3::new(0.0, 0.0, 0.5), radius: 0.2, normal, color: 0 });
        BruteForce::new(splats)
    }

    /// The rays come down −z: a disk with normal −z faces away from them. Crossed at d/r = 0.25
    /// (coverage 0.75), a lone disk facing the viewer is surface, one facing away (a far-side
    /// disk sticking out past a silhouette) is not, and the ray goes on to the plane behind. A
    /// whole sheet facing away (an open scan seen from behind) is covered and still shows where
    /// nothing facing the viewer lies just behind it (see the next test).
    #[test]
    fn sj_skips_a_lone_disk_facing_away_but_keeps_a_sheet() {
        let away = plane_and_lone_disk_facing(-Vec3::Z);
        assert!(hit_z(&away, 0.05, SurfaceScheme::sj()).abs() < 1e-5);
        // Ten radii in front of the plane, beyond `OVERHANG`: the threshold alone decides.
        let mut far = plane(0.0, Vec3::Z);
        far.push(Splat { center: Vec3::new(0.0, 0.0, 0.5), radius: 0.05, normal: -Vec3::Z, color: 0 });
        let far = BruteForce::new(far);
        assert!(hit_z(&far, 0.0125, SurfaceScheme::sj()).abs() < 1e-5);
        let old = SurfaceScheme { min_coverage_facing_away: 0.15, ..SurfaceScheme::sj() };
        assert!((hit_z(&far, 0.0125, old) - 0.5).abs() < 1e-5);
        assert!((hit_z(&plane_and_lone_disk(), 0.05, SurfaceScheme::sj()) - 0.5).abs() < 1e-5);
        let sheet = BruteForce::new([plane(-0.5, Vec3::Z), plane(0.5, -Vec3::Z)].concat());
        for x in [0.0, 0.013, 0.05, 0.21] {
            assert!((hit_z(&sheet, x, SurfaceScheme::sj()) - 0.5).abs() < 1e-5, "x = {x}");
        }
    }

    /// A covered sheet facing away from the viewer with a covered one facing it 2 or 5 radii
    /// behind: disks of a crest's far side sticking out over its near side (the Armadillo's
    /// shell seen at a grazing angle), and the near side is the surface, for SJ and RFD alike.
    /// 7 or 10 radii behind, past `OVERHANG`, the sheet facing away is a surface of its own (the
    /// inside of a room, an open scan from behind). (Within 1e-4: the planes' disks are snapped.)
    #[test]
    fn sj_takes_the_near_side_just_behind_a_sheet_facing_away() {
        for scheme in [SurfaceScheme::sj(), SurfaceScheme::rfd()] {
            for (behind, seen) in [(0.2, 0.3), (0.5, 0.0), (0.7, 0.5), (1.0, 0.5)] {
                let sheets = BruteForce::new([plane(0.5, -Vec3::Z), plane(0.5 - behind, Vec3::Z)].concat());
                for x in [0.0, 0.013, 0.05] {
                    let z = hit_z(&sheets, x, scheme);
                    assert!((z - seen).abs() < 1e-4, "{:?}, {behind} behind, x = {x}: {z}", scheme.kind);
                }
            }
        }
        // A weak window facing the viewer behind it is no near side.
        let mut weak = plane(0.5, -Vec3::Z);
        weak.push(Splat { center: Vec3::new(0.0, 0.0, 0.3), radius: 0.2, normal: Vec3::Z, color: 0 });
        assert!((hit_z(&BruteForce::new(weak), 0.19, SurfaceScheme::sj()) - 0.5).abs() < 1e-5);
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
        // The nearest disk (z = 1.0625) is wide, so its window reaches the disk at z = 0.5,
        // which a narrow disk found first (z = 1) would have cut off. And a tie at z = 1.0625
        // (on every disk's grid, so snapping keeps the tie).
        let cases = [
            vec![disk(1.0, 0.1), disk(0.5, 0.3), disk(1.0625, 1.0)],
            vec![disk(1.0625, 0.1), disk(0.5, 0.3), disk(1.0625, 1.0)],
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

    /// A lone disk facing the viewer, crossed at its rim (a thin spot), with the far side of a
    /// shape behind it, seen from within (facing away): the ray went between the near side's
    /// disks, and the thin spot is the surface. With a surface facing the viewer behind it
    /// instead, the lone disk is one sticking out, and the ray goes on (as before).
    #[test]
    fn sj_keeps_a_thin_spot_with_the_inside_behind_it() {
        let mut splats = plane(0.0, -Vec3::Z);
        splats.push(Splat { center: Vec3::new(0.0, 0.0, 0.5), radius: 0.2, normal: Vec3::Z, color: 0 });
        let inside = BruteForce::new(splats);
        assert!((hit_z(&inside, 0.19, SurfaceScheme::sj()) - 0.5).abs() < 1e-5);
        assert!(hit_z(&plane_and_lone_disk(), 0.19, SurfaceScheme::sj()).abs() < 1e-5);
    }

    /// A tilted disk facing away from the viewer just in front of a plane facing it, within
    /// the window: the window blends the plane's side, not the first disk's.
    #[test]
    fn sj_blends_the_side_that_faces_the_viewer() {
        let mut splats = plane(0.0, Vec3::Z);
        let tilted = Vec3::new(0.5, 0.0, -1.0).normalize();
        splats.push(Splat { center: Vec3::new(0.0, 0.0, 0.02), radius: 0.2, normal: tilted, color: 0 });
        let accel = BruteForce::new(splats);
        let ray = Ray::new(Vec3::new(0.013, 0.0, 3.0), -Vec3::Z, RayCone::default());
        let hit = intersect(&accel, &ray, &SurfaceScheme::sj(), &mut TraversalStats::default()).unwrap();
        assert!(hit.position.z.abs() < 1e-5 && hit.normal == Vec3::Z, "{hit:?}");
    }

    /// Two lone disks facing the viewer, both too weakly covered, nothing behind: the ray
    /// crosses the first at d/r = 0.95 (coverage 0.05) and the second, half a unit behind, at
    /// d/r = 0.9 (0.1), and the better covered is the surface (a rim disk in front of a crease,
    /// whose normal may be turned from the light, gives way to the disks behind it). The first
    /// wins a tie and over a window out of reach, and a weak disk facing away behind never beats
    /// one facing the viewer.
    #[test]
    fn sj_keeps_the_best_covered_of_weak_windows() {
        let lone = |z: f32, x: f32, normal: Vec3| Splat { center: Vec3::new(x, 0.0, z), radius: 0.2, normal, color: 0 };
        let z = |disks: Vec<Splat>| hit_z(&BruteForce::new(disks), 0.19, SurfaceScheme::sj());
        assert!((z(vec![lone(1.0, 0.0, Vec3::Z), lone(0.5, 0.01, Vec3::Z)]) - 0.5).abs() < 1e-5);
        assert!((z(vec![lone(1.0, 0.0, Vec3::Z), lone(0.5, 0.0, Vec3::Z)]) - 1.0).abs() < 1e-5);
        assert!((z(vec![lone(1.0, 0.0, Vec3::Z), lone(0.5, 0.01, -Vec3::Z)]) - 1.0).abs() < 1e-5);
        // Facing away first, a weak disk facing the viewer behind it wins whatever it covers.
        assert!((z(vec![lone(1.0, 0.01, -Vec3::Z), lone(0.5, 0.0, Vec3::Z)]) - 0.5).abs() < 1e-5);
        // Past `OVERHANG` radii (1.2 here) behind the kept one, a window is another surface.
        assert!((z(vec![lone(1.0, 0.0, Vec3::Z), lone(-0.5, 0.01, Vec3::Z)]) - 1.0).abs() < 1e-5);
        // With the inside of the shape behind them, the better covered is the thin spot.
        let mut inside = plane(0.0, -Vec3::Z);
        inside.extend([lone(1.0, 0.0, Vec3::Z), lone(0.5, 0.01, Vec3::Z)]);
        assert!((z(inside) - 0.5).abs() < 1e-5);
    }

    /// A shadow ray up +z past one disk of radius 0.2 at z = 1 tilted 3° from the ray's line
    /// (|n·d| = 0.05): crossed 0.9 of its radius out it is a sliver and blocks nothing, 0.5 out
    /// it blocks; a disk facing the ray blocks at 0.9 out, and so does the tilted one at 0.12
    /// (|n·d| past [`SLIVER_COS`]), and a ray-facing disk (RFD) whatever its normal.
    #[test]
    fn shadow_rays_pass_slivers_of_disks_in_line_with_them() {
        let blocked = |offset: f32, sin: f32| {
            let normal = Vec3::new((1.0 - sin * sin).sqrt(), 0.0, sin);
            let disk = Splat { center: Vec3::new(0.0, 0.0, 1.0), radius: 0.2, normal, color: 0 };
            // The ray passes offset·sin off the centre's line and crosses the disk's plane
            // |offset| from its centre.
            let ray = Ray::new(Vec3::new(offset * sin, 0.0, 0.0), Vec3::Z, RayCone::default());
            occluded(
                &BruteForce::new(vec![disk]),
                &ray,
                f32::INFINITY,
                &SurfaceScheme::sj(),
                &mut TraversalStats::default(),
            )
        };
        assert!(!blocked(0.18, 0.05));
        assert!(blocked(0.1, 0.05));
        assert!(blocked(0.18, 1.0));
        assert!(blocked(0.18, 0.12));
        // A grazing ray (|n·d| = 0.05) through a densely covered plane is blocked wherever it
        // crosses: some disk there is crossed well inside its rim. (Disks spaced wider than
        // 0.8·√2 r leave spots only rims cover, which such a ray passes.)
        let sheet = BruteForce::new(plane(0.0, Vec3::Z));
        let dir = Vec3::new(1.0, 0.0, 0.05).normalize();
        for i in 0..64 {
            let at = Vec3::new(-0.5 + 0.0173 * i as f32, -0.3 + 0.0097 * i as f32, 0.0);
            let ray = Ray::new(at - dir, dir, RayCone::default());
            let stats = &mut TraversalStats::default();
            assert!(occluded(&sheet, &ray, f32::INFINITY, &SurfaceScheme::sj(), stats), "{at}");
        }
        // The sliver's crossing of a disk turned to face the ray (RFD) blocks.
        let disk = Splat { center: Vec3::new(0.0, 0.0, 1.0), radius: 0.2, normal: Vec3::X, color: 0 };
        let ray = Ray::new(Vec3::new(0.18, 0.0, 0.0), Vec3::Z, RayCone::default());
        let rfd = SurfaceScheme::rfd();
        assert!(occluded(&BruteForce::new(vec![disk]), &ray, f32::INFINITY, &rfd, &mut TraversalStats::default()));
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
