"""Numba kernel of the default roughness ROI (:func:`fuse4d.metrics.default_roi`). Private."""

from __future__ import annotations

import numpy as np

from ._common import ROW_CHUNKS, _step_limit
from ._numba import njit_parallel, prange


@njit_parallel
def _default_roi_kernel(depth, quad, max_step, half, counts, out):
    """``out[v, u]`` = the (2 half + 1)^2 window at (v, u) lies inside the image, holds valid
    (finite) ``depth`` only, and no two horizontally or vertically neighbouring pixels in it
    differ by more than the larger of their step limits (the fusion's rule
    :func:`._common._step_limit`, max(max_step, 2.5 q z^2) mm; one (H, W) frame, q = ``quad``).

    Two passes of window sums. Along each row, from prefix sums, into ``counts`` ((2, H, W)
    int32): ``counts[0]`` the invalid pixels of columns u-half .. u+half plus the right links
    that are depth edges in columns u-half .. u+half-1; ``counts[1]`` the lower links (to
    the next row) that are edges in columns u-half .. u+half. Then down the columns, as
    running sums over each chunk's rows: a window is in the ROI when ``counts[0]`` over its
    2 half + 1 rows and ``counts[1]`` over its first 2 half rows are all 0. The step test has
    numpy's arithmetic (float64 z; a link with a NaN end is no edge: its window is invalid
    anyway), so the mask is that of the scipy filters this replaced (tested against them).
    """
    h, w = depth.shape
    n_chunks = min(h, ROW_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk, not per row
        lim = np.empty(w, np.float64)
        lim_next = np.empty(w, np.float64)
        # prefix sums over the row: invalid pixels, right links and lower links that are edges
        pre0 = np.zeros(w + 1, np.int32)
        pre_r = np.zeros(w + 1, np.int32)
        pre_d = np.zeros(w + 1, np.int32)
        for v in range(ci * h // n_chunks, (ci + 1) * h // n_chunks):
            row = depth[v]
            for u in range(w):
                lim[u] = _step_limit(float(row[u]), max_step, quad)
            if v + 1 < h:
                below = depth[v + 1]
                for u in range(w):
                    lim_next[u] = _step_limit(float(below[u]), max_step, quad)
            for u in range(w):
                z = float(row[u])
                pre0[u + 1] = pre0[u] + (0 if np.isfinite(z) else 1)
                edge_r = u + 1 < w and abs(float(row[u + 1]) - z) > max(lim[u + 1], lim[u])
                pre_r[u + 1] = pre_r[u] + (1 if edge_r else 0)
                edge_d = v + 1 < h and abs(float(depth[v + 1, u]) - z) > max(lim_next[u], lim[u])
                pre_d[u + 1] = pre_d[u] + (1 if edge_d else 0)
            for u in range(half, w - half):  # windows inside the image only
                counts[0, v, u] = (
                    pre0[u + half + 1] - pre0[u - half] + pre_r[u + half] - pre_r[u - half]
                )
                counts[1, v, u] = pre_d[u + half + 1] - pre_d[u - half]
    for ci in prange(n_chunks):
        acc = np.zeros(w, np.int32)
        started = False
        for v in range(ci * h // n_chunks, (ci + 1) * h // n_chunks):
            out[v, :] = False
            if v < half or v + half >= h:
                continue
            if not started:  # the chunk's first window: every row of it
                for dv in range(-half, half + 1):
                    for u in range(half, w - half):
                        acc[u] += counts[0, v + dv, u]
                for dv in range(-half, half):
                    for u in range(half, w - half):
                        acc[u] += counts[1, v + dv, u]
                started = True
            else:  # slide down by one row
                for u in range(half, w - half):
                    acc[u] += (
                        counts[0, v + half, u]
                        - counts[0, v - half - 1, u]
                        + counts[1, v + half - 1, u]
                        - counts[1, v - half - 1, u]
                    )
            for u in range(half, w - half):
                out[v, u] = acc[u] == 0
