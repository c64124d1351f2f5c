"""Kernels of the edge-limited smoothing of one map (``fuse4d.motion._segment_smooth``: the
motion-reference depth D~, A3', and A42's smoothing of the fused depth). Private.

The values, bit for bit, of four :func:`._kernels.fusion._segment_box_rows_kernel` passes
(two along rows, two along the columns of the transposed maps), in two sweeps:

* :func:`_segment_smooth_rows_kernel`: per row, the depth-continuous segments are found once
  and both row passes run on line buffers; the result and the depth go out transposed (the
  column sweep's layout).
* :func:`_segment_smooth_cols_kernel`: per column likewise, the result transposed back.

Four passes found every line's segments four times and the column passes needed three
transposed copies: one smoothing of a 640 x 480 frame of ``uva_cv2_person_turning`` took
1.85 ms, the two sweeps 1.52 (two threads, medians of 30, alternating; stop 48). The engine
smooths twice per frame (D~, and A42's fused depth).
The arithmetic is :func:`._segments._box_line`'s, compiled with the same flags
(:data:`._segments.SEGMENT_FASTMATH`), so the values do not move (tested against the passes).
"""

from __future__ import annotations

import numpy as np

from ._numba import njit, njit_parallel, prange
from ._segments import BLOCK, BLOCK_CHUNKS, SEGMENT_FASTMATH, _box_line, _line_segments

__all__ = ["_segment_smooth_cols_kernel", "_segment_smooth_rows_kernel"]


@njit(inline="always")
def _line_scratch(n):
    """Scratch of :func:`_smooth_line` for lines of ``n`` pixels."""
    y = np.empty(n, np.float32)
    starts = np.empty(n, np.int64)
    ends = np.empty(n, np.int64)
    s_val = np.empty(n + 1, np.float64)
    s_kv = np.empty(n + 1, np.float64)
    return y, starts, ends, s_val, s_kv


@njit(inline="always")
def _smooth_line(values, depth, radius, max_step, quad, scratch, line):
    """Both box passes of one line ``values`` within the segments of ``depth`` (float32,
    NaN = excluded) into ``line``, NaN where the depth is NaN (``scratch``:
    :func:`_line_scratch`)."""
    y, starts, ends, s_val, s_kv = scratch
    m = _line_segments(depth, max_step, quad, starts, ends)
    _box_line(values, y, starts, ends, m, radius, s_val, s_kv)
    _box_line(y, line, starts, ends, m, radius, s_val, s_kv)
    for k in range(depth.shape[0]):
        if np.isnan(depth[k]):
            line[k] = np.float32(np.nan)


@njit_parallel(fastmath=set(SEGMENT_FASTMATH))
def _segment_smooth_rows_kernel(values, depth, radius, max_step, quad, rows_t, depth_t):
    """Row sweep: both local-linear box passes of ``values`` along the rows, within the
    depth-continuous segments of ``depth`` (both (H, W) float32; NaN depth = excluded).

    Out, transposed: ``rows_t`` (W, H) float32 the values after the two passes (NaN where
    ``depth`` is NaN) and ``depth_t`` (W, H) float32 ``depth``.
    """
    h, w = depth.shape
    n_blocks = (h + BLOCK - 1) // BLOCK
    n_chunks = min(n_blocks, BLOCK_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk of blocks
        scratch = _line_scratch(w)
        tile = np.empty((BLOCK, w), np.float32)
        for bi in range(ci * n_blocks // n_chunks, (ci + 1) * n_blocks // n_chunks):
            v0 = bi * BLOCK
            v1 = min(h, v0 + BLOCK)
            for v in range(v0, v1):
                _smooth_line(values[v], depth[v], radius, max_step, quad, scratch, tile[v - v0])
            for u in range(w):
                for v in range(v0, v1):
                    rows_t[u, v] = tile[v - v0, u]
                    depth_t[u, v] = depth[v, u]


@njit_parallel(fastmath=set(SEGMENT_FASTMATH))
def _segment_smooth_cols_kernel(rows_t, depth_t, radius, max_step, quad, out):
    """Column sweep: both box passes of ``rows_t`` (W, H) along its lines (the image's
    columns) within the segments of ``depth_t`` (W, H); ``out`` (H, W) float32 gets the
    result in the image's layout, NaN where the depth is NaN."""
    w, h = depth_t.shape
    n_blocks = (w + BLOCK - 1) // BLOCK
    n_chunks = min(n_blocks, BLOCK_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk of blocks
        scratch = _line_scratch(h)
        tile = np.empty((BLOCK, h), np.float32)
        for bi in range(ci * n_blocks // n_chunks, (ci + 1) * n_blocks // n_chunks):
            u0 = bi * BLOCK
            u1 = min(w, u0 + BLOCK)
            for u in range(u0, u1):
                _smooth_line(rows_t[u], depth_t[u], radius, max_step, quad, scratch, tile[u - u0])
            for v in range(h):
                for u in range(u0, u1):
                    out[v, u] = tile[u - u0, v]
