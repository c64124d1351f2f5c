"""Pure-NumPy/Python oracles for the fusion kernels (slow, obviously correct, tiny inputs)."""

from __future__ import annotations

import math

import numpy as np


def approx_exp_neg(x):
    """The kernels' weight function: exp(-x) ~ (1 - x / 1024) ** 1024, 0 beyond x = 1024."""
    return max(1.0 - x / 1024.0, 0.0) ** 1024


def bilateral3d(points, intensity, radius, sigma_d, sigma_g, reference=None):
    """Inner sum of Eq. 5 with exact exp; residual form when ``reference`` is given."""
    h, w = intensity.shape
    out = np.full_like(points, np.nan, dtype=np.float64)
    for v in range(h):
        for u in range(w):
            if np.isnan(points[v, u, 2]):
                continue
            acc = np.zeros(3)
            wsum = 0.0
            for nv in range(max(v - radius, 0), min(v + radius + 1, h)):
                for nu in range(max(u - radius, 0), min(u + radius + 1, w)):
                    q = points[nv, nu].astype(np.float64)
                    if np.isnan(q[2]):
                        continue
                    d2 = np.sum((q - points[v, u]) ** 2)
                    di = float(intensity[nv, nu]) - float(intensity[v, u])
                    wgt = approx_exp_neg(d2 / (2 * sigma_d**2) + di * di / (2 * sigma_g**2))
                    acc += wgt * (q - reference[nv, nu] if reference is not None else q)
                    wsum += wgt
            out[v, u] = acc / wsum + (reference[v, u] if reference is not None else 0.0)
    return out


def segment_box_rows(values, depth, radius, max_step):
    """One local-linear box pass along rows limited to depth-continuous segments."""
    h, w = depth.shape
    out = np.full((h, w), np.nan)
    for v in range(h):
        segment = np.full(w, -1)
        sid = -1
        for u in range(w):
            if np.isnan(depth[v, u]):
                continue
            if u == 0 or segment[u - 1] < 0 or not abs(depth[v, u] - depth[v, u - 1]) < max_step:
                sid += 1
            segment[u] = sid
        for u in range(w):
            if segment[u] < 0:
                continue
            idx = [
                k
                for k in range(u - radius, u + radius + 1)
                if 0 <= k < w and segment[k] == segment[u]
            ]
            vals = np.array([values[v, k] for k in idx], dtype=np.float64)
            if len(idx) > 1:
                slope, intercept = np.polyfit(np.array(idx, dtype=np.float64), vals, 1)
                out[v, u] = slope * u + intercept
            else:
                out[v, u] = vals[0]
    return out


def bilinear(field, x, y):
    """Bilinear sample with the 2x2 stencil clamped at the last row/column."""
    h, w = field.shape[:2]
    x0 = min(max(math.floor(x), 0), max(w - 2, 0))
    y0 = min(max(math.floor(y), 0), max(h - 2, 0))
    x1 = min(x0 + 1, w - 1)
    y1 = min(y0 + 1, h - 1)
    fx = x - x0 if w > 1 else 0.0
    fy = y - y0 if h > 1 else 0.0
    top = field[y0, x0] * (1 - fx) + field[y0, x1] * fx
    bottom = field[y1, x0] * (1 - fx) + field[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def track(fwd, bwd, depth, t, first, last, theta, max_step):
    """Chained tracks (METHOD §4.1, quantize='final'): {T: (row, col, valid)} per pixel."""
    _n, h, w = depth.shape
    result = {}
    for v in range(h):
        for u in range(w):
            valid0 = not np.isnan(depth[t, v, u])
            for direction in (1, -1):
                x, y = float(u), float(v)
                pr, pc = v, u
                alive = valid0
                rng = range(t + 1, last + 1) if direction == 1 else range(t - 1, first - 1, -1)
                for T in rng:
                    if alive:
                        if direction == 1:
                            step, check, prev = fwd[T - 1], bwd[T - 1], T - 1
                        else:
                            step, check, prev = bwd[T], fwd[T], T + 1
                        s = bilinear(step, x, y)
                        nx, ny = x + s[0], y + s[1]
                        ok = 0 <= nx <= w - 1 and 0 <= ny <= h - 1
                        if ok:
                            c = bilinear(check, nx, ny)
                            ok = math.hypot(s[0] + c[0], s[1] + c[1]) < theta
                        if ok:
                            r, cc = math.floor(ny + 0.5), math.floor(nx + 0.5)
                            d1 = depth[T, r, cc]
                            ok = not np.isnan(d1) and abs(d1 - depth[prev, pr, pc]) < max_step
                        if ok:
                            x, y, pr, pc = nx, ny, r, cc
                        else:
                            alive = False
                    result[(T, v, u)] = (pr, pc, alive)
    return result


def fuse(bilateral, reference, tracks, t, first, last, weights, gate, *, trajectory=False):
    """Outer sum of Eq. 5 along given tracks, with the temporal range gate (A19) and,
    optionally, the trajectory base (A21: least-squares line through the motion vectors)."""
    _n, h, w, _ = bilateral.shape
    out = np.full((h, w, 3), np.nan)
    support = np.zeros((h, w), int)
    for v in range(h):
        for u in range(w):
            if np.isnan(reference[t, v, u, 2]):
                continue
            own = bilateral[t, v, u] - reference[t, v, u]
            taus, wts, details, motions = [0.0], [weights[0]], [own], [np.zeros(3)]
            for T in range(first, last + 1):
                if t == T:
                    continue
                r, c, ok = tracks[(T, v, u)]
                if not ok:
                    continue
                detail = bilateral[T, r, c] - reference[T, r, c]
                if not np.linalg.norm(detail - own) < gate:
                    continue
                taus.append(float(T - t))
                wts.append(weights[abs(T - t)])
                details.append(detail)
                motions.append(reference[T, r, c] - reference[t, v, u])
                support[v, u] += 1
            wts_a = np.array(wts)
            base = np.zeros(3)
            if trajectory:
                taus_a = np.array(taus)
                if len(set(taus)) > 1:
                    design = (
                        np.stack([np.ones_like(taus_a), taus_a], axis=1) * np.sqrt(wts_a)[:, None]
                    )
                    rhs = np.array(motions) * np.sqrt(wts_a)[:, None]
                    base = np.linalg.lstsq(design, rhs, rcond=None)[0][0]
                else:
                    base = np.average(np.array(motions), axis=0, weights=wts_a)
            out[v, u] = (
                reference[t, v, u] + base + np.average(np.array(details), axis=0, weights=wts_a)
            )
    return out, support
