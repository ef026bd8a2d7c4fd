"""pointray: multiresolution ray tracing of point clouds, rendered directly as splats.

Clouds and images are numpy arrays; render options are the ``pointray render`` command's, by
the same names (``spp``, ``surface``, ``lod_threshold``, ``distance``, ``eye``, ``look_at``, ...).

>>> import pointray
>>> image = pointray.render("bunny.ply", width=640, height=480, spp=4)   # H x W x 3, linear
>>> png_bytes = pointray.to_srgb8(image)                                  # what the CLI writes
"""

from ._pointray import (
    Cloud,
    Frame,
    Scene,
    VideoWriter,
    __version__,
    prepare,
    prepare_file,
    read_cloud,
    render,
    render_frame,
    render_region,
    to_srgb8,
)

__all__ = [
    "Cloud",
    "Frame",
    "Scene",
    "VideoWriter",
    "__version__",
    "prepare",
    "prepare_file",
    "read_cloud",
    "render",
    "render_frame",
    "render_region",
    "to_srgb8",
]
