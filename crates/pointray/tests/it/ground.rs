//! The analytic ground plane with splats on and over it: its exact shading and the shadow a
//! sphere of splats casts on it, no shadow acne at grazing light, and energy conserved when
//! light bounces between the plane and the splats.

use glam::Vec3;
use pointray::accel::{Bvh, BvhParams};
use pointray::camera::{Camera, Region};
use pointray::ground::GroundPlane;
use pointray::material::{Material, Phong};
use pointray::render::{Integrator, RenderConfig, render};
use pointray::shading::{Environment, Light};
use pointray::splat::pack_color;
use pointray::splat::scheme::SurfaceHit;

use crate::util::{render_config, sphere_splats};

const SIZE: u32 = 96;
const PHONG: Phong = Phong { ambient: 0.1, specular: 0.2, shininess: 20.0 };

fn ground(color: f32) -> GroundPlane {
    GroundPlane { up: Vec3::Z, height: 0.0, color: [color; 3], checker: None, material: Material::Phong(PHONG) }
}

fn camera() -> Camera {
    Camera::look_at(Vec3::new(0.0, -3.0, 3.0), Vec3::ZERO, Vec3::Z, 30.0, SIZE, SIZE)
}

/// Renders a sphere of splats of radius 0.5 centred at `center` over the plane z = 0 under a
/// directional light, one sample through each pixel's centre. Returns each pixel's camera
/// ray with its green value.
fn whitted(center: Vec3, light: Vec3) -> Vec<(pointray::math::Ray, f32)> {
    let mut splats = sphere_splats(20_000, 0.5, 11);
    splats.iter_mut().for_each(|s| s.center += center);
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let config = RenderConfig {
        lights: vec![Light::Directional { direction: light, intensity: 1.0 }],
        materials: vec![Material::Phong(PHONG)],
        ground: Some(ground(0.6)),
        ..render_config(Region::full(SIZE, SIZE), 1)
    };
    let (film, _) = render(&bvh, &camera(), &config, &|_| {});
    let cam = camera();
    (0..SIZE * SIZE)
        .map(|i| (cam.ray((i % SIZE) as f32 + 0.5, (i / SIZE) as f32 + 0.5), film.rgb[i as usize][1]))
        .collect()
}

/// What the plane shows at the ground hit of `ray`, lit or in shadow.
fn plane_value(ray: &pointray::math::Ray, light: Vec3, lit: bool) -> (Vec3, f32) {
    let t = -ray.origin.z / ray.dir.z;
    let position = ray.at(t);
    let hit = SurfaceHit { t, position, normal: Vec3::Z, color: [0.6; 3], radius: 0.0, splat: 0, blended: 0 };
    let mut value = PHONG.ambient(&hit);
    if lit {
        value += PHONG.direct(&hit, -ray.dir, light.normalize(), 1.0);
    }
    (position, value.y)
}

#[test]
fn a_sphere_over_the_ground_casts_the_shadow_of_its_outline() {
    // Light from straight above: the shadow is the sphere's disk of radius 0.5 around the axis.
    let pixels = whitted(Vec3::new(0.0, 0.0, 0.8), Vec3::Z);
    let (mut lit, mut shadowed) = (0, 0);
    for (ray, value) in pixels {
        // Pixels whose ray passes near the sphere show the sphere, not the ground.
        let to_center = Vec3::new(0.0, 0.0, 0.8) - ray.origin;
        if to_center.cross(ray.dir).length() < 0.6 || ray.dir.z >= 0.0 {
            continue;
        }
        let (position, _) = plane_value(&ray, Vec3::Z, true);
        let off_axis = position.truncate().length();
        // The splats' disks overhang the sphere's outline by a fraction of their radius.
        if (0.47..0.56).contains(&off_axis) {
            continue;
        }
        let in_shadow = off_axis < 0.5;
        let (_, expected) = plane_value(&ray, Vec3::Z, !in_shadow);
        assert!((value - expected).abs() < 1e-5, "at {position}: {value}, expected {expected}");
        if in_shadow { shadowed += 1 } else { lit += 1 }
    }
    assert!(shadowed > 100 && lit > 3000, "{shadowed} shadowed and {lit} lit pixels checked");
}

#[test]
fn grazing_light_leaves_the_ground_free_of_acne() {
    // 88° from the normal, the sphere far below the plane, out of sight and of the light:
    // every shadow ray leaves the plane at 2°, and every ground pixel is exactly lit.
    let light = Vec3::new((88f32).to_radians().sin(), 0.0, (88f32).to_radians().cos());
    let pixels = whitted(Vec3::new(0.0, 0.0, -50.0), light);
    let mut checked = 0;
    for (ray, value) in pixels.into_iter().filter(|(ray, _)| ray.dir.z < 0.0) {
        let (position, expected) = plane_value(&ray, light, true);
        assert!((value - expected).abs() < 1e-5, "at {position}: {value}, expected {expected}");
        checked += 1;
    }
    assert_eq!(checked, SIZE * SIZE, "the whole view is ground");
}

#[test]
fn a_white_sphere_on_a_white_ground_in_a_white_furnace_shows_the_environment() {
    // Albedo 1 everywhere in a uniform environment of radiance 1: every path brings back 1
    // however often it bounces between the sphere and the plane (Russian roulette keeps the
    // mean), so the image's mean is 1 and only truncation at max_depth can lower it.
    let mut splats = sphere_splats(20_000, 0.5, 12);
    splats.iter_mut().for_each(|s| {
        s.center.z += 0.5;
        s.color = pack_color([1.0; 3]);
    });
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let config = RenderConfig {
        integrator: Integrator::Path,
        environment: Environment::Uniform { color: [1.0; 3] },
        ground: Some(ground(1.0)),
        max_depth: 64,
        seed: 5,
        ..render_config(Region::full(SIZE, SIZE), 16)
    };
    let (film, stats) = render(&bvh, &camera(), &config, &|_| {});
    let mean = film.rgb.iter().map(|c| f64::from(c[1])).sum::<f64>() / film.rgb.len() as f64;
    let camera_rays = u64::from(SIZE * SIZE * 16);
    eprintln!(
        "furnace with ground: mean {mean:.5}, {} of {camera_rays} camera rays meet splats, {} secondary rays",
        stats.primary_hits, stats.secondary_rays
    );
    // Camera rays meet the sphere, every one that does not meets the ground, and some paths
    // bounce between the two. Measured: mean 0.99990.
    assert!(stats.primary_hits > camera_rays / 10 && stats.secondary_rays > camera_rays + camera_rays / 20);
    assert!((mean - 1.0).abs() < 0.002, "mean {mean}");
}
