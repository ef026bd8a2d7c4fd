//! The built-in demo scene: a sphere and a torus on a checkered floor, sampled as random
//! points (positions and colours only, so the demo exercises the whole preprocessing).

use std::f32::consts::TAU;

use glam::{Mat3, Vec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::PointCloud;
use crate::scene::SceneParts;
use crate::shading::Light;

/// About `points` points spread over the three surfaces in proportion to their areas.
pub fn demo_cloud(points: usize, seed: u64) -> PointCloud {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let floor_half = 1.6f32;
    let (sphere_c, sphere_r) = (Vec3::new(-0.55, 0.5, -0.25), 0.5f32);
    let (torus_c, torus_big, torus_small) = (Vec3::new(0.62, 0.56, 0.25), 0.4f32, 0.16f32);
    // Standing on its rim, turned towards the demo camera.
    let torus_rot = Mat3::from_rotation_y(0.5) * Mat3::from_rotation_x(-0.15);
    let areas = [
        4.0 * floor_half * floor_half,
        4.0 * std::f32::consts::PI * sphere_r * sphere_r,
        TAU * TAU * torus_big * torus_small,
    ];
    let total: f32 = areas.iter().sum();
    let mut positions = Vec::with_capacity(points);
    let mut colors = Vec::with_capacity(points);
    for (surface, area) in areas.iter().enumerate() {
        let n = (points as f32 * area / total) as usize;
        for _ in 0..n {
            let (p, c) = match surface {
                0 => {
                    let p = Vec3::new(
                        rng.random_range(-floor_half..floor_half),
                        0.0,
                        rng.random_range(-floor_half..floor_half),
                    );
                    let check = ((p.x * 2.5).floor() as i32 + (p.z * 2.5).floor() as i32).rem_euclid(2) == 0;
                    (p, if check { [0.85, 0.85, 0.82] } else { [0.35, 0.37, 0.42] })
                }
                1 => (sphere_c + uniform_sphere(&mut rng) * sphere_r, [0.30, 0.52, 0.85]),
                _ => {
                    let local = uniform_torus(&mut rng, torus_big, torus_small);
                    (torus_c + torus_rot * local, [0.92, 0.55, 0.22])
                }
            };
            positions.push(p);
            colors.push(c);
        }
    }
    PointCloud { positions, colors: Some(colors), ..PointCloud::default() }
}

/// Points in the demo scene unless told otherwise (`--demo-points`).
pub const DEMO_POINTS: usize = 300_000;

/// The demo's camera, as (view direction, distance in bounding-box diagonals).
pub const DEMO_VIEW: ([f32; 3], f32) = ([0.35, 0.5, 1.0], 0.62);

/// The demo's light: high, to the left and in front, so both objects cast visible shadows.
pub fn demo_light() -> Light {
    Light::Directional { direction: Vec3::new(-0.5, 1.0, 0.6), intensity: 1.0 }
}

/// The demo scene of a [`demo_cloud`], preprocessed: seen from its own view, lit by its own
/// light (unless the settings name others).
pub fn demo_scene_parts(cloud: PointCloud) -> SceneParts {
    let view = Some((Vec3::from(DEMO_VIEW.0), DEMO_VIEW.1));
    SceneParts { cloud, view, light: Some(demo_light()), ..SceneParts::default() }
}

pub fn uniform_sphere(rng: &mut Pcg64Mcg) -> Vec3 {
    let z: f32 = rng.random_range(-1.0..1.0);
    let phi = rng.random_range(0.0..TAU);
    let s = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// Area-uniform point on a torus around the z axis (rejection on the tube angle, whose area
/// element is proportional to R + r·cos v).
pub fn uniform_torus(rng: &mut Pcg64Mcg, big: f32, small: f32) -> Vec3 {
    loop {
        let u = rng.random_range(0.0..TAU);
        let v = rng.random_range(0.0..TAU);
        let w = rng.random_range(0.0..big + small);
        if w <= big + small * v.cos() {
            let ring = big + small * v.cos();
            return Vec3::new(ring * u.cos(), ring * u.sin(), small * v.sin());
        }
    }
}
