"""Rendering on a Dask cluster: a frame split into tiles, or a sequence of frames, each a task.

>>> from dask.distributed import Client
>>> import pointray.dask
>>> client = Client()                         # a LocalCluster here; a cluster's scheduler address
>>> image = pointray.dask.render(client, "survey.prs", width=2048, height=1536, spp=16)
>>> frames = pointray.dask.render_frames(client, "survey.prs", orbit=120, width=1280, height=720)

Every worker opens the source once (a ``.prs`` scene file is memory-mapped, a cloud file
prepared) from a path every worker can read, or a scene file's URL (an object store, an HTTP
server: each worker fetches the parts of the file its tiles' rays enter, by range requests,
``pointray._remote``), and keeps it for the tasks it is given. A pixel
does not depend on the worker that renders it (each pixel seeds its own samples), so the image
is ``pointray.render``'s for the same options, bit for bit, and a task run again after its
worker died changes nothing. Workers on the same kernel path (AVX2, or the baseline SSE/NEON
one; ``POINTRAY_ISA=baseline`` forces it) give the same bits; across paths, images agree bit for
bit too, the disk tests doing the same arithmetic in the same order on each (no FMA).
"""

from __future__ import annotations

import functools
import numbers
import os
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

import pointray
from pointray._remote import is_url

Path = Union[str, "os.PathLike[str]"]
Progress = Union[bool, Callable[[int, int], Any], None]

#: The options of a scene's preprocessing, which only ``prepare`` takes.
PREPROCESS_OPTIONS = frozenset({"k_normals", "k_radius", "radius_scale", "recompute", "strays", "outlier_std", "columns"})
#: The options a scene is prepared with: its preprocessing, and the build the library checks a
#: render against (`Scene::check_build`) and the environment map. The others are a render's
#: own, free to change from task to task.
PREPARE_OPTIONS = PREPROCESS_OPTIONS | {
    "accel", "sphere_from_level", "surface", "color_by", "classes", "exclude_classes", "clip_box", "clip_planes",
    "up", "env_map",
}  # fmt: skip

#: Scenes this process opened (a worker's count, for the tests: one a source and build).
opened = 0
#: How often a task is run again after it raised (a scene file at a URL that could not be
#: fetched is opened again for the retry); a worker's death is Dask's to reschedule.
RETRIES = 2


def render(
    client: Any,
    source: Union[Path, Sequence[Path]],
    *,
    width: int = 800,
    height: int = 600,
    tile: Union[int, Tuple[int, int]] = 128,
    progress: Progress = None,
    **options: Any,
) -> np.ndarray:
    """The linear RGB image (H x W x 3 float32) ``pointray.render(source, width=..., height=...,
    **options)`` gives, rendered as tiles of ``tile`` pixels (a side, or (width, height)) on the
    workers of ``client`` (a ``dask.distributed.Client``).

    ``source``: a path (or a survey's tiles) every worker can read at the same place, or the
    URL of a scene file (``https://``, ``s3://``, ...; fsspec's credentials on the workers). ``progress``:
    True for a tqdm bar, or a callable given (pixels done, pixels in all) as tiles arrive.
    Interrupting the call (Ctrl-C) cancels the tiles not yet rendered. ``threads`` (a task's
    render threads) defaults to all the cores of the worker's machine: start one worker a
    machine, with one thread.
    """
    key = _scene_key(source, options)
    _open_everywhere(client, key)
    regions = _regions(width, height, tile)
    token = os.urandom(6).hex()
    futures = [
        client.submit(
            _render_tile, key, region, width, height, options, key=f"pointray-tile-{token}-{i}", retries=RETRIES
        )
        for i, region in enumerate(regions)
    ]
    image = np.zeros((height, width, 3), dtype=np.float32)
    place = dict(zip((f.key for f in futures), regions))

    def paste(future: Any, tile: np.ndarray) -> int:
        x0, y0, x1, y1 = place[future.key]
        image[y0:y1, x0:x1] = tile
        return (x1 - x0) * (y1 - y0)

    _gather(client, futures, paste, progress, width * height, "px")
    return image


def render_frames(
    client: Any,
    source: Union[Path, Sequence[Path]],
    *,
    frames: Optional[Sequence[Union[int, Dict[str, Any]]]] = None,
    orbit: Optional[int] = None,
    width: int = 800,
    height: int = 600,
    progress: Progress = None,
    output: Optional[Path] = None,
    fps: float = 30.0,
    **options: Any,
) -> Optional[List[np.ndarray]]:
    """Frames of one scene, each a task on the workers of ``client``: ``orbit=N``, a turntable of
    N frames (the camera turned about the up axis by 360/N degrees a frame, as ``pointray
    render --turntable N`` turns it; frame 0 is the view ``options`` give); or ``frames``, each
    a frame number of the scene file's ``[animation]`` (``range(scene.frames)`` for them all),
    or a dict of the frame's own options (``eye``, ``look_at``, ``fov``, ...) over ``options``.
    Each frame is ``pointray.render``'s for its options, bit for bit. ``progress`` counts
    frames; the rest as for `render`.

    ``output``: an MP4 to write the frames into, ``fps`` a second, in order as they arrive
    (``pointray.VideoWriter``, through the options' ``tonemap`` and ``exposure``); the frames
    are then let go once written, not returned (None), so that thousands of frames take the
    memory of those that arrive before their turn. No file where the render fails."""
    if (frames is None) == (orbit is None):
        raise ValueError("render_frames: give either frames (frame numbers or option dicts) or orbit (a frame count)")
    if orbit is not None and (not isinstance(orbit, int) or orbit < 1):
        raise ValueError(f"orbit: expected a positive frame count, got {orbit!r}")
    shots: List[Tuple[Dict[str, Any], Optional[Tuple[str, int, int]]]]
    if orbit is not None:
        shots = [({}, ("orbit", k, orbit)) for k in range(orbit)]
    else:
        shots = [({}, ("animation", int(f), 0)) if isinstance(f, numbers.Integral) else (dict(f), None) for f in frames]
        changed = sorted({k for f, _ in shots for k in f} & PREPARE_OPTIONS)
        if changed:
            raise ValueError(f"frames: {', '.join(changed)} change the scene's build; give them once, for all frames")
    key = _scene_key(source, options)
    _open_everywhere(client, key)
    # The video before the tasks: without ffmpeg, nothing is rendered for nothing.
    tone = {k: options[k] for k in ("tonemap", "exposure") if k in options}
    video = None if output is None else pointray.VideoWriter(output, fps=fps, **tone)
    token = os.urandom(6).hex()
    size = {"width": width, "height": height}
    futures = [
        client.submit(
            _render_frame, key, {**options, **size, **own}, camera, key=f"pointray-frame-{token}-{i}", retries=RETRIES
        )
        for i, (own, camera) in enumerate(shots)
    ]
    index = {f.key: i for i, f in enumerate(futures)}
    if video is not None:
        with video:
            _gather(client, futures, _in_order(video.write, index), progress, len(futures), "frames")
        return None
    done: List[Optional[np.ndarray]] = [None] * len(futures)

    def keep(future: Any, frame: np.ndarray) -> int:
        done[index[future.key]] = frame
        return 1

    _gather(client, futures, keep, progress, len(futures), "frames")
    return done  # type: ignore[return-value]


def _in_order(write: Callable[[np.ndarray], Any], index: Dict[str, int]) -> Callable[[Any, np.ndarray], int]:
    """A `take` for `_gather` handing frames to `write` in their order (those that arrive early
    kept until their turn), each task's result let go on the cluster once taken."""
    early: Dict[int, np.ndarray] = {}
    turn = 0

    def take(future: Any, frame: np.ndarray) -> int:
        nonlocal turn
        early[index[future.key]] = frame
        future.release()
        while turn in early:
            write(early.pop(turn))
            turn += 1
        return 1

    return take


def _gather(
    client: Any, futures: List[Any], take: Callable[[Any, np.ndarray], int], progress: Progress, total: int, unit: str
) -> None:
    """Hands each finished task's result to `take` (which says how much of `total` it was) as
    tasks finish, telling `progress`; cancels the rest on an error or an interruption."""
    from dask.distributed import as_completed

    report = _reporter(progress, total, unit)
    try:
        done = 0
        for future in as_completed(futures):
            done += take(future, future.result())
            report(done)
    except BaseException:
        client.cancel(futures)
        raise
    finally:
        report(None)


def _regions(width: int, height: int, tile: Union[int, Tuple[int, int]]) -> List[Tuple[int, int, int, int]]:
    """The frame's tiles, (x0, y0, x1, y1) each (x1, y1 exclusive), row by row."""
    tw, th = (tile, tile) if isinstance(tile, int) else tile
    if width < 1 or height < 1:
        raise ValueError(f"width and height must be at least 1 (got {width} x {height})")
    if tw < 1 or th < 1:
        raise ValueError(f"tile: expected a positive size, got {tile!r}")
    return [(x, y, min(x + tw, width), min(y + th, height)) for y in range(0, height, th) for x in range(0, width, tw)]


def _scene_key(source: Union[Path, Sequence[Path]], options: Dict[str, Any]) -> Tuple[Any, ...]:
    """What names a scene on a worker: its files' absolute paths (or its URL) and its prepare
    options (hashable)."""
    if isinstance(source, (pointray.Cloud, pointray.Scene)):
        raise TypeError(
            "source: a Dask render opens its source on the workers; give a path every worker can read, or a URL"
        )
    prepare = _frozen({k: v for k, v in options.items() if k in PREPARE_OPTIONS})
    if is_url(source):
        return ((source,), prepare)
    paths = [source] if isinstance(source, (str, os.PathLike)) else list(source)
    if not paths or not all(isinstance(p, (str, os.PathLike)) for p in paths):
        raise TypeError("source: expected a path or a list of paths")
    return (tuple(os.path.abspath(os.fspath(p)) for p in paths), prepare)


def _frozen(value: Any) -> Any:
    """`value` (options) as a hashable value: dicts as sorted pairs, lists as tuples."""
    if isinstance(value, dict):
        return ("dict", tuple(sorted((k, _frozen(v)) for k, v in value.items())))
    if isinstance(value, (list, tuple)):
        return ("list", tuple(_frozen(v) for v in value))
    return value


def _thawed(value: Any) -> Any:
    """The value `_frozen` made `value` of."""
    if isinstance(value, tuple) and len(value) == 2 and value[0] in ("dict", "list"):
        if value[0] == "dict":
            return {k: _thawed(v) for k, v in value[1]}
        return [_thawed(v) for v in value[1]]
    return value


@functools.lru_cache(maxsize=4)
def _scene(key: Tuple[Any, ...]) -> "pointray.Scene":
    """The scene `key` names, opened once on this process (the last four kept)."""
    global opened
    paths, prepare = key
    scene = pointray.prepare(list(paths) if len(paths) > 1 else paths[0], **_thawed(prepare))
    opened += 1
    return scene


def _open(key: Tuple[Any, ...]) -> Optional[str]:
    """Opens `key`'s scene on this worker: None, or why it cannot."""
    try:
        _scene(key)
        return None
    except Exception as e:  # noqa: BLE001 - each worker's reason goes back to the client
        return f"{type(e).__name__}: {e}"


def _open_everywhere(client: Any, key: Tuple[Any, ...]) -> None:
    """Opens the scene on every worker before the tasks go out, so that a source a worker
    cannot read is named with that worker, not as a failed task."""
    failures = {w: why for w, why in client.run(_open, key).items() if why is not None}
    if failures:
        lines = "; ".join(f"worker {w}: {why}" for w, why in sorted(failures.items()))
        raise OSError(f"the source cannot be opened on {len(failures)} of the workers: {lines}")


def _reopened_after_failed_fetches(task: Callable[..., np.ndarray]) -> Callable[..., np.ndarray]:
    """`task`, after which a scene that could not fetch part of its file (a scene file at a
    URL: the failure stays with the scene, as damage does) is let go, so that the task's retry
    (`RETRIES`) opens it again and fetches anew."""

    @functools.wraps(task)
    def run(*args: Any) -> np.ndarray:
        try:
            return task(*args)
        except ValueError as e:
            if "could not be read" in str(e):
                _scene.cache_clear()
                _orbit.cache_clear()
            raise

    return run


@_reopened_after_failed_fetches
def _render_tile(
    key: Tuple[Any, ...], region: Tuple[int, int, int, int], width: int, height: int, options: Dict[str, Any]
) -> np.ndarray:
    own = _render_options(options)
    return pointray.render_region(_scene(key), region, width=width, height=height, **own)


@_reopened_after_failed_fetches
def _render_frame(key: Tuple[Any, ...], options: Dict[str, Any], camera: Optional[Tuple[str, int, int]]) -> np.ndarray:
    """A frame: `options`, with the camera of an orbit's frame or the animation's, if named."""
    scene, own = _scene(key), _render_options(options)
    view = {o: v for o, v in own.items() if o != "threads"}
    if camera is not None:
        kind, k, frames = camera
        if kind == "orbit":
            own.update(_orbit(key, frames, _frozen(view))[k])
        else:
            own.update(scene.animation_frame(k, **view))
    return pointray.render(scene, **own)


@functools.lru_cache(maxsize=4)
def _orbit(key: Tuple[Any, ...], frames: int, view: Any) -> List[Dict[str, Any]]:
    """The cameras of an orbit's `frames` frames, found once on this process for all its tasks."""
    return _scene(key).turntable(frames, **_thawed(view))


def _render_options(options: Dict[str, Any]) -> Dict[str, Any]:
    """`options` less those only ``prepare`` takes (a scene renders with the rest)."""
    return {k: v for k, v in options.items() if k not in PREPROCESS_OPTIONS}


def _reporter(progress: Progress, total: int, unit: str) -> Callable[[Optional[int]], None]:
    """A function told how much is done as tasks finish (None at the end), driving `progress`."""
    if progress is None or progress is False:
        return lambda done: None
    if callable(progress):
        return lambda done: None if done is None else progress(done, total)
    from tqdm.auto import tqdm

    bar = tqdm(total=total, unit=unit, unit_scale=unit == "px", desc="pointray")

    def report(done: Optional[int]) -> None:
        if done is None:
            bar.close()
        else:
            bar.update(done - bar.n)

    return report
