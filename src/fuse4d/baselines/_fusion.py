"""Geometry helpers of the 6D baselines: normals, rigid transforms, projective box fusion."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..camera import Intrinsics

__all__ = [
    "apply_rigid",
    "grid_normals",
    "projective_fuse",
    "projective_icp",
]


def apply_rigid(transform: NDArray[np.float64], points: NDArray) -> NDArray[np.float64]:
    """Apply a 4×4 rigid transform to (..., 3) points (mm)."""
    return points @ transform[:3, :3].T + transform[:3, 3]


def grid_normals(points: NDArray[np.float32], *, step: int = 1) -> NDArray[np.float32]:
    """Unit normals of an (H, W, 3) point map from central differences over ±``step`` px.

    NaN where undefined; oriented toward the camera (negative Z component). A larger ``step``
    averages depth noise (the normal angle noise falls roughly as 1/step).
    """
    p = points.astype(np.float64)
    du = np.full_like(p, np.nan)
    dv = np.full_like(p, np.nan)
    du[:, step:-step] = p[:, 2 * step :] - p[:, : -2 * step]
    dv[step:-step] = p[2 * step :] - p[: -2 * step]
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / norm
    flip = n[..., 2] > 0
    n[flip] *= -1
    return n.astype(np.float32)


def projective_icp(
    source: NDArray[np.float32],
    target: NDArray[np.float32],
    intrinsics: Intrinsics,
    *,
    max_distance: float = 2.0,
    max_iterations: int = 30,
    tolerance: float = 1e-6,
    stride: int = 2,
) -> NDArray[np.float64]:
    """Point-to-plane ICP with projective data association (KinectFusion's own variant).

    Used when Open3D is absent. Source and target are (H, W, 3) point maps (mm); returns the
    4×4 transform mapping source points into the target frame (identity initialisation).
    Correspondence: the target pixel that the transformed source point projects to, kept if
    closer than ``max_distance`` mm.
    """
    src = source[::stride, ::stride].reshape(-1, 3).astype(np.float64)
    src = src[np.isfinite(src).all(axis=1)]
    tgt = target.astype(np.float64)
    nrm = grid_normals(target).astype(np.float64)
    h, w = target.shape[:2]
    transform = np.eye(4)
    prev_err = np.inf
    for _ in range(max_iterations):
        p = apply_rigid(transform, src)
        with np.errstate(invalid="ignore", divide="ignore"):
            u = np.rint(intrinsics.fx * p[:, 0] / p[:, 2] + intrinsics.cx)
            v = np.rint(intrinsics.fy * p[:, 1] / p[:, 2] + intrinsics.cy)
        ok = (p[:, 2] > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        ui, vi = u[ok].astype(np.int64), v[ok].astype(np.int64)
        q = tgt[vi, ui]
        n = nrm[vi, ui]
        ps = p[ok]
        good = np.isfinite(q).all(axis=1) & np.isfinite(n).all(axis=1)
        good &= np.linalg.norm(ps - np.where(np.isfinite(q), q, 0), axis=1) < max_distance
        if good.sum() < 6:
            break
        ps, q, n = ps[good], q[good], n[good]
        r = np.sum((ps - q) * n, axis=1)
        jac = np.concatenate([np.cross(ps, n), n], axis=1)  # d r / d (omega, t)
        delta = np.linalg.lstsq(jac, -r, rcond=None)[0]
        wx, wy, wz = delta[:3]
        step = np.eye(4)
        step[:3, :3] = np.array([[1, -wz, wy], [wz, 1, -wx], [-wy, wx, 1]])
        u_, _, vt_ = np.linalg.svd(step[:3, :3])
        step[:3, :3] = u_ @ vt_
        step[:3, 3] = delta[3:]
        transform = step @ transform
        err = float(np.sqrt(np.mean(r**2)))
        if abs(prev_err - err) < tolerance or np.linalg.norm(delta) < tolerance:
            break
        prev_err = err
    return transform


def projective_fuse(
    points: NDArray[np.float64],
    intrinsics: Intrinsics,
    *,
    band: float = 2.0,
) -> NDArray[np.float32]:
    """Box-weighted projective fusion in the reference camera (BASELINES §8 fallback, §9).

    Every point (already in the reference camera frame, mm) is projected to its nearest
    pixel; per pixel the output is the mean of the points whose z lies within ``band`` mm of
    the per-pixel median z. Pixels that receive no point are NaN.

    Parameters
    ----------
    points : (N, 3) ndarray
        Points in mm (NaN rows are ignored).
    intrinsics : Intrinsics
        Reference camera.
    band : float, default 2
        Half-width (mm) of the z band around the median.

    Returns
    -------
    (H, W, 3) ndarray of float32
        Fused points (mm), NaN where empty.
    """
    h, w = intrinsics.height, intrinsics.width
    out = np.full((h * w, 3), np.nan, np.float32)
    p = points[np.isfinite(points).all(axis=1) & (points[:, 2] > 0)]
    u = np.rint(intrinsics.fx * p[:, 0] / p[:, 2] + intrinsics.cx)
    v = np.rint(intrinsics.fy * p[:, 1] / p[:, 2] + intrinsics.cy)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    p = p[ok]
    if p.shape[0] == 0:
        return out.reshape(h, w, 3)
    pix = v[ok].astype(np.int64) * w + u[ok].astype(np.int64)
    order = np.lexsort((p[:, 2], pix))
    pix, p = pix[order], p[order]
    uniq, start, count = np.unique(pix, return_index=True, return_counts=True)
    lo = start + (count - 1) // 2
    hi = start + count // 2
    median = 0.5 * (p[lo, 2] + p[hi, 2])
    group = np.repeat(np.arange(uniq.size), count)
    keep = np.abs(p[:, 2] - median[group]) <= band
    n = np.bincount(group[keep], minlength=uniq.size).astype(np.float64)
    for c in range(3):
        s = np.bincount(group[keep], weights=p[keep, c], minlength=uniq.size)
        with np.errstate(invalid="ignore", divide="ignore"):  # n = 0: pixel stays NaN
            out[uniq, c] = np.where(n > 0, s / np.maximum(n, 1), np.nan).astype(np.float32)
    return out.reshape(h, w, 3)
