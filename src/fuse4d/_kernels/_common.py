"""Numeric primitives shared by the kernels (private; compiled through ``_numba``).

* :data:`ROW_CHUNKS`: parallel loops run over this many row chunks.
* :func:`_balanced_row_bounds`: row chunks of about equal work where few pixels have any.
* :func:`_exp_neg_fast`: the bilateral weight function exp(-x) ~ (1 - x/1024)^1024.
* :func:`gauss_factor`: 1 / (2 sigma^2) for those weights, finite for any sigma > 0.
* :func:`_bilinear_stencil`: the clamped 2x2 stencil (indices, weights) of a bilinear sample.
* :func:`_bilinear2`: bilinear sample of a two-component (flow) field, stencil clamped.
* :func:`_bilinear2_plane`: the same on one (H, W, 2) field (a ring slot taken once per loop).
* :func:`_round_half_up`: METHOD §4.1 rounding floor(x + 0.5).
* :func:`_step_limit`: the one depth-step rule (A22) of every depth-continuity test.
* :func:`_difference`: central / one-sided difference of a point map (Eq. 6 Jacobian, A17
  normals).
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit

__all__ = [
    "EXP_POWER",
    "ROW_CHUNKS",
    "_balanced_row_bounds",
    "_bilinear2",
    "_bilinear2_plane",
    "_bilinear_stencil",
    "_difference",
    "_exp_neg_fast",
    "_round_half_up",
    "_step_limit",
    "gauss_factor",
]

#: parallel loops run over this many row chunks (scratch buffers are allocated per chunk:
#: allocating inside a prange body per row serialises the threads on the allocator)
ROW_CHUNKS = 64

#: exp(-x) ~ (1 - x / EXP_POWER) ** EXP_POWER (10 squarings): relative error x^2 / 2048, i.e.
#: 0.05 % at x = 1 and 0.8 % at x = 4; exactly 0 beyond x = EXP_POWER. Pure arithmetic, so the
#: bilateral loops vectorise (a table lookup or a libm call would not).
EXP_POWER = 1024.0


#: Largest Gaussian exponent factor handed to a kernel: any squared difference >= 1e-27 then
#: weighs 0 already, and a zero difference still weighs exp(0) = 1 in float32.
MAX_GAUSS_FACTOR = 1e30


def gauss_factor(sigma: float) -> float:
    """The exponent factor 1 / (2 sigma^2) of a Gaussian weight exp(-d^2 / (2 sigma^2)), at
    most :data:`MAX_GAUSS_FACTOR` (plain Python, for the kernels' arguments).

    Without the cap a sigma under ~1e-19 overflows float32 to inf, and a zero difference
    (the centre pixel) gets 0 x inf = NaN: every output NaN (``--set sigma_intensity=1e-30``
    emptied the whole result). With it, a vanishing sigma is the limit it should be: only
    equal values weigh.
    """
    s = float(sigma)
    two_var = 2.0 * s * s  # 0.0 for sigma < ~1e-162; inf (factor 0) past ~1e154, not an error
    return MAX_GAUSS_FACTOR if two_var * MAX_GAUSS_FACTOR <= 1.0 else 1.0 / two_var


@njit
def _balanced_row_bounds(row_work, n_chunks):
    """Row bounds ``b`` (n_chunks + 1,) int64 of chunks ``b[i] <= v < b[i + 1]`` that cover
    the rows in order with about equal total ``row_work`` (float64 (H,), >= 0) each.

    For the kernels whose work is a sparse set of target pixels (the sensor-hole fills): the
    parallel runtime hands each thread an equal share of the chunks in order, so chunks of
    equal rows leave one thread idle while the other fills the rows that hold most of the
    holes (measured on ``uva_cv2_person_turning``: 58 % / 42 % of a frame's time-fill targets
    in the two halves of the image). A chunk ends at the first row whose cumulative work
    reaches its share; chunks may be empty.
    """
    h = row_work.size
    total = 0.0
    for v in range(h):
        total += row_work[v]
    bounds = np.empty(n_chunks + 1, np.int64)
    bounds[0] = 0
    v = 0
    cum = 0.0
    for i in range(1, n_chunks):
        goal = total * i / n_chunks
        while v < h and cum + row_work[v] <= goal:
            cum += row_work[v]
            v += 1
        bounds[i] = v
    bounds[n_chunks] = h
    return bounds


@njit(inline="always")
def _exp_neg_fast(x):
    """exp(-x) for float32 x >= 0 as (1 - x/1024)^1024 (see :data:`EXP_POWER`)."""
    t = max(np.float32(1.0) - x * np.float32(1.0 / EXP_POWER), np.float32(0.0))
    for _ in range(10):
        t = t * t
    return t


@njit(inline="always")
def _bilinear_stencil(h, w, x, y):
    """The 2x2 stencil of a bilinear sample at (x = column, y = row) px of an H x W grid:
    ``(x0, y0, x1, y1, w00, w01, w10, w11)``, clamped at the last row/column (METHOD §4.1);
    ``wRC`` weighs the sample at row ``yR``, column ``xC``."""
    x0 = min(max(int(math.floor(x)), 0), max(w - 2, 0))
    y0 = min(max(int(math.floor(y)), 0), max(h - 2, 0))
    x1 = min(x0 + 1, w - 1)
    y1 = min(y0 + 1, h - 1)
    fx = x - x0 if w > 1 else 0.0
    fy = y - y0 if h > 1 else 0.0
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = fx * (1.0 - fy)
    w10 = (1.0 - fx) * fy
    w11 = fx * fy
    return x0, y0, x1, y1, w00, w01, w10, w11


@njit(inline="always")
def _bilinear2(ring, slot, x, y):
    """Bilinear sample of both components of ``ring[slot]`` (H, W, 2) at (x = column, y = row).

    The 2x2 stencil is clamped at the last row/column (METHOD §4.1); callers ensure
    0 <= x <= W-1 and 0 <= y <= H-1.
    """
    x0, y0, x1, y1, w00, w01, w10, w11 = _bilinear_stencil(ring.shape[1], ring.shape[2], x, y)
    a = (
        w00 * ring[slot, y0, x0, 0]
        + w01 * ring[slot, y0, x1, 0]
        + w10 * ring[slot, y1, x0, 0]
        + w11 * ring[slot, y1, x1, 0]
    )
    b = (
        w00 * ring[slot, y0, x0, 1]
        + w01 * ring[slot, y0, x1, 1]
        + w10 * ring[slot, y1, x0, 1]
        + w11 * ring[slot, y1, x1, 1]
    )
    return a, b


@njit(inline="always")
def _bilinear2_plane(field, x, y):
    """:func:`_bilinear2` on one (H, W, 2) field (``ring[slot]``): the same arithmetic, so
    the same bits; the slot's offset is taken once per loop instead of once per sample."""
    x0, y0, x1, y1, w00, w01, w10, w11 = _bilinear_stencil(field.shape[0], field.shape[1], x, y)
    a = (
        w00 * field[y0, x0, 0]
        + w01 * field[y0, x1, 0]
        + w10 * field[y1, x0, 0]
        + w11 * field[y1, x1, 0]
    )
    b = (
        w00 * field[y0, x0, 1]
        + w01 * field[y0, x1, 1]
        + w10 * field[y1, x0, 1]
        + w11 * field[y1, x1, 1]
    )
    return a, b


@njit(inline="always")
def _round_half_up(x):
    """floor(x + 0.5): METHOD §4.1 rounding (not round-half-to-even)."""
    return np.int64(math.floor(x + 0.5))


@njit(inline="always")
def _step_limit(z, max_step, quad):
    """Largest plausible depth change (mm) between neighbours at depth z (mm): the fixed
    ``max_step`` (tau_jump) or, on quantised/noisy far depth, 2.5 noise levels of the frame's
    depth-noise model sigma(z) = quad * z^2 (A22), whichever is larger.

    The one depth-continuity rule: tracking steps, the per-pair motion field, the segments of
    the motion-reference smoothing and the reference-surface normals all use it.
    """
    return max(max_step, 2.5 * quad * z * z)


@njit(inline="always")
def _difference(points, v, u, dv, du, plus, minus):
    """Derivative of the point map ``points`` (H, W, 3) at (v, u) along the pixel step (dv, du).

    Central difference when both neighbours qualify (``plus``: (v + dv, u + du), ``minus``:
    (v - dv, u - du)), one-sided when only one does. Returns ``(ok, gx, gy, gz)`` in mm/px;
    ``ok`` is False (and the derivative 0) when neither neighbour qualifies.
    """
    vp, up = v + dv, u + du
    vm, um = v - dv, u - du
    gx = 0.0
    gy = 0.0
    gz = 0.0
    if plus and minus:
        gx = 0.5 * (points[vp, up, 0] - points[vm, um, 0])
        gy = 0.5 * (points[vp, up, 1] - points[vm, um, 1])
        gz = 0.5 * (points[vp, up, 2] - points[vm, um, 2])
    elif plus:
        gx = points[vp, up, 0] - points[v, u, 0]
        gy = points[vp, up, 1] - points[v, u, 1]
        gz = points[vp, up, 2] - points[v, u, 2]
    elif minus:
        gx = points[v, u, 0] - points[vm, um, 0]
        gy = points[v, u, 1] - points[vm, um, 1]
        gz = points[v, u, 2] - points[vm, um, 2]
    return plus or minus, gx, gy, gz
