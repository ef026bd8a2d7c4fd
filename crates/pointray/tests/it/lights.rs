//! Soft shadows from a spherical light, against what symmetry says they must be.

use glam::Vec3;
use pointray::accel::{Bvh, BvhParams};
use pointray::camera::{Camera, Region};
use pointray::material::{Material, Phong};
use pointray::render::{RenderConfig, render};
use pointray::shading::Light;

use crate::util::{plane_splats, render_config};

/// A receiver plane z = 0 under a sheet at z = 0.5 covering x < 0, lit by a sphere of radius
/// 0.3 centred 1.5 above the origin. Returns the visible fraction of the light at receiver
/// points (x, 0, 0): the pixel there with the sheet, over the same pixel without it. Phong
/// without ambient or specular, so a pixel is visibility × direct light.
fn visibility(xs: &[f32], light_radius: f32, samples: u32) -> Vec<f32> {
    let receiver = plane_splats(60_000, 41);
    let mut sheet = plane_splats(30_000, 42);
    // [−1, 1]² → x ∈ [−1.6, 0], y ∈ [−1, 1], at z = 0.5.
    sheet.iter_mut().for_each(|s| s.center = Vec3::new(s.center.x * 0.8 - 0.8, s.center.y, 0.5));
    let with = Bvh::build([receiver.clone(), sheet].concat(), &BvhParams::standard());
    let without = Bvh::build(receiver, &BvhParams::standard());
    // Low and to the side, under the sheet's level: it sees the receiver, not the sheet.
    let cam = Camera::look_at(Vec3::new(0.0, -3.0, 0.15), Vec3::ZERO, Vec3::Z, 30.0, 256, 256);
    let config = |x: u32, y: u32| RenderConfig {
        lights: vec![Light::Sphere { center: Vec3::new(0.0, 0.0, 1.5), radius: light_radius, intensity: 1.0 }],
        materials: vec![Material::Phong(Phong { ambient: 0.0, specular: 0.0, shininess: 1.0 })],
        max_depth: 1,
        seed: 7,
        ..render_config(Region { x0: x, y0: y, x1: x + 1, y1: y + 1 }, samples)
    };
    xs.iter()
        .map(|&x| {
            let (px, py) = cam.project(Vec3::new(x, 0.0, 0.0)).unwrap();
            let c = config(px as u32, py as u32);
            let (lit, _) = render(&with, &cam, &c, &|_| {});
            let (full, _) = render(&without, &cam, &c, &|_| {});
            lit.rgb[0][1] / full.rgb[0][1]
        })
        .collect()
}

#[test]
fn a_sphere_light_casts_a_penumbra_half_lit_where_the_hard_shadow_ends() {
    // Where a point light at the sphere's centre puts the shadow's edge (bisection; the
    // sheet's disks overhang its centres by a fraction of their radius).
    let (mut shadowed, mut lit) = (-0.1f32, 0.1f32);
    for _ in 0..10 {
        let mid = 0.5 * (shadowed + lit);
        if visibility(&[mid], 0.0, 1)[0] > 0.5 {
            lit = mid;
        } else {
            shadowed = mid;
        }
    }
    let edge = 0.5 * (shadowed + lit);
    let xs = [-0.3, edge - 0.05, edge, edge + 0.05, 0.3];
    let soft = visibility(&xs, 0.3, 1024);
    eprintln!("hard edge at x = {edge:.4}; visible fraction of the light at x = {xs:?}: {soft:?}");
    // There the sheet hides half of the light's disc, by symmetry. With 1,024 samples the
    // estimate's standard deviation is 0.016. Measured: 0.474 (edge at x = 0.031), 0.289 and
    // 0.711 at 0.05 either side.
    assert!((soft[2] - 0.5).abs() < 0.06, "{soft:?}");
    // The penumbra is 0.2 wide: beyond it, umbra and full light; within it, a steady rise.
    assert!(soft[0] < 0.02 && soft[4] > 0.98, "{soft:?}");
    assert!(soft.windows(2).all(|w| w[0] < w[1]), "{soft:?}");
    // The point light's shadow has no penumbra where the sphere's is half lit. (Closer to
    // the edge a pixel, stretched along y by the grazing view, straddles the disks' ragged
    // outline.)
    assert_eq!(visibility(&[edge - 0.05, edge + 0.05], 0.0, 16), [0.0, 1.0]);
}
