"""Kernels of A29's base-offset smoothing (``fuse4d.fusion._smooth_base``). Private.

The edge-limited smoothing of the three offset channels, the values of three
:func:`fuse4d.motion._segment_smooth` calls (two local-linear box passes along rows, two along
columns, each limited to frame t's depth-continuous segments) bit for bit, in two sweeps:

* :func:`_smooth_base_rows_kernel`: per row, the segments are found once and the three
  channels get both row passes together (:func:`._segments._box_line3`, line buffers); the
  output, frame t's segments and A29's clip bound go out transposed (the column sweep's
  layout).
* :func:`_smooth_base_cols_kernel`: per column likewise, then A29's clipped update of the
  points.

The box pass is that of ``_kernels.fusion._segment_box_rows_kernel`` (``_kernels/_segments.py``:
rounding written out in the source, compiled with ``SEGMENT_FASTMATH``), so the values are
identical; only the segment search, the loops and the transposes are shared. Without FMA
contraction the update rounds like the NumPy expression of the reference (the bound
``limit_quad z^2`` is two float32 products, as there).
"""

from __future__ import annotations

import numpy as np

from ._numba import njit, njit_parallel, prange
from ._segments import BLOCK, BLOCK_CHUNKS, SEGMENT_FASTMATH, _box_line3, _line_segments

__all__ = ["_smooth_base_cols_kernel", "_smooth_base_rows_kernel"]


#: largest finite float32
_F32_MAX = np.float32(3.4028234663852886e38)


@njit(inline="always")
def _nan_to_num32(x):
    """``np.nan_to_num`` of one float32: NaN -> 0, +-inf -> +-float32 max (branch-free)."""
    y = np.float32(0.0) if np.isnan(x) else x
    return min(max(y, -_F32_MAX), _F32_MAX)


@njit_parallel(fastmath=set(SEGMENT_FASTMATH))
def _smooth_base_rows_kernel(
    base, depth, hole, radius, max_step, quad, limit_quad, rows_t, seg_t, bound_t
):
    """Row sweep of A29: both row box passes of the three channels of ``nan_to_num(base)``.

    base (H, W, 3) float32 mm; depth (H, W) float32 mm and hole (H, W) bool give frame t's
    segments (``seg`` = depth, NaN at holes). Out, transposed: ``rows_t`` (W, 3, H) the
    channels after the row passes (unwritten where ``seg`` is NaN), ``seg_t`` (W, H) ``seg``
    and ``bound_t`` (W, H) float32 ``limit_quad * seg^2`` (A29's clip bound, mm).
    """
    h, w = depth.shape
    lq = np.float32(limit_quad)
    nan32 = np.float32(np.nan)
    n_blocks = (h + BLOCK - 1) // BLOCK
    n_chunks = min(n_blocks, BLOCK_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk of blocks
        x = np.empty((3, w), np.float32)
        y = np.empty((3, w), np.float32)
        starts = np.empty(w, np.int64)
        ends = np.empty(w, np.int64)
        s_val = np.empty((3, w + 1), np.float64)
        s_kv = np.empty((3, w + 1), np.float64)
        zt = np.empty((BLOCK, w), np.float32)
        tile = np.empty((BLOCK, 3, w), np.float32)
        for bi in range(ci * n_blocks // n_chunks, (ci + 1) * n_blocks // n_chunks):
            v0 = bi * BLOCK
            v1 = min(h, v0 + BLOCK)
            for v in range(v0, v1):
                z = zt[v - v0]
                for u in range(w):
                    z[u] = nan32 if hole[v, u] else depth[v, u]
                    for c in range(3):
                        x[c, u] = _nan_to_num32(base[v, u, c])
                m = _line_segments(z, max_step, quad, starts, ends)
                _box_line3(x, y, starts, ends, m, radius, s_val, s_kv)
                _box_line3(y, tile[v - v0], starts, ends, m, radius, s_val, s_kv)
            for u in range(w):
                for v in range(v0, v1):
                    zz = zt[v - v0, u]
                    seg_t[u, v] = zz
                    bound_t[u, v] = lq * zz * zz
                    for c in range(3):
                        rows_t[u, c, v] = tile[v - v0, c, u]


@njit_parallel(fastmath=set(SEGMENT_FASTMATH))
def _smooth_base_cols_kernel(rows_t, seg_t, bound_t, base, radius, max_step, quad, points):
    """Column sweep of A29 and its update of ``points`` (H, W, 3) float32 mm, in place.

    ``rows_t``, ``seg_t``, ``bound_t``: the row sweep's output. Both column box passes give the
    smoothed offset S of each channel c; where S is finite (``seg`` finite), coordinate c of
    pixel (v, u) with its own offset o = ``nan_to_num(base[v, u, c])`` gets
    ``+= S + clip(o - S, -b, b) - o``, b = ``bound_t[u, v]``.
    """
    w, h = seg_t.shape
    n_blocks = (w + BLOCK - 1) // BLOCK
    for bi in prange(n_blocks):
        u0 = bi * BLOCK
        u1 = min(w, u0 + BLOCK)
        y = np.empty((3, h), np.float32)
        starts = np.empty(h, np.int64)
        ends = np.empty(h, np.int64)
        s_val = np.empty((3, h + 1), np.float64)
        s_kv = np.empty((3, h + 1), np.float64)
        tile = np.empty((u1 - u0, 3, h), np.float32)
        for u in range(u0, u1):
            m = _line_segments(seg_t[u], max_step, quad, starts, ends)
            _box_line3(rows_t[u], y, starts, ends, m, radius, s_val, s_kv)
            _box_line3(y, tile[u - u0], starts, ends, m, radius, s_val, s_kv)
        for v in range(h):
            for u in range(u0, u1):
                if np.isnan(seg_t[u, v]):
                    continue  # S is NaN: no change
                bound = bound_t[u, v]
                for c in range(3):
                    smooth = tile[u - u0, c, v]
                    if not np.isfinite(smooth):
                        continue
                    own = _nan_to_num32(base[v, u, c])
                    fine = own - smooth
                    if fine < -bound:
                        fine = -bound
                    if fine > bound:
                        fine = bound
                    points[v, u, c] += smooth + fine - own
