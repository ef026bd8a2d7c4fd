"""Scene files at URLs: an object store (``s3://``, ``gs://``, ``az://``, with fsspec's
packages for them: s3fs, gcsfs, adlfs) or an HTTP server (``https://``; it must answer range
requests), read by ranges as a render reads them; fsspec's chained URLs
(``simplecache::s3://...``) too. ``pointray.prepare(url)``, the renders and ``pointray.dask``
take one as their source (a scene file's, not a cloud file's); credentials are fsspec's, from
the environment.
"""

from __future__ import annotations

import re
from typing import Any, Callable, List, Sequence, Tuple

# A scheme of two letters at least ("C://" is a Windows path), fsspec's chains before it.
_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.\-]+::)*[A-Za-z][A-Za-z0-9+.\-]+://")


def is_url(source: Any) -> bool:
    """Whether ``source`` is a URL other than a local ``file://`` one."""
    return isinstance(source, str) and bool(_SCHEME.match(source)) and not source.startswith("file://")


def reader(url: str) -> Tuple[int, Callable[[Sequence[Tuple[int, int]]], List[bytes]]]:
    """The length of the file at ``url``, and a callable giving the bytes of ranges of it."""
    try:
        import fsspec
    except ImportError:
        raise ImportError(f'{url}: a scene file at a URL is read through fsspec: pip install "pointray[remote]"') from None
    fs, path = fsspec.core.url_to_fs(url)
    size = fs.size(path)
    if size is None:
        raise OSError(f"{url}: its size is unknown (the server gives no Content-Length)")

    def read(ranges: Sequence[Tuple[int, int]]) -> List[bytes]:
        starts, ends = [s for s, _ in ranges], [e for _, e in ranges]
        return fs.cat_ranges([path] * len(ranges), starts, ends, on_error="raise")

    return int(size), read
