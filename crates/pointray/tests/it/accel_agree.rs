//! Every accelerator returns exactly the hits of the brute-force oracle (full detail: level of
//! detail and culling off), whatever bounds its nodes test.

use glam::Vec3;
use pointray::accel::{Accel, BruteForce, Bvh, BvhParams, KdTree, KdTreeParams, NodeBounds, TraversalStats};
use pointray::math::Aabb;
use pointray::splat::scheme::{self, SurfaceKind, SurfaceScheme};
use pointray::splat::{DiskShape, Splat};

use crate::util::{random_rays, sphere_splats, torus_splats};

/// A BVH built with `params`, its invariants checked.
fn bvh(splats: &[Splat], params: &BvhParams) -> Bvh {
    let bvh = Bvh::build(splats.to_vec(), params);
    pointray::accel::bvh::check_invariants(&bvh).expect("BVH invariants");
    bvh
}

/// A kd-tree built with `params`, its invariants checked.
fn kdtree(splats: &[Splat], params: &KdTreeParams) -> KdTree {
    let tree = KdTree::build(splats.to_vec(), params);
    pointray::accel::kdtree::check_invariants(&tree).expect("kd-tree invariants");
    tree
}

/// Compares closest hits (first-hit, SJ, PSS on every eighth ray, and RFD if the accelerator
/// holds ray-facing disks) and shadow queries of `accel`, built over `splats`, against brute
/// force, over `rays` random rays. Returns how many rays hit.
fn check_agreement(splats: &[Splat], accel: &impl Accel, rays: usize, seed: u64) -> usize {
    let brute = BruteForce::new(splats.to_vec());
    let target = if splats.is_empty() { Aabb::new(Vec3::splat(-1.0), Vec3::ONE) } else { brute.bounds() };
    let mut schemes = vec![SurfaceScheme::first_hit(), SurfaceScheme::sj(), SurfaceScheme::pss()];
    if accel.shape() == DiskShape::RayFacing {
        schemes.push(SurfaceScheme::rfd());
    }
    let mut hits = 0;
    for (i, ray) in random_rays(rays, &target, seed).iter().enumerate() {
        for scheme in schemes.iter().filter(|s| s.kind != SurfaceKind::Pss || i % 8 == 0) {
            let mut s = TraversalStats::default();
            let a = scheme::intersect(&brute, ray, scheme, &mut s);
            let b = scheme::intersect(accel, ray, scheme, &mut s);
            match (a, b) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    assert_eq!(a.t.to_bits(), b.t.to_bits(), "ray {i} {scheme:?}: t differs");
                    assert_eq!(a.normal, b.normal, "ray {i} {scheme:?}: normal differs");
                    assert_eq!(a.color, b.color, "ray {i} {scheme:?}: colour differs");
                    assert_eq!(a.blended, b.blended, "ray {i} {scheme:?}");
                    assert_eq!(brute.splat(a.splat), accel.splat(b.splat), "ray {i}: other disk");
                    hits += 1;
                }
                (a, b) => panic!("ray {i} {scheme:?}: brute {a:?} vs {} {b:?}", accel.name()),
            }
        }
        let mut s = TraversalStats::default();
        // Shadow rays depend only on the disk shape: one scheme per shape.
        let shapes = schemes.iter().filter(|s| matches!(s.kind, SurfaceKind::Sj | SurfaceKind::Rfd));
        for (scheme, t_max) in shapes.flat_map(|s| [(s, 0.5 * target.diagonal()), (s, f32::INFINITY)]) {
            assert_eq!(
                scheme::occluded(&brute, ray, t_max, scheme, &mut s),
                scheme::occluded(accel, ray, t_max, scheme, &mut s),
                "ray {i} {:?}: occlusion differs",
                scheme.kind
            );
        }
    }
    hits
}

/// The node bounds every preset is checked with: the foundation's boxes, spheres from the
/// root or from level 2 (the mixed volumes of thesis ch. 3), and the per-node choice.
const NODE_BOUNDS: [NodeBounds; 4] =
    [NodeBounds::Boxes, NodeBounds::SpheresFrom(0), NodeBounds::SpheresFrom(2), NodeBounds::Auto];

#[test]
fn bvh_matches_brute_force_on_sphere_and_torus_for_every_preset() {
    let sphere = sphere_splats(20_000, 1.0, 1);
    let torus = torus_splats(20_000, 2);
    for (name, params) in BvhParams::presets() {
        for node_bounds in NODE_BOUNDS {
            let params = BvhParams { node_bounds, ..params };
            // 10⁴ rays for the default; fewer for the other variants keep the suite short.
            let rays = if name == "standard" && node_bounds == NodeBounds::Boxes { 10_000 } else { 2_000 };
            let hits = check_agreement(&sphere, &bvh(&sphere, &params), rays, 11);
            assert!(hits > rays / 2, "{name} {node_bounds:?}: too few hits ({hits}) to mean anything");
            let hits = check_agreement(&torus, &bvh(&torus, &params), rays, 12);
            assert!(hits > rays / 3, "{name} {node_bounds:?}: too few hits ({hits}) on the torus");
        }
    }
}

/// A BVH built a chunk at a time (chunks of 1,000 splats here, of 2²² by default) finds the
/// oracle's hits, from sorted or shuffled input, whatever its nodes' bounds; and the degenerate
/// inputs, whose Morton cells cannot all split, too.
#[test]
fn a_bvh_built_in_chunks_matches_brute_force() {
    let torus = torus_splats(20_000, 3);
    let mut shuffled = torus.clone();
    // A fixed permutation: odd steps through the array.
    let n = shuffled.len();
    shuffled = (0..n).map(|i| torus[(i * 7_919) % n]).collect();
    for node_bounds in [NodeBounds::Boxes, NodeBounds::SpheresFrom(1)] {
        let params = BvhParams { node_bounds, chunk_splats: 1_000, ..BvhParams::standard() };
        for splats in [&torus, &shuffled] {
            let chunked = bvh(splats, &params);
            assert!(chunked.node_count() > 0);
            let hits = check_agreement(splats, &chunked, 3_000, 21);
            assert!(hits > 1_000, "{node_bounds:?}: too few hits ({hits})");
        }
    }
    let params = BvhParams { chunk_splats: 64, ..BvhParams::standard() };
    for (what, splats) in &degenerate_inputs() {
        let hits = check_agreement(splats, &bvh(splats, &params), 1_000, 6);
        assert!(hits > 0, "{what}: no ray hit, the test is vacuous");
    }
}

/// Inputs that break naive builds: one disk, coplanar disks, coincident disks, a line.
fn degenerate_inputs() -> [(&'static str, Vec<Splat>); 5] {
    let disk = |c: Vec3, n: Vec3| Splat { center: c, radius: 0.1, normal: n.normalize(), color: 0 };
    let one = vec![disk(Vec3::ZERO, Vec3::Z)];
    let coplanar: Vec<Splat> =
        (0..500).map(|i| disk(Vec3::new((i % 25) as f32 * 0.08, (i / 25) as f32 * 0.08, 0.0), Vec3::Z)).collect();
    // Every splat at one place: SAH finds no split, the build must still terminate.
    let duplicates: Vec<Splat> = (0..300).map(|i| disk(Vec3::ONE, Vec3::new(1.0, i as f32 * 0.01, 0.0))).collect();
    let collinear: Vec<Splat> = (0..300).map(|i| disk(Vec3::new(i as f32 * 0.05, 0.0, 0.0), Vec3::Y)).collect();
    // Centres a subnormal apart on x: binning's scale there overflows to ∞, and a centre at
    // the lowest gets position 0·∞ = NaN, which binning and the partition must place alike.
    let subnormal: Vec<Splat> =
        (0..300).map(|i| disk(Vec3::new((i % 2) as f32 * 1e-41, i as f32 * 0.05, 0.0), Vec3::Z)).collect();
    [
        ("one", one),
        ("coplanar", coplanar),
        ("duplicates", duplicates),
        ("collinear", collinear),
        ("subnormal", subnormal),
    ]
}

#[test]
fn bvh_matches_brute_force_on_degenerate_inputs() {
    let inputs = degenerate_inputs();
    for (name, params) in BvhParams::presets() {
        for node_bounds in [NodeBounds::Boxes, NodeBounds::SpheresFrom(0)] {
            let params = BvhParams { node_bounds, ..params };
            for (what, splats) in &inputs {
                let hits = check_agreement(splats, &bvh(splats, &params), 2_000, 5);
                assert!(hits > 0, "{name}/{what}: no ray hit, the test is vacuous");
            }
            assert_eq!(check_agreement(&[], &bvh(&[], &params), 100, 5), 0);
        }
    }
}

#[test]
fn bvh_nodes_bound_their_splats_and_visit_fewer_than_brute_force() {
    let splats = sphere_splats(30_000, 1.0, 3);
    let bvh = Bvh::build(splats.clone(), &BvhParams::standard());
    assert!(bvh.depth() < 64, "depth {}", bvh.depth());
    pointray::accel::bvh::check_invariants(&bvh).expect("BVH invariants");
    // The BVH holds the input's splats as every accelerator stores them (snapped; the brute
    // force's), reordered: the same multiset, bit for bit.
    let oracle = BruteForce::new(splats.clone());
    let mut input: Vec<_> = (0..splats.len() as u32).map(|i| oracle.splat(i).bits()).collect();
    let mut held: Vec<_> = bvh.splats().map(|(_, s)| s.bits()).collect();
    input.sort_unstable();
    held.sort_unstable();
    assert!(input == held, "the BVH's splats are not the input's");
    assert_eq!(bvh.splat_count(), splats.len());
    // Work per ray: the BVH must test orders of magnitude fewer disks than brute force.
    let mut stats = TraversalStats::default();
    let rays = random_rays(2_000, &bvh.bounds(), 9);
    for ray in &rays {
        scheme::intersect(&bvh, ray, &SurfaceScheme::sj(), &mut stats);
    }
    let per_ray = stats.splat_tests as f64 / rays.len() as f64;
    assert!(per_ray < 100.0, "{per_ray} splat tests per ray");
}

#[test]
fn kdtree_matches_brute_force_on_sphere_and_torus_for_every_preset() {
    let sphere = sphere_splats(20_000, 1.0, 1);
    let torus = torus_splats(20_000, 2);
    for (name, params) in KdTreeParams::presets() {
        let rays = if name == "standard" { 10_000 } else { 2_000 };
        let hits = check_agreement(&sphere, &kdtree(&sphere, &params), rays, 11);
        assert!(hits > rays / 2, "{name}: too few hits ({hits}) to mean anything");
        let hits = check_agreement(&torus, &kdtree(&torus, &params), rays, 12);
        assert!(hits > rays / 3, "{name}: too few hits ({hits}) on the torus");
    }
}

#[test]
fn kdtree_matches_brute_force_on_degenerate_inputs() {
    let inputs = degenerate_inputs();
    for (name, params) in KdTreeParams::presets() {
        for (what, splats) in &inputs {
            let hits = check_agreement(splats, &kdtree(splats, &params), 2_000, 5);
            assert!(hits > 0, "{name}/{what}: no ray hit, the test is vacuous");
        }
        assert_eq!(check_agreement(&[], &kdtree(&[], &params), 100, 5), 0);
    }
}

#[test]
fn kdtree_splits_space_and_tests_few_disks_per_ray() {
    let splats = sphere_splats(30_000, 1.0, 3);
    let tree = kdtree(&splats, &KdTreeParams::standard());
    assert!(tree.depth() > 10 && tree.depth() <= 64, "depth {}", tree.depth());
    // Overlapping disks straddle many planes (6.7 references per splat measured here), but a
    // build that referenced splats wholesale would show.
    let per_splat = tree.reference_count() as f64 / splats.len() as f64;
    assert!((1.0..12.0).contains(&per_splat), "{per_splat} references per splat");
    let mut stats = TraversalStats::default();
    let rays = random_rays(2_000, &tree.bounds(), 9);
    for ray in &rays {
        scheme::intersect(&tree, ray, &SurfaceScheme::sj(), &mut stats);
    }
    let per_ray = stats.splat_tests as f64 / rays.len() as f64;
    // 107 measured: random rays cross the sphere's empty inside and its shell twice.
    assert!(per_ray < 125.0, "{per_ray} splat tests per ray");
}

/// Built for ray-facing disks (their balls bounded), both accelerators find exactly the RFD
/// hits of brute force, and still the oriented disks' ones.
#[test]
fn accelerators_built_for_ray_facing_disks_match_brute_force() {
    let sphere = sphere_splats(20_000, 1.0, 1);
    let torus = torus_splats(20_000, 2);
    for node_bounds in [NodeBounds::Boxes, NodeBounds::SpheresFrom(0)] {
        let params = BvhParams { node_bounds, shape: DiskShape::RayFacing, ..BvhParams::standard() };
        assert!(check_agreement(&sphere, &bvh(&sphere, &params), 2_000, 21) > 1_000);
        assert!(check_agreement(&torus, &bvh(&torus, &params), 2_000, 22) > 700);
    }
    let params = KdTreeParams { shape: DiskShape::RayFacing, ..KdTreeParams::standard() };
    assert!(check_agreement(&sphere, &kdtree(&sphere, &params), 2_000, 23) > 1_000);
    assert!(check_agreement(&torus, &kdtree(&torus, &params), 2_000, 24) > 700);
}

/// The radius query reports each splat within the radius exactly once, as brute force does.
#[test]
fn radius_queries_match_brute_force() {
    fn near(accel: &impl Accel, center: Vec3, radius: f32) -> Vec<[u32; 3]> {
        let mut found = Vec::new();
        accel.for_each_near(center, radius, &mut TraversalStats::default(), |_, s| {
            found.push(s.center.to_array().map(f32::to_bits))
        });
        found.sort_unstable();
        found
    }
    let splats = torus_splats(20_000, 3);
    let brute = BruteForce::new(splats.clone());
    let bvh = bvh(&splats, &BvhParams::standard());
    let kd = kdtree(&splats, &KdTreeParams::standard());
    let mut total = 0;
    // Around splats (an offset along random directions) and at random places.
    for (i, ray) in random_rays(300, &brute.bounds(), 4).iter().enumerate() {
        let c = if i % 2 == 0 { splats[i * 61].center + ray.dir * 0.02 } else { ray.origin };
        let r = [0.01, 0.05, 0.2][i % 3];
        let expected = near(&brute, c, r);
        assert_eq!(expected, near(&bvh, c, r), "query {i}: BVH");
        assert_eq!(expected, near(&kd, c, r), "query {i}: kd-tree (a straddling splat reported twice?)");
        total += expected.len();
    }
    assert!(total > 1_000, "the queries must find neighbours: {total}");
}

/// Sheets of disks facing away from the rays from above with the near side 2 radii behind them
/// and another 10 radii behind: SJ's walk behind a window facing away collects only what begins
/// within reach (`scheme::windowed`), and must find what brute force finds from every side.
#[test]
fn accelerators_match_brute_force_behind_sheets_facing_away() {
    let sheet = |z: f32, normal: Vec3| -> Vec<Splat> {
        let at = |i: i32, j: i32| Vec3::new(i as f32 * 0.05, j as f32 * 0.05, z);
        (-20..=20)
            .flat_map(|i| (-20..=20).map(move |j| Splat { center: at(i, j), radius: 0.1, normal, color: 0 }))
            .collect()
    };
    let splats = [sheet(0.5, -Vec3::Z), sheet(0.3, Vec3::Z), sheet(-0.5, Vec3::Z)].concat();
    let bvh_hits = check_agreement(&splats, &bvh(&splats, &BvhParams::standard()), 1_500, 31);
    let kd_hits = check_agreement(&splats, &kdtree(&splats, &KdTreeParams::standard()), 1_500, 32);
    assert!(bvh_hits > 1_000 && kd_hits > 1_000, "{bvh_hits} and {kd_hits} hits");
}
