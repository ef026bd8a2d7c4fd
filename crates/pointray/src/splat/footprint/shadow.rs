//! A layer's shadow as many shadow rays would find it, from one gather.
//!
//! Each of the pixel's sample points that a layer covers is a shadow ray's origin: where the
//! sample's line meets the piece covering it (the nearest), lifted off it as a shadow ray is
//! lifted off a disk. A beam along the light wide enough for all of them gathers what lies
//! ahead, and a piece blocks the points it covers across the beam that lie behind it along the
//! light. The layer sees the light through the share of its points nothing blocks: a fold's
//! far wall shadows the points deep in the fold and not those on its rim, as the rays of many
//! samples a pixel would find.

use glam::{Vec3, Vec4};

use super::{
    Aggregate, Beam, Candidates, FOOTPRINT_RADIUS, Footprint, FootprintVisitor, GATHER_TAU, Layer, MIN_COS, SAMPLES,
    SamplePoints, covered_radius, screen,
};
use crate::accel::{Accel, TraversalStats};
use crate::splat::Splat;

/// The gather towards a light from a layer's sample points (see the module).
pub struct ShadowBeam {
    beam: Beam,
    /// As [`Footprint`]'s.
    size_scale: f32,
    /// Unit vectors across the beam, the axes of `points`.
    across: (Vec3, Vec3),
    /// The layer's points across the beam, in its frame through the local origin.
    points: SamplePoints,
    /// Where each point's ray starts along the beam, from that frame's origin (+∞ for points
    /// the layer does not cover).
    starts: [Vec4; SAMPLES / 4],
    /// The points the layer covers.
    layer: u64,
    /// The points something blocks, and those the layer does not cover.
    blocked: u64,
    t_cut: f32,
    /// The gather's threshold in beam radii: the pixel's, [`GATHER_TAU`].
    tau: f32,
}

impl ShadowBeam {
    /// The rays towards `light` (unit) up to `t_max` from `layer`'s points in `footprint`, each
    /// lifted `lift` of its piece's disk radius off it and ignoring what lies within `reach` of
    /// those radii, as a shadow ray from a disk does; none where the layer covers no point.
    pub fn new(footprint: &Footprint, layer: &Layer, light: Vec3, t_max: f32, lift: f32, reach: f32) -> Option<Self> {
        let across = crate::math::orthonormal_basis(light);
        let o = sample_origins(footprint, layer, (across.0, across.1, light), lift, reach);
        if o.covered == 0 {
            return None;
        }
        // Points and depths stay in the light's frame (through the local origin): the beam's
        // axis runs through the middle of their box across it, as wide as the box's corners.
        let (lo, hi) = (o.low, o.high);
        let (cu, cv) = (0.5 * (lo.0 + hi.0), 0.5 * (lo.1 + hi.1));
        let radius = (0.5 * (hi.0 - lo.0).hypot(hi.1 - lo.1)).max(1e-3 * footprint.beam.radius(layer.t));
        let lanes = |a: &[f32; SAMPLES]| std::array::from_fn(|i| Vec4::from_slice(&a[4 * i..]));
        let origin = across.0 * cu + across.1 * cv;
        let beam = Beam { origin, dir: light, r0: radius, spread: 0.0, t_min: o.first_start, t_max };
        let pixel = footprint.beam.radius(layer.t) / FOOTPRINT_RADIUS;
        Some(Self {
            beam,
            size_scale: footprint.size_scale,
            across,
            points: SamplePoints { x: lanes(&o.u), y: lanes(&o.v) },
            starts: lanes(&o.start),
            layer: o.covered,
            blocked: !o.covered,
            t_cut: t_max,
            tau: GATHER_TAU * pixel / radius,
        })
    }

    /// Gathers what lies ahead in `accel`, at the pixel's level of detail (`tau_scale` times its
    /// threshold, as [`Footprint::gather`]'s: 0 at full detail), until every point is blocked.
    pub fn gather<A: Accel>(&mut self, accel: &A, tau_scale: f32, stats: &mut TraversalStats) {
        let beam = self.beam;
        accel.gather(&beam, tau_scale * self.tau, self, stats);
    }

    /// The share of the layer's points that something blocks.
    pub fn blocked(&self) -> f32 {
        (self.blocked & self.layer).count_ones() as f32 / self.layer.count_ones() as f32
    }

    /// The points whose rays start before `t`.
    #[inline(always)]
    fn started(&self, t: f32) -> u64 {
        let t = Vec4::splat(t);
        self.starts.iter().enumerate().fold(0, |m, (i, s)| m | u64::from(t.cmpgt(*s).bitmask()) << (4 * i))
    }
}

impl FootprintVisitor for ShadowBeam {
    #[inline(always)]
    fn t_cut(&self) -> f32 {
        self.t_cut
    }

    /// Blocks the points `splat` covers across the beam (the disk of a piece as
    /// [`Footprint`] makes it) whose rays it lies ahead of; it must face them.
    fn add(&mut self, _index: u32, s: &Splat, aggregate: Aggregate) {
        let b = &self.beam;
        let cos = s.normal.dot(b.dir);
        let oc = s.center - b.origin;
        let t = oc.dot(b.dir);
        if cos > 0.0 || t < b.t_min || t > self.t_cut {
            return;
        }
        let foreshortening = (-cos).max(MIN_COS).sqrt();
        let size = aggregate.area_radius * self.size_scale * foreshortening;
        // As the screen and `Footprint::piece` keep it (its area's disk reaches the beam), so
        // that every accelerator's gather, and brute force's, blocks the same points.
        if (oc - t * b.dir).length() >= size + b.r0 {
            return;
        }
        let covered = covered_radius(s, aggregate, size, foreshortening);
        // The points are where they cross the plane through the local origin across the beam.
        let (x, y) = (s.center.dot(self.across.0), s.center.dot(self.across.1));
        self.blocked |= self.points.within(x, y, covered) & self.started(t);
        if self.blocked == u64::MAX {
            self.t_cut = f32::NEG_INFINITY;
        }
    }

    #[inline(always)]
    fn screen(&self, c: &Candidates) -> u32 {
        screen(&self.beam, self.t_cut, self.size_scale, c)
    }
}

/// The layer's sample points as shadow rays' origins, in the light's frame (through the local
/// origin): across it (`u`, `v`), and where each ray starts along it.
struct Origins {
    u: [f32; SAMPLES],
    v: [f32; SAMPLES],
    /// +∞ for the points the layer does not cover.
    start: [f32; SAMPLES],
    /// The points the layer covers.
    covered: u64,
    /// The corners of their box across the light, and the nearest start.
    low: (f32, f32),
    high: (f32, f32),
    first_start: f32,
}

/// Where the line of each sample point of `footprint` that `layer` covers meets the layer: on
/// the plane of the nearest piece covering it (within two beam radii of the piece's depth),
/// lifted `lift` of the piece's radius along its normal, its ray starting `reach` of that
/// radius on; in the frame `axes` (across, across, along the light).
fn sample_origins(footprint: &Footprint, layer: &Layer, axes: (Vec3, Vec3, Vec3), lift: f32, reach: f32) -> Origins {
    let b = &footprint.beam;
    let (a1, a2) = footprint.across;
    let (u, v, start) = ([0.0; SAMPLES], [0.0; SAMPLES], [f32::INFINITY; SAMPLES]);
    let (low, high) = ((f32::INFINITY, f32::INFINITY), (f32::NEG_INFINITY, f32::NEG_INFINITY));
    let mut o = Origins { u, v, start, covered: 0, low, high, first_start: f32::INFINITY };
    for p in &footprint.pieces[layer.pieces.clone()] {
        let w = b.radius(p.t);
        let facing = p.normal.dot(b.dir).min(-MIN_COS);
        // The piece's plane along the beam's axis, and how it tilts across it.
        let (x1, x2) = (w * a1, w * a2);
        let lifted = b.origin + p.normal * (lift * p.radius);
        let t0 = (p.center - b.origin).dot(p.normal) / facing;
        let (dt1, dt2) = (-x1.dot(p.normal) / facing, -x2.dot(p.normal) / facing);
        let (lo, hi) = (p.t - 2.0 * w, p.t + 2.0 * w);
        for k in bits(p.mask & !o.covered) {
            let (x, y) = footprint.points.get(k);
            let t = (t0 + x * dt1 + y * dt2).clamp(lo, hi);
            let at = lifted + x * x1 + y * x2 + t * b.dir;
            let (pu, pv, ps) = (at.dot(axes.0), at.dot(axes.1), at.dot(axes.2) + reach * p.radius);
            (o.u[k], o.v[k], o.start[k]) = (pu, pv, ps);
            (o.low, o.high) = ((o.low.0.min(pu), o.low.1.min(pv)), (o.high.0.max(pu), o.high.1.max(pv)));
            o.first_start = o.first_start.min(ps);
        }
        o.covered |= p.mask;
    }
    o
}

/// The indices of `mask`'s set bits.
fn bits(mut mask: u64) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            i
        })
    })
}
