"""Kernels of the baselines besides the joint bilateral: ST-MF, TA, and Ad-GF's PCA view angle.

Private; arrays and scalars only; the public wrappers live in ``fuse4d.baselines``.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit_parallel, prange

__all__ = [
    "_block_match_kernel",
    "_pca_view_angle_kernel",
    "_stmf_median_kernel",
    "_temporal_average_kernel",
]


@njit_parallel
def _block_match_kernel(reference, moving, block, search, out):  # pragma: no cover - compiled
    """Full-search block matching (SAD) of ``reference`` blocks in ``moving``.

    Parameters
    ----------
    reference, moving : (H, W) float32
        Intensity frames t and τ.
    block : int
        Block size (px); edge blocks are truncated.
    search : int
        Search range ±``search`` px.
    out : (BH, BW, 2) int32
        Vector per block, ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row), such that
        ``moving[x + v] ≈ reference[x]``. Displacements that move the block outside the image
        are not considered; ties keep the shorter vector (the search starts at 0).
    """
    height, width = reference.shape
    n_brow, n_bcol = out.shape[0], out.shape[1]
    for br in prange(n_brow):
        r0 = br * block
        r1 = min(r0 + block, height)
        for bc in range(n_bcol):
            c0 = bc * block
            c1 = min(c0 + block, width)
            best = 0.0
            for rr in range(r0, r1):
                for cc in range(c0, c1):
                    best += abs(reference[rr, cc] - moving[rr, cc])
            best_du = 0
            best_dv = 0
            best_len = 0
            for dv in range(-search, search + 1):
                if r0 + dv < 0 or r1 + dv > height:
                    continue
                for du in range(-search, search + 1):
                    if c0 + du < 0 or c1 + du > width:
                        continue
                    if du == 0 and dv == 0:
                        continue
                    sad = 0.0
                    for rr in range(r0, r1):
                        for cc in range(c0, c1):
                            sad += abs(reference[rr, cc] - moving[rr + dv, cc + du])
                        if sad > best:
                            break
                    length = du * du + dv * dv
                    if sad < best or (sad == best and length < best_len):
                        best = sad
                        best_du = du
                        best_dv = dv
                        best_len = length
            out[br, bc, 0] = best_du
            out[br, bc, 1] = best_dv


@njit_parallel
def _stmf_median_kernel(
    depth, intensity, ref, vectors, half_window, intensity_tol, out
):  # pragma: no cover - compiled
    """Median of the motion-compensated, intensity-checked candidates (ST-MF step 2–3).

    Parameters
    ----------
    depth, intensity : (K, H, W) float32
        Window frames (depth mm, NaN = invalid; intensity [0, 1]).
    ref : int
        Index of frame t in the window.
    vectors : (K, H, W, 2) int32
        Per-pixel vector of each frame toward frame t (du, dv); zeros for ``ref``.
    half_window : int
        a, the spatial half window ((2a+1)² offsets).
    intensity_tol : float
        τ_I: candidates with |I_τ(x+v+o) − I_t(x+o)| ≥ τ_I are rejected.
    out : (H, W) float32
        Median of the candidates; NaN when there are none.
    """
    n_frames, height, width = depth.shape
    cap = n_frames * (2 * half_window + 1) * (2 * half_window + 1)
    for row in prange(height):
        buf = np.empty(cap, np.float32)
        for col in range(width):
            n = 0
            for k in range(n_frames):
                du = vectors[k, row, col, 0]
                dv = vectors[k, row, col, 1]
                for orow in range(-half_window, half_window + 1):
                    tr = row + orow
                    sr = tr + dv
                    if tr < 0 or tr >= height or sr < 0 or sr >= height:
                        continue
                    for ocol in range(-half_window, half_window + 1):
                        tc = col + ocol
                        sc = tc + du
                        if tc < 0 or tc >= width or sc < 0 or sc >= width:
                            continue
                        value = depth[k, sr, sc]
                        if math.isnan(value):
                            continue
                        if abs(intensity[k, sr, sc] - intensity[ref, tr, tc]) >= intensity_tol:
                            continue
                        # insertion into the sorted prefix
                        j = n
                        while j > 0 and buf[j - 1] > value:
                            buf[j] = buf[j - 1]
                            j -= 1
                        buf[j] = value
                        n += 1
            if n == 0:
                out[row, col] = np.nan
            elif n % 2 == 1:
                out[row, col] = buf[n // 2]
            else:
                out[row, col] = 0.5 * (buf[n // 2 - 1] + buf[n // 2])


@njit_parallel
def _pca_view_angle_kernel(points, half, min_count, out):  # pragma: no cover - compiled
    """Angle (rad) between the PCA normal of a (2·half+1)² window and the camera ray (Ad-GF).

    Parameters
    ----------
    points : (H, W, 3) float32
        Point map (mm), NaN = invalid.
    half : int
        Window half size (2 for the spec's 5×5 window).
    min_count : int
        Minimum valid points in the window; fewer (or an invalid centre) gives 0.
    out : (H, W) float32
        θ in [0, π/2]; the normal is the eigenvector of the smallest eigenvalue of the
        window covariance (closed-form symmetric 3×3 eigenvalues, then a cross product of two
        rows of C − λI).
    """
    height, width = out.shape
    for row in prange(height):
        for col in range(width):
            px = points[row, col, 0]
            py = points[row, col, 1]
            pz = points[row, col, 2]
            out[row, col] = 0.0
            if math.isnan(pz):
                continue
            n = 0
            sx = sy = sz = 0.0
            sxx = syy = szz = sxy = sxz = syz = 0.0
            for rr in range(max(row - half, 0), min(row + half + 1, height)):
                for cc in range(max(col - half, 0), min(col + half + 1, width)):
                    z = points[rr, cc, 2]
                    if math.isnan(z):
                        continue
                    x = points[rr, cc, 0] - px  # centred on the pixel for conditioning
                    y = points[rr, cc, 1] - py
                    z = z - pz
                    n += 1
                    sx += x
                    sy += y
                    sz += z
                    sxx += x * x
                    syy += y * y
                    szz += z * z
                    sxy += x * y
                    sxz += x * z
                    syz += y * z
            if n < min_count:
                continue
            mx, my, mz = sx / n, sy / n, sz / n
            a = sxx / n - mx * mx
            b = syy / n - my * my
            c = szz / n - mz * mz
            d = sxy / n - mx * my
            e = sxz / n - mx * mz
            f = syz / n - my * mz
            # smallest eigenvalue (trigonometric method for symmetric 3x3)
            p1 = d * d + e * e + f * f
            q = (a + b + c) / 3.0
            p2 = (a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2.0 * p1
            if p2 <= 0.0:
                continue
            p = math.sqrt(p2 / 6.0)
            b11, b22, b33 = (a - q) / p, (b - q) / p, (c - q) / p
            b12, b13, b23 = d / p, e / p, f / p
            detb = (
                b11 * (b22 * b33 - b23 * b23)
                - b12 * (b12 * b33 - b23 * b13)
                + b13 * (b12 * b23 - b22 * b13)
            )
            r = min(max(detb / 2.0, -1.0), 1.0)
            phi = math.acos(r) / 3.0
            lam = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
            # eigenvector: the largest cross product of two rows of (C - lam I)
            r0x, r0y, r0z = a - lam, d, e
            r1x, r1y, r1z = d, b - lam, f
            r2x, r2y, r2z = e, f, c - lam
            best = -1.0
            nx = ny = nz = 0.0
            for k in range(3):
                if k == 0:
                    cx = r0y * r1z - r0z * r1y
                    cy = r0z * r1x - r0x * r1z
                    cz = r0x * r1y - r0y * r1x
                elif k == 1:
                    cx = r0y * r2z - r0z * r2y
                    cy = r0z * r2x - r0x * r2z
                    cz = r0x * r2y - r0y * r2x
                else:
                    cx = r1y * r2z - r1z * r2y
                    cy = r1z * r2x - r1x * r2z
                    cz = r1x * r2y - r1y * r2x
                norm2 = cx * cx + cy * cy + cz * cz
                if norm2 > best:
                    best, nx, ny, nz = norm2, cx, cy, cz
            if best <= 0.0:
                continue
            ray = math.sqrt(px * px + py * py + pz * pz)
            cos = abs(nx * px + ny * py + nz * pz) / (math.sqrt(best) * ray)
            out[row, col] = math.acos(min(cos, 1.0))


@njit_parallel
def _temporal_average_kernel(depth, num_frames, coeff_t, coeff_r, out):  # pragma: no cover
    """TA: causal range-gated per-pixel average of the last ``num_frames`` frames.

    Parameters
    ----------
    depth : (T, H, W) float32
        Depth (mm), NaN = invalid.
    num_frames : int
        N (window of frames t−N+1 … t, truncated at the start).
    coeff_t : float
        ``1 / (2 σ_t²)`` (1/frames²); 0 = uniform in time.
    coeff_r : float
        ``1 / (2 σ_r²)`` (1/mm²).
    out : (T, H, W) float32
        Output; NaN where the centre sample is NaN.
    """
    n_t, height, width = depth.shape
    for row in prange(height):
        for t in range(n_t):
            for col in range(width):
                center = depth[t, row, col]
                if math.isnan(center):
                    out[t, row, col] = np.nan
                    continue
                acc = 0.0
                norm = 0.0
                for k in range(min(num_frames, t + 1)):
                    value = depth[t - k, row, col]
                    if math.isnan(value):
                        continue
                    diff = value - center
                    w = math.exp(-(k * k) * coeff_t - diff * diff * coeff_r)
                    acc += w * value
                    norm += w
                out[t, row, col] = acc / norm
