//! The multiresolution accelerators, the BVH (thesis ch. 3) and the kd-tree (ch. 4): what
//! level of detail and culling may change, and what they must not.

use glam::Vec3;
use pointray::accel::{
    Accel, Bvh, BvhParams, Crossing, KdTree, KdTreeParams, NodeBounds, SplatVisitor, TraversalStats,
};
use pointray::camera::{Camera, Region};
use pointray::culling::{backfacing_fraction, backfacing_fraction_in_view};
use pointray::math::Ray;
use pointray::splat::Splat;
use pointray::splat::scheme::{self, SurfaceScheme};

use crate::util::{random_rays, sphere_splats, torus_splats};

/// Takes every crossing handed over and never narrows the walk: the nodes it visits depend
/// only on the ray and the level-of-detail rule, not on what was hit.
struct Everything(usize);

impl SplatVisitor for Everything {
    fn t_max(&self) -> f32 {
        f32::INFINITY
    }

    fn hit(&mut self, _: &Ray, _: Crossing) {
        self.0 += 1;
    }
}

/// Camera rays (with their pixel footprints) at a torus from far enough away that level of
/// detail has work to do.
fn far_camera_rays(bounds: &pointray::math::Aabb, distance: f32, size: u32) -> Vec<Ray> {
    let cam = Camera::orbit(bounds, Vec3::new(0.3, 0.8, 1.0), Vec3::Y, distance, 40.0, size, size);
    (0..size * size).map(|i| cam.ray((i % size) as f32 + 0.5, (i / size) as f32 + 0.5)).collect()
}

#[test]
fn a_coarser_threshold_never_visits_more_nodes() {
    let splats = torus_splats(40_000, 7);
    check_coarser_threshold(&Bvh::build(splats.clone(), &BvhParams::standard()));
    check_coarser_threshold(&KdTree::build(splats, &KdTreeParams::standard()));
}

fn check_coarser_threshold(accel: &impl Accel) {
    let name = accel.name();
    let thresholds = [0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 16.0];
    let mut stops = 0;
    for ray in far_camera_rays(&accel.bounds(), 3.0, 48) {
        let mut previous = u64::MAX;
        for tau in thresholds {
            let mut stats = TraversalStats::default();
            accel.traverse(&ray.with_lod_threshold(tau), &mut Everything(0), &mut stats);
            assert!(
                stats.nodes_visited <= previous,
                "{name} τ = {tau}: {} nodes, more than before",
                stats.nodes_visited
            );
            previous = stats.nodes_visited;
            stops += stats.lod_stops;
        }
    }
    assert!(stops > 1_000, "{name}: the rays must stop at coarse nodes to test anything ({stops} stops)");
    // The surface schemes narrow the walk as they find hits. The SJ window of a representative
    // is as long as the representative is wide, and a window that grows to one found late is
    // walked again, so a threshold that stops at a few of them may cost more than full detail,
    // which seldom walks twice (8-wide BVH: 3,370 nodes at full detail, 3,552 at τ = 0.5),
    // while from a pixel on the totals fall, and the coarse thresholds save much (τ = 16:
    // 2,332; the 4-wide BVH saved more nodes, 4,141 → 2,335, but each was a smaller step).
    let rays = far_camera_rays(&accel.bounds(), 3.0, 48);
    let totals: Vec<u64> = thresholds
        .iter()
        .map(|&tau| {
            let mut stats = TraversalStats::default();
            for ray in &rays {
                scheme::intersect(accel, &ray.with_lod_threshold(tau), &SurfaceScheme::sj(), &mut stats);
            }
            stats.nodes_visited
        })
        .collect();
    let (full, coarse) = (totals[0] as f64, &totals[3..]);
    assert!(totals.iter().all(|&t| t as f64 <= full * 1.1), "{name}: nodes visited per threshold: {totals:?}");
    assert!(coarse.windows(2).all(|w| w[1] <= w[0]), "{name}: nodes visited per threshold: {totals:?}");
    assert!(
        totals[3] < totals[0] && totals[6] * 4 < totals[0] * 3,
        "{name}: level of detail must save work: {totals:?}"
    );
}

/// Exact hit of a ray with the unit sphere at the origin.
fn unit_sphere_hit(ray: &Ray) -> Option<f32> {
    let b = ray.origin.dot(ray.dir);
    let disc = b * b - (ray.origin.length_squared() - 1.0);
    (disc >= 0.0).then(|| -b - disc.sqrt()).filter(|t| *t > 0.0)
}

/// A representative splat stands for a subtree narrower than τ footprints. On a smooth surface
/// it lies close to the surface (within the sagitta of its patch, a small part of a footprint)
/// and its normal is the patch's mean: measured max |Δt| 0.016 footprints, normal error mean
/// 0.3°, p99 1.1°; the bounds leave room for other seeds, not for a wrong representative.
#[test]
fn level_of_detail_hits_stay_within_the_footprint_of_the_sphere() {
    let splats = sphere_splats(50_000, 1.0, 4);
    check_sphere_hits(&Bvh::build(splats.clone(), &BvhParams::standard()));
    check_sphere_hits(&KdTree::build(splats, &KdTreeParams::standard()));
}

fn check_sphere_hits(accel: &impl Accel) {
    let name = accel.name();
    let tau = 1.0;
    let (mut checked, mut stops) = (0, 0);
    let mut normal_err = Vec::new();
    for ray in far_camera_rays(&accel.bounds(), 3.0, 128) {
        let Some(t) = unit_sphere_hit(&ray) else { continue };
        let exact_n = ray.at(t).normalize();
        if exact_n.dot(-ray.dir) < 0.3 {
            continue; // grazing: a footprint there spans a long stretch of depth
        }
        let ray = ray.with_lod_threshold(tau);
        let mut stats = TraversalStats::default();
        let hit = scheme::intersect(accel, &ray, &SurfaceScheme::sj(), &mut stats)
            .unwrap_or_else(|| panic!("{name}: the ray misses the sphere"));
        let footprint = ray.cone.width_at(t);
        assert!(
            (hit.t - t).abs() <= 0.1 * tau * footprint,
            "{name}: hit {} vs exact {t}: more than 0.1 τ footprints ({footprint}) off",
            hit.t
        );
        normal_err.push(hit.normal.dot(exact_n).clamp(-1.0, 1.0).acos().to_degrees());
        checked += 1;
        stops += stats.lod_stops;
    }
    // (One window walk a ray: before the window reached past its first crossing, a second walk
    // counted its stops again.)
    assert!(
        checked > 500 && stops * 2 > checked as u64,
        "{name}: {checked} rays, {stops} stops: level of detail unused"
    );
    normal_err.sort_by(f32::total_cmp);
    let mean = normal_err.iter().sum::<f32>() / normal_err.len() as f32;
    let p99 = normal_err[normal_err.len() * 99 / 100];
    eprintln!("{name}: normal error mean {mean}°, p99 {p99}°");
    assert!(mean < 1.0 && p99 < 3.0, "{name}: normal error: mean {mean}°, p99 {p99}°");
}

/// Culling drops only subtrees all of whose disks face away from the ray's origin, so a ray
/// whose nearest disk faces it finds that disk with culling too (and a closed surface seen from
/// outside is all such rays, up to stray disks at its rim).
#[test]
fn culling_keeps_every_front_facing_hit() {
    for (what, splats) in [("sphere", sphere_splats(20_000, 1.0, 5)), ("torus", torus_splats(20_000, 6))] {
        for node_bounds in [NodeBounds::Boxes, NodeBounds::Auto] {
            let bvh = Bvh::build(splats.clone(), &BvhParams { node_bounds, ..BvhParams::standard() });
            let (mut front, mut culled) = (0, 0);
            for (i, ray) in random_rays(5_000, &bvh.bounds(), 8).iter().enumerate() {
                let mut stats = TraversalStats::default();
                let Some(full) = scheme::intersect(&bvh, ray, &SurfaceScheme::first_hit(), &mut stats) else {
                    continue;
                };
                if bvh.splat(full.splat).normal.dot(ray.dir) >= 0.0 {
                    continue;
                }
                let ray = ray.with_backface_culling(true);
                let cut = scheme::intersect(&bvh, &ray, &SurfaceScheme::first_hit(), &mut stats);
                assert_eq!(cut, Some(full), "{what} {node_bounds:?} ray {i}: culling changed a front-facing hit");
                front += 1;
                culled += stats.culled;
            }
            assert!(front > 1_000 && culled > 100, "{what}: {front} front hits, {culled} culled subtrees");
        }
    }
}

#[test]
fn the_culling_check_tells_closed_surfaces_from_open_ones() {
    let sphere = Bvh::build(sphere_splats(20_000, 1.0, 9), &BvhParams::standard());
    let closed = backfacing_fraction(&sphere, 4096, 0).unwrap();
    assert!(closed < 0.01, "closed sphere: {closed}");
    // The upper half of the sphere: seen from below, its inside faces away.
    let bowl: Vec<Splat> = sphere_splats(20_000, 1.0, 9).into_iter().filter(|s| s.center.z > 0.0).collect();
    let bowl = Bvh::build(bowl, &BvhParams::standard());
    let open = backfacing_fraction(&bowl, 4096, 0).unwrap();
    assert!(open > 0.1, "open bowl: {open}");
    // The prefilter's check asks the view: the bowl's outside from above meets front faces,
    // its inside from below back faces.
    let bounds = pointray::math::Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
    let seen_from = |dir: Vec3| {
        let camera = Camera::orbit(&bounds, dir, Vec3::Y, 1.0, 40.0, 64, 64);
        backfacing_fraction_in_view(&bowl, &camera, Region::full(64, 64), 1024, 0).expect("the bowl in view")
    };
    let (above, below) = (seen_from(Vec3::new(0.2, 0.1, 1.0)), seen_from(Vec3::new(0.2, 0.1, -1.0)));
    assert!(above < 0.01 && below > 0.9, "the bowl from above {above}, from below {below}");
}

/// Where an accelerator says that no ray from a point with a given footprint can stop at a
/// representative (so a renderer may give its camera rays no level of detail at all), no ray
/// from there, in any direction, does; and from far enough away some can.
#[test]
fn a_view_without_level_of_detail_has_no_ray_that_stops() {
    let splats = torus_splats(40_000, 9);
    check_view_bound(&Bvh::build(splats.clone(), &BvhParams::standard()));
    check_view_bound(&KdTree::build(splats, &KdTreeParams::standard()));
}

fn check_view_bound(accel: &impl Accel) {
    let b = accel.bounds();
    let mut rng = crate::util::rng(5);
    let (mut near, mut far) = (0, 0);
    for distance in [0.2, 0.5, 1.0, 2.0, 4.0, 16.0] {
        for tau in [0.5, 1.0, 4.0] {
            let cam = Camera::orbit(&b, Vec3::new(0.3, 0.8, 1.0), Vec3::Y, distance, 40.0, 256, 256);
            let cone = cam.ray(0.5, 0.5).cone;
            if accel.may_stop_at_representatives_from(cam.eye, cone, tau) {
                far += 1;
                continue;
            }
            near += 1;
            for _ in 0..2_000 {
                let dir = pointray::demo::uniform_sphere(&mut rng);
                let ray = Ray::new(cam.eye, dir, cone).with_lod_threshold(tau);
                assert!(!accel.may_stop_at_representatives(&ray), "{} at {distance}, τ {tau}: {dir}", accel.name());
            }
        }
    }
    assert!(near > 0 && far > 0, "{}: {near} views without level of detail, {far} with", accel.name());
    // An origin on the plane of a face: a ray along the plane has an undefined exit there,
    // which the traversal takes for infinitely far.
    let cone = Camera::orbit(&b, Vec3::Z, Vec3::Y, 0.2, 40.0, 256, 256).ray(0.5, 0.5).cone;
    let on_face = Vec3::new(b.min.x, b.center().y, b.center().z);
    assert!(accel.may_stop_at_representatives_from(on_face, cone, 1.0));
    assert!(!accel.may_stop_at_representatives_from(on_face, cone, 0.0));
}
