"""Numba kernels of the roughness metric (paper Eq. 7, EVALUATION §1). Private.

The public wrappers live in :mod:`fuse4d.metrics`; these only fill preallocated buffers.
"""

from __future__ import annotations

import math

import numpy as np

from ._common import ROW_CHUNKS
from ._numba import njit, njit_parallel, prange

#: Newton steps from c = -1 on 4 c^3 - 3 c = r, whose smallest root c = cos(acos(r) / 3 +
#: 2 pi / 3) gives the smallest eigenvalue (trigonometric method): g is increasing and concave
#: on [-1, -1/2], so the steps rise to the root without overshooting. Six steps reach float64
#: precision (<= 4.5e-16 from the trigonometric value on a 1e-4 grid of r) for r <= 0.8, i.e.
#: wherever the two smallest eigenvalues are not close (a plane-like window: r near -1); above
#: (a line-like window, a double root at r = 1) the trigonometric formula is used.
_NEWTON_STEPS = 6
_NEWTON_MAX_R = 0.8


@njit(inline="always", error_model="numpy")
def _eig_setup(a00, a01, a02, a11, a12, a22):
    """``(q, p, p2, r)`` of the trigonometric method: the eigenvalues are
    q + 2 p c_k with c_k the roots of 4 c^3 - 3 c = r (p2 = 6 p^2; p2 <= 0: A = q I)."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    b00 = a00 - q
    b11 = a11 - q
    b22 = a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = math.sqrt(max(p2, 0.0) / 6.0)
    inv = 1.0 / p if p > 0.0 else 0.0
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
    r = min(1.0, max(-1.0, det / 2.0))
    return q, p, p2, r


@njit(inline="always", error_model="numpy")
def _eigvec_of(a00, a01, a02, a11, a12, a22, q, p2, lam):
    """Unit eigenvector of eigenvalue ``lam``: the largest cross product of two rows of
    ``A - lam I``; Z where A = q I (``p2`` <= 0) or the rows are degenerate. Branch-free
    (selects), so that a loop over pixels vectorises. Returns ``(nx, ny, nz, lam, nn)``,
    ``nn`` the squared norm of that cross product (unused where inlined: no cost)."""
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
    first = (n0 >= n1) & (n0 >= n2)
    second = (not first) & (n1 >= n2)
    nx = x0 if first else (x1 if second else x2)
    ny = y0 if first else (y1 if second else y2)
    nz = z0 if first else (z1 if second else z2)
    nn = n0 if first else (n1 if second else n2)
    ok = (nn > 0.0) & (p2 > 0.0)
    s = 1.0 / math.sqrt(nn) if ok else 0.0
    return (nx * s if ok else 0.0), (ny * s if ok else 0.0), (nz * s if ok else 1.0), lam, nn


@njit(inline="always", error_model="numpy")
def _eigvec_of_rank1_safe(a00, a01, a02, a11, a12, a22, q, p2, lam):
    """:func:`_eigvec_of`, also where ``A - lam I`` has rank 1 (a double ``lam``).

    Collinear points (A of rank 1) have a double smallest eigenvalue: every cross product of
    two rows of ``A - lam I`` is rounding noise, and the normal was not perpendicular to the
    points' line (two points scored 1-2 % of their distance). Any unit vector perpendicular
    to the largest row is then an eigenvector: that row crossed with the axis least along it.
    Only the scalar path needs it (a double smallest root has r = 1, beyond the Newton
    path's range); there the extra selects cost a third of the vectorised kernel's time.
    """
    nx, ny, nz, lam, nn = _eigvec_of(a00, a01, a02, a11, a12, a22, q, p2, lam)
    m00 = a00 - lam
    m11 = a11 - lam
    m22 = a22 - lam
    s0 = m00 * m00 + a01 * a01 + a02 * a02
    s1 = a01 * a01 + m11 * m11 + a12 * a12
    s2 = a02 * a02 + a12 * a12 + m22 * m22
    if p2 <= 0.0 or nn > 1e-20 * max(s0, s1, s2) ** 2:  # |r_i x r_j|^2 <= max |r|^4
        return nx, ny, nz, lam
    f0 = (s0 >= s1) & (s0 >= s2)
    f1 = (not f0) & (s1 >= s2)
    vx = m00 if f0 else (a01 if f1 else a02)
    vy = a01 if f0 else (m11 if f1 else a12)
    vz = a02 if f0 else (a12 if f1 else m22)
    kx = (abs(vx) <= abs(vy)) & (abs(vx) <= abs(vz))
    ky = (not kx) & (abs(vy) <= abs(vz))
    px = 0.0 if kx else (-vz if ky else vy)  # v x e_x, v x e_y, v x e_z
    py = vz if kx else (0.0 if ky else -vx)
    pz = -vy if kx else (vx if ky else 0.0)
    norm = math.sqrt(px * px + py * py + pz * pz)
    if norm == 0.0:  # A - lam I = 0 (A = lam I): any direction, as _eigvec_of
        return nx, ny, nz, lam
    return px / norm, py / norm, pz / norm, lam


@njit
def _smallest_eigvec_kernel(a00, a01, a02, a11, a12, a22):
    """Unit eigenvector of the smallest eigenvalue of a symmetric PSD 3x3 matrix.

    Closed form: eigenvalues by the trigonometric method, the eigenvector as the largest
    cross product of two rows of ``A - lambda_min I``. Returns ``(nx, ny, nz, lambda_min)``.
    """
    q, p, p2, r = _eig_setup(a00, a01, a02, a11, a12, a22)
    if p2 <= 0.0:  # A = q I: any direction; take Z
        return 0.0, 0.0, 1.0, q
    phi = math.acos(r) / 3.0
    lam = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)  # smallest eigenvalue
    return _eigvec_of_rank1_safe(a00, a01, a02, a11, a12, a22, q, p2, lam)


@njit(inline="always", error_model="numpy")
def _smallest_eigvec_newton(a00, a01, a02, a11, a12, a22):
    """:func:`_smallest_eigvec_kernel` with the cosine found by :data:`_NEWTON_STEPS` Newton
    steps instead of ``acos`` and ``cos`` (library calls, which keep a loop scalar). Returns
    ``(nx, ny, nz, lambda_min, exact)``; ``exact`` False (r > :data:`_NEWTON_MAX_R`): use
    :func:`_smallest_eigvec_kernel`."""
    q, p, p2, r = _eig_setup(a00, a01, a02, a11, a12, a22)
    c = -1.0
    for _ in range(_NEWTON_STEPS):
        # g' > 0 left of the root (r <= 0.8); the floor only keeps an r near 1 finite
        c -= (4.0 * c * c * c - 3.0 * c - r) / max(12.0 * c * c - 3.0, 1e-300)
    lam = q + 2.0 * p * c if p2 > 0.0 else q
    nx, ny, nz, lam, _ = _eigvec_of(a00, a01, a02, a11, a12, a22, q, p2, lam)
    return nx, ny, nz, lam, (r <= _NEWTON_MAX_R) | (p2 <= 0.0)


@njit(inline="always", error_model="numpy")
def _plane_fit_from_normal(cnt, mx, my, mz, a00, a01, a02, a11, a12, a22, nx, ny, nz):
    """``(N |(p_i - c) . n|, sqrt(n^T S n / N))`` (mm) of one window from its count ``cnt``,
    the centroid relative to the centre point (mx, my, mz), the scatter matrix S about the
    centroid (a00 .. a22) and the plane's unit normal n, float64."""
    # centre minus centroid is (-mx, -my, -mz)
    dist = -(mx * nx + my * ny + mz * nz)
    quad = (
        a00 * nx * nx
        + a11 * ny * ny
        + a22 * nz * nz
        + 2.0 * (a01 * nx * ny + a02 * nx * nz + a12 * ny * nz)
    )
    return cnt * abs(dist), math.sqrt(max(quad, 0.0) / max(cnt, 1.0))  # cnt 0: not scored


@njit(inline="always")
def _centroid_offset(qx, qy, qz, px, py, pz, cnt, sx, sy, sz):  # pragma: no cover - compiled
    """First pass, one window offset over a row (1D slices; this loop vectorises): the count
    and the sums of the valid neighbours ``q`` relative to the centres ``p`` (float64).
    Inlined, as :func:`_scatter_offset` (2 n^2 calls a row, each with ten or more array
    arguments): the kernel is a fifth faster (640 x 480, one thread: 20-21 ms called,
    15-17 ms inlined) and its values the same bits (stop 39)."""
    for u in range(px.shape[0]):
        x = float(qx[u])
        y = float(qy[u])
        z = float(qz[u])
        ok = not (math.isnan(x) | math.isnan(y) | math.isnan(z))
        cnt[u] += 1.0 if ok else 0.0
        sx[u] += (x - float(px[u])) if ok else 0.0
        sy[u] += (y - float(py[u])) if ok else 0.0
        sz[u] += (z - float(pz[u])) if ok else 0.0


@njit(inline="always")
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


#: ``error_model="numpy"``: a division by zero gives inf / NaN instead of raising, so the plane
#: fits of the pixels that are not scored (count 0) cost no test and the loop vectorises
@njit(error_model="numpy")
def _roughness_row(planes, t, i, radius, min_count, mask, masked, sums, out_sum, out_rms):
    """Row ``i`` of frame ``t`` of :func:`_roughness_kernel` (``planes``: (T, 3, H, W) float32
    x, y, z planes; ``sums``: (14, W) float64 scratch).

    Offset-major: for each window offset (di, dj) a loop over the row's columns
    (:func:`_centroid_offset`, :func:`_scatter_offset`), so that it vectorises; each pixel
    still sees its window's points in the order di, then dj, with the arithmetic of a
    per-pixel two-pass loop (float64: a first pass for the count and the centroid relative to
    the centre point, a second for the scatter matrix about it), so the values are those of
    that loop (the per-pixel kernel this replaced in stop 35, several times slower at
    640 x 480: its branches and gathers kept every loop scalar).

    ``masked``: only the span of the row from its first to its last ``mask`` pixel is summed
    and fitted (NaN outside it; a row without one is all NaN) (the run summary's ROI:
    a uva map 15.3 -> 12.5 ms on one thread, stop 40); the values inside are the same bits.
    """
    h, w = planes.shape[2], planes.shape[3]
    lo, hi = 0, w
    if masked:  # the row's span of scored pixels
        while lo < w and not mask[t, i, lo]:
            lo += 1
        while hi > lo and not mask[t, i, hi - 1]:
            hi -= 1  # (no mask pixel: lo = hi = w, every pass below is empty, all NaN)
    sums[:10] = 0.0
    cnt, sx, sy, sz = sums[0], sums[1], sums[2], sums[3]
    a00, a01, a02, a11, a12, a22 = sums[4], sums[5], sums[6], sums[7], sums[8], sums[9]
    mx, my, mz, again = sums[10], sums[11], sums[12], sums[13]
    px, py, pz = planes[t, 0, i], planes[t, 1, i], planes[t, 2, i]
    rows = range(max(0, i - radius), min(h, i + radius + 1))
    for di in rows:
        qx, qy, qz = planes[t, 0, di], planes[t, 1, di], planes[t, 2, di]
        for dj in range(-radius, radius + 1):
            u0, u1 = max(lo, -dj), min(hi, w - dj)
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
            u0, u1 = max(lo, -dj), min(hi, w - dj)
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
    # the plane fits of the span (NaN outside it)
    nan = np.nan
    out_sum[t, i, :lo] = nan
    out_rms[t, i, :lo] = nan
    out_sum[t, i, hi:] = nan
    out_rms[t, i, hi:] = nan
    _fit_span(
        px[lo:hi],
        py[lo:hi],
        pz[lo:hi],
        cnt[lo:hi],
        mx[lo:hi],
        my[lo:hi],
        mz[lo:hi],
        a00[lo:hi],
        a01[lo:hi],
        a02[lo:hi],
        a11[lo:hi],
        a12[lo:hi],
        a22[lo:hi],
        again[lo:hi],
        mask[t, i, lo:hi] if masked else mask[0, 0, :0],
        masked,
        min_count,
        out_sum[t, i, lo:hi],
        out_rms[t, i, lo:hi],
    )


@njit(inline="always", error_model="numpy")
def _fit_span(
    px,
    py,
    pz,
    cnt,
    mx,
    my,
    mz,
    a00,
    a01,
    a02,
    a11,
    a12,
    a22,
    again,
    mask,
    masked,
    min_count,
    out_sum,
    out_rms,
):  # pragma: no cover - compiled
    """The plane fits of a row's span of centres (1D views of the row's sums and outputs,
    :func:`_roughness_row`): a vectorised pass (Newton's cosine), then the few line-like
    windows again with the trigonometric formula (``exact`` False, marked in ``again``).
    Views indexed from 0 on purpose: the same loop over ``range(lo, hi)`` of the whole rows
    does not vectorise (a masked 640 x 480 map took twice as long, stop 40)."""
    nan = np.nan
    for u in range(px.shape[0]):
        x, y, z = px[u], py[u], pz[u]
        use = (not (math.isnan(x) | math.isnan(y) | math.isnan(z))) & (cnt[u] >= min_count)
        if masked:
            use &= mask[u]
        nx, ny, nz, _, exact = _smallest_eigvec_newton(
            a00[u], a01[u], a02[u], a11[u], a12[u], a22[u]
        )
        pi, rms = _plane_fit_from_normal(
            cnt[u], mx[u], my[u], mz[u], a00[u], a01[u], a02[u], a11[u], a12[u], a22[u], nx, ny, nz
        )
        out_sum[u] = pi if use else nan
        out_rms[u] = rms if use else nan
        again[u] = 1.0 if (use & (not exact)) else 0.0
    for u in range(px.shape[0]):
        if again[u] != 0.0:
            nx, ny, nz, _ = _smallest_eigvec_kernel(a00[u], a01[u], a02[u], a11[u], a12[u], a22[u])
            out_sum[u], out_rms[u] = _plane_fit_from_normal(
                cnt[u],
                mx[u],
                my[u],
                mz[u],
                a00[u],
                a01[u],
                a02[u],
                a11[u],
                a12[u],
                a22[u],
                nx,
                ny,
                nz,
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
        sums = np.empty((14, w), np.float64)
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
        sums = np.empty((14, w), np.float64)
        for tr in range(ci * num_t * h // n_chunks, (ci + 1) * num_t * h // n_chunks):
            _roughness_row(
                planes, tr // h, tr % h, radius, min_count, mask, True, sums, out_sum, out_rms
            )
