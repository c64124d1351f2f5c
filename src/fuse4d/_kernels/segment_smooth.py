"""Kernels of the edge-limited smoothing of one map (``fuse4d.motion._segment_smooth``: the
motion-reference depth D~, A3', and A42's smoothing of the fused depth). Private.

The values, bit for bit, of four :func:`._kernels.fusion._segment_box_rows_kernel` passes
(two along rows, two along the columns of the transposed maps), in two sweeps of
:func:`_segment_smooth_sweep_kernel`: per line, the depth-continuous segments are found once
and both passes run on line buffers, and the result goes out transposed. The row sweep's
output is the column sweep's input; the column sweep's output is in the image's layout.

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

__all__ = ["_segment_smooth_sweep_kernel"]


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
def _segment_smooth_sweep_kernel(values, depth, radius, max_step, quad, out_t):
    """One sweep: both local-linear box passes of each line of ``values`` (N, L) float32
    within the depth-continuous segments of the same line of ``depth`` (N, L) float32, NaN =
    excluded; ``out_t`` (L, N) float32 gets the result transposed, NaN where the depth is NaN.
    The row sweep takes the image's maps, the column sweep the row sweep's output and the
    transposed depth."""
    n, length = depth.shape
    n_blocks = (n + BLOCK - 1) // BLOCK
    n_chunks = min(n_blocks, BLOCK_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk of blocks
        scratch = _line_scratch(length)
        tile = np.empty((BLOCK, length), np.float32)
        for bi in range(ci * n_blocks // n_chunks, (ci + 1) * n_blocks // n_chunks):
            i0 = bi * BLOCK
            i1 = min(n, i0 + BLOCK)
            for i in range(i0, i1):
                _smooth_line(values[i], depth[i], radius, max_step, quad, scratch, tile[i - i0])
            for k in range(length):  # runs of BLOCK float32 in each output line
                for i in range(i0, i1):
                    out_t[k, i] = tile[i - i0, k]
