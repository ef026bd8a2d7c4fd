//! Splat renders against the exact sphere they sample.

use glam::Vec3;
use pointray::accel::{Bvh, BvhParams, TraversalStats};
use pointray::camera::{Camera, Region};
use pointray::material::Material;
use pointray::render::{Integrator, RenderConfig, render};
use pointray::shading::Light;
use pointray::splat::scheme::{self, SurfaceHit, SurfaceScheme};

use crate::util::sphere_splats;

/// Exact hit of a ray with the unit sphere at the origin.
fn sphere_hit(origin: Vec3, dir: Vec3) -> Option<f32> {
    let b = origin.dot(dir);
    let disc = b * b - (origin.length_squared() - 1.0);
    (disc >= 0.0).then(|| -b - disc.sqrt()).filter(|t| *t > 0.0)
}

struct Errors {
    mean_t_over_r: f32,
    max_t_over_r: f32,
    mean_normal_deg: f32,
    p99_normal_deg: f32,
}

/// Hit-position and normal errors over camera rays whose exact hit is not grazing.
fn measure(scheme: SurfaceScheme) -> Errors {
    let splats = sphere_splats(100_000, 1.0, 21);
    let r = splats[0].radius;
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let cam = Camera::look_at(Vec3::new(0.3, 0.4, 3.0), Vec3::ZERO, Vec3::Y, 45.0, 96, 96);
    let (mut dt, mut dn) = (Vec::new(), Vec::new());
    for y in 0..96 {
        for x in 0..96 {
            let ray = cam.ray(x as f32 + 0.37, y as f32 + 0.61);
            let Some(t) = sphere_hit(ray.origin, ray.dir) else { continue };
            let exact_n = ray.at(t).normalize();
            if exact_n.dot(-ray.dir) < 0.3 {
                continue;
            }
            let hit = scheme::intersect(&bvh, &ray, &scheme, &mut TraversalStats::default())
                .expect("a non-grazing ray that hits the sphere must hit its splats");
            dt.push((hit.t - t).abs() / r);
            dn.push(hit.normal.dot(exact_n).clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    assert!(dt.len() > 2_000, "too few rays on the sphere: {}", dt.len());
    dn.sort_by(f32::total_cmp);
    Errors {
        mean_t_over_r: dt.iter().sum::<f32>() / dt.len() as f32,
        max_t_over_r: dt.iter().copied().fold(0.0, f32::max),
        mean_normal_deg: dn.iter().sum::<f32>() / dn.len() as f32,
        p99_normal_deg: dn[dn.len() * 99 / 100],
    }
}

#[test]
fn sj_hits_lie_on_the_sphere_with_smooth_normals() {
    let sj = measure(SurfaceScheme::sj());
    let first = measure(SurfaceScheme::first_hit());
    eprintln!(
        "sj: |dt|/r mean {:.4} max {:.4}, normal mean {:.3}° p99 {:.3}°; first-hit: |dt|/r mean {:.4} max {:.4}, normal mean {:.3}° p99 {:.3}°",
        sj.mean_t_over_r,
        sj.max_t_over_r,
        sj.mean_normal_deg,
        sj.p99_normal_deg,
        first.mean_t_over_r,
        first.max_t_over_r,
        first.mean_normal_deg,
        first.p99_normal_deg
    );
    // Measured: |dt|/r mean 0.005, max 0.025; normals mean 0.17°, p99 0.55° (first-hit 1.08°).
    assert!(sj.mean_t_over_r < 0.02 && sj.max_t_over_r < 0.1, "position error");
    assert!(sj.p99_normal_deg <= 2.0, "normal error");
    // Interpolation is the point of SJ: its normals are far closer to the truth than one disk's.
    assert!(sj.mean_normal_deg < 0.4 * first.mean_normal_deg, "SJ does not smooth the normals");
}

/// Lambert + Phong shading (or the eye light) of the exact sphere, pixel for pixel as the
/// renderer shades.
fn analytic_image(cam: &Camera, config: &RenderConfig) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    for y in 0..cam.height {
        for x in 0..cam.width {
            let ray = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            out.push(match sphere_hit(ray.origin, ray.dir) {
                None => config.environment.flat_color(),
                Some(t) => {
                    let p = ray.at(t);
                    let hit = SurfaceHit {
                        t,
                        position: p,
                        normal: p.normalize(),
                        // What the splats carry: sRGB 0.8 quantised to 8 bits, as linear.
                        color: [pointray::color::srgb_to_linear(204.0 / 255.0); 3],
                        radius: 0.0,
                        splat: 0,
                        blended: 1,
                    };
                    if config.integrator == Integrator::EyeLight {
                        (Vec3::from(hit.color) * hit.normal.dot(ray.dir).abs()).to_array()
                    } else {
                        let (l, _, e) = config.lights[0].towards(p);
                        let Material::Phong(phong) = config.materials[0] else { panic!("a Phong sphere") };
                        let lit = if hit.normal.dot(l) > 0.0 { phong.direct(&hit, -ray.dir, l, e) } else { Vec3::ZERO };
                        (phong.ambient(&hit) + lit).to_array()
                    }
                }
            });
        }
    }
    out
}

/// Pixels off the analytic image by more than 0.03, and the mean difference, of a render of
/// a grey sphere of splats.
fn sphere_against_analytic(config: &RenderConfig) -> (usize, f32) {
    let mut splats = sphere_splats(100_000, 1.0, 22);
    let grey = pointray::splat::pack_color([0.8, 0.8, 0.8]);
    splats.iter_mut().for_each(|s| s.color = grey);
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 3.2), Vec3::ZERO, Vec3::Y, 45.0, 64, 64);
    let (film, stats) = render(&bvh, &cam, config, &|_| {});
    assert!(stats.primary_hits > 1_000);
    let exact = analytic_image(&cam, config);
    let diff: Vec<f32> =
        film.rgb.iter().zip(&exact).map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0, f32::max)).collect();
    let off = diff.iter().filter(|d| **d > 0.03).count();
    let mean = diff.iter().sum::<f32>() / diff.len() as f32;
    eprintln!("pixels off by > 0.03: {off} of {}, mean |diff| {mean:.5}", diff.len());
    (off, mean)
}

#[test]
fn sphere_image_matches_the_analytic_image() {
    let config = RenderConfig {
        lights: vec![Light::Point { position: Vec3::new(2.0, 3.0, 4.0), intensity: 25.0 }],
        ..crate::util::render_config(Region::full(64, 64), 1)
    };
    let (off, mean) = sphere_against_analytic(&config);
    // Measured: no pixel off by more than 0.03, mean 0.0004. A few silhouette pixels may
    // differ (disks overhang the exact outline by up to r).
    assert!(off <= 8, "{off} pixels differ");
    assert!(mean < 0.002, "mean difference {mean}");
}

/// The eye light shows albedo × |N·D| of the exact sphere.
#[test]
fn eye_light_matches_the_analytic_cosine() {
    let config =
        RenderConfig { integrator: Integrator::EyeLight, ..crate::util::render_config(Region::full(64, 64), 1) };
    let (off, mean) = sphere_against_analytic(&config);
    // Measured: 0 pixels off, mean 0.0004.
    assert!(off <= 8, "{off} pixels differ");
    assert!(mean < 0.002, "mean difference {mean}");
}
