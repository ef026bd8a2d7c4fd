//! The footprint prefilter (`splat::footprint`): what a pixel's beam gathers on analytic
//! surfaces, the BVH's walk against brute force, and the renderer's use of it.

use glam::Vec3;
use pointray::accel::{Accel, BruteForce, Bvh, BvhParams, KdTree, KdTreeParams, TraversalStats};
use pointray::camera::{Camera, Region};
use pointray::math::{Ray, RayCone};
use pointray::render::{RenderConfig, render};
use pointray::shading::Environment;
use pointray::splat::footprint::{Footprint, Layer, ShadowBeam};
use pointray::splat::{Splat, pack_color};

use crate::util::{plane_splats, random_rays, sphere_splats, torus_splats};

/// A ray from `origin` towards `target` whose footprint is `width` wide at `target`.
fn beam_ray(origin: Vec3, target: Vec3, width: f32) -> Ray {
    let spread = width / (target - origin).length();
    Ray::new(origin, target - origin, RayCone { width0: 0.0, spread })
}

/// The first layer `ray`'s footprint meets in `accel`, at full detail (`tau` 0) or not (1).
fn first_layer(accel: &impl Accel, ray: &Ray, tau: f32) -> Option<Layer> {
    let mut footprint = Footprint::new(accel, ray, f32::INFINITY);
    footprint.gather(accel, tau, &mut TraversalStats::default());
    footprint.layers().next()
}

#[test]
fn a_plane_covers_the_footprint_whole_with_its_own_colour_and_normal() {
    let splats = plane_splats(20_000, 3);
    let color = Vec3::from(splats[0].color_linear());
    covers_the_plane(&Bvh::build(splats.clone(), &BvhParams::standard()), color);
    covers_the_plane(&KdTree::build(splats, &KdTreeParams::standard()), color);
}

fn covers_the_plane(accel: &impl Accel, color: Vec3) {
    // A footprint some ten disks wide, straight down and at 45°, at full detail and with the
    // representatives of subtrees up to its width.
    for origin in [Vec3::new(0.1, -0.2, 3.0), Vec3::new(2.1, -0.2, 2.0)] {
        for tau in [0.0, 1.0] {
            let ray = beam_ray(origin, Vec3::new(0.1, -0.2, 0.0), 0.15);
            let name = accel.name();
            let layer = first_layer(accel, &ray, tau).expect("the plane");
            assert!(layer.coverage > 0.97, "{name} {origin} τ {tau}: coverage {}", layer.coverage);
            assert!(layer.normal.normalize().dot(Vec3::Z) > 0.999 && layer.normal.length() > 0.99, "{layer:?}");
            assert!((layer.color - color).abs().max_element() < 1e-3, "{name} {layer:?}");
            let depth = (ray.origin + layer.t * ray.dir).z;
            assert!(depth.abs() < 0.02, "{name}: the layer lies on the plane: {depth}");
        }
    }
}

#[test]
fn a_footprint_on_the_planes_edge_covers_what_its_disks_cover_and_one_past_it_nothing() {
    // The square [−1, 1]²: a footprint centred on its edge x = 1 sees half of it, and the
    // disks reaching past the edge.
    let splats = plane_splats(20_000, 5);
    let bvh = Bvh::build(splats.clone(), &BvhParams::standard());
    let (center, width) = (Vec3::new(1.0, 0.3, 0.0), 0.3);
    let union = disks_cover(&splats, center, width * pointray::splat::footprint::FOOTPRINT_RADIUS);
    assert!(union > 0.55 && union < 0.65, "the disks reach past the edge: {union}");
    for tau in [0.0, 1.0] {
        let edge = first_layer(&bvh, &beam_ray(center + 3.0 * Vec3::Z, center, width), tau);
        let coverage = edge.expect("half the plane").coverage;
        // On the beam's 64 sample points, at full detail and with representatives (widened so
        // that they meet, `footprint::REPRESENTATIVE_SPREAD`).
        assert!((coverage - union).abs() < 0.06, "τ {tau}: coverage {coverage}, the disks' union {union}");
        let past = first_layer(&bvh, &beam_ray(Vec3::new(1.5, 0.3, 3.0), Vec3::new(1.5, 0.3, 0.0), width), tau);
        assert!(past.is_none(), "τ {tau}: {past:?}");
    }
}

/// A layer's shadow rays, gathered as one beam ([`ShadowBeam`]): a sheet facing the ground
/// shadows the ground behind it from a light at 45°, past its edge the ground is lit, the
/// ground's own disks (facing the light) block nothing, and the edge falls between; at full
/// detail (as brute force) and with representatives, in the BVH and the kd-tree.
#[test]
fn a_layers_shadow_rays_are_blocked_where_a_sheet_stands_between_it_and_the_light() {
    // The ground [−1, 1]² at z = 0 facing up; the sheet [1.5, 3.5] × [−1, 1] at z = 1 facing
    // down. From the ground, the light along (1, 0, 1) meets the sheet past x = 0.5.
    let sheet = plane_splats(20_000, 5);
    let over = sheet.iter().map(|s| Splat { center: s.center + Vec3::new(2.5, 0.0, 1.0), normal: -Vec3::Z, ..*s });
    let splats: Vec<Splat> = over.chain(plane_splats(20_000, 6)).collect();
    let light = Vec3::new(1.0, 0.0, 1.0).normalize();
    let bvh = Bvh::build(splats.clone(), &BvhParams::standard());
    let kdtree = KdTree::build(splats.clone(), &KdTreeParams::standard());
    // At full detail each accelerator blocks what brute force blocks, to a point of the 64: a
    // beam square to the ground meets all its disks at one depth, and which of them comes first
    // (and lifts a point by its radius) follows the order they are handed in.
    let brute = BruteForce::new(splats);
    for x in [-0.3, 0.45, 0.5, 0.55, 0.8] {
        let all = shadow_of_ground(&brute, x, 0.0, light);
        for (name, one) in
            [("bvh", shadow_of_ground(&bvh, x, 0.0, light)), ("kd-tree", shadow_of_ground(&kdtree, x, 0.0, light))]
        {
            assert!((one - all).abs() <= 1.0 / 64.0, "{name} at {x}: {one} against brute force's {all}");
        }
    }
    for (name, blocked) in [
        ("bvh", &(|x: f32, tau: f32| shadow_of_ground(&bvh, x, tau, light)) as &dyn Fn(f32, f32) -> f32),
        ("kd-tree", &|x: f32, tau: f32| shadow_of_ground(&kdtree, x, tau, light)),
    ] {
        for tau in [0.0, 1.0] {
            assert_eq!(blocked(-0.3, tau), 0.0, "{name} τ {tau}: lit ground");
            let under = blocked(0.8, tau);
            assert!(under > 0.97, "{name} τ {tau}: {under} in the sheet's shadow");
            let edge = blocked(0.5, tau);
            assert!(edge > 0.2 && edge < 0.8, "{name} τ {tau}: {edge} at the shadow's edge");
        }
    }
}

/// The blocked share of the ground's first layer under a beam straight down at (x, 0.3).
fn shadow_of_ground(accel: &impl Accel, x: f32, tau: f32, light: Vec3) -> f32 {
    let target = Vec3::new(x, 0.3, 0.0);
    let ray = beam_ray(target + 3.0 * Vec3::Z, target, 0.15);
    let mut footprint = Footprint::new(accel, &ray, f32::INFINITY);
    footprint.gather(accel, tau, &mut TraversalStats::default());
    let ground = footprint.layers().next().expect("the ground");
    let mut beam = ShadowBeam::new(&footprint, &ground, light, 10.0, 0.5, 1.0).expect("points on the ground");
    beam.gather(accel, tau, &mut TraversalStats::default());
    beam.blocked()
}

/// The share of the disk of `radius` about `center` in the plane z = 0 that `disks` (in that
/// plane) cover, on a fine grid.
fn disks_cover(disks: &[Splat], center: Vec3, radius: f32) -> f32 {
    let near: Vec<&Splat> = disks.iter().filter(|s| (s.center - center).length() < radius + s.radius).collect();
    let (mut inside, mut covered) = (0, 0);
    for i in 0..200 {
        for j in 0..200 {
            let p = center + radius * Vec3::new(i as f32 / 99.5 - 1.0, j as f32 / 99.5 - 1.0, 0.0);
            if (p - center).length() <= radius {
                inside += 1;
                covered += usize::from(near.iter().any(|s| (s.center - p).length() <= s.radius));
            }
        }
    }
    covered as f32 / inside as f32
}

#[test]
fn normals_that_spread_give_a_shorter_mean_normal() {
    // A plane whose disks tilt ±30° about y in turn: the pixel's mean normal is cos 30° long.
    let mut splats = plane_splats(20_000, 9);
    let tilt = 30f32.to_radians();
    for (i, s) in splats.iter_mut().enumerate() {
        let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
        s.normal = Vec3::new(sign * tilt.sin(), 0.0, tilt.cos());
    }
    let bvh = Bvh::build(splats, &BvhParams::standard());
    for tau in [0.0, 1.0] {
        let layer = first_layer(&bvh, &beam_ray(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 0.2), tau).expect("the plane");
        let agreement = layer.normal.length();
        assert!((agreement - tilt.cos()).abs() < 0.03, "τ {tau}: {agreement}");
        assert!(layer.normal.normalize().dot(Vec3::Z) > 0.99, "{layer:?}");
    }
}

#[test]
fn the_bvh_and_the_kd_tree_gather_what_brute_force_gathers_at_full_detail() {
    for (name, splats) in [("sphere", sphere_splats(3_000, 1.0, 11)), ("torus", torus_splats(3_000, 12))] {
        let brute = BruteForce::new(splats.clone());
        gathers_as_brute_force(&Bvh::build(splats.clone(), &BvhParams::standard()), &brute, name);
        gathers_as_brute_force(&KdTree::build(splats, &KdTreeParams::standard()), &brute, name);
    }
}

fn gathers_as_brute_force(accel: &impl Accel, brute: &BruteForce, surface: &str) {
    let name = format!("{surface}, {}", accel.name());
    assert_eq!(accel.coverage_density().to_bits(), brute.coverage_density().to_bits(), "{name}");
    let mut met = 0;
    for (i, ray) in random_rays(300, &brute.bounds(), 21).iter().enumerate() {
        let ray = Ray { cone: RayCone { width0: 0.0, spread: 0.02 }, ..*ray };
        match (first_layer(brute, &ray, 0.0), first_layer(accel, &ray, 0.0)) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                met += 1;
                let close = |x: f32, y: f32| (x - y).abs() <= 1e-5 * (1.0 + x.abs());
                assert!(close(a.coverage, b.coverage) && close(a.t, b.t), "{name} ray {i}: {a:?} vs {b:?}");
                assert!((a.color - b.color).abs().max_element() < 1e-5, "{name} ray {i}");
                assert!((a.normal - b.normal).abs().max_element() < 1e-5, "{name} ray {i}");
                assert_eq!(a.pieces.len(), b.pieces.len(), "{name} ray {i}");
            }
            (a, b) => panic!("{name} ray {i}: brute {a:?} vs {b:?}"),
        }
    }
    assert!(met > 50, "{name}: the rays must meet the surface ({met})");
}

/// A torus's render through the prefilter, with a light and shadows.
fn prefiltered(threads: usize, config: &RenderConfig, accel: &impl Accel, cam: &Camera) -> pointray::film::Film {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| render(accel, cam, config, &|_| {})).0
}

#[test]
fn a_prefiltered_render_is_the_same_with_any_threads_and_its_edges_partly_covered() {
    let bvh = Bvh::build(torus_splats(60_000, 7), &BvhParams::standard());
    // Far enough that a pixel holds many disks: level of detail, and the prefilter, apply.
    let bounds = pointray::math::Aabb::new(Vec3::splat(-1.4), Vec3::splat(1.4));
    let cam = Camera::orbit(&bounds, Vec3::new(0.4, 0.9, 1.0), Vec3::Y, 4.0, 30.0, 96, 72);
    let config = RenderConfig {
        lights: vec![pointray::demo::demo_light()],
        environment: Environment::Uniform { color: [0.1, 0.1, 0.1] },
        lod_threshold: 1.0,
        prefilter: true,
        ..crate::util::render_config(Region::full(96, 72), 1)
    };
    let (a, b) = (prefiltered(1, &config, &bvh, &cam), prefiltered(2, &config, &bvh, &cam));
    assert!(a.rgb.iter().zip(&b.rgb).all(|(x, y)| x.map(f32::to_bits) == y.map(f32::to_bits)));
    let coverage = &a.first_hits.as_ref().expect("recorded").coverage;
    let partly = coverage.iter().filter(|&&c| c > 0.05 && c < 0.95).count();
    let whole = coverage.iter().filter(|&&c| c >= 0.99).count();
    assert!(partly > 20 && whole > 100, "edges blend, insides are covered: {partly} partly, {whole} whole");
    // Without the prefilter every pixel is a hit or a miss.
    let plain = prefiltered(2, &RenderConfig { prefilter: false, ..config.clone() }, &bvh, &cam);
    let hard = &plain.first_hits.as_ref().expect("recorded").coverage;
    assert!(hard.iter().all(|&c| c == 0.0 || c == 1.0));
    // And the two images agree but where they should not: within a few levels on the whole.
    let mean = |f: &pointray::film::Film| f.rgb.iter().map(|p| Vec3::from(*p)).sum::<Vec3>() / f.rgb.len() as f32;
    assert!((mean(&a) - mean(&plain)).abs().max_element() < 0.02, "{} vs {}", mean(&a), mean(&plain));
    // The kd-tree's prefilter: the same on any threads, and close to the BVH's (their
    // representatives differ: a kd-tree cell's stand for the disks centred in it).
    let kdtree = KdTree::build(torus_splats(60_000, 7), &KdTreeParams::standard());
    let (k1, k2) = (prefiltered(1, &config, &kdtree, &cam), prefiltered(2, &config, &kdtree, &cam));
    assert!(k1.rgb.iter().zip(&k2.rgb).all(|(x, y)| x.map(f32::to_bits) == y.map(f32::to_bits)));
    let kd_coverage = &k1.first_hits.as_ref().expect("recorded").coverage;
    assert!(kd_coverage.iter().filter(|&&c| c > 0.05 && c < 0.95).count() > 20, "the kd-tree's edges blend too");
    let rms = (a.rgb.iter().zip(&k1.rgb).map(|(x, y)| (Vec3::from(*x) - Vec3::from(*y)).length_squared()).sum::<f32>()
        / a.rgb.len() as f32)
        .sqrt();
    // Measured 0.0012.
    assert!(rms < 0.005, "the kd-tree's prefiltered image strays from the BVH's: RMS {rms}");
}

#[test]
fn a_mirror_in_the_footprint_is_traced_as_a_ray() {
    // Splats of material 1, a mirror: the prefilter leaves them to the ray (and its image is
    // the unfiltered one's).
    let mut splats: Vec<Splat> = torus_splats(20_000, 4);
    for s in &mut splats {
        s.color = pack_color([0.8, 0.8, 0.8]);
        s.set_material(1);
    }
    let bvh = Bvh::build(splats, &BvhParams::standard());
    let bounds = pointray::math::Aabb::new(Vec3::splat(-1.4), Vec3::splat(1.4));
    let cam = Camera::orbit(&bounds, Vec3::new(0.4, 0.9, 1.0), Vec3::Y, 6.0, 30.0, 32, 24);
    let config = RenderConfig {
        materials: vec![
            pointray::material::Material::standard(),
            pointray::material::Material::Mirror { tint: [0.9; 3] },
        ],
        environment: Environment::Uniform { color: [0.3, 0.5, 0.7] },
        lod_threshold: 1.0,
        prefilter: true,
        ..crate::util::render_config(Region::full(32, 24), 1)
    };
    let a = prefiltered(1, &config, &bvh, &cam);
    let b = prefiltered(1, &RenderConfig { prefilter: false, ..config.clone() }, &bvh, &cam);
    assert!(a.rgb.iter().zip(&b.rgb).all(|(x, y)| x == y));
    // The same view of Phong splats is prefiltered: the view is one where it applies.
    let phong = RenderConfig { materials: vec![pointray::material::Material::standard()], ..config.clone() };
    let c = prefiltered(1, &phong, &bvh, &cam);
    let d = prefiltered(1, &RenderConfig { prefilter: false, ..phong.clone() }, &bvh, &cam);
    assert!(c.rgb.iter().zip(&d.rgb).any(|(x, y)| x != y), "the prefilter did not apply to this view");
}
