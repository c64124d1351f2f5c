"""Composed tracks (``FusionParams(tracks="composed")``, our A31; issue 13). Private.

The exact tracks (:func:`._kernels.fusion._track_kernel`) chain every pixel of frame t
through each flow of its window: 8 bilinear steps per pixel and output frame at n = 9, each
(t, T) chain computed once, but no step shared between two output frames. Composed tracks
share them: a chain from frame s to frame c takes its exact first step to s ± 1 and then
follows the chain that starts at the pixel it landed on (computed once, for frame s ± 1),
shifted by the sub-pixel offset of the landing. So each frame costs two exact steps (one per
direction, :func:`_one_step_kernel`) and one gather per other frame of the window
(:func:`_compose_kernel`).

Both kernels work on one ``(H, W)`` frame pair and write positions (float32 px: x = column,
y = row), validity and, for the composed chains, the rounded landing pixel.
"""

from __future__ import annotations

import numpy as np

from ._common import _bilinear2_plane, _round_half_up, _step_limit
from ._numba import njit, njit_parallel, prange

__all__ = ["_compose_kernel", "_one_step_kernel"]


@njit(inline="always")
def _in_image(x, y, w, h):
    """Whether (x = column, y = row) px lies in a W x H image (its last pixel included)."""
    return x >= 0.0 and x <= w - 1.0 and y >= 0.0 and y <= h - 1.0


@njit(inline="always")
def _continues(d, d_ref, max_step, quad):
    """Whether depth ``d`` (mm) is valid and within ``_step_limit`` of ``d_ref`` (A22)."""
    return (not np.isnan(d)) and abs(d - d_ref) < _step_limit(d_ref, max_step, quad)


@njit_parallel
def _one_step_kernel(
    step_flow,
    check_flow,
    depth_from,
    depth_to,
    theta,
    max_step,
    quad,
    out_x,
    out_y,
    out_ok,
    out_row,
    out_col,
):
    """One exact tracking step from every pixel of frame s to frame s ± 1.

    ``step_flow`` (H, W, 2) moves the pixel (on frame s's grid); ``check_flow`` (H, W, 2) is the
    reverse flow on the landing frame's grid. Valid (``out_ok``) as the first step of
    :func:`._kernels.fusion._track_kernel`: valid depth at the start, landing in the image,
    forward-backward error < ``theta`` px, valid depth at the rounded landing pixel within
    ``_step_limit`` of the start's (mm, ``quad`` mm^-1). ``out_x``/``out_y`` get the landing
    position (px) even where the step is invalid, ``out_row``/``out_col`` the rounded landing
    pixel (the start pixel where invalid), as :func:`_compose_kernel`.
    """
    h, w = depth_from.shape
    theta2 = theta * theta
    for v in prange(h):
        for u in range(w):
            d0 = depth_from[v, u]
            su = float(step_flow[v, u, 0])
            sv = float(step_flow[v, u, 1])
            x = u + su
            y = v + sv
            ok = (not np.isnan(d0)) and _in_image(x, y, w, h)
            if ok:
                cu, cv = _bilinear2_plane(check_flow, x, y)
                ok = (su + cu) * (su + cu) + (sv + cv) * (sv + cv) < theta2
            r = v
            c = u
            if ok:
                r = _round_half_up(y)
                c = _round_half_up(x)
                ok = _continues(depth_to[r, c], d0, max_step, quad)
                if not ok:
                    r = v
                    c = u
            out_x[v, u] = x
            out_y[v, u] = y
            out_ok[v, u] = ok
            out_row[v, u] = r
            out_col[v, u] = c


@njit_parallel
def _compose_kernel(
    first_x,
    first_y,
    first_ok,
    next_x,
    next_y,
    next_ok,
    depth_c,
    max_step,
    quad,
    out_x,
    out_y,
    out_ok,
    out_row,
    out_col,
):
    """Chains s -> c composed of an exact first step s -> s ± 1 and the chains s ± 1 -> c.

    ``first_*`` (H, W): the first step of every pixel of s (:func:`_one_step_kernel`);
    ``next_*`` (H, W): the chains from every pixel of s ± 1 to c. A pixel's chain follows
    the chain of the pixel its first step landed on (rounded), shifted by the landing's
    sub-pixel offset, and is valid if both parts are, the shifted position lies in the image
    and, where the shift moves it off the followed chain's landing pixel, the new pixel has
    valid depth (``depth_c``, mm) within ``_step_limit`` of that pixel's. Writes positions
    (``out_x``, ``out_y``), validity and the rounded landing pixel (``out_row``,
    ``out_col``; the start pixel where invalid).
    """
    h, w = first_x.shape
    for v in prange(h):
        for u in range(w):
            x1 = float(first_x[v, u])
            y1 = float(first_y[v, u])
            ok = first_ok[v, u]
            x = x1
            y = y1
            r = v
            c = u
            if ok:
                r1 = _round_half_up(y1)
                c1 = _round_half_up(x1)
                ok = next_ok[r1, c1]
                if ok:
                    nx = float(next_x[r1, c1])
                    ny = float(next_y[r1, c1])
                    x = nx + (x1 - c1)
                    y = ny + (y1 - r1)
                    ok = _in_image(x, y, w, h)
                    if ok:
                        r = _round_half_up(y)
                        c = _round_half_up(x)
                        rn = _round_half_up(ny)
                        cn = _round_half_up(nx)
                        if r != rn or c != cn:
                            ok = _continues(depth_c[r, c], depth_c[rn, cn], max_step, quad)
            if not ok:  # an in-image pixel, never read through (the start pixel)
                r = v
                c = u
            out_x[v, u] = x
            out_y[v, u] = y
            out_ok[v, u] = ok
            out_row[v, u] = r
            out_col[v, u] = c
