//! Every surface scheme against the analytic surfaces its splats sample: a sphere, a torus and
//! a plane seen at grazing angles. Errors are in units of the mean point spacing
//! √(area / n); the tolerances sit a little above what was measured (printed with
//! `--nocapture`), so that a regression breaks them.

use glam::{Vec2, Vec3};
use pointray::accel::{Bvh, BvhParams, TraversalStats};
use pointray::camera::Camera;
use pointray::math::Ray;
use pointray::splat::scheme::{self, SurfaceKind, SurfaceScheme};
use pointray::splat::{DiskShape, Splat};

use crate::util::{plane_splats, sphere_splats, torus_splats};

/// A surface known exactly: its first hit along a ray and its normal there.
struct Exact {
    name: &'static str,
    splats: Vec<Splat>,
    spacing: f32,
    hit: fn(&Ray) -> Option<f32>,
    normal: fn(Vec3) -> Vec3,
}

fn sphere() -> Exact {
    let n = 50_000;
    Exact {
        name: "sphere",
        splats: sphere_splats(n, 1.0, 31),
        spacing: (4.0 * std::f32::consts::PI / n as f32).sqrt(),
        hit: |ray| {
            let b = ray.origin.dot(ray.dir);
            let disc = b * b - (ray.origin.length_squared() - 1.0);
            (disc >= 0.0).then(|| -b - disc.sqrt()).filter(|t| *t > 0.0)
        },
        normal: |p| p.normalize(),
    }
}

const BIG: f32 = 1.0;
const SMALL: f32 = 0.35;

fn torus_distance(p: Vec3) -> f32 {
    Vec2::new(Vec2::new(p.x, p.y).length() - BIG, p.z).length() - SMALL
}

fn torus() -> Exact {
    let n = 50_000;
    let area = 4.0 * std::f32::consts::PI * std::f32::consts::PI * BIG * SMALL;
    Exact {
        name: "torus",
        splats: torus_splats(n, 32),
        spacing: (area / n as f32).sqrt(),
        // Sphere tracing on the distance function, then bisection across the sign change.
        hit: |ray| {
            let mut t = 0.0;
            for _ in 0..400 {
                let d = torus_distance(ray.at(t));
                if d < 1e-4 {
                    let (mut lo, mut hi) = (t - 2e-4, t + 2e-4);
                    for _ in 0..40 {
                        let mid = 0.5 * (lo + hi);
                        if torus_distance(ray.at(mid)) > 0.0 { lo = mid } else { hi = mid }
                    }
                    return Some(0.5 * (lo + hi));
                }
                t += d;
                if t > 20.0 {
                    return None;
                }
            }
            None
        },
        normal: |p| (p - Vec3::new(p.x, p.y, 0.0).normalize() * BIG).normalize(),
    }
}

fn plane() -> Exact {
    let n = 40_000;
    Exact {
        name: "plane",
        splats: plane_splats(n, 33),
        spacing: (4.0 / n as f32).sqrt(),
        hit: |ray| {
            let t = -ray.origin.z / ray.dir.z;
            let p = ray.at(t);
            (t > 0.0 && p.x.abs() < 0.9 && p.y.abs() < 0.9).then_some(t)
        },
        normal: |_| Vec3::Z,
    }
}

/// What a scheme makes of one surface, over one camera's rays.
#[derive(Debug, Default)]
struct Errors {
    /// Rays whose exact hit faces the camera at cos ≥ `min_cos`.
    rays: usize,
    /// Of those, rays the scheme missed.
    misses: usize,
    mean_dt: f32,
    p99_dt: f32,
    mean_normal_deg: f32,
    p99_normal_deg: f32,
    pss_steps_per_hit: f32,
    pss_fallbacks: u64,
}

fn p99(mut v: Vec<f32>) -> f32 {
    v.sort_by(f32::total_cmp);
    v.get(v.len() * 99 / 100).copied().unwrap_or(0.0)
}

/// Rays from `eye` over a 96² image; only those whose exact hit has cos ∈ [min_cos, max_cos]
/// with the ray count.
fn measure(s: &Exact, bvh: &Bvh, scheme: &SurfaceScheme, eye: Vec3, cos: (f32, f32)) -> Errors {
    let cam =
        Camera::look_at(eye, Vec3::ZERO, Vec3::Z.cross(eye).try_normalize().map_or(Vec3::Y, |_| Vec3::Z), 40.0, 96, 96);
    let (mut dt, mut dn, mut e) = (Vec::new(), Vec::new(), Errors::default());
    let mut stats = TraversalStats::default();
    for y in 0..96 {
        for x in 0..96 {
            let ray = cam.ray(x as f32 + 0.37, y as f32 + 0.61);
            let Some(t) = (s.hit)(&ray) else { continue };
            let n = (s.normal)(ray.at(t));
            let c = n.dot(-ray.dir).abs();
            if c < cos.0 || c > cos.1 {
                continue;
            }
            e.rays += 1;
            let Some(hit) = scheme::intersect(bvh, &ray, scheme, &mut stats) else {
                e.misses += 1;
                continue;
            };
            dt.push((hit.t - t).abs() / s.spacing);
            dn.push(hit.normal.dot(n).abs().min(1.0).acos().to_degrees());
        }
    }
    let hits = dt.len().max(1) as f32;
    e.mean_dt = dt.iter().sum::<f32>() / hits;
    e.mean_normal_deg = dn.iter().sum::<f32>() / hits;
    e.p99_dt = p99(dt);
    e.p99_normal_deg = p99(dn);
    e.pss_steps_per_hit = stats.pss_steps as f32 / hits;
    e.pss_fallbacks = stats.pss_fallbacks;
    e
}

fn schemes() -> [(&'static str, SurfaceScheme); 5] {
    [
        ("sj", SurfaceScheme::sj()),
        ("rfd", SurfaceScheme::rfd()),
        ("rfd-window", SurfaceScheme { tangent_planes: false, ..SurfaceScheme::rfd() }),
        ("pss", SurfaceScheme::pss()),
        ("first-hit", SurfaceScheme::first_hit()),
    ]
}

/// A BVH whose bounds hold ray-facing disks, so that one serves every scheme.
fn bvh(s: &Exact) -> Bvh {
    Bvh::build(s.splats.clone(), &BvhParams { shape: DiskShape::RayFacing, ..BvhParams::standard() })
}

/// Per surface and scheme: (mean |Δt|, p99 |Δt|) in spacings and (mean, p99) normal error in
/// degrees, at most. Measured values in the comments.
#[test]
fn every_scheme_meets_the_analytic_surfaces() {
    for s in [sphere(), torus(), plane()] {
        let bvh = bvh(&s);
        // The plane is seen at 15° above its surface; the others from a general direction, rays
        // at least 17° off grazing.
        let (eye, cos) = if s.name == "plane" {
            (Vec3::new(0.0, -2.6, 0.7), (0.0, 1.0))
        } else {
            (Vec3::new(0.9, -2.2, 1.6), (0.3, 1.0))
        };
        for (name, scheme) in schemes() {
            let e = measure(&s, &bvh, &scheme, eye, cos);
            eprintln!("{} {name}: {e:?}", s.name);
            assert!(e.rays > 1_500, "{} {name}: too few rays ({})", s.name, e.rays);
            assert_eq!(e.misses, 0, "{} {name}: holes", s.name);
            let (dt, dt99, n, n99) = bound(s.name, name);
            assert!(e.mean_dt <= dt && e.p99_dt <= dt99, "{} {name}: position error {e:?}", s.name);
            assert!(e.mean_normal_deg <= n && e.p99_normal_deg <= n99, "{} {name}: normal error {e:?}", s.name);
            if scheme.kind == SurfaceKind::Pss {
                // A smooth surface: a few steps and no fallback (measured: sphere 2.04, torus
                // 2.11, plane 1 step per hit).
                assert!(e.pss_steps_per_hit < 3.0 && e.pss_fallbacks == 0, "{} pss: {e:?}", s.name);
            }
        }
    }
}

/// Tolerances: mean and p99 |Δt| in spacings, mean and p99 normal error in degrees; the
/// measured values (sphere 50k points, torus 50k, plane 40k) in the comments. Every scheme's
/// normals beat first-hit's flat disks; RFD's positions come from the splats' tangent planes
/// (`rfd`) or from the centres' projections (`rfd-window`), ten times farther off.
fn bound(surface: &str, scheme: &str) -> (f32, f32, f32, f32) {
    match (surface, scheme) {
        ("sphere", "sj") => (0.02, 0.06, 0.4, 1.2),        // 0.012 0.034 0.24 0.76
        ("sphere", "rfd") => (0.04, 0.2, 0.6, 3.0),        // 0.022 0.123 0.37 1.92
        ("sphere", "rfd-window") => (0.4, 3.0, 0.6, 3.0),  // 0.268 1.96 0.37 1.92
        ("sphere", "pss") => (0.07, 0.18, 0.4, 1.0),       // 0.042 0.112 0.24 0.58
        ("sphere", "first-hit") => (0.06, 0.15, 2.3, 3.0), // 0.035 0.088 1.52 2.04
        ("torus", "sj") => (0.025, 0.08, 0.8, 3.0),        // 0.016 0.053 0.51 1.98
        ("torus", "rfd") => (0.04, 0.2, 1.0, 5.5),         // 0.024 0.123 0.67 3.69
        ("torus", "rfd-window") => (0.35, 2.7, 1.0, 5.5),  // 0.231 1.81 0.67 3.69
        ("torus", "pss") => (0.08, 0.22, 0.75, 2.2),       // 0.053 0.148 0.48 1.47
        ("torus", "first-hit") => (0.11, 0.3, 5.7, 8.7),   // 0.072 0.205 3.80 5.80
        ("plane", "rfd-window") => (4.5, 9.0, 0.05, 0.05), // 2.97 6.51 0.003 0.02
        ("plane", _) => (1e-3, 1e-3, 0.05, 0.05),          // ≤ 1.3e-5 4.8e-5 0.003 0.02
        _ => unreachable!("no tolerance for {surface} {scheme}"),
    }
}

/// At the silhouette an oriented disk is seen edge-on and rays slip between neighbours; a
/// ray-facing disk always faces the ray, so RFD leaves no cracks there.
#[test]
fn ray_facing_disks_leave_no_cracks_at_the_silhouette() {
    let s = sphere();
    let bvh = bvh(&s);
    let eye = Vec3::new(0.9, -2.2, 1.6);
    let rfd = measure(&s, &bvh, &SurfaceScheme::rfd(), eye, (0.0, 0.3));
    let sj = measure(&s, &bvh, &SurfaceScheme::sj(), eye, (0.0, 0.3));
    eprintln!("silhouette rays: rfd {rfd:?}, sj {sj:?}");
    assert!(rfd.rays > 300, "too few silhouette rays: {}", rfd.rays);
    assert_eq!(rfd.misses, 0, "RFD cracks at the silhouette");
    // The price: a view-dependent surface, thicker there (measured mean 0.68, p99 3.8
    // spacings, against SJ's 0.05 and 0.21; this dense sphere shows SJ no cracks either).
    assert!(rfd.mean_dt < 1.0 && rfd.p99_dt < 5.0, "{rfd:?}");
}

/// Shadow rays leave each scheme's surface cleanly: on a plane lit at a grazing 21° and on a
/// sphere (convex: nothing of it shadows a lit point), the image with shadows equals the one
/// without, but for a few pixels at the sphere's terminator, where the light grazes the surface
/// and shading is dim anyway (measured: none for SJ, PSS and first-hit, 8 for RFD).
#[test]
fn shadow_rays_do_not_hit_their_own_surface() {
    use pointray::camera::Region;
    use pointray::render::{RenderConfig, render};
    use pointray::shading::Light;
    let cases = [
        (plane(), Vec3::new(0.0, -0.4, 2.5), Vec3::new(1.0, 0.3, 0.4)),
        (sphere(), Vec3::new(0.0, 0.0, 3.2), Vec3::new(1.0, 0.6, 0.8)),
    ];
    for (s, eye, light) in cases {
        let bvh = bvh(&s);
        let cam = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 40.0, 64, 64);
        for (name, scheme) in schemes() {
            let config = |shadows| RenderConfig {
                scheme,
                lights: vec![Light::Directional { direction: light, intensity: 3.0 }],
                shadows,
                ..crate::util::render_config(Region::full(64, 64), 1)
            };
            let (lit, stats) = render(&bvh, &cam, &config(true), &|_| {});
            let (free, _) = render(&bvh, &cam, &config(false), &|_| {});
            let diff: Vec<f32> = lit.rgb.iter().zip(&free.rgb).map(|(a, b)| (a[0] - b[0]).abs()).collect();
            let differ = diff.iter().filter(|d| **d > 0.0).count();
            // On the surface itself (RFD's silhouette fringe, outside the exact outline, may
            // shadow itself: 6 such pixels measured on the sphere).
            let on_surface = |i: usize| (s.hit)(&cam.ray((i % 64) as f32 + 0.5, (i / 64) as f32 + 0.5)).is_some();
            let bright = diff.iter().enumerate().filter(|&(i, d)| *d > 0.1 && on_surface(i)).count();
            eprintln!(
                "{} {name}: {differ} of {} hit pixels differ, {bright} by more than 0.1",
                s.name, stats.primary_hits
            );
            assert!(stats.primary_hits > 1_000, "{} {name}: the surface must fill the view", s.name);
            assert!(
                differ <= if s.name == "plane" { 0 } else { 30 },
                "{} {name}: {differ} self-shadowed pixels",
                s.name
            );
            assert_eq!(bright, 0, "{} {name}: self-shadowed pixels away from the terminator", s.name);
        }
    }
}

/// PSS from inside a closed surface: the rays meet the splats from behind, and the projection
/// must still find its neighbours (their stored normals face away from the ray) and converge.
#[test]
fn pss_converges_when_the_surface_is_seen_from_behind() {
    let s = sphere();
    let bvh = bvh(&s);
    let cam = Camera::look_at(Vec3::new(0.1, -0.2, 0.3), Vec3::new(0.0, 1.0, 0.0), Vec3::Z, 60.0, 48, 48);
    let mut stats = TraversalStats::default();
    let mut hits = 0;
    for y in 0..48 {
        for x in 0..48 {
            let ray = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            // The far root: the origin is inside the unit sphere.
            let b = ray.origin.dot(ray.dir);
            let t = -b + (b * b - (ray.origin.length_squared() - 1.0)).sqrt();
            let hit = scheme::intersect(&bvh, &ray, &SurfaceScheme::pss(), &mut stats).expect("inside a closed sphere");
            assert!((hit.t - t).abs() < 0.2 * s.spacing, "hit {} vs exact {t}", hit.t);
            hits += 1;
        }
    }
    assert_eq!(stats.pss_fallbacks, 0, "{stats:?}");
    assert!(stats.pss_steps as f32 / (hits as f32) < 3.0, "{stats:?}");
}
