"""Obviously-correct NumPy oracle of the lazily evaluated projective TSDF ray cast (tiny arrays)."""

from __future__ import annotations

import numpy as np


def _bilinear(depth: np.ndarray, uf: np.ndarray, vf: np.ndarray) -> np.ndarray:
    """Bilinear depth at sub-pixel positions; NaN outside the 4-valid-neighbour region."""
    h, w = depth.shape
    out = np.full(uf.shape, np.nan)
    u0 = np.floor(uf).astype(int)
    v0 = np.floor(vf).astype(int)
    ok = (u0 >= 0) & (v0 >= 0) & (u0 + 1 < w) & (v0 + 1 < h)
    u0, v0, a, b = u0[ok], v0[ok], uf[ok] - u0[ok], vf[ok] - v0[ok]
    top = depth[v0, u0] * (1 - a) + depth[v0, u0 + 1] * a
    bottom = depth[v0 + 1, u0] * (1 - a) + depth[v0 + 1, u0 + 1] * a
    out[ok] = top * (1 - b) + bottom * b
    return out


def tsdf_raycast(
    depth: np.ndarray,
    to_reference: np.ndarray,
    k: np.ndarray,
    *,
    truncation: float,
    z_range: tuple[float, float],
    fine_step: float = 0.002,
) -> np.ndarray:
    """Dense march (``fine_step`` mm) of every ray over ``z_range``; first +→− crossing.

    Smooth surfaces only (bilinear lookup, no depth-jump fallback). ``k`` = (fx, fy, cx, cy).
    """
    fx, fy, cx, cy = k
    n, h, w = depth.shape
    zs = np.arange(z_range[0], z_range[1], fine_step)
    out = np.full((h, w), np.nan)
    from_ref = np.linalg.inv(to_reference)
    for v in range(h):
        for u in range(w):
            ray = np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
            x = zs[:, None] * ray  # (S, 3) points in the reference camera
            acc = np.zeros(zs.size)
            wgt = np.zeros(zs.size)
            for f in range(n):
                xt = x @ from_ref[f, :3, :3].T + from_ref[f, :3, 3]
                d = _bilinear(
                    depth[f], fx * xt[:, 0] / xt[:, 2] + cx, fy * xt[:, 1] / xt[:, 2] + cy
                )
                sdf = d - xt[:, 2]
                use = np.isfinite(sdf) & (sdf >= -truncation)
                acc[use] += np.minimum(1.0, sdf[use] / truncation)
                wgt[use] += 1
            f_val = np.where(wgt > 0, acc / np.maximum(wgt, 1), np.nan)
            cross = np.nonzero((f_val[:-1] > 0) & (f_val[1:] <= 0))[0]
            if cross.size:
                i = cross[0]
                out[v, u] = zs[i] + fine_step * f_val[i] / (f_val[i] - f_val[i + 1])
    return out
