"""The depth camera's field of view, as its valid depth shows it (our A38, issue 10).

A depth image registered to a colour camera covers less than the colour image (a band of
30-50 px with no depth around a Kinect-class or aligned RealSense frame; on
``uva_cv2_person_turning`` rows 34-463 and columns 41-604 of 640×480). Sensor holes are
filled only inside it (:mod:`fuse4d.holes`); ``fuse4d info`` reports it. NumPy only, so
that ``fuse4d info`` does not load the numba kernels.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_float32, check_shape

__all__ = ["field_of_view"]


def field_of_view(depth: ArrayLike) -> NDArray[np.bool_]:
    """The depth camera's field of view, as the valid depth of one or more frames shows it.

    A pixel is inside when, in the frames given, its row has valid depth on both sides of it
    (or at it) and so has its column: the row-and-column hull of the valid pixels. Holes in
    the interior (shadows, dark or glassy surfaces) are inside; the band that a registered
    depth image leaves around the colour image, and any row or column end beyond the last
    valid pixel, are outside. The fusion engine takes the hull of the frames of each output
    frame's window (from per-frame extents computed once per frame).

    Parameters
    ----------
    depth : (H, W) or (K, H, W) ndarray
        Depth in mm; NaN or <= 0 = no depth.

    Returns
    -------
    (H, W) ndarray of bool
        True inside the field of view.

    Examples
    --------
    >>> d = np.full((5, 6), np.nan, np.float32); d[1:4, 1:5] = 1000.0; d[2, 2] = np.nan
    >>> field_of_view(d).astype(int)  # the interior hole is inside, the border band is not
    array([[0, 0, 0, 0, 0, 0],
           [0, 1, 1, 1, 1, 0],
           [0, 1, 1, 1, 1, 0],
           [0, 1, 1, 1, 1, 0],
           [0, 0, 0, 0, 0, 0]])
    """
    d = as_float32(depth, name="depth")
    frames = d[None] if d.ndim == 2 else d
    check_shape(frames, ("K", "H", "W"), name="depth")
    extents = [_valid_extents(np.where(f > 0, f, np.float32(np.nan))) for f in frames]
    return _inside_extents(np.stack([r for r, _ in extents]), np.stack([c for _, c in extents]))


def _valid_extents(depth: NDArray[np.float32]) -> tuple[NDArray[np.int32], NDArray[np.int32]]:
    """First and last pixel with valid (non-NaN) depth of every row and column of one frame:
    (H, 2) int32 [first, last] column per row ((W, -1) where a row has none) and (W, 2) int32
    [first, last] row per column ((H, -1)). The fusion engine computes the same values once
    per frame with ``_kernels.fov._valid_extents_kernel`` (0.5 -> 0.2 ms at 640×480); this numpy
    form is its oracle and serves ``fuse4d info``, which loads no numba."""
    valid = ~np.isnan(depth)
    h, w = valid.shape
    in_row, in_col = valid.any(axis=1), valid.any(axis=0)
    rows = np.empty((h, 2), np.int32)
    cols = np.empty((w, 2), np.int32)
    rows[:, 0] = np.where(in_row, valid.argmax(axis=1), w)
    rows[:, 1] = np.where(in_row, w - 1 - valid[:, ::-1].argmax(axis=1), -1)
    cols[:, 0] = np.where(in_col, valid.argmax(axis=0), h)
    cols[:, 1] = np.where(in_col, h - 1 - valid[::-1].argmax(axis=0), -1)
    return rows, cols


def _inside_extents(
    row_extent: NDArray[np.int32], col_extent: NDArray[np.int32]
) -> NDArray[np.bool_]:
    """Unvalidated :func:`field_of_view` from per-frame extents ((K, H, 2), (K, W, 2) int32
    of :func:`_valid_extents`): the hull of their union. The engine's per-output-frame form
    is ``_kernels.fov._inside_extents_kernel`` (0.4 -> 0.12 ms at 640×480), tested against this."""
    h, w = row_extent.shape[1], col_extent.shape[1]
    row_lo = row_extent[:, :, 0].min(axis=0)[:, None]
    row_hi = row_extent[:, :, 1].max(axis=0)[:, None]
    col_lo = col_extent[:, :, 0].min(axis=0)[None, :]
    col_hi = col_extent[:, :, 1].max(axis=0)[None, :]
    u = np.arange(w, dtype=np.int32)[None, :]
    v = np.arange(h, dtype=np.int32)[:, None]
    return (u >= row_lo) & (u <= row_hi) & (v >= col_lo) & (v <= col_hi)
