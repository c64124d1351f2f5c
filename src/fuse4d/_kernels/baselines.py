"""Kernels of the baselines besides the joint bilateral: ST-MF, TA, and Ad-GF's PCA view angle.

Private; arrays and scalars only; the public wrappers live in ``fuse4d.baselines``.
"""

from __future__ import annotations

import math

import numpy as np

from ._common import ROW_CHUNKS
from ._numba import njit, njit_parallel, prange

__all__ = [
    "_block_match_kernel",
    "_pca_view_angle_kernel",
    "_region_grow_kernel",
    "_stmf_median_kernel",
    "_temporal_average_kernel",
]


@njit
def _row_absdiff_add(ref_row, mov_row, acc):  # pragma: no cover - compiled
    """acc += |ref_row - mov_row| (1D slices of equal length; this loop vectorises)."""
    for u in range(acc.shape[0]):
        acc[u] += abs(ref_row[u] - mov_row[u])


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

    Notes
    -----
    Displacement-major: for one block row and one displacement, the absolute differences of
    whole image rows are summed (a vectorised loop over ~W columns), then cut into blocks. This
    evaluates every displacement of every block of the row at once (no early termination,
    but SIMD), several times faster than a per-block search.
    """
    height, width = reference.shape
    n_brow, n_bcol = out.shape[0], out.shape[1]
    for br in prange(n_brow):
        r0 = br * block
        r1 = min(r0 + block, height)
        acc = np.empty(width, dtype=np.float32)
        best = np.full(n_bcol, np.inf, dtype=np.float32)
        best_len = np.zeros(n_bcol, dtype=np.int32)
        for bc in range(n_bcol):
            out[br, bc, 0] = 0
            out[br, bc, 1] = 0
        for step in range(-1, (2 * search + 1) * (2 * search + 1)):
            if step < 0:  # zero displacement first, as the reference search order
                dv = 0
                du = 0
            else:
                dv = step // (2 * search + 1) - search
                du = step % (2 * search + 1) - search
                if du == 0 and dv == 0:
                    continue
            if r0 + dv < 0 or r1 + dv > height:
                continue
            u0 = max(0, -du)
            u1 = min(width, width - du)
            acc[:] = 0.0
            for rr in range(r0, r1):
                _row_absdiff_add(
                    reference[rr, u0:u1], moving[rr + dv, u0 + du : u1 + du], acc[u0:u1]
                )
            length = du * du + dv * dv
            for bc in range(n_bcol):
                c0 = bc * block
                c1 = min(c0 + block, width)
                if c0 + du < 0 or c1 + du > width:
                    continue
                sad = np.float32(0.0)
                for cc in range(c0, c1):
                    sad += acc[cc]
                if sad < best[bc] or (sad == best[bc] and length < best_len[bc]):
                    best[bc] = sad
                    best_len[bc] = length
                    out[br, bc, 0] = du
                    out[br, bc, 1] = dv


@njit
def _compare_exchange(low, high):  # pragma: no cover - compiled
    """low, high = min(low, high), max(low, high) elementwise (1D rows; vectorises)."""
    for u in range(low.shape[0]):
        a = low[u]
        b = high[u]
        low[u] = min(a, b)
        high[u] = max(a, b)


@njit
def _gather_candidates(source, source_intensity, target_intensity, tol, cand, count):
    """cand = source where valid and intensity-consistent, else +inf; count += accepted.

    1D slices of one run of equal motion vectors (branch-free; this loop vectorises)."""
    inf = np.float32(np.inf)
    for i in range(cand.shape[0]):
        v = source[i]
        ok = (not math.isnan(v)) & (abs(source_intensity[i] - target_intensity[i]) < tol)
        cand[i] = v if ok else inf
        count[i] += np.int32(ok)


@njit_parallel
def _stmf_median_kernel(
    depth, intensity, ref, vectors, half_window, intensity_tol, network, out
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
    network : (P, 2) int32
        Compare-exchange pairs (i < j) of a sorting network for exactly K·(2a+1)² inputs
        (indices beyond that would write out of bounds: the wrapper guarantees the size).
    out : (H, W) float32
        Median of the candidates; NaN when there are none.

    Notes
    -----
    Per row, the candidates of all pixels are laid out as a (K·(2a+1)², W) table (rejected
    ones +inf), sorted column-wise by the data-independent sorting network (branch-free
    min/max over whole rows: SIMD, no mispredictions), and the median of each column's n
    valid values is read at (n−1)//2 and n//2. A per-pixel sort was ~10x slower. Candidates
    are gathered per run of equal vectors along the row (contiguous slices, SIMD).
    """
    n_frames, height, width = depth.shape
    side = 2 * half_window + 1
    cap = n_frames * side * side
    inf = np.float32(np.inf)
    n_chunks = min(height, ROW_CHUNKS)
    for chunk in prange(n_chunks):
        cand = np.empty((cap, width), np.float32)
        count = np.empty(width, np.int32)
        run_start = np.empty(width + 1, np.int64)
        for row in range(chunk * height // n_chunks, (chunk + 1) * height // n_chunks):
            count[:] = 0
            slot = 0
            for k in range(n_frames):
                # runs of equal vectors along the row (one block's width or more for ST-MF)
                n_runs = 0
                run_start[0] = 0
                for col in range(1, width):
                    if (vectors[k, row, col, 0] != vectors[k, row, col - 1, 0]) or (
                        vectors[k, row, col, 1] != vectors[k, row, col - 1, 1]
                    ):
                        n_runs += 1
                        run_start[n_runs] = col
                n_runs += 1
                run_start[n_runs] = width
                for orow in range(-half_window, half_window + 1):
                    tr = row + orow
                    for ocol in range(-half_window, half_window + 1):
                        for r in range(n_runs):
                            c0 = run_start[r]
                            c1 = run_start[r + 1]
                            du = vectors[k, row, c0, 0]
                            sr = tr + vectors[k, row, c0, 1]
                            lo = c1  # columns [lo, hi) have target and source inside
                            hi = c1
                            if 0 <= tr < height and 0 <= sr < height:
                                lo = min(max(c0, -ocol, -ocol - du), c1)
                                hi = max(min(c1, width - ocol, width - ocol - du), lo)
                            for col in range(c0, lo):
                                cand[slot, col] = inf
                            for col in range(hi, c1):
                                cand[slot, col] = inf
                            if hi > lo:
                                _gather_candidates(
                                    depth[k, sr, lo + ocol + du : hi + ocol + du],
                                    intensity[k, sr, lo + ocol + du : hi + ocol + du],
                                    intensity[ref, tr, lo + ocol : hi + ocol],
                                    intensity_tol,
                                    cand[slot, lo:hi],
                                    count[lo:hi],
                                )
                        slot += 1
            for p in range(network.shape[0]):
                _compare_exchange(cand[network[p, 0]], cand[network[p, 1]])
            for col in range(width):
                n = count[col]
                if n == 0:
                    out[row, col] = np.nan
                elif n % 2 == 1:
                    out[row, col] = cand[n // 2, col]
                else:
                    out[row, col] = np.float32(0.5) * (cand[n // 2 - 1, col] + cand[n // 2, col])


@njit_parallel
def _pca_view_angle_kernel(points, half, min_count, out):  # pragma: no cover - compiled
    """Angle (rad) between the PCA normal of a (2·half+1)² window and the camera ray (Ad-GF).

    Parameters
    ----------
    points : (H, W, 3) float32
        Point map (mm), NaN = invalid.
    half : int
        Window half size (2 for the spec's 5×5 window), clipped at the border.
    min_count : int
        Minimum valid points in the window; fewer (or an invalid centre) gives 0.
    out : (H, W) float32
        θ in [0, π/2]; the normal is the eigenvector of the smallest eigenvalue of the
        window covariance (closed-form symmetric 3×3 eigenvalues, then a cross product of two
        rows of C − λI).

    Notes
    -----
    The window moments (count, Σx … Σyz) are separable box sums: per row, column sums over the
    row band, then a running sum along the row, in float64 (E[xx] − E[x]² stays exact to
    ~1e-7 mm² at 5 m). O(1) in the window size instead of a per-pixel window loop.
    """
    height, width = out.shape
    n_chunks = min(height, ROW_CHUNKS)
    for chunk in prange(n_chunks):
        colsum = np.empty((10, width), dtype=np.float64)
        win = np.empty(10, dtype=np.float64)
        for row in range(chunk * height // n_chunks, (chunk + 1) * height // n_chunks):
            colsum[:] = 0.0
            for rr in range(max(row - half, 0), min(row + half + 1, height)):
                for cc in range(width):
                    z = points[rr, cc, 2]
                    if not math.isnan(z):
                        x = np.float64(points[rr, cc, 0])
                        y = np.float64(points[rr, cc, 1])
                        z = np.float64(z)
                        colsum[0, cc] += 1.0
                        colsum[1, cc] += x
                        colsum[2, cc] += y
                        colsum[3, cc] += z
                        colsum[4, cc] += x * x
                        colsum[5, cc] += y * y
                        colsum[6, cc] += z * z
                        colsum[7, cc] += x * y
                        colsum[8, cc] += x * z
                        colsum[9, cc] += y * z
            win[:] = 0.0
            for cc in range(min(half, width)):  # prime the running window with columns < half
                for q in range(10):
                    win[q] += colsum[q, cc]
            for col in range(width):
                enter = col + half
                if enter < width:
                    for q in range(10):
                        win[q] += colsum[q, enter]
                leave = col - half - 1
                if leave >= 0:
                    for q in range(10):
                        win[q] -= colsum[q, leave]
                px = points[row, col, 0]
                py = points[row, col, 1]
                pz = points[row, col, 2]
                out[row, col] = 0.0
                n = win[0]
                if math.isnan(pz) or n < min_count - 0.5:
                    continue
                mx, my, mz = win[1] / n, win[2] / n, win[3] / n
                a = win[4] / n - mx * mx
                b = win[5] / n - my * my
                c = win[6] / n - mz * mz
                d = win[7] / n - mx * my
                e = win[8] / n - mx * mz
                f = win[9] / n - my * mz
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


#: the 8-neighbourhood in the order Ad-BF's region growing sums it (row-major)
_NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


@njit
def _region_grow_kernel(depth, intensity, todo, threshold, max_rounds):  # pragma: no cover
    """Ad-BF's region growing (:func:`fuse4d.baselines.bilateral.region_growing_repair`), in
    place on ``depth`` (H, W) float32 mm and ``todo`` (H, W) bool: round after round, every
    ``todo`` pixel with finite 8-neighbours whose intensity differs from its own by less than
    ``threshold`` (float32, as numpy compares a float32 image with a Python float) takes
    their mean (summed in float64 in :data:`_NEIGHBOURS` order), all of a round from the
    previous round's depth, until a round grows nothing or ``max_rounds`` rounds ran. Returns
    the rounds that grew something.

    Only the pixels that can grow are visited: a pixel that did not grow in a round can grow
    in the next only if a neighbour grew, so each round looks at the todo neighbours of the
    last round's growth (all todo pixels in the first). The values are those of the numpy
    loop that evaluated every pixel in every round (tested against it), at the cost of the
    holes' area instead of the image's times the rounds (a 640 x 480 uva frame: 3 s).
    """
    h, w = depth.shape
    n = h * w
    cand = np.empty(n, np.int64)
    nxt = np.empty(n, np.int64)
    grown = np.empty(n, np.int64)
    values = np.empty(n, np.float32)
    queued = np.zeros(n, np.bool_)
    m = 0
    for v in range(h):
        for u in range(w):
            if todo[v, u]:
                cand[m] = v * w + u
                m += 1
    rounds = 0
    while m > 0 and rounds < max_rounds:
        g = 0
        for j in range(m):
            v = cand[j] // w
            u = cand[j] - v * w
            own = intensity[v, u]
            acc = 0.0
            cnt = 0
            for k in range(8):
                vv = v + _NEIGHBOURS[k][0]
                uu = u + _NEIGHBOURS[k][1]
                if vv < 0 or vv >= h or uu < 0 or uu >= w:
                    continue
                nd = depth[vv, uu]
                if np.isfinite(nd) and abs(intensity[vv, uu] - own) < threshold:
                    acc += np.float64(nd)
                    cnt += 1
            if cnt > 0:
                grown[g] = cand[j]
                values[g] = np.float32(acc / cnt)
                g += 1
        if g == 0:
            break
        rounds += 1
        for j in range(g):  # the round's values, all from the previous round's depth
            v = grown[j] // w
            u = grown[j] - v * w
            depth[v, u] = values[j]
            todo[v, u] = False
        m = 0
        for j in range(g):
            v = grown[j] // w
            u = grown[j] - v * w
            for k in range(8):
                vv = v + _NEIGHBOURS[k][0]
                uu = u + _NEIGHBOURS[k][1]
                if 0 <= vv < h and 0 <= uu < w and todo[vv, uu] and not queued[vv * w + uu]:
                    queued[vv * w + uu] = True
                    nxt[m] = vv * w + uu
                    m += 1
        for j in range(m):
            queued[nxt[j]] = False
        cand, nxt = nxt, cand
    return rounds
