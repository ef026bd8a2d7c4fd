//! Synthetic clouds with known geometry, and small helpers.

use glam::Vec3;
use pointray::demo::{uniform_sphere, uniform_torus};
use pointray::splat::{Splat, pack_color};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// The radius that makes `n` random disks cover a surface of `area`: on average f² = 6.25
/// disks overlap a point, leaving exp(−f²) ≈ 0.2 % uncovered (as the Embree bench's clouds).
pub fn covering_radius(area: f32, n: usize) -> f32 {
    2.5 * (area / (std::f32::consts::PI * n as f32)).sqrt()
}

pub fn rng(seed: u64) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(seed)
}

/// `n` splats on a sphere of radius `radius` at the origin, exact outward normals.
pub fn sphere_splats(n: usize, radius: f32, seed: u64) -> Vec<Splat> {
    let mut rng = rng(seed);
    let r = covering_radius(4.0 * std::f32::consts::PI * radius * radius, n);
    (0..n)
        .map(|i| {
            let d = uniform_sphere(&mut rng);
            Splat { center: d * radius, radius: r, normal: d, color: pack_color([(i % 7) as f32 / 7.0, 0.5, 0.8]) }
        })
        .collect()
}

/// `n` splats on a torus (major radius 1, minor 0.35) around the z axis, exact normals.
pub fn torus_splats(n: usize, seed: u64) -> Vec<Splat> {
    let (big, small) = (1.0f32, 0.35f32);
    let mut rng = rng(seed);
    let r = covering_radius(4.0 * std::f32::consts::PI * std::f32::consts::PI * big * small, n);
    (0..n)
        .map(|_| {
            let p = uniform_torus(&mut rng, big, small);
            let ring = Vec3::new(p.x, p.y, 0.0).normalize() * big;
            Splat { center: p, radius: r, normal: (p - ring).normalize(), color: pack_color([0.9, 0.6, 0.2]) }
        })
        .collect()
}

/// Random rays aimed at random points of `target`'s box from all around it: some hit, some
/// graze, some miss.
pub fn random_rays(n: usize, target: &pointray::math::Aabb, seed: u64) -> Vec<pointray::math::Ray> {
    let mut rng = rng(seed);
    let c = target.center();
    let reach = target.diagonal();
    (0..n)
        .map(|_| {
            let origin = c + uniform_sphere(&mut rng) * reach * rng.random_range(0.8..2.0);
            let aim = target.min + target.extent() * Vec3::new(rng.random(), rng.random(), rng.random());
            pointray::math::Ray::new(origin, aim - origin, Default::default())
        })
        .collect()
}
