"""The Python package against the command line and the library's oracle. The CLI binary is
$POINTRAY_BIN (CI sets it to the one the Rust tests built); tests that need it skip without."""

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import pointray

BIN = os.environ.get("POINTRAY_BIN")


def sphere_points(n=3000, seed=7):
    """Points on a unit sphere about (10, 20, 30), away from the origin on purpose."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v + np.array([10.0, 20.0, 30.0])


@pytest.fixture
def sphere_file(tmp_path):
    path = tmp_path / "sphere.xyz"
    np.savetxt(path, sphere_points(), fmt="%.9f")
    return path


def cli_png(tmp_path, args):
    from PIL import Image

    out = tmp_path / "cli.png"
    subprocess.run([BIN, "-q", "render", *map(str, args), "-o", str(out)], check=True)
    return np.asarray(Image.open(out).convert("RGB"))


@pytest.mark.skipif(not BIN, reason="POINTRAY_BIN not set")
@pytest.mark.parametrize(
    "options",
    [
        {},
        {"surface": "first-hit", "spp": 2, "lod_threshold": 1.0},
        {"tonemap": "filmic", "exposure": 1.0, "sky": True, "ground": True},
    ],
)
def test_the_python_image_is_the_cli_png(tmp_path, sphere_file, options):
    flags = []
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        flags += [flag] if value is True else [flag, value]
    expected = cli_png(tmp_path, [sphere_file, "--width", 96, "--height", 80, *flags])
    image = pointray.render(str(sphere_file), width=96, height=80, **options)
    assert image.shape == (80, 96, 3) and image.dtype == np.float32
    tone = {k: options[k] for k in ("tonemap", "exposure") if k in options}
    assert np.array_equal(pointray.to_srgb8(image, **tone), expected)


@pytest.mark.skipif(not BIN, reason="POINTRAY_BIN not set")
def test_a_scene_file_renders_and_answers_as_its_cloud(tmp_path, sphere_file):
    stored = tmp_path / "sphere.prs"
    subprocess.run([BIN, "-q", "prepare", str(sphere_file), "-o", str(stored)], check=True)
    cloud, scene = pointray.prepare(str(sphere_file)), pointray.prepare(str(stored))
    # Saved from Python, the same file.
    cloud.save(str(tmp_path / "saved.prs"))
    assert (tmp_path / "saved.prs").read_bytes() == stored.read_bytes()
    with pytest.raises(ValueError, match="only a BVH"):
        pointray.prepare(str(sphere_file), accel="kdtree").save(str(tmp_path / "kd.prs"))
    assert not (tmp_path / "kd.prs").exists()
    assert len(scene) == len(cloud) == 3000
    options = dict(width=64, height=48, spp=2)
    assert np.array_equal(pointray.render(scene, **options), pointray.render(cloud, **options))
    origins, directions = cloud.camera_rays(width=40, height=32)
    rays = (origins.reshape(-1, 3), directions.reshape(-1, 3))
    for a, b in zip(scene.intersect(*rays), cloud.intersect(*rays)):
        assert np.array_equal(a, b, equal_nan=True)
    with pytest.raises(ValueError, match="accel"):
        pointray.render(scene, accel="kdtree", **options)


def test_a_scene_file_is_prepared_in_memory_or_out_of_core_alike(tmp_path):
    """prepare_file writes the file `pointray prepare` writes, the same bytes out of core (a
    budget of 1 KiB) as in memory; a list of paths is a survey's tiles, read as one cloud."""
    west, east = tmp_path / "west.xyz", tmp_path / "east.xyz"
    points = sphere_points(4000)
    np.savetxt(west, points[:2000], fmt="%.9f")
    np.savetxt(east, points[2000:], fmt="%.9f")
    whole = pointray.prepare_file([west, east], tmp_path / "memory.prs")
    assert whole == {"points": 4000, "chunks": None, "parts": 1, "bytes": (tmp_path / "memory.prs").stat().st_size}
    assert len(pointray.prepare([str(west), str(east)])) == 4000
    # Out of core takes binary PLY and LAS: the tiles as PLYs, then both ways.
    plys = []
    for name, part in (("west", points[:2000]), ("east", points[2000:])):
        plys.append(tmp_path / f"{name}.ply")
        header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(part)}\n"
        header += "property double x\nproperty double y\nproperty double z\nend_header\n"
        plys[-1].write_bytes(header.encode() + part.astype("<f8").tobytes())
    for options in ({}, {"surface": "rfd", "color_by": "elevation"}):
        memory = pointray.prepare_file(plys, tmp_path / "a.prs", **options)
        streamed = pointray.prepare_file(plys, tmp_path / "b.prs", memory_budget=1024, **options)
        assert memory["chunks"] is None and streamed["chunks"] == 1 and memory["parts"] == streamed["parts"] == 1
        assert (tmp_path / "a.prs").read_bytes() == (tmp_path / "b.prs").read_bytes()
    with pytest.raises(ValueError, match="accel"):
        pointray.prepare_file(plys, tmp_path / "c.prs", memory_budget=1024, accel="kdtree")
    with pytest.raises(TypeError, match="list of paths"):
        pointray.prepare_file(42, tmp_path / "d.prs")
    assert not (tmp_path / "c.prs").exists() and not (tmp_path / "d.prs").exists()


def test_a_cloud_from_numpy_renders_like_its_file(sphere_file):
    read = pointray.read_cloud(sphere_file)
    assert len(read) == 3000 and read.normals is None
    np.testing.assert_allclose(read.positions, sphere_points(), atol=1e-6)
    rebuilt = pointray.Cloud(read.positions)
    a = pointray.render(str(sphere_file), width=48, height=40)
    b = pointray.render(rebuilt, width=48, height=40)
    assert np.array_equal(a, b)
    assert (a.max(axis=2) > 0.05).mean() > 0.1, "the sphere shows"


def test_scan_attributes_round_trip_and_colour_the_points(sphere_file):
    points = sphere_points()
    up = points[:, 1] > 20.0
    classes = np.where(up, 6, 9).astype(np.uint8)
    cloud = pointray.Cloud(points, intensity=points[:, 1], classification=classes)
    assert np.array_equal(cloud.classification, classes) and cloud.classification.dtype == np.uint8
    np.testing.assert_allclose(cloud.intensity, points[:, 1].astype(np.float32))
    assert cloud.gps_time is None and pointray.read_cloud(sphere_file).classification is None
    image = pointray.render(cloud, width=64, height=48, color_by="classification", classes=[9])
    lit = image.max(axis=2) > 0.02
    assert lit.sum() > 100 and (image[lit][:, 2] > image[lit][:, 0]).mean() > 0.95, "water alone: blue"
    lower = pointray.prepare(cloud, clip_planes=[{"normal": (0, 1, 0), "offset": 20.0}])
    assert len(lower) == int((points[:, 1] <= 20.0).sum())
    boxed = pointray.prepare(cloud, clip_box={"min": (9, 19, 29), "max": (11, 21, 30)})
    assert len(boxed) == int((points[:, 2] <= 30.0).sum())
    with pytest.raises(ValueError, match="color_by rgb: the cloud has no colours"):
        pointray.render(cloud, width=8, height=8, color_by="rgb")
    with pytest.raises(ValueError, match="classification: 2 values for 3000 points"):
        pointray.Cloud(points, classification=classes[:2])


def test_columns_name_a_text_layout(tmp_path):
    path = tmp_path / "scan.txt"
    points = sphere_points(500)
    np.savetxt(path, np.hstack([points, np.full((500, 1), 42.0), np.full((500, 1), 6.0)]), fmt="%.6f")
    cloud = pointray.read_cloud(path, columns="x,y,z,i,c")
    assert np.all(cloud.intensity == 42.0) and np.all(cloud.classification == 6)
    scene = pointray.prepare(str(path), columns="x,y,z,i,c", color_by="classification")
    assert len(scene) == 500
    with pytest.raises(ValueError, match="columns: unknown column 'q'"):
        pointray.read_cloud(path, columns="x,y,q")


def test_a_region_is_that_part_of_the_frame(sphere_file):
    scene = pointray.prepare(str(sphere_file))
    whole = pointray.render(scene, width=64, height=48, spp=2)
    tile = pointray.render_region(scene, (10, 5, 40, 30), width=64, height=48, spp=2)
    assert np.array_equal(tile, whole[5:30, 10:40])


def test_intersect_meets_the_depth_of_the_camera_rays(sphere_file):
    scene = pointray.prepare(str(sphere_file))
    options = dict(width=40, height=32, lod_threshold=0.0)
    frame = pointray.render_frame(scene, aovs=["depth"], **options)
    origins, directions = scene.camera_rays(**options)
    t, splat, normal = scene.intersect(origins.reshape(-1, 3), directions.reshape(-1, 3))
    depth = frame.aov("depth").reshape(-1)
    assert np.isfinite(depth).sum() > 200
    assert np.array_equal(t, depth)
    assert ((splat >= 0) == np.isfinite(t)).all() and splat.max() < len(scene)
    hit = np.isfinite(t)
    np.testing.assert_allclose(np.linalg.norm(normal[hit], axis=1), 1.0, atol=1e-5)


def test_intersect_agrees_with_the_brute_force_oracle(sphere_file):
    cloud = pointray.read_cloud(sphere_file)
    rng = np.random.default_rng(3)
    origins = np.array([10.0, 20.0, 30.0]) + 3.0 * rng.normal(size=(2000, 3))
    directions = np.array([10.0, 20.0, 30.0]) + 0.5 * rng.normal(size=(2000, 3)) - origins
    results = [
        pointray.prepare(cloud, accel=accel).intersect(origins, directions) for accel in ("bvh", "kdtree", "brute")
    ]
    assert np.isfinite(results[0][0]).sum() > 500
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def test_intersect_and_prepare_take_threads(sphere_file):
    scene = pointray.prepare(str(sphere_file), threads=1)
    origins, directions = scene.camera_rays(width=24, height=16)
    o, d = origins.reshape(-1, 3), directions.reshape(-1, 3)
    one = scene.intersect(o, d, threads=1)
    every = scene.intersect(o, d)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(one, every))
    with pytest.raises(ValueError, match="threads must be between 1 and 1024"):
        scene.intersect(o, d, threads=0)


def test_statistics_are_a_dict(sphere_file):
    frame = pointray.render_frame(str(sphere_file), width=32, height=32, count_work=True)
    stats = frame.stats
    assert stats["width"] == 32 and stats["accel"] == "bvh" and stats["rays"] > 0
    assert stats["nodes_visited_per_ray"] > 0


def test_bad_input_raises_with_the_cli_message(tmp_path):
    with pytest.raises(OSError, match="missing.ply"):
        pointray.render(str(tmp_path / "missing.ply"))
    garbage = tmp_path / "garbage.ply"
    garbage.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\nx\n")
    with pytest.raises(ValueError, match="garbage.ply"):
        pointray.read_cloud(garbage)
    with pytest.raises(ValueError, match="spp must be at least 1"):
        pointray.render(pointray.Cloud(sphere_points()), spp=0)
    with pytest.raises(ValueError, match="unknown field `sp`"):
        pointray.render(pointray.Cloud(sphere_points()), sp=4)
    with pytest.raises(ValueError, match="expected a Nx3"):
        pointray.Cloud(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="surface"):
        scene = pointray.prepare(pointray.Cloud(sphere_points()))
        pointray.render(scene, surface="rfd")


def test_a_scene_renders_again_with_other_settings(sphere_file):
    scene = pointray.prepare(str(sphere_file), surface="sj")
    a = pointray.render(scene, width=32, height=24)
    b = pointray.render(scene, width=32, height=24, surface="first-hit")
    assert a.shape == b.shape and not np.array_equal(a, b)
    assert np.array_equal(a, pointray.render(scene, width=32, height=24)), "deterministic"


def test_ctrl_c_interrupts_a_render(tmp_path, sphere_file):
    import signal
    import sys
    import time

    script = (
        "import pointray, sys\n"
        "scene = pointray.prepare(sys.argv[1])\n"
        "print('rendering', flush=True)\n"
        "pointray.render(scene, width=4096, height=4096, spp=256)\n"
    )
    child = subprocess.Popen(
        [sys.executable, "-c", script, str(sphere_file)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert child.stdout.readline().strip() == "rendering"
    time.sleep(0.5)
    child.send_signal(signal.SIGINT)
    start = time.monotonic()
    _, stderr = child.communicate(timeout=60)
    assert "KeyboardInterrupt" in stderr, stderr
    assert time.monotonic() - start < 10, "the render stopped soon after the signal"


BUNNY = Path(__file__).resolve().parents[4] / "shared/data/stanford/bunny/reconstruction/bun_zipper.ply"


@pytest.mark.skipif(not BIN or not BUNNY.exists(), reason="needs POINTRAY_BIN and ../shared/data")
def test_the_bunny_is_the_cli_png(tmp_path):
    expected = cli_png(tmp_path, [BUNNY, "--width", 192, "--height", 160])
    assert np.array_equal(pointray.to_srgb8(pointray.render(str(BUNNY), width=192, height=160)), expected)


def test_threads_change_no_pixel_and_progress_reaches_the_total(sphere_file):
    scene = pointray.prepare(str(sphere_file))
    calls = []
    one = pointray.render(scene, width=64, height=48, spp=2, threads=1, progress=lambda done, total: calls.append((done, total)))
    assert np.array_equal(one, pointray.render(scene, width=64, height=48, spp=2))
    assert calls and calls[-1] == (64 * 48, 64 * 48)
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:]))
    with pytest.raises(ValueError, match="threads"):
        pointray.render(scene, width=8, height=8, threads=0)

    def stop(done, total):
        raise RuntimeError("enough")

    with pytest.raises(RuntimeError, match="enough"):
        pointray.render(scene, width=64, height=48, progress=stop)


def write_hdr(path, texels):
    """A flat Radiance picture of linear RGB texels (H x W x 3, each channel's value a few
    bits of mantissa, so that it is stored exactly)."""
    h, w, _ = texels.shape
    out = bytearray(f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode())
    for r, g, b in texels.reshape(-1, 3):
        e = int(np.floor(np.log2(max(r, g, b)))) + 1
        out += bytes([int(c * 256 / 2**e) for c in (r, g, b)] + [e + 128])
    path.write_bytes(bytes(out))


@pytest.mark.skipif(not BIN, reason="POINTRAY_BIN not set")
def test_an_environment_map_renders_as_on_the_command_line(tmp_path, sphere_file):
    rows = 0.5 + 0.25 * np.arange(8)[::-1]
    hdr = tmp_path / "sky.hdr"
    write_hdr(hdr, np.repeat(rows[:, None, None], 16, axis=1).repeat(3, axis=2))
    flags = ["--env-map", hdr, "--integrator", "path", "--spp", 4]
    expected = cli_png(tmp_path, [sphere_file, "--width", 48, "--height", 40, *flags])
    options = {"env_map": str(hdr), "integrator": "path", "spp": 4}
    image = pointray.render(str(sphere_file), width=48, height=40, **options)
    assert np.array_equal(pointray.to_srgb8(image), expected)
    scene = pointray.prepare(str(sphere_file))
    with pytest.raises(ValueError, match="give it there"):
        pointray.render(scene, env_map=str(hdr))
    with pytest.raises(OSError, match="missing.hdr"):
        pointray.render(str(sphere_file), env_map=str(tmp_path / "missing.hdr"))


def video_frames(path):
    """The number of frames ffprobe counts in the video at `path`."""
    probe = ["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0"]
    probe += ["-show_entries", "stream=nb_read_frames,width,height", "-of", "csv=p=0", str(path)]
    width, height, frames = subprocess.run(probe, check=True, capture_output=True, text=True).stdout.strip().split(",")
    return int(frames), (int(width), int(height))


needs_ffmpeg = pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg not installed")


@needs_ffmpeg
def test_frames_become_a_video_whole_or_not_at_all(tmp_path, sphere_file, monkeypatch):
    scene = pointray.prepare(str(sphere_file))
    out = tmp_path / "videos"
    out.mkdir()
    views = scene.turntable(3, width=33, height=24)
    with pointray.VideoWriter(out / "turn.mp4", fps=12) as video:
        for view in views:
            video.write(pointray.render(scene, width=33, height=24, **view))
    assert video_frames(out / "turn.mp4") == (3, (34, 24)), "odd sizes padded to even"
    with pytest.raises(ValueError, match="closed"):
        video.write(np.zeros((24, 33, 3), dtype=np.float32))
    video.close()
    # An error inside the writer's block, or a frame of another size: no video.
    with pytest.raises(ZeroDivisionError), pointray.VideoWriter(out / "broken.mp4") as video:
        video.write(np.zeros((24, 33, 3), dtype=np.float32))
        1 / 0
    with pytest.raises(ValueError, match="as the first frame"), pointray.VideoWriter(out / "sizes.mp4") as video:
        video.write(np.zeros((24, 33, 3), dtype=np.float32))
        video.write(np.zeros((24, 32, 3), dtype=np.float32))
    assert sorted(p.name for p in out.iterdir()) == ["turn.mp4"]
    with pytest.raises(ValueError, match="no frames"), pointray.VideoWriter(out / "empty.mp4"):
        pass
    monkeypatch.setenv("POINTRAY_FFMPEG", "/nonexistent/ffmpeg")
    with pytest.raises(OSError, match="ffmpeg not found"):
        pointray.VideoWriter(out / "none.mp4")
