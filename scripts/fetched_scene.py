#!/usr/bin/env python3
"""A scene file read over HTTP by range requests, against the same file mapped: bytes fetched
to open it and to render a view, wall times, and the two images compared bit for bit.

Usage: scripts/fetched_scene.py SCENE.prs [--size 512] [--spp 1] [--distance D] [--lod-threshold T]

Serves the file's directory on 127.0.0.1 with the Python tests' range-answering server
(crates/pointray-py/tests/ranged_http.py), so the figures are the fetching's own, without a
network's latency. Needs the package: pip install "./crates/pointray-py[remote]".
"""
import argparse
import os
import sys
import time

import numpy as np

import pointray

here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(here, "..", "crates", "pointray-py", "tests"))
from ranged_http import RangedServer  # noqa: E402


def timed(work):
    start = time.perf_counter()
    result = work()
    return result, time.perf_counter() - start


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--distance", type=float)
    ap.add_argument("--lod-threshold", type=float)
    args = ap.parse_args()
    options = {"width": args.size, "height": args.size, "spp": args.spp}
    if args.distance is not None:
        options["distance"] = args.distance
    if args.lod_threshold is not None:
        options["lod_threshold"] = args.lod_threshold
    size = os.path.getsize(args.scene)
    with RangedServer(os.path.dirname(os.path.abspath(args.scene))) as server:
        remote, open_s = timed(lambda: pointray.prepare(server.url(os.path.basename(args.scene))))
        opened = server.sent
        image, render_s = timed(lambda: pointray.render(remote, **options))
        rendered = server.sent
    local, local_open_s = timed(lambda: pointray.prepare(args.scene))
    expected, local_s = timed(lambda: pointray.render(local, **options))
    mb = 1e6
    print(f"file {size / mb:.1f} MB; options {options}")
    print(f"over HTTP: opened in {open_s:.3f} s fetching {opened / mb:.2f} MB; "
          f"rendered in {render_s:.3f} s fetching {(rendered - opened) / mb:.2f} MB more "
          f"({100 * rendered / size:.1f} % of the file in all)")
    print(f"mapped:    opened in {local_open_s:.3f} s; rendered in {local_s:.3f} s")
    print("images identical" if np.array_equal(image, expected) else "IMAGES DIFFER")


if __name__ == "__main__":
    main()
