#!/usr/bin/env python3
"""Isolated dark speckles in default renders, against 16 rays a pixel of the same view.

Usage: scripts/speckle_check.py [--data ../shared/data] [--size 1024] [--out DIR] [--pointray BIN]
                                [--only NAME,...] [-- EXTRA RENDER ARGS]

For each scene (the built-in demo and the real scans the image-fidelity issue names) it renders
the default view at SIZE² with `--aov depth`, renders it again with `--spp 16`, and runs
`pointray compare A B --speckles A.depth.png`: a speckle is a lit pixel 60 levels of luma darker
than each of its four neighbours (`pointray::metrics::dark_speckles`), and the count that matters
is of those the 16-ray render lacks at the same place; the last column counts those of which it
shows no trace at all (`pointray::metrics::darkness_share`: the pixel darker than its neighbours
by less than half of what one ray of sixteen meeting the dot would make it), the speckles that
are the one-ray image's own rather than its sampling of a sliver of shadow or crack smaller than
a pixel. Prints a Markdown table and leaves the images in DIR. Needs `cargo build --release`.
"""
import argparse, json, os, subprocess, sys, tempfile

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.dirname(here)

SCENES = [
    ("demo", None),
    ("dragon", "stanford/dragon/dragon_vrip.vertices.binary_le.ply"),
    ("bunny", "stanford/bunny/reconstruction/bun_zipper.ply"),
    ("happy-buddha", "stanford/happy/happy_vrip_res3.ply"),
    ("igea", "scans_other/igea.ply"),
    ("armadillo", "scans_other/armadillo_38k_pts_normals.ply"),
]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.path.join(root, "..", "shared", "data"))
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--out", default=None)
    ap.add_argument("--pointray", default=os.path.join(root, "target", "release", "pointray"))
    ap.add_argument("--only", default=None, help="comma-separated scene names")
    ap.add_argument("extra", nargs="*", help="more render arguments, after --")
    a = ap.parse_args()
    out = a.out or tempfile.mkdtemp(prefix="speckles-")
    os.makedirs(out, exist_ok=True)
    only = set(a.only.split(",")) if a.only else None
    print(f"{a.size}², default settings {' '.join(a.extra)}; images in {out}\n")
    print("| scene | dark speckles | of which 16 rays a pixel lacks | of which they show no trace |")
    print("|---|---:|---:|---:|")
    for name, rel in SCENES:
        if only and name not in only:
            continue
        inputs = [] if rel is None else [os.path.join(a.data, rel)]
        if inputs and not os.path.exists(inputs[0]):
            print(f"| {name} | missing {inputs[0]} | | |")
            continue
        one, many = os.path.join(out, f"{name}.png"), os.path.join(out, f"{name}-16.png")
        size = ["--width", str(a.size), "--height", str(a.size)]
        render = [a.pointray, "-q", "render", *inputs, *size, *a.extra]
        subprocess.run([*render, "-o", one, "--aov", "depth"], check=True)
        subprocess.run([*render, "-o", many, "--spp", "16"], check=True)
        mask = os.path.join(out, f"{name}.depth.png")
        cmp = subprocess.run([a.pointray, "compare", one, many, "--speckles", mask, "--json"],
                             check=True, capture_output=True, text=True)
        s = json.loads(cmp.stdout)["speckles"]
        print(f"| {name} | {s['first']} | {s['not_in_second']} | {s['without_trace_in_second']} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
