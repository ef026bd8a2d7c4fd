//! Splats: oriented disks built from the points, and the ray–surface schemes over them.
//!
//! One file per kernel, as in Embree's `geometry/*_intersector.h`: [`oriented_disk`] and
//! [`ray_facing_disk`] are the exact ray–disk tests (a splat as a disk in its tangent plane, or
//! as a disk turned to face the ray); [`scheme`] turns the disks a ray crosses into one surface
//! hit: the first disk alone (`first-hit`), an interpolation window over oriented disks
//! (Schaufler–Jensen, `sj`) or over ray-facing disks (`rfd`, [`window`]), or the moving
//! least-squares surface of the splats near the first hit (`pss`, [`pss`]).

pub mod footprint;
pub mod oriented_disk;
pub mod pss;
pub mod ray_facing_disk;
pub mod scheme;
pub mod window;

use glam::Vec3;

use crate::PointCloud;
use crate::math::{Aabb, Ray};
use oriented_disk::DiskHit;

/// The disk a splat stands for when a ray meets it. The accelerators' bounds must hold it: a
/// ray-facing disk reaches r from its centre in every direction, an oriented disk only within
/// its plane.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DiskShape {
    #[default]
    Oriented,
    RayFacing,
}

impl DiskShape {
    /// Whether bounds built for `self` hold the disks of `other` too.
    pub fn holds(self, other: DiskShape) -> bool {
        self == other || self == DiskShape::RayFacing
    }

    /// The exact test of this shape: [`oriented_disk::intersect`] or [`ray_facing_disk::intersect`].
    #[inline(always)]
    pub fn intersect(self, ray: &Ray, splat: &Splat, t_max: f32) -> Option<DiskHit> {
        match self {
            DiskShape::Oriented => oriented_disk::intersect(ray, splat, t_max),
            DiskShape::RayFacing => ray_facing_disk::intersect(ray, splat, t_max),
        }
    }
}

/// A disk shape as a type, for the visitors of the surface schemes, which are generic over the
/// disks the accelerator tests for them.
pub trait DiskTest {
    const SHAPE: DiskShape;
}

/// The disk in the splat's tangent plane ([`oriented_disk`]).
pub struct Oriented;

/// The disk turned to face the ray ([`ray_facing_disk`]).
pub struct RayFacing;

impl DiskTest for Oriented {
    const SHAPE: DiskShape = DiskShape::Oriented;
}

impl DiskTest for RayFacing {
    const SHAPE: DiskShape = DiskShape::RayFacing;
}

/// One surface element: a disk of `radius` around `center`, perpendicular to the unit `normal`.
/// 32 bytes, so two share a cache line; the colour is packed sRGB8 with the index of the
/// splat's material in the top byte (`0xMMBBGGRR`, see [`Splat::material`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Splat {
    pub center: Vec3,
    pub radius: f32,
    pub normal: Vec3,
    pub color: u32,
}

/// The oriented-disk test scales normals by this (2¹⁴, exactly) before it uses them; the BVH's
/// blocks store normals as multiples of its inverse (`accel::block`).
pub(crate) const NORMAL_SCALE: f32 = 16384.0;

/// The colour of splats whose cloud has none: a light warm grey, as in the Embree bench.
pub const DEFAULT_COLOR: [f32; 3] = [0.92, 0.88, 0.80];

impl Splat {
    /// Every field's bits (centre, radius, normal, colour): equal only for the same splat, −0
    /// and +0 told apart.
    pub fn bits(&self) -> [u32; 8] {
        let (c, n, b) = (self.center, self.normal, f32::to_bits);
        [b(c.x), b(c.y), b(c.z), b(self.radius), b(n.x), b(n.y), b(n.z), self.color]
    }

    /// Tight bounds of the disk: along axis `i` it extends `r·sqrt(1 − nᵢ²)` from the centre.
    pub fn bounds(&self) -> Aabb {
        let half = self.radius * (Vec3::ONE - self.normal * self.normal).max(Vec3::ZERO).sqrt();
        Aabb::new(self.center - half, self.center + half)
    }

    /// Bounds of the disk as `shape`: a ray-facing disk may turn any way, so its bounds are
    /// those of the ball of radius r.
    pub fn bounds_as(&self, shape: DiskShape) -> Aabb {
        match shape {
            DiskShape::Oriented => self.bounds(),
            DiskShape::RayFacing => Aabb::new(self.center - self.radius, self.center + self.radius),
        }
    }

    /// The index of the splat's material in the render's list (`RenderConfig::materials`):
    /// the packed colour's top byte, so that a scene of several clouds costs no memory.
    pub fn material(&self) -> u8 {
        material_of(self.color)
    }

    pub fn set_material(&mut self, material: u8) {
        self.color = self.color & 0x00ff_ffff | u32::from(material) << 24;
    }

    /// The colour in linear RGB (for shading and blending), through a table: no `powf` per hit.
    /// Inlined: as a call it made the SJ blend spill ten registers per disk.
    #[inline]
    pub fn color_linear(&self) -> [f32; 3] {
        color_linear_in(self.color, crate::color::srgb8_to_linear_table())
    }
}

/// A packed colour (as [`Splat::color`]) in linear RGB, through `table`: [`Splat::color_linear`]
/// with the table fetched once, for loops over many colours.
#[inline(always)]
pub(crate) fn color_linear_in(c: u32, table: &[f32; 256]) -> [f32; 3] {
    [table[(c & 0xff) as usize], table[(c >> 8 & 0xff) as usize], table[(c >> 16 & 0xff) as usize]]
}

/// The material index in a packed colour (its top byte, see [`Splat::material`]).
#[inline(always)]
pub(crate) fn material_of(color: u32) -> u8 {
    (color >> 24) as u8
}

/// Packs an sRGB-encoded colour (each channel in `[0, 1]`) into a splat's 8-bit channels.
pub fn pack_color(rgb: [f32; 3]) -> u32 {
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u32;
    q(rgb[0]) | q(rgb[1]) << 8 | q(rgb[2]) << 16
}

/// Splats for every point of a preprocessed cloud (normals and radii present).
///
/// # Panics
/// If the cloud has no normals or no radii: run [`crate::preprocess::preprocess`] first.
pub fn splats_from_cloud(cloud: &PointCloud) -> Vec<Splat> {
    let normals = cloud.normals.as_ref().expect("splats need normals: preprocess the cloud first");
    let radii = cloud.radii.as_ref().expect("splats need radii: preprocess the cloud first");
    let default = pack_color(DEFAULT_COLOR);
    (0..cloud.len())
        .map(|i| Splat {
            center: cloud.positions[i],
            radius: radii[i],
            normal: normals[i],
            color: cloud.colors.as_ref().map_or(default, |c| pack_color(c[i])),
        })
        .collect()
}
