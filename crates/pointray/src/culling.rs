//! Whether normal-cone culling is right for a cloud: a probe of the accelerator through the
//! first-hit surface, above both (the accelerators know disks, not surfaces).
//!
//! Culling drops subtrees whose disks all face away from the ray's origin. That changes no
//! image exactly when a ray from outside always meets a front face first: a closed surface
//! with consistently outward normals. Open scans (a single range scan, terrain seen from
//! below) and clouds whose orientation went wrong in places show back faces, and culling would
//! punch holes in them. So we ask the cloud: shoot rays from all around it and count the
//! first hits on disks that face away from the ray.

use glam::Vec3;
use rand::{RngExt, SeedableRng};

use crate::accel::{Accel, TraversalStats};
use crate::camera::{Camera, Region};
use crate::math::{Ray, RayCone};
use crate::splat::scheme::{self, SurfaceScheme};

/// Of rays from random points around the model (on a sphere twice its bounding sphere)
/// towards random points of its box, the fraction whose first disk faces away from them;
/// `None` if none hits. Deterministic for a given `seed`.
pub fn backfacing_fraction<A: Accel + ?Sized>(accel: &A, rays: usize, seed: u64) -> Option<f64> {
    let bounds = accel.bounds();
    if bounds.is_empty() {
        return None;
    }
    let center = bounds.center();
    let reach = bounds.diagonal().max(f32::MIN_POSITIVE);
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    let unit = |rng: &mut rand_pcg::Pcg64Mcg| loop {
        let v = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        if (1e-4..=1.0).contains(&v.length_squared()) {
            return v.normalize();
        }
    };
    let rays = (0..rays).map(|_| {
        let origin = center + unit(&mut rng) * reach;
        let target = bounds.min + bounds.extent() * Vec3::new(rng.random(), rng.random(), rng.random());
        Ray::new(origin, target - origin, RayCone::default())
    });
    first_hits_facing_away(accel, rays)
}

/// Of camera rays through random points of `region` of `camera`'s film, the fraction whose
/// first disk faces away from them; `None` if none hits. Deterministic for a given `seed`.
/// What the prefilter asks (its beams keep the disks that face them): a scan seen from the
/// side it was scanned from, terrain from above, meets front faces, though rays from all
/// around ([`backfacing_fraction`]) meet its back half the time.
pub fn backfacing_fraction_in_view<A: Accel + ?Sized>(
    accel: &A,
    camera: &Camera,
    region: Region,
    rays: usize,
    seed: u64,
) -> Option<f64> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    let (x0, y0, w, h) = (region.x0 as f32, region.y0 as f32, region.width() as f32, region.height() as f32);
    let rays = (0..rays).map(|_| camera.ray(x0 + w * rng.random::<f32>(), y0 + h * rng.random::<f32>()));
    first_hits_facing_away(accel, rays)
}

/// Of those of `rays` that meet a disk, the fraction whose first disk faces away from them.
fn first_hits_facing_away<A: Accel + ?Sized>(accel: &A, rays: impl Iterator<Item = Ray>) -> Option<f64> {
    let (mut hits, mut back) = (0usize, 0usize);
    let mut stats = TraversalStats::default();
    for ray in rays {
        if let Some(hit) = scheme::intersect(accel, &ray, &SurfaceScheme::first_hit(), &mut stats) {
            hits += 1;
            back += usize::from(accel.splat(hit.splat).normal.dot(ray.dir) > 0.0);
        }
    }
    (hits > 0).then(|| back as f64 / hits as f64)
}
