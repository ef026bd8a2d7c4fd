//! The same image and counters whatever the thread count, and whether work is counted.

use glam::Vec3;
use pointray::accel::{Bvh, BvhParams};
use pointray::camera::Camera;
use pointray::render::{RenderConfig, render, render_into};
use pointray::shading::Environment;

use crate::util::torus_splats;

#[test]
fn image_is_identical_with_one_and_two_threads() {
    let bvh = Bvh::build(torus_splats(40_000, 7), &BvhParams::standard());
    let cam = Camera::orbit(
        &pointray::math::Aabb::new(Vec3::splat(-1.4), Vec3::splat(1.4)),
        Vec3::new(0.4, 0.9, 1.0),
        Vec3::Y,
        0.9,
        60.0,
        48,
        40,
    );
    let config = RenderConfig {
        lights: vec![pointray::demo::demo_light()],
        environment: Environment::Uniform { color: [0.1, 0.1, 0.1] },
        seed: 42,
        // Level of detail and culling on: their work must not depend on the threads either.
        lod_threshold: 1.0,
        cull_backfaces: true,
        ..crate::util::render_config(pointray::camera::Region::full(48, 40), 3)
    };
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| render(&bvh, &cam, &config, &|_| {}))
    };
    let (a, sa) = run(1);
    let (b, sb) = run(2);
    assert!(sa.primary_hits > 200 && sa.shadow_rays > 0, "the scene must exercise hits and shadows");
    assert!(sa.traversal.lod_stops > 0 && sa.traversal.culled > 0, "and level of detail and culling: {sa:?}");
    assert_eq!(sa, sb);
    assert!(a.rgb.iter().zip(&b.rgb).all(|(x, y)| x.map(f32::to_bits) == y.map(f32::to_bits)));
    assert_eq!(a.nodes_visited, b.nodes_visited);
    // And the seed matters when jittering: another seed gives another image.
    let (c, _) = render(&bvh, &cam, &RenderConfig { seed: 43, ..config.clone() }, &|_| {});
    assert!(a.rgb.iter().zip(&c.rgb).any(|(x, y)| x != y));
    // A film used before (here for the other seed's image) is written over completely.
    let mut reused = c;
    let sr = render_into(&bvh, &cam, &config, &mut reused, &|_| {});
    assert_eq!(sa, sr);
    let bits = |f: &pointray::film::Film| {
        let v3 = |v: &[[f32; 3]]| v.iter().flat_map(|x| x.map(f32::to_bits)).collect::<Vec<_>>();
        let first = f
            .first_hits
            .as_ref()
            .map(|c| (v3(&c.normal), v3(&c.albedo), c.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>()));
        (v3(&f.rgb), first)
    };
    assert!(bits(&a) == bits(&reused) && a.nodes_visited == reused.nodes_visited);
    // Without counting, the same image, and nothing counted.
    let quiet = RenderConfig { count_work: false, ..config.clone() };
    let (q, sq) = render(&bvh, &cam, &quiet, &|_| {});
    assert!(bits(&a) == bits(&q), "counting work changed the image");
    assert_eq!(sq.traversal.nodes_visited + sq.traversal.splat_tests + sq.traversal.lod_stops, 0, "{sq:?}");
    assert!(q.nodes_visited.iter().all(|&n| n == 0) && a.nodes_visited.iter().any(|&n| n > 0));
    // Without the first hits' channels, the same image, and no channels made; a film that has
    // them keeps them as they were.
    let plain = RenderConfig { first_hit_aovs: false, ..config.clone() };
    let (p, _) = render(&bvh, &cam, &plain, &|_| {});
    assert!(bits(&a).0 == bits(&p).0, "leaving the first hits out changed the image");
    assert!(p.first_hits.is_none() && a.first_hits.as_ref().is_some_and(|c| c.normal.iter().any(|n| *n != [0.0; 3])));
    let mut kept = pointray::film::Film::with_first_hits(config.region);
    render_into(&bvh, &cam, &plain, &mut kept, &|_| {});
    assert!(bits(&kept).0 == bits(&p).0);
    let untouched = kept.first_hits.as_ref().expect("made with them");
    assert!(untouched.normal.iter().all(|n| *n == [0.0; 3]) && untouched.depth.iter().all(|d| d.is_infinite()));
    assert_eq!((sq.rays, sq.primary_hits), (sa.rays, sa.primary_hits));
}

/// Passes over ranges of a pixel's samples, averaged by their lengths, make the image of all the
/// samples at once: the path tracer with its low-discrepancy numbers, the samples made in
/// batches through a pinhole (R2) and one at a time (random), first hits' channels included.
#[test]
fn passes_over_sample_ranges_add_up_to_the_whole_render() {
    use pointray::render::{Integrator, Sampler};
    let bvh = Bvh::build(torus_splats(20_000, 9), &BvhParams::standard());
    let cam = Camera::look_at(Vec3::new(0.3, 1.6, 2.4), Vec3::ZERO, Vec3::Y, 50.0, 24, 20);
    for sampler in [Sampler::R2, Sampler::Random] {
        let config = RenderConfig {
            sampler,
            integrator: Integrator::Path,
            environment: Environment::Uniform { color: [0.8, 0.9, 1.0] },
            lights: vec![pointray::demo::demo_light()],
            seed: 11,
            ..crate::util::render_config(pointray::camera::Region::full(24, 20), 13)
        };
        let whole = render(&bvh, &cam, &config, &|_| {}).0;
        let mut sum = vec![[0.0f32; 3]; whole.rgb.len()];
        let mut coverage = vec![0.0f32; whole.rgb.len()];
        for range in [0..5, 5..12, 12..13] {
            let len = range.len() as f32;
            let pass = render(&bvh, &cam, &RenderConfig { sample_range: Some(range), ..config.clone() }, &|_| {}).0;
            for (s, p) in sum.iter_mut().zip(&pass.rgb) {
                (0..3).for_each(|k| s[k] += p[k] * len);
            }
            let c = &pass.first_hits.as_ref().unwrap().coverage;
            coverage.iter_mut().zip(c).for_each(|(a, b)| *a += b * len);
        }
        let whole_coverage = &whole.first_hits.as_ref().unwrap().coverage;
        for (i, (s, w)) in sum.iter().zip(&whole.rgb).enumerate() {
            for k in 0..3 {
                assert!(
                    (s[k] / 13.0 - w[k]).abs() <= 1e-5 * w[k].max(1.0),
                    "{sampler:?} pixel {i}: {s:?} against {w:?}"
                );
            }
            assert!((coverage[i] / 13.0 - whole_coverage[i]).abs() < 1e-6);
        }
        assert!(whole_coverage.iter().any(|&c| c > 0.0 && c < 1.0), "edges are part-covered");
    }
}
