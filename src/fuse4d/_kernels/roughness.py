"""Numba kernels of the roughness metric (paper Eq. 7, EVALUATION §1). Private.

The public wrappers live in :mod:`fuse4d.metrics`; these only fill preallocated buffers.
"""

from __future__ import annotations

import math

import numpy as np

from ._common import ROW_CHUNKS
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
def _plane_fit_values(cnt, mx, my, mz, a00, a01, a02, a11, a12, a22):
    """``(N |(p_i - c) . n|, sqrt(n^T S n / N))`` (mm) of one window from its count ``cnt``,
    the centroid relative to the centre point (mx, my, mz) and the scatter matrix S about the
    centroid (a00 .. a22), float64."""
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


@njit
def _centroid_offset(qx, qy, qz, px, py, pz, cnt, sx, sy, sz):  # pragma: no cover - compiled
    """First pass, one window offset over a row (1D slices; this loop vectorises): the count
    and the sums of the valid neighbours ``q`` relative to the centres ``p`` (float64)."""
    for u in range(px.shape[0]):
        x = float(qx[u])
        y = float(qy[u])
        z = float(qz[u])
        ok = not (math.isnan(x) | math.isnan(y) | math.isnan(z))
        cnt[u] += 1.0 if ok else 0.0
        sx[u] += (x - float(px[u])) if ok else 0.0
        sy[u] += (y - float(py[u])) if ok else 0.0
        sz[u] += (z - float(pz[u])) if ok else 0.0


@njit
def _scatter_offset(
    qx, qy, qz, px, py, pz, mx, my, mz, a00, a01, a02, a11, a12, a22
):  # pragma: no cover - compiled
    """Second pass, one window offset over a row (1D slices; this loop vectorises): the
    scatter sums of the valid neighbours about the centroid (mx, my, mz) relative to ``p``."""
    for u in range(px.shape[0]):
        x = float(qx[u])
        y = float(qy[u])
        z = float(qz[u])
        ok = not (math.isnan(x) | math.isnan(y) | math.isnan(z))
        dx = x - float(px[u]) - mx[u]
        dy = y - float(py[u]) - my[u]
        dz = z - float(pz[u]) - mz[u]
        a00[u] += (dx * dx) if ok else 0.0
        a01[u] += (dx * dy) if ok else 0.0
        a02[u] += (dx * dz) if ok else 0.0
        a11[u] += (dy * dy) if ok else 0.0
        a12[u] += (dy * dz) if ok else 0.0
        a22[u] += (dz * dz) if ok else 0.0


@njit
def _roughness_row(planes, t, i, radius, min_count, mask, masked, sums, out_sum, out_rms):
    """Row ``i`` of frame ``t`` of :func:`_roughness_kernel` (``planes``: (T, 3, H, W) float32
    x, y, z planes; ``sums``: (13, W) float64 scratch).

    Offset-major: for each window offset (di, dj) a loop over the row's columns
    (:func:`_centroid_offset`, :func:`_scatter_offset`), so that it vectorises; each pixel
    still sees its window's points in the order di, then dj, with the arithmetic of a
    per-pixel two-pass loop (float64: a first pass for the count and the centroid relative to
    the centre point, a second for the scatter matrix about it), so the values are those of
    that loop (the per-pixel kernel this replaced in stop 35, several times slower at
    640 x 480: its branches and gathers kept every loop scalar).
    """
    h, w = planes.shape[2], planes.shape[3]
    sums[:10] = 0.0
    cnt, sx, sy, sz = sums[0], sums[1], sums[2], sums[3]
    a00, a01, a02, a11, a12, a22 = sums[4], sums[5], sums[6], sums[7], sums[8], sums[9]
    mx, my, mz = sums[10], sums[11], sums[12]
    px, py, pz = planes[t, 0, i], planes[t, 1, i], planes[t, 2, i]
    rows = range(max(0, i - radius), min(h, i + radius + 1))
    for di in rows:
        qx, qy, qz = planes[t, 0, di], planes[t, 1, di], planes[t, 2, di]
        for dj in range(-radius, radius + 1):
            u0, u1 = max(0, -dj), min(w, w - dj)
            if u1 > u0:
                _centroid_offset(
                    qx[u0 + dj : u1 + dj],
                    qy[u0 + dj : u1 + dj],
                    qz[u0 + dj : u1 + dj],
                    px[u0:u1],
                    py[u0:u1],
                    pz[u0:u1],
                    cnt[u0:u1],
                    sx[u0:u1],
                    sy[u0:u1],
                    sz[u0:u1],
                )
    for u in range(w):
        n = cnt[u] if cnt[u] > 0.0 else 1.0
        mx[u] = sx[u] / n
        my[u] = sy[u] / n
        mz[u] = sz[u] / n
    for di in rows:
        qx, qy, qz = planes[t, 0, di], planes[t, 1, di], planes[t, 2, di]
        for dj in range(-radius, radius + 1):
            u0, u1 = max(0, -dj), min(w, w - dj)
            if u1 > u0:
                _scatter_offset(
                    qx[u0 + dj : u1 + dj],
                    qy[u0 + dj : u1 + dj],
                    qz[u0 + dj : u1 + dj],
                    px[u0:u1],
                    py[u0:u1],
                    pz[u0:u1],
                    mx[u0:u1],
                    my[u0:u1],
                    mz[u0:u1],
                    a00[u0:u1],
                    a01[u0:u1],
                    a02[u0:u1],
                    a11[u0:u1],
                    a12[u0:u1],
                    a22[u0:u1],
                )
    for u in range(w):
        x, y, z = float(px[u]), float(py[u]), float(pz[u])
        centre_ok = not (math.isnan(x) or math.isnan(y) or math.isnan(z))
        if not centre_ok or cnt[u] < min_count or (masked and not mask[t, i, u]):
            out_sum[t, i, u] = np.nan
            out_rms[t, i, u] = np.nan
            continue
        out_sum[t, i, u], out_rms[t, i, u] = _plane_fit_values(
            cnt[u], mx[u], my[u], mz[u], a00[u], a01[u], a02[u], a11[u], a12[u], a22[u]
        )


@njit_parallel
def _roughness_kernel(planes, radius, min_count, out_sum, out_rms):
    """Per-pixel roughness Pi (Eq. 7) and RMS plane residual on point maps.

    Parameters
    ----------
    planes : (T, 3, H, W) float32
        Point maps in mm as x, y, z planes (contiguous rows: the loops vectorise), NaN =
        invalid.
    radius : int
        Window half-size (window n = 2 radius + 1); pixels outside the image count as invalid.
    min_count : int
        Minimum number of valid window points (the centre must be valid too).
    out_sum, out_rms : (T, H, W) float32
        Filled with ``N |(p_i - c) . n|`` and ``sqrt(n^T S n / N)`` (mm); NaN where undefined.
    """
    num_t, h, w = planes.shape[0], planes.shape[2], planes.shape[3]
    no_mask = np.zeros((1, 1, 1), np.bool_)
    n_chunks = min(num_t * h, ROW_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk, not per row
        sums = np.empty((13, w), np.float64)
        for tr in range(ci * num_t * h // n_chunks, (ci + 1) * num_t * h // n_chunks):
            _roughness_row(
                planes, tr // h, tr % h, radius, min_count, no_mask, False, sums, out_sum, out_rms
            )


@njit_parallel
def _roughness_masked_kernel(planes, mask, radius, min_count, out_sum, out_rms):
    """:func:`_roughness_kernel` on the ``mask`` (T, H, W) bool pixels only (NaN elsewhere):
    the summary of ``fuse4d run`` scores only its ROI's pixels."""
    num_t, h, w = planes.shape[0], planes.shape[2], planes.shape[3]
    n_chunks = min(num_t * h, ROW_CHUNKS)
    for ci in prange(n_chunks):
        sums = np.empty((13, w), np.float64)
        for tr in range(ci * num_t * h // n_chunks, (ci + 1) * num_t * h // n_chunks):
            _roughness_row(
                planes, tr // h, tr % h, radius, min_count, mask, True, sums, out_sum, out_rms
            )
