"""The one joint-bilateral kernel behind Ad-GF, Ad-BF, Ad-JBF and DNBF (BASELINES.md, "Shared kernel").

Weight of neighbour ``j`` (frame ``tau``) for centre pixel ``i`` of the reference frame::

    w = time_weight[tau]
        * exp(-|x_i - x_j|^2 * spatial_coeff[i])          spatial   (coeff = 1 / (2 sigma_s^2))
        * exp(-(I_tau(j) - I_ref(i))^2 * intensity_coeff) intensity (0 = off)
        * exp(-rho^2 * range_coeff[i])                    depth range (0 = off)

with ``rho = D_tau(j) - D_ref(i)`` (mm), or ``rho = (D_tau(j) - D_ref(i)) / D_ref(i)`` when
``relative`` (DNBF's divisive normalisation). The three Gaussians are evaluated as a single
``exp`` of the summed exponents. The window is the disc ``|x_i - x_j| <= radius[i]`` (like
OpenCV's bilateral filters), clipped at the image border (no padding). NaN depth never
contributes; a NaN centre gives NaN.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit_parallel, prange

__all__ = ["_joint_bilateral_kernel", "make_exp_table"]

#: Exponent range of the weight table: exp(-30) ~ 1e-13 is treated as 0.
EXP_TABLE_MAX = 30.0
#: Entries per unit exponent; linear interpolation error <= (1/64)^2 / 8 ~ 3e-5 (relative).
EXP_TABLE_SCALE = 64.0


def make_exp_table(
    max_exponent: float = EXP_TABLE_MAX, scale: float = EXP_TABLE_SCALE
) -> np.ndarray:
    """Lookup table ``exp(-k / scale)``, k = 0 .. max_exponent·scale (float32).

    The kernel interpolates it linearly instead of calling ``exp`` per tap (no SIMD exp in
    numba without SVML), which makes it several times faster.
    """
    n = round(max_exponent * scale) + 2
    return np.exp(-np.arange(n, dtype=np.float64) / scale).astype(np.float32)


@njit_parallel
def _joint_bilateral_kernel(
    depth,
    intensity,
    ref,
    time_weight,
    radius,
    spatial_coeff,
    intensity_coeff,
    range_coeff,
    relative,
    exp_table,
    table_scale,
    out,
):  # pragma: no cover - compiled (covered via NUMBA_DISABLE_JIT runs)
    """Fill ``out`` (H, W) with the joint-bilateral average around frame ``ref``.

    Parameters
    ----------
    depth : (K, H, W) float32
        Depth (mm) of the K frames of the window; NaN = invalid.
    intensity : (K, H, W) float32
        Intensity in [0, 1] of the same frames (ignored when ``intensity_coeff == 0``).
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
    exp_table : (N,) float32
        ``exp(-k / table_scale)`` for k = 0..N-1 (linearly interpolated; exponents beyond the
        table give weight 0). See :func:`make_exp_table`.
    table_scale : float
        Table entries per unit of exponent.
    out : (H, W) float32
        Output buffer.
    """
    n_frames, height, width = depth.shape
    use_intensity = intensity_coeff > 0.0
    a_i = np.float32(intensity_coeff)
    scale = np.float32(table_scale)
    last = np.float32(exp_table.shape[0] - 1)
    for row in prange(height):
        for col in range(width):
            center = depth[ref, row, col]
            if math.isnan(center):
                out[row, col] = np.nan
                continue
            rad = radius[row, col]
            rad2 = rad * rad
            a_s = spatial_coeff[row, col]
            a_d = range_coeff[row, col]
            inv_center = np.float32(1.0) / center if relative else np.float32(1.0)
            i_c = intensity[ref, row, col] if use_intensity else np.float32(0.0)
            r0 = max(row - rad, 0)
            r1 = min(row + rad, height - 1)
            acc = 0.0
            norm = 0.0
            for k in range(n_frames):
                wt = time_weight[k]
                if wt <= 0.0:
                    continue
                for rr in range(r0, r1 + 1):
                    dr2 = (rr - row) * (rr - row)
                    half = int(math.sqrt(rad2 - dr2))  # disc: |dc| <= sqrt(r^2 - dr^2)
                    c0 = max(col - half, 0)
                    c1 = min(col + half, width - 1)
                    for cc in range(c0, c1 + 1):
                        value = depth[k, rr, cc]
                        if math.isnan(value):  # NaN never contributes
                            continue
                        dc = cc - col
                        diff = (value - center) * inv_center
                        expo = np.float32(dr2 + dc * dc) * a_s + diff * diff * a_d
                        if use_intensity:
                            di = intensity[k, rr, cc] - i_c
                            expo += di * di * a_i
                        x = expo * scale
                        if x >= last:
                            continue
                        i = int(x)
                        f = x - np.float32(i)
                        w = wt * (exp_table[i] + f * (exp_table[i + 1] - exp_table[i]))
                        acc += w * value
                        norm += w
            out[row, col] = acc / norm if norm > 0.0 else center
