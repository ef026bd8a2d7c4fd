#!/usr/bin/env python3
"""Dask scaling on this machine: one frame rendered by pointray.render and by pointray.dask on
LocalClusters of 1 and 2 single-threaded worker processes, each image checked against
pointray.render's bit for bit.

Usage: scripts/dask_scaling.py [--source PRS_OR_CLOUD] [--size 1024] [--spp 8] [--tile 128]
                               [--repeats 3] [--serve]

The source defaults to the Stanford dragon from ../shared/data, prepared into a scene file
first (the workers map it; none builds). Prints the least wall time of `repeats` renders for
each setting, the scene already open everywhere, and the first render's, which opens it.
`--serve`: the workers read the scene file over HTTP by range requests (the Python tests'
server on this machine), as workers with no shared file system would. Needs the package with
its Dask part: pip install "./crates/pointray-py[dask]".
"""
import argparse
import contextlib
import os
import sys
import tempfile
import time

import numpy as np

import pointray
import pointray.dask
from dask.distributed import Client, LocalCluster

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crates", "pointray-py", "tests"))
from ranged_http import RangedServer  # noqa: E402

here = os.path.dirname(os.path.abspath(__file__))
dragon = os.path.join(here, "..", "..", "shared", "data", "stanford", "dragon", "dragon_vrip.vertices.binary_le.ply")


def least(repeats, render):
    times, image = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        image = render()
        times.append(time.perf_counter() - start)
    return min(times), image


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--source", default=dragon)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--tile", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--serve", action="store_true", help="workers read the scene file over HTTP (range requests)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        source = a.source
        if not source.endswith(".prs"):
            source = os.path.join(tmp, "scene.prs")
            pointray.prepare_file(a.source, source)
        where = source
        if a.serve:
            server = stack.enter_context(RangedServer(os.path.dirname(os.path.abspath(source))))
            where = server.url(os.path.basename(source))
        options = {"width": a.size, "height": a.size, "spp": a.spp}
        scene = pointray.prepare(source)
        pointray.render(scene, **options)
        alone, expected = least(a.repeats, lambda: pointray.render(scene, **options))
        print(f"pointray.render, all cores: {alone:.2f} s")
        for workers, threads in [(1, None), (2, 1), (2, None)]:
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0")
            with cluster, Client(cluster) as client:
                run = {**options, **({"threads": threads} if threads else {})}
                first, _ = least(1, lambda: pointray.dask.render(client, where, tile=a.tile, **run))
                took, image = least(a.repeats, lambda: pointray.dask.render(client, where, tile=a.tile, **run))
                same = "the same image" if np.array_equal(image, expected) else "A DIFFERENT IMAGE"
                each = f"{threads} thread" if threads else "all cores"
                print(f"dask, {workers} worker(s), a task on {each}: {took:.2f} s ({alone / took:.2f}x), {same}; "
                      f"the first render, opening the scene on the workers: {first:.2f} s")


if __name__ == "__main__":
    main()
