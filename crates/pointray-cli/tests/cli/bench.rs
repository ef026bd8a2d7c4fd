//! `pointray bench`: an experiment's matrix measured end to end on the sphere test cloud.

use super::support::*;

const EXPERIMENT: &str = r#"
title = "sphere"
width = 96
height = 96
repeats = 2
min_seconds = 0
reference = "pss"

[[model]]
name = "sphere"
file = "sphere.ply"

[[matrix]]
accel = ["bvh", "kdtree"]
surface = ["sj"]
lod_threshold = [0, 2]
distance = [1, 4]

[[matrix]]
accel = ["bvh-spheres", "bvh"]
surface = ["rfd"]
lod_threshold = [0]
distance = [1]
"#;

fn lines(path: &std::path::Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

#[test]
fn bench_measures_every_point_and_compares_each_image_with_full_detail() {
    let dir = temp_dir();
    write_sphere(dir.path());
    write_file(dir.path(), "e.toml", EXPERIMENT);
    let dry = run_in(dir.path(), &["bench", "e.toml", "--dry-run"]);
    dry.assert_success().assert_stdout_contains("10 points");
    run_in(dir.path(), &["-q", "bench", "e.toml", "--out", "out", "--report", "doc/RESULTS.md"]).assert_success();

    let records = lines(&dir.path().join("out/results.jsonl"));
    let header = &records[0];
    assert_eq!((header["kind"].as_str(), header["title"].as_str()), (Some("header"), Some("sphere")));
    assert!(
        header["machine"]["cores"].as_u64().unwrap() >= 1 && header["machine"]["date"].as_str().unwrap().len() == 16
    );
    assert_eq!(records[1]["kind"], "model");
    assert_eq!(records[1]["points"], 3000);
    let points: Vec<&serde_json::Value> = records.iter().filter(|r| r["kind"] == "point").collect();
    assert_eq!(points.len(), 10);
    let find = |accel: &str, lod: f64, distance: f64| {
        points
            .iter()
            .find(|p| {
                p["accel"] == accel && p["surface"] == "sj" && p["lod_threshold"] == lod && p["distance"] == distance
            })
            .unwrap_or_else(|| panic!("no {accel} {lod} {distance}"))
    };
    for p in &points {
        // Primary rays only, one per traced pixel; every frame timed.
        assert_eq!(p["rays"], p["pixels"], "{p}");
        assert!(p["render_seconds"].as_f64().unwrap() > 0.0 && p["frames"].as_u64().unwrap() >= 2, "{p}");
        assert!(p["render_seconds_min"].as_f64() <= p["render_seconds"].as_f64(), "{p}");
        // The sphere seen through PSS is smooth; SJ at full detail differs from it a little,
        // RFD more (its silhouette is thicker by up to a radius). Measured: 47.1–49.5 dB and 16.6 dB.
        if p["lod_threshold"] == 0.0 {
            let least = if p["surface"] == "sj" { 40.0 } else { 14.0 };
            let reference = p["psnr_reference_db"].as_f64().unwrap();
            assert!(reference > least && p["flip_reference"].as_f64().unwrap() > 0.0, "{p}");
        }
    }
    // At full detail every accelerator draws the full-detail image exactly.
    for accel in ["bvh", "kdtree"] {
        for distance in [1.0, 4.0] {
            let p = find(accel, 0.0, distance);
            assert!(p["psnr_db"].is_null() && p["differing_pixels"] == 0 && p["flip"] == 0.0, "{p}");
        }
    }
    // Far away, level of detail stops early and changes a few pixels, not many.
    for accel in ["bvh", "kdtree"] {
        let (near, far) = (find(accel, 0.0, 4.0), find(accel, 2.0, 4.0));
        assert!(far["lod_stops_per_ray"].as_f64().unwrap() > 0.0, "{far}");
        // The splat tests fall (BVH tenfold, kd-tree threefold). The BVH's nodes do not: on
        // 19 × 19 pixels of 3,000 points the SJ windows of the wide representatives span more
        // nodes than the thin full-detail ones, 4.7 against 4.2 a ray.
        let splat_tests = |p: &serde_json::Value| p["splat_tests_per_ray"].as_f64().unwrap();
        assert!(splat_tests(far) * 2.0 < splat_tests(near), "{far} against {near}");
        let psnr = far["psnr_db"].as_f64().expect("the level of detail changed no pixel");
        assert!(psnr > 15.0 && far["flip"].as_f64().unwrap() > 0.0, "{far}");
    }
    // A distant model covers fewer pixels (the crop).
    assert!(find("bvh", 0.0, 4.0)["pixels"].as_u64() < find("bvh", 0.0, 1.0)["pixels"].as_u64());
    assert!(points.iter().any(|p| p["accel"] == "bvh-spheres" && p["surface"] == "rfd"));

    // The CSV holds the same points, one row each, and the images are written.
    let csv = std::fs::read_to_string(dir.path().join("out/results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 10);
    assert!(csv.lines().next().unwrap().starts_with("kind,model,points,accel,surface,lod_threshold,distance"));
    let image = points[0]["image"].as_str().unwrap();
    let png = read_png(&dir.path().join("out").join(image));
    assert_eq!(u64::from(png.width * png.height), points[0]["pixels"].as_u64().unwrap());
}

#[test]
fn the_report_shows_every_experiment_with_figures_and_keeps_its_discussion() {
    let dir = temp_dir();
    write_sphere(dir.path());
    write_file(dir.path(), "e.toml", EXPERIMENT);
    run_in(dir.path(), &["-q", "bench", "e.toml", "--out", "out", "--report", "doc/RESULTS.md"]).assert_success();
    let report = std::fs::read_to_string(dir.path().join("doc/RESULTS.md")).unwrap();
    for section in [
        "# Results: sphere",
        "this file was written by `pointray -q bench e.toml --out out --report doc/RESULTS.md`",
        "## Level of detail against distance: the BVH",
        "## Level of detail against distance: the SAH kd-tree",
        "## Percentage improvement from level of detail",
        "## Surface schemes",
        "## Images: full detail and level of detail",
        "| sphere | bvh | 2 |",
    ] {
        assert!(report.contains(section), "no {section:?} in\n{report}");
    }
    for figure in ["time_bvh_sphere", "work_bvh_sphere", "time_kdtree_sphere", "work_kdtree_sphere"] {
        assert!(report.contains(&format!("results/{figure}.svg")), "{figure} not linked");
        for ext in ["svg", "png"] {
            let path = dir.path().join("doc/results").join(format!("{figure}.{ext}"));
            assert!(std::fs::metadata(&path).is_ok_and(|m| m.len() > 1000), "{} missing", path.display());
        }
    }
    for image in ["sphere_bvh_sj_d1_t0.png", "sphere_bvh_sj_d1_t2.png"] {
        assert!(dir.path().join("doc/results/images").join(image).exists(), "{image}: {report}");
    }
    // Regenerated from the same run, the hand-written discussion stays.
    std::fs::write(dir.path().join("doc/RESULTS.md"), report.clone() + "\n## Discussion\n\nWritten by hand.\n")
        .unwrap();
    run_in(dir.path(), &["report", "out", "-o", "doc/RESULTS.md"]).assert_success();
    let again = std::fs::read_to_string(dir.path().join("doc/RESULTS.md")).unwrap();
    assert!(again.ends_with("## Discussion\n\nWritten by hand.\n"), "{again}");
    assert!(again.contains("this file was written by `pointray report out -o doc/RESULTS.md`"));
}

/// The quality experiments: more samples a pixel, and every image against the converged one.
const QUALITY: &str = r#"
title = "sphere quality"
width = 64
height = 64
repeats = 1
min_seconds = 0
converged_spp = 32

[[model]]
name = "sphere"
file = "sphere.ply"

[[matrix]]
accel = ["bvh"]
surface = ["sj"]
lod_threshold = [0]
spp = [1, 8]
distance = [2]

[[matrix]]
accel = ["bvh"]
surface = ["sj"]
lod_threshold = [2]
distance = [2]
"#;

#[test]
fn more_samples_come_closer_to_the_converged_image_and_the_report_sets_them_side_by_side() {
    let dir = temp_dir();
    write_sphere(dir.path());
    write_file(dir.path(), "q.toml", QUALITY);
    run_in(dir.path(), &["-q", "bench", "q.toml", "--out", "out", "--report", "doc/quality.md"]).assert_success();
    let records = lines(&dir.path().join("out/results.jsonl"));
    assert_eq!(records[0]["converged_spp"], 32);
    let points: Vec<&serde_json::Value> = records.iter().filter(|r| r["kind"] == "point").collect();
    assert_eq!(points.len(), 3);
    let find = |lod: f64, spp: u64| points.iter().find(|p| p["lod_threshold"] == lod && p["spp"] == spp).unwrap();
    let converged = |p: &serde_json::Value| p["psnr_converged_db"].as_f64().unwrap();
    let (one, eight, lod) = (find(0.0, 1), find(0.0, 8), find(2.0, 1));
    // Eight rays a pixel trace eight times the rays, and come closer to the converged image.
    assert_eq!(eight["rays"].as_u64().unwrap(), 8 * one["rays"].as_u64().unwrap());
    assert!(converged(eight) > converged(one) + 3.0, "{eight} against {one}");
    assert!(eight["flip_converged"].as_f64() < one["flip_converged"].as_f64());
    // Each is compared with full detail at its own samples a pixel too: itself.
    assert!(eight["psnr_db"].is_null() && lod["psnr_db"].is_number(), "{eight} {lod}");
    assert!(converged(lod) > 10.0, "{lod}");
    assert!(eight["image"].as_str().unwrap().ends_with("_d2_t0_spp8.png"));

    let report = std::fs::read_to_string(dir.path().join("doc/quality.md")).unwrap();
    for cell in [
        "## Quality against the converged image",
        "full detail at 32 samples a pixel",
        "| bvh sj, full detail, 1 spp | bvh sj, full detail, 8 spp | bvh sj, τ = 2, 1 spp |",
    ] {
        assert!(report.contains(cell), "no {cell:?} in\n{report}");
    }
    // The thesis's sections keep to one sample a pixel: the LoD table has full detail and τ = 2.
    assert!(report.contains("| full detail ms | τ = 2 ms |"), "{report}");
}

#[test]
fn bad_experiments_are_refused_with_the_file_and_the_problem() {
    let dir = temp_dir();
    write_sphere(dir.path());
    let cases = [
        ("accel.toml", EXPERIMENT.replace("\"kdtree\"", "\"octree\""), "unknown accelerator \"octree\""),
        ("model.toml", EXPERIMENT.replace("sphere.ply", "none.ply"), "none.ply"),
        ("key.toml", EXPERIMENT.replace("repeats", "repeat"), "unknown field `repeat`"),
    ];
    for (name, text, fragment) in &cases {
        write_file(dir.path(), name, text);
        let run = run_in(dir.path(), &["-q", "bench", name, "--out", "out"]);
        run.assert_failure(1).assert_stderr_contains(fragment);
        if *name != "model.toml" {
            run.assert_stderr_contains(name);
        }
    }
    run_in(dir.path(), &["bench", "accel.toml", "--models", "nothing"]).assert_failure(1);
    let run = run_in(dir.path(), &["-q", "bench", "key.toml"]);
    assert!(!dir.path().join("results").exists(), "{run}");
}

/// Answers like Embree's point bench: one JSON line for the `--dist` it is given, reporting
/// as many rays as the `--reps` it was asked for, so the test can see both arrive.
const FAKE_EMBREE: &str = r#"#!/bin/sh
dist=""; reps=""
while [ $# -gt 0 ]; do
  case "$1" in --dist) dist="$2"; shift;; --reps) reps="$2"; shift;; esac
  shift
done
echo "Embree 3.13.5 (fake)"
echo "{\"k\":$dist,\"mrays_s\":2.5,\"build_s\":0.125,\"rays\":$reps,\"embree_version\":\"3.13.5\"}"
"#;

#[cfg(unix)]
#[test]
fn embree_runs_beside_each_model_with_as_many_frames_as_full_detail() {
    use std::os::unix::fs::PermissionsExt;
    let dir = temp_dir();
    write_sphere(dir.path());
    let fake = write_file(dir.path(), "fake_embree.sh", FAKE_EMBREE);
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    write_file(
        dir.path(),
        "e.toml",
        format!("embree = \"fake_embree.sh\"\n{EXPERIMENT}\n[[matrix]]\naccel = [\"bvh-spheres\"]\nsurface = [\"sj\"]\nlod_threshold = [0]\ndistance = [1]\n")
            .replace("repeats = 2", "repeats = 3"),
    );
    run_in(dir.path(), &["-q", "bench", "e.toml", "--out", "out"]).assert_success();
    let records = lines(&dir.path().join("out/results.jsonl"));
    assert_eq!(records[0]["embree"], "fake_embree.sh");
    let points: Vec<&serde_json::Value> = records.iter().filter(|r| r["kind"] == "point").collect();
    for p in &points {
        let full = points
            .iter()
            .find(|f| {
                f["accel"] == "bvh"
                    && f["surface"] == p["surface"]
                    && f["distance"] == p["distance"]
                    && f["lod_threshold"] == 0.0
            })
            .unwrap();
        assert_eq!(p["embree_rays"], full["frames"], "{p}");
        assert_eq!(
            (p["embree_mrays_per_second"].as_f64(), p["embree_build_seconds"].as_f64()),
            (Some(2.5), Some(0.125))
        );
        let ratio = p["mrays_per_second"].as_f64().unwrap() / 2.5;
        assert!((p["speed_vs_embree"].as_f64().unwrap() - ratio).abs() < 1e-9, "{p}");
        assert!(p["embree_other_load_cores"].as_f64().is_some_and(|o| o >= 0.0), "{p}");
        assert_eq!(p["embree_version"], "3.13.5", "{p}");
    }
    // The report names the Embree it ran beside.
    run_in(dir.path(), &["report", "out", "-o", "r.md"]).assert_success();
    let report = std::fs::read_to_string(dir.path().join("r.md")).unwrap();
    assert!(report.contains("`fake_embree.sh` (Embree 3.13.5) traced the same pixels"), "{report}");
    assert!(report.contains("--out out --report r.md"), "{report}");
    assert!(report.contains("| Embree ms | speed vs Embree |"), "{report}");
    // Embree's row under the bounding volumes: its time at distance 1 and its build time.
    assert!(report.lines().any(|l| l.starts_with("| Embree |") && l.contains("| 0.125 |")), "{report}");
    // The cloud handed to Embree is gone; the partial results were renamed.
    let mut left: Vec<String> = std::fs::read_dir(dir.path().join("out"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["images", "results.csv", "results.jsonl"]);
    // A bench that fails stops the run, names itself, and leaves no results.
    write_file(dir.path(), "fake_embree.sh", "#!/bin/sh\necho broken >&2\nexit 3\n");
    let run = run_in(dir.path(), &["-q", "bench", "e.toml", "--out", "again"]);
    run.assert_failure(1).assert_stderr_contains("fake_embree.sh").assert_stderr_contains("broken");
    assert!(!dir.path().join("again/results.jsonl").exists() && !dir.path().join("again/results.csv").exists());
}

#[test]
fn the_camera_table_sets_every_model_s_view_unless_the_model_sets_its_own() {
    let dir = temp_dir();
    // An ellipsoid three times as long in x: seen along x or along z it covers different pixels.
    let long: Vec<[f32; 3]> = sphere_points(3000).into_iter().map(|[x, y, z]| [3.0 * x, y, z]).collect();
    write_file(dir.path(), "long.ply", ascii_ply(&long, 0));
    let experiment = |camera: &str, model: &str| {
        format!(
            "title = \"t\"\nwidth = 64\nheight = 64\nrepeats = 1\nmin_seconds = 0\n{camera}\n[[model]]\nname = \"long\"\nfile = \"long.ply\"\n{model}\n[[matrix]]\naccel = [\"bvh\"]\nsurface = [\"sj\"]\nlod_threshold = [0]\ndistance = [1]\n"
        )
    };
    let pixels = |name: &str, text: String| {
        write_file(dir.path(), name, text);
        let out = format!("{name}.out");
        run_in(dir.path(), &["-q", "bench", name, "--out", &out]).assert_success();
        lines(&dir.path().join(out).join("results.jsonl"))[2]["pixels"].as_u64().unwrap()
    };
    let end_on = pixels("x.toml", experiment("[camera]\nview_dir = [1.0, 0.0, 0.0]", ""));
    let side_on = pixels("z.toml", experiment("[camera]\nview_dir = [0.0, 0.0, 1.0]", ""));
    let model_own = pixels("m.toml", experiment("[camera]\nview_dir = [1.0, 0.0, 0.0]", "view_dir = [0.0, 0.0, 1.0]"));
    assert!(side_on > end_on, "side on {side_on} pixels, end on {end_on}");
    assert_eq!(model_own, side_on);
    // An unknown model in --models is an error, not a silent skip.
    run_in(dir.path(), &["-q", "bench", "x.toml", "--models", "long,lnog"])
        .assert_failure(2)
        .assert_stderr_contains("lnog");
}

#[test]
fn a_model_may_be_points_sampled_on_a_mesh() {
    let dir = temp_dir();
    write_file(dir.path(), "octahedron.ply", octahedron_ply());
    let experiment = "title = \"mesh\"\nwidth = 48\nheight = 48\nrepeats = 1\nmin_seconds = 0\n\
                      [[model]]\nname = \"octahedron\"\nmesh = \"octahedron.ply\"\npoints = 2000\n\
                      [[matrix]]\naccel = [\"bvh\"]\nsurface = [\"sj\"]\nlod_threshold = [0]\ndistance = [1]\n";
    write_file(dir.path(), "m.toml", experiment);
    run_in(dir.path(), &["-q", "bench", "m.toml", "--out", "out"]).assert_success();
    let records = lines(&dir.path().join("out/results.jsonl"));
    assert_eq!(records[1]["points"], 2000, "{}", records[1]);
    assert!(records[1]["source"].as_str().unwrap().ends_with("octahedron.ply (2000 points sampled)"));
    assert!(records[2]["hit_fraction"].as_f64().unwrap() > 0.2, "{}", records[2]);
}
