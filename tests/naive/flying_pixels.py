"""NumPy oracle of fuse4d's flying-pixel test (``fuse4d.flying_pixels``, A36)."""

from __future__ import annotations

import numpy as np

from fuse4d import Intrinsics


def _shift(points: np.ndarray, dv: int, du: int) -> np.ndarray:
    """``out[v, u] = points[v - dv, u - du]``, NaN outside the image."""
    h, w = points.shape[:2]
    out = np.full_like(points, np.nan)
    out[max(dv, 0) : h + min(dv, 0), max(du, 0) : w + min(du, 0)] = points[
        max(-dv, 0) : h + min(-dv, 0), max(-du, 0) : w + min(-du, 0)
    ]
    return out


def flying_pixel_mask(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    *,
    max_angle_deg: float,
    jump_quad: float,
    isolation: float,
) -> np.ndarray:
    """Pixels p lying between their two neighbours a, b on a line (row, column, diagonal),
    both segments within ``max_angle_deg`` of p's ray, longer than ``jump_quad z^2`` in depth
    and than ``isolation`` times the next segment beyond a (a to a2) and beyond b."""
    k = intrinsics
    z = np.asarray(depth, np.float64)
    v, u = np.indices(z.shape, dtype=np.float64)
    p = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=-1)
    ray = p / np.linalg.norm(p, axis=-1, keepdims=True)
    cos_max = np.cos(np.radians(max_angle_deg))
    floor = jump_quad * z**2
    out = np.zeros(depth.shape, bool)
    for dv, du in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a, b = _shift(p, dv, du), _shift(p, -dv, -du)
        a2, b2 = _shift(p, 2 * dv, 2 * du), _shift(p, -2 * dv, -2 * du)
        with np.errstate(invalid="ignore"):
            za, zb = a[..., 2], b[..., 2]
            hit = (np.minimum(za, zb) < z) & (z < np.maximum(za, zb))
            hit &= (np.abs(za - z) > floor) & (np.abs(zb - z) > floor)
            for q, q2 in ((a, a2), (b, b2)):
                seg = np.linalg.norm(q - p, axis=-1)
                along = np.abs(np.sum((q - p) * ray, axis=-1))
                hit &= along > cos_max * seg
                hit &= seg > isolation * np.linalg.norm(q2 - q, axis=-1)
        out |= hit
    return out
