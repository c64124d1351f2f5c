"""Obviously-correct NumPy oracles for the baselines' kernels (slow; tiny arrays only)."""

from __future__ import annotations

import numpy as np


def joint_bilateral(
    depth: np.ndarray,
    intensity: np.ndarray | None,
    ref: int,
    time_weight: np.ndarray,
    radius: np.ndarray,
    sigma_spatial: np.ndarray,
    sigma_intensity: float | None,
    sigma_range: np.ndarray | None,
    relative: bool = False,
) -> np.ndarray:
    """Direct double loop over pixels and disc neighbours of the shared kernel's formula."""
    k_frames, h, w = depth.shape
    out = np.full((h, w), np.nan)
    for r in range(h):
        for c in range(w):
            center = depth[ref, r, c]
            if np.isnan(center):
                continue
            rad = int(radius[r, c])
            acc = norm = 0.0
            for k in range(k_frames):
                for rr in range(max(0, r - rad), min(h, r + rad + 1)):
                    for cc in range(max(0, c - rad), min(w, c + rad + 1)):
                        d2 = (rr - r) ** 2 + (cc - c) ** 2
                        val = depth[k, rr, cc]
                        if d2 > rad * rad or np.isnan(val):
                            continue
                        wgt = time_weight[k] * np.exp(-d2 / (2 * sigma_spatial[r, c] ** 2))
                        if sigma_intensity is not None:
                            di = intensity[k, rr, cc] - intensity[ref, r, c]
                            wgt *= np.exp(-(di**2) / (2 * sigma_intensity**2))
                        if sigma_range is not None:
                            diff = (val - center) / (center if relative else 1.0)
                            wgt *= np.exp(-(diff**2) / (2 * sigma_range[r, c] ** 2))
                        acc += wgt * val
                        norm += wgt
            out[r, c] = acc / norm
    return out


def _box_mean(a: np.ndarray, r: int) -> np.ndarray:
    """Mean over the (2r+1)² window clipped at the border (He et al.'s boxfilter / N)."""
    h, w = a.shape
    out = np.empty_like(a, dtype=np.float64)
    for i in range(h):
        for j in range(w):
            out[i, j] = a[max(0, i - r) : i + r + 1, max(0, j - r) : j + r + 1].mean()
    return out


def guided_filter(guide: np.ndarray, src: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """He et al. (TPAMI 2013) Algorithm 1 with box means (valid away from borders)."""
    i = guide.astype(np.float64)
    p = src.astype(np.float64)
    mean_i = _box_mean(i, radius)
    mean_p = _box_mean(p, radius)
    cov_ip = _box_mean(i * p, radius) - mean_i * mean_p
    var_i = _box_mean(i * i, radius) - mean_i**2
    a = cov_ip / (var_i + eps)
    b = mean_p - a * mean_i
    return _box_mean(a, radius) * i + _box_mean(b, radius)


def block_match(reference: np.ndarray, moving: np.ndarray, block: int, search: int) -> np.ndarray:
    """Exhaustive SAD block matching (before the vector median), (BH, BW, 2) (du, dv)."""
    h, w = reference.shape
    nbr, nbc = -(-h // block), -(-w // block)
    out = np.zeros((nbr, nbc, 2), np.int32)
    for br in range(nbr):
        for bc in range(nbc):
            r0, r1 = br * block, min(br * block + block, h)
            c0, c1 = bc * block, min(bc * block + block, w)
            ref = reference[r0:r1, c0:c1]
            best = (np.abs(ref - moving[r0:r1, c0:c1]).sum(), 0, 0, 0)
            for dv in range(-search, search + 1):
                for du in range(-search, search + 1):
                    if r0 + dv < 0 or r1 + dv > h or c0 + du < 0 or c1 + du > w:
                        continue
                    sad = np.abs(ref - moving[r0 + dv : r1 + dv, c0 + du : c1 + du]).sum()
                    length = du * du + dv * dv
                    if sad < best[0] or (sad == best[0] and length < best[3]):
                        best = (sad, du, dv, length)
            out[br, bc] = best[1], best[2]
    return out


def temporal_average(depth: np.ndarray, n: int, sigma_r: float) -> np.ndarray:
    """TA (σ_t = ∞): per pixel, weighted mean of the last n frames with a range weight."""
    out = np.full(depth.shape, np.nan)
    for t in range(depth.shape[0]):
        center = depth[t]
        acc = np.zeros(center.shape)
        norm = np.zeros(center.shape)
        for k in range(min(n, t + 1)):
            v = depth[t - k]
            w = np.exp(-((v - center) ** 2) / (2 * sigma_r**2))
            ok = np.isfinite(v) & np.isfinite(center)
            acc += np.where(ok, w * v, 0)
            norm += np.where(ok, w, 0)
        with np.errstate(invalid="ignore"):
            out[t] = np.where(np.isfinite(center), acc / norm, np.nan)
    return out


def pca_view_angle(points: np.ndarray, half: int, min_count: int) -> np.ndarray:
    """Angle (rad) between the window's PCA normal (numpy eigh) and the camera ray; 0 if unknown."""
    h, w, _ = points.shape
    out = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            if np.isnan(points[r, c, 2]):
                continue
            win = points[max(0, r - half) : r + half + 1, max(0, c - half) : c + half + 1]
            win = win.reshape(-1, 3).astype(np.float64)
            win = win[np.isfinite(win[:, 2])]
            if len(win) < min_count:
                continue
            cov = np.cov(win.T, bias=True)
            normal = np.linalg.eigh(cov)[1][:, 0]
            ray = points[r, c].astype(np.float64)
            cos = abs(normal @ ray) / np.linalg.norm(ray)
            out[r, c] = np.arccos(min(cos, 1.0))
    return out


def stmf_median(depth, intensity, ref, vectors, half_window, intensity_tol) -> np.ndarray:
    """ST-MF step 2-3 by a direct loop: median of the accepted candidates (NaN if none)."""
    k_frames, h, w = depth.shape
    out = np.full((h, w), np.nan)
    for r in range(h):
        for c in range(w):
            cands = []
            for k in range(k_frames):
                du, dv = vectors[k, r, c]
                for orow in range(-half_window, half_window + 1):
                    for ocol in range(-half_window, half_window + 1):
                        tr, tc = r + orow, c + ocol
                        sr, sc = tr + dv, tc + du
                        if not (0 <= tr < h and 0 <= tc < w and 0 <= sr < h and 0 <= sc < w):
                            continue
                        value = depth[k, sr, sc]
                        di = abs(intensity[k, sr, sc] - intensity[ref, tr, tc])
                        if np.isfinite(value) and di < intensity_tol:
                            cands.append(value)
            if cands:
                out[r, c] = np.median(cands)
    return out


def region_grow(depth, intensity, todo, threshold, rounds):
    """Ad-BF's region growing as fuse4d wrote it in numpy before stop 51 (every pixel, every
    round): the oracle of ``_kernels.baselines._region_grow_kernel``. In place on ``depth``
    and ``todo``."""
    h, w = depth.shape
    offsets = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]
    pad_i = np.pad(intensity, 1, mode="edge")
    for _ in range(rounds):
        pad_d = np.pad(depth, 1, constant_values=np.nan)
        acc = np.zeros((h, w), np.float64)
        cnt = np.zeros((h, w), np.int32)
        for dr, dc in offsets:
            nd = pad_d[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            ni = pad_i[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            ok = np.isfinite(nd) & (np.abs(ni - intensity) < threshold)
            acc += np.where(ok, nd, 0.0)
            cnt += ok
        grow = todo & (cnt > 0)
        if not grow.any():
            break
        depth[grow] = (acc[grow] / cnt[grow]).astype(np.float32)
        todo &= ~grow
