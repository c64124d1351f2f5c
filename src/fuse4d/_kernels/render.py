"""Report rendering kernel: normal shading of an organised point map (one pass, no temporaries).

Oracle: :func:`fuse4d.report.render.normal_map` + :func:`~fuse4d.report.render.shade_normals`
(NumPy), compared in ``tests/test_report.py``.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit_parallel, prange


@njit_parallel
def _shade_points_kernel(points, lx, ly, lz, ambient, invalid, out):  # pragma: no cover - jit
    """Lambert-shade the central-difference normals of ``points`` into ``out``.

    points : (H, W, 3) float32 mm, NaN invalid; (lx, ly, lz): unit direction towards the light;
    ambient: gray level in [0, 1]; invalid: (3,) uint8 colour of pixels without a normal;
    out : (H, W, 3) uint8, written completely.
    """
    h, w = points.shape[0], points.shape[1]
    for r in prange(h):
        for c in range(w):
            done = False
            if 0 < r < h - 1 and 0 < c < w - 1:
                ux = points[r, c + 1, 0] - points[r, c - 1, 0]
                uy = points[r, c + 1, 1] - points[r, c - 1, 1]
                uz = points[r, c + 1, 2] - points[r, c - 1, 2]
                vx = points[r + 1, c, 0] - points[r - 1, c, 0]
                vy = points[r + 1, c, 1] - points[r - 1, c, 1]
                vz = points[r + 1, c, 2] - points[r - 1, c, 2]
                nx = uy * vz - uz * vy
                ny = uz * vx - ux * vz
                nz = ux * vy - uy * vx
                norm = math.sqrt(nx * nx + ny * ny + nz * nz)
                if np.isfinite(norm) and norm > 0.0:
                    facing = nx * points[r, c, 0] + ny * points[r, c, 1] + nz * points[r, c, 2]
                    s = -1.0 / norm if facing > 0.0 else 1.0 / norm
                    lam = (nx * lx + ny * ly + nz * lz) * s
                    lam = min(max(lam, 0.0), 1.0)
                    g = np.uint8(np.rint(255.0 * ambient + 255.0 * (1.0 - ambient) * lam))
                    out[r, c, 0] = g
                    out[r, c, 1] = g
                    out[r, c, 2] = g
                    done = True
            if not done:
                out[r, c, 0] = invalid[0]
                out[r, c, 1] = invalid[1]
                out[r, c, 2] = invalid[2]
