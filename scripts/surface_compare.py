#!/usr/bin/env python3
"""The surface schemes side by side (thesis ch. 2 and 4): SJ, RFD, PSS and first-hit on real
scans; writes docs/surfaces.md, docs/surfaces-results.jsonl and close-up images.

For each model and camera distance k (in bounding-box diagonals, cropped to the model) it renders
every scheme with the BVH (built for the scheme's disks: the splats' balls for RFD) at full detail
and with level of detail (τ = 1). PSNR is over the crop region against the PSS image of the same
distance and LoD setting. One round per configuration: compare within a
block, not across the table.

    python3 scripts/surface_compare.py --pointray target/release/pointray [--models dragon,bunny]
"""

import json
import math
import os
import sys

import reportlib

MODELS = {
    "bunny": "stanford/bunny/reconstruction/bun_zipper.ply",
    "dragon": "stanford/dragon/dragon_vrip.vertices.binary_le.ply",
    "igea": "scans_other/igea.ply",
}
SCHEMES = ["sj", "rfd", "pss", "first-hit"]
LODS = ["off", 1]
DISTANCES = [1, 4, 16]
STATS = ["points", "rays", "render_seconds", "mrays_per_second", "primary_mrays_per_second", "splat_tests_per_ray",
         "nodes_visited_per_ray", "pss_steps_per_hit", "pss_fallback_fraction", "blended_splats_per_hit",
         "lod_stops_per_ray", "hit_fraction"]




def main():
    a = reportlib.arguments(__doc__, "/tmp/pointray-surfaces", MODELS, 768, "docs/surfaces.md",
                            lambda ap: ap.add_argument("--images", default="docs/images/surfaces"))
    jsonl = a.jsonl
    if a.report_only:
        write_markdown(a, *reportlib.read_jsonl(jsonl))
        return
    os.makedirs(a.cache, exist_ok=True)
    os.makedirs(a.images, exist_ok=True)
    header = reportlib.header(models=a.models, size=a.size, threads=a.threads)
    records = []
    for model in a.models.split(","):
        ply = os.path.join(a.cache, model + ".ply")
        if not os.path.exists(ply):
            reportlib.run([a.pointray, "-q", "prepare", os.path.join(a.data, MODELS[model]), "-o",
                           ply + ".partial.ply"])
            os.replace(ply + ".partial.ply", ply)
        for k in DISTANCES:
            for lod in LODS:
                ref = None
                for scheme in ["pss"] + [x for x in SCHEMES if x != "pss"]:  # the reference first
                    png = os.path.join(a.cache, f"{model}_k{k}_{lod}_{scheme}.png")
                    stats_path = png[:-4] + ".json"
                    lod_flags = ["--lod", "off"] if lod == "off" else ["--lod-threshold", lod]
                    cmd = [a.pointray, "-q", "render", ply, "-o", png, "--surface", scheme, "--distance", k,
                           "--crop-to-model", "--threads", a.threads, "--width", a.size, "--height", a.size,
                           "--cull", "off", "--stats", stats_path] + lod_flags
                    reportlib.run(cmd + ["--bench-frames", 0])
                    rays = json.load(open(stats_path))["rays"]
                    # About 2 s of work per configuration; PSS is slower, so fewer frames.
                    frames = max(3, math.ceil((1_000_000 if scheme == "pss" else 4_000_000) / max(rays, 1)))
                    reportlib.run(cmd + ["--bench-frames", frames])
                    s = json.load(open(stats_path))
                    r = s["region"]
                    region = f"{r['x0']},{r['y0']},{r['x1']},{r['y1']}"
                    if scheme == "pss":
                        ref, psnr = png, None
                    else:
                        c = json.loads(reportlib.run([a.pointray, "-q", "compare", png, ref, "--region", region,
                                                      "--json"]))
                        psnr = c["psnr_db"] if c["psnr_db"] is not None else "identical"
                    records.append({"model": model, "k": k, "lod": lod, "scheme": scheme, "frames": frames,
                                    "psnr_vs_pss": psnr, "stats": {x: s.get(x) for x in STATS}})
                    print(f"{model} k={k} lod={lod} {scheme}: {s['render_seconds'] * 1e3:.3g} ms, psnr {psnr}",
                          file=sys.stderr)
    # Close-ups of the dragon's head, the same view for every scheme.
    if "dragon" in a.models.split(","):
        ply = os.path.join(a.cache, "dragon.ply")
        for scheme in SCHEMES:
            reportlib.run([a.pointray, "-q", "render", ply, "-o", os.path.join(a.images, f"dragon-{scheme}.png"),
                           "--surface", scheme, "--distance", "0.3", "--width", 360, "--height", 360, "--threads",
                           a.threads])
    reportlib.write_jsonl(jsonl, header, records)
    write_markdown(a, header, records)


def write_markdown(a, header, records):
    h = header
    out = ["# Surface schemes: SJ, RFD, PSS and first-hit", "",
           f"- Date: {h['date']}; commit {h['commit']}; {h['cores']} cores, shared and noisy",
           f"- Regenerate: `python3 scripts/surface_compare.py --pointray target/release/pointray` (models "
           f"{h['models']}; {h['size']}×{h['size']}, `--crop-to-model`, {h['threads']} threads, the BVH built for "
           "each scheme's disks, hard shadows, `--cull off`); the report alone: `--report-only`",
           "- One round per configuration: compare within a block. *ms* is the median frame; Mrays/s counts "
           "camera and shadow rays; *camera Mrays/s* only the camera rays; PSNR is over the crop region "
           "against the PSS image of the same block (PSS is the smooth reference).", "",
           "| model | k | LoD τ | scheme | ms | Mrays/s | camera Mrays/s | vs SJ | splat tests/ray | "
           "PSS steps/hit | PSS fallbacks | PSNR dB vs PSS |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]

    for rec in records:
        s = rec["stats"]
        sj = reportlib.find(records, model=rec["model"], k=rec["k"], lod=rec["lod"], scheme="sj")
        vs_sj = sj["stats"]["render_seconds"] / s["render_seconds"]
        psnr = rec["psnr_vs_pss"]
        psnr = "ref" if psnr is None else psnr if isinstance(psnr, str) else f"{psnr:.1f}"
        steps = f"{s['pss_steps_per_hit']:.2f}" if rec["scheme"] == "pss" else "–"
        falls = f"{100 * s['pss_fallback_fraction']:.2f} %" if rec["scheme"] == "pss" else "–"
        out.append(f"| {rec['model']} | {rec['k']} | {rec['lod']} | {rec['scheme']} | "
                   f"{s['render_seconds'] * 1e3:.3g} | {s['mrays_per_second']:.2f} | "
                   f"{s['primary_mrays_per_second']:.2f} | {vs_sj:.2f}× | {s['splat_tests_per_ray']:.1f} | "
                   f"{steps} | {falls} | {psnr} |")
    out += ["", "*vs SJ*: SJ's frame time over this scheme's (above 1: faster than SJ).", ""]
    if os.path.isdir(a.images):
        out += ["## Close-ups", "",
                "The dragon's head at distance 0.3 (360², default level of detail), one image per scheme:", "",
                "| SJ | RFD | PSS | first-hit |", "|---|---|---|---|",
                "| " + " | ".join(f"![{s}](images/surfaces/dragon-{s}.png)"
                                   for s in SCHEMES) + " |", ""]
    reportlib.write_report(a.out, out)


if __name__ == "__main__":
    main()
