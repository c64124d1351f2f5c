"""Pure-NumPy oracle of the PMBP energy terms and BP updates (METHOD.md §2.1-2.2).

Written from the spec, independently of the numba kernels: bilinear sampling by
``scipy.ndimage.map_coordinates(order=1)``, explicit Python loops over the tiny grids of the
tests. Directions d: 0 up (r-1), 1 down (r+1), 2 left (c-1), 3 right (c+1).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import map_coordinates

OFFSETS = ((-1, 0), (1, 0), (0, -1), (0, 1))


def asw_weights(guide: np.ndarray, rho: int, gamma: float) -> np.ndarray:
    """(H, W, (2ρ+1)²) weights exp(−|Ī(p) − Ī(q)| / γ), 0 for q off the image."""
    h, w = guide.shape
    side = 2 * rho + 1
    out = np.zeros((h, w, side * side))
    for r in range(h):
        for c in range(w):
            for j, (dy, dx) in enumerate(np.ndindex(side, side)):
                qr, qc = r + dy - rho, c + dx - rho
                if 0 <= qr < h and 0 <= qc < w:
                    out[r, c, j] = math.exp(-abs(guide[r, c] - guide[qr, qc]) / gamma)
    return out


def patch_cost(src, tgt, weights, r, c, s, *, rho, tau1, border, alpha=0.0, tau2=1.0, grads=None):
    """ψ1_p(s) = Σ_q w_pq c(q, s) with bilinear sampling; ``border`` per sample off ``tgt``."""
    h, w = src.shape
    side = 2 * rho + 1
    total = 0.0
    for j, (dy, dx) in enumerate(np.ndindex(side, side)):
        qr, qc = r + dy - rho, c + dx - rho
        if not (0 <= qr < h and 0 <= qc < w):
            continue
        y, x = qr + s[1], qc + s[0]
        if not (0 <= y <= h - 1 and 0 <= x <= w - 1):
            total += weights[r, c, j] * border
            continue
        val = map_coordinates(tgt.astype(np.float64), [[y], [x]], order=1)[0]
        cost = (1 - alpha) * min(abs(src[qr, qc] - val), tau1)
        if alpha > 0:
            sgu, sgv, tgu, tgv = grads
            gu = map_coordinates(tgu.astype(np.float64), [[y], [x]], order=1)[0]
            gv = map_coordinates(tgv.astype(np.float64), [[y], [x]], order=1)[0]
            cost += alpha * min(abs(sgu[qr, qc] - gu) + abs(sgv[qr, qc] - gv), tau2)
        total += weights[r, c, j] * cost
    return total


def neighbours(r, c, shape):
    """[(d, qr, qc)] of the 4-neighbours inside a grid of ``shape``."""
    h, w = shape
    out = []
    for d, (dr, dc) in enumerate(OFFSETS):
        qr, qc = r + dr, c + dc
        if 0 <= qr < h and 0 <= qc < w:
            out.append((d, qr, qc))
    return out


def pairwise(s, t, lam, trunc):
    """ψ2 = λ min(|s − t|², T)."""
    d = np.asarray(s, float) - np.asarray(t, float)
    return lam * min(float(d @ d), trunc)


def message(lab, found, qr, qc, d_toward_p, s, lam, trunc):
    """m_{q→p}(s) = min_k ψ2(s, s_q^k) + F_{q\\p}^k (``found[qr, qc, d_toward_p]``)."""
    return min(
        pairwise(s, lab[qr, qc, k], lam, trunc) + found[qr, qc, d_toward_p, k]
        for k in range(lab.shape[2])
    )


def message_sum(lab, found, r, c, s, lam, trunc):
    """Σ_q m_{q→p}(s) over the 4-neighbours q of p = (r, c)."""
    return sum(
        message(lab, found, qr, qc, d ^ 1, s, lam, trunc)
        for d, qr, qc in neighbours(r, c, lab.shape[:2])
    )


def disbelief(unary, lab, found, r, c, s, lam, trunc):
    """B_p(s) = ψ1_p(s) + Σ_q m_{q→p}(s), with ψ1 given as the number ``unary``."""
    return unary + message_sum(lab, found, r, c, s, lam, trunc)


def foundations(lab, dis, found, r, c, lam, trunc):
    """New ``found[r, c]`` (4, K): F_{p\\q}^k = B_p^k − m_{q→p}(s_p^k), min shifted to 0."""
    out = np.array(found[r, c], dtype=float)
    for d, qr, qc in neighbours(r, c, lab.shape[:2]):
        f = np.array(
            [
                dis[r, c, k] - message(lab, found, qr, qc, d ^ 1, lab[r, c, k], lam, trunc)
                for k in range(lab.shape[2])
            ]
        )
        out[d] = f - f.min()
    return out


def energy(flow, unary_fn, lam, trunc):
    """E(s) = Σ_p ψ1_p(s_p) + Σ_{(p,q)} ψ2(s_p, s_q) of a flow field (H, W, 2)."""
    h, w = flow.shape[:2]
    e = 0.0
    for r in range(h):
        for c in range(w):
            e += unary_fn(r, c, flow[r, c])
            if r + 1 < h:
                e += pairwise(flow[r, c], flow[r + 1, c], lam, trunc)
            if c + 1 < w:
                e += pairwise(flow[r, c], flow[r, c + 1], lam, trunc)
    return e
