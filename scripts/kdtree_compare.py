#!/usr/bin/env python3
"""The kd-tree beside the multiresolution BVH and Embree (thesis ch. 4): writes docs/kdtree.md
and docs/kdtree-results.jsonl.

For each model and camera distance k (in bounding-box diagonals, cropped to the model), it
renders with both accelerators at full detail and at the level-of-detail thresholds, then runs
the Embree bench on the same prepared cloud right after. Each configuration runs once (one
round; `--bench-frames` frames, the median frame reported), so compare ratios within a model
and distance, not across the table. PSNR is over the crop region, against the same
accelerator's LoD-off image.

    python3 scripts/kdtree_compare.py --pointray target/release/pointray \
        [--embree ../shared/bench/embree/bin/embree_points_bench] [--models dragon,bunny]
"""

import array
import json
import math
import os
import random
import sys

import reportlib

MODELS = {
    "dragon": "stanford/dragon/dragon_vrip.vertices.binary_le.ply",
    "bunny": "stanford/bunny/reconstruction/bun_zipper.ply",
    "buddha": "stanford/happy/happy_vrip_res3.ply",
    "igea": "scans_other/igea.ply",
}
# Made by this script (no data files): points uniformly distributed over a torus, with exact
# normals; `pointray prepare` gives them radii as for a scan.
SYNTHETIC = {"torus-1m": 1_000_000}
ACCELS = ["bvh", "kdtree"]
LODS = ["off", 1, 2, 4]
DISTANCES = [1, 4, 16]


def main():
    a = reportlib.arguments(__doc__, "/tmp/pointray-kdtree", list(MODELS) + list(SYNTHETIC), 1024, "docs/kdtree.md",
                            lambda ap: ap.add_argument("--embree", default="../shared/bench/embree/bin/embree_points_bench"))
    jsonl = a.jsonl
    if a.report_only:
        write_markdown(a, *reportlib.read_jsonl(jsonl))
        return
    os.makedirs(a.cache, exist_ok=True)
    header = reportlib.header(models=a.models, size=a.size, threads=a.threads)
    records = []
    for model in a.models.split(","):
        ply = os.path.join(a.cache, model + ".ply")
        if model in SYNTHETIC:
            src = os.path.join(a.cache, model + "-raw.ply")
            if not os.path.exists(src):
                write_torus(src, SYNTHETIC[model])
        else:
            src = os.path.join(a.data, MODELS[model])
        if not os.path.exists(ply):
            reportlib.run([a.pointray, "-q", "prepare", src, "-o", ply + ".partial.ply"])
            os.replace(ply + ".partial.ply", ply)
        for k in DISTANCES:
            frames = None
            for accel in ACCELS:
                ref = None
                for lod in LODS:
                    png = os.path.join(a.cache, f"{model}_k{k}_{accel}_{lod}.png")
                    stats_path = png[:-4] + ".json"
                    lod_flags = ["--lod", "off"] if lod == "off" else ["--lod-threshold", lod]
                    cmd = [a.pointray, "-q", "render", ply, "-o", png, "--accel", accel, "--distance", k,
                           "--crop-to-model", "--threads", a.threads, "--width", a.size, "--height", a.size,
                           "--cull", "off", "--stats", stats_path] + lod_flags
                    if frames is None:  # size the timing by the rays of the first render
                        reportlib.run(cmd + ["--bench-frames", 0])
                        rays = json.load(open(stats_path))["rays"]
                        frames = max(5, math.ceil(3_000_000 / max(rays, 1)))
                    reportlib.run(cmd + ["--bench-frames", frames])
                    s = json.load(open(stats_path))
                    r = s["region"]
                    region = f"{r['x0']},{r['y0']},{r['x1']},{r['y1']}"
                    if lod == "off":
                        ref, psnr = png, None
                    else:
                        c = json.loads(reportlib.run([a.pointray, "-q", "compare", png, ref, "--region", region, "--json"]))
                        psnr = c["psnr_db"] if c["psnr_db"] is not None else "identical"
                    rec = {"model": model, "k": k, "accel": accel, "lod": lod, "frames": frames, "psnr_vs_off": psnr,
                           "stats": {x: s.get(x) for x in [
                               "points", "rays", "build_seconds", "bytes_per_splat", "nodes", "render_seconds",
                               "mrays_per_second", "nodes_visited_per_ray", "splat_tests_per_ray",
                               "lod_stops_per_ray", "hit_fraction"]}}
                    records.append(rec)
                    print(f"{model} k={k} {accel} lod={lod}: {s['render_seconds'] * 1e3:.3g} ms, "
                          f"{s['mrays_per_second']:.2f} Mrays/s, psnr {psnr}", file=sys.stderr)
            if a.embree and os.path.exists(a.embree):
                out = reportlib.run([a.embree, ply, "--geom", "oriented", "--threads", a.threads, "--dist", k, "--crop",
                           "--reps", frames, "--size", f"{a.size}x{a.size}"])
                e = json.loads(out.strip().splitlines()[-1])
                records.append({"model": model, "k": k, "accel": "embree", "lod": "off", "frames": frames,
                                "embree": {x: e.get(x) for x in ["mrays_s", "render_s", "build_s", "bvh_mb", "rays"]}})
                print(f"{model} k={k} embree: {e.get('mrays_s')} Mrays/s", file=sys.stderr)
    reportlib.write_jsonl(jsonl, header, records)
    write_markdown(a, header, records)


def write_torus(path, n, seed=1, major=1.0, minor=0.4):
    """n points uniformly distributed over a torus's surface (rejection sampling of the tube
    angle by the area element), with their outward normals, as a binary PLY."""
    rng = random.Random(seed)
    data = array.array("f")
    while len(data) < 6 * n:
        u, v = rng.uniform(0, 2 * math.pi), rng.uniform(0, 2 * math.pi)
        if rng.uniform(0, major + minor) > major + minor * math.cos(v):
            continue
        nx, ny, nz = math.cos(v) * math.cos(u), math.cos(v) * math.sin(u), math.sin(v)
        data.extend([major * math.cos(u) + minor * nx, major * math.sin(u) + minor * ny, minor * nz, nx, ny, nz])
    if sys.byteorder != "little":
        data.byteswap()
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n"
              + "".join(f"property float {p}\n" for p in ["x", "y", "z", "nx", "ny", "nz"]) + "end_header\n")
    with open(path + ".partial", "wb") as f:
        f.write(header.encode())
        data.tofile(f)
    os.replace(path + ".partial", path)


def write_markdown(a, header, records):
    h = header
    out = ["# The SAH kd-tree beside the multiresolution BVH and Embree (thesis chapter 4)", "",
           f"- Date: {h['date']}; commit {h['commit']}; {h['cores']} cores, shared and noisy",
           f"- Regenerate: `python3 scripts/kdtree_compare.py --pointray target/release/pointray` "
           f"(models {h['models']}; {h['size']}×{h['size']}, `--crop-to-model`, {h['threads']} threads, SJ, "
           "hard shadows, `--cull off`); the report alone, from the JSON lines: add `--report-only`",
           "- One round per configuration: ratios within one model and distance are meaningful, small "
           "differences are noise. *ms* is the median frame; Mrays/s counts camera and shadow rays; PSNR is "
           "over the crop region against the same accelerator's LoD-off image; Embree (oriented discs) ran "
           "right after the pointray rows of its block.", ""]
    out += ["## Build and memory", "",
            "Accelerator bytes per splat: pointray's nodes, representatives and references (not the splats "
            "themselves); Embree's, what it allocated while committing the scene.", "",
            "| model | points | accel | nodes | build s | accelerator bytes/splat |", "|---|---|---|---|---|---|"]
    for rec in records:
        if rec["accel"] != "embree" and rec["k"] == DISTANCES[0] and rec["lod"] == "off":
            s = rec["stats"]
            out.append(f"| {rec['model']} | {s['points']:,} | {rec['accel']} | {s['nodes']:,} | "
                       f"{s['build_seconds']:.3g} | {s['bytes_per_splat']:.1f} |")
    points = {r["model"]: r["stats"]["points"] for r in records if "stats" in r}
    for rec in records:
        if rec["accel"] == "embree" and rec["k"] == DISTANCES[0]:
            e = rec["embree"]
            # The bench reports the MiB Embree allocated while committing the scene.
            per_splat = (e["bvh_mb"] or 0) * 2**20 / points[rec["model"]]
            out.append(f"| {rec['model']} | | Embree | | {e['build_s']:.3g} | {per_splat:.1f} |")
    out += ["", "## Rendering", "",
            "| model | k | accel | LoD τ | ms | Mrays/s | vs BVH same τ | vs Embree | nodes/ray | splat tests/ray | "
            "LoD stops/ray | speed-up vs LoD off | PSNR dB vs LoD off |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for rec in records:
        if rec["accel"] == "embree":
            continue
        s = rec["stats"]
        bvh = reportlib.find(records, model=rec["model"], k=rec["k"], accel="bvh", lod=rec["lod"])
        off = reportlib.find(records, model=rec["model"], k=rec["k"], accel=rec["accel"], lod="off")
        emb = reportlib.find(records, model=rec["model"], k=rec["k"], accel="embree")
        vs_bvh = s["mrays_per_second"] / bvh["stats"]["mrays_per_second"]
        vs_emb = f"{s['mrays_per_second'] / emb['embree']['mrays_s']:.2f}×" if emb and emb["embree"]["mrays_s"] else "–"
        speedup = s["mrays_per_second"] / off["stats"]["mrays_per_second"]
        psnr = rec["psnr_vs_off"]
        psnr = "ref" if psnr is None else psnr if isinstance(psnr, str) else f"{psnr:.1f}"
        out.append(f"| {rec['model']} | {rec['k']} | {rec['accel']} | {rec['lod']} | {s['render_seconds'] * 1e3:.3g} | "
                   f"{s['mrays_per_second']:.2f} | {vs_bvh:.2f}× | {vs_emb} | {s['nodes_visited_per_ray']:.1f} | "
                   f"{s['splat_tests_per_ray']:.1f} | {s['lod_stops_per_ray']:.2f} | {speedup:.2f}× | {psnr} |")
    out += ["", "## Percentage improvement of LoD (thesis Fig. 4.11, 4.12)", "",
            "(render time with LoD off − with LoD) / with LoD off, per accelerator; PSNR in brackets.", "",
            "| model | k | accel | " + " | ".join(f"τ = {t}" for t in LODS[1:]) + " |",
            "|---|---|---|" + "---|" * (len(LODS) - 1)]
    for rec in records:
        if rec["accel"] == "embree" or rec["lod"] != "off":
            continue
        cells = []
        for t in LODS[1:]:
            r = reportlib.find(records, model=rec["model"], k=rec["k"], accel=rec["accel"], lod=t)
            if r is None:
                cells.append("–")
                continue
            gain = 100 * (1 - r["stats"]["render_seconds"] / rec["stats"]["render_seconds"])
            p = r["psnr_vs_off"]
            p = "=" if isinstance(p, str) else f"{p:.1f} dB"
            cells.append(f"{gain:+.0f} % ({p})")
        out.append(f"| {rec['model']} | {rec['k']} | {rec['accel']} | " + " | ".join(cells) + " |")
    embree_rows = [r for r in records if r["accel"] == "embree"]
    if embree_rows:
        out += ["", "Embree (same prepared cloud, camera and crop):", "", "| model | k | Mrays/s | ms |", "|---|---|---|---|"]
        for r in embree_rows:
            e = r["embree"]
            out.append(f"| {r['model']} | {r['k']} | {e['mrays_s']:.2f} | {e['render_s'] * 1e3:.3g} |")
    reportlib.write_report(a.out, out)


if __name__ == "__main__":
    main()
