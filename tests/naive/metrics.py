"""Pure-NumPy oracles for the metric kernels (slow, obviously correct)."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage


def naive_roughness(points, *, window=5, min_valid_fraction=0.8):
    """Per-pixel (Pi, R) of one (H, W, 3) point map with ``np.linalg.eigh`` per window."""
    p = np.asarray(points, dtype=np.float64)
    h, w = p.shape[:2]
    r = window // 2
    pi = np.full((h, w), np.nan)
    rms = np.full((h, w), np.nan)
    for i in range(h):
        for j in range(w):
            if not np.all(np.isfinite(p[i, j])):
                continue
            win = p[max(0, i - r) : i + r + 1, max(0, j - r) : j + r + 1].reshape(-1, 3)
            win = win[np.all(np.isfinite(win), axis=1)]
            if win.shape[0] < min_valid_fraction * window * window - 1e-9:
                continue
            c = win.mean(axis=0)
            scatter = (win - c).T @ (win - c)
            _, vecs = np.linalg.eigh(scatter)
            n = vecs[:, 0]
            pi[i, j] = abs(np.sum((p[i, j] - win) @ n))
            rms[i, j] = math.sqrt(np.mean(((win - c) @ n) ** 2))
    return pi, rms


def naive_mlesac_score(points, centre, radius, *, sigma=0.5, nu=50.0, num_em=5):
    """(L, gamma) of one sphere/circle hypothesis (EVALUATION §2)."""
    e = np.abs(np.linalg.norm(points - centre, axis=1) - radius)
    g = np.exp(-(e**2) / (2 * sigma**2)) / (math.sqrt(2 * math.pi) * sigma)
    gamma = 0.5
    for _ in range(num_em):
        z = gamma * g / (gamma * g + (1 - gamma) / nu)
        gamma = z.mean()
    return -np.sum(np.log(gamma * g + (1 - gamma) / nu)), gamma


def naive_default_roi(d, window, max_step, quads):
    """:func:`fuse4d.metrics.default_roi` with scipy's minimum filters (the code its kernel
    replaced in stop 38): windows inside the image, all valid, no depth edge in them."""
    quads = np.asarray(quads, np.float64)[..., None, None]
    size = (1,) * (d.ndim - 2) + (window, window)
    full = ndimage.minimum_filter(np.isfinite(d), size=size, mode="constant", cval=False)
    z = d.astype(np.float64)
    limit = np.maximum(float(max_step), 2.5 * quads * z * z)
    with np.errstate(invalid="ignore"):
        jump_c = np.abs(z[..., :, 1:] - z[..., :, :-1]) > np.fmax(
            limit[..., :, 1:], limit[..., :, :-1]
        )
        jump_r = np.abs(z[..., 1:, :] - z[..., :-1, :]) > np.fmax(
            limit[..., 1:, :], limit[..., :-1, :]
        )
    ok_c = np.ones(d.shape, bool)
    ok_c[..., :, :-1] = ~jump_c
    ok_r = np.ones(d.shape, bool)
    ok_r[..., :-1, :] = ~jump_r
    half = window // 2
    if half == 0:
        return full
    size_c, size_r = list(size), list(size)
    size_c[-1] = 2 * half  # right links of columns u - half .. u + half - 1
    size_r[-2] = 2 * half
    free_c = ndimage.minimum_filter(ok_c, size=tuple(size_c), mode="constant", cval=True)
    free_r = ndimage.minimum_filter(ok_r, size=tuple(size_r), mode="constant", cval=True)
    return full & free_c & free_r
