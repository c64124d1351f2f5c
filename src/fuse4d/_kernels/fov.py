"""The field-of-view hull of the fusion engine (A38, :mod:`fuse4d.fov`), without numpy
temporaries (issue 13: the numpy forms took 1.1 ms per 640x480 frame on the engine's thread).

* :func:`_valid_extents_kernel`: the per-frame extents of :func:`fuse4d.fov._valid_extents`.
* :func:`_inside_extents_kernel`: the mask of :func:`fuse4d.fov._inside_extents`.

Integer work only: the same values as the numpy forms (their oracle, ``tests/test_fov.py``).
"""

from __future__ import annotations

import numpy as np

from ._numba import njit

__all__ = ["_inside_extents_kernel", "_valid_extents_kernel"]


@njit
def _valid_extents_kernel(depth, rows, cols):
    """First and last column with non-NaN ``depth`` (H, W) of every row into ``rows`` (H, 2)
    int32 ((W, -1) where a row has none), first and last row of every column into ``cols``
    (W, 2) int32 ((H, -1))."""
    h, w = depth.shape
    for u in range(w):
        cols[u, 0] = h
        cols[u, 1] = -1
    for v in range(h):
        first = w
        last = -1
        for u in range(w):
            if not np.isnan(depth[v, u]):
                if first == w:
                    first = u
                last = u
                if cols[u, 0] == h:
                    cols[u, 0] = v
                cols[u, 1] = v
        rows[v, 0] = first
        rows[v, 1] = last


@njit(inline="always")
def _union_extent(extent, frame_slot, i):
    """(first, last) of line ``i`` over the frames ``frame_slot`` of the ring ``extent``
    (S, N, 2) int32: the smallest first and the largest last."""
    lo = extent[frame_slot[0], i, 0]
    hi = extent[frame_slot[0], i, 1]
    for k in range(1, frame_slot.shape[0]):
        lo = min(lo, extent[frame_slot[k], i, 0])
        hi = max(hi, extent[frame_slot[k], i, 1])
    return lo, hi


@njit
def _inside_extents_kernel(row_extent, col_extent, frame_slot, out):
    """The hull of the union of the extents of the frames ``frame_slot`` (K,) of the rings
    ``row_extent`` (S, H, 2) and ``col_extent`` (S, W, 2) int32: ``out`` (H, W) bool, True
    where the pixel's row and column both reach over it."""
    h, w = out.shape
    col_lo = np.empty(w, np.int32)
    col_hi = np.empty(w, np.int32)
    for u in range(w):
        col_lo[u], col_hi[u] = _union_extent(col_extent, frame_slot, u)
    for v in range(h):
        lo, hi = _union_extent(row_extent, frame_slot, v)
        for u in range(w):
            out[v, u] = u >= lo and u <= hi and v >= col_lo[u] and v <= col_hi[u]
