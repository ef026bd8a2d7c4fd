//! The path tracer against scenes whose answers are known: an object in a uniform white
//! environment, with no lights, shows its albedo (a convex one, after one bounce) or, with
//! albedo 1, exactly the environment (energy is conserved however the light bounces); a plane
//! under a sun of intensity I shows albedo × I cos θ (next-event estimation), as Whitted's
//! Phong does, and under a sky whose radiance is the sine of the elevation, 2/3 of its albedo
//! (the cosine-distributed bounces).

use glam::Vec3;
use pointray::accel::{Bvh, BvhParams};
use pointray::camera::{Camera, Region};
use pointray::render::{Integrator, RenderConfig, render};
use pointray::shading::Environment;
use pointray::splat::{Splat, pack_color};

use pointray::material::{Material, Phong};
use pointray::shading::Light;

use crate::util::{plane_splats, render_config, sphere_splats, torus_splats};

/// Mean and largest deviation from `expected` over the pixels wholly on the splats, rendered
/// by the path tracer in a uniform environment of radiance 1.
fn furnace(mut splats: Vec<Splat>, srgb: f32, expected: f32, max_depth: u32) -> (f32, f32) {
    splats.iter_mut().for_each(|s| s.color = pack_color([srgb; 3]));
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let cam = Camera::look_at(Vec3::new(0.5, 1.8, 2.6), Vec3::ZERO, Vec3::Y, 50.0, 64, 64);
    let config = RenderConfig {
        integrator: Integrator::Path,
        environment: Environment::Uniform { color: [1.0; 3] },
        max_depth,
        seed: 3,
        ..render_config(Region::full(64, 64), 16)
    };
    let (film, _) = render(&bvh, &cam, &config, &|_| {});
    // Pixels whose every sample hit: their mean normal is (nearly) unit; a miss counts zero.
    let covered = |n: &[f32; 3]| Vec3::from(*n).length() > 0.99;
    let normal = &film.first_hits.as_ref().expect("first hits recorded").normal;
    let hits: Vec<f32> = film.rgb.iter().zip(normal).filter(|(_, n)| covered(n)).map(|(c, _)| c[1]).collect();
    assert!(hits.len() > 500, "{} hit pixels", hits.len());
    let mean = hits.iter().sum::<f32>() / hits.len() as f32;
    let worst = hits.iter().map(|v| (v - expected).abs()).fold(0.0, f32::max);
    (mean, worst)
}

#[test]
fn a_grey_convex_sphere_in_a_white_furnace_shows_its_albedo() {
    // sRGB 188 is linear 0.5029: one cosine-distributed bounce off a convex surface always
    // escapes, so every path carries exactly the albedo.
    let albedo = pointray::color::srgb_to_linear(188.0 / 255.0);
    let (mean, worst) = furnace(sphere_splats(60_000, 1.0, 51), 188.0 / 255.0, albedo, 8);
    eprintln!("grey sphere: mean {mean:.5} (expected {albedo:.5}), worst pixel off by {worst:.5}");
    // Measured: every covered pixel exactly the albedo (the secondary rays never come back).
    assert!((mean - albedo).abs() < 1e-4 && worst < 1e-3, "mean {mean}, worst {worst}");
}

#[test]
fn a_white_torus_in_a_white_furnace_disappears() {
    // Albedo 1: whatever path the light takes through the hole, it arrives undiminished.
    let (mean, worst) = furnace(torus_splats(60_000, 52), 1.0, 1.0, 64);
    eprintln!("white torus: mean {mean:.5} (expected 1), worst pixel off by {worst:.5}");
    // Measured: mean 1.00004; single pixels off by up to 0.0625 (Russian roulette at 16 samples).
    assert!((mean - 1.0).abs() < 0.005, "mean {mean}");
}

/// The path tracer's mean over a Lambert plane (the standard material's highlight left out),
/// and the plane's albedo; see [`plane_green`].
fn plane_mean(lights: Vec<Light>, sky: Environment, samples: u32) -> (f32, f32) {
    let lambert = Material::Phong(Phong { specular: 0.0, ..Phong::standard() });
    plane_mean_with(Integrator::Path, lambert, lights, sky, samples)
}

/// The mean of [`plane_green`], and the plane's albedo.
fn plane_mean_with(
    integrator: Integrator,
    material: Material,
    lights: Vec<Light>,
    sky: Environment,
    samples: u32,
) -> (f32, f32) {
    let green = plane_green(integrator, material, lights, sky, samples);
    (green.iter().sum::<f32>() / green.len() as f32, pointray::color::srgb_to_linear(188.0 / 255.0))
}

/// The green channel of a plane of splats (z = 0, normal +z, albedo from sRGB 188) seen from
/// straight above, filling the 32 × 32 frame, rendered by `integrator` with `lights` and `sky`.
fn plane_green(
    integrator: Integrator,
    material: Material,
    lights: Vec<Light>,
    sky: Environment,
    samples: u32,
) -> Vec<f32> {
    let mut splats = plane_splats(40_000, 53);
    splats.iter_mut().for_each(|s| s.color = pack_color([188.0 / 255.0; 3]));
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 30.0, 32, 32);
    let config = RenderConfig {
        integrator,
        materials: vec![material],
        lights,
        environment: sky,
        max_depth: 6,
        seed: 4,
        ..render_config(Region::full(32, 32), samples)
    };
    let (film, _) = render(&bvh, &cam, &config, &|_| {});
    let depth = &film.first_hits.as_ref().expect("first hits recorded").depth;
    assert!(depth.iter().all(|d| d.is_finite()), "the plane fills the frame");
    film.rgb.iter().map(|c| c[1]).collect()
}

#[test]
fn a_plane_under_a_sun_shows_albedo_times_intensity_cos() {
    let direction = Vec3::new(0.3, 0.0, 1.0);
    let sun = Light::Directional { direction, intensity: 0.6 };
    let (mean, albedo) = plane_mean(vec![sun], Environment::Uniform { color: [0.0; 3] }, 1);
    let expected = albedo * 0.6 * direction.normalize().z;
    eprintln!("plane under a sun: {mean:.5}, expected {expected:.5}");
    assert!((mean - expected).abs() < 1e-4 * expected.max(1.0), "{mean} against {expected}");
}

#[test]
fn whitted_and_the_path_tracer_agree_on_direct_light() {
    // A Lambert surface (no ambient, no specular lobe) under a sun in the dark: Whitted's
    // Phong and the path tracer's next-event estimation must give the same radiance, so a
    // scene keeps its brightness whichever integrator renders it. Each kind of light; the
    // sphere's shadow rays are random, but nothing is there to shadow.
    let lambert = Material::Phong(Phong { ambient: 0.0, specular: 0.0, shininess: 1.0 });
    let dark = Environment::Uniform { color: [0.0; 3] };
    let lights = [
        Light::Directional { direction: Vec3::new(0.3, -0.2, 1.0), intensity: 0.7 },
        Light::Point { position: Vec3::new(0.2, 0.1, 1.5), intensity: 0.9 },
        Light::Sphere { center: Vec3::new(-0.3, 0.2, 1.2), radius: 0.2, intensity: 0.5 },
        Light::Spot {
            position: Vec3::new(0.0, 0.0, 2.0),
            direction: Vec3::NEG_Z,
            inner: 0.2,
            outer: 0.4,
            intensity: 2.0,
        },
    ];
    for light in lights {
        let (whitted, _) = plane_mean_with(Integrator::Whitted, lambert, vec![light], dark.clone(), 1);
        let (path, _) = plane_mean_with(Integrator::Path, lambert, vec![light], dark.clone(), 1);
        eprintln!("{light:?}: Whitted {whitted:.5}, path tracer {path:.5}");
        assert!(whitted > 0.01 && (whitted - path).abs() < 1e-5 * whitted.max(1.0), "{whitted} against {path}");
    }
}

/// The brightest pixel of [`plane_green`] under `light` in the dark, its value, and the mean.
fn highlight(integrator: Integrator, material: Material, light: Light) -> (usize, f32, f32) {
    let green = plane_green(integrator, material, vec![light], Environment::Uniform { color: [0.0; 3] }, 1);
    let (at, peak) = green.iter().enumerate().fold((0, 0.0f32), |m, (i, &g)| if g > m.1 { (i, g) } else { m });
    (at, peak, green.iter().sum::<f32>() / green.len() as f32)
}

#[test]
fn whitted_and_the_path_tracer_draw_one_highlight() {
    // A glossy Lambert surface (no ambient) under a point light in the dark: the path tracer
    // adds the same lobe to its light samples as Whitted adds to each light, so the highlight
    // lies on the same pixel with the same brightness, and the frame's mean agrees.
    let glossy = Material::Phong(Phong { ambient: 0.0, specular: 0.5, shininess: 40.0 });
    let lambert = Material::Phong(Phong { ambient: 0.0, specular: 0.0, shininess: 1.0 });
    let light = Light::Point { position: Vec3::new(0.4, 0.2, 1.5), intensity: 0.9 };
    let (w_at, w_peak, w_mean) = highlight(Integrator::Whitted, glossy, light);
    let (p_at, p_peak, p_mean) = highlight(Integrator::Path, glossy, light);
    let (_, matte_peak, _) = highlight(Integrator::Path, lambert, light);
    eprintln!("Whitted {w_at} {w_peak:.5} {w_mean:.5}, path {p_at} {p_peak:.5} {p_mean:.5}, matte {matte_peak:.5}");
    assert!(w_peak > 1.5 * matte_peak, "no highlight: {w_peak} against {matte_peak}");
    assert_eq!(w_at, p_at);
    assert!((w_peak - p_peak).abs() < 1e-5 && (w_mean - p_mean).abs() < 1e-5, "{w_peak} {p_peak} {w_mean} {p_mean}");
}

#[test]
fn a_plane_under_a_graded_sky_shows_two_thirds_of_its_albedo() {
    // L(ω) = cos θ above the horizon: ∫ L cos θ dω / π = 2/3 of the albedo.
    let sky = Environment::Gradient { up: Vec3::Z, zenith: [1.0; 3], horizon: [0.0; 3], ground: [0.0; 3] };
    let (mean, albedo) = plane_mean(Vec::new(), sky, 64);
    let expected = albedo * 2.0 / 3.0;
    eprintln!("plane under the sky: {mean:.5}, expected {expected:.5}");
    // 65,536 samples of a quantity with standard deviation 0.236 × albedo: 0.0009 × albedo.
    assert!((mean - expected).abs() < 0.005 * albedo, "{mean} against {expected}");
}

/// Ambient occlusion at the point (−0.05, 0, 0) of a floor, with or without a wall x = 0
/// beside it (2 wide, 2 tall): the visible fraction of the cosine-weighted sky.
fn occlusion_beside_a_wall(wall: bool) -> f32 {
    let mut splats = plane_splats(40_000, 54);
    if wall {
        let mut w = plane_splats(40_000, 55);
        w.iter_mut().for_each(|s| {
            s.center = Vec3::new(0.0, s.center.y, s.center.x + 1.0);
            s.normal = Vec3::NEG_X;
        });
        splats.extend(w);
    }
    splats.iter_mut().for_each(|s| s.color = pack_color([1.0; 3]));
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let point = Vec3::new(-0.05, 0.0, 0.0);
    let cam = Camera::look_at(Vec3::new(-1.0, 0.0, 1.0), point, Vec3::Z, 20.0, 65, 65);
    let (px, py) = cam.project(point).unwrap();
    let config = RenderConfig {
        integrator: Integrator::Ao,
        ao_distance: 100.0,
        max_depth: 1,
        seed: 5,
        ..render_config(Region { x0: px as u32, y0: py as u32, x1: px as u32 + 1, y1: py as u32 + 1 }, 4096)
    };
    render(&bvh, &cam, &config, &|_| {}).0.rgb[0][1]
}

#[test]
fn ambient_occlusion_is_one_in_the_open_and_about_half_beside_a_wall() {
    assert_eq!(occlusion_beside_a_wall(false), 1.0, "nothing occludes an open floor");
    // An infinite wall would hide exactly the half of the hemisphere facing it, whatever its
    // distance (half of the cosine-weighted directions); this one, 40 times as wide as its
    // distance, a little less. 4,096 samples: standard deviation 0.008.
    let beside = occlusion_beside_a_wall(true);
    eprintln!("open fraction beside the wall: {beside:.4}");
    assert!((0.5..0.56).contains(&beside), "{beside}");
}

/// A sphere's coverage of each pixel (ambient occlusion of a convex white sphere on black is
/// exactly 1 where the sphere is), estimated with `samples` camera rays per pixel.
fn coverage(sampler: pointray::render::Sampler, samples: u32) -> Vec<f32> {
    let mut splats = sphere_splats(60_000, 1.0, 56);
    splats.iter_mut().for_each(|s| s.color = pack_color([1.0; 3]));
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 30.0, 48, 48);
    let config = RenderConfig {
        sampler,
        integrator: Integrator::Ao,
        ao_distance: 1.0,
        max_depth: 1,
        seed: 8,
        ..render_config(Region::full(48, 48), samples)
    };
    render(&bvh, &cam, &config, &|_| {}).0.rgb.iter().map(|c| c[1]).collect()
}

#[test]
fn low_discrepancy_samples_find_edges_faster_than_independent_ones() {
    use pointray::render::Sampler;
    let truth = coverage(Sampler::Random, 2048);
    let rms = |estimate: &[f32]| {
        let edge: Vec<f32> = estimate
            .iter()
            .zip(&truth)
            .filter(|(_, t)| **t > 0.02 && **t < 0.98)
            .map(|(e, t)| (e - t).powi(2))
            .collect();
        (edge.iter().sum::<f32>() / edge.len() as f32).sqrt()
    };
    let (random, r2) = (rms(&coverage(Sampler::Random, 16)), rms(&coverage(Sampler::R2, 16)));
    eprintln!("edge pixels' RMS error at 16 samples: random {random:.4}, R2 {r2:.4}");
    // Measured: random 0.103, R2 0.058.
    assert!(r2 < 0.75 * random, "random {random}, R2 {r2}");
}

/// A map around a z-up world: a sky of radiance 0.3 above the horizon, dark below, and a
/// sun: 2 × 2 texels (1.4° across) of radiance 4,000, 40° from the zenith.
fn sun_and_sky() -> (std::sync::Arc<pointray::env_map::EnvMap>, pointray::env_map::EnvFrame) {
    let (w, h) = (256, 128);
    let mut texels: Vec<[f32; 3]> = (0..w * h).map(|i| if i / w < h / 2 { [0.3; 3] } else { [0.0; 3] }).collect();
    let sun_row = (40.0 / 180.0 * h as f32) as usize;
    for y in sun_row..sun_row + 2 {
        for x in 100..102 {
            texels[y * w + x] = [4000.0; 3];
        }
    }
    let map = pointray::env_map::EnvMap::new(w, h, texels).unwrap();
    (std::sync::Arc::new(map), pointray::env_map::EnvFrame::new(Vec3::Z, 25.0))
}

/// The irradiance on a face looking up (+z) under `map`, by quadrature of the radiance the
/// renderer looks up, over a fine grid of the upper hemisphere.
fn irradiance_up(map: &pointray::env_map::EnvMap, frame: &pointray::env_map::EnvFrame) -> f32 {
    let (n, m) = (1200, 2400);
    let mut e = 0.0f64;
    for i in 0..n {
        let theta = (i as f64 + 0.5) / n as f64 * std::f64::consts::FRAC_PI_2;
        let d_omega = theta.sin() * (std::f64::consts::FRAC_PI_2 / n as f64) * (std::f64::consts::TAU / m as f64);
        for j in 0..m {
            let phi = (j as f64 + 0.5) / m as f64 * std::f64::consts::TAU;
            let d = Vec3::new((theta.sin() * phi.cos()) as f32, (theta.sin() * phi.sin()) as f32, theta.cos() as f32);
            e += f64::from(map.radiance(frame, d).y) * theta.cos() * d_omega;
        }
    }
    e as f32
}

#[test]
fn a_plane_under_an_environment_map_with_a_sun_converges_to_its_irradiance() {
    // The path tracer samples the map by luminance and weighs those samples against its
    // cosine-distributed bounces: the sun, 83 % of the light from a 4,000th of the sky,
    // which bounces alone would seldom find, comes out right at 16 samples.
    let (map, frame) = sun_and_sky();
    let expected_e = irradiance_up(&map, &frame);
    let sky = Environment::Map { map, frame };
    let green =
        plane_green(Integrator::Path, Material::Phong(Phong { specular: 0.0, ..Phong::standard() }), vec![], sky, 16);
    let albedo = pointray::color::srgb_to_linear(188.0 / 255.0);
    let mean = green.iter().sum::<f32>() / green.len() as f32;
    let spread = (green.iter().map(|g| (g - mean).powi(2)).sum::<f32>() / green.len() as f32).sqrt();
    let expected = albedo * expected_e / std::f32::consts::PI;
    eprintln!("plane under a sun and sky map: {mean:.4} ± {spread:.4} a pixel, expected {expected:.4}");
    // Measured: the mean 0.2 % off; the pixels spread 21 % about it (10 % at 64 samples). A
    // density from the texels unfiltered, which left the sun's bilinear fringe to the bounces,
    // spread them 3.9 about a mean of 1.1.
    assert!((mean / expected - 1.0).abs() < 0.01, "{mean} against {expected}");
    assert!(spread < 0.3 * expected, "pixels spread {spread} about {mean}");
}

#[test]
fn whitted_takes_a_maps_irradiance_as_its_ambient_light() {
    // No lights, a uniform map of radiance 0.4: a Lambert plane facing up gets E = 0.4π, and
    // shows albedo × E / π, the path tracer's answer.
    let map = pointray::env_map::EnvMap::new(16, 8, vec![[0.4; 3]; 128]).unwrap();
    let sky = Environment::Map { map: std::sync::Arc::new(map), frame: pointray::env_map::EnvFrame::new(Vec3::Z, 0.0) };
    let lambert = Material::Phong(Phong { specular: 0.0, ..Phong::standard() });
    let (whitted, albedo) = plane_mean_with(Integrator::Whitted, lambert, vec![], sky.clone(), 1);
    let (path, _) = plane_mean_with(Integrator::Path, lambert, vec![], sky, 16);
    eprintln!("plane in a uniform map: Whitted {whitted:.4}, path {path:.4}, expected {:.4}", albedo * 0.4);
    assert!((whitted / (albedo * 0.4) - 1.0).abs() < 0.01, "{whitted}");
    assert!((path / (albedo * 0.4) - 1.0).abs() < 0.01, "{path}");
}

#[test]
fn a_background_hides_the_environment_from_camera_rays_only() {
    // A grey sphere in a white furnace, behind a black background: the missed pixels are
    // black, the sphere still shows its albedo (its bounced rays see the environment).
    let mut splats = sphere_splats(20_000, 1.0, 54);
    splats.iter_mut().for_each(|s| s.color = pack_color([188.0 / 255.0; 3]));
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 40.0, 32, 32);
    let config = RenderConfig {
        integrator: Integrator::Path,
        environment: Environment::Uniform { color: [1.0; 3] },
        background: Some([0.0; 3]),
        seed: 5,
        ..render_config(Region::full(32, 32), 4)
    };
    let (film, _) = render(&bvh, &cam, &config, &|_| {});
    let albedo = pointray::color::srgb_to_linear(188.0 / 255.0);
    let (corner, centre) = (film.rgb[0][1], film.rgb[16 * 32 + 16][1]);
    assert_eq!(corner, 0.0);
    assert!((centre - albedo).abs() < 1e-3, "{centre} against {albedo}");
}
