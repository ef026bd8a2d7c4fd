"""pointray.dask on a LocalCluster of two worker processes, started here: the frames it renders
are pointray.render's, bit for bit, a worker killed midway included."""

import os
import signal

import numpy as np
import pytest

import pointray

distributed = pytest.importorskip("dask.distributed")
import pointray.dask  # noqa: E402 - after the skip: it needs dask

from test_pointray import needs_ffmpeg, sphere_points, video_frames  # noqa: E402


def cluster(workers=2):
    return distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0")


@pytest.fixture(scope="module")
def client():
    with cluster() as c, distributed.Client(c) as client:
        yield client


@pytest.fixture(scope="module")
def sphere_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("dask") / "sphere.xyz"
    np.savetxt(path, sphere_points(), fmt="%.9f")
    return path


def test_a_frame_in_tiles_is_the_render_and_each_worker_opens_the_scene_once(client, sphere_file, tmp_path):
    options = {"width": 200, "height": 150, "spp": 4, "surface": "sj"}
    expected = pointray.render(str(sphere_file), **options)
    # Tiles that do not divide the frame, of both kinds of source.
    prs = tmp_path / "sphere.prs"
    pointray.prepare_file(str(sphere_file), str(prs), surface="sj")
    for source in (sphere_file, prs):
        image = pointray.dask.render(client, source, tile=(64, 48), **options)
        assert image.dtype == np.float32 and np.array_equal(image, expected), source
    again = pointray.dask.render(client, prs, tile=100, **{**options, "spp": 1})
    assert np.array_equal(again, pointray.render(str(prs), **{**options, "spp": 1}))
    # Two sources, one build each: two scenes on each worker, however many tiles.
    assert set(client.run(lambda: pointray.dask.opened).values()) == {2}


def test_a_worker_killed_midway_changes_no_pixel(sphere_file):
    options = {"width": 1024, "height": 1024, "spp": 8}
    expected = pointray.render(str(sphere_file), **options)
    with cluster() as c, distributed.Client(c) as client:
        pids = client.run(os.getpid)
        victim = sorted(pids.values())[0]
        killed = []

        def progress(done, total):
            if not killed:
                os.kill(victim, signal.SIGKILL)
                killed.append(done)

        image = pointray.dask.render(client, sphere_file, tile=64, progress=progress, **options)
        assert np.array_equal(image, expected)
        # The worker died midway (its nanny started another), so its tiles were rendered again.
        client.wait_for_workers(2, timeout=60)
        now = set(client.run(os.getpid).values())
        assert killed and victim not in now and len(now) == 2, (pids, now)


def test_an_orbit_turns_the_view_and_frames_are_their_renders(client, sphere_file):
    frames = pointray.dask.render_frames(client, sphere_file, orbit=4, width=128, height=128)
    assert len(frames) == 4
    assert all(not np.array_equal(a, b) for i, a in enumerate(frames) for b in frames[i + 1 :])
    scene = pointray.prepare(str(sphere_file))
    views = scene.turntable(4, width=128, height=128)
    for frame, view in zip(frames, views):
        assert np.array_equal(frame, pointray.render(scene, width=128, height=128, **view))
    assert np.array_equal(frames[0], pointray.render(scene, width=128, height=128)), "frame 0 is the view"
    eyes = [{"eye": [10.0, 20.0, 36.0 + k], "look_at": [10.0, 20.0, 30.0]} for k in range(2)]
    done = []
    shots = pointray.dask.render_frames(
        client, sphere_file, frames=eyes, width=64, height=48, progress=lambda d, t: done.append((d, t))
    )
    for shot, eye in zip(shots, eyes):
        assert np.array_equal(shot, pointray.render(scene, width=64, height=48, **eye))
    assert done[-1] == (2, 2)


@needs_ffmpeg
def test_frames_arriving_in_any_order_go_into_a_video_in_theirs(client, sphere_file, tmp_path):
    video = tmp_path / "orbit.mp4"
    assert pointray.dask.render_frames(client, sphere_file, orbit=5, width=64, height=48, output=video, fps=10) is None
    assert video_frames(video) == (5, (64, 48))
    # In order whatever the order of arrival: frames given out of turn wait for theirs.
    written = []
    take = pointray.dask._in_order(written.append, {"a": 0, "b": 1, "c": 2})

    class Done:
        def __init__(self, key):
            self.key = key

        def release(self):
            pass

    for key, frame in (("c", 2), ("a", 0), ("b", 1)):
        take(Done(key), frame)
    assert written == [0, 1, 2]


def test_a_scene_files_animation_renders_frame_by_frame(client, sphere_file, tmp_path):
    scene_file = tmp_path / "fly.toml"
    scene_file.write_text(
        f"""
[camera]
eye = [10.0, 20.0, 36.0]
look_at = [10.0, 20.0, 30.0]

[render]
width = 64
height = 48

[[cloud]]
file = "{sphere_file.as_posix()}"

[animation]
frames = 6

[[animation.keyframe]]
eye = [10.0, 20.0, 36.0]
look_at = [10.0, 20.0, 30.0]

[[animation.keyframe]]
eye = [14.0, 22.0, 34.0]
look_at = [10.0, 20.0, 30.0]
fov = 30.0

[[animation.keyframe]]
eye = [16.0, 20.0, 30.0]
look_at = [10.0, 20.0, 30.0]
"""
    )
    scene = pointray.prepare(str(scene_file))
    assert scene.frames == 6
    # Frame numbers as numpy gives them, too.
    frames = pointray.dask.render_frames(client, scene_file, frames=np.array([0, 2, 5]), width=64, height=48)
    for frame, k in zip(frames, [0, 2, 5]):
        assert np.array_equal(frame, pointray.render(scene, **scene.animation_frame(k)))
    assert np.array_equal(frames[0], pointray.render(scene)), "the first keyframe is the camera"
    assert scene.animation_frame(5)["eye"] == [16.0, 20.0, 30.0], "the last frame is the last keyframe"
    with pytest.raises(ValueError, match="frame 6: the animation has 6"):
        scene.animation_frame(6)
    with pytest.raises(ValueError, match="no \\[animation\\]"):
        pointray.prepare(str(sphere_file)).animation_frame(0)


def test_an_interrupted_render_cancels_the_tiles_left(client, sphere_file):
    import time

    def interrupt(done, total):
        raise KeyboardInterrupt

    # The traceback, kept, holds the tiles' futures: only cancelling them frees the scheduler.
    with pytest.raises(KeyboardInterrupt) as interrupted:
        pointray.dask.render(client, sphere_file, width=512, height=512, spp=4, tile=32, progress=interrupt)

    def tasks(dask_scheduler):
        return sum(key.startswith("pointray-tile-") for key in map(str, dask_scheduler.tasks))

    deadline = time.monotonic() + 10
    while client.run_on_scheduler(tasks) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert client.run_on_scheduler(tasks) == 0, "tiles left on the scheduler"
    del interrupted  # held until here on purpose (see above)


def test_a_source_a_worker_cannot_read_is_named_with_the_worker(client, tmp_path):
    missing = tmp_path / "nowhere.ply"
    with pytest.raises(OSError, match=r"2 of the workers: worker tcp://.*nowhere\.ply"):
        pointray.dask.render(client, missing, width=32, height=32)
    with pytest.raises(TypeError, match="give a path every worker can read"):
        pointray.dask.render(client, pointray.Cloud(sphere_points()), width=32, height=32)
    with pytest.raises(ValueError, match="either frames .* or orbit"):
        pointray.dask.render_frames(client, missing)
    with pytest.raises(ValueError, match="surface change the scene's build"):
        pointray.dask.render_frames(client, missing, frames=[{"surface": "sj"}])


def test_workers_read_a_scene_file_at_a_url_by_ranges(client, tmp_path):
    pytest.importorskip("fsspec")
    from ranged_http import RangedServer

    # Large enough that opening it leaves treelets for the tiles to fetch.
    np.savetxt(tmp_path / "sphere.xyz", sphere_points(n=100_000), fmt="%.9f")
    pointray.prepare_file(str(tmp_path / "sphere.xyz"), str(tmp_path / "sphere.prs"))
    options = {"width": 160, "height": 120, "spp": 2}
    expected = pointray.render(str(tmp_path / "sphere.prs"), **options)
    with RangedServer(tmp_path) as server:
        image = pointray.dask.render(client, server.url("sphere.prs"), tile=48, **options)
        assert np.array_equal(image, expected)
        # Each worker fetched what its tiles read: at most the file each.
        assert 0 < server.sent <= 2 * (tmp_path / "sphere.prs").stat().st_size
        with pytest.raises(OSError, match=r"2 of the workers: worker tcp://.*nowhere\.prs"):
            pointray.dask.render(client, server.url("nowhere.prs"), width=32, height=32)
        # A fetch failing midway: the task that met it is run again on the scene opened anew.
        again = {**options, "spp": 1}
        expected = pointray.render(str(tmp_path / "sphere.prs"), **again)
        client.run(lambda: pointray.dask._scene.cache_clear())
        pointray.dask._open_everywhere(client, pointray.dask._scene_key(server.url("sphere.prs"), again))
        server.fail_next(1)
        image = pointray.dask.render(client, server.url("sphere.prs"), tile=48, **again)
        assert server.httpd.failures == 0, "a tile's fetch failed"
        assert np.array_equal(image, expected)


def test_workers_on_either_kernel_path_render_the_same_pixels(sphere_file, monkeypatch):
    options = {"width": 96, "height": 80, "spp": 2, "surface": "sj", "lod_threshold": 1.0}
    expected = pointray.render(str(sphere_file), **options)
    best = pointray.render_frame(str(sphere_file), width=8, height=8).stats["isa"]

    def path():
        return pointray.render_frame(str(sphere_file), width=8, height=8).stats["isa"]

    for isa in ("baseline", "auto"):
        # The variable the kernel path is forced by, which the worker processes inherit.
        monkeypatch.setenv("POINTRAY_ISA", isa)
        with cluster(1) as c:
            client = distributed.Client(c)
            assert client.run(path).popitem()[1] == ("baseline" if isa == "baseline" else best)
            assert np.array_equal(pointray.dask.render(client, sphere_file, tile=32, **options), expected), isa
            client.close()
