#!/usr/bin/env python3
"""Thesis chapter 3 for pointray: the multiresolution BVH (level of detail), measured.

Usage (from the repository root, after `cargo build --release`):

    scripts/lod_experiments.py                      # everything: roughly 10-20 minutes on 2 cores
    scripts/lod_experiments.py --quick --models bunny --dist 1,16 --out /tmp/lodtest
    scripts/lod_experiments.py --sections E         # rerun one section, keep the others' results
    scripts/lod_experiments.py --report-only        # rebuild docs/multires.md and the plots
                                                    # from docs/multires-results.jsonl

Each model is first run through `pointray -q prepare` into --cache (once; kept between runs),
so every render, and Embree, reads the same normals and radii. All renders are
--width/--height 1024 (--size), --crop-to-model, 2 threads (--threads), camera at k
bounding-box diagonals along the default view direction (0.4, 0.3, 1), and time
--bench-frames N frames after one warm-up frame (the median is reported), with N chosen so
every timed configuration traces at least --min-rays rays (3 million) and at least
--min-frames frames (5); --quick divides N by 10.

Sections (--sections, default ABCDEF):
  A  LoD threshold tau in {0.25, 0.5, 1, 2, 4} against LoD off, per model and distance (SJ
     surface with shadows, 1 spp, seed 0, culling off, boxes only); tables and SVG plots of
     time per ray, nodes per ray and PSNR against distance.
  B  Normal-cone backface culling off / on / auto, LoD off and tau 1, distances 1 and 16.
  C  Mixed bounding volumes (thesis tables 3.1/3.2): --sphere-from-level never, 0, 2, 3, 4,
     auto; dragon and bunny, distances 1, 4, 16, LoD off and tau 1.
  D  Quality against a converged reference (LoD off, 64 spp, seed 1): dragon, distances 4, 16.
  E  Beside Embree's oriented discs (first hit, no shadows, culling off), back to back.
  F  Images: dragon at distance 1 (768x768) LoD off / tau 1 and their node heat maps, and 8x
     magnified crops at distance 16 (LoD off | tau 1 | |difference| x4).
Sections B-E use their own distances, intersected with --dist. Where a section names the
dragon (C, D, F) and it is not among --models, the first model stands in.

PSNR is always measured over the crop region of the render (`pointray compare --region`), so
background outside the model's projected box does not inflate it; identical images have no
PSNR ("identical"). Raw results go to OUT/multires-results.jsonl (one JSON object per line),
the report to OUT/multires.md, plots and images to OUT/images/multires/.

Python 3 standard library only (PNG reading and writing and the SVG charts are in here).
"""
import argparse
import datetime
import json
import math
import os
import shlex
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

MODELS = {
    "dragon": "stanford/dragon/dragon_vrip.vertices.binary_le.ply",
    "bunny": "stanford/bunny/reconstruction/bun_zipper.ply",
    "buddha": "stanford/happy/happy_vrip_res3.ply",
}
TAUS = [0.25, 0.5, 1.0, 2.0, 4.0]
SPHERE_LEVELS = ["never", "0", "2", "3", "4", "auto"]
SECTION_DISTANCES = {"B": [1, 16], "C": [1, 4, 16], "D": [4, 16], "E": [1, 4, 16]}
RESULTS = "multires-results.jsonl"
REPORT = "multires.md"
IMAGES = os.path.join("images", "multires")

# What the report keeps of each render's --stats JSON.
STATS_KEYS = [
    "points", "width", "height", "region", "threads", "surface", "samples_per_pixel",
    "build_seconds", "render_seconds", "render_seconds_min", "timed_frames", "rays",
    "primary_rays", "shadow_rays", "mrays_per_second", "primary_mrays_per_second",
    "hit_fraction", "nodes_visited_per_ray", "splat_tests_per_ray", "box_tests_per_ray",
    "sphere_tests_per_ray", "lod_stops_per_ray", "culled_per_ray", "lod_threshold", "culling",
    "node_bounds", "nodes", "sphere_nodes", "bytes_per_node", "bytes_per_splat", "accel_bytes",
    "nodes_visited_max_per_pixel",
]


def log(msg):
    print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------------------------
# Configurations


def config(lod=None, cull="off", sphere="never", surface="sj", shadows=True, spp=1, seed=0):
    """One render configuration; lod None is LoD off, otherwise tau in pixels."""
    return {"lod": lod, "cull": cull, "sphere": sphere, "surface": surface,
            "shadows": shadows, "spp": spp, "seed": seed}


def scheme_of(cfg):
    """The LoD-off reference of a configuration: same surface, shadows, spp and seed."""
    return config(None, "off", "never", cfg["surface"], cfg["shadows"], cfg["spp"], cfg["seed"])


def fmt_num(x):
    return ("%g" % x) if x is not None else "off"


def tau_label(lod):
    return "LoD off" if lod is None else "τ = %s" % fmt_num(lod)


def slug(model, k, cfg, size):
    parts = [model, "d" + k, "off" if cfg["lod"] is None else "t" + fmt_num(cfg["lod"]),
             "c" + cfg["cull"], "s" + cfg["sphere"], "fh" if cfg["surface"] == "first-hit" else "sj",
             "sh" if cfg["shadows"] else "nosh", "spp%d" % cfg["spp"], "seed%d" % cfg["seed"], str(size)]
    return "_".join(parts)


def render_flags(cfg):
    f = ["--surface", cfg["surface"], "--spp", str(cfg["spp"]), "--seed", str(cfg["seed"]),
         "--cull", cfg["cull"], "--sphere-from-level", cfg["sphere"]]
    if not cfg["shadows"]:
        f.append("--no-shadows")
    if cfg["lod"] is None:
        f += ["--lod", "off"]
    else:
        f += ["--lod", "on", "--lod-threshold", fmt_num(cfg["lod"])]
    return f


def region_arg(stats):
    r = stats["region"]
    return "%d,%d,%d,%d" % (r["x0"], r["y0"], r["x1"], r["y1"])


# ----------------------------------------------------------------------------------------------
# Machine and load


def cpu_times():
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    idle = v[3] + (v[4] if len(v) > 4 else 0)
    return sum(v[:8]), idle


def load_snapshot(seconds=1.0):
    """Load averages, and the cores other processes kept busy over `seconds` while we slept."""
    la = list(os.getloadavg())
    try:
        t0, i0 = cpu_times()
        time.sleep(seconds)
        t1, i1 = cpu_times()
        busy = 1.0 - (i1 - i0) / max(1, t1 - t0)
        other = busy * (os.cpu_count() or 1)
    except OSError:
        other = None
    return {"loadavg": [round(x, 2) for x in la], "other_cores": None if other is None else round(other, 2)}


def machine():
    cpu = "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        nproc = subprocess.run(["nproc"], capture_output=True, text=True).stdout.strip()
    except OSError:
        nproc = str(os.cpu_count())
    mem = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal"):
                    mem = round(int(line.split()[1]) / 1024 / 1024, 1)
    except OSError:
        pass
    return {"nproc": nproc, "cpu": cpu, "mem_gib": mem}


def git_commit():
    try:
        c = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"],
                           capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return c + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def utc_now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


# ----------------------------------------------------------------------------------------------
# PNG (8-bit, non-interlaced; grey, RGB, grey+alpha and RGBA read as RGB; RGB written)

PNG_SIG = b"\x89PNG\r\n\x1a\n"
CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    return b if pb <= pc else c


def read_png(path, max_rows=None):
    """Returns (width, height, rows): rows a list of bytearrays of RGB, height of them (or only
    the first max_rows)."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != PNG_SIG:
        raise ValueError(f"{path}: not a PNG")
    pos, idat, hdr = 8, [], None
    while pos + 8 <= len(data):
        n, typ = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        pos += 12 + n
        if typ == b"IHDR":
            hdr = struct.unpack(">IIBBBBB", body)
        elif typ == b"IDAT":
            idat.append(body)
        elif typ == b"IEND":
            break
    w, h, depth, ctype, _comp, _filt, interlace = hdr
    if depth != 8 or interlace != 0 or ctype not in CHANNELS:
        raise ValueError(f"{path}: only 8-bit non-interlaced grey/RGB(A) PNGs are supported")
    bpp = CHANNELS[ctype]
    stride = w * bpp
    raw = zlib.decompress(b"".join(idat))
    rows, prev, i = [], bytearray(stride), 0
    for _y in range(h if max_rows is None else min(h, max_rows)):
        ft = raw[i]
        line = bytearray(raw[i + 1:i + 1 + stride])
        i += 1 + stride
        if ft == 1:  # Sub
            for x in range(bpp, stride):
                line[x] = (line[x] + line[x - bpp]) & 255
        elif ft == 2:  # Up
            line = bytearray((a + b) & 255 for a, b in zip(line, prev))
        elif ft == 3:  # Average
            for x in range(stride):
                left = line[x - bpp] if x >= bpp else 0
                line[x] = (line[x] + ((left + prev[x]) >> 1)) & 255
        elif ft == 4:  # Paeth
            for x in range(stride):
                if x >= bpp:
                    line[x] = (line[x] + _paeth(line[x - bpp], prev[x], prev[x - bpp])) & 255
                else:
                    line[x] = (line[x] + prev[x]) & 255
        elif ft != 0:
            raise ValueError(f"{path}: bad filter type {ft}")
        rows.append(line)
        prev = line
    if ctype == 2:
        out = rows
    elif ctype == 6:
        out = [bytearray(b for x in range(w) for b in r[4 * x:4 * x + 3]) for r in rows]
    elif ctype == 0:
        out = [bytearray(v for g in r for v in (g, g, g)) for r in rows]
    else:  # 4: grey + alpha
        out = [bytearray(v for x in range(w) for v in (r[2 * x],) * 3) for r in rows]
    return w, h, out


def write_png(path, w, rows):
    """Writes RGB rows (bytes-like, 3*w each) as an 8-bit PNG, per-row filter None/Sub/Up by
    the minimum-sum-of-absolute-differences heuristic; atomically."""
    stride = 3 * w
    raw = bytearray()
    prev = bytes(stride)
    for row in rows:
        row = bytes(row)
        assert len(row) == stride
        sub = bytes((row[x] - (row[x - 3] if x >= 3 else 0)) & 255 for x in range(stride))
        up = bytes((a - b) & 255 for a, b in zip(row, prev))
        best = min(((0, row), (1, sub), (2, up)), key=lambda c: sum(v if v < 128 else 256 - v for v in c[1]))
        raw.append(best[0])
        raw += best[1]
        prev = row

    def chunk(t, body):
        return struct.pack(">I", len(body)) + t + body + struct.pack(">I", zlib.crc32(t + body) & 0xFFFFFFFF)

    png = PNG_SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", w, len(rows), 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(bytes(raw), 9)) + chunk(b"IEND", b"")
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(png)
    os.replace(tmp, path)


def crop_rows(rows, r):
    return [bytes(row[3 * r["x0"]:3 * r["x1"]]) for row in rows[r["y0"]:r["y1"]]]


def magnify(rows, s):
    out = []
    for row in rows:
        big = bytes(b for x in range(0, len(row), 3) for b in row[x:x + 3] * s)
        out += [big] * s
    return out


def abs_diff(a, b, gain):
    return [bytes(min(255, abs(x - y) * gain) for x, y in zip(ra, rb)) for ra, rb in zip(a, b)]


def hcat(panels, gap, colour=(255, 255, 255)):
    g = bytes(colour) * gap
    return [g.join(parts) for parts in zip(*panels)]


# ----------------------------------------------------------------------------------------------
# Running pointray and Embree


class Runner:
    def __init__(self, a, work, emit):
        self.a = a
        self.work = work
        self.emit = emit  # callable(record)
        self.prepared_paths = {}
        self.refs = {}  # (model, k, slug of scheme) -> (png, stats)
        self.model_recorded = set()
        self.count = 0

    # -- bookkeeping
    def frames_for(self, rays_per_frame):
        n = max(self.a.min_frames, math.ceil(self.a.min_rays / max(1, rays_per_frame)))
        if self.a.quick:
            n = max(1, math.ceil(n / 10))
        return n

    def prepared(self, model):
        if model in self.prepared_paths:
            return self.prepared_paths[model]
        src = os.path.join(self.a.data, MODELS[model])
        dst = os.path.join(self.a.cache, model + ".ply")
        if not os.path.exists(dst):
            if not os.path.exists(src):
                raise SystemExit(f"missing model file {src}")
            os.makedirs(self.a.cache, exist_ok=True)
            log(f"prepare {model}: {src} -> {dst}")
            tmp = dst + ".partial.ply"
            subprocess.run([self.a.pointray, "-q", "prepare", src, "-o", tmp], check=True)
            os.replace(tmp, dst)
        self.prepared_paths[model] = dst
        return dst

    # -- pointray
    def render(self, model, k, cfg, frames, size=None, name=None, aov=False):
        """Renders one configuration; returns (png path, stats subset, wall seconds)."""
        size = size or self.a.size
        name = name or slug(model, k, cfg, size)
        png = os.path.join(self.work, name + ".png")
        sj = os.path.join(self.work, name + ".json")
        cmd = [self.a.pointray, "-q", "render", self.prepared(model), "-o", png, "--distance", k,
               "--crop-to-model", "--threads", str(self.a.threads), "--width", str(size),
               "--height", str(size), "--bench-frames", str(frames), "--stats", sj] + render_flags(cfg)
        if aov:
            cmd += ["--aov", "nodes"]
        t0 = time.time()
        p = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.time() - t0
        self.count += 1
        if p.returncode != 0:
            raise RuntimeError(f"pointray failed ({p.returncode}): {shlex.join(cmd)}\n{p.stderr.strip()}")
        with open(sj) as f:
            s = json.load(f)
        stats = {key: s.get(key) for key in STATS_KEYS}
        if model not in self.model_recorded:
            self.model_recorded.add(model)
            self.emit({"type": "model", "model": model, "source": MODELS[model], "points": s.get("points"),
                       "nodes": s.get("nodes"), "bytes_per_node": s.get("bytes_per_node"),
                       "bytes_per_splat": s.get("bytes_per_splat"), "accel_bytes": s.get("accel_bytes"),
                       "build_seconds": s.get("build_seconds"), "bounds_diagonal": s.get("bounds_diagonal")})
        return png, stats, wall

    def compare(self, a, b, stats):
        cmd = [self.a.pointray, "-q", "compare", a, b, "--region", region_arg(stats), "--json"]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            raise RuntimeError(f"compare failed: {shlex.join(cmd)}\n{p.stderr.strip()}")
        return json.loads(p.stdout.strip().splitlines()[-1])

    def ref(self, model, k, cfg, size=None):
        """The LoD-off image of cfg's scheme (untimed single frame), rendered once per run; it
        also tells how many rays a frame holds."""
        scheme = scheme_of(cfg)
        key = (model, k, slug(model, k, scheme, size or self.a.size))
        if key not in self.refs:
            png, stats, _ = self.render(model, k, scheme, 0, size=size, name="ref_" + key[2])
            self.refs[key] = (png, stats)
        return self.refs[key]

    def row(self, section, model, k, cfg, timed=True, extra=None, size=None):
        """One timed configuration, compared against its LoD-off reference; emits the record."""
        ref_png, ref_stats = self.ref(model, k, cfg, size)
        frames = self.frames_for(ref_stats["rays"] or 1) if timed else 0
        rec = {"type": "row", "section": section, "model": model, "k": k, "cfg": cfg, "frames": frames}
        if extra:
            rec.update(extra)
        try:
            png, stats, wall = self.render(model, k, cfg, frames, size=size)
            if stats["region"] != ref_stats["region"]:
                log(f"warning: region {stats['region']} differs from the reference's {ref_stats['region']}")
            rec.update(stats=stats, wall_seconds=round(wall, 2), psnr_vs_off=self.compare(png, ref_png, stats))
            rec["png"] = png
            s = stats
            log(f"[{section}] {model} k={k} {describe(cfg)}: {fmt_ms(s['render_seconds'])} ms/frame, "
                f"{s['mrays_per_second']:.2f} Mrays/s, {s['nodes_visited_per_ray']:.1f} nodes/ray, "
                f"{frames} frames, {wall:.1f} s")
        except RuntimeError as e:
            log(str(e))
            rec["error"] = str(e)[:2000]
        self.emit(rec)
        return rec

    def group(self, section, model, k, cfgs, extras=None, embree=False):
        """Times configurations that belong together in --rounds interleaved rounds (each round
        runs every configuration once, and Embree after each with `embree`), so that the shared
        machine's drift hits all of them alike; reports the median round. Work counters and
        images do not change from round to round. Emits and returns one record per config."""
        plans = []
        for cfg in cfgs:
            ref_png, ref_stats = self.ref(model, k, cfg)
            plans.append((cfg, ref_png, ref_stats, self.frames_for(ref_stats["rays"] or 1)))
        runs = [[] for _ in cfgs]
        eruns = [[] for _ in cfgs]
        for _ in range(self.a.rounds):
            for i, (cfg, _, _, frames) in enumerate(plans):
                try:
                    runs[i].append(self.render(model, k, cfg, frames))
                except RuntimeError as e:
                    log(str(e))
                    runs[i].append(e)
                    continue
                if embree:
                    try:
                        eruns[i].append(self.embree(model, k, frames))
                    except (RuntimeError, ValueError) as ex:
                        log(str(ex))
                        eruns[i].append(ex)
        recs = []
        for i, (cfg, ref_png, ref_stats, frames) in enumerate(plans):
            rec = {"type": "row", "section": section, "model": model, "k": k, "cfg": cfg, "frames": frames,
                   "rounds": self.a.rounds}
            if extras:
                rec.update(extras[i])
            failed = [r for r in runs[i] if isinstance(r, Exception)]
            if failed:
                rec["error"] = str(failed[0])[:2000]
            else:
                png, stats, _ = runs[i][-1]
                times = sorted(r[1]["render_seconds"] for r in runs[i])
                stats = dict(stats)
                stats["render_seconds"] = times[len(times) // 2]
                stats["render_seconds_rounds"] = times
                stats["mrays_per_second"] = stats["rays"] / stats["render_seconds"] / 1e6
                stats["primary_mrays_per_second"] = stats["primary_rays"] / stats["render_seconds"] / 1e6
                if stats["region"] != ref_stats["region"]:
                    log(f"warning: region {stats['region']} differs from the reference's {ref_stats['region']}")
                rec.update(stats=stats, wall_seconds=round(sum(r[2] for r in runs[i]), 2),
                           psnr_vs_off=self.compare(png, ref_png, stats), png=png)
                log(f"[{section}] {model} k={k} {describe(cfg)}: {fmt_ms(stats['render_seconds'])} ms/frame "
                    f"(rounds {', '.join(fmt_ms(t) for t in times)}), {stats['mrays_per_second']:.2f} Mrays/s, "
                    f"{stats['nodes_visited_per_ray']:.1f} nodes/ray, {frames} frames")
                if embree:
                    good = sorted((e for e in eruns[i] if not isinstance(e, Exception)), key=lambda e: e[0]["mrays_s"])
                    if good:
                        e, wall = good[len(good) // 2]
                        e = dict(e)
                        e["mrays_s_rounds"] = [g[0]["mrays_s"] for g in good]
                        rec["embree"] = e
                        rec["embree_wall_seconds"] = wall
                        if e.get("rays") != stats["primary_rays"]:
                            log(f"warning: {model} k={k}: Embree traced {e.get('rays')} rays, "
                                f"pointray {stats['primary_rays']}")
                    else:
                        rec["embree_error"] = str(eruns[i][0])[:2000] if eruns[i] else "not run"
            self.emit(rec)
            recs.append(rec)
        return recs

    # -- Embree
    def embree(self, model, k, reps):
        cmd = [self.a.embree, self.prepared(model), "--geom", "oriented", "--threads", str(self.a.threads),
               "--dist", k, "--crop", "--reps", str(reps), "--size", f"{self.a.size}x{self.a.size}"]
        t0 = time.time()
        p = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.time() - t0
        if p.returncode != 0:
            raise RuntimeError(f"embree failed ({p.returncode}): {shlex.join(cmd)}\n{p.stderr.strip()}")
        e = json.loads(p.stdout.strip().splitlines()[-1])
        log(f"[E] {model} k={k} Embree: {e.get('mrays_s', 0):.2f} Mrays/s, {reps} reps, {wall:.1f} s")
        keep = ["embree", "rays", "mrays_s", "mrays_s_best", "render_s", "render_s_min", "build_s", "bvh_mb",
                "hit_frac", "reps", "other_cores", "quality"]
        return {x: e.get(x) for x in keep}, round(wall, 2)


def describe(cfg):
    d = tau_label(cfg["lod"])
    if cfg["cull"] != "off":
        d += ", cull " + cfg["cull"]
    if cfg["sphere"] != "never":
        d += ", spheres from " + cfg["sphere"]
    if cfg["surface"] != "sj":
        d += ", " + cfg["surface"]
    if not cfg["shadows"]:
        d += ", no shadows"
    if cfg["spp"] != 1 or cfg["seed"] != 0:
        d += f", {cfg['spp']} spp seed {cfg['seed']}"
    return d


# ----------------------------------------------------------------------------------------------
# Sections


def section_dists(a, sec):
    want = SECTION_DISTANCES[sec]
    return [k for k in a.dist if float(k) in [float(w) for w in want]]


def section_note_dists(sec):
    return "distances %s" % ", ".join(str(x) for x in SECTION_DISTANCES[sec])


def run_A(r, a):
    for m in a.models:
        for k in a.dist:
            r.group("A", m, k, [config(lod) for lod in [None] + TAUS])


def run_B(r, a):
    ks = section_dists(a, "B")
    if not ks:
        return f"skipped: none of {section_note_dists('B')} in --dist"
    for m in a.models:
        for k in ks:
            for lod in (None, 1.0):
                base, *rest = r.group("B", m, k, [config(lod, cull=c) for c in ("off", "on", "auto")])
                for rec in rest:
                    if "error" not in rec and "error" not in base:
                        rec["psnr_vs_cull_off"] = r.compare(rec["png"], base["png"], rec["stats"])
                        r.emit(rec, update=True)
    return None


def c_models(a):
    ms = [m for m in a.models if m in ("dragon", "bunny")]
    return ms or a.models[:1]


def one_model(a):
    return "dragon" if "dragon" in a.models else a.models[0]


def run_C(r, a):
    ks = section_dists(a, "C")
    if not ks:
        return f"skipped: none of {section_note_dists('C')} in --dist"
    for m in c_models(a):
        for k in ks:
            for lod in (None, 1.0):
                r.group("C", m, k, [config(lod, sphere=sph) for sph in SPHERE_LEVELS])
    return None


def run_D(r, a):
    ks = section_dists(a, "D")
    if not ks:
        return f"skipped: none of {section_note_dists('D')} in --dist"
    m = one_model(a)
    for k in ks:
        ref_cfg = config(None, spp=64, seed=1)
        ref_png, ref_stats = r.ref(m, k, ref_cfg)
        r.emit({"type": "row", "section": "D", "model": m, "k": k, "cfg": ref_cfg, "frames": 0, "role": "reference",
                "stats": ref_stats, "psnr_vs_off": None, "psnr_vs_truth": None})
        tests = [config(lod, spp=spp) for lod, spp in ((None, 1), (0.5, 1), (1.0, 1), (2.0, 1), (None, 16), (1.0, 16))]
        for rec in r.group("D", m, k, tests, extras=[{"role": "test"}] * len(tests)):
            if "error" not in rec:
                rec["psnr_vs_truth"] = r.compare(rec["png"], ref_png, ref_stats)
                r.emit(rec, update=True)
    return None


def run_E(r, a):
    if not a.embree or not os.path.exists(a.embree):
        return f"skipped: the Embree bench was not found at {a.embree}"
    ks = section_dists(a, "E")
    if not ks:
        return f"skipped: none of {section_note_dists('E')} in --dist"
    for m in a.models:
        for k in ks:
            r.group("E", m, k, [config(lod, surface="first-hit", shadows=False) for lod in (None, 0.5, 1.0)],
                    embree=True)
    return None


def run_F(r, a):
    m = one_model(a)
    img_dir = os.path.join(a.out, IMAGES)
    os.makedirs(img_dir, exist_ok=True)
    # Distance 1: full frames at 768x768, with the node heat maps.
    pngs = {}
    for lod, tag in ((None, "off"), (1.0, "tau1")):
        cfg = config(lod)
        png, stats, _ = r.render(m, "1", cfg, 0, size=768, name=f"F_{m}_d1_{tag}", aov=True)
        dst = os.path.join(img_dir, f"{m}_d1_{tag}.png")
        shutil.copyfile(png, dst)
        shutil.copyfile(png[:-4] + ".nodes.png", os.path.join(img_dir, f"{m}_d1_{tag}.nodes.png"))
        pngs[tag] = (png, stats)
    cmp1 = r.compare(pngs["tau1"][0], pngs["off"][0], pngs["off"][1])
    r.emit({"type": "image", "section": "F", "model": m, "k": "1", "size": 768,
            "files": [f"{m}_d1_off.png", f"{m}_d1_tau1.png", f"{m}_d1_off.nodes.png", f"{m}_d1_tau1.nodes.png"],
            "stats_off": pngs["off"][1], "stats_tau1": pngs["tau1"][1], "psnr": cmp1})
    # Distance 16: the crop, magnified.
    scale, gain = 8, 4
    off_png, off_stats = r.ref(m, "16", config(None))
    tau_png, tau_stats, _ = r.render(m, "16", config(1.0), 0)
    reg = off_stats["region"]
    _, _, ra = read_png(off_png, max_rows=reg["y1"])
    _, _, rb = read_png(tau_png, max_rows=reg["y1"])
    ca, cb = crop_rows(ra, reg), crop_rows(rb, reg)
    diff = abs_diff(ca, cb, gain)
    maxd = max((max(row) for row in diff), default=0)
    rows = hcat([magnify(ca, scale), magnify(cb, scale), magnify(diff, scale)], gap=8)
    name = f"{m}_d16_zoom.png"
    write_png(os.path.join(img_dir, name), len(rows[0]) // 3, rows)
    cmp16 = r.compare(tau_png, off_png, off_stats)
    r.emit({"type": "image", "section": "F", "model": m, "k": "16", "size": a.size, "files": [name],
            "region": reg, "scale": scale, "gain": gain, "max_amplified_diff": maxd,
            "stats_off": off_stats, "stats_tau1": tau_stats, "psnr": cmp16})
    return None


SECTIONS = {"A": run_A, "B": run_B, "C": run_C, "D": run_D, "E": run_E, "F": run_F}
SECTION_TITLES = {
    "A": "A. Level-of-detail threshold",
    "B": "B. Normal-cone backface culling",
    "C": "C. Mixed bounding volumes (thesis tables 3.1 and 3.2)",
    "D": "D. Quality against a converged reference",
    "E": "E. Beside Embree",
    "F": "F. Images",
}


# ----------------------------------------------------------------------------------------------
# Formatting


def fmt_sig(v, n=3):
    if v is None:
        return "–"
    if v == 0:
        return "0"
    d = max(0, n - 1 - math.floor(math.log10(abs(v))))
    return f"{v:.{d}f}"


def fmt_ms(seconds):
    return fmt_sig(None if seconds is None else seconds * 1e3)


def fmt_count(v):
    if v is None:
        return "–"
    if v == 0:
        return "0"
    if abs(v) < 0.05:
        return "<0.1"
    return f"{v:.1f}"


def fmt_psnr(c):
    if c is None:
        return "–"
    if c.get("psnr_db") is None:
        return "identical"
    return f"{c['psnr_db']:.1f}"


def psnr_phrase(c, start=False):
    if c.get("psnr_db") is None:
        return ("Identical" if start else "identical") + " images"
    return f"PSNR {c['psnr_db']:.1f} dB"


def fmt_ratio(x):
    return "–" if x is None else f"{x:.2f}×"


def ns_per_ray(s):
    if not s or not s.get("rays"):
        return None
    return s["render_seconds"] / s["rays"] * 1e9


def md_table(header, rows, drop_zero=()):
    """Markdown table; columns named in drop_zero are left out when every row shows "0"."""
    keep = [i for i, h in enumerate(header)
            if h not in drop_zero or any(r[i] not in ("0", "–") for r in rows)]
    dropped = [header[i] for i in range(len(header)) if i not in keep]
    out = ["| " + " | ".join(header[i] for i in keep) + " |", "|" + "---|" * len(keep)]
    out += ["| " + " | ".join(str(r[i]) for i in keep) + " |" for r in rows]
    return "\n".join(out), dropped


def dropped_note(dropped):
    if not dropped:
        return ""
    return "\n\n(" + ", ".join(dropped) + ": 0 in every row, left out.)"


# ----------------------------------------------------------------------------------------------
# SVG line charts

PALETTE = ["#000000", "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2"]


def esc(s):
    return str(s).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")


def nice_ticks(lo, hi, n=5):
    if hi - lo < 1e-12:
        lo, hi = (lo - 1, hi + 1) if lo == 0 else (lo * 0.9, hi * 1.1)
        if lo > hi:
            lo, hi = hi, lo
    raw = (hi - lo) / n
    mag = 10 ** math.floor(math.log10(raw))
    for mul in (1, 2, 2.5, 5, 10):
        step = mul * mag
        if (hi - lo) / step <= n:
            break
    start = math.floor(lo / step + 1e-9) * step
    end = math.ceil(hi / step - 1e-9) * step
    count = int(round((end - start) / step))
    dec = max(0, -math.floor(math.log10(step) + 1e-9)) + (1 if mul == 2.5 and step < 10 else 0)
    return [start + i * step for i in range(count + 1)], dec


def line_chart(path, title, xlabel, ylabel, series, y_from_zero=True, identical_label=None):
    """series: [(name, colour, [(x, y)])], y None meaning identical (plotted on a line of its own
    above the others when identical_label is set, else left out). x on a log2 axis."""
    W, H = 680, 420
    L, R, T, B = 72, 150, 44, 58
    pw, ph = W - L - R, H - T - B
    xs = [x for _, _, pts in series for x, _ in pts]
    ys = [y for _, _, pts in series for _, y in pts if y is not None]
    has_identical = identical_label and any(y is None for _, _, pts in series for _, y in pts)
    if not xs:
        xs = [1]
    e_lo, e_hi = math.floor(math.log2(min(xs))), math.ceil(math.log2(max(xs)))
    if e_lo == e_hi:
        e_lo, e_hi = e_lo - 1, e_hi + 1
    d_lo, d_hi = e_lo - 0.3, e_hi + 0.3
    if ys:
        lo, hi = (0 if y_from_zero else min(ys)), max(ys)
    else:
        lo, hi = (0, 1) if y_from_zero else (20, 60)
    ticks, dec = nice_ticks(lo, hi)
    y_lo, y_hi = ticks[0], ticks[-1]
    y_ident = None
    if has_identical:
        step = ticks[1] - ticks[0] if len(ticks) > 1 else 1
        y_ident = y_hi + step
        y_hi = y_ident + step * 0.4
    else:
        y_hi = y_hi + (y_hi - y_lo) * 0.04

    def X(x):
        return L + (math.log2(x) - d_lo) / (d_hi - d_lo) * pw

    def Y(y):
        return T + ph - (y - y_lo) / (y_hi - y_lo) * ph

    o = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" '
         f'font-family="Helvetica, Arial, sans-serif" font-size="12">',
         f'<rect width="{W}" height="{H}" fill="#ffffff"/>',
         f'<text x="{L + pw / 2:.1f}" y="22" text-anchor="middle" font-size="14" font-weight="bold">{esc(title)}</text>']
    # grid and ticks
    for t in ticks:
        y = Y(t)
        o.append(f'<line x1="{L}" y1="{y:.1f}" x2="{L + pw}" y2="{y:.1f}" stroke="#e4e4e4"/>')
        o.append(f'<line x1="{L - 5}" y1="{y:.1f}" x2="{L}" y2="{y:.1f}" stroke="#000"/>')
        o.append(f'<text x="{L - 8}" y="{y + 4:.1f}" text-anchor="end">{t:.{dec}f}</text>')
    for e in range(e_lo, e_hi + 1):
        x = X(2.0 ** e)
        lab = ("%d" % 2 ** e) if e >= 0 else "1/%d" % 2 ** -e
        o.append(f'<line x1="{x:.1f}" y1="{T}" x2="{x:.1f}" y2="{T + ph}" stroke="#e4e4e4"/>')
        o.append(f'<line x1="{x:.1f}" y1="{T + ph}" x2="{x:.1f}" y2="{T + ph + 5}" stroke="#000"/>')
        o.append(f'<text x="{x:.1f}" y="{T + ph + 19}" text-anchor="middle">{lab}</text>')
    if y_ident is not None:
        y = Y(y_ident)
        o.append(f'<line x1="{L}" y1="{y:.1f}" x2="{L + pw}" y2="{y:.1f}" stroke="#888" stroke-dasharray="5,4"/>')
        o.append(f'<text x="{L - 8}" y="{y + 4:.1f}" text-anchor="end" font-style="italic">{esc(identical_label)}</text>')
    # axes
    o.append(f'<line x1="{L}" y1="{T + ph}" x2="{L + pw}" y2="{T + ph}" stroke="#000"/>')
    o.append(f'<line x1="{L}" y1="{T}" x2="{L}" y2="{T + ph}" stroke="#000"/>')
    o.append(f'<text x="{L + pw / 2:.1f}" y="{H - 14}" text-anchor="middle">{esc(xlabel)}</text>')
    o.append(f'<text transform="translate(18,{T + ph / 2:.1f}) rotate(-90)" text-anchor="middle">{esc(ylabel)}</text>')
    # series
    for idx, (name, colour, pts) in enumerate(series):
        pts = sorted(pts)
        # Identical points share one line: stagger the series a little so each stays visible.
        stagger = (idx - (len(series) - 1) / 2) * 3
        coords = [(X(x), Y(y) if y is not None else Y(y_ident) + stagger) for x, y in pts
                  if y is not None or y_ident is not None]
        if len(coords) > 1:
            d = " ".join(f"{cx:.1f},{cy:.1f}" for cx, cy in coords)
            o.append(f'<polyline points="{d}" fill="none" stroke="{colour}" stroke-width="2"/>')
        for cx, cy in coords:
            o.append(f'<circle cx="{cx:.1f}" cy="{cy:.1f}" r="3.5" fill="{colour}"/>')
        ly = T + 10 + idx * 20
        lx = L + pw + 16
        o.append(f'<line x1="{lx}" y1="{ly}" x2="{lx + 24}" y2="{ly}" stroke="{colour}" stroke-width="2"/>')
        o.append(f'<circle cx="{lx + 12}" cy="{ly}" r="3.5" fill="{colour}"/>')
        o.append(f'<text x="{lx + 32}" y="{ly + 4}">{esc(name)}</text>')
    o.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(o) + "\n")


# ----------------------------------------------------------------------------------------------
# Report


def by(records, **kw):
    return [r for r in records if all(r.get(k) == v for k, v in kw.items())]


def kval(r):
    return float(r["k"])


def ordered_models(rows):
    seen = []
    for r in rows:
        if r["model"] not in seen:
            seen.append(r["model"])
    return seen


def sorted_ks(rows):
    return sorted({r["k"] for r in rows}, key=float)


def find(rows, **cfg_kw):
    for r in rows:
        if all(r["cfg"].get(k) == v for k, v in cfg_kw.items()):
            return r
    return None


def section_header(sec, secrec, runs, head_run):
    lines = [f"## {SECTION_TITLES[sec]}", ""]
    if secrec is None:
        return lines
    run = runs.get(secrec.get("run_id"), {})
    bits = []
    if run and head_run and run.get("run_id") != head_run.get("run_id"):
        bits.append(f"From an earlier run: {run.get('date_utc')}, commit {run.get('commit')}, "
                    f"`{run.get('command')}`.")
    ld = secrec.get("load") or {}
    la = ld.get("loadavg")
    if la:
        oc = ld.get("other_cores")
        bits.append(f"Load before this section: load average {la[0]:.2f} / {la[1]:.2f} / {la[2]:.2f} "
                    f"(1/5/15 min, counting this script's own earlier renders)"
                    + (f"; other processes kept {oc:.2f} cores busy over the 1 s before it" if oc is not None else "")
                    + ".")
    if secrec.get("wall_seconds") is not None:
        bits.append(f"The section took {secrec['wall_seconds']:.0f} s.")
    if secrec.get("note"):
        bits.append(f"**{secrec['note']}**")
    if bits:
        lines += [" ".join(bits), ""]
    return lines


def ok(r):
    return r is not None and "error" not in r and r.get("stats")


def stat_cols(r):
    s = r["stats"]
    return [fmt_ms(s["render_seconds"]), fmt_sig(s["mrays_per_second"]), fmt_count(s["nodes_visited_per_ray"]),
            fmt_count(s["box_tests_per_ray"]), fmt_count(s["sphere_tests_per_ray"]),
            fmt_count(s["splat_tests_per_ray"]), fmt_count(s["lod_stops_per_ray"]), fmt_count(s["culled_per_ray"])]


STAT_HEAD = ["render ms", "Mrays/s", "nodes/ray", "box tests/ray", "sphere tests/ray", "splat tests/ray",
             "LoD stops/ray", "culled/ray"]
DROPPABLE = ("box tests/ray", "sphere tests/ray", "LoD stops/ray", "culled/ray")


def error_row(r, ncols, lead):
    return lead + ["failed"] + ["–"] * (ncols - len(lead) - 1)


def report_A(recs, img_dir, out):
    rows = by(recs, type="row", section="A")
    lines = []
    if not rows:
        return ["No results."]
    lines += ["SJ surface with hard shadows, 1 spp, seed 0, `--cull off --sphere-from-level never`. "
              "τ is `--lod-threshold` in pixels; *speed-up* is the LoD-off median frame time over this "
              "row's; PSNR is against the LoD-off image of the same model and distance, over the crop region. "
              "Rays per frame include the shadow rays.", ""]
    for m in ordered_models(rows):
        mr = [r for r in rows if r["model"] == m]
        lines += [f"### {m}", ""]
        head = ["k", "LoD", "rays/frame", "frames"] + STAT_HEAD[:1] + ["ns/ray", "speed-up vs LoD off"] + STAT_HEAD[1:] + ["PSNR dB vs LoD off"]
        body = []
        for k in sorted_ks(mr):
            kr = [r for r in mr if r["k"] == k]
            off = find(kr, lod=None)
            for lod in [None] + TAUS:
                r = find(kr, lod=lod)
                if r is None:
                    continue
                lead = [k, "off" if lod is None else fmt_num(lod)]
                if not ok(r):
                    body.append(error_row(r, len(head), lead))
                    continue
                s = r["stats"]
                sp = (off["stats"]["render_seconds"] / s["render_seconds"]) if ok(off) and s["render_seconds"] else None
                sc = stat_cols(r)
                ps = "ref" if lod is None and (r.get("psnr_vs_off") or {}).get("psnr_db") is None else fmt_psnr(r.get("psnr_vs_off"))
                body.append(lead + [str(s["rays"]), str(r["frames"]), sc[0], fmt_sig(ns_per_ray(s)), fmt_ratio(sp)] + sc[1:] + [ps])
        t, dropped = md_table(head, body, DROPPABLE)
        lines += [t + dropped_note(dropped), ""]
        # plots
        series_ns, series_nodes, series_psnr = [], [], []
        for i, lod in enumerate([None] + TAUS):
            pts = [(kval(r), r) for r in mr if r["cfg"]["lod"] == lod and ok(r)]
            if not pts:
                continue
            name, col = tau_label(lod), PALETTE[i % len(PALETTE)]
            series_ns.append((name, col, [(x, ns_per_ray(r["stats"])) for x, r in pts]))
            series_nodes.append((name, col, [(x, r["stats"]["nodes_visited_per_ray"]) for x, r in pts]))
            if lod is not None:
                series_psnr.append((name, col, [(x, (r.get("psnr_vs_off") or {}).get("psnr_db")) for x, r in pts]))
        xl = "camera distance k (bounding-box diagonals, log2 scale)"
        files = []
        f1 = f"a_{m}_ns_per_ray.svg"
        line_chart(os.path.join(img_dir, f1), f"{m}: render time per ray", xl, "ns per ray (median frame, 2 threads)", series_ns)
        f2 = f"a_{m}_nodes_per_ray.svg"
        line_chart(os.path.join(img_dir, f2), f"{m}: BVH nodes visited per ray", xl, "nodes visited per ray", series_nodes)
        f3 = f"a_{m}_psnr.svg"
        line_chart(os.path.join(img_dir, f3), f"{m}: PSNR against LoD off", xl, "PSNR (dB), crop region",
                   series_psnr, y_from_zero=False, identical_label="identical")
        rel = os.path.relpath(img_dir, out)
        for f, alt in ((f1, "time per ray"), (f2, "nodes per ray"), (f3, "PSNR")):
            files.append(f"![{m}: {alt}]({rel}/{f})")
        lines += ["\n\n".join(files), ""]
    lines += ["Time per ray is the median frame's wall time over the rays it traced (camera and shadow "
              "rays, 2 threads). In the PSNR plots, points on the dashed line are images identical to "
              "LoD off (no PSNR), staggered by a few pixels so that every series stays visible.", ""]
    return lines


def report_B(recs):
    rows = by(recs, type="row", section="B")
    if not rows:
        return []
    lines = ["SJ with shadows, 1 spp, boxes only. Culling applies to camera rays only. *speed-up* is "
             "against `--cull off` with the same LoD; \"same as cull off\" says whether culling changed "
             "any pixel of the crop.", ""]
    head = ["model", "k", "LoD", "cull"] + STAT_HEAD[:1] + ["speed-up vs cull off"] + STAT_HEAD[1:] + \
           ["PSNR dB vs LoD off", "same as cull off"]
    body = []
    auto = []
    for m in ordered_models(rows):
        for k in sorted_ks([r for r in rows if r["model"] == m]):
            kr = [r for r in rows if r["model"] == m and r["k"] == k]
            for lod in (None, 1.0):
                base = find(kr, lod=lod, cull="off")
                for cull in ("off", "on", "auto"):
                    r = find(kr, lod=lod, cull=cull)
                    if r is None:
                        continue
                    lead = [m, k, "off" if lod is None else fmt_num(lod), cull]
                    if not ok(r):
                        body.append(error_row(r, len(head), lead))
                        continue
                    s = r["stats"]
                    cu = s.get("culling") or {}
                    if cull == "auto":
                        lead[3] = "auto (%s)" % ("on" if cu.get("enabled") else "off")
                        if lod is None:
                            auto.append((m, k, cu.get("backfacing_fraction"), cu.get("enabled")))
                    sp = base["stats"]["render_seconds"] / s["render_seconds"] if ok(base) and s["render_seconds"] else None
                    same = "–"
                    if cull != "off" and r.get("psnr_vs_cull_off"):
                        c = r["psnr_vs_cull_off"]
                        same = "yes" if c.get("psnr_db") is None else "no (%d px, PSNR %.1f dB)" % (
                            c.get("differing_pixels", 0), c["psnr_db"])
                    sc = stat_cols(r)
                    body.append(lead + [sc[0], fmt_ratio(sp)] + sc[1:] + [fmt_psnr(r.get("psnr_vs_off")), same])
    t, dropped = md_table(head, body, DROPPABLE)
    lines += [t + dropped_note(dropped), ""]
    if auto:
        lines += ["What `--cull auto` measured (LoD off runs): the fraction of probe rays from around the "
                  "model whose first hit is a back face, and whether that turned culling on.", ""]
        t, _ = md_table(["model", "k", "backfacing fraction", "auto enables culling"],
                        [[m, k, "–" if f is None else f"{f:.4f}", "yes" if en else "no"] for m, k, f, en in auto])
        lines += [t, ""]
    return lines


def report_C(recs):
    rows = by(recs, type="row", section="C")
    if not rows:
        return []
    lines = ["SJ with shadows, 1 spp, culling off. `--sphere-from-level L`: nodes at depth ≥ L of the "
             "4-wide tree test bounding spheres instead of boxes (`never`: boxes only; `auto`: chosen per "
             "node by surface area). *speed vs boxes* is the `never` row's median frame time over this "
             "row's; PSNR is against LoD off with boxes only.", ""]
    for m in ordered_models(rows):
        mr = [r for r in rows if r["model"] == m]
        lines += [f"### {m}", ""]
        head = ["k", "LoD", "spheres from", "Mrays/s", "render ms", "speed vs boxes", "nodes/ray", "box tests/ray",
                "sphere tests/ray", "splat tests/ray", "LoD stops/ray", "sphere nodes / nodes", "PSNR dB vs LoD off"]
        body = []
        for k in sorted_ks(mr):
            kr = [r for r in mr if r["k"] == k]
            for lod in (None, 1.0):
                base = find(kr, lod=lod, sphere="never")
                for sph in SPHERE_LEVELS:
                    r = find(kr, lod=lod, sphere=sph)
                    if r is None:
                        continue
                    lead = [k, "off" if lod is None else fmt_num(lod), sph]
                    if not ok(r):
                        body.append(error_row(r, len(head), lead))
                        continue
                    s = r["stats"]
                    sp = base["stats"]["render_seconds"] / s["render_seconds"] if ok(base) and s["render_seconds"] else None
                    frac = f"{s['sphere_nodes']} / {s['nodes']}" if s.get("nodes") else "–"
                    ps = "ref" if lod is None and sph == "never" and (r.get("psnr_vs_off") or {}).get("psnr_db") is None \
                        else fmt_psnr(r.get("psnr_vs_off"))
                    body.append(lead + [fmt_sig(s["mrays_per_second"]), fmt_ms(s["render_seconds"]), fmt_ratio(sp),
                                        fmt_count(s["nodes_visited_per_ray"]), fmt_count(s["box_tests_per_ray"]),
                                        fmt_count(s["sphere_tests_per_ray"]), fmt_count(s["splat_tests_per_ray"]),
                                        fmt_count(s["lod_stops_per_ray"]), frac, ps])
        t, dropped = md_table(head, body, ("LoD stops/ray",))
        lines += [t + dropped_note(dropped), ""]
    return lines


def report_D(recs):
    rows = by(recs, type="row", section="D")
    if not rows:
        return []
    m = rows[0]["model"]
    lines = [f"{m}, SJ with shadows, culling off, boxes only. The reference is LoD off with 64 jittered "
             "samples per pixel (seed 1), close to the converged image; the test images use seed 0, so "
             "none of them shares its sample positions. *PSNR vs LoD off* compares with LoD off at the same "
             "spp (seed 0), as in section A.", ""]
    head = ["k", "config", "spp", "frames", "render ms", "Mrays/s", "nodes/ray", "LoD stops/ray",
            "PSNR dB vs reference", "PSNR dB vs LoD off"]
    body = []
    for k in sorted_ks(rows):
        for r in [r for r in rows if r["k"] == k]:
            c = r["cfg"]
            lead = [k, ("reference: " if r.get("role") == "reference" else "") + tau_label(c["lod"]), str(c["spp"])]
            if not ok(r):
                body.append(error_row(r, len(head), lead))
                continue
            s = r["stats"]
            fr = "1 (untimed)" if r["frames"] == 0 else str(r["frames"])
            vs_off = "–" if r.get("role") == "reference" else (
                "ref" if c["lod"] is None and (r.get("psnr_vs_off") or {}).get("psnr_db") is None else fmt_psnr(r.get("psnr_vs_off")))
            body.append(lead + [fr, fmt_ms(s["render_seconds"]), fmt_sig(s["mrays_per_second"]),
                                fmt_count(s["nodes_visited_per_ray"]), fmt_count(s["lod_stops_per_ray"]),
                                "–" if r.get("role") == "reference" else fmt_psnr(r.get("psnr_vs_truth")), vs_off])
    t, dropped = md_table(head, body, ("LoD stops/ray",))
    lines += [t + dropped_note(dropped), ""]
    return lines


def report_E(recs):
    rows = by(recs, type="row", section="E")
    if not rows:
        return []
    ver = next((r["embree"].get("embree") for r in rows if r.get("embree")), None)
    lines = [f"Primary rays only: pointray `--surface first-hit --no-shadows --cull off --sphere-from-level never`, "
             f"then right after each pointray configuration Embree {ver or ''} (`--geom oriented --crop --reps N`, "
             "oriented discs, `rtcIntersect1`, same prepared file, camera and frame count). Embree has no level of "
             "detail: it always intersects the input discs. *ratio* is pointray's Mrays/s over Embree's "
             "(median frames); PSNR compares pointray's τ image with its own LoD-off first-hit image.", ""]
    head = ["model", "k", "rays", "frames", "pointray", "pointray ms", "pointray Mrays/s", "Embree Mrays/s", "ratio",
            "nodes/ray", "splat tests/ray", "LoD stops/ray", "PSNR dB vs LoD off"]
    body = []
    for m in ordered_models(rows):
        for k in sorted_ks([r for r in rows if r["model"] == m]):
            for lod in (None, 0.5, 1.0):
                r = find([x for x in rows if x["model"] == m and x["k"] == k], lod=lod)
                if r is None:
                    continue
                lead = [m, k]
                if not ok(r):
                    body.append(error_row(r, len(head), lead))
                    continue
                s, e = r["stats"], r.get("embree")
                em = e.get("mrays_s") if e else None
                ratio = s["mrays_per_second"] / em if em else None
                ps = "ref" if lod is None and (r.get("psnr_vs_off") or {}).get("psnr_db") is None else fmt_psnr(r.get("psnr_vs_off"))
                body.append(lead + [str(s["primary_rays"]), str(r["frames"]), tau_label(lod), fmt_ms(s["render_seconds"]),
                                    fmt_sig(s["mrays_per_second"]), fmt_sig(em) if e else "failed" if "embree_error" in r else "–",
                                    fmt_ratio(ratio), fmt_count(s["nodes_visited_per_ray"]),
                                    fmt_count(s["splat_tests_per_ray"]), fmt_count(s["lod_stops_per_ray"]), ps])
    t, dropped = md_table(head, body, ("LoD stops/ray",))
    lines += [t + dropped_note(dropped), ""]
    mism = [r for r in rows if ok(r) and r.get("embree") and r["embree"].get("rays") != r["stats"]["primary_rays"]]
    if mism:
        lines += ["Ray counts differ between the renderers in: " + ", ".join(
            f"{r['model']} k={r['k']} ({r['stats']['primary_rays']} vs {r['embree'].get('rays')})" for r in mism) + ".", ""]
    return lines


def report_F(recs, img_dir, out):
    imgs = by(recs, type="image", section="F")
    if not imgs:
        return []
    rel = os.path.relpath(img_dir, out)
    lines = []
    for im in imgs:
        m = im["model"]
        so, st = im["stats_off"], im["stats_tau1"]
        if im["k"] == "1":
            f = im["files"]
            lines += [f"{m} at distance 1, {im['size']}×{im['size']}, SJ with shadows, 1 spp, culling off, boxes only. "
                      f"τ = 1 against LoD off: {psnr_phrase(im['psnr'])} over the crop, "
                      f"{im['psnr'].get('differing_pixels')} of {im['psnr'].get('pixels')} pixels differ; "
                      f"LoD stops/ray {fmt_count(st['lod_stops_per_ray'])}, nodes/ray "
                      f"{fmt_count(so['nodes_visited_per_ray'])} (off) and {fmt_count(st['nodes_visited_per_ray'])} (τ = 1).", "",
                      "| LoD off | τ = 1 |", "|---|---|",
                      f"| ![{m} LoD off]({rel}/{f[0]}) | ![{m} tau 1]({rel}/{f[1]}) |",
                      f"| ![{m} LoD off, nodes]({rel}/{f[2]}) | ![{m} tau 1, nodes]({rel}/{f[3]}) |", "",
                      "Second row: BVH nodes visited per pixel (camera and shadow rays), black = 0 to pale yellow = "
                      f"each image's own maximum: {so.get('nodes_visited_max_per_pixel')} with LoD off, "
                      f"{st.get('nodes_visited_max_per_pixel')} with τ = 1.", ""]
        else:
            reg = im["region"]
            lines += [f"{m} at distance 16, {im['size']}×{im['size']} frame: the model covers only the "
                      f"{reg['x1'] - reg['x0']}×{reg['y1'] - reg['y0']} pixel crop ({reg['x0']},{reg['y0']})–"
                      f"({reg['x1']},{reg['y1']}), shown {im['scale']}× magnified (nearest neighbour): "
                      f"LoD off | τ = 1 | |difference| × {im['gain']}. {psnr_phrase(im['psnr'], True)}, "
                      f"{im['psnr'].get('differing_pixels')} of {im['psnr'].get('pixels')} pixels differ "
                      f"(largest channel difference {im['psnr'].get('max_abs_diff')}); LoD stops/ray "
                      f"{fmt_count(st['lod_stops_per_ray'])}, nodes/ray {fmt_count(so['nodes_visited_per_ray'])} (off) "
                      f"and {fmt_count(st['nodes_visited_per_ray'])} (τ = 1).", "",
                      f"![{m} at distance 16: LoD off, tau 1, difference]({rel}/{im['files'][0]})", ""]
    return lines


def write_report(records, out):
    img_dir = os.path.join(out, IMAGES)
    os.makedirs(img_dir, exist_ok=True)
    runs = {r["run_id"]: r for r in records if r.get("type") == "run"}
    head = max(runs.values(), key=lambda r: r["run_id"]) if runs else {}
    secs = {r["section"]: r for r in records if r.get("type") == "section"}
    st = head.get("settings", {})
    lines = ["# Multiresolution BVH: level of detail, measured (thesis chapter 3)", ""]
    mach = head.get("machine", {})
    lines += [
        f"- Date: {head.get('date_utc', '?')}",
        f"- Machine: {mach.get('nproc', '?')} cores (`nproc`), {mach.get('cpu', '?')}"
        + (f", {mach['mem_gib']} GiB" if mach.get("mem_gib") else "") + "; shared and noisy, see the load lines",
        f"- pointray: commit {head.get('commit', '?')}, binary `{head.get('pointray', '?')}` "
        f"({head.get('pointray_version', '?')}, built {head.get('pointray_mtime', '?')})",
        f"- Embree bench: `{head.get('embree') or 'not found'}`",
        f"- Regenerate: `{head.get('command', '?')}` (tables and plots alone, from `{RESULTS}`: add `--report-only`)",
        f"- Settings: {st.get('size', '?')}×{st.get('size', '?')} frames, `--crop-to-model`, {st.get('threads', '?')} "
        f"threads, view direction (0.4, 0.3, 1), vertical field of view 60°; each timed configuration runs "
        f"`--bench-frames N` after one warm-up frame, N = max({st.get('min_frames', '?')}, ⌈{st.get('min_rays', 0):,.0f} / "
        f"rays per frame⌉)" + (" divided by 10 (`--quick`)" if st.get("quick") else "") + "; times are the median frame. "
        f"Configurations compared in one table block run in {st.get('rounds', 1)} interleaved rounds (each round runs "
        f"every configuration of the block once, Embree right after pointray's) and the median round is reported, so "
        f"that the shared machine's drift hits all of them alike.",
        "",
    ]
    models = {r["model"]: r for r in records if r.get("type") == "model"}
    if models:
        t, _ = md_table(["model", "file", "points", "BVH nodes", "bytes/node", "accel bytes/splat", "build s"],
                        [[m, f"`{r['source']}` (prepared)", f"{r['points']:,}", str(r["nodes"]), str(r["bytes_per_node"]),
                          f"{r['bytes_per_splat']:.1f}", fmt_sig(r["build_seconds"], 2)] for m, r in models.items()])
        lines += ["Models (prepared once with `pointray prepare`: Morton order, PCA normals, MST orientation, radii):", "", t, ""]
    lines += ["Definitions: τ (`--lod-threshold`) is in pixels: a subtree whose bounding sphere's radius is below τ "
              "times the ray's pixel footprint is replaced by its representative splat. Per-ray counts are averages "
              "over all rays traced (camera and shadow rays); *LoD stops* are subtrees cut off that way, *culled* "
              "subtrees skipped by the normal-cone test. PSNR is over the model's crop region only "
              "(`pointray compare --region`); \"identical\" means no pixel differs. k is the camera distance in "
              "bounding-box diagonals.", ""]
    builders = {"A": lambda: report_A(records, img_dir, out), "B": lambda: report_B(records),
                "C": lambda: report_C(records), "D": lambda: report_D(records), "E": lambda: report_E(records),
                "F": lambda: report_F(records, img_dir, out)}
    for sec in "ABCDEF":
        if sec not in secs and not by(records, section=sec):
            continue
        lines += section_header(sec, secs.get(sec), runs, head)
        lines += builders[sec]()
    path = os.path.join(out, REPORT)
    lines += kept_discussion(path)
    with open(path + ".tmp", "w") as f:
        f.write("\n".join(lines))
    os.replace(path + ".tmp", path)
    return path


def kept_discussion(path):
    """The hand-written "## Discussion" section of the report at `path`, kept across
    regenerations (it names the run it discusses); a heading for one if there is none yet."""
    if os.path.exists(path):
        with open(path) as f:
            text = f.read()
        at = text.find("\n## Discussion\n")
        if at >= 0:
            return [text[at + 1:].rstrip("\n"), ""]
    return ["## Discussion", "", "(to be written by whoever ran the experiments: what the tables show, and why)", ""]


# ----------------------------------------------------------------------------------------------
# Main


def load_records(path):
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n", 2)[2])
    ap.add_argument("--pointray", default=os.path.join(ROOT, "target", "release", "pointray"),
                    help="the binary (default target/release/pointray)")
    ap.add_argument("--embree", default=os.path.join(ROOT, "..", "shared", "bench", "embree", "bin", "embree_points_bench"),
                    help="Embree bench (default ../shared/bench/embree/bin/embree_points_bench; section E is "
                         "skipped with a note when missing)")
    ap.add_argument("--data", default=os.path.join(ROOT, "..", "shared", "data"), help="default ../shared/data")
    ap.add_argument("--models", default="dragon,bunny,buddha", help="default dragon,bunny,buddha")
    ap.add_argument("--dist", default="1,2,4,8,16", help="camera distances k (default 1,2,4,8,16)")
    ap.add_argument("--out", default=os.path.join(ROOT, "docs"), help="report directory (default docs)")
    ap.add_argument("--cache", default="/tmp/pointray-lod-cache", help="prepared models, kept between runs")
    ap.add_argument("--quick", action="store_true", help="a tenth of the frames")
    ap.add_argument("--sections", default="ABCDEF", help="subset to run; the others' results are kept")
    ap.add_argument("--threads", type=int, default=2, help="default 2")
    ap.add_argument("--size", type=int, default=1024, help="frame width and height (default 1024)")
    ap.add_argument("--min-rays", type=float, default=3e6, help="rays per timed configuration (default 3e6)")
    ap.add_argument("--min-frames", type=int, default=5, help="default 5")
    ap.add_argument("--rounds", type=int, default=3,
                    help="interleaved rounds per group of configurations; the median round is reported (default 3)")
    ap.add_argument("--keep-renders", action="store_true", help="keep the work directory of renders")
    ap.add_argument("--report-only", action="store_true", help="rebuild the report from the JSONL results")
    a = ap.parse_args()

    a.out = os.path.abspath(a.out)
    results = os.path.join(a.out, RESULTS)
    if a.report_only:
        recs = load_records(results)
        if not recs:
            sys.exit(f"no results in {results}")
        log(f"wrote {write_report(recs, a.out)}")
        return

    a.models = [m.strip() for m in a.models.split(",") if m.strip()]
    for m in a.models:
        if m not in MODELS:
            sys.exit(f"unknown model {m}; known: {', '.join(MODELS)}")
    a.dist = [k.strip() for k in a.dist.split(",") if k.strip()]
    for k in a.dist:
        if not float(k) > 0:
            sys.exit(f"bad distance {k}")
    sections = [s for s in a.sections.upper() if s in SECTIONS]
    if not os.path.exists(a.pointray):
        sys.exit(f"missing {a.pointray} (cargo build --release, or --pointray PATH)")
    a.pointray = os.path.abspath(a.pointray)
    a.embree = os.path.abspath(a.embree) if a.embree else None

    os.makedirs(os.path.join(a.out, IMAGES), exist_ok=True)
    # Keep the results of the sections not run now (and the runs they came from).
    old = load_records(results)
    kept = [r for r in old if r.get("section") and r.get("section") not in sections]
    kept_runs = {r.get("run_id") for r in kept}
    kept = [r for r in old if r.get("type") == "run" and r.get("run_id") in kept_runs] + kept
    kept += [r for r in old if r.get("type") == "model" and r.get("model") not in a.models]
    records = list(kept)

    def flush():
        tmp = results + ".tmp"
        with open(tmp, "w") as f:
            for r in records:
                f.write(json.dumps({k: v for k, v in r.items() if k != "png"}) + "\n")
        os.replace(tmp, results)

    def emit(rec, update=False):
        if not update:
            records.append(rec)
        flush()

    run_id = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%S")
    script = os.path.relpath(os.path.abspath(__file__), ROOT)
    try:
        version = subprocess.run([a.pointray, "--version"], capture_output=True, text=True).stdout.strip()
    except OSError:
        version = "?"
    mtime = datetime.datetime.fromtimestamp(os.path.getmtime(a.pointray), datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    emit({"type": "run", "run_id": run_id, "date_utc": utc_now(), "machine": machine(), "commit": git_commit(),
          "pointray": a.pointray, "pointray_version": version, "pointray_mtime": mtime,
          "embree": a.embree if a.embree and os.path.exists(a.embree) else None,
          "command": shlex.join(["python3", script] + sys.argv[1:]),
          "settings": {"size": a.size, "threads": a.threads, "quick": a.quick, "min_rays": a.min_rays,
                       "min_frames": a.min_frames, "rounds": a.rounds, "models": a.models, "dist": a.dist, "sections": sections}})

    work = tempfile.mkdtemp(prefix="pointray-lod-")
    r = Runner(a, work, emit)
    t_all = time.time()
    try:
        for m in a.models:
            r.prepared(m)
        for sec in sections:
            load = load_snapshot()
            log(f"== section {sec}: load {load}")
            secrec = {"type": "section", "section": sec, "run_id": run_id, "started_utc": utc_now(), "load": load}
            records.append(secrec)
            t0 = time.time()
            note = SECTIONS[sec](r, a)
            secrec["wall_seconds"] = round(time.time() - t0, 1)
            if note:
                secrec["note"] = note
                log(f"section {sec}: {note}")
            flush()
            write_report(records, a.out)
    finally:
        if a.keep_renders:
            log(f"renders kept in {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    path = write_report(records, a.out)
    log(f"{r.count} pointray renders, {time.time() - t_all:.0f} s; wrote {path} and {results}")


if __name__ == "__main__":
    main()
