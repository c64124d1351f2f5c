"""Pure-NumPy oracles for the metric kernels (slow, obviously correct)."""

from __future__ import annotations

import math

import numpy as np


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
