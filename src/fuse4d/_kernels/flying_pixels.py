"""Flying (mixed) pixels of time-of-flight depth (``fuse4d.flying_pixels``). Private."""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit_parallel, prange

__all__ = ["_flying_pixels_kernel"]


@njit_parallel
def _flying_pixels_kernel(
    depth, fx, fy, cx, cy, cos_max, jump_quad, isolation, out
):  # pragma: no cover - compiled
    """``out[v, u]`` = pixel (v, u) is a flying pixel (see :func:`fuse4d.flying_pixels.
    flying_pixel_mask` for the test; the oracle is ``tests/naive/flying_pixels.py``).

    ``depth`` (H, W) float32 mm, NaN = invalid; ``fx, fy, cx, cy`` px; ``cos_max`` the cosine
    of the largest angle (to the pixel's viewing ray) of a segment that counts as a jump;
    ``jump_quad`` mm^-1: each jump must exceed ``jump_quad * z^2`` mm; ``isolation``: each
    segment must be longer than this many times the next segment on its side. ``out`` (H, W)
    bool.
    The four lines through a pixel: k = 0 the row, 1 the column, 2 and 3 the diagonals.
    """
    h, w = depth.shape
    for v in prange(h):
        for u in range(w):
            out[v, u] = False
            z = np.float64(depth[v, u])
            if math.isnan(z):
                continue
            floor = jump_quad * z * z
            for k in range(4):
                dv = 0 if k == 0 else 1
                du = 1 if k == 0 else (0 if k == 1 else (1 if k == 2 else -1))
                va, ua, vb, ub = v - dv, u - du, v + dv, u + du
                if va < 0 or vb >= h or min(ua, ub) < 0 or max(ua, ub) >= w:
                    continue
                za = np.float64(depth[va, ua])
                zb = np.float64(depth[vb, ub])
                # cheapest tests first (NaN fails them): between, and both jumps > floor
                if not (abs(za - z) > floor and abs(zb - z) > floor):
                    continue
                if not (min(za, zb) < z < max(za, zb)):
                    continue
                va2, ua2, vb2, ub2 = va - dv, ua - du, vb + dv, ub + du
                if va2 < 0 or vb2 >= h or min(ua2, ub2) < 0 or max(ua2, ub2) >= w:
                    continue
                za2 = np.float64(depth[va2, ua2])
                zb2 = np.float64(depth[vb2, ub2])
                if math.isnan(za2) or math.isnan(zb2):
                    continue
                xn = (u - cx) / fx
                yn = (v - cy) / fy
                norm = math.sqrt(xn * xn + yn * yn + 1.0)
                rx, ry, rz = xn / norm, yn / norm, 1.0 / norm
                px, py = xn * z, yn * z
                ok = True
                for side in range(2):
                    if side == 0:
                        v1, u1, z1, v2, u2, z2 = va, ua, za, va2, ua2, za2
                    else:
                        v1, u1, z1, v2, u2, z2 = vb, ub, zb, vb2, ub2, zb2
                    x1 = (u1 - cx) / fx * z1
                    y1 = (v1 - cy) / fy * z1
                    sx, sy, sz = x1 - px, y1 - py, z1 - z
                    seg = math.sqrt(sx * sx + sy * sy + sz * sz)
                    if abs(sx * rx + sy * ry + sz * rz) <= cos_max * seg:
                        ok = False  # not along the viewing ray: a slanted surface
                        break
                    x2 = (u2 - cx) / fx * z2
                    y2 = (v2 - cy) / fy * z2
                    nx, ny, nz = x2 - x1, y2 - y1, z2 - z1
                    if seg <= isolation * math.sqrt(nx * nx + ny * ny + nz * nz):
                        ok = False  # as long as the surface's own next step: a steep rim
                        break
                if ok:
                    out[v, u] = True
                    break
