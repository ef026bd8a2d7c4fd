#!/usr/bin/env python3
"""Instructions per ray: a speed figure that machine noise cannot move.

Usage: scripts/instructions_per_ray.py [--pointray target/release/pointray] [--model PLY]
                                       [--surface first-hit,sj] [--size 512]

For each surface it runs `valgrind --tool=callgrind` on

    pointray render MODEL --crop-to-model --surface S --no-shadows --threads 1 --width N --height N

at N x N and at 1 x 1, and prints (instructions at N^2 - instructions at 1^2) / N^2: everything a
render costs per pixel of the frame (ray set-up, traversal, shading, the film and the PNG),
without loading the model and building the BVH, which both runs share. Callgrind counts are
deterministic (the same binary and input give the same count to a few hundred instructions).
The model defaults to the Stanford dragon from ../shared/data, run through `pointray prepare`
first. Needs valgrind (Debian's package) and a release build.
"""
import argparse, os, re, subprocess, sys, tempfile

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.dirname(here)
dragon = os.path.join(root, "..", "shared", "data", "stanford", "dragon", "dragon_vrip.vertices.binary_le.ply")


def instructions(pointray, model, surface, size, tmp):
    out = os.path.join(tmp, "callgrind.out")
    cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", pointray, "-q", "render", model,
           "-o", os.path.join(tmp, "x.png"), "--crop-to-model", "--surface", surface, "--no-shadows",
           "--threads", "1", "--width", str(size), "--height", str(size)]
    log = subprocess.run(cmd, check=True, capture_output=True, text=True).stderr
    m = re.search(r"Collected : (\d+)", log)
    if not m:
        sys.exit(f"no instruction count in callgrind's output:\n{log}")
    return int(m.group(1))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pointray", default=os.path.join(root, "target", "release", "pointray"))
    ap.add_argument("--model", help="a prepared PLY (default: the dragon, prepared here)")
    ap.add_argument("--surface", default="first-hit,sj")
    ap.add_argument("--size", type=int, default=512)
    a = ap.parse_args()
    if not os.path.exists(a.pointray):
        sys.exit(f"missing {a.pointray}: cargo build --release")
    with tempfile.TemporaryDirectory() as tmp:
        model = a.model
        if model is None:
            model = os.path.join(tmp, "dragon.ply")
            subprocess.run([a.pointray, "-q", "prepare", dragon, "-o", model], check=True)
        print(f"| surface | instructions per pixel ({a.size}², minus 1×1) |")
        print("|---|---|")
        for surface in a.surface.split(","):
            big = instructions(a.pointray, model, surface, a.size, tmp)
            one = instructions(a.pointray, model, surface, 1, tmp)
            print(f"| {surface} | {(big - one) / a.size ** 2:,.0f} |", flush=True)


if __name__ == "__main__":
    main()
