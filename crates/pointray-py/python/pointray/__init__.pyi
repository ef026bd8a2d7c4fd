"""Type stubs of pointray's native module (render options are ``pointray render``'s)."""

import os
from typing import Any, Dict, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

Path = Union[str, "os.PathLike[str]"]
Source = Union[Path, Sequence[Path], "Cloud", "Scene"]

class Cloud:
    """A point cloud: positions (N x 3, float64, the file's coordinates) and, where known,
    normals (N x 3), colours (N x 3, sRGB-encoded as files store them, 0 to 1) and radii (N), float32; and the scan
    attributes: intensity (float32), classification and return number (uint8), GPS time
    (float64), N each."""

    def __init__(
        self,
        positions: npt.ArrayLike,
        normals: Optional[npt.ArrayLike] = None,
        colors: Optional[npt.ArrayLike] = None,
        radii: Optional[npt.ArrayLike] = None,
        *,
        intensity: Optional[npt.ArrayLike] = None,
        classification: Optional[npt.ArrayLike] = None,
        return_number: Optional[npt.ArrayLike] = None,
        gps_time: Optional[npt.ArrayLike] = None,
    ) -> None: ...
    def __len__(self) -> int: ...
    @property
    def positions(self) -> npt.NDArray[np.float64]: ...
    @property
    def normals(self) -> Optional[npt.NDArray[np.float32]]: ...
    @property
    def colors(self) -> Optional[npt.NDArray[np.float32]]: ...
    @property
    def radii(self) -> Optional[npt.NDArray[np.float32]]: ...
    @property
    def intensity(self) -> Optional[npt.NDArray[np.float32]]: ...
    @property
    def classification(self) -> Optional[npt.NDArray[np.uint8]]: ...
    @property
    def return_number(self) -> Optional[npt.NDArray[np.uint8]]: ...
    @property
    def gps_time(self) -> Optional[npt.NDArray[np.float64]]: ...

class Scene:
    """Splats in a multiresolution accelerator, built once by ``prepare``."""

    def __len__(self) -> int: ...
    def intersect(
        self, origins: npt.ArrayLike, directions: npt.ArrayLike, **options: Any
    ) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.int64], npt.NDArray[np.float32]]:
        """(t, splat_id, normal) of the first surface point along each ray, at full detail;
        inf, -1 and NaN for a miss. ``threads`` (default all cores)."""
    def camera_rays(self, **options: Any) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float32]]:
        """Origins and directions (H x W x 3) of the camera's rays through the pixel centres."""
    def turntable(self, frames: int, **options: Any) -> list[Dict[str, Any]]:
        """For each of ``frames`` frames, the camera options (eye, look_at, fov, view_dir, view) of
        the view the options give turned about the up axis by 360 k / frames degrees, as
        ``--turntable`` does."""
    @property
    def frames(self) -> int:
        """The frames of the scene file's [animation] (0 without one)."""
    def animation_frame(self, k: int, **options: Any) -> Dict[str, Any]:
        """Frame ``k`` of the scene file's [animation] (keyframes or an orbit): its camera options."""

class Frame:
    """A rendered frame: image, AOVs and statistics."""

    @property
    def image(self) -> npt.NDArray[np.float32]: ...
    def aov(self, name: str) -> npt.NDArray[Any]: ...
    @property
    def stats(self) -> dict[str, Any]: ...

class VideoWriter:
    """An MP4 (H.264) written a frame at a time through ffmpeg (``POINTRAY_FFMPEG`` names
    another): ``with VideoWriter("fly.mp4", fps=30) as video: video.write(image)``, each image
    linear H x W x 3 as ``render`` gives, through the tone map as ``to_srgb8``. The file
    appears whole when the writer closes after no error; else none. OSError without ffmpeg."""

    def __init__(self, path: Path, *, fps: float = 30.0, tonemap: str = "clamp", exposure: float = 0.0) -> None: ...
    def write(self, image: npt.ArrayLike) -> None: ...
    def close(self) -> None: ...
    def __enter__(self) -> "VideoWriter": ...
    def __exit__(self, *exc: Any) -> bool: ...

def read_cloud(path: Union[str, "os.PathLike[str]"], *, columns: Optional[str] = None) -> Cloud:
    """Reads PLY, LAS/LAZ, E57, PCD, XYZ/PTS, OFF or OBJ vertices, or a Stanford scan set (by
    content); ``columns`` ("x,y,z,r,g,b,i") names a text file's columns, as ``--columns`` does."""

def prepare(source: Source, **options: Any) -> Scene:
    """A source is a cloud or scene file's path (or a survey's tiles), a Cloud, or a scene
    file's URL (``https://``, ``s3://``, ...; read by ranges through fsspec as renders need it,
    ``pip install "pointray[remote]"``). Normals, orientation and radii where missing (k_normals, k_radius, radius_scale,
    recompute, strays, outlier_std; a text file's columns), the points drawn (classes,
    exclude_classes, clip_box, clip_planes) and their colours (color_by), then the accelerator
    (accel, sphere_from_level, surface); ``threads`` (default all cores)."""

def prepare_file(
    source: Union[Path, Sequence[Path]], output: Path, *, memory_budget: Optional[int] = None, **options: Any
) -> Dict[str, Any]:
    """The scene file (.prs) ``pointray prepare SOURCE -o OUTPUT`` writes: in memory, or out of
    core where that would take more than ``memory_budget`` bytes (default: half the machine's
    memory). Returns ``points``, ``chunks`` (out of core, else None), ``parts`` (more than one
    for a scene in parts) and ``bytes``."""

def render(source: Source, **options: Any) -> npt.NDArray[np.float32]:
    """The linear RGB image, H x W x 3 float32. Besides the render options: ``threads`` (default
    all cores) and ``progress``, a callable given (pixels done, pixels in all)."""

def render_region(source: Source, region: Tuple[int, int, int, int], **options: Any) -> npt.NDArray[np.float32]:
    """The pixels (x0, y0, x1, y1) of the frame (x1, y1 exclusive), as a tile."""

def render_frame(source: Source, **options: Any) -> Frame:
    """``render`` with the AOVs (aovs=[...]) and the statistics."""

def to_srgb8(image: npt.ArrayLike, *, tonemap: str = "clamp", exposure: float = 0.0) -> npt.NDArray[np.uint8]:
    """The 8-bit sRGB bytes of ``pointray render``'s PNG for the same options."""
