#!/usr/bin/env python3
"""Temporal stability: how much a slow orbit's frames flicker, level of detail (plain and
prefiltered) against full detail.

Usage: scripts/temporal_stability.py MODEL [--dist 8,16] [--frames 12] [--step 0.5] [--size 1024]
                                     [--tau 1] [--pointray BIN] [--out DIR]

For each distance (bounding-box diagonals) the camera turns about the vertical axis in STEP
degrees a frame from the default view, and each frame is rendered four ways: full detail at one
ray a pixel, level of detail (threshold TAU) at one ray a pixel, plain and prefiltered
(`--prefilter`), and full detail at 64 rays a pixel, whose frames change only as the model turns. The figure is the RMS difference between
consecutive frames over the model's box (`pointray compare --region`, in levels of 255), and
above all its excess over the 64-ray sequence's: shimmer and popping. Needs `cargo build --release`.
"""
import argparse, json, math, os, subprocess, tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("--dist", default="8,16")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--step", type=float, default=0.5, help="degrees a frame")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--tau", default="1")
    ap.add_argument("--pointray", default=os.path.join(ROOT, "target", "release", "pointray"))
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    out = a.out or tempfile.mkdtemp(prefix="orbit-")
    os.makedirs(out, exist_ok=True)
    configs = [("full detail, 1 ray", ["--lod", "off"]), (f"τ = {a.tau}, 1 ray", ["--lod-threshold", a.tau]),
               (f"τ = {a.tau}, 1 ray, prefiltered", ["--lod-threshold", a.tau, "--prefilter"]),
               ("full detail, 64 rays", ["--lod", "off", "--spp", "64"])]
    print(f"{a.model}: {a.frames} frames, {a.step}° apart, {a.size}²; RMS frame-to-frame difference (levels)\n")
    print("| distance | " + " | ".join(name for name, _ in configs) +
          " | excess over the 64 rays': level of detail, prefiltered, full detail |")
    print("|---:|" + "---:|" * (len(configs) + 1))
    for dist in a.dist.split(","):
        region = model_region(a, dist, out)
        rms = []
        for c, (_, flags) in enumerate(configs):
            frames = [render(a, dist, i, flags, os.path.join(out, f"d{dist}_c{c}_{i:03}.png")) for i in range(a.frames)]
            diffs = [compare(a, frames[i], frames[i + 1], region) for i in range(a.frames - 1)]
            rms.append(math.sqrt(sum(d * d for d in diffs) / len(diffs)))
        excess = lambda r: math.sqrt(max(r * r - rms[3] ** 2, 0.0))
        print(f"| {dist} | " + " | ".join(f"{r:.2f}" for r in rms) +
              f" | {excess(rms[1]):.2f}, {excess(rms[2]):.2f}, {excess(rms[0]):.2f} |", flush=True)
    print(f"\nframes in {out}")


def view(i, step):
    """The default view direction (0.4, 0.3, 1) turned by i × step degrees about +y."""
    a = math.radians(i * step)
    x, y, z = 0.4, 0.3, 1.0
    return f"{x * math.cos(a) + z * math.sin(a)},{y},{-x * math.sin(a) + z * math.cos(a)}"


def render(a, dist, i, flags, png):
    size = ["--width", str(a.size), "--height", str(a.size)]
    subprocess.run([a.pointray, "-q", "render", a.model, "-o", png, *size, "--distance", dist,
                    "--view-dir", view(i, a.step), *flags], check=True)
    return png


def model_region(a, dist, out):
    """The model's box over the whole orbit: the union of the first and last frames' crops."""
    boxes = []
    for i in (0, a.frames - 1):
        stats = os.path.join(out, f"region_{dist}_{i}.json")
        subprocess.run([a.pointray, "-q", "render", a.model, "-o", os.path.join(out, "region.png"),
                        "--width", str(a.size), "--height", str(a.size), "--distance", dist,
                        "--view-dir", view(i, a.step), "--crop-to-model", "--stats", stats], check=True)
        boxes.append(json.load(open(stats))["region"])
    x0, y0 = min(b["x0"] for b in boxes), min(b["y0"] for b in boxes)
    x1, y1 = max(b["x1"] for b in boxes), max(b["y1"] for b in boxes)
    return f"{x0},{y0},{x1},{y1}"


def compare(a, first, second, region):
    result = subprocess.run([a.pointray, "compare", first, second, "--region", region, "--json"],
                            check=True, capture_output=True, text=True)
    return json.loads(result.stdout)["rmse"] * 255


if __name__ == "__main__":
    main()
