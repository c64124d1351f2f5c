"""Evidence for static pixels (``FusionParams(static_tracks=True)``, our A33; issue 10). Private.

Per pixel of frame t, over the other frames T of its window:

* ``still``: frame t's raw depth is valid and the motion reference z~ at the *same* pixel
  stays within ``tol_quad * z~_t^2`` mm of z~_t in every frame T where it is valid;
* ``cost_zero = sum_T (I_T(x) - I_t(x))^2``: the intensity cost of "the pixel does not move";
* ``cost_track = sum_T (I_T(x^T) - I_t(x))^2`` at the track's rounded landing x^T where the
  track is valid (the zero-motion term where it is not): the cost of the flow's answer.

:func:`fuse4d.static_tracks.static_pixels` sums both costs over a small box and decides.
"""

from __future__ import annotations

import numpy as np

from ._numba import njit_parallel, prange

__all__ = ["_static_evidence_kernel"]


@njit_parallel
def _static_evidence_kernel(
    ref_ring,
    intensity_ring,
    depth_t,
    frame_slot,
    t,
    first,
    land_row,
    land_col,
    land_ok,
    tol_quad,
    still,
    cost_zero,
    cost_track,
):  # pragma: no cover - compiled (covered via NUMBA_DISABLE_JIT runs)
    """Fill ``still`` (H, W) bool and ``cost_zero`` / ``cost_track`` (H, W) float32.

    ``ref_ring`` (S, H, W, 3) motion-reference points P~ (mm; z~ = P~[..., 2]),
    ``intensity_ring`` (S, H, W) in [0, 1], ``depth_t`` (H, W) frame t's raw depth (mm, NaN =
    invalid); ``frame_slot[T - first]`` is the ring slot of frame T; ``land_*`` (K, H, W) the
    tracks of frame t's pixels (K = the window's other frames, increasing, t excluded) as from
    ``_track_window``; ``tol_quad`` (mm^-1): the depth tolerance is ``tol_quad * z~_t^2`` mm.
    """
    h, w = depth_t.shape
    kmax = land_ok.shape[0]
    st = frame_slot[t - first]
    for v in prange(h):
        # frame-major over the row: each frame's planes are read as contiguous rows
        for u in range(w):
            zt = ref_ring[st, v, u, 2]
            still[v, u] = not (np.isnan(depth_t[v, u]) or np.isnan(zt))
            cost_zero[v, u] = 0.0
            cost_track[v, u] = 0.0
        for k in range(kmax):
            s_t = frame_slot[k if first + k < t else k + 1]
            for u in range(w):
                zt = ref_ring[st, v, u, 2]
                if abs(ref_ring[s_t, v, u, 2] - zt) > tol_quad * zt * zt:
                    still[v, u] = False  # (False for NaN: a frame without z~ does not object)
                it = intensity_ring[st, v, u]
                d0 = intensity_ring[s_t, v, u] - it
                cost_zero[v, u] += d0 * d0
                if land_ok[k, v, u]:
                    d1 = intensity_ring[s_t, land_row[k, v, u], land_col[k, v, u]] - it
                    cost_track[v, u] += d1 * d1
                else:
                    cost_track[v, u] += d0 * d0
