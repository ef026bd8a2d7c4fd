//! The footprint prefilter: level of detail as a prefilter, one beam a pixel.
//!
//! A camera ray stands for its pixel: a beam about the ray, as wide as the pixel's footprint
//! (a disk of the pixel's area). Instead of the first disk the ray meets, the beam gathers
//! every disk, or representative of disks finer than the pixel, that overlaps it, as a
//! [`Piece`]: the share of the beam's cross-section the disks cover, their mean colour and
//! their mean normal, whose length says how much the normals below spread. Pieces at one depth
//! make a [`Layer`], a surface seen through the pixel: the share of the pixel they cover
//! together, attributes averaged by each one's share. Layers composite front to back, so a
//! pixel the model covers in part blends with what lies behind, and a rough patch shades
//! darker and with a wider highlight (Toksvig).
//! One beam a pixel then approaches the mean of many rays a pixel (`docs/RESULTS.md`).
//!
//! Coverage. A layer covers the share of [`SAMPLES`] points of the beam's cross-section that
//! one of its pieces covers: a union, so that overlapping disks (they overlap by design)
//! count once. A disk covers its own disk, projected along the beam; a representative the
//! area its disks cover, `area / ρ` (`area` their summed area, ρ the cloud's
//! [`coverage_density`], how many disks cover a point of it), as a disk in its plane widened by
//! [`REPRESENTATIVE_SPREAD`], since what a subtree covers is no disk about its centre and
//! neighbouring representatives must meet. Each piece's own share, its lens with the beam at
//! `area / ρ`, weighs its colour, normal and depth within the layer.

use arrayvec::ArrayVec;
use glam::{Vec2, Vec3, Vec4};

use crate::accel::{Accel, TraversalStats};
use crate::color::srgb8_to_linear_table;
use crate::math::Ray;
use crate::splat::{Splat, color_linear_in};

mod shadow;
pub use shadow::ShadowBeam;

/// The beam's radius as a share of the pixel's width: a disk of the pixel's area (1/√π).
pub const FOOTPRINT_RADIUS: f32 = 0.564_189_6;

/// The gather stops at subtrees whose bounding sphere's radius is below this share of the
/// pixel's width (whatever the level-of-detail threshold, which decides only where the
/// prefilter applies): a few pieces across the pixel. On the dragon at 16 diagonals, against
/// 256 rays a pixel (without the BVH's `LEAF_SLACK`): 0.25, 0.28, 0.35, 0.5 and 0.7 gave 33.8,
/// 34.6, 35.0, 34.1 and 31.1 dB, the coarser with silhouettes too coarse, the finer with more
/// pieces than help (`docs/RESULTS.md`).
pub const GATHER_TAU: f32 = 0.35;

/// Pieces within this many beam radii (or piece radii, if wider) of a layer's first piece
/// join the layer.
const LAYER_DEPTH: f32 = 2.0;

/// Light passing layers below this share is gone: the beam stops, and what lies behind is
/// neither gathered nor shaded.
pub const OPAQUE: f32 = 0.01;

/// The most pieces a beam keeps; past it, the farthest go (pixels of the dragon at 16
/// diagonals filled 96 with every leaf opened at a finer cut, and lost coverage).
pub const MAX_PIECES: usize = 256;

/// Points of the beam's cross-section whose union of pieces gives a layer's coverage. With 32
/// the dragon at 16 diagonals came 0.4 dB further from the converged image than with 64.
pub const SAMPLES: usize = 64;

/// A representative's covered disk is this much wider than one of its disks' area over ρ: the
/// dragon at 16 diagonals, against 256 rays a pixel, 34.1 / 34.8 dB at 1.3 / 1.5 (coverage
/// summed, not a union, with the density scaled by 0.8: 34.7; `docs/RESULTS.md`).
pub const REPRESENTATIVE_SPREAD: f32 = 1.5;

/// What a representative's disks are beyond its own disk.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aggregate {
    /// √(Σ r²): the radius of a disk of their summed area.
    pub area_radius: f32,
    /// The length of their area-weighted mean normal: 1 where all agree.
    pub agreement: f32,
    /// A disk itself, not a representative: it covers its own disk.
    pub disk: bool,
}

impl Aggregate {
    /// One disk's.
    pub fn disk(radius: f32) -> Self {
        Self { area_radius: radius, agreement: 1.0, disk: true }
    }
}

/// A pixel's beam: about the ray's axis, radius `r0 + spread·t` for t in `[t_min, t_max]`.
#[derive(Clone, Copy, Debug)]
pub struct Beam {
    pub origin: Vec3,
    pub dir: Vec3,
    pub r0: f32,
    pub spread: f32,
    pub t_min: f32,
    pub t_max: f32,
}

impl Beam {
    /// The beam of `ray`'s footprint, up to `t_max`.
    pub fn of_ray(ray: &Ray, t_max: f32) -> Self {
        Self {
            origin: ray.origin,
            dir: ray.dir,
            r0: ray.cone.width0 * FOOTPRINT_RADIUS,
            spread: ray.cone.spread * FOOTPRINT_RADIUS,
            t_min: ray.t_min,
            t_max,
        }
    }

    #[inline(always)]
    pub fn radius(&self, t: f32) -> f32 {
        self.r0 + self.spread * t.max(0.0)
    }
}

/// What an accelerator hands the gather: each disk or representative the beam may overlap.
pub trait FootprintVisitor {
    /// Nothing beyond this depth can show.
    fn t_cut(&self) -> f32;
    /// A disk (or a representative, with what it stands for) that the beam may overlap.
    fn add(&mut self, index: u32, splat: &Splat, aggregate: Aggregate);
    /// Which of eight candidates (bit i for lane i) may make a piece: every one that
    /// [`Self::add`] would keep, and few it would not.
    fn screen(&self, candidates: &Candidates) -> u32;
}

/// Eight disks or representatives side by side, as an accelerator's blocks hold them, with
/// the radius of the area each stands for ([`Aggregate::area_radius`]; a disk's own radius).
pub struct Candidates {
    pub center: [[f32; 8]; 3],
    pub normal: [[f32; 8]; 3],
    pub area_radius: [f32; 8],
}

/// One disk's or representative's share of the beam.
#[derive(Clone, Copy, Debug)]
pub struct Piece {
    /// Depth of its centre along the beam.
    pub t: f32,
    /// Its own share of the beam's cross-section (its lens with the beam, at `area / ρ`): its
    /// weight in the layer's averages.
    pub coverage: f32,
    /// Linear albedo.
    pub color: Vec3,
    /// Unit normal, facing the beam's origin.
    pub normal: Vec3,
    /// Its normals' agreement ([`Aggregate::agreement`]).
    pub agreement: f32,
    pub center: Vec3,
    /// The covered disk's radius as the beam sees it.
    pub size: f32,
    /// The disk's own radius.
    pub radius: f32,
    /// As [`Accel::splat`] takes it.
    pub index: u32,
    /// The points of the beam's cross-section it covers (bit i: [`sample_points`]' i).
    pub mask: u64,
}

/// Area of the intersection of two disks of radii `a` and `b` whose centres are `d` apart.
pub fn lens_area(d: f32, a: f32, b: f32) -> f32 {
    use std::f32::consts::PI;
    if d >= a + b {
        return 0.0;
    }
    if d <= (a - b).abs() {
        return PI * a.min(b).powi(2);
    }
    let ca = ((d * d + a * a - b * b) / (2.0 * d * a)).clamp(-1.0, 1.0);
    let cb = ((d * d + b * b - a * a) / (2.0 * d * b)).clamp(-1.0, 1.0);
    let k = ((-d + a + b) * (d + a - b) * (d - a + b) * (d + a + b)).max(0.0);
    (a * a * acos(ca) + b * b * acos(cb) - 0.5 * k.sqrt()).max(0.0)
}

/// arccos within 7·10⁻⁵ (Abramowitz and Stegun 4.4.45): a square root and a cubic, where the
/// library's took a hundred instructions.
fn acos(x: f32) -> f32 {
    let a = x.abs();
    let r = (1.0 - a).sqrt() * (1.570_728_8 + a * (-0.212_114_4 + a * (0.074_261_0 - 0.018_729_3 * a)));
    if x < 0.0 { std::f32::consts::PI - r } else { r }
}

/// A beam's gather: the pieces so far (nearest first once gathered), and the depth past which
/// the layers already in front are opaque.
pub struct Footprint {
    pub beam: Beam,
    /// 1/√ρ: a disk of area A covers A/ρ of the surface.
    size_scale: f32,
    /// Unit vectors across the beam: the axes of [`sample_points`].
    across: (Vec3, Vec3),
    points: &'static SamplePoints,
    pieces: ArrayVec<Piece, MAX_PIECES>,
    t_cut: f32,
    /// The pieces' summed shares.
    total: f32,
    /// The sample points some piece covers: no layer is opaque before they all are.
    covered: u64,
    /// The summed shares at which to look for an opaque layer again, once they all are.
    next_scan: f32,
    /// The largest piece size so far.
    widest: f32,
}

impl Footprint {
    /// An empty gather of `ray`'s footprint up to `t_max` in `accel` (see [`Self::gather`]).
    /// Inlined, so that the caller's frame holds it: returned by value, its pieces were a copy
    /// of 30 kB a pixel.
    #[inline(always)]
    pub fn new<A: Accel>(accel: &A, ray: &Ray, t_max: f32) -> Self {
        let beam = Beam::of_ray(ray, t_max);
        Self {
            beam,
            size_scale: accel.coverage_density().max(1.0).sqrt().recip(),
            across: crate::math::orthonormal_basis(beam.dir),
            points: sample_points(),
            pieces: ArrayVec::new(),
            t_cut: t_max,
            total: 0.0,
            covered: 0,
            next_scan: 0.0,
            widest: 0.0,
        }
    }

    /// Gathers the footprint in `accel`, down to subtrees narrower than [`GATHER_TAU`] of the
    /// pixel (`tau_scale` times: 0 gathers every disk, at full detail).
    pub fn gather<A: Accel>(&mut self, accel: &A, tau_scale: f32, stats: &mut TraversalStats) {
        let beam = self.beam;
        accel.gather(&beam, tau_scale * GATHER_TAU / FOOTPRINT_RADIUS, self, stats);
        self.sort();
    }

    pub fn pieces(&self) -> &[Piece] {
        &self.pieces
    }

    /// The surfaces the beam met, nearest first (the gather left out what lies some way behind
    /// the first opaque ones, [`OPAQUE`]).
    pub fn layers(&self) -> Layers<'_> {
        Layers { pieces: &self.pieces, beam: &self.beam, next: 0 }
    }

    /// Pieces come nearly in order (subtrees nearest first): an insertion sort's case, by hand
    /// (the library's sorts, of the pieces and of the BVH's children, took 34,000 instructions
    /// a pixel of the dragon at 16 diagonals, callgrind).
    fn sort(&mut self) {
        let pieces = self.pieces.as_mut_slice();
        for i in 1..pieces.len() {
            let p = pieces[i];
            let mut at = i;
            while at > 0 && pieces[at - 1].t > p.t {
                pieces[at] = pieces[at - 1];
                at -= 1;
            }
            pieces[at] = p;
        }
    }

    /// The piece `splat` makes, or none where it does not overlap the beam or faces away.
    #[inline(always)]
    fn piece(&self, index: u32, s: &Splat, aggregate: Aggregate) -> Option<Piece> {
        let beam = &self.beam;
        let cos = s.normal.dot(beam.dir);
        // The far side of a closed surface, and subtrees whose normals face away on the
        // whole (a crease's other side shows through its own pieces, which face the beam):
        // the normals must face the view, which `RenderJob` checks (`Scene::job`). Taken as
        // two-sided, as rays take disks, rim representatives leaning away stood in front of
        // the surface (the dragon at 16 diagonals: 34.7 → 29.9 dB).
        if cos > 0.0 {
            return None;
        }
        let oc = s.center - beam.origin;
        let t = oc.dot(beam.dir);
        if t < beam.t_min || t > self.t_cut {
            return None;
        }
        let across = oc - t * beam.dir;
        // Disks seen along the beam: ellipses, taken as disks of their area.
        let foreshortening = (-cos).max(MIN_COS).sqrt();
        let size = aggregate.area_radius * self.size_scale * foreshortening;
        let w = beam.radius(t);
        let coverage = lens_area(across.length(), size, w) / (std::f32::consts::PI * w * w);
        if coverage <= MIN_COVERAGE {
            return None;
        }
        let covered = covered_radius(s, aggregate, size, foreshortening);
        let mask = self.sample_mask(across, w, covered);
        let color = Vec3::from(color_linear_in(s.color, srgb8_to_linear_table()));
        let (normal, agreement, center, radius) = (s.normal, aggregate.agreement, s.center, s.radius);
        Some(Piece { t, coverage, color, normal, agreement, center, size, radius, index, mask })
    }

    /// The sample points within `radius` of a point `across` the axis, in a beam `w` wide.
    #[inline(always)]
    fn sample_mask(&self, across: Vec3, w: f32, radius: f32) -> u64 {
        self.points.within(across.dot(self.across.0) / w, across.dot(self.across.1) / w, radius / w)
    }

    fn insert(&mut self, p: Piece) {
        if self.pieces.is_full() {
            self.sort();
            if self.pieces.last().is_some_and(|last| last.t <= p.t) {
                return;
            }
            let dropped = self.pieces.pop().map_or(0.0, |q| q.coverage);
            self.total -= dropped;
        }
        self.pieces.push(p);
        self.total += p.coverage;
        self.covered |= p.mask;
        self.widest = self.widest.max(p.size);
        if self.covered == u64::MAX && self.total >= self.next_scan {
            self.cut_behind_opaque();
        }
    }

    /// Drops what lies behind the first layers that let less than [`OPAQUE`] through.
    fn cut_behind_opaque(&mut self) {
        self.sort();
        let mut transmit = 1.0;
        let mut cut = None;
        for layer in self.layers() {
            transmit *= 1.0 - layer.coverage;
            if transmit < OPAQUE {
                cut = Some(layer.end);
                break;
            }
        }
        if let Some(end) = cut {
            // A layer's end depends on the pieces in it, and a piece still to come in front
            // may move the layers' bounds by up to a layer's depth: what lies within one more
            // layer's depth of the opaque layer's end stays, so that the gather does not depend
            // on the order the pieces come in (the BVH's nearest first, brute force's any).
            self.t_cut = end + LAYER_DEPTH * self.beam.radius(end).max(self.widest);
            let keep = self.pieces.partition_point(|p| p.t <= self.t_cut);
            self.pieces.truncate(keep);
            self.total = self.pieces.iter().map(|p| p.coverage).sum();
            self.covered = self.pieces.iter().fold(0, |m, p| m | p.mask);
        }
        // Scans a piece, each over all the pieces, cost the dragon at 16 diagonals most of its
        // time: the next once a quarter more coverage has come.
        self.next_scan = self.total + SCAN_STEP;
    }
}

/// [`SAMPLES`] points spread evenly over the unit disk (a Vogel spiral: radius √((i + ½)/n),
/// the golden angle apart), four to a vector.
#[derive(Clone, Copy)]
struct SamplePoints {
    x: [Vec4; SAMPLES / 4],
    y: [Vec4; SAMPLES / 4],
}

impl SamplePoints {
    /// The points within `r` of (`x`, `y`), bit i for point i.
    #[inline(always)]
    fn within(&self, x: f32, y: f32, r: f32) -> u64 {
        let (cx, cy, r2) = (Vec4::splat(x), Vec4::splat(y), Vec4::splat(r * r));
        // Four points at a time, in SSE lanes (glam's). The dragon at 16 diagonals, a frame:
        // a scalar test of every point, 6,500 instructions a pixel; in lanes, 1,600 and 2.59 ms;
        // the points sorted by y and only the fours in the disk's rows tested, 2,000 fewer
        // instructions but 2.79 ms (its branches mispredicted).
        let mut mask = 0;
        for (i, (px, py)) in self.x.iter().zip(&self.y).enumerate() {
            let (dx, dy) = (*px - cx, *py - cy);
            mask |= u64::from((dx * dx + dy * dy).cmple(r2).bitmask()) << (4 * i);
        }
        mask
    }

    /// Point `i`.
    fn get(&self, i: usize) -> (f32, f32) {
        (self.x[i / 4][i % 4], self.y[i / 4][i % 4])
    }
}

fn sample_points() -> &'static SamplePoints {
    static POINTS: std::sync::OnceLock<SamplePoints> = std::sync::OnceLock::new();
    POINTS.get_or_init(|| {
        let point = |i: usize| {
            let (r, a) = (((i as f32 + 0.5) / SAMPLES as f32).sqrt(), i as f32 * 2.399_963_2);
            Vec2::new(r * a.cos(), r * a.sin())
        };
        let lanes = |f: fn(Vec2) -> f32| {
            std::array::from_fn(|v| Vec4::from_array(std::array::from_fn(|l| f(point(4 * v + l)))))
        };
        SamplePoints { x: lanes(|p| p.x), y: lanes(|p| p.y) }
    })
}

/// The coverage gathered between two looks for an opaque layer.
const SCAN_STEP: f32 = 0.25;

/// Grazing disks count as seen at this cosine: edge-on, a disk still covers its thickness.
const MIN_COS: f32 = 0.05;

/// Pieces covering less than this share of the beam are left out.
const MIN_COVERAGE: f32 = 1e-4;

impl FootprintVisitor for Footprint {
    #[inline(always)]
    fn t_cut(&self) -> f32 {
        self.t_cut
    }

    fn add(&mut self, index: u32, splat: &Splat, aggregate: Aggregate) {
        if let Some(p) = self.piece(index, splat, aggregate) {
            self.insert(p);
        }
    }

    #[inline(always)]
    fn screen(&self, c: &Candidates) -> u32 {
        screen(&self.beam, self.t_cut, self.size_scale, c)
    }
}

/// [`Footprint::piece`]'s tests for eight at once, each with a margin for rounding (lanes sum
/// in another order): facing the beam, within its depths (to `t_cut`), and no farther from its
/// axis than the covered disk's radius plus the beam's. Two in three of the dragon's candidates
/// at 16 diagonals failed them one by one in `piece`, at some 70 instructions each.
#[inline(always)]
fn screen(b: &Beam, t_cut: f32, size_scale: f32, c: &Candidates) -> u32 {
    let (t_lo, t_hi) = (b.t_min - SCREEN_MARGIN * b.t_min.abs(), t_cut + SCREEN_MARGIN * t_cut.abs());
    let (o, d) = (b.origin, b.dir);
    // Lane by lane over plain arrays, which the compiler turns into vector code.
    let mut keep = [false; 8];
    for (i, keep) in keep.iter_mut().enumerate() {
        let oc = [c.center[0][i] - o.x, c.center[1][i] - o.y, c.center[2][i] - o.z];
        let cos = c.normal[0][i] * d.x + c.normal[1][i] * d.y + c.normal[2][i] * d.z;
        let t = oc[0] * d.x + oc[1] * d.y + oc[2] * d.z;
        let off = [oc[0] - t * d.x, oc[1] - t * d.y, oc[2] - t * d.z];
        let off2 = off[0] * off[0] + off[1] * off[1] + off[2] * off[2];
        let size = c.area_radius[i] * size_scale * (-cos).max(MIN_COS).sqrt();
        let reach = (size + b.r0 + b.spread * t.max(0.0)) * (1.0 + SCREEN_MARGIN);
        *keep = (cos <= SCREEN_MARGIN) & (t >= t_lo) & (t <= t_hi) & (off2 <= reach * reach);
    }
    keep.iter().enumerate().fold(0, |mask, (i, &k)| mask | u32::from(k) << i)
}

/// The radius of the disk a piece covers as a beam sees it, `size` its area's over ρ: a disk
/// covers its own disk, a representative [`REPRESENTATIVE_SPREAD`] times `size`.
#[inline(always)]
fn covered_radius(s: &Splat, aggregate: Aggregate, size: f32, foreshortening: f32) -> f32 {
    if aggregate.disk { s.radius * foreshortening } else { REPRESENTATIVE_SPREAD * size }
}

/// [`screen`]'s relative margin.
const SCREEN_MARGIN: f32 = 1e-4;

/// Pieces at one depth: a surface as the pixel sees it.
#[derive(Clone, Debug)]
pub struct Layer {
    /// Coverage-weighted mean depth.
    pub t: f32,
    /// Where it ends: later pieces make another layer.
    pub end: f32,
    /// The share of the beam's sample points its pieces cover.
    pub coverage: f32,
    /// Coverage-weighted mean albedo (linear).
    pub color: Vec3,
    /// Coverage-weighted mean of the pieces' normals scaled by their agreement: its length
    /// (≤ 1) measures how much the normals under the pixel spread.
    pub normal: Vec3,
    /// The piece covering most, whose disk names the layer's material.
    pub index: u32,
    /// Its pieces, in [`Footprint::pieces`].
    pub pieces: std::ops::Range<usize>,
}

/// [`Footprint::layers`].
pub struct Layers<'a> {
    pieces: &'a [Piece],
    beam: &'a Beam,
    next: usize,
}

impl Iterator for Layers<'_> {
    type Item = Layer;

    fn next(&mut self) -> Option<Layer> {
        let start = self.next;
        let first = self.pieces.get(start)?;
        let reach = |p: &Piece| p.t + LAYER_DEPTH * self.beam.radius(p.t).max(p.size);
        let mut end = reach(first);
        let (mut sum, mut t, mut color, mut normal) = (0.0, 0.0, Vec3::ZERO, Vec3::ZERO);
        let mut most = (0.0, first.index);
        let mut covered = 0;
        while let Some(p) = self.pieces.get(self.next).filter(|p| p.t <= end) {
            covered |= p.mask;
            end = end.max(p.t + 0.5 * (reach(p) - p.t));
            sum += p.coverage;
            t += p.coverage * p.t;
            color += p.coverage * p.color;
            normal += (p.coverage * p.agreement) * p.normal;
            if p.coverage > most.0 {
                most = (p.coverage, p.index);
            }
            self.next += 1;
        }
        let pieces = start..self.next;
        Some(Layer {
            t: t / sum,
            end,
            coverage: covered.count_ones() as f32 / SAMPLES as f32,
            color: color / sum,
            normal: normal / sum,
            index: most.1,
            pieces,
        })
    }
}

/// A point of `layer` to aim its shadow rays from (the light's direction and distance): the
/// coverage-weighted mean of its pieces' points nearest the beam's axis (each in its plane,
/// within half its radius of its centre), so that a partly covered layer's lies on its
/// pieces, not on the axis beside them.
pub fn shadow_origin(footprint: &Footprint, layer: &Layer) -> Vec3 {
    let beam = &footprint.beam;
    let (mut weight, mut point) = (0.0, Vec3::ZERO);
    for p in &footprint.pieces[layer.pieces.clone()] {
        let axis = beam.origin + p.t * beam.dir;
        let off = axis - p.center;
        let off = off - p.normal * off.dot(p.normal);
        let len = off.length();
        let nearest = if len > 0.0 { p.center + off * (len.min(0.5 * p.radius) / len) } else { p.center };
        weight += p.coverage;
        point += p.coverage * nearest;
    }
    if weight > 0.0 { point / weight } else { beam.origin + layer.t * beam.dir }
}

/// How many disks cover a point of the surface, on average, in `accel` (at least 1): at the
/// centres of [`DENSITY_SAMPLES`] of its `disks` spread over them, the disks whose radius
/// reaches it (the dragon: 8.5; at random points of the disks instead of their centres, 8.5 too).
pub fn coverage_density<A: Accel>(accel: &A, samples: impl Iterator<Item = Splat>) -> f32 {
    density_of(coverage_counts(accel, samples))
}

/// The disks covering the `samples`' centres, summed, and the samples: [`coverage_density`]
/// in parts, for taking the samples a batch at a time (`pointray_io::prepare`).
pub fn coverage_counts<A: Accel>(accel: &A, samples: impl Iterator<Item = Splat>) -> (u64, u64) {
    let reach = accel.wide_radius();
    let mut stats = TraversalStats::uncounted();
    let (mut covering, mut count) = (0u64, 0u64);
    for s in samples {
        accel.for_each_near(s.center, reach, &mut stats, |_, d| {
            covering += u64::from((d.center - s.center).length_squared() <= d.radius * d.radius);
        });
        count += 1;
    }
    (covering, count)
}

/// [`coverage_density`] from [`coverage_counts`] (summed over batches).
pub fn density_of((covering, count): (u64, u64)) -> f32 {
    (covering as f32 / count.max(1) as f32).max(1.0)
}

/// Disks [`coverage_density`] looks at.
const DENSITY_SAMPLES: usize = 4096;

/// The stride through `n` disks (or blocks) that samples about [`DENSITY_SAMPLES`] of them.
pub fn density_stride(n: usize) -> usize {
    (n / DENSITY_SAMPLES).max(1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::PI;

    #[test]
    fn lens_area_of_disks_apart_inside_and_across() {
        assert_eq!(lens_area(3.0, 1.0, 1.5), 0.0);
        assert!((lens_area(0.2, 1.0, 0.5) - PI * 0.25).abs() < 1e-6, "the smaller inside the larger");
        // Two unit disks a radius apart: 2π/3 − √3/2.
        let expected = 2.0 * PI / 3.0 - 3f32.sqrt() / 2.0;
        assert!((lens_area(1.0, 1.0, 1.0) - expected).abs() < 1e-3, "{}", lens_area(1.0, 1.0, 1.0));
        assert!((lens_area(0.7, 1.0, 0.6) - lens_area(0.7, 0.6, 1.0)).abs() < 1e-6, "symmetric");
        // Shrinks as the centres part (to the arccos's error).
        let areas: Vec<f32> = (0..20).map(|i| lens_area(i as f32 * 0.1, 1.0, 0.8)).collect();
        assert!(areas.windows(2).all(|w| w[1] <= w[0] + 1e-3), "{areas:?}");
        assert!(areas[5] < 0.85 * areas[0] && areas[19] == 0.0, "{areas:?}");
    }

    #[test]
    fn acos_is_within_its_bound() {
        for i in 0..=2000 {
            let x = -1.0 + i as f32 / 1000.0;
            assert!((acos(x) - x.acos()).abs() < 1e-4, "{x}: {} vs {}", acos(x), x.acos());
        }
    }

    /// A piece whose share is `coverage`, covering as many sample points from the `first`.
    fn piece(t: f32, coverage: f32, color: Vec3, normal: Vec3, first: u32) -> Piece {
        let (center, size, radius) = (Vec3::ZERO, 0.01, 0.01);
        let points = (coverage * SAMPLES as f32).round() as u32;
        let mask = (u64::MAX >> (64 - points)).rotate_left(first);
        Piece { t, coverage, color, normal, agreement: 1.0, center, size, radius, index: 0, mask }
    }

    fn footprint(beam: Beam, size_scale: f32, t_cut: f32) -> Footprint {
        let across = crate::math::orthonormal_basis(beam.dir);
        let (pieces, total, covered, next_scan, widest) = (ArrayVec::new(), 0.0, 0, 0.0, 0.0);
        let points = sample_points();
        Footprint { beam, size_scale, across, points, pieces, t_cut, total, covered, next_scan, widest }
    }

    fn beam() -> Beam {
        Beam { origin: Vec3::ZERO, dir: Vec3::Z, r0: 0.1, spread: 0.0, t_min: 0.0, t_max: f32::INFINITY }
    }

    #[test]
    fn pieces_at_one_depth_make_one_layer_and_later_ones_another() {
        let (red, blue) = (Vec3::X, Vec3::Z);
        // The front two cover the sample points between them, overlapping (a union).
        let pieces =
            [piece(1.0, 0.5, red, Vec3::Z, 0), piece(1.05, 0.7, blue, Vec3::Y, 20), piece(2.0, 0.3, red, Vec3::Z, 0)];
        let layers: Vec<Layer> = Layers { pieces: &pieces, beam: &beam(), next: 0 }.collect();
        assert_eq!(layers.len(), 2);
        let front = &layers[0];
        assert_eq!((front.coverage, front.pieces.clone()), (1.0, 0..2), "the union covers every point");
        let w = 0.5 / 1.2;
        assert!((front.color - (red * w + blue * (1.0 - w))).length() < 1e-6, "colour weighed by coverage");
        assert!((front.normal.length() - (w * w + (1.0 - w) * (1.0 - w)).sqrt()).abs() < 1e-6, "spread normals");
        assert!((front.t - (1.0 * w + 1.05 * (1.0 - w))).abs() < 1e-6);
        assert_eq!((layers[1].coverage, layers[1].pieces.clone()), (19.0 / 64.0, 2..3));
        // Two pieces over the same points cover them once.
        let same = [piece(1.0, 0.5, red, Vec3::Z, 0), piece(1.05, 0.5, blue, Vec3::Y, 0)];
        let layer = Layers { pieces: &same, beam: &beam(), next: 0 }.next().expect("a layer");
        assert_eq!(layer.coverage, 0.5);
    }

    /// A disk covers the sample points within it: all of a beam it contains, about its area's
    /// share of those of a beam it partly covers, none of a beam it misses.
    #[test]
    fn a_disk_covers_the_sample_points_within_it() {
        let f = footprint(beam(), 1.0, f32::INFINITY);
        let (e1, e2) = f.across;
        let share = |at: Vec3, r: f32| f.sample_mask(at, 1.0, r).count_ones() as f32 / SAMPLES as f32;
        assert_eq!(share(Vec3::ZERO, 1.01), 1.0);
        assert_eq!(share(2.0 * e1, 0.9), 0.0);
        for (at, r) in [(Vec3::ZERO, 0.5), (0.5 * e2, 0.7), (e1 - e2 * 0.2, 1.0), (0.8 * e1, 0.3)] {
            // The lens of the two disks over the beam's area.
            let expected = lens_area(at.length(), r, 1.0) / std::f32::consts::PI;
            assert!((share(at, r) - expected).abs() < 0.05, "{at} {r}: {} against {expected}", share(at, r));
        }
    }

    /// The screen keeps every candidate that makes a piece (else the BVH would miss pieces
    /// brute force finds), and drops most that do not.
    #[test]
    fn the_screen_keeps_every_piece_and_drops_most_of_the_rest() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(21);
        let beam = Beam { origin: Vec3::new(0.1, -0.2, 0.0), dir: Vec3::new(0.3, 0.1, 1.0).normalize(), ..beam() };
        let f = footprint(beam, 0.4, 4.0);
        let (mut pieces, mut kept, mut dropped) = (0, 0, 0);
        for _ in 0..2000 {
            let disks: [Splat; 8] = std::array::from_fn(|_| {
                let t = rng.random_range(-1.0..6.0);
                let off = Vec3::new(rng.random_range(-0.4..0.4), rng.random_range(-0.4..0.4), 0.0);
                let normal =
                    Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                let (normal, radius) = (normal.normalize_or(Vec3::Z), rng.random_range(0.01..0.3));
                Splat { center: beam.origin + t * beam.dir + off, radius, normal, color: 0xff80_4020 }
            });
            let c = Candidates {
                center: std::array::from_fn(|k| disks.map(|s| s.center[k])),
                normal: std::array::from_fn(|k| disks.map(|s| s.normal[k])),
                area_radius: disks.map(|s| 2.0 * s.radius),
            };
            let mask = f.screen(&c);
            for (i, s) in disks.iter().enumerate() {
                let piece =
                    f.piece(i as u32, s, Aggregate { area_radius: 2.0 * s.radius, agreement: 1.0, disk: false });
                let screened = mask >> i & 1 == 1;
                assert!(piece.is_none() || screened, "{s:?} makes a piece but was screened out");
                pieces += usize::from(piece.is_some());
                kept += usize::from(screened && piece.is_none());
                dropped += usize::from(!screened);
            }
        }
        assert!(pieces > 500 && dropped > 10 * kept, "{pieces} pieces, {kept} kept in vain, {dropped} dropped");
    }

    #[test]
    fn the_gather_drops_what_lies_behind_an_opaque_layer_but_not_within_a_layer_of_it() {
        let mut f = footprint(beam(), 1.0, f32::INFINITY);
        // Each covers 38 of the 64 points, the next ones the rest and more.
        for (i, t) in [5.0, 1.0, 1.1, 1.35, 3.0].into_iter().enumerate() {
            f.insert(piece(t, 0.6, Vec3::ONE, Vec3::Z, 32 * i as u32));
        }
        f.sort();
        // The first layer (1.0 and 1.1, to 1.2) is opaque: 1.35, within a layer's depth (0.2)
        // of its end, stays; 3 and 5 go.
        let kept: Vec<f32> = f.pieces().iter().map(|p| p.t).collect();
        assert_eq!(kept, [1.0, 1.1, 1.35]);
        assert!(f.t_cut() < 3.0);
    }
}
