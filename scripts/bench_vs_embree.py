#!/usr/bin/env python3
"""pointray beside Embree's oriented-disc points, back to back on the same file and camera.

Usage: scripts/bench_vs_embree.py MODEL.ply [--dist 1,4,16] [--threads 2] [--reps 10] [--size 1024]
                                  [--surface first-hit] [--spp 1] [--tau T] [--rounds 1]
                                  [--integrator eye-light] [--pointray BIN]

The model is first run through `pointray prepare`, so both renderers see the same normals and
radii. For each distance it runs one pointray benchmark (`--surface SURFACE --no-shadows
--crop-to-model --bench-frames REPS --integrator eye-light`: primary rays only, shaded |N.D| as
Embree's bench shades them, so that the ratio measures the ray query; `--integrator whitted` gives
the Phong shading of the figures before 2026-11-25's third session) and then
Embree's bench (`--geom oriented --crop --reps REPS`), and prints a Markdown table of median
frame times (ten times as many frames for k ≥ 2, whose crops hold few rays) and the median of
three builds each (Embree's bench's default `--build-reps`; a process's first build pays for its
fresh memory). With `--spp N` both
trace N rays a pixel; `--tau T` sets the level-of-detail threshold at one ray a pixel (pointray
gets T·√N, since each of N samples' footprints is 1/√N of the pixel: the same work a ray),
and without it pointray runs with `--lod off`. `--rounds R` repeats every measurement R times,
pointray and Embree alternating, and reports the median. Needs `cargo build --release` and
../shared/bench/embree built (see its README).
"""
import argparse, json, os, subprocess, sys, tempfile

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.dirname(here)
pointray = os.path.join(root, "target", "release", "pointray")
embree = os.path.join(root, "..", "shared", "bench", "embree", "bin", "embree_points_bench")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("--dist", default="1,4,16")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--surface", default="first-hit")
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--tau", type=float)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--integrator", default="eye-light")
    ap.add_argument("--pointray", default=pointray)
    a = ap.parse_args()
    pointray_bin = a.pointray
    for exe in (pointray_bin, embree):
        if not os.path.exists(exe):
            sys.exit(f"missing {exe}")
    tmp = tempfile.mkdtemp()
    prepared = os.path.join(tmp, "prepared.ply")
    subprocess.run([pointray_bin, "-q", "prepare", a.model, "-o", prepared], check=True)
    lod = ["--lod", "off"] if a.tau is None else ["--lod-threshold", str(a.tau * a.spp ** 0.5)]
    print(f"model {os.path.basename(a.model)}, {a.size}x{a.size}, {a.threads} threads, crop, surface {a.surface}, integrator {a.integrator}, "
          f"{a.spp} rays a pixel, {' '.join(lod)}, median of {a.reps} frames ({10 * a.reps} for k >= 2), "
          f"median of {a.rounds} rounds\n")
    print("| k | rays | pointray build s | Embree build s | pointray Mrays/s | Embree Mrays/s | ratio | nodes/ray | splat tests/ray | pointray B/splat | Embree BVH MB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for k in a.dist.split(","):
        # Small crops hold few rays and frames of a millisecond: time more of them.
        reps = a.reps if float(k) < 2 else a.reps * 10
        stats = os.path.join(tmp, "s.json")
        ps, es = [], []
        for _ in range(a.rounds):
            subprocess.run([pointray_bin, "-q", "render", prepared, "-o", os.path.join(tmp, "p.png"), "--distance", k,
                            "--crop-to-model", "--surface", a.surface, "--no-shadows", "--threads", str(a.threads),
                            "--width", str(a.size), "--height", str(a.size), "--bench-frames", str(reps),
                            "--spp", str(a.spp), "--integrator", a.integrator, *lod, "--bench-builds", "3",
                            "--stats", stats], check=True)
            ps.append(json.load(open(stats)))
            out = subprocess.run([embree, prepared, "--geom", "oriented", "--threads", str(a.threads), "--dist", k,
                                  "--crop", "--reps", str(reps), "--size", f"{a.size}x{a.size}", "--spp", str(a.spp)],
                                 check=True, capture_output=True, text=True).stdout
            es.append(json.loads(out.strip().splitlines()[-1]))
        p = sorted(ps, key=lambda r: r["mrays_per_second"])[len(ps) // 2]
        e = sorted(es, key=lambda r: r["mrays_s"])[len(es) // 2]
        if e["rays"] != p["primary_rays"]:
            print(f"warning: k={k}: Embree traced {e['rays']} rays, pointray {p['primary_rays']}", file=sys.stderr)
        ratio = p["mrays_per_second"] / e["mrays_s"]
        print(f"| {k} | {p['primary_rays']} | {p['build_seconds']:.3f} | {e['build_s']:.3f} | {p['mrays_per_second']:.2f} | "
              f"{e['mrays_s']:.2f} | {ratio:.2f} | {p['nodes_visited_per_ray']:.1f} | {p['splat_tests_per_ray']:.1f} | "
              f"{p['bytes_per_splat']:.1f} | {e['bvh_mb']:.1f} |")


if __name__ == "__main__":
    main()
