"""Numba kernels of the roughness metric (paper Eq. 7, EVALUATION §1). Private.

The public wrappers live in :mod:`fuse4d.metrics`; these only fill preallocated buffers.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit, njit_parallel, prange


@njit
def _smallest_eigvec_kernel(a00, a01, a02, a11, a12, a22):
    """Unit eigenvector of the smallest eigenvalue of a symmetric PSD 3x3 matrix.

    Closed form: eigenvalues by the trigonometric method, the eigenvector as the largest
    cross product of two rows of ``A - lambda_min I``. Returns ``(nx, ny, nz, lambda_min)``.
    """
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    b00 = a00 - q
    b11 = a11 - q
    b22 = a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    if p2 <= 0.0:  # A = q I: any direction; take Z
        return 0.0, 0.0, 1.0, q
    p = math.sqrt(p2 / 6.0)
    inv = 1.0 / p
    c00 = b00 * inv
    c11 = b11 * inv
    c22 = b22 * inv
    c01 = a01 * inv
    c02 = a02 * inv
    c12 = a12 * inv
    det = (
        c00 * (c11 * c22 - c12 * c12)
        - c01 * (c01 * c22 - c12 * c02)
        + c02 * (c01 * c12 - c11 * c02)
    )
    r = det / 2.0
    r = min(1.0, max(-1.0, r))
    phi = math.acos(r) / 3.0
    lam = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)  # smallest eigenvalue
    # rows of M = A - lam I
    m00 = a00 - lam
    m11 = a11 - lam
    m22 = a22 - lam
    # cross products r0 x r1, r0 x r2, r1 x r2
    x0 = a01 * a12 - a02 * m11
    y0 = a02 * a01 - m00 * a12
    z0 = m00 * m11 - a01 * a01
    x1 = a01 * m22 - a02 * a12
    y1 = a02 * a02 - m00 * m22
    z1 = m00 * a12 - a01 * a02
    x2 = m11 * m22 - a12 * a12
    y2 = a12 * a02 - a01 * m22
    z2 = a01 * a12 - m11 * a02
    n0 = x0 * x0 + y0 * y0 + z0 * z0
    n1 = x1 * x1 + y1 * y1 + z1 * z1
    n2 = x2 * x2 + y2 * y2 + z2 * z2
    if n0 >= n1 and n0 >= n2:
        nx, ny, nz, nn = x0, y0, z0, n0
    elif n1 >= n2:
        nx, ny, nz, nn = x1, y1, z1, n1
    else:
        nx, ny, nz, nn = x2, y2, z2, n2
    if nn <= 0.0:  # two or three equal smallest eigenvalues: degenerate, pick Z
        return 0.0, 0.0, 1.0, lam
    s = 1.0 / math.sqrt(nn)
    return nx * s, ny * s, nz * s, lam


@njit(inline="always")
def _window_point(points, t, i, j):
    """``(x, y, z, valid)`` of pixel ``(t, i, j)``: mm as float64, valid = no NaN coordinate.

    float() promotes the float32 samples to float64 (identically with and without JIT).
    """
    x = float(points[t, i, j, 0])
    y = float(points[t, i, j, 1])
    z = float(points[t, i, j, 2])
    return x, y, z, not (math.isnan(x) or math.isnan(y) or math.isnan(z))


@njit
def _pixel_roughness_kernel(points, t, i, j, radius, min_count):
    """``(N |(p_i - c) . n|, sqrt(n^T S n / N))`` (mm) of pixel ``(t, i, j)``; NaN, NaN where
    the centre is invalid or fewer than ``min_count`` window points are valid."""
    h, w = points.shape[1], points.shape[2]
    px, py, pz, valid = _window_point(points, t, i, j)
    if not valid:
        return np.nan, np.nan
    # first pass: centroid relative to the centre point (better conditioning)
    cnt = 0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for di in range(max(0, i - radius), min(h, i + radius + 1)):
        for dj in range(max(0, j - radius), min(w, j + radius + 1)):
            qx, qy, qz, valid = _window_point(points, t, di, dj)
            if not valid:
                continue
            cnt += 1
            sx += qx - px
            sy += qy - py
            sz += qz - pz
    if cnt < min_count:
        return np.nan, np.nan
    mx = sx / cnt
    my = sy / cnt
    mz = sz / cnt
    a00 = 0.0
    a01 = 0.0
    a02 = 0.0
    a11 = 0.0
    a12 = 0.0
    a22 = 0.0
    for di in range(max(0, i - radius), min(h, i + radius + 1)):
        for dj in range(max(0, j - radius), min(w, j + radius + 1)):
            qx, qy, qz, valid = _window_point(points, t, di, dj)
            if not valid:
                continue
            dx = qx - px - mx
            dy = qy - py - my
            dz = qz - pz - mz
            a00 += dx * dx
            a01 += dx * dy
            a02 += dx * dz
            a11 += dy * dy
            a12 += dy * dz
            a22 += dz * dz
    nx, ny, nz, _ = _smallest_eigvec_kernel(a00, a01, a02, a11, a12, a22)
    # centre minus centroid is (-mx, -my, -mz)
    dist = -(mx * nx + my * ny + mz * nz)
    quad = (
        a00 * nx * nx
        + a11 * ny * ny
        + a22 * nz * nz
        + 2.0 * (a01 * nx * ny + a02 * nx * nz + a12 * ny * nz)
    )
    return cnt * abs(dist), math.sqrt(max(quad, 0.0) / cnt)


@njit_parallel
def _roughness_kernel(points, radius, min_count, out_sum, out_rms):
    """Per-pixel roughness Pi (Eq. 7) and RMS plane residual on point maps.

    Parameters
    ----------
    points : (T, H, W, 3) float32
        Point maps in mm, NaN = invalid.
    radius : int
        Window half-size (window n = 2 radius + 1); pixels outside the image count as invalid.
    min_count : int
        Minimum number of valid window points (the centre must be valid too).
    out_sum, out_rms : (T, H, W) float32
        Filled with ``N |(p_i - c) . n|`` and ``sqrt(n^T S n / N)`` (mm); NaN where undefined.
    """
    num_t, h, w = points.shape[0], points.shape[1], points.shape[2]
    for tr in prange(num_t * h):
        t = tr // h
        i = tr % h
        for j in range(w):
            out_sum[t, i, j], out_rms[t, i, j] = _pixel_roughness_kernel(
                points, t, i, j, radius, min_count
            )


@njit_parallel
def _roughness_masked_kernel(points, mask, radius, min_count, out_sum, out_rms):
    """:func:`_roughness_kernel` on the ``mask`` (T, H, W) bool pixels only (NaN elsewhere):
    the summary of ``fuse4d run`` scores only its ROI's pixels."""
    num_t, h, w = points.shape[0], points.shape[1], points.shape[2]
    for tr in prange(num_t * h):
        t = tr // h
        i = tr % h
        for j in range(w):
            if mask[t, i, j]:
                out_sum[t, i, j], out_rms[t, i, j] = _pixel_roughness_kernel(
                    points, t, i, j, radius, min_count
                )
            else:
                out_sum[t, i, j] = np.nan
                out_rms[t, i, j] = np.nan
