"""Scene files at URLs, read by ranges as a render reads them (fsspec; here a local HTTP server
that answers range requests): the renders and queries are the local file's, and a distant view
fetches a small part of the file."""

import numpy as np
import pytest

import pointray

from ranged_http import RangedServer
from test_pointray import sphere_points

pytest.importorskip("fsspec")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A scene file of many treelets, and the server serving its directory."""
    directory = tmp_path_factory.mktemp("served")
    cloud = directory / "sphere.xyz"
    np.savetxt(cloud, sphere_points(n=400_000), fmt="%.9f")
    pointray.prepare_file(str(cloud), str(directory / "sphere.prs"))
    (directory / "cloud.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with RangedServer(directory) as server:
        yield directory, server


def test_a_scene_file_at_a_url_is_the_local_one_fetched_as_read(served):
    directory, server = served
    local = pointray.prepare(str(directory / "sphere.prs"))
    size = (directory / "sphere.prs").stat().st_size
    server.forget()
    sent = server.sent
    remote = pointray.prepare(server.url("sphere.prs"))
    opening = server.sent - sent
    far = {"width": 64, "height": 64, "distance": 6.0}
    assert np.array_equal(pointray.render(remote, **far), pointray.render(local, **far))
    far_view = server.sent - sent
    # Here 0.39 MB to open, 0.91 of 14.3 MB after the view (the top alone from 16 diagonals).
    assert opening < far_view < size / 4, (opening, far_view, size)
    close = {"width": 96, "height": 80, "spp": 2, "lod_threshold": 0.0}
    assert np.array_equal(pointray.render(remote, **close), pointray.render(local, **close))
    origins = np.array([[10.0, 20.0, 35.0], [10.2, 20.1, 35.0]])
    directions = np.array([[0.0, 0.0, -1.0]] * 2)
    hits, expected = remote.intersect(origins, directions), local.intersect(origins, directions)
    assert all(np.array_equal(a, b) for a, b in zip(hits, expected)) and (hits[1] >= 0).all()
    server.sent_once()
    # A URL is a source as a path is.
    assert np.array_equal(pointray.render(server.url("sphere.prs"), **far), pointray.render(local, **far))


def test_what_cannot_be_read_at_a_url_is_named_until_opened_again(served):
    directory, server = served
    with pytest.raises(FileNotFoundError, match="missing.prs"):
        pointray.prepare(server.url("missing.prs"))
    with pytest.raises(ValueError, match="cloud.ply.*not a pointray scene file"):
        pointray.prepare(server.url("cloud.ply"))
    # The server down after the open: the render that needs more of the file fails, naming
    # what it could not read, and so do the scene's later ones (as for damage); the scene
    # opened again, with the server back, renders whole.
    scene = pointray.prepare(server.url("sphere.prs"))
    close = {"width": 32, "height": 32, "lod_threshold": 0.0}
    server.set_down(True)
    try:
        with pytest.raises(ValueError, match="could not be read"):
            pointray.render(scene, **close)
    finally:
        server.set_down(False)
    with pytest.raises(ValueError, match="could not be read"):
        pointray.render(scene, **close)
    again = pointray.prepare(server.url("sphere.prs"))
    assert np.array_equal(pointray.render(again, **close), pointray.render(str(directory / "sphere.prs"), **close))


def test_threads_rendering_a_scene_at_a_url_at_once_each_get_their_image(served):
    """Renders from Python threads at once, each probing the scene (culling's, the
    prefilter's) while the other's render threads fetch through Python: no thread may hold
    the GIL while it waits for a treelet another fetches."""
    import threading

    directory, server = served
    views = [{"width": 48, "height": 48, "distance": d, "prefilter": True, "cull": "auto"} for d in (1.5, 2.5)]
    local = pointray.prepare(str(directory / "sphere.prs"))
    remote = pointray.prepare(server.url("sphere.prs"))
    images = [None, None]

    def render(k):
        images[k] = pointray.render(remote, **views[k])

    threads = [threading.Thread(target=render, args=(k,), daemon=True) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not any(t.is_alive() for t in threads), "a render never ended"
    for image, view in zip(images, views):
        assert np.array_equal(image, pointray.render(local, **view))
