"""The one joint-bilateral kernel behind Ad-GF, Ad-BF, Ad-JBF and DNBF (BASELINES.md, "Shared kernel").

Weight of neighbour ``j`` (frame ``tau``) for centre pixel ``i`` of the reference frame::

    w = time_weight[tau]
        * exp(-|x_i - x_j|^2 * spatial_coeff[i])          spatial   (coeff = 1 / (2 sigma_s^2))
        * exp(-(I_tau(j) - I_ref(i))^2 * intensity_coeff) intensity (0 = off)
        * exp(-rho^2 * range_coeff[i])                    depth range (0 = off)

with ``rho = D_tau(j) - D_ref(i)`` (mm), or ``rho = (D_tau(j) - D_ref(i)) / D_ref(i)`` when
``relative`` (DNBF's divisive normalisation). The three Gaussians are evaluated as a single
``exp`` of the summed exponents, with exp(-x) ~ (1 - x/1024)^1024 (relative error x^2/2048:
0.05 % at x = 1, 0.8 % at x = 4; fuse4d's own bilateral's function, shared). The window
is the disc ``|x_i - x_j| <= radius[i]`` (like OpenCV's bilateral filters), clipped at the image
border (no padding). NaN depth never contributes; a NaN centre gives NaN.

Layout: offset-major. For each output row, the loop runs over the frames and the (dr, dc)
offsets of the largest disc in that row, and innermost over the columns, so that the centre and
the neighbour are both contiguous slices and the inner loop vectorises (SIMD); the per-pixel
disc is a mask ``dr^2 + dc^2 <= radius^2`` inside that loop. A per-pixel gather loop (one disc
per pixel) cannot vectorise and was 4-8x slower.
"""

from __future__ import annotations

import math

import numpy as np

from ._common import ROW_CHUNKS
from ._common import _exp_neg_fast as _exp_neg
from ._numba import njit, njit_parallel, prange

__all__ = ["_joint_bilateral_kernel"]


@njit
def _accumulate_offset(
    center, inv_center, guide_c, a_s, a_d, rad2, nbr_depth, nbr_guide, wt, d2, a_i, acc, norm
):  # pragma: no cover - compiled
    """Add one (frame, dr, dc) offset to a row's sums (1D slices; this loop vectorises)."""
    zero = np.float32(0.0)
    d2f = np.float32(d2)
    for u in range(center.shape[0]):
        value = nbr_depth[u]
        ok = (not math.isnan(value)) & (d2 <= rad2[u])
        diff = (value - center[u]) * inv_center[u]
        di = nbr_guide[u] - guide_c[u]
        expo = d2f * a_s[u] + diff * diff * a_d[u] + di * di * a_i
        w = wt * _exp_neg(expo) if ok else zero
        acc[u] += w * (value if ok else zero)
        norm[u] += w


@njit_parallel
def _joint_bilateral_kernel(
    depth,
    guide,
    ref,
    time_weight,
    radius,
    spatial_coeff,
    intensity_coeff,
    range_coeff,
    relative,
    out,
):  # pragma: no cover - compiled (covered via NUMBA_DISABLE_JIT runs)
    """Fill ``out`` (H, W) with the joint-bilateral average around frame ``ref``.

    Parameters
    ----------
    depth : (K, H, W) float32
        Depth (mm) of the K frames of the window; NaN = invalid.
    guide : (K, H, W) float32
        Intensity in [0, 1] of the same frames (any array of that shape when
        ``intensity_coeff == 0``, e.g. ``depth`` itself).
    ref : int
        Index of the reference (centre) frame in ``depth``.
    time_weight : (K,) float32
        Temporal weight per frame; frames with weight 0 are skipped.
    radius : (H, W) int32
        Per-pixel window radius (px).
    spatial_coeff : (H, W) float32
        Per-pixel ``1 / (2 sigma_s^2)`` (1/px^2).
    intensity_coeff : float
        ``1 / (2 sigma_I^2)``; 0 disables the intensity kernel.
    range_coeff : (H, W) float32
        Per-pixel ``1 / (2 sigma_D^2)`` (1/mm^2, or dimensionless when ``relative``); 0 = off.
    relative : bool
        Divide the depth difference by the centre depth (DNBF).
    out : (H, W) float32
        Output buffer.
    """
    n_frames, height, width = depth.shape
    a_i = np.float32(intensity_coeff)
    n_chunks = min(height, ROW_CHUNKS)
    for chunk in prange(n_chunks):
        acc = np.empty(width, dtype=np.float32)
        norm = np.empty(width, dtype=np.float32)
        center = np.empty(width, dtype=np.float32)
        inv_center = np.empty(width, dtype=np.float32)
        rad2 = np.empty(width, dtype=np.int32)
        for row in range(chunk * height // n_chunks, (chunk + 1) * height // n_chunks):
            max_rad = 0
            for u in range(width):
                c = depth[ref, row, u]
                ok = not math.isnan(c)
                center[u] = c if ok else np.float32(0.0)
                inv_center[u] = np.float32(1.0) / c if (relative and ok) else np.float32(1.0)
                r = radius[row, u] if ok else 0
                rad2[u] = r * r
                max_rad = max(max_rad, r)
                acc[u] = 0.0
                norm[u] = 0.0
            for k in range(n_frames):
                wt = time_weight[k]
                if wt <= 0.0:
                    continue
                for rr in range(max(row - max_rad, 0), min(row + max_rad + 1, height)):
                    dr = rr - row
                    for dc in range(-max_rad, max_rad + 1):
                        d2 = dr * dr + dc * dc
                        if d2 > max_rad * max_rad:
                            continue
                        u0 = max(0, -dc)
                        u1 = min(width, width - dc)
                        if u1 <= u0:
                            continue
                        _accumulate_offset(
                            center[u0:u1],
                            inv_center[u0:u1],
                            guide[ref, row, u0:u1],
                            spatial_coeff[row, u0:u1],
                            range_coeff[row, u0:u1],
                            rad2[u0:u1],
                            depth[k, rr, u0 + dc : u1 + dc],
                            guide[k, rr, u0 + dc : u1 + dc],
                            wt,
                            d2,
                            a_i,
                            acc[u0:u1],
                            norm[u0:u1],
                        )
            for u in range(width):
                c = depth[ref, row, u]
                if math.isnan(c):
                    out[row, u] = np.nan
                else:
                    out[row, u] = acc[u] / norm[u] if norm[u] > 0.0 else c
