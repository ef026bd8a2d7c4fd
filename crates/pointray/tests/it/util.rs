//! Synthetic clouds with known geometry, and small helpers.

use glam::Vec3;
use pointray::demo::{uniform_sphere, uniform_torus};
use pointray::splat::{Splat, pack_color};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Splats at `centers` with the given normals and the pipeline's own radii (§2.1: distance to
/// the 8th neighbour), so the disks cover the surface without holes.
fn splats(centers: Vec<Vec3>, normals: Vec<Vec3>, color: impl Fn(usize) -> u32) -> Vec<Splat> {
    let cfg = pointray::preprocess::PreprocessConfig::standard();
    let nbrs = pointray::knn::k_nearest(&centers, cfg.k_radius);
    let radii = pointray::preprocess::radii::splat_radii(&centers, &nbrs, cfg.k_radius, cfg.radius_scale);
    (0..centers.len())
        .map(|i| Splat { center: centers[i], radius: radii[i], normal: normals[i], color: color(i) })
        .collect()
}

pub fn rng(seed: u64) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(seed)
}

/// `n` splats on a sphere of radius `radius` at the origin, exact outward normals.
pub fn sphere_splats(n: usize, radius: f32, seed: u64) -> Vec<Splat> {
    let mut rng = rng(seed);
    let normals: Vec<Vec3> = (0..n).map(|_| uniform_sphere(&mut rng)).collect();
    let centers = normals.iter().map(|d| *d * radius).collect();
    splats(centers, normals, |i| pack_color([(i % 7) as f32 / 7.0, 0.5, 0.8]))
}

/// `n` splats on a torus (major radius 1, minor 0.35) around the z axis, exact normals.
pub fn torus_splats(n: usize, seed: u64) -> Vec<Splat> {
    let (big, small) = (1.0f32, 0.35f32);
    let mut rng = rng(seed);
    let centers: Vec<Vec3> = (0..n).map(|_| uniform_torus(&mut rng, big, small)).collect();
    let normals = centers.iter().map(|p| (*p - Vec3::new(p.x, p.y, 0.0).normalize() * big).normalize()).collect();
    splats(centers, normals, |_| pack_color([0.9, 0.6, 0.2]))
}

/// `n` splats uniformly on the square [−1, 1]² of the plane z = 0, normals +z.
pub fn plane_splats(n: usize, seed: u64) -> Vec<Splat> {
    let mut rng = rng(seed);
    let centers = (0..n).map(|_| Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 0.0)).collect();
    splats(centers, vec![Vec3::Z; n], |_| pack_color([0.5, 0.7, 0.3]))
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

/// A render's settings with neutral defaults (Whitted, SJ, no light, the standard material, a
/// black environment, independent samples, full detail), for tests to override by field.
pub fn render_config(region: pointray::camera::Region, samples: u32) -> pointray::render::RenderConfig {
    use pointray::render::{Filter, Integrator, RenderConfig, Sampler};
    RenderConfig {
        sampler: Sampler::Random,
        filter: Filter::Box,
        integrator: Integrator::Whitted,
        ao_distance: 1.0,
        scheme: pointray::splat::scheme::SurfaceScheme::sj(),
        lights: Vec::new(),
        materials: vec![pointray::material::Material::standard()],
        shadows: true,
        shadow_offset: 1.0,
        environment: pointray::shading::Environment::Uniform { color: [0.0; 3] },
        background: None,
        ground: None,
        max_depth: 5,
        region,
        samples,
        sample_range: None,
        seed: 0,
        lod_threshold: 0.0,
        prefilter: false,
        diffuse_spread: 0.0,
        cull_backfaces: false,
        count_work: true,
        first_hit_aovs: true,
    }
}
