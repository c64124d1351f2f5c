"""Recordings on disk as lazy dask arrays: one delayed read per frame, any readable layout.

Each frame task opens (once per worker process, then reuses) the layout's
:class:`fuse4d.io.FrameReader` and returns that frame's depth and intensity exactly as the
streaming ``fuse4d run`` sees them, so a lazily loaded recording fuses to the same bits.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import dask
import dask.array as da
import numpy as np
from numpy.typing import NDArray

from ..camera import Intrinsics
from ..io import detect_format, open_frames

__all__ = ["LazyRecording", "open_lazy", "read_frame_pair"]

_READERS: dict[tuple[str, str], Any] = {}
_LOCK = threading.Lock()


def _reader(path: str, fmt: str) -> Any:
    """This process's reader of ``path`` (opened on first use; readers are not thread-safe,
    so callers hold ``_LOCK`` while reading)."""
    key = (path, fmt)
    if key not in _READERS:
        if len(_READERS) >= 8:  # a worker handling many recordings: keep the newest few open
            old_key = next(iter(_READERS))
            _READERS.pop(old_key).close()
        _READERS[key] = open_frames(path, format=fmt)
    return _READERS[key]


def read_frame_pair(path: str, fmt: str, index: int, stamp: int = 0) -> NDArray[np.float32]:
    """Frame ``index`` of a recording as a ``(2, H, W)`` float32 array: depth (mm, NaN =
    invalid) and intensity ([0, 1]). ``stamp`` (the file's mtime) only keys the task."""
    with _LOCK:
        frame = _reader(path, fmt).read_frame(index)
    return np.stack([frame.depth, frame.intensity]).astype(np.float32, copy=False)


@dataclass(frozen=True)
class LazyRecording:
    """A recording as lazy dask arrays.

    Attributes
    ----------
    path : Path
    format : str
        Layout name (``"npz"``, ``"folder"``, ...).
    depth : dask.array.Array, (T, H, W) float32
        mm, NaN = invalid; one chunk per frame.
    intensity : dask.array.Array, (T, H, W) float32
        [0, 1].
    intrinsics : Intrinsics
    fps : float or None
    depth_unit_mm : float or None
        Millimetres per stored depth unit of the input (None for float layouts).
    """

    path: Path
    format: str
    depth: da.Array
    intensity: da.Array
    intrinsics: Intrinsics
    fps: float | None
    depth_unit_mm: float | None

    @property
    def num_frames(self) -> int:
        """T."""
        return int(self.depth.shape[0])


def open_lazy(path: str | Path, *, format: str | None = None) -> LazyRecording:
    """Open any layout that :func:`fuse4d.io.open_frames` reads as lazy dask arrays.

    Only the metadata is read now; each frame is read by its own task when computed.

    Parameters
    ----------
    path : str or Path
        ``.npz`` file or sequence folder.
    format : str, optional
        Force a layout (default: :func:`fuse4d.io.detect_format`).

    Returns
    -------
    LazyRecording
    """
    src = Path(path).resolve()
    fmt = format or detect_format(src)
    with open_frames(src, format=fmt) as reader:
        total = len(reader)
        k = reader.intrinsics
        fps, unit = reader.fps, reader.depth_unit_mm
    h, w = k.height, k.width
    read = dask.delayed(read_frame_pair, pure=True)
    stamp = src.stat().st_mtime_ns  # a rewritten input gets new task keys
    frames = [
        da.from_delayed(read(str(src), fmt, t, stamp), (2, h, w), np.float32) for t in range(total)
    ]
    both = da.stack(frames)  # (T, 2, H, W), one chunk per frame
    return LazyRecording(src, fmt, both[:, 0], both[:, 1], k, fps, unit)
