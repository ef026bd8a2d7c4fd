//! The representative splat of a set of disks: what a multiresolution accelerator hands the
//! surface scheme instead of the disks below a node (QSplat's merge, RECONSTRUCTION A3), shared
//! by the BVH and the kd-tree.

use glam::DVec3;

use crate::accel::block::{BLOCK, SplatBlock, snap_normal};
use crate::color::{linear_to_srgb, srgb8_to_linear_table};
use crate::splat::footprint::Aggregate;
use crate::splat::{Splat, color_linear_in, material_of, pack_color};

/// A representative and whether the normals below agree enough to have a mean.
pub(crate) struct Representative {
    /// An oriented disk at the area-weighted mean centre, with the area-weighted mean normal
    /// and colour, and a radius between covering every disk and matching their spread.
    pub(crate) splat: Splat,
    /// False when the normals cancel out (both sides of a thin sheet, a tiny closed blob):
    /// the normal is then the first disk's, and no normal cone bounds the disks.
    pub(crate) coherent: bool,
}

/// The representative of `disks` (at least one).
pub(crate) fn representative<'a>(disks: impl Iterator<Item = &'a Splat> + Clone) -> Representative {
    let first_normal = disks.clone().next().expect("a representative of no disk").normal;
    let frame = Moments::of(disks.clone()).frame(first_normal);
    let mut spread = Spread::default();
    disks.for_each(|s| spread.add(&frame, s));
    frame.representative(&spread)
}

/// The area-weighted sums a representative starts from. Those of a set of disks are the sums
/// of its parts', so a tree gets every node's from its children's (`Moments::merge`) where
/// summing over the disks below each node again cost O(n · depth).
#[derive(Clone, Debug, Default)]
pub(crate) struct Moments {
    area: f64,
    center: DVec3,
    normal: DVec3,
    color: DVec3,
    /// The area of each material.
    materials: Materials,
}

/// Areas by material: the first material met kept inline, the others (rare: most clouds have
/// one) in a vector, so that a node's or a leaf's moments allocate nothing.
#[derive(Clone, Debug, Default)]
struct Materials {
    first: Option<(u8, f64)>,
    others: Vec<(u8, f64)>,
}

impl Materials {
    fn add(&mut self, material: u8, area: f64) {
        match &mut self.first {
            Some((m, a)) if *m == material => *a += area,
            None => self.first = Some((material, area)),
            Some(_) => match self.others.iter_mut().find(|(m, _)| *m == material) {
                Some((_, a)) => *a += area,
                None => self.others.push((material, area)),
            },
        }
    }

    fn iter(&self) -> impl Iterator<Item = &(u8, f64)> {
        self.first.iter().chain(&self.others)
    }
}

impl Moments {
    pub(crate) fn of<'a>(disks: impl Iterator<Item = &'a Splat>) -> Self {
        let mut m = Moments::default();
        disks.for_each(|s| m.add(s));
        m
    }

    #[inline]
    pub(crate) fn add(&mut self, s: &Splat) {
        let disk = (s.center.as_dvec3(), s.normal.as_dvec3(), s.radius, s.color);
        self.add_disk(disk, srgb8_to_linear_table());
    }

    /// [`Moments::add`] of the first `count` disks of `block`, read from the block's lanes:
    /// extracting each disk first, the leaves' moments took 83 million instructions of the
    /// dragon's build, this 67 (callgrind).
    #[inline(always)]
    pub(crate) fn add_block(&mut self, block: &SplatBlock, count: usize) {
        let table = srgb8_to_linear_table();
        let [cx, cy, cz] = block.centers_f64();
        let [nx, ny, nz] = block.normals_f64();
        let (radius, color) = (block.radii(), block.colors());
        for i in 0..count {
            let disk = (DVec3::new(cx[i], cy[i], cz[i]), DVec3::new(nx[i], ny[i], nz[i]), radius[i], color[i]);
            self.add_disk(disk, table);
        }
    }

    /// One disk: centre, normal, radius and packed colour.
    #[inline(always)]
    fn add_disk(&mut self, (center, normal, radius, color): (DVec3, DVec3, f32, u32), table: &[f32; 256]) {
        // Zero-radius disks still count (a little), so that a cloud of them has a centre.
        let w = f64::from(radius).powi(2).max(f64::MIN_POSITIVE);
        self.materials.add(material_of(color), w);
        self.area += w;
        self.center += w * center;
        self.normal += w * normal;
        self.color += w * glam::Vec3::from(color_linear_in(color, table)).as_dvec3();
    }

    /// What the footprint prefilter needs of these disks beyond their representative: the
    /// radius of a disk of their summed area, and their mean normal's length.
    pub(crate) fn aggregate(&self) -> Aggregate {
        Aggregate {
            area_radius: self.area.sqrt() as f32,
            agreement: (self.normal.length() / self.area).min(1.0) as f32,
            disk: false,
        }
    }

    pub(crate) fn merge(&mut self, other: &Moments) {
        self.area += other.area;
        self.center += other.center;
        self.normal += other.normal;
        self.color += other.color;
        for &(material, area) in other.materials.iter() {
            self.materials.add(material, area);
        }
    }

    /// The representative's centre, axis, colour and material; `first_normal` is the normal
    /// of the first disk, the axis where the normals cancel out.
    pub(crate) fn frame(&self, first_normal: glam::Vec3) -> Frame {
        let center = self.center / self.area;
        let coherent = self.normal.length() > 1e-3 * self.area;
        let axis = if coherent { self.normal.normalize() } else { first_normal.as_dvec3() };
        // As a block stores it, so that the normal cone about it bounds what the traversal reads.
        let axis = snap_normal(axis.as_vec3()).as_dvec3();
        let color = (self.color / self.area).as_vec3().to_array().map(linear_to_srgb);
        // Materials do not blend: the one covering the most area (by the disks' areas) wins.
        let material =
            self.materials.iter().max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0))).map_or(0, |&(m, _)| m);
        Frame { center, axis, coherent, area: self.area, color: pack_color(color), material }
    }
}

/// A representative but for its radius, which takes one more pass over the disks ([`Spread`]).
pub(crate) struct Frame {
    center: DVec3,
    axis: DVec3,
    coherent: bool,
    area: f64,
    color: u32,
    material: u8,
}

/// What the radius needs of the disks, as seen in a [`Frame`].
#[derive(Default)]
pub(crate) struct Spread {
    cover: f64,
    moment: f64,
}

impl Spread {
    /// [`Spread::add`] for the first `count` disks of `block`: their distances from the axis
    /// lane by lane (which the compiler vectorizes), then taken in the lanes' order.
    #[inline(always)]
    pub(crate) fn add_block(&mut self, frame: &Frame, block: &SplatBlock, count: usize) {
        let (o, a) = (frame.center, frame.axis.to_array());
        let [cx, cy, cz] = block.centers_f64();
        let mut off = [0.0; BLOCK];
        for i in 0..BLOCK {
            off[i] = along_and_off([cx[i] - o.x, cy[i] - o.y, cz[i] - o.z], a).1;
        }
        // A counted loop: as `zip(…).take(count)` it cost the level-of-detail pass 60 million
        // instructions more on the dragon after an unrelated change (callgrind).
        let radii = block.radii();
        for i in 0..count.min(BLOCK) {
            self.include(off[i], f64::from(radii[i]));
        }
    }

    pub(crate) fn add(&mut self, frame: &Frame, s: &Splat) {
        let d = s.center.as_dvec3() - frame.center;
        self.include(along_and_off(d.to_array(), frame.axis.to_array()).1, f64::from(s.radius));
    }

    /// A disk of radius `r` whose centre lies `in_plane` off the axis. (A compare, not
    /// `f64::max`, whose NaN rules cost four instructions: no value here is NaN.)
    #[inline(always)]
    fn include(&mut self, in_plane: f64, r: f64) {
        self.cover = if in_plane + r > self.cover { in_plane + r } else { self.cover };
        // A uniform disk of radius ρ has mean squared distance ρ²/2 from its centre.
        self.moment += r * r * (2.0 * in_plane * in_plane + r * r);
    }
}

/// `d`'s component along the unit `axis` and its distance from the axis, in the one order of
/// operations that every caller, a disk at a time or lane by lane, shares: the same bits.
#[inline(always)]
pub(crate) fn along_and_off(d: [f64; 3], axis: [f64; 3]) -> (f64, f64) {
    let h = d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2];
    let q = [d[0] - h * axis[0], d[1] - h * axis[1], d[2] - h * axis[2]];
    (h, (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt())
}

impl Frame {
    /// The representative's normal.
    pub(crate) fn normal(&self) -> glam::Vec3 {
        self.axis.as_vec3()
    }

    pub(crate) fn representative(&self, spread: &Spread) -> Representative {
        // The radius: between the disk that covers every disk below (as seen along the axis),
        // which fattens silhouettes, and the disk with the same second moment as the area
        // below, which leaves gaps where neighbouring representatives meet. Their mean measured
        // best on the dragon at 16 diagonals with the BVH (PSNR against the full-detail image
        // 28.7 dB against 28.1 and 27.5; mean brightness +0.4 % against +1.4 % and −2.1 %).
        let moment = (spread.moment / self.area).sqrt();
        let radius = 0.5 * (spread.cover + moment);
        let mut splat = Splat {
            center: self.center.as_vec3(),
            radius: radius as f32,
            normal: self.axis.as_vec3(),
            color: self.color,
        };
        splat.set_material(self.material);
        Representative { splat, coherent: self.coherent }
    }
}

/// The quantile for [`radius_quantile`]. With the floor at the smallest radius, one BVH node
/// of a few coincident points sent every ray of a close-up through the multiresolution loop
/// (+5 % instructions on the dragon at distance 1 for 15 stops in 287,000 rays).
pub(crate) const LOD_FLOOR_QUANTILE: f64 = 0.05;

/// [`crate::accel::Accel::wide_radius`] of these splats. Measured on the dragon (SJ, first
/// hits, callgrind): the window reaching the largest radius cost 1,597 instructions a ray, the
/// 99th percentile 1,580, the 90th 1,661, and the first crossing's own radius (a second walk
/// for the 23 % of rays whose window grew) 1,755.
pub(crate) fn wide_radius(splats: &[Splat]) -> f32 {
    radius_quantile(splats.iter().map(|s| s.radius).collect(), WIDE_QUANTILE)
}

/// The quantile of the radii [`wide_radius`] takes.
pub(crate) const WIDE_QUANTILE: f64 = 0.99;

/// The `quantile` (0–1) of a multiresolution accelerator's representative radii; +∞ without
/// any. Rays whose footprint, scaled by the threshold, stays below it take the full-detail
/// traversal: they forgo level of detail only at the narrowest representatives, where it
/// would save little, and close up level of detail costs nothing.
pub(crate) fn radius_quantile(mut radii: Vec<f32>, quantile: f64) -> f32 {
    if radii.is_empty() {
        return f32::INFINITY;
    }
    let at = ((radii.len() - 1) as f64 * quantile) as usize;
    *radii.select_nth_unstable_by(at, f32::total_cmp).1
}
