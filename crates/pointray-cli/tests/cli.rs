//! End-to-end tests of the `pointray` binary: every test runs the real executable on
//! synthetic inputs written to a fresh temporary directory, and checks exit codes, messages,
//! the PNG it writes (decoded) and the `--stats` JSON.

#[path = "cli/support.rs"]
mod support;

#[cfg(feature = "bench")]
#[path = "cli/bench.rs"]
mod bench;

use std::io::{BufRead, BufReader, Read};
use std::process::Stdio;

use support::*;

// ---------------------------------------------------------------------------------------------
// 1. Help texts
// ---------------------------------------------------------------------------------------------

#[test]
fn top_level_help_lists_subcommands_and_examples() {
    let dir = temp_dir();
    let run = run_in(dir.path(), &["--help"]);
    run.assert_success();
    for needle in
        ["render", "prepare", "info", "Examples:", "pointray render -o demo.png", "--crop-to-model", "--stats"]
    {
        run.assert_stdout_contains(needle);
    }
    assert_dir_contains_exactly(dir.path(), &[]);
}

#[test]
fn render_help_documents_key_flags_and_examples() {
    let dir = temp_dir();
    let run = run_in(dir.path(), &["render", "--help"]);
    run.assert_success();
    for needle in [
        "Examples:",
        "--output",
        "--crop-to-model",
        "--view-dir",
        "--distance",
        "--region",
        "--stats",
        "--surface",
        "first-hit",
        "--accel",
        "brute",
        "--spp",
        "--threads",
        "--demo-points",
        "--k-normals",
    ] {
        run.assert_stdout_contains(needle);
    }
    // Nothing is rendered or written by --help, even though -o is otherwise required.
    assert_dir_contains_exactly(dir.path(), &[]);
}

#[test]
fn prepare_and_info_help_show_their_examples() {
    let dir = temp_dir();
    let run = run_in(dir.path(), &["prepare", "--help"]);
    run.assert_success().assert_stdout_contains("Example:").assert_stdout_contains("pointray prepare");
    run.assert_stdout_contains("--output")
        .assert_stdout_contains("--recompute")
        .assert_stdout_contains("--radius-scale");

    let run = run_in(dir.path(), &["info", "--help"]);
    run.assert_success().assert_stdout_contains("Example:").assert_stdout_contains("pointray info");
    assert_dir_contains_exactly(dir.path(), &[]);
}

#[test]
fn version_and_missing_subcommand() {
    let dir = temp_dir();
    run_in(dir.path(), &["--version"]).assert_success().assert_stdout_contains("pointray");
    // No subcommand: clap's usage error (exit 2) on stderr.
    let run = run_in(dir.path(), &[]);
    assert_eq!(run.code, Some(2), "{run}");
    run.assert_no_panic();
    run.assert_stderr_contains("Usage");
    // render without -o is a usage error too.
    let run = run_in(dir.path(), &["render"]);
    assert_eq!(run.code, Some(2), "{run}");
    run.assert_stderr_contains("--output");
}

// ---------------------------------------------------------------------------------------------
// 2. The built-in demo scene, PNG and stats
// ---------------------------------------------------------------------------------------------

#[test]
fn demo_render_writes_png_and_complete_stats() {
    let dir = temp_dir();
    render_in(dir.path(), &["-o", "out.png", "--demo-points", "20000", "--stats", "s.json"]).assert_success();

    // Atomic writes leave no temporary files behind.
    assert_dir_contains_exactly(dir.path(), &["out.png", "s.json"]);

    let image = read_png(&dir.path().join("out.png"));
    assert_eq!((image.width, image.height), (W, H));
    let bg = background_srgb8();
    let lit = image.count_not(bg);
    assert!(lit > (W * H / 4) as usize, "only {lit} of {} pixels show the scene", W * H);
    assert!(lit < (W * H) as usize, "no background pixel at all: the sky is not visible");
    let distinct: std::collections::BTreeSet<[u8; 3]> = image.pixels().map(|(_, _, p)| p).collect();
    assert!(distinct.len() > 20, "a shaded scene has many colours, got {}", distinct.len());

    let s = read_stats(&dir.path().join("s.json"));
    for key in [
        "points",
        "build_seconds",
        "render_seconds",
        "rays",
        "primary_rays",
        "mrays_per_second",
        "hit_fraction",
        "nodes_visited_per_ray",
        "splat_tests_per_ray",
        "accel_bytes",
        "bytes_per_splat",
        "preprocess_seconds",
    ] {
        assert!(s.get(key).is_some(), "stats lack {key:?}: {s:#}");
    }
    let isa = s["isa"].as_str();
    assert!(matches!(isa, Some("baseline" | "avx2")), "stats name the kernels' instruction set: {isa:?}");
    let points = stat_u64(&s, "points");
    assert!((19_000..=20_000).contains(&points), "demo with 20000 points has {points}");
    let primary = stat_u64(&s, "primary_rays");
    assert_eq!(primary, u64::from(W * H));
    let rays = stat_u64(&s, "rays");
    assert!(rays >= primary, "rays {rays} < primary rays {primary}");
    assert!(rays > primary, "shadows are on by default, so some shadow rays must be traced");
    let hit = stat_f64(&s, "hit_fraction");
    assert!(hit > 0.0 && hit < 1.0, "hit_fraction {hit}");
    // The PNG and the stats agree about hits: hit pixels are not background.
    assert!((lit as f64) >= hit * f64::from(W * H) * 0.9, "{lit} lit pixels but hit fraction {hit}");
    for key in ["build_seconds", "render_seconds"] {
        let v = stat_f64(&s, key);
        assert!(v.is_finite() && v >= 0.0, "{key} = {v}");
    }
    let mrays = stat_f64(&s, "mrays_per_second");
    assert!(mrays.is_finite() && mrays > 0.0, "mrays_per_second = {mrays}");
    assert!(stat_f64(&s, "nodes_visited_per_ray") > 0.0);
    let tests = stat_f64(&s, "splat_tests_per_ray");
    assert!(tests > 0.0 && tests < points as f64, "a BVH tests far fewer splats than exist: {tests}");
    let accel_bytes = stat_u64(&s, "accel_bytes");
    let per_splat = stat_f64(&s, "bytes_per_splat");
    assert!(accel_bytes > points, "accel_bytes {accel_bytes}");
    assert!((per_splat - accel_bytes as f64 / points as f64).abs() < 1e-6 * per_splat, "bytes_per_splat {per_splat}");
    assert_eq!(s["accel"], "bvh");
    assert_eq!(s["width"], W);
    assert_eq!(s["height"], H);

    let pre = s["preprocess_seconds"].as_object().unwrap_or_else(|| panic!("preprocess_seconds is no object: {s:#}"));
    assert!(!pre.is_empty());
    let mut sum = 0.0;
    for (stage, v) in pre {
        let v = v.as_f64().unwrap_or_else(|| panic!("preprocess_seconds.{stage} is not a number"));
        assert!(v.is_finite() && v >= 0.0, "preprocess_seconds.{stage} = {v}");
        if stage != "total" {
            sum += v;
        }
    }
    if let Some(total) = pre.get("total").and_then(serde_json::Value::as_f64) {
        assert!((total - sum).abs() <= 1e-9 + 1e-6 * total, "total {total} != sum of stages {sum}");
    }
}

// ---------------------------------------------------------------------------------------------
// 3. Determinism across thread counts
// ---------------------------------------------------------------------------------------------

#[test]
fn pixels_do_not_depend_on_thread_count() {
    let dir = temp_dir();
    for spp in ["1", "2"] {
        let mut images = Vec::new();
        for threads in ["1", "2"] {
            let out = format!("t{threads}_spp{spp}.png");
            let stats = format!("t{threads}_spp{spp}.json");
            render_in(
                dir.path(),
                &["-o", &out, "--demo-points", "20000", "--threads", threads, "--spp", spp, "--stats", &stats],
            )
            .assert_success();
            let s = read_stats(&dir.path().join(&stats));
            assert_eq!(stat_u64(&s, "threads").to_string(), threads, "the pool has the requested size");
            images.push((read_png(&dir.path().join(&out)), stat_u64(&s, "rays"), stat_u64(&s, "primary_rays")));
        }
        let (a, b) = (&images[0], &images[1]);
        assert_eq!((a.0.width, a.0.height), (W, H));
        assert!(a.0 == b.0, "spp {spp}: 1 and 2 threads give different pixels");
        assert_eq!(a.1, b.1, "spp {spp}: ray counts differ between 1 and 2 threads");
        assert_eq!(a.2, b.2);
    }
}

#[test]
fn the_prefilter_renders_a_distant_demo_and_is_refused_where_it_cannot_apply() {
    let dir = temp_dir();
    // A sphere with outward normals, far enough for a pixel to hold a dozen of its points.
    let ball = write_file(dir.path(), "ball.ply", ascii_ply_with_normals(&sphere_points(20_000)));
    let ball = ball.to_str().expect("a UTF-8 path");
    let args = [ball, "--distance", "8", "--prefilter", "--aov", "alpha"];
    let mut images = Vec::new();
    for threads in ["1", "2"] {
        let out = format!("pf{threads}.png");
        let mut a = vec!["-o", out.as_str(), "--threads", threads];
        a.extend_from_slice(&args);
        let stats = format!("pf{threads}.json");
        a.extend_from_slice(&["--stats", &stats]);
        let run = render_in(dir.path(), &a);
        run.assert_success();
        assert!(!run.stderr.contains("rendering without it"), "{}", run.stderr);
        assert_eq!(read_stats(&dir.path().join(&stats))["prefilter"], true);
        images.push(read_png(&dir.path().join(&out)));
    }
    assert!(images[0] == images[1], "1 and 2 threads give different pixels");
    // Edges blend: the coverage channel has levels between empty and whole.
    let alpha = read_png(&dir.path().join("pf1.alpha.png"));
    assert!(alpha.rgb.iter().any(|&v| v > 20 && v < 235), "no partly covered pixel");
    // The kd-tree gathers too.
    let mut a = vec!["-o", "kd.png", "--accel", "kdtree", "--stats", "kd.json"];
    a.extend_from_slice(&args);
    render_in(dir.path(), &a).assert_success();
    assert_eq!(read_stats(&dir.path().join("kd.json"))["prefilter"], true);
    assert!(read_png(&dir.path().join("kd.alpha.png")).rgb.iter().any(|&v| v > 20 && v < 235));
    // A scene file asks for it in `[render]` (one ray a pixel there too).
    let scene = |spp: u32| {
        format!(
            "[camera]\neye = [0.0, 0.0, 24.0]\nlook_at = [0.0, 0.0, 0.0]\n\n[render]\nwidth = 64\nheight = 48\n\
             spp = {spp}\nlod_threshold = 1.0\nprefilter = true\n\n[[cloud]]\nfile = \"ball.ply\"\n"
        )
    };
    write_file(dir.path(), "far.toml", scene(1));
    render_in(dir.path(), &["far.toml", "-o", "scene.png", "--stats", "scene.json"]).assert_success();
    assert_eq!(read_stats(&dir.path().join("scene.json"))["prefilter"], true);
    write_file(dir.path(), "far4.toml", scene(4));
    render_in(dir.path(), &["far4.toml", "-o", "scene4.png"]).assert_failure(2).assert_stderr_contains("prefilter");
    assert!(!dir.path().join("scene4.png").exists());
    // A square scanned from above (normals up): the prefilter applies seen from above, and
    // from below, where the view meets its back, it is left out.
    let square: Vec<[f32; 3]> =
        (0..10_000).map(|i| [(i % 100) as f32 / 50.0 - 1.0, (i / 100) as f32 / 50.0 - 1.0, 0.0]).collect();
    write_file(dir.path(), "square.ply", ascii_ply_facing(&square, [0.0, 0.0, 1.0]));
    for (view, applies) in [("0.1,0.2,1", true), ("0.1,0.2,-1", false)] {
        let view = format!("--view-dir={view}");
        let args =
            ["square.ply", "-o", "square.png", "--distance", "8", "--prefilter", &view, "--stats", "square.json"];
        let run = render_in(dir.path(), &args);
        run.assert_success();
        assert_eq!(read_stats(&dir.path().join("square.json"))["prefilter"], applies, "{view}");
    }
    for (flags, why) in [
        (&["--integrator", "path"][..], "whitted and eye-light"),
        (&["--lod", "off"][..], "needs level of detail"),
        (&["--spp", "4"][..], "one ray a pixel"),
    ] {
        let mut a = vec!["-o", "refused.png", "--prefilter"];
        a.extend_from_slice(flags);
        render_in(dir.path(), &a).assert_failure(2).assert_stderr_contains(why);
        assert!(!dir.path().join("refused.png").exists());
    }
}

#[test]
fn same_seed_same_image_different_seed_different_image() {
    let dir = temp_dir();
    let base = ["--demo-points", "20000", "--spp", "2"];
    for (out, seed) in [("a.png", "7"), ("b.png", "7"), ("c.png", "8")] {
        let mut args = vec!["-o", out, "--seed", seed];
        args.extend_from_slice(&base);
        render_in(dir.path(), &args).assert_success();
    }
    let [a, b, c] = ["a.png", "b.png", "c.png"].map(|f| read_png(&dir.path().join(f)));
    assert!(a == b, "the same seed gives different pixels");
    assert!(a != c, "the seed changes neither the demo points nor the jitter");
}

// ---------------------------------------------------------------------------------------------
// 4. Brute force, the BVH and the kd-tree agree
// ---------------------------------------------------------------------------------------------

fn assert_accels_agree(dir: &std::path::Path, input: &str) {
    for surface in ["first-hit", "sj", "rfd", "pss"] {
        let mut renders = Vec::new();
        for accel in ["brute", "bvh", "kdtree"] {
            let out = format!("{input}.{surface}.{accel}.png");
            let stats = format!("{input}.{surface}.{accel}.json");
            // Full detail: brute force has no level of detail or culling to agree with.
            let args = [input, "-o", &out, "--accel", accel, "--surface", surface, "--stats", &stats];
            render_in(dir, &[&args[..], &["--lod", "off", "--cull", "off"]].concat()).assert_success();
            let s = read_stats(&dir.join(&stats));
            assert_eq!(
                s["accel"].as_str().map(str::to_ascii_lowercase).as_deref().map(|a| a.contains(accel)),
                Some(true),
                "{s:#}"
            );
            renders.push((read_png(&dir.join(&out)), s));
        }
        let (brute, sb) = &renders[0];
        let lit = brute.count_not(background_srgb8());
        assert!(lit > 100, "{input} {surface}: the sphere covers only {lit} pixels");
        // Brute force tests every splat for every ray; the others must do far less work.
        let points = stat_f64(sb, "points");
        assert!(stat_f64(sb, "splat_tests_per_ray") >= points * 0.99, "{sb:#}");
        for (image, s) in &renders[1..] {
            let accel = &s["accel"];
            let differing: Vec<_> = brute.pixels().zip(image.pixels()).filter(|(a, b)| a.2 != b.2).take(5).collect();
            assert!(differing.is_empty(), "{input} {surface}: brute force and {accel} differ, e.g. {differing:?}");
            assert_eq!(sb["hit_fraction"], s["hit_fraction"], "{input} {surface} {accel}");
            assert_eq!(sb["primary_rays"], s["primary_rays"]);
            // (PSS neighbourhoods, a few radii wide, hold a good part of these small spheres.)
            if surface != "pss" {
                assert!(stat_f64(s, "splat_tests_per_ray") < points * 0.25, "{s:#}");
            }
        }
    }
}

#[test]
fn every_accelerator_gives_identical_pixels_positions_only() {
    let dir = temp_dir();
    write_sphere(dir.path());
    assert_accels_agree(dir.path(), "sphere.ply");
}

#[test]
fn every_accelerator_gives_identical_pixels_with_normals() {
    let dir = temp_dir();
    write_file(dir.path(), "normals.ply", ascii_ply_with_normals(&sphere_points(2000)));
    assert_accels_agree(dir.path(), "normals.ply");
}

#[test]
fn surface_schemes_differ_but_cover_the_same_silhouette_roughly() {
    let dir = temp_dir();
    write_sphere(dir.path());
    for surface in ["first-hit", "sj", "rfd", "pss"] {
        render_in(dir.path(), &["sphere.ply", "-o", &format!("{surface}.png"), "--surface", surface]).assert_success();
    }
    let first = read_png(&dir.path().join("first-hit.png"));
    let sj = read_png(&dir.path().join("sj.png"));
    assert!(first != sj, "--surface has no effect on the image");
    let bg = background_srgb8();
    let (a, b) = (first.count_not(bg) as f64, sj.count_not(bg) as f64);
    assert!((a - b).abs() <= 0.1 * a.max(b), "silhouettes differ a lot: {a} vs {b} pixels");
}

/// Mirror and glass spheres in a sky: reflected and refracted rays are traced and counted,
/// and every accelerator gives the same pixels at full detail.
#[test]
fn mirror_and_glass_spheres_trace_secondary_rays_alike_in_every_accelerator() {
    let dir = temp_dir();
    write_sphere(dir.path());
    for material in ["mirror", "glass"] {
        let mut images = Vec::new();
        for accel in ["brute", "bvh", "kdtree"] {
            let (out, stats) = (format!("{material}.{accel}.png"), format!("{material}.{accel}.json"));
            let args = ["sphere.ply", "-o", &out, "--material", material, "--sky", "--accel", accel, "--lod", "off"];
            render_in(dir.path(), &[&args[..], &["--stats", &stats]].concat()).assert_success();
            let s = read_stats(&dir.path().join(&stats));
            assert_eq!(s["materials"], serde_json::json!([material]));
            // Each hit on a mirror spawns one reflected ray; on glass a reflected and (but
            // for total internal reflection) a refracted one, and more inside.
            let (hits, secondary) =
                (stat_u64(&s, "primary_rays") as f64 * stat_f64(&s, "hit_fraction"), stat_f64(&s, "secondary_rays"));
            assert!(hits > 100.0 && secondary >= hits.round(), "{s:#}");
            if material == "glass" {
                assert!(secondary > 2.5 * hits, "{s:#}");
            }
            images.push(read_png(&dir.path().join(&out)));
        }
        assert!(images[0] == images[1] && images[0] == images[2], "{material}: the accelerators differ");
    }
    run_in(dir.path(), &["-q", "render", "sphere.ply", "-o", "x.png", "--material", "glass", "--ior", "0"])
        .assert_failure(2)
        .assert_stderr_contains("--ior");
}

/// Two spheres, a mirror and a diffuse one, on a ground, under a sphere light and a sun.
fn two_sphere_scene(spp: u32) -> String {
    format!(
        r#"
[camera]
eye = [0.0, 1.5, 6.0]
look_at = [0.0, 0.5, 0.0]

[render]
width = 64
height = 48
spp = {spp}

[[light]]
kind = "sphere"
position = [-3.0, 5.0, 4.0]
radius = 0.5
intensity = 50.0

[[light]]
kind = "directional"
direction = [1.0, 1.0, 0.0]
intensity = 0.3

[[light]]
kind = "spot"
position = [1.2, 3.0, 0.0]
direction = [0.0, -1.0, 0.0]
inner = 10.0
outer = 20.0
intensity = 6.0

[ground]
color = [0.8, 0.8, 0.8]
checker = {{ color = [0.2, 0.2, 0.2], tile = 1.0 }}

[[cloud]]
file = "sphere.ply"
translate = [-1.2, 1.0, 0.0]
material = {{ kind = "mirror" }}

[[cloud]]
file = "sphere.ply"
scale = 0.5
translate = [1.2, 0.5, 0.0]
color = [0.9, 0.2, 0.1]
"#
    )
}

#[test]
fn scene_files_place_clouds_with_their_materials_and_lights() {
    let dir = temp_dir();
    write_sphere(dir.path());
    std::fs::create_dir(dir.path().join("scenes")).unwrap();
    // Cloud paths are relative to the scene file.
    std::fs::rename(dir.path().join("sphere.ply"), dir.path().join("scenes/sphere.ply")).unwrap();
    write_file(&dir.path().join("scenes"), "two.toml", two_sphere_scene(4));
    let run = run_in(dir.path(), &["-q", "render", "scenes/two.toml", "-o", "a.png", "--stats", "a.json"]);
    run.assert_success();
    let s = read_stats(&dir.path().join("a.json"));
    assert_eq!(s["materials"], serde_json::json!(["mirror", "phong"]), "{s:#}");
    assert_eq!(s["ground"], "phong", "{s:#}");
    assert_eq!(stat_u64(&s, "points_read"), 2 * 3000, "{s:#}");
    assert!(stat_u64(&s, "secondary_rays") > 0 && stat_u64(&s, "shadow_rays") > 0, "{s:#}");
    assert_eq!((stat_u64(&s, "width"), stat_u64(&s, "height"), stat_u64(&s, "samples_per_pixel")), (64, 48, 4));
    let image = read_png(&dir.path().join("a.png"));
    assert_eq!((image.width, image.height), (64, 48));
    // The red sphere is red; below the horizon the ground's light and dark squares show.
    assert!(image.pixels().any(|(_, _, [r, g, b])| r > 120 && g < 60 && b < 60), "no red sphere");
    let greys = |levels: std::ops::RangeInclusive<u8>| {
        image.pixels().filter(|&(_, y, [r, g, b])| y > 40 && r == g && g == b && levels.contains(&r)).count()
    };
    let (dark, light) = (greys(20..=110), greys(150..=255));
    assert!(dark > 20 && light > 20, "no checkered ground: {dark} dark and {light} light grey pixels");
    // The same scene, the same pixels, whatever the thread count.
    run_in(dir.path(), &["-q", "render", "scenes/two.toml", "-o", "b.png", "--threads", "1"]).assert_success();
    assert!(image == read_png(&dir.path().join("b.png")), "the thread count changed the image");
}

#[test]
fn flags_override_a_scenes_render_settings_and_may_not_contradict_the_rest() {
    let dir = temp_dir();
    write_sphere(dir.path());
    write_file(dir.path(), "two.toml", two_sphere_scene(4));
    // Render settings given as flags win: a quick look at fewer pixels and samples, without
    // level of detail.
    let quick = ["-q", "render", "two.toml", "-o", "q.png", "--spp", "2", "--width", "40", "--stats", "q.json"];
    run_in(dir.path(), &[&quick[..], &["--lod", "off"]].concat()).assert_success();
    let s = read_stats(&dir.path().join("q.json"));
    assert_eq!((stat_u64(&s, "width"), stat_u64(&s, "height"), stat_u64(&s, "samples_per_pixel")), (40, 48, 2));
    assert!(s["lod_threshold"].is_null(), "{s:#}");
    // The scene's own settings otherwise, and `lod_threshold = 0` is full detail too.
    write_file(dir.path(), "full.toml", two_sphere_scene(1).replace("spp = 1", "spp = 1\nlod_threshold = 0.0"));
    run_in(dir.path(), &["-q", "render", "full.toml", "-o", "f.png", "--stats", "f.json"]).assert_success();
    let s = read_stats(&dir.path().join("f.json"));
    assert_eq!((stat_u64(&s, "width"), stat_u64(&s, "samples_per_pixel")), (64, 1));
    assert!(s["lod_threshold"].is_null(), "{s:#}");
    // `--lod on` switches level of detail on and keeps the scene's threshold.
    write_file(dir.path(), "tau.toml", two_sphere_scene(1).replace("spp = 1", "spp = 1\nlod_threshold = 0.3"));
    run_in(dir.path(), &["-q", "render", "tau.toml", "-o", "t.png", "--lod", "on", "--stats", "t.json"])
        .assert_success();
    assert_eq!(read_stats(&dir.path().join("t.json"))["lod_threshold"], 0.3);
    // Colours and eye-dome lighting from the scene, unless a flag says otherwise.
    let shaded = two_sphere_scene(1).replace("spp = 1", "spp = 1\ncolor_by = \"normal\"\nedl = 0.5");
    write_file(dir.path(), "shaded.toml", shaded);
    run_in(dir.path(), &["-q", "render", "shaded.toml", "-o", "s.png", "--stats", "s.json"]).assert_success();
    let s = read_stats(&dir.path().join("s.json"));
    assert_eq!((&s["color_by"], &s["edl"]), (&serde_json::json!("normal"), &serde_json::json!(0.5)));
    run_in(dir.path(), &["-q", "render", "shaded.toml", "-o", "s.png", "--edl", "0", "--stats", "s.json"])
        .assert_success();
    assert_eq!(read_stats(&dir.path().join("s.json"))["edl"], 0.0);
    // The camera, lights, materials and sky are the scene's: such a flag is refused.
    for flag in [&["--fov", "30"][..], &["--light-dir", "0,1,0"], &["--material", "glass"], &["--sky"], &["--ground"]] {
        let run = run_in(dir.path(), &[&["-q", "render", "two.toml", "-o", "x.png"][..], flag].concat());
        run.assert_failure(2).assert_stderr_contains(flag[0]).assert_stderr_contains("two.toml");
    }
    assert!(!dir.path().join("x.png").exists());
}

#[test]
fn a_filmic_tone_map_keeps_highlights_that_clamping_burns_out() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let render = |name: &str, extra: &[&str]| {
        let base =
            ["-q", "render", "sphere.ply", "-o", name, "--width", "64", "--height", "64", "--light-intensity", "4"];
        run_in(dir.path(), &[&base[..], extra].concat()).assert_success();
        read_png(&dir.path().join(name))
    };
    let burnt = |image: &Image| image.pixels().filter(|(_, _, c)| c.contains(&255)).count();
    let clamp = render("clamp.png", &[]);
    let filmic = render("filmic.png", &["--tonemap", "filmic"]);
    let brighter = render("filmic2.png", &["--tonemap", "filmic", "--exposure", "1"]);
    // Four times the light saturates most of the lit sphere; the filmic curve reaches white
    // only near 12 and keeps its gradations.
    assert!(burnt(&clamp) > 500 && burnt(&filmic) == 0, "{} and {} burnt pixels", burnt(&clamp), burnt(&filmic));
    let levels = |image: &Image| image.pixels().map(|(_, _, c)| c[1]).collect::<std::collections::BTreeSet<_>>().len();
    assert!(levels(&filmic) > levels(&clamp), "{} against {} grey levels", levels(&filmic), levels(&clamp));
    // One stop more exposure brightens every lit pixel (the background too: it is radiance).
    let pairs: Vec<(u8, u8)> =
        filmic.pixels().zip(brighter.pixels()).map(|((_, _, a), (_, _, b))| (a[1], b[1])).collect();
    assert!(pairs.iter().all(|(a, b)| a <= b));
    assert!(pairs.iter().filter(|(a, b)| a < b).count() > 1000);
}

#[test]
fn ground_puts_a_floor_under_the_model_that_takes_its_shadow() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let render = |name: &str, extra: &[&str]| {
        render_in(dir.path(), &[&["sphere.ply", "-o", name][..], extra].concat()).assert_success();
        read_png(&dir.path().join(name))
    };
    let plain = render("plain.png", &[]);
    // Light from straight above: the shadow lies under the sphere, in front of it as seen.
    let floor = render("floor.png", &["--ground", "--light-dir", "0,1,0", "--stats", "floor.json"]);
    let unshadowed = render("lit.png", &["--ground", "--light-dir", "0,1,0", "--no-shadows"]);
    assert_eq!(read_stats(&dir.path().join("floor.json"))["ground"], "phong");
    // The floor fills the view below the horizon.
    let bg = background_srgb8();
    assert!(
        floor.count_not(bg) > plain.count_not(bg) + 1000,
        "{} against {}",
        floor.count_not(bg),
        plain.count_not(bg)
    );
    // Shadow rays only darken, and they darken the floor under the sphere.
    let pairs = || floor.pixels().zip(unshadowed.pixels()).map(|((_, _, a), (_, _, b))| (a[1], b[1]));
    let darker = pairs().filter(|(a, b)| a + 20 < *b).count();
    assert!(darker > 50 && pairs().all(|(a, b)| a <= b), "{darker} pixels in shadow");
}

#[test]
fn bad_scene_files_are_refused_with_their_name_and_line() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let cases = [
        ("typo.toml", two_sphere_scene(1).replace("look_at", "look_to"), "typo.toml"),
        ("line.toml", two_sphere_scene(1).replace("spp = 1", "spp = \"many\""), "line 9"),
        ("missing.toml", two_sphere_scene(1).replace("sphere.ply", "nothing.ply"), "nothing.ply"),
        (
            "both.toml",
            two_sphere_scene(1).replace("[[cloud]]\nfile", "[[cloud]]\ngrid = { size = 1.0, spacing = 0.1 }\nfile"),
            "either `file` or `grid`",
        ),
        ("flat.toml", two_sphere_scene(1).replace("[ground]", "[ground]\nup = [0.0, 0.0, 0.0]"), "[ground] up"),
        (
            "glass.toml",
            two_sphere_scene(1).replace("[ground]", "[ground]\nmaterial = { kind = \"glass\" }"),
            "[ground] material: may be phong or mirror, not glass",
        ),
        ("none.toml", "cloud = []\n[camera]\neye = [0, 0, 1]\nlook_at = [0, 0, 0]\n".to_string(), "no [[cloud]]"),
        ("scale.toml", two_sphere_scene(1).replace("scale = 0.5", "scale = -1.0"), "scale must be positive"),
        // Values TOML's types cannot refuse, named by table and key.
        (
            "dark.toml",
            two_sphere_scene(1).replace("direction = [1.0, 1.0, 0.0]", "direction = [0.0, 0.0, 0.0]"),
            "[[light]] 2: direction: must be a non-zero direction",
        ),
        (
            "negative.toml",
            two_sphere_scene(1).replace("intensity = 0.3", "intensity = -0.3"),
            "[[light]] 2: intensity: must not be negative",
        ),
        ("nan.toml", two_sphere_scene(1).replace("radius = 0.5", "radius = nan"), "[[light]] 1: radius"),
        (
            "tiny.toml",
            two_sphere_scene(1).replace("direction = [0.0, -1.0, 0.0]", "direction = [0.0, -1e-30, 0.0]"),
            "[[light]] 3: direction: must be a non-zero direction",
        ),
        (
            "ior.toml",
            two_sphere_scene(1).replace("kind = \"mirror\"", "kind = \"glass\", ior = 0.0"),
            "[[cloud]] 1 material: ior: must be positive",
        ),
        (
            "shiny.toml",
            two_sphere_scene(1).replace("color = [0.9, 0.2, 0.1]", "material = { kind = \"phong\", shine = 9.0 }"),
            "unknown field `shine`",
        ),
        ("tile.toml", two_sphere_scene(1).replace("tile = 1.0", "tile = 0.0"), "[ground]: the checker's `tile`"),
        ("spp.toml", two_sphere_scene(1).replace("spp = 1", "spp = 0"), "[render] spp"),
        ("fov.toml", two_sphere_scene(1).replace("[render]", "fov = 0.0\n[render]"), "[camera] fov"),
        (
            "animation.toml",
            format!("{}\n[animation]\nframes = 4\norbit = true\n{}", two_sphere_scene(1), keyframes(2)),
            "[animation]: give orbit = true or [[animation.keyframe]]s, not both",
        ),
        (
            "keyframe.toml",
            format!("{}\n[animation]\nframes = 4\n{}", two_sphere_scene(1), keyframes(1)),
            "[animation] keyframe a camera path needs two keyframes or more, not 1",
        ),
    ];
    for (name, text, fragment) in &cases {
        write_file(dir.path(), name, text);
        let run = run_in(dir.path(), &["-q", "render", name, "-o", "out.png"]);
        run.assert_failure(1).assert_stderr_contains(name).assert_stderr_contains(fragment);
    }
    let run = run_in(dir.path(), &["-q", "render", "line.toml", "-o", "out.png"]);
    run.assert_stderr_contains("line.toml");
    assert!(!dir.path().join("out.png").exists());
}

// ---------------------------------------------------------------------------------------------
// 5. Regions and --crop-to-model
// ---------------------------------------------------------------------------------------------

#[test]
fn region_renders_exactly_its_pixels() {
    let dir = temp_dir();
    write_sphere(dir.path());
    render_in(dir.path(), &["sphere.ply", "-o", "full.png", "--stats", "full.json"]).assert_success();
    render_in(dir.path(), &["sphere.ply", "-o", "part.png", "--stats", "part.json", "--region", "10,10,30,20"])
        .assert_success();
    let s = read_stats(&dir.path().join("part.json"));
    assert_eq!(stat_u64(&s, "primary_rays"), (30 - 10) * (20 - 10));
    assert_eq!(stat_u64(&read_stats(&dir.path().join("full.json")), "primary_rays"), u64::from(W * H));

    let full = read_png(&dir.path().join("full.png"));
    let part = read_png(&dir.path().join("part.png"));
    assert_eq!((part.width, part.height), (W, H), "a region render still writes the whole frame");
    let bg = background_srgb8();
    let mut inside_lit = 0;
    for (x, y, p) in part.pixels() {
        if (10..30).contains(&x) && (10..20).contains(&y) {
            // Per-pixel results do not depend on what else is rendered.
            assert_eq!(p, full.pixel(x, y), "pixel ({x},{y}) differs from the full-frame render");
            inside_lit += usize::from(p != bg);
        } else {
            assert_eq!(p, bg, "pixel ({x},{y}) outside the region is not background");
        }
    }
    assert!(inside_lit > 50, "the region should cover the sphere, {inside_lit} lit pixels");
}

#[test]
fn region_partly_outside_the_frame_is_clamped() {
    let dir = temp_dir();
    write_sphere(dir.path());
    render_in(dir.path(), &["sphere.ply", "-o", "c.png", "--stats", "c.json", "--region", "40,30,1000,1000"])
        .assert_success();
    let s = read_stats(&dir.path().join("c.json"));
    assert_eq!(stat_u64(&s, "primary_rays"), u64::from((W - 40) * (H - 30)));
    let image = read_png(&dir.path().join("c.png"));
    assert_eq!((image.width, image.height), (W, H));
}

#[test]
fn crop_to_model_renders_fewer_rays_and_loses_no_hits() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let common = ["sphere.ply", "--distance", "4", "--view-dir", "0.4,0.3,1"];
    let mut args = common.to_vec();
    args.extend_from_slice(&["-o", "full.png", "--stats", "full.json"]);
    render_in(dir.path(), &args).assert_success();
    let mut args = common.to_vec();
    args.extend_from_slice(&["-o", "crop.png", "--stats", "crop.json", "--crop-to-model"]);
    render_in(dir.path(), &args).assert_success();

    let full_s = read_stats(&dir.path().join("full.json"));
    let crop_s = read_stats(&dir.path().join("crop.json"));
    let (full_rays, crop_rays) = (stat_u64(&full_s, "primary_rays"), stat_u64(&crop_s, "primary_rays"));
    assert_eq!(full_rays, u64::from(W * H));
    assert!(crop_rays > 0 && crop_rays < full_rays / 2, "crop renders {crop_rays} of {full_rays} primary rays");
    let (full_hit, crop_hit) = (stat_f64(&full_s, "hit_fraction"), stat_f64(&crop_s, "hit_fraction"));
    assert!(full_hit > 0.0, "the sphere is not visible at --distance 4");
    assert!(crop_hit > full_hit, "cropping should raise the hit fraction: {crop_hit} <= {full_hit}");
    // Same number of hits: the crop is conservative.
    let (full_hits, crop_hits) = (full_hit * full_rays as f64, crop_hit * crop_rays as f64);
    assert!((full_hits - crop_hits).abs() < 0.5, "hits {full_hits} (full) vs {crop_hits} (crop)");

    // The same picture: the crop only skips pixels that would be background anyway.
    let full = read_png(&dir.path().join("full.png"));
    let crop = read_png(&dir.path().join("crop.png"));
    let differing: Vec<_> = full.pixels().zip(crop.pixels()).filter(|(a, b)| a.2 != b.2).take(5).collect();
    assert!(differing.is_empty(), "--crop-to-model changes pixels, e.g. {differing:?}");
    let r = &crop_s["region"];
    assert!(r.is_object(), "stats lack the region: {crop_s:#}");
}

// ---------------------------------------------------------------------------------------------
// 6. prepare and info
// ---------------------------------------------------------------------------------------------

#[test]
fn prepare_adds_normals_and_radii_that_info_reports() {
    let dir = temp_dir();
    write_sphere(dir.path());

    let raw = run_in(dir.path(), &["info", "sphere.ply"]);
    raw.assert_success();
    for needle in
        ["ascii", "points:      3000", "normals:     no", "radii:       no", "element:     vertex 3000", "diagonal:"]
    {
        raw.assert_stdout_contains(needle);
    }

    run_in(dir.path(), &["-q", "prepare", "sphere.ply", "-o", "prepared.ply"]).assert_success();
    assert_dir_contains_exactly(dir.path(), &["sphere.ply", "prepared.ply"]);

    let info = run_in(dir.path(), &["info", "prepared.ply"]);
    info.assert_success();
    for needle in ["file:        prepared.ply", "binary", "points:      3000", "normals:     yes", "radii:       yes"] {
        info.assert_stdout_contains(needle);
    }
    // Same bounds as the raw cloud: prepare reorders but does not move points.
    let bounds = |s: &str| s.lines().filter(|l| l.starts_with("bounds")).map(str::to_string).collect::<Vec<_>>();
    assert_eq!(bounds(&raw.stdout).len(), 2, "{raw}");
    assert_eq!(bounds(&raw.stdout), bounds(&info.stdout));

    // Rendering the prepared file uses its normals and radii instead of recomputing them.
    render_in(dir.path(), &["prepared.ply", "-o", "p.png", "--stats", "p.json"]).assert_success();
    let s = read_stats(&dir.path().join("p.json"));
    assert_eq!(stat_u64(&s, "points"), 3000);
    assert_eq!(s["preprocess"]["computed_normals"], false, "{s:#}");
    assert_eq!(s["preprocess"]["computed_radii"], false, "{s:#}");
    assert!(read_png(&dir.path().join("p.png")).count_not(background_srgb8()) > 100);
}

/// A scene file renders the image its cloud renders, without a build; it refuses settings
/// that need another build, and damage, naming the file, with no output left behind.
#[test]
fn a_prepared_scene_file_renders_as_its_cloud_does() {
    let dir = temp_dir();
    write_sphere(dir.path());
    run_in(dir.path(), &["-q", "prepare", "sphere.ply", "-o", "prepared.ply"]).assert_success();
    let run = run_in(dir.path(), &["prepare", "prepared.ply", "-o", "scene.prs"]);
    run.assert_success().assert_stderr_contains("3000 points in a BVH").assert_stderr_contains("scene.prs");
    run_in(dir.path(), &["info", "scene.prs"])
        .assert_success()
        .assert_stdout_contains("pointray scene file")
        .assert_stdout_contains("points:      3000");
    for flags in [&[][..], &["--spp", "2", "--crop-to-model"], &["--prefilter", "--lod-threshold", "1"]] {
        let args = |input: &'static str, out: &'static str| [&[input, "-o", out][..], flags].concat();
        render_in(dir.path(), &args("prepared.ply", "cloud.png")).assert_success();
        render_in(dir.path(), &args("scene.prs", "file.png")).assert_success();
        let (a, b) = (read_png(&dir.path().join("cloud.png")), read_png(&dir.path().join("file.png")));
        assert!(a.count_not(background_srgb8()) > 100, "{flags:?}");
        assert!(a == b, "{flags:?}: the scene file's image differs from its cloud's");
    }
    // As a colour flag the cloud cannot give: the input's (exit status 1).
    render_in(dir.path(), &["scene.prs", "-o", "kd.png", "--accel", "kdtree"])
        .assert_failure(1)
        .assert_stderr_contains("render the cloud it was prepared from");
    let mut bytes = std::fs::read(dir.path().join("scene.prs")).unwrap();
    bytes.truncate(bytes.len() - 1);
    write_file(dir.path(), "cut.prs", bytes);
    render_in(dir.path(), &["cut.prs", "-o", "cut.png"]).assert_failure(1).assert_stderr_contains("cut.prs: truncated");
    assert!(!dir.path().join("kd.png").exists() && !dir.path().join("cut.png").exists());
}

/// A binary PLY of `n` disks on a unit sphere with their normals pointing in, then repeats of
/// the first ten points and one point at NaN: what preprocessing turns, drops and drops.
fn write_inward_sphere(dir: &std::path::Path, n: usize, name: &str, with_normals: bool) {
    write_inward_sphere_at(dir, n, name, with_normals, 0.0);
}

/// [`write_inward_sphere`] centred at `x` on the x axis.
fn write_inward_sphere_at(dir: &std::path::Path, n: usize, name: &str, with_normals: bool, x: f32) {
    let mut body = Vec::new();
    let mut push = |p: [f32; 3], normal: [f32; 3]| {
        let attributes: &[f32] = if with_normals { &[normal[0], normal[1], normal[2], 0.06] } else { &[] };
        for &v in p.iter().chain(attributes) {
            body.extend_from_slice(&v.to_le_bytes());
        }
    };
    let point = |i: usize| {
        let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let (r, phi) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
        [r * phi.cos(), r * phi.sin(), z]
    };
    for i in (0..n).chain(0..10) {
        let p = point(i);
        push([p[0] + x, p[1], p[2]], p.map(|v| -v));
    }
    push([f32::NAN, 0.0, 0.0], [0.0, 0.0, 1.0]);
    let attributes = "property float nx\nproperty float ny\nproperty float nz\nproperty float radius\n";
    let header = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         {}end_header\n",
        n + 11,
        if with_normals { attributes } else { "" }
    );
    write_file(dir, name, [header.into_bytes(), body].concat());
}

#[test]
fn a_scene_file_prepared_out_of_core_is_the_one_prepared_in_memory() {
    let dir = temp_dir();
    write_inward_sphere(dir.path(), 5_000, "inward.ply", true);
    // Normals and radii computed: in one chunk, as in memory (`pointray_io::prepare`'s tests
    // check their orientation across the chunks of a larger cloud).
    write_inward_sphere(dir.path(), 5_000, "bare.ply", false);
    // And a LAZ file, read as a stream (laspy's plane, 18,335 points).
    let laz = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../pointray-io/tests/data/plane.laz");
    std::fs::copy(laz, dir.path().join("plane.laz")).unwrap();
    // Tiles of one survey, read as one cloud: two with normals (kept), and one without (the
    // set's normals computed), each placed as its points are read alone.
    write_inward_sphere_at(dir.path(), 3_000, "east.ply", true, 2.5);
    write_inward_sphere_at(dir.path(), 3_000, "east_bare.ply", false, 2.5);
    // And the statistical outlier filter (the points it drops move the bounds the chunks are
    // planned over).
    // And build flags; a sensor's view framing the points before the filters, as in memory.
    let inward = std::fs::read(dir.path().join("inward.ply")).unwrap();
    let at = inward.windows(8).position(|w| w == b"element ").unwrap();
    write_file(dir.path(), "seen.ply", [&inward[..at], b"comment viewpoint 0 0 5\n", &inward[at..]].concat());
    let inputs: [&[&str]; 11] = [
        &["inward.ply"],
        &["bare.ply"],
        &["plane.laz"],
        &["inward.ply", "east.ply"],
        &["inward.ply", "east_bare.ply"],
        &["inward.ply", "east.ply", "--outlier-std", "1"],
        &["bare.ply", "--outlier-std", "1.5"],
        &["inward.ply", "--surface", "rfd", "--sphere-from-level", "2"],
        &["bare.ply", "--color-by", "elevation", "--clip-plane", "0,0,1,0.5"],
        &["seen.ply", "--clip-box", "-2,-2,-2,2,2,0"],
        &["inward.ply", "east.ply", "--color-by", "normal", "--clip-box", "-2,-2,-2,2.6,2,2"],
    ];
    for input in inputs {
        run_in(dir.path(), &[&["-q", "prepare"], input, &["-o", "memory.prs"]].concat()).assert_success();
        let out =
            run_in(dir.path(), &[&["prepare"], input, &["-o", "streamed.prs", "--memory-budget", "1KiB"]].concat());
        out.assert_success().assert_stderr_contains("points in 1 chunks, out of core");
        if input.contains(&"--outlier-std") {
            out.assert_stderr_contains("points far from their neighbours (statistical outliers)");
        }
        let (memory, streamed) = (dir.path().join("memory.prs"), dir.path().join("streamed.prs"));
        assert!(std::fs::read(&memory).unwrap() == std::fs::read(&streamed).unwrap(), "{input:?}: the files differ");
    }
    let both = run_in(dir.path(), &["prepare", "inward.ply", "east.ply", "-o", "both.ply"]);
    both.assert_success().assert_stderr_contains("inward.ply and east.ply: 8000 points, normals from file");
    // Rendered as one cloud, the tiles are their scene file.
    run_in(dir.path(), &["-q", "prepare", "inward.ply", "east.ply", "-o", "both.prs"]).assert_success();
    render_in(dir.path(), &["inward.ply", "east.ply", "-o", "tiles.png"]).assert_success();
    render_in(dir.path(), &["both.prs", "-o", "both.png"]).assert_success();
    assert!(read_png(&dir.path().join("tiles.png")) == read_png(&dir.path().join("both.png")), "the images differ");
    render_in(dir.path(), &["inward.ply", "memory.prs", "-o", "x.png"])
        .assert_failure(1)
        .assert_stderr_contains("memory.prs: a scene file is read alone");
    // (A render of a scene file asks for the build flags it was prepared with: the last's.)
    let built_with = ["--color-by", "normal", "--clip-box", "-2,-2,-2,2.6,2,2"];
    render_in(dir.path(), &[&["streamed.prs", "-o", "s.png"][..], &built_with].concat()).assert_success();
    assert!(read_png(&dir.path().join("s.png")).count_not(background_srgb8()) > 100);
    // A flag the cloud cannot meet fails alike both ways, named as the flag (exit 1, as a render).
    for budget in [&[][..], &["--memory-budget", "1KiB"]] {
        run_in(dir.path(), &[&["prepare", "plane.laz", "-o", "rgb.prs", "--color-by", "rgb"][..], budget].concat())
            .assert_failure(1)
            .assert_stderr_contains("--color-by rgb: the cloud has no colours");
    }
    // What it cannot do yet is refused, naming the way: a text PLY.
    write_sphere(dir.path());
    run_in(dir.path(), &["prepare", "sphere.ply", "-o", "raw.prs", "--memory-budget", "1KiB"])
        .assert_failure(1)
        .assert_stderr_contains("prepare it without --memory-budget");
    run_in(dir.path(), &["prepare", "inward.ply", "-o", "x.prs", "--memory-budget", "lots"]).assert_failure(2);
    assert!(!dir.path().join("raw.prs").exists());
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}

#[test]
fn prepare_not_quiet_summarises_on_stderr() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let run = run_in(dir.path(), &["prepare", "sphere.ply", "-o", "out.ply"]);
    run.assert_success().assert_stderr_contains("3000 points").assert_stderr_contains("computed");
    run.assert_stderr_contains("out.ply");
    assert!(run.stdout.is_empty(), "prepare prints nothing on stdout: {run}");
}

#[test]
fn info_reads_xyz_text() {
    let dir = temp_dir();
    let points = [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [-1.0, 0.5, 2.0], [0.25, -2.0, 1.0]];
    write_file(dir.path(), "cloud.xyz", xyz_text(&points));
    let run = run_in(dir.path(), &["info", "cloud.xyz"]);
    run.assert_success();
    for needle in [
        "file:        cloud.xyz",
        "XYZ",
        "points:      4",
        "normals:     no",
        "radii:       no",
        "bounds min:  -1.000000 -2.000000 0.000000",
        "bounds max:  1.000000 2.000000 3.000000",
    ] {
        run.assert_stdout_contains(needle);
    }
    assert!(run.stderr.is_empty(), "info writes nothing to stderr on success: {run}");
}

/// The octahedron written as OFF and as OBJ (with quads split alike, and corners of every
/// form) samples to the very points of its PLY, and renders as its vertices.
#[test]
fn off_and_obj_meshes_sample_like_the_ply() {
    let dir = temp_dir();
    write_file(dir.path(), "octa.ply", octahedron_ply());
    let vertices = "1 0 0\n-1 0 0\n0 1 0\n0 -1 0\n0 0 1\n0 0 -1\n";
    let faces = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
    let mut off = format!("OFF\n# the octahedron\n6 8 12\n{vertices}");
    let mut obj = format!(
        "# the octahedron\no octa\n{}vn 0 0 1\n",
        vertices.lines().map(|v| format!("v {v}\n")).collect::<String>()
    );
    for [a, b, c] in faces {
        off += &format!("3 {a} {b} {c}\n");
        obj += &format!("f {}//1 {}/1/1 {}\n", a + 1, b + 1, c as i64 - 6);
    }
    write_file(dir.path(), "octa.off", off);
    write_file(dir.path(), "octa.obj", obj);
    for name in ["octa.ply", "octa.off", "octa.obj"] {
        let run = run_in(dir.path(), &["sample", name, "-n", "5000", "-o", &format!("{name}.dense.ply")]);
        run.assert_success().assert_stderr_contains(&format!("{name}: 8 triangles, area 6.928203; 5000 points"));
    }
    let bytes = |name: &str| std::fs::read(dir.path().join(name)).unwrap();
    assert_eq!(bytes("octa.off.dense.ply"), bytes("octa.ply.dense.ply"));
    assert_eq!(bytes("octa.obj.dense.ply"), bytes("octa.ply.dense.ply"));
    for name in ["octa.off", "octa.obj"] {
        run_in(dir.path(), &["info", name]).assert_success().assert_stdout_contains("points:      6");
    }
    // Vertex colours go with the points.
    write_file(
        dir.path(),
        "sq.off",
        "COFF\n4 2 0\n0 0 0 255 0 0\n1 0 0 0 255 0\n1 1 0 0 0 255\n0 1 0 255 255 255\n3 0 1 2\n3 0 2 3\n",
    );
    run_in(dir.path(), &["-q", "sample", "sq.off", "-n", "100", "-o", "sq.ply"]).assert_success();
    run_in(dir.path(), &["info", "sq.ply"])
        .assert_success()
        .assert_stdout_contains("uchar red, uchar green, uchar blue");
}

/// A closed mesh: the octahedron |x| + |y| + |z| = 1, wound outwards.
#[test]
fn sample_makes_a_dense_cloud_on_a_mesh() {
    let dir = temp_dir();
    write_file(dir.path(), "octa.ply", octahedron_ply());
    let run = run_in(dir.path(), &["sample", "octa.ply", "-n", "20000", "-o", "dense.ply"]);
    run.assert_success().assert_stderr_contains("octa.ply: 8 triangles, area 6.928203; 20000 points");
    let info = run_in(dir.path(), &["info", "dense.ply"]);
    info.assert_success().assert_stdout_contains("points:      20000").assert_stdout_contains("normals:     yes");
    // The same seed, the same file; every point on the surface.
    run_in(dir.path(), &["-q", "sample", "octa.ply", "-n", "20000", "-o", "again.ply"]).assert_success();
    assert_eq!(
        std::fs::read(dir.path().join("dense.ply")).unwrap(),
        std::fs::read(dir.path().join("again.ply")).unwrap()
    );
    let stats = dir.path().join("s.json");
    let args = ["dense.ply", "-o", "dense.png", "--crop-to-model", "--stats", stats.to_str().unwrap()];
    render_in(dir.path(), &args).assert_success();
    let stats = read_stats(&stats);
    assert_eq!(stat_u64(&stats, "points"), 20_000);
    // From the default view the octahedron's outline covers about a fifth of its bounding
    // box's projection (0.19 here, 0.22 at 256 x 256): a solid surface, no empty crop.
    assert!((0.15..0.3).contains(&stat_f64(&stats, "hit_fraction")), "{stats}");

    run_in(dir.path(), &["-q", "sample", "octa.ply", "-n", "0", "-o", "x.ply"]).assert_failure(2);
    run_in(dir.path(), &["-q", "sample", "dense.ply", "-n", "10", "-o", "x.ply"])
        .assert_failure(1)
        .assert_stderr_contains("dense.ply: no 'face' element: not a mesh");
    run_in(dir.path(), &["-q", "sample", "octa.ply", "-n", "10", "-o", "no/x.ply"]).assert_failure(3);
    assert_dir_contains_exactly(dir.path(), &["octa.ply", "dense.ply", "again.ply", "dense.png", "s.json"]);
}

#[test]
fn render_and_prepare_accept_xyz() {
    let dir = temp_dir();
    write_file(dir.path(), "sphere.xyz", xyz_text(&sphere_points(2000)));
    render_in(dir.path(), &["sphere.xyz", "-o", "x.png", "--stats", "x.json"]).assert_success();
    assert_eq!(stat_u64(&read_stats(&dir.path().join("x.json")), "points"), 2000);
    assert!(read_png(&dir.path().join("x.png")).count_not(background_srgb8()) > 100);
    run_in(dir.path(), &["-q", "prepare", "sphere.xyz", "-o", "x.ply"]).assert_success();
    run_in(dir.path(), &["info", "x.ply"]).assert_success().assert_stdout_contains("points:      2000");
}

/// A sphere of 3,000 points whose upper half (y > 0, the default view's up) is class 6
/// (building) and lower half class 9 (water), with an intensity that grows with y.
fn classified_sphere() -> String {
    let points = sphere_points(3000);
    let mut s = format!("ply\nformat ascii 1.0\nelement vertex {}\n", points.len());
    s.push_str("property float x\nproperty float y\nproperty float z\nproperty ushort intensity\n");
    s.push_str("property uchar classification\nend_header\n");
    for [x, y, z] in points {
        let class = if y > 0.0 { 6 } else { 9 };
        s += &format!("{x} {y} {z} {} {class}\n", ((y + 1.0) * 1000.0) as u16);
    }
    s
}

/// A scene file prepared with the render's build flags (colour, classes, a clip) keeps them:
/// rendered with the same flags it gives the cloud's image, without them it is refused; a
/// prepared PLY refuses them (they would be lost).
#[test]
fn a_scene_file_keeps_the_build_flags_it_was_prepared_with() {
    let dir = temp_dir();
    write_file(dir.path(), "classified.ply", classified_sphere());
    let build = ["--color-by", "intensity", "--classes", "6", "--clip-plane", "1,0,0,0.5"];
    let prepare = [&["-q", "prepare", "classified.ply", "-o", "top.prs"][..], &build].concat();
    run_in(dir.path(), &prepare).assert_success();
    render_in(dir.path(), &[&["classified.ply", "-o", "cloud.png"][..], &build].concat()).assert_success();
    render_in(dir.path(), &[&["top.prs", "-o", "file.png"][..], &build].concat()).assert_success();
    let (cloud, file) = (read_png(&dir.path().join("cloud.png")), read_png(&dir.path().join("file.png")));
    assert!(cloud.count_not(background_srgb8()) > 100 && cloud == file);
    render_in(dir.path(), &["top.prs", "-o", "plain.png"]).assert_failure(1).assert_stderr_contains("--color-by");
    let ply = [&["-q", "prepare", "classified.ply", "-o", "p.ply"][..], &build].concat();
    run_in(dir.path(), &ply).assert_failure(2).assert_stderr_contains("scene file");
    assert!(!dir.path().join("plain.png").exists() && !dir.path().join("p.ply").exists());
}

/// The share of the image's model pixels (not the background) where `test` holds.
fn share_of_model(image: &Image, test: impl Fn([u8; 3]) -> bool) -> f64 {
    let model: Vec<[u8; 3]> = image.pixels().map(|(.., p)| p).filter(|&p| p != background_srgb8()).collect();
    assert!(model.len() > 300, "the model covers {} pixels", model.len());
    model.iter().filter(|&&p| test(p)).count() as f64 / model.len() as f64
}

#[test]
fn colour_by_class_and_class_filters() {
    let dir = temp_dir();
    write_file(dir.path(), "sphere.ply", classified_sphere());
    let render = |name: &str, flags: &[&str]| {
        let args = [&["sphere.ply", "-o", name, "--distance", "0.6"], flags].concat();
        render_in(dir.path(), &args).assert_success();
        read_png(&dir.path().join(name))
    };
    let (red, blue) = (|p: [u8; 3]| p[0] > p[2], |p: [u8; 3]| p[2] > p[0]);
    // Buildings orange-red, water blue, lit by the headlight: both show.
    let both = render("both.png", &["--color-by", "classification"]);
    let (reds, blues) = (share_of_model(&both, red), share_of_model(&both, blue));
    assert!(reds > 0.2 && blues > 0.2, "red {reds:.2}, blue {blues:.2}");
    // A filter leaves one half: its colour alone (but at rims blended with the background).
    let water = render("water.png", &["--color-by", "classification", "--classes", "9", "--stats", "w.json"]);
    assert!(share_of_model(&water, blue) > 0.97);
    let stats = read_stats(&dir.path().join("w.json"));
    assert_eq!(
        (&stats["color_by"], &stats["classes"]),
        (&serde_json::json!("classification"), &serde_json::json!([9]))
    );
    assert_eq!(stat_u64(&stats, "points"), 1500, "half the sphere");
    let buildings = render("buildings.png", &["--color-by", "classification", "--exclude-classes", "9,2"]);
    assert!(share_of_model(&buildings, red) > 0.95);
    // Intensity on viridis: from purple (low, blue above red) to yellow (high, red above blue).
    let ramp = render("ramp.png", &["--color-by", "intensity"]);
    assert!(share_of_model(&ramp, red) > 0.2 && share_of_model(&ramp, blue) > 0.2);
    // By default the attributes change nothing: the same image as the bare positions'.
    let plain = render("plain.png", &[]);
    write_file(dir.path(), "bare.ply", ascii_ply(&sphere_points(3000), 0));
    render_in(dir.path(), &["bare.ply", "-o", "bare.png", "--distance", "0.6"]).assert_success();
    assert_eq!(plain.rgb, read_png(&dir.path().join("bare.png")).rgb);
}

#[test]
fn colour_and_class_flags_the_cloud_cannot_serve_are_refused() {
    let dir = temp_dir();
    write_sphere(dir.path());
    for (flags, message) in [
        (&["--color-by", "intensity"][..], "--color-by intensity: the cloud has no intensity"),
        (&["--color-by", "rgb"][..], "--color-by rgb: the cloud has no colours"),
        (&["--classes", "2"][..], "--classes needs classified points; the cloud has no classification"),
    ] {
        let args = [&["sphere.ply", "-o", "x.png"], flags].concat();
        render_in(dir.path(), &args).assert_failure(1).assert_stderr_contains(message);
        assert!(!dir.path().join("x.png").exists(), "no partial output");
    }
    write_file(dir.path(), "classified.ply", classified_sphere());
    render_in(dir.path(), &["classified.ply", "-o", "x.png", "--classes", "2,3"])
        .assert_failure(1)
        .assert_stderr_contains("--classes leaves no points (the cloud's classes: 6, 9)");
}

/// A 16-bit PNG's samples and its colour type.
fn read_png16(path: &std::path::Path) -> (Vec<u16>, png::ColorType) {
    let (bytes, info) = png_bytes(path);
    assert_eq!(info.bit_depth, png::BitDepth::Sixteen);
    (bytes.chunks_exact(2).map(|b| u16::from_be_bytes([b[0], b[1]])).collect(), info.color_type)
}

#[test]
fn a_16_bit_png_holds_the_8_bit_image_and_more() {
    let dir = temp_dir();
    write_sphere(dir.path());
    for (flags, color) in [(&[][..], png::ColorType::Rgb), (&["--transparent"][..], png::ColorType::Rgba)] {
        render_in(dir.path(), &[&["sphere.ply", "-o", "a.png"], flags].concat()).assert_success();
        render_in(dir.path(), &[&["sphere.ply", "-o", "b.png", "--bit-depth", "16"], flags].concat()).assert_success();
        let eight = png_samples(&dir.path().join("a.png"));
        let (sixteen, color_type) = read_png16(&dir.path().join("b.png"));
        assert_eq!((color_type, sixteen.len()), (color, eight.len()));
        // The same image: each 16-bit sample rounds to the 8-bit one, give or take the 8-bit
        // table's rounding; and finer steps than 8 bits have.
        assert!(sixteen.iter().zip(&eight).all(|(&s, &e)| (f64::from(s) / 257.0 - f64::from(e)).abs() <= 0.51));
        assert!(sixteen.iter().any(|&s| s % 257 != 0), "more than 256 levels");
    }
    render_in(dir.path(), &["sphere.ply", "-o", "c.exr", "--bit-depth", "16"]).assert_failure(2);
}

/// Any 8-bit PNG's samples.
fn png_samples(path: &std::path::Path) -> Vec<u8> {
    let (bytes, info) = png_bytes(path);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    bytes
}

/// A PNG's image bytes, whatever its colour type and depth, and what it is.
fn png_bytes(path: &std::path::Path) -> (Vec<u8>, png::OutputInfo) {
    let decoder = png::Decoder::new(std::io::Cursor::new(std::fs::read(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    (buf, info)
}

/// `n` keyframes round the two spheres, the first the scene's own camera.
fn keyframes(n: usize) -> String {
    let eyes = ["[0.0, 1.5, 6.0]", "[4.0, 2.0, 4.0]", "[6.0, 1.0, 0.0]"];
    eyes[..n].iter().map(|eye| format!("[[animation.keyframe]]\neye = {eye}\nlook_at = [0.0, 0.5, 0.0]\n")).collect()
}

#[test]
fn a_scene_files_animation_renders_its_frames_along_its_keyframes() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let scene = format!("{}\n[animation]\nframes = 5\n{}", two_sphere_scene(1), keyframes(3));
    write_file(dir.path(), "path.toml", &scene);
    write_file(dir.path(), "still.toml", two_sphere_scene(1));
    run_in(dir.path(), &["-q", "render", "still.toml", "-o", "still.png"]).assert_success();
    run_in(dir.path(), &["-q", "render", "path.toml", "-o", "fly_###.png", "--frames", "0..3"]).assert_success();
    let frames = ["fly_000.png", "fly_001.png", "fly_002.png"].map(|f| read_png(&dir.path().join(f)));
    assert!(!dir.path().join("fly_003.png").exists());
    assert_eq!(frames[0].rgb, read_png(&dir.path().join("still.png")).rgb, "the first keyframe is the camera");
    assert!(frames[0].rgb != frames[1].rgb && frames[1].rgb != frames[2].rgb);
    // The last frame is the last keyframe, rendered alone.
    run_in(dir.path(), &["-q", "render", "path.toml", "-o", "fly_###.png", "--frames", "4"]).assert_success();
    let last = two_sphere_scene(1).replace("eye = [0.0, 1.5, 6.0]", "eye = [6.0, 1.0, 0.0]");
    write_file(dir.path(), "last.toml", &last);
    run_in(dir.path(), &["-q", "render", "last.toml", "-o", "last.png"]).assert_success();
    assert_eq!(read_png(&dir.path().join("fly_004.png")).rgb, read_png(&dir.path().join("last.png")).rgb);
    // An orbit in the file is the turntable's.
    write_file(dir.path(), "orbit.toml", format!("{}\n[animation]\nframes = 3\norbit = true\n", two_sphere_scene(1)));
    run_in(dir.path(), &["-q", "render", "orbit.toml", "-o", "orbit.png", "--frames", "1"]).assert_success();
    run_in(dir.path(), &["-q", "render", "still.toml", "-o", "turn.png", "--turntable", "3"]).assert_success();
    assert_eq!(read_png(&dir.path().join("orbit_0001.png")).rgb, read_png(&dir.path().join("turn_0001.png")).rgb);
    // Frames the animation has not, or an animation the input has not.
    let past = run_in(dir.path(), &["-q", "render", "path.toml", "-o", "x.png", "--frames", "4..6"]);
    past.assert_failure(2).assert_stderr_contains("the animation has frames 0..5");
    let none = run_in(dir.path(), &["-q", "render", "sphere.ply", "-o", "x.png", "--frames", "0..2"]);
    none.assert_failure(2).assert_stderr_contains("need an animation");
    let stats =
        run_in(dir.path(), &["-q", "render", "path.toml", "-o", "x.png", "--frames", "0..2", "--stats", "x.json"]);
    stats.assert_failure(2).assert_stderr_contains("single frame's");
    assert!(!dir.path().join("x.png").exists() && !dir.path().join("x_0000.png").exists());
    // Asked for no frames, the scene renders its camera's view.
    run_in(dir.path(), &["-q", "render", "path.toml", "-o", "view.png", "--stats", "view.json"]).assert_success();
    assert_eq!(read_png(&dir.path().join("view.png")).rgb, read_png(&dir.path().join("still.png")).rgb);
}

#[test]
fn an_animation_to_mp4_is_encoded_or_left_as_frames_without_ffmpeg() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let args = ["-q", "render", "sphere.ply", "-o", "turn.mp4", "--turntable", "3", "--width", "33", "--height", "24"];
    // Without ffmpeg: the frames, as PNGs beside the video's name.
    let missing = run_in_with_env(dir.path(), &args[1..], &[("POINTRAY_FFMPEG", "/nonexistent/ffmpeg")]);
    missing.assert_success().assert_stderr_contains("writing the frames as PNGs");
    for k in 0..3 {
        assert!(dir.path().join(format!("turn_{k:04}.png")).exists());
    }
    assert!(!dir.path().join("turn.mp4").exists());
    let has_ffmpeg = std::process::Command::new("ffmpeg").arg("-version").output().is_ok_and(|o| o.status.success());
    if !has_ffmpeg {
        eprintln!("ffmpeg not installed: the MP4 itself is not checked");
        return;
    }
    run_in(dir.path(), &args).assert_success();
    let video = std::fs::read(dir.path().join("turn.mp4")).unwrap();
    assert_eq!(&video[4..8], b"ftyp", "an MP4 file");
    let mut probe = std::process::Command::new("ffmpeg");
    let decoded = probe.args(["-v", "error", "-i", "turn.mp4", "-f", "null", "-"]).current_dir(dir.path()).output();
    let decoded = decoded.unwrap();
    assert!(decoded.status.success(), "{}", String::from_utf8_lossy(&decoded.stderr));
    // Nothing left beside the video: the frames went to ffmpeg as they came, no partial file.
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().filter_map(|e| e.ok()).collect();
    assert_eq!(left.len(), 5, "{left:?}");
}

#[test]
fn a_turntable_writes_its_frames_the_first_the_plain_view() {
    let dir = temp_dir();
    write_sphere(dir.path());
    render_in(dir.path(), &["sphere.ply", "-o", "plain.png", "--ground"]).assert_success();
    render_in(dir.path(), &["sphere.ply", "-o", "turn.png", "--ground", "--turntable", "3"]).assert_success();
    assert_dir_contains_exactly(
        dir.path(),
        &["sphere.ply", "plain.png", "turn_0000.png", "turn_0001.png", "turn_0002.png"],
    );
    let [plain, first, second] = ["plain.png", "turn_0000.png", "turn_0001.png"].map(|f| read_png(&dir.path().join(f)));
    assert_eq!(plain.rgb, first.rgb);
    assert_ne!(first.rgb, second.rgb, "the floor's checks turn with the camera");
    render_in(dir.path(), &["sphere.ply", "-o", "x.png", "--turntable", "2", "--stats", "x.json"]).assert_failure(2);
}

#[test]
fn clip_boxes_and_planes_keep_their_part() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let points = |flags: &[&str]| {
        let args = [&["sphere.ply", "-o", "x.png", "--stats", "x.json"], flags].concat();
        render_in(dir.path(), &args).assert_success();
        stat_u64(&read_stats(&dir.path().join("x.json")), "points")
    };
    let expect = |keep: &dyn Fn([f32; 3]) -> bool| sphere_points(3000).into_iter().filter(|p| keep(*p)).count() as u64;
    assert_eq!(points(&["--clip-plane", "0,0,1,0.25"]), expect(&|p| p[2] <= 0.25));
    assert_eq!(
        points(&["--clip-plane", "0,0,1,0.25", "--clip-plane", "-1,0,0,0"]),
        expect(&|p| p[2] <= 0.25 && p[0] >= 0.0)
    );
    assert_eq!(points(&["--clip-box", "-2,-2,-0.5,2,2,0.5"]), expect(&|p| p[2].abs() <= 0.5));
    render_in(dir.path(), &["sphere.ply", "-o", "y.png", "--clip-box", "5,5,5,6,6,6"])
        .assert_failure(1)
        .assert_stderr_contains("--clip-box leaves no points");
    assert!(!dir.path().join("y.png").exists());
}

#[test]
fn columns_name_a_text_layout_the_first_line_cannot_tell() {
    let dir = temp_dir();
    // x y z r g b intensity: seven columns, which by themselves read as x y z intensity r g b.
    let mut text = String::new();
    for (i, [x, y, z]) in sphere_points(3000).into_iter().enumerate() {
        text += &format!("{x} {y} {z} 200 30 20 {}\n", i % 100);
    }
    write_file(dir.path(), "scan.txt", text);
    let run = run_in(dir.path(), &["info", "scan.txt", "--columns", "x,y,z,r,g,b,i"]);
    run.assert_success().assert_stdout_contains("properties:  x, y, z, red, green, blue, intensity");
    render_in(dir.path(), &["scan.txt", "-o", "red.png", "--columns", "x,y,z,r,g,b,i"]).assert_success();
    let red = read_png(&dir.path().join("red.png"));
    assert!(share_of_model(&red, |p| p[0] > 2 * p[2]) > 0.95, "the colour columns are red");
    render_in(dir.path(), &["scan.txt", "-o", "guessed.png"]).assert_success();
    assert!(share_of_model(&read_png(&dir.path().join("guessed.png")), |p| p[0] > 2 * p[2]) < 0.5);
    // A layout that does not fit, or does not parse, is named.
    render_in(dir.path(), &["scan.txt", "-o", "x.png", "--columns", "x,y,z,r,g,b"])
        .assert_failure(1)
        .assert_stderr_contains("expected 6 values (x y z red green blue), found 7");
    run_in(dir.path(), &["info", "scan.txt", "--columns", "x,y,q"])
        .assert_failure(2)
        .assert_stderr_contains("unknown column 'q'");
    write_file(dir.path(), "five.txt", "1 2 3 4 5\n");
    render_in(dir.path(), &["five.txt", "-o", "x.png"]).assert_failure(1).assert_stderr_contains("--columns");
}

// ---------------------------------------------------------------------------------------------
// 7. Bad input files
// ---------------------------------------------------------------------------------------------

/// Bad input files, by name: (file name, contents or None for "does not exist").
fn bad_inputs() -> Vec<(&'static str, Option<Vec<u8>>)> {
    let points = sphere_points(100);
    let mut truncated = binary_ply(&points, 100);
    truncated.truncate(truncated.len() - 100 * 12 / 2 - 5);
    let garbage = ascii_ply(&points[..10], 0).replace("\n0.", "\nbanana ").into_bytes();
    assert!(garbage.windows(6).any(|w| w == b"banana"));
    let huge_binary = binary_ply(&points, 1_000_000_000_000);
    let huge_ascii = ascii_ply(&points, 0).replace("element vertex 100", "element vertex 1000000000000").into_bytes();
    vec![
        ("missing.ply", None),
        ("empty.ply", Some(Vec::new())),
        ("truncated.ply", Some(truncated)),
        ("garbage.ply", Some(garbage)),
        ("huge_binary.ply", Some(huge_binary)),
        ("huge_ascii.ply", Some(huge_ascii)),
        ("not_a_ply.ply", Some(b"hello world\n1 2 3\n".to_vec())),
        ("header_only.ply", Some(b"ply\nformat ascii 1.0\nelement vertex 3\n".to_vec())),
        ("garbage.xyz", Some(b"1 2 3\n4 five 6\n".to_vec())),
        ("mystery.bin", Some(vec![0xff, 0x00, 0x13, 0x37, 0x80, 0x81])),
    ]
}

#[track_caller]
fn assert_clean_failure(run: &Run, file: &str) {
    run.assert_failure(1);
    run.assert_stderr_contains(file);
    run.assert_stderr_contains("error");
}

#[test]
fn bad_input_files_fail_cleanly_in_every_command() {
    let dir = temp_dir();
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    let mut inputs = Vec::new();
    for (name, contents) in bad_inputs() {
        if let Some(bytes) = contents {
            write_file(dir.path(), name, bytes);
            inputs.push(name.to_string());
        }
    }
    for (name, _) in bad_inputs() {
        let runs = [
            render_in(dir.path(), &[name, "-o", "out.png", "--stats", "out.json"]),
            render_in(dir.path(), &[name, "-o", "sub/out.png"]),
            run_in(dir.path(), &["-q", "prepare", name, "-o", "out.ply"]),
            run_in(dir.path(), &["prepare", name, "-o", "sub/out.ply"]),
            run_in(dir.path(), &["info", name]),
        ];
        for run in &runs {
            assert_clean_failure(run, name);
            assert!(run.stdout.is_empty(), "nothing on stdout for a failure: {run}");
        }
        // No output (nor temporary file) appeared, neither beside the inputs nor in sub/.
        let mut expected: Vec<&str> = inputs.iter().map(String::as_str).collect();
        expected.push("sub");
        assert_dir_contains_exactly(dir.path(), &expected);
        assert_dir_contains_exactly(&sub, &[]);
    }
}

#[test]
fn bad_input_errors_name_the_problem() {
    let dir = temp_dir();
    for (name, contents) in bad_inputs() {
        if let Some(bytes) = contents {
            write_file(dir.path(), name, bytes);
        }
    }
    let msg = |name: &str| {
        let run = run_in(dir.path(), &["info", name]);
        assert_clean_failure(&run, name);
        run.stderr.to_lowercase()
    };
    assert!(msg("missing.ply").contains("no such file"));
    assert!(msg("empty.ply").contains("empty"));
    // Binary errors carry a byte offset, text errors a line number.
    assert!(msg("truncated.ply").contains("byte"));
    assert!(msg("garbage.ply").contains("line"));
    assert!(msg("garbage.xyz").contains("line 2"));
    let huge = msg("huge_binary.ply");
    assert!(huge.contains("1000000000000"), "the claimed count is reported: {huge}");

    // An absolute path appears as given.
    let abs = dir.path().join("empty.ply");
    let run = run_in(dir.path(), &["info", abs.to_str().unwrap()]);
    assert_clean_failure(&run, abs.to_str().unwrap());
}

#[test]
fn cloud_without_finite_points_is_an_error() {
    let dir = temp_dir();
    write_file(dir.path(), "nan.xyz", "nan nan nan\ninf 1 2\n");
    write_file(dir.path(), "zero.ply", ascii_ply(&[], 0));
    for name in ["nan.xyz", "zero.ply"] {
        let run = render_in(dir.path(), &[name, "-o", "out.png"]);
        assert_clean_failure(&run, name);
        run.assert_stderr_contains("no (finite) points");
        let run = run_in(dir.path(), &["-q", "prepare", name, "-o", "out.ply"]);
        assert_clean_failure(&run, name);
    }
    assert_dir_contains_exactly(dir.path(), &["nan.xyz", "zero.ply"]);
    // info describes such a file without failing.
    run_in(dir.path(), &["info", "nan.xyz"]).assert_success().assert_stdout_contains("non-finite:  2 points");
    run_in(dir.path(), &["info", "zero.ply"]).assert_success().assert_stdout_contains("points:      0");
}

/// The fixture directory: one small file per class of bad input, with its exact outcome.
fn bad_input_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad-input")
}

/// Every file in `tests/bad-input` through `prepare` (whose exit status and whole stderr must
/// match `NAME.expected` exactly) and `render` (same exit status; quiet, so only an error).
#[test]
fn bad_input_classes_have_exact_outcomes() {
    let mut checked = 0;
    for entry in std::fs::read_dir(bad_input_dir()).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_str().unwrap().to_string();
        if name.ends_with(".expected") || name == "README.md" {
            continue;
        }
        let expected = std::fs::read_to_string(path.with_file_name(format!("{name}.expected")))
            .unwrap_or_else(|e| panic!("{name}: no .expected file: {e}"));
        let (status_line, expected_stderr) = expected.split_once('\n').unwrap();
        let status: i32 = status_line.strip_prefix("exit ").unwrap().parse().unwrap();

        let dir = temp_dir();
        std::fs::copy(&path, dir.path().join(&name)).unwrap();
        let run = run_in(dir.path(), &["prepare", &name, "-o", "out.ply"]);
        run.assert_no_panic();
        assert_eq!(run.code, Some(status), "{name}: {run}");
        assert_eq!(run.stderr, expected_stderr, "{name}: stderr");
        let render = render_in(dir.path(), &[&name, "-o", "out.png"]);
        assert_eq!(render.code, Some(status), "{name}: render: {render}");
        if status == 0 {
            assert!(render.stderr.is_empty(), "{name}: render: {render}");
            assert_dir_contains_exactly(dir.path(), &[&name, "out.ply", "out.png"]);
        } else {
            let error_line = expected_stderr.lines().last().unwrap();
            assert_eq!(render.stderr.trim_end(), error_line, "{name}: render");
            assert_dir_contains_exactly(dir.path(), &[&name]);
        }
        checked += 1;
    }
    assert!(checked >= 20, "only {checked} bad-input files found");
}

// ---------------------------------------------------------------------------------------------
// 7a. Exit statuses and Ctrl-C
// ---------------------------------------------------------------------------------------------

#[test]
fn exit_statuses_tell_input_usage_and_output_failures_apart() {
    let dir = temp_dir();
    write_sphere(dir.path());
    render_in(dir.path(), &["sphere.ply", "-o", "a.png"]).assert_success();
    render_in(dir.path(), &["missing.ply", "-o", "b.png"]).assert_failure(1);
    render_in(dir.path(), &["sphere.ply", "-o", "b.png", "--fov", "0"]).assert_failure(2);
    render_in(dir.path(), &["sphere.ply", "-o", "b.png", "--no-such-flag"]).assert_failure(2);
    run_in(dir.path(), &["-q", "prepare", "sphere.ply", "-o", "b.ply", "--k-normals", "1"]).assert_failure(2);
    render_in(dir.path(), &["sphere.ply", "-o", "no/such/dir/b.png"]).assert_failure(3);
    std::fs::create_dir(dir.path().join("folder.png")).unwrap();
    render_in(dir.path(), &["sphere.ply", "-o", "folder.png"]).assert_failure(3);
    render_in(dir.path(), &["sphere.ply", "-o", "b.jpg"]).assert_failure(2);
    assert_dir_contains_exactly(dir.path(), &["sphere.ply", "a.png", "folder.png"]);
}

/// Ctrl-C in the middle of a render: status 130, a message, and no file at all.
#[cfg(unix)]
#[test]
fn interrupted_render_exits_130_and_leaves_nothing() {
    let dir = temp_dir();
    let args =
        ["render", "-o", "big.png", "--stats", "big.json", "--width", "2000", "--height", "2000", "--spp", "256"];
    let mut child = pointray().current_dir(dir.path()).args(args).stderr(Stdio::piped()).spawn().unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    assert!(child.try_wait().unwrap().is_none(), "the render must still be running when interrupted");
    let kill = std::process::Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(kill.success());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{stderr}");
    assert!(stderr.ends_with("pointray: interrupted\n"), "{stderr}");
    assert_dir_contains_exactly(dir.path(), &[]);
}

fn write_tiny_clouds(dir: &std::path::Path) {
    write_file(dir, "two.xyz", "1 2 3\n1 2 4\n");
    write_file(dir, "same.xyz", "1 2 3\n1 2 4\n".repeat(50));
    write_file(dir, "line.xyz", (0..50).map(|i| format!("{i} 0 0\n")).collect::<String>());
}

/// Renders `name` with every accelerator; they must succeed and agree.
fn assert_tiny_cloud_renders(dir: &std::path::Path, name: &str) {
    let mut images = Vec::new();
    for accel in ["brute", "bvh", "kdtree"] {
        let out = format!("{name}.{accel}.png");
        render_in(dir, &[name, "-o", &out, "--accel", accel]).assert_success();
        let image = read_png(&dir.join(&out));
        assert_eq!((image.width, image.height), (W, H));
        images.push(image);
    }
    assert!(images[0] == images[1], "{name}: brute force and BVH differ");
    assert!(images[0] == images[2], "{name}: brute force and kd-tree differ");
    run_in(dir, &["-q", "prepare", name, "-o", &format!("{name}.ply")]).assert_success();
}

/// Two points, 100 points repeating two positions, and 50 collinear ones: defined results,
/// the same with every accelerator, and no panic.
#[test]
fn tiny_and_degenerate_clouds_render_without_panicking() {
    let dir = temp_dir();
    write_tiny_clouds(dir.path());
    for name in ["two.xyz", "same.xyz", "line.xyz"] {
        assert_tiny_cloud_renders(dir.path(), name);
    }
}

// ---------------------------------------------------------------------------------------------
// 7b. Bad flags
// ---------------------------------------------------------------------------------------------

#[test]
fn bad_flags_are_rejected_with_clear_messages() {
    let dir = temp_dir();
    write_sphere(dir.path());
    // (extra args, exit code, words the message must contain)
    let cases: &[(&[&str], i32, &[&str])] = &[
        (&["--width", "0", "--height", "40"], 2, &["--width", "positive"]),
        (&["--width", "48", "--height", "0"], 2, &["--height", "positive"]),
        (&["--width", "48", "--height", "40", "--fov", "0"], 2, &["--fov"]),
        (&["--width", "48", "--height", "40", "--fov", "180"], 2, &["--fov"]),
        (&["--width", "48", "--height", "40", "--distance=-1"], 2, &["--distance", "positive"]),
        (&["--width", "48", "--height", "40", "--distance", "0"], 2, &["--distance", "positive"]),
        // `-1` looks like a flag to clap: a usage error that tells how to pass it.
        (&["--width", "48", "--height", "40", "--distance", "-1"], 2, &["-1"]),
        (&["--width", "48", "--height", "40", "--spp", "0"], 2, &["--spp"]),
        (&["--width", "48", "--height", "40", "--k-normals", "2"], 2, &["--k-normals"]),
        (&["--width", "48", "--height", "40", "--k-radius", "0"], 2, &["--k-radius"]),
        (&["--width", "48", "--height", "40", "--k-normals", "100000"], 2, &["--k-normals", "at most 256"]),
        (&["--width", "48", "--height", "40", "--k-radius", "257"], 2, &["--k-radius", "256"]),
        (&["--width", "48", "--height", "40", "--radius-scale", "0"], 2, &["--radius-scale"]),
        (&["--width", "48", "--height", "40", "--region", "5,5,2,2"], 2, &["--region", "empty region"]),
        (&["--width", "48", "--height", "40", "--region", "1,2,3"], 2, &["--region", "4"]),
        (&["--width", "48", "--height", "40", "--region", "1.5,0,3,3"], 2, &["--region", "integers"]),
        (&["--width", "48", "--height", "40", "--region", "100,100,200,200"], 2, &["--region", "outside"]),
        (&["--width", "48", "--height", "40", "--region", "0,0,8,8", "--crop-to-model"], 2, &["--crop-to-model"]),
        (&["--width", "48", "--height", "40", "--eye", "0,0,3"], 2, &["--look-at"]),
        (&["--width", "48", "--height", "40", "--view-dir", "1,2"], 2, &["--view-dir", "3"]),
        (&["--width", "48", "--height", "40", "--view-dir", "1,nan,2"], 2, &["--view-dir"]),
        (&["--width", "48", "--height", "40", "--accel", "octree"], 2, &["--accel", "bvh", "kdtree", "brute"]),
        (&["--width", "48", "--height", "40", "--surface", "nope"], 2, &["--surface", "first-hit"]),
        (&["--width", "abc"], 2, &["--width"]),
        (&["--width", "48", "--height", "40", "--lod-threshold=-1"], 2, &["--lod-threshold", "non-negative"]),
        (&["--width", "48", "--height", "40", "--lod-threshold", "inf"], 2, &["--lod-threshold", "non-negative"]),
        (&["--width", "48", "--height", "40", "--lod", "maybe"], 2, &["--lod", "on", "off"]),
        (&["--width", "48", "--height", "40", "--cull", "always"], 2, &["--cull", "auto"]),
        (&["--width", "48", "--height", "40", "--sphere-from-level", "deep"], 2, &["--sphere-from-level", "never"]),
        (&["--width", "48", "--height", "40", "--aov", "colour"], 2, &["--aov", "nodes", "albedo"]),
        (&["--width", "48", "--height", "40", "--lens-radius=-1"], 2, &["--lens-radius must be non-negative"]),
        (&["--width", "48", "--height", "40", "--focus-distance", "0"], 2, &["--focus-distance"]),
        (&["--width", "48", "--height", "40", "--exposure", "nan"], 2, &["--exposure"]),
        (&["--width", "48", "--height", "40", "--tonemap", "gamma"], 2, &["--tonemap", "clamp", "filmic"]),
    ];
    for (extra, code, words) in cases {
        let mut args = vec!["-q", "render", "sphere.ply", "-o", "out.png"];
        args.extend_from_slice(extra);
        let run = run_in(dir.path(), &args);
        run.assert_failure(*code);
        for w in *words {
            run.assert_stderr_contains(w);
        }
        run.assert_stderr_contains("error");
        assert_dir_contains_exactly(dir.path(), &["sphere.ply"]);
    }
    // The extension of -o chooses the format: another one is not quietly written as PNG.
    for name in ["out.jpg", "out"] {
        let run = run_in(dir.path(), &["-q", "render", "sphere.ply", "-o", name, "--width", "48", "--height", "40"]);
        run.assert_failure(2).assert_stderr_contains(name).assert_stderr_contains(".png, .exr or .mp4");
        assert_dir_contains_exactly(dir.path(), &["sphere.ply"]);
    }
}

#[test]
fn region_outside_frame_message_shows_the_region_as_typed() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let run = render_in(dir.path(), &["sphere.ply", "-o", "out.png", "--region", "100,100,200,200"]);
    run.assert_failure(2).assert_stderr_contains("100,100,200,200");
    assert!(!run.stderr.contains("Some("), "{run}");
    assert!(!run.stderr.contains("Region {"), "{run}");
}

#[test]
fn degenerate_camera_is_rejected() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let cases: &[&[&str]] = &[&["--view-dir", "0,0,0"], &["--up", "0,0,0"], &["--eye", "1,1,1", "--look-at", "1,1,1"]];
    for extra in cases {
        let mut args = vec!["sphere.ply", "-o", "out.png"];
        args.extend_from_slice(extra);
        let run = render_in(dir.path(), &args);
        run.assert_failure(2).assert_stderr_contains("error");
        assert!(!dir.path().join("out.png").exists(), "{run}");
    }
}

#[test]
fn huge_frames_are_rejected_up_front() {
    let dir = temp_dir();
    write_sphere(dir.path());
    for size in ["4000000000", "100000"] {
        // A memory limit keeps a regression from thrashing the machine; a fixed CLI refuses
        // these sizes before allocating anything.
        let script =
            format!("ulimit -v 2000000; exec \"$0\" -q render sphere.ply -o out.png --width {size} --height {size}");
        let output = std::process::Command::new("sh")
            .args(["-c", &script, env!("CARGO_BIN_EXE_pointray")])
            .current_dir(dir.path())
            .env("RUST_BACKTRACE", "0")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "size {size}: {stderr}");
        assert!(!stderr.contains("panicked") && !stderr.contains("memory allocation"), "size {size}: {stderr}");
        assert!(stderr.contains("--width"), "size {size}: {stderr}");
        assert_dir_contains_exactly(dir.path(), &["sphere.ply"]);
    }
}

// ---------------------------------------------------------------------------------------------
// 8. A failed run does not clobber an existing output
// ---------------------------------------------------------------------------------------------

#[test]
fn failed_render_keeps_the_existing_output() {
    let dir = temp_dir();
    write_file(dir.path(), "empty.ply", b"");
    write_file(
        dir.path(),
        "garbage.ply",
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\nx\n",
    );
    let old_png = b"not really a png, but precious".to_vec();
    let old_ply = b"an older prepared cloud".to_vec();
    let old_json = b"{\"old\": true}".to_vec();
    write_file(dir.path(), "out.png", &old_png);
    write_file(dir.path(), "out.ply", &old_ply);
    write_file(dir.path(), "s.json", &old_json);

    let runs = [
        (1, render_in(dir.path(), &["empty.ply", "-o", "out.png", "--stats", "s.json"])),
        (1, render_in(dir.path(), &["garbage.ply", "-o", "out.png", "--stats", "s.json"])),
        (1, render_in(dir.path(), &["missing.ply", "-o", "out.png", "--stats", "s.json"])),
        (2, render_in(dir.path(), &["-o", "out.png", "--stats", "s.json", "--fov", "0"])),
        (1, run_in(dir.path(), &["-q", "prepare", "garbage.ply", "-o", "out.ply"])),
        (1, run_in(dir.path(), &["-q", "prepare", "empty.ply", "-o", "out.ply"])),
    ];
    for (status, run) in &runs {
        run.assert_failure(*status);
        assert_eq!(std::fs::read(dir.path().join("out.png")).unwrap(), old_png, "out.png clobbered by {run}");
        assert_eq!(std::fs::read(dir.path().join("out.ply")).unwrap(), old_ply, "out.ply clobbered by {run}");
        assert_eq!(std::fs::read(dir.path().join("s.json")).unwrap(), old_json, "s.json clobbered by {run}");
    }
    assert_dir_contains_exactly(dir.path(), &["empty.ply", "garbage.ply", "out.png", "out.ply", "s.json"]);
}

#[track_caller]
fn assert_output_failure(run: &Run, file: &str) {
    run.assert_failure(3);
    run.assert_stderr_contains(file);
    run.assert_stderr_contains("error");
}

#[test]
fn unwritable_outputs_fail_without_leftovers() {
    let dir = temp_dir();
    write_sphere(dir.path());
    std::fs::create_dir(dir.path().join("adir.png")).unwrap();
    // -o names an existing directory, or a file in a directory that does not exist.
    for out in ["adir.png", "nodir/out.png"] {
        let run = render_in(dir.path(), &["sphere.ply", "-o", out]);
        assert_output_failure(&run, out);
        let run = run_in(dir.path(), &["-q", "prepare", "sphere.ply", "-o", out]);
        assert_output_failure(&run, out);
    }
    assert_dir_contains_exactly(dir.path(), &["adir.png", "sphere.ply"]);
    assert_dir_contains_exactly(&dir.path().join("adir.png"), &[]);
}

#[test]
fn failed_stats_write_keeps_the_existing_png() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let old = b"precious".to_vec();
    write_file(dir.path(), "out.png", &old);
    let run = render_in(dir.path(), &["sphere.ply", "-o", "out.png", "--stats", "nodir/s.json"]);
    assert_output_failure(&run, "nodir/s.json");
    assert_eq!(std::fs::read(dir.path().join("out.png")).unwrap(), old, "the failed run replaced out.png");
}

// ---------------------------------------------------------------------------------------------
// 9. A closed pipe on stdout
// ---------------------------------------------------------------------------------------------

#[test]
fn info_into_a_closed_pipe_exits_successfully() {
    let dir = temp_dir();
    // 20000 comment lines: ~900 kB of output, far more than a pipe buffer holds.
    write_file(dir.path(), "big.ply", ascii_ply(&sphere_points(10), 20_000));
    let mut child = pointray()
        .args(["info", "big.ply"])
        .current_dir(dir.path())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    stdout.read_line(&mut first).unwrap();
    assert_eq!(first.trim_end(), "file:        big.ply");
    drop(stdout); // like `| head -1`
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = child.wait().unwrap();
    assert!(status.success(), "status {status}, stderr: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(!stderr.contains("error"), "a closed pipe is not an error: {stderr}");

    // And the full output really is long: one line per comment.
    let run = run_in(dir.path(), &["info", "big.ply"]);
    run.assert_success();
    assert_eq!(run.stdout.lines().filter(|l| l.starts_with("comment:")).count(), 20_000);
    assert!(run.stdout.contains("comment:     synthetic test comment number 19999"));
    run.assert_stdout_contains("points:      10");
}

// ---------------------------------------------------------------------------------------------
// 10. Atomic outputs
// ---------------------------------------------------------------------------------------------

#[test]
fn successful_runs_leave_only_their_outputs() {
    let dir = temp_dir();
    write_sphere(dir.path());
    std::fs::create_dir(dir.path().join("sub")).unwrap();
    render_in(dir.path(), &["sphere.ply", "-o", "sub/a.png", "--stats", "sub/a.json"]).assert_success();
    run_in(dir.path(), &["-q", "prepare", "sphere.ply", "-o", "sub/a.ply"]).assert_success();
    // Overwriting existing outputs is fine and also leaves nothing behind.
    render_in(dir.path(), &["sub/a.ply", "-o", "sub/a.png", "--stats", "sub/a.json", "--spp", "2"]).assert_success();
    assert_dir_contains_exactly(dir.path(), &["sphere.ply", "sub"]);
    assert_dir_contains_exactly(&dir.path().join("sub"), &["a.json", "a.ply", "a.png"]);
    let image = read_png(&dir.path().join("sub/a.png"));
    assert_eq!((image.width, image.height), (W, H));
    assert_eq!(read_stats(&dir.path().join("sub/a.json"))["samples_per_pixel"], 2);

    // Outputs get ordinary permissions (not the 0600 of a temporary file).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(dir.path().join("sub/a.png")).unwrap().permissions().mode();
        assert_ne!(mode & 0o044, 0, "out.png is readable only by its owner: {mode:o}");
    }
}

#[test]
fn render_reports_on_stderr_unless_quiet() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let run = run_in(dir.path(), &["render", "sphere.ply", "-o", "a.png", "--width", "48", "--height", "40"]);
    run.assert_success().assert_stderr_contains("3000 points").assert_stderr_contains("a.png");
    assert!(run.stdout.is_empty(), "{run}");
    let run = run_in(dir.path(), &["-q", "render", "sphere.ply", "-o", "b.png", "--width", "48", "--height", "40"]);
    run.assert_success();
    assert!(run.stderr.is_empty() && run.stdout.is_empty(), "-q prints nothing: {run}");
    assert!(read_png(&dir.path().join("a.png")) == read_png(&dir.path().join("b.png")));
}

/// `--eye`/`--look-at` are in the file's coordinates, even when the cloud lies far from the
/// origin (it is stored relative to its centre): an explicit camera at the orbit camera's
/// position gives the orbit camera's image.
#[test]
fn eye_and_look_at_are_in_file_coordinates_far_from_the_origin() {
    let dir = temp_dir();
    let offset = [636_000.0f64, 849_000.0, 400.0];
    let world: Vec<[f64; 3]> =
        sphere_points(3000).iter().map(|p| std::array::from_fn(|k| offset[k] + f64::from(p[k]))).collect();
    let text: String = world.iter().map(|p| format!("{:.6} {:.6} {:.6}\n", p[0], p[1], p[2])).collect();
    write_file(dir.path(), "far.xyz", text);
    let (lo, hi) = world.iter().fold(([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]), |(lo, hi), p| {
        (std::array::from_fn(|k| lo[k].min(p[k])), std::array::from_fn(|k| hi[k].max(p[k])))
    });
    let centre: [f64; 3] = std::array::from_fn(|k| (lo[k] + hi[k]) / 2.0);
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let view = [0.4f64, 0.3, 1.0];
    let norm = view.iter().map(|v| v * v).sum::<f64>().sqrt();
    let eye: [f64; 3] = std::array::from_fn(|k| centre[k] + view[k] / norm * diagonal);
    let csv = |p: [f64; 3]| format!("{},{},{}", p[0], p[1], p[2]);
    render_in(dir.path(), &["far.xyz", "-o", "orbit.png", "--distance", "1", "--no-shadows"]).assert_success();
    render_in(dir.path(), &["far.xyz", "-o", "eye.png", "--eye", &csv(eye), "--look-at", &csv(centre), "--no-shadows"])
        .assert_success();
    let (a, b) = (read_png(&dir.path().join("orbit.png")), read_png(&dir.path().join("eye.png")));
    let bg = background_srgb8();
    let covered = a.rgb.chunks(3).filter(|p| *p != bg).count();
    assert!(covered > 100, "the orbit view must show the sphere ({covered} pixels)");
    let differ =
        a.rgb.chunks(3).zip(b.rgb.chunks(3)).filter(|(p, q)| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > 8)).count();
    assert!(differ * 50 < covered, "{differ} of {covered} pixels differ");
}

// ---------------------------------------------------------------------------------------------
// 11. compare
// ---------------------------------------------------------------------------------------------

/// Writes a `width`×`height` PNG whose every channel value is `value`.
fn write_flat_png(dir: &std::path::Path, name: &str, width: u32, height: u32, value: u8) {
    pointray_io::write_png(&dir.join(name), width, height, &vec![value; (width * height * 3) as usize]).unwrap();
}

#[test]
fn compare_identical_and_different_images() {
    let dir = temp_dir();
    write_flat_png(dir.path(), "a.png", 8, 4, 100);
    write_flat_png(dir.path(), "b.png", 8, 4, 100);
    write_flat_png(dir.path(), "c.png", 8, 4, 101);

    let run = run_in(dir.path(), &["compare", "a.png", "b.png"]);
    run.assert_success();
    assert_eq!(run.stdout, "PSNR inf dB, RMSE 0.0000, max diff 0, 0 of 32 pixels differ, mean FLIP 0.0000\n", "{run}");
    let run = run_in(dir.path(), &["compare", "a.png", "b.png", "--json"]);
    run.assert_success();
    let json: serde_json::Value = serde_json::from_str(&run.stdout).unwrap_or_else(|e| panic!("{e}: {run}"));
    assert_eq!(
        json,
        serde_json::json!({"psnr_db": null, "rmse": 0.0, "max_abs_diff": 0, "differing_pixels": 0, "pixels": 32, "flip_mean": 0.0})
    );

    // Every channel off by one: PSNR 20·log10(255).
    let run = run_in(dir.path(), &["compare", "a.png", "c.png"]);
    run.assert_success();
    assert!(
        run.stdout.starts_with("PSNR 48.13 dB, RMSE 0.0039, max diff 1, 32 of 32 pixels differ, mean FLIP 0.0"),
        "{run}"
    );
    let run = run_in(dir.path(), &["compare", "c.png", "a.png", "--json"]);
    run.assert_success();
    let json: serde_json::Value = serde_json::from_str(&run.stdout).unwrap_or_else(|e| panic!("{e}: {run}"));
    assert!((stat_f64(&json, "psnr_db") - 48.1308).abs() < 1e-4, "{json}");
    assert_eq!(stat_u64(&json, "differing_pixels"), 32);
    // A step of one level in 255 is all but invisible (FLIP measured 0.031 on this 8 × 4 image).
    let flip = stat_f64(&json, "flip_mean");
    assert!(flip > 0.0 && flip < 0.05, "{json}");
    assert_dir_contains_exactly(dir.path(), &["a.png", "b.png", "c.png"]);
}

/// `--speckles`: a lone dark pixel on a lit patch is one in the first image; the second has it
/// too, or not, and where not, shows a trace of it or none; a mask of another size is refused,
/// naming it.
#[test]
fn compare_counts_the_first_images_speckles() {
    let dir = temp_dir();
    let mut speckled = vec![200u8; 6 * 5 * 3];
    speckled[(2 * 6 + 2) * 3..][..3].fill(40);
    pointray_io::write_png(&dir.path().join("a.png"), 6, 5, &speckled).unwrap();
    write_flat_png(dir.path(), "smooth.png", 6, 5, 200);
    write_flat_png(dir.path(), "mask.png", 6, 5, 255);
    write_flat_png(dir.path(), "small.png", 5, 5, 255);
    let count = |b: &str| {
        let run = run_in(dir.path(), &["compare", "a.png", b, "--speckles", "mask.png", "--json"]);
        run.assert_success();
        let json: serde_json::Value = serde_json::from_str(&run.stdout).unwrap_or_else(|e| panic!("{e}: {run}"));
        let s = &json["speckles"];
        ["first", "not_in_second", "without_trace_in_second"].map(|k| s[k].as_u64().unwrap())
    };
    assert_eq!(count("smooth.png"), [1, 1, 1]);
    assert_eq!(count("a.png"), [1, 0, 0]);
    // A second image with a trace of the dot, too faint to be a speckle itself: 3.5 % of its
    // depth in linear light is a trace, 2.3 % none (`metrics::SPECKLE_TRACE`, 1/32).
    for (level, traces) in [(197u8, 0), (198, 1)] {
        let mut faint = vec![200u8; 6 * 5 * 3];
        faint[(2 * 6 + 2) * 3..][..3].fill(level);
        pointray_io::write_png(&dir.path().join("faint.png"), 6, 5, &faint).unwrap();
        assert_eq!(count("faint.png"), [1, 1, traces], "{level}");
    }
    // Within a region: the speckle counts where it has its four neighbours there, and not
    // where the region cuts them off.
    let within = |region: &str| {
        let run = run_in(dir.path(), &["compare", "a.png", "smooth.png", "--speckles", "mask.png", "--region", region]);
        run.assert_success().assert_stdout_contains(" dark speckles in the first");
        run.stdout.clone()
    };
    assert!(within("1,1,4,4").contains("1 dark speckles in the first"));
    assert!(within("2,0,6,5").contains("0 dark speckles in the first"));
    run_in(dir.path(), &["compare", "a.png", "smooth.png", "--speckles", "mask.png"])
        .assert_success()
        .assert_stdout_contains("1 dark speckles in the first, 1 of them not in the second, 1 with no trace there");
    let run = run_in(dir.path(), &["compare", "a.png", "smooth.png", "--speckles", "small.png"]);
    run.assert_failure(1).assert_stderr_contains("small.png is 5x5");
    assert!(run.stdout.is_empty(), "{run}");
}

#[test]
fn compare_refuses_images_of_different_sizes() {
    let dir = temp_dir();
    write_flat_png(dir.path(), "wide.png", 8, 4, 0);
    write_flat_png(dir.path(), "tall.png", 4, 8, 0);
    let run = run_in(dir.path(), &["compare", "wide.png", "tall.png", "--json"]);
    run.assert_failure(1).assert_stderr_contains("wide.png is 8x4").assert_stderr_contains("tall.png is 4x8");
    assert!(run.stdout.is_empty(), "{run}");
}

#[test]
fn compare_missing_or_broken_files_are_named() {
    let dir = temp_dir();
    write_flat_png(dir.path(), "a.png", 8, 4, 0);
    let run = run_in(dir.path(), &["compare", "a.png", "missing.png"]);
    run.assert_failure(1).assert_stderr_contains("pointray: error: missing.png");
    let run = run_in(dir.path(), &["compare", "missing.png", "a.png"]);
    run.assert_failure(1).assert_stderr_contains("pointray: error: missing.png");
    let bytes = std::fs::read(dir.path().join("a.png")).unwrap();
    write_file(dir.path(), "cut.png", &bytes[..bytes.len() - 20]);
    let run = run_in(dir.path(), &["compare", "cut.png", "a.png"]);
    run.assert_failure(1).assert_stderr_contains("cut.png");
    assert!(run.stdout.is_empty(), "{run}");
}

// ---------------------------------------------------------------------------------------------
// 12. Level of detail, culling, bounding volumes, --aov nodes
// ---------------------------------------------------------------------------------------------

/// Renders the demo (a few pixels per feature at this frame size) with `extra` flags; returns
/// the stats.
fn render_demo_small(dir: &std::path::Path, out: &str, extra: &[&str]) -> serde_json::Value {
    let stats = format!("{out}.json");
    let args = [&["-o", out, "--demo-points", "40000", "--distance", "2", "--stats", &stats][..], extra].concat();
    render_in(dir, &args).assert_success();
    read_stats(&dir.join(stats))
}

#[test]
fn level_of_detail_saves_work_far_away_and_costs_little_image() {
    let dir = temp_dir();
    let full = render_demo_small(dir.path(), "full.png", &["--lod", "off"]);
    let coarse = render_demo_small(dir.path(), "coarse.png", &["--lod-threshold", "1"]);
    assert!(full["lod_threshold"].is_null() && stat_f64(&coarse, "lod_threshold") == 1.0);
    assert_eq!(stat_f64(&full, "lod_stops_per_ray"), 0.0);
    assert!(stat_f64(&coarse, "lod_stops_per_ray") > 0.1, "{coarse:#}");
    let (a, b) = (stat_f64(&full, "splat_tests_per_ray"), stat_f64(&coarse, "splat_tests_per_ray"));
    assert!(b < 0.5 * a, "splat tests per ray: {a} without, {b} with level of detail");
    assert!(stat_f64(&coarse, "nodes_visited_per_ray") < stat_f64(&full, "nodes_visited_per_ray"));
    // The same picture, smoothed: `compare` measures how far apart over the model's pixels.
    let r = &coarse["region"];
    let region = format!("{},{},{},{}", r["x0"], r["y0"], r["x1"], r["y1"]);
    let run = run_in(dir.path(), &["compare", "full.png", "coarse.png", "--region", &region, "--json"]);
    run.assert_success();
    let diff: serde_json::Value = serde_json::from_str(&run.stdout).unwrap();
    let psnr = stat_f64(&diff, "psnr_db");
    assert!(psnr > 20.0 && stat_u64(&diff, "differing_pixels") > 0, "PSNR {psnr}: {diff}");
}

#[test]
fn culling_and_bounding_volumes_are_reported_and_change_no_full_detail_pixel() {
    let dir = temp_dir();
    let base = render_demo_small(dir.path(), "base.png", &["--lod", "off"]);
    assert_eq!(base["culling"]["mode"], "off", "culling is off by default");
    assert_eq!(base["culling"]["enabled"], false);
    assert_eq!(stat_f64(&base, "culled_per_ray"), 0.0);
    assert_eq!(stat_u64(&base, "sphere_nodes"), 0);
    let spheres =
        render_demo_small(dir.path(), "spheres.png", &["--lod", "off", "--cull", "off", "--sphere-from-level", "1"]);
    assert!(stat_u64(&spheres, "sphere_nodes") > 0 && stat_f64(&spheres, "sphere_tests_per_ray") > 0.0);
    let same = read_png(&dir.path().join("base.png")) == read_png(&dir.path().join("spheres.png"));
    assert!(same, "bounding spheres changed the image");
    // The demo's sphere and torus are closed, but its floor is an open sheet seen from above
    // only: auto decides from the rays around the model, and says why.
    let auto = render_demo_small(dir.path(), "auto.png", &["--lod", "off", "--cull", "auto"]);
    let fraction = stat_f64(&auto["culling"], "backfacing_fraction");
    assert_eq!(auto["culling"]["enabled"], fraction <= 0.01, "{auto:#}");
    let on = render_demo_small(dir.path(), "on.png", &["--lod", "off", "--cull", "on"]);
    assert_eq!(on["culling"]["enabled"], true);
    assert!(stat_f64(&on, "culled_per_ray") > 0.0, "{on:#}");
}

/// Normal, depth and albedo images: misses are grey, black and black; hits face the camera,
/// and depths spread from white (nearest) to a fifth (farthest).
#[test]
fn aov_normal_depth_and_albedo_describe_the_first_hits() {
    let dir = temp_dir();
    render_demo_small(dir.path(), "out.png", &["--aov", "normal,depth", "--aov", "albedo"]);
    let names = ["out.png", "out.normal.png", "out.depth.png", "out.albedo.png", "out.png.json"];
    assert_dir_contains_exactly(dir.path(), &names);
    let [normal, depth, albedo] =
        ["normal", "depth", "albedo"].map(|k| read_png(&dir.path().join(format!("out.{k}.png"))));
    // The demo's camera looks back along its view direction (0.35, 0.5, 1).
    let towards_camera = [0.35f32, 0.5, 1.0];
    let (mut hits, mut facing) = (0, 0);
    for ((x, y, n), (_, _, d)) in normal.pixels().zip(depth.pixels()) {
        if d == [0; 3] {
            assert_eq!(n, [128; 3], "a miss at ({x}, {y}) has no normal");
            assert_eq!(albedo.pixel(x, y), [0; 3], "a miss at ({x}, {y}) has no albedo");
            continue;
        }
        hits += 1;
        let decoded = n.map(|c| c as f32 / 255.0 * 2.0 - 1.0);
        facing += usize::from((0..3).map(|i| decoded[i] * towards_camera[i]).sum::<f32>() > 0.0);
    }
    assert!(hits > 50 && facing == hits, "{facing} of {hits} hit normals face the camera");
    // Depth: the nearest hit white, the farthest at a fifth, grey levels between.
    let levels: std::collections::BTreeSet<u8> = depth.pixels().map(|p| p.2[0]).filter(|&v| v > 0).collect();
    assert_eq!((levels.first(), levels.last()), (Some(&51), Some(&255)), "{levels:?}");
    assert!(levels.len() > 10, "{levels:?}");
}

/// `-o NAME.exr`: linear radiance as R, G, B (the same pixels the PNG encodes) and the AOVs
/// as layers, in one file.
#[test]
fn exr_output_holds_linear_radiance_and_the_aovs() {
    let dir = temp_dir();
    render_demo_small(dir.path(), "out.png", &[]);
    render_demo_small(dir.path(), "out.exr", &["--aov", "depth,normal,albedo,nodes"]);
    assert_dir_contains_exactly(dir.path(), &["out.png", "out.png.json", "out.exr", "out.exr.json"]);
    let image = exr::prelude::read_all_flat_layers_from_file(dir.path().join("out.exr")).unwrap();
    let layer = &image.layer_data[0];
    assert_eq!((layer.size.0, layer.size.1), (W as usize, H as usize));
    let channel = |name: &str| -> Vec<f32> {
        let c =
            layer.channel_data.list.iter().find(|c| c.name.to_string() == name).unwrap_or_else(|| panic!("no {name}"));
        c.sample_data.values_as_f32().collect()
    };
    let names: Vec<String> = layer.channel_data.list.iter().map(|c| c.name.to_string()).collect();
    assert_eq!(names.len(), 11, "{names:?}");
    // The PNG is the EXR's radiance, encoded to 8-bit sRGB.
    let png = read_png(&dir.path().join("out.png"));
    let (r, g, b) = (channel("R"), channel("G"), channel("B"));
    let encode = |v: f32| (pointray::color::linear_to_srgb(v) * 255.0 + 0.5) as u8;
    for (i, (x, y, p)) in png.pixels().enumerate() {
        assert_eq!(p, [encode(r[i]), encode(g[i]), encode(b[i])], "pixel ({x}, {y})");
    }
    // Depth is finite exactly where the normal is not zero.
    let (depth, nx) = (channel("depth.Z"), channel("normal.X"));
    let (ny, nz) = (channel("normal.Y"), channel("normal.Z"));
    for i in 0..depth.len() {
        let n = (nx[i] * nx[i] + ny[i] * ny[i] + nz[i] * nz[i]).sqrt();
        assert_eq!(depth[i].is_finite(), n > 0.0, "pixel {i}: depth {}, |n| {n}", depth[i]);
    }
    assert!(channel("nodes.Y").iter().any(|&v| v > 0.0));
}

#[test]
fn aov_nodes_writes_a_heat_map_beside_the_image() {
    let dir = temp_dir();
    let s = render_demo_small(dir.path(), "out.png", &["--aov", "nodes"]);
    assert_dir_contains_exactly(dir.path(), &["out.png", "out.nodes.png", "out.png.json"]);
    let heat = read_png(&dir.path().join("out.nodes.png"));
    assert_eq!((heat.width, heat.height), (W, H));
    let colours: std::collections::BTreeSet<[u8; 3]> = heat.pixels().map(|(_, _, p)| p).collect();
    assert!(colours.len() >= 3, "a heat map of a scene has several levels: {colours:?}");
    assert!(stat_u64(&s, "nodes_visited_max_per_pixel") > 0);
}

#[test]
fn compare_region_counts_only_its_pixels() {
    let dir = temp_dir();
    write_flat_png(dir.path(), "a.png", 8, 4, 100);
    let mut half = vec![100u8; 8 * 4 * 3];
    half[..4 * 3].fill(90); // the first four pixels of the top row differ
    pointray_io::write_png(&dir.path().join("b.png"), 8, 4, &half).unwrap();
    let run = run_in(dir.path(), &["compare", "a.png", "b.png", "--region", "0,0,2,1", "--json"]);
    run.assert_success();
    let json: serde_json::Value = serde_json::from_str(&run.stdout).unwrap();
    assert_eq!((stat_u64(&json, "pixels"), stat_u64(&json, "differing_pixels")), (2, 2), "{json}");
    let run = run_in(dir.path(), &["compare", "a.png", "b.png", "--region", "4,0,8,4"]);
    run.assert_success().assert_stdout_contains("PSNR inf");
    run_in(dir.path(), &["compare", "a.png", "b.png", "--region", "0,0,9,4"])
        .assert_failure(2)
        .assert_stderr_contains("outside");
}

/// `--transparent`: an RGBA PNG whose alpha is the coverage; covered pixels keep the opaque
/// image's colours, uncovered ones are clear, and a partly covered edge is the model's colour
/// (the background's share taken out), not darkened by it.
#[test]
fn transparent_pngs_carry_the_coverage_as_alpha() {
    let dir = temp_dir();
    write_sphere(dir.path());
    render_in(dir.path(), &["sphere.ply", "-o", "opaque.png", "--spp", "4"]).assert_success();
    render_in(dir.path(), &["sphere.ply", "-o", "clear.png", "--spp", "4", "--transparent"]).assert_success();
    assert_dir_contains_exactly(dir.path(), &["sphere.ply", "opaque.png", "clear.png"]);
    let opaque = read_png(&dir.path().join("opaque.png"));
    let bytes = std::fs::read(dir.path().join("clear.png")).unwrap();
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap();
    let mut rgba = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut rgba).unwrap();
    assert_eq!((info.color_type, info.width, info.height), (png::ColorType::Rgba, opaque.width, opaque.height));
    let (mut covered, mut clear, mut edge) = (0, 0, 0);
    for (i, px) in rgba.chunks_exact(4).enumerate() {
        let plain = &opaque.rgb[i * 3..i * 3 + 3];
        match px[3] {
            255 => {
                assert_eq!(&px[..3], plain, "a covered pixel keeps its colour");
                covered += 1;
            }
            0 => {
                assert_eq!(&px[..3], [0, 0, 0]);
                clear += 1;
            }
            _ => {
                // The opaque edge mixes in the dark background: the clear one is brighter.
                assert!(px[..3].iter().zip(plain).all(|(c, o)| c >= o), "{px:?} vs {plain:?}");
                edge += 1;
            }
        }
    }
    assert!(covered > 200 && clear > 200 && edge > 10, "{covered} {clear} {edge}");
}

/// `--env-map`: a panorama read from a Radiance `.hdr` shows behind the model (a uniform one
/// exactly its radiance), the same map from OpenEXR gives the same image, and a missing or
/// damaged map fails before any work, naming the file; with `--sky` it is refused.
#[test]
fn an_environment_map_shows_behind_the_model_and_lights_it() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let (w, h) = (16, 8);
    // Radiance 0.5 (sRGB 188), brighter towards the top rows.
    let texels: Vec<[f32; 3]> = (0..w * h).map(|i| [0.5 + 0.25 * ((h - 1 - i / w) as f32); 3]).collect();
    write_file(dir.path(), "sky.hdr", pointray_io::env_map::encode_rgbe(w, h, &texels));
    let flat = vec![[0.5f32; 3]; w * h];
    write_file(dir.path(), "grey.hdr", pointray_io::env_map::encode_rgbe(w, h, &flat));
    let channel = |k: usize| texels.iter().map(|t| t[k]).collect::<Vec<f32>>();
    let channels = vec![("R".to_string(), channel(0)), ("G".to_string(), channel(1)), ("B".to_string(), channel(2))];
    pointray_io::write_exr(&dir.path().join("sky.exr"), w as u32, h as u32, channels).unwrap();
    render_in(dir.path(), &["sphere.ply", "-o", "grey.png", "--env-map", "grey.hdr"]).assert_success();
    assert_eq!(read_png(&dir.path().join("grey.png")).pixels().next().unwrap().2, [188; 3]);
    render_in(dir.path(), &["sphere.ply", "-o", "hdr.png", "--env-map", "sky.hdr", "--integrator", "path"])
        .assert_success();
    render_in(dir.path(), &["sphere.ply", "-o", "exr.png", "--env-map", "sky.exr", "--integrator", "path"])
        .assert_success();
    let (hdr, exr) = (read_png(&dir.path().join("hdr.png")), read_png(&dir.path().join("exr.png")));
    assert_eq!(hdr.rgb, exr.rgb, "the 8-bit mantissas of sky.hdr hold these values exactly");
    assert_ne!(hdr.rgb, read_png(&dir.path().join("grey.png")).rgb);
    render_in(dir.path(), &["sphere.ply", "-o", "x.png", "--env-map", "missing.hdr"])
        .assert_failure(1)
        .assert_stderr_contains("missing.hdr");
    let bytes = std::fs::read(dir.path().join("sky.hdr")).unwrap();
    write_file(dir.path(), "cut.hdr", &bytes[..bytes.len() - 10]);
    render_in(dir.path(), &["sphere.ply", "-o", "x.png", "--env-map", "cut.hdr"])
        .assert_failure(1)
        .assert_stderr_contains("cut.hdr: byte");
    render_in(dir.path(), &["sphere.ply", "-o", "x.png", "--env-map", "sky.hdr", "--sky"])
        .assert_failure(2)
        .assert_stderr_contains("--env-map and sky");
    assert!(!dir.path().join("x.png").exists());
}

/// `pointray view`: the page is served, a WebSocket gets the hello (the camera in the file's
/// coordinates), then frames as PNGs that refine; a camera sent back starts a new view with a
/// preview, and a bad option is answered with an error while the view goes on. A second page
/// gets frames too.
#[test]
fn the_viewer_serves_its_page_and_refines_the_view_a_page_sends() {
    use std::net::TcpStream;
    use tungstenite::Message;
    let dir = temp_dir();
    write_sphere(dir.path());
    /// The server, stopped however the test ends (a failed assertion too).
    struct Server(std::process::Child);
    impl Drop for Server {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let mut server = Server(
        pointray()
            .args(["-q", "view", "sphere.ply", "--port", "0", "--no-open", "--width", "64", "--height", "48"])
            .args(["--spp", "4"])
            .current_dir(dir.path())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    BufReader::new(server.0.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let address = line.trim().strip_prefix("pointray view: http://").unwrap().trim_end_matches('/').to_string();
    let mut page = String::new();
    let mut http = TcpStream::connect(&address).unwrap();
    std::io::Write::write_all(&mut http, b"GET / HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").unwrap();
    http.read_to_string(&mut page).unwrap();
    assert!(page.starts_with("HTTP/1.1 200") && page.contains("<canvas"), "{page}");
    // Reads give up after a while: a viewer that stops sending fails the test, not hangs it.
    let connect = |address: &str| {
        let (socket, _) = tungstenite::connect(format!("ws://{address}/ws")).unwrap();
        if let tungstenite::stream::MaybeTlsStream::Plain(tcp) = socket.get_ref() {
            tcp.set_read_timeout(Some(std::time::Duration::from_secs(60))).unwrap();
        }
        socket
    };
    let mut socket = connect(&address);
    let next_text = |socket: &mut tungstenite::WebSocket<_>| loop {
        match socket.read().unwrap() {
            Message::Text(t) => return serde_json::from_str::<serde_json::Value>(&t).unwrap(),
            Message::Binary(png) => assert!(png.starts_with(b"\x89PNG"), "frames are PNGs"),
            _ => {}
        }
    };
    let hello = next_text(&mut socket);
    assert_eq!((hello["kind"].as_str(), hello["width"].as_u64()), (Some("hello"), Some(64)));
    // Frames until the view has its four samples a pixel.
    while next_text(&mut socket)["samples"].as_u64() != Some(4) {}
    let eye: Vec<f64> = hello["eye"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() * 1.5).collect();
    let view = serde_json::json!({ "eye": eye, "look_at": hello["look_at"], "fov": 30.0 });
    socket.send(Message::Text(view.to_string().into())).unwrap();
    let first = next_text(&mut socket);
    assert_eq!((first["generation"].as_u64(), first["samples"].as_u64()), (Some(1), Some(1)), "{first}");
    assert!(first["nodes_per_ray"].as_f64().unwrap() > 0.0, "the work is counted: {first}");
    // The heat map of the nodes visited: the view renders again.
    socket.send(Message::Text(r#"{"heat_map": true}"#.into())).unwrap();
    while next_text(&mut socket)["generation"].as_u64() != Some(2) {}
    socket.send(Message::Text(r#"{"spp": 0}"#.into())).unwrap();
    let mut error = next_text(&mut socket);
    while error["kind"] != "error" {
        error = next_text(&mut socket);
    }
    assert!(error["message"].as_str().unwrap().contains("spp"), "{error}");
    // What the colours show is built into the scene: asked for, the scene is built anew; one the
    // cloud cannot give (it has no intensity) is refused, and the view goes on.
    socket.send(Message::Text(r#"{"color_by": "normal"}"#.into())).unwrap();
    let mut built = next_text(&mut socket);
    while built["kind"] != "frame" || built["generation"].as_u64() < Some(3) {
        assert_ne!(built["kind"], "error", "{built}");
        built = next_text(&mut socket);
    }
    socket.send(Message::Text(r#"{"color_by": "intensity"}"#.into())).unwrap();
    let mut refused = next_text(&mut socket);
    while refused["kind"] != "error" {
        refused = next_text(&mut socket);
    }
    assert!(refused["message"].as_str().unwrap().contains("intensity"), "{refused}");
    let mut shown = next_text(&mut socket);
    while shown["kind"] != "frame" {
        shown = next_text(&mut socket);
    }
    // A view the viewer cannot show (cropped) is refused, and the next message merges into the
    // view kept, not into the refused one: a newer view's frames come.
    socket.send(Message::Text(r#"{"crop_to_model": true}"#.into())).unwrap();
    let mut cropped = next_text(&mut socket);
    while cropped["kind"] != "error" {
        cropped = next_text(&mut socket);
    }
    assert!(cropped["message"].as_str().unwrap().contains("crop_to_model"), "{cropped}");
    socket.send(Message::Text(r#"{"fov": 40.0}"#.into())).unwrap();
    let kept = shown["generation"].as_u64();
    while next_text(&mut socket)["generation"].as_u64() <= kept {}
    // A double-click's pick: the sphere's surface under the centre becomes the pivot, the eye
    // stays (the sphere of `write_sphere` has radius 1 about the origin).
    socket.send(Message::Text(r#"{"pick": [32, 24]}"#.into())).unwrap();
    let mut pivot = next_text(&mut socket);
    while pivot["kind"] != "pivot" {
        pivot = next_text(&mut socket);
    }
    let at: Vec<f64> = pivot["look_at"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let radius = at.iter().map(|v| v * v).sum::<f64>().sqrt();
    assert!((radius - 1.0).abs() < 0.05, "{pivot}");
    assert_eq!(pivot["eye"].as_array().unwrap().len(), 3);
    let mut second = connect(&address);
    assert_eq!(next_text(&mut second)["kind"], "hello");
    assert_eq!(next_text(&mut second)["kind"], "frame");
    // A file that fails to load fails as `render` does, before any server.
    run_in(dir.path(), &["-q", "view", "missing.ply", "--no-open", "--port", "0"])
        .assert_failure(1)
        .assert_stderr_contains("missing.ply");
}
