"""Per-pixel temporal baselines: TA (Wasza et al. 2011, BASELINES §5) and the plain mean."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._kernels._common import gauss_factor
from .._kernels.baselines import _temporal_average_kernel
from .._params import check_int, check_number
from ..camera import Intrinsics
from ._common import check_inputs, estimate_noise_model, iterate

__all__ = ["temporal_average", "temporal_mean"]


def temporal_average(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 5,
    iterations: int = 1,
    noise_sigma: float | None = None,
    sigma_temporal: float = np.inf,
) -> NDArray[np.float32]:
    """TA: causal, range-constrained per-pixel averaging of the last N frames.

    ``D'_t(x) = Σ_k w_k D_{t−k}(x) / Σ_k w_k``, ``w_k = exp(−k²/2σ_t²) ·
    exp(−(D_{t−k}(x) − D_t(x))²/2σ_r²)``, σ_r = 3 σ̂_d (BASELINES §5, weights [R]).
    Without ``noise_sigma``, σ̂_d follows the depth-noise model at each pixel's depth,
    σ_r(x) = 3 max(σ0, q D_t(x)²) (:func:`fuse4d.baselines._common.estimate_noise_model`,
    A22): on quantised far depth the gate spans the sensor's depth steps.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray or None
        Unused (common signature).
    intrinsics : Intrinsics
        Camera (shape check only).
    size : int, default 5
        ``num_frames`` N: frames in the causal window (truncated at the start). Sweep 2–9.
    iterations : int, default 1
        Repeated application to its own output sequence.
    noise_sigma : float, optional
        σ_d in mm (oracle, one value for every pixel); default: the noise model
        σ(z) = max(σ0, q z²) estimated from ``depth``.
    sigma_temporal : float, default inf
        σ_t in frames (inf = uniform in time).

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm), NaN where the input is NaN.
    """
    d, _ = check_inputs(depth, intensity, intrinsics)
    n = check_int("temporal_average", "size", size, minimum=1)
    check_number("temporal_average", "sigma_temporal", sigma_temporal, gt=0)
    # gauss_factor: a tiny sigma is the narrowest kernel (1 / (2 sigma^2) was a ZeroDivisionError)
    coeff_t = 0.0 if np.isinf(sigma_temporal) else gauss_factor(sigma_temporal)
    if noise_sigma is not None:
        sigma = check_number("temporal_average", "noise_sigma", noise_sigma, gt=0, finite=True)
        model = None
    else:
        model = estimate_noise_model(d)
        sigma = model.sigma_median
        if model.quad == 0.0:
            model = None  # constant sigma: the compiled kernel

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        if model is None:
            out = np.empty_like(cur)
            _temporal_average_kernel(
                np.ascontiguousarray(cur), n, coeff_t, gauss_factor(3.0 * sigma), out
            )
            return out
        sigma_r = 3.0 * np.maximum(model.sigma_at(cur), 1e-3)
        return _temporal_average_varying(cur, n, coeff_t, 0.5 / sigma_r**2)

    return iterate(step, d, iterations, owner="temporal_average")


def _temporal_average_varying(
    depth: NDArray[np.float32], n: int, coeff_t: float, coeff_r: NDArray[np.float64]
) -> NDArray[np.float32]:
    """TA with a per-pixel range coefficient ``coeff_r`` (T, H, W) = 1 / (2 σ_r²) (1/mm²).

    Same weights as the compiled kernel; σ_r is taken at the centre sample D_t(x).
    """
    acc = np.zeros(depth.shape, np.float64)
    norm = np.zeros(depth.shape, np.float64)
    for k in range(min(n, depth.shape[0])):
        cur = depth[k:].astype(np.float64)
        past = depth[: depth.shape[0] - k].astype(np.float64)
        with np.errstate(invalid="ignore"):
            w = np.exp(-(k * k) * coeff_t - (past - cur) ** 2 * coeff_r[k:])
        ok = np.isfinite(w)
        acc[k:] += np.where(ok, w * past, 0.0)
        norm[k:] += np.where(ok, w, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = acc / norm
    return np.where(np.isfinite(depth), out, np.nan).astype(np.float32)


def temporal_mean(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 9,
    iterations: int = 1,
) -> NDArray[np.float32]:
    """Plain per-pixel mean over a centred window of ``size`` frames (no motion compensation).

    The reference users run today, over the same window as fuse4d's fusion (9 frames). Invalid
    samples are skipped; the window is truncated at the sequence ends; output NaN where the
    centre frame is NaN. Moving objects leave ghosts (that is the point of this reference).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray or None
        Unused (common signature).
    intrinsics : Intrinsics
        Camera (shape check only).
    size : int, default 9
        ``num_frames`` n: the window is [t − ⌊(n−1)/2⌋, t + ⌈(n−1)/2⌉]. Sweep 2–9.
    iterations : int, default 1
        Repeated application to its own output sequence.

    Returns
    -------
    (T, H, W) ndarray of float32
        Averaged depth (mm).
    """
    d, _ = check_inputs(depth, intensity, intrinsics)
    n = check_int("temporal_mean", "size", size, minimum=1)
    before = (n - 1) // 2
    after = n - 1 - before

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        valid = np.isfinite(cur)
        vals = np.where(valid, cur, 0.0).astype(np.float64)
        csum = np.concatenate([np.zeros((1, *cur.shape[1:])), np.cumsum(vals, axis=0)])
        ccnt = np.concatenate([np.zeros((1, *cur.shape[1:])), np.cumsum(valid, axis=0)])
        t = np.arange(cur.shape[0])
        lo = np.clip(t - before, 0, cur.shape[0])
        hi = np.clip(t + after + 1, 0, cur.shape[0])
        total = csum[hi] - csum[lo]
        count = ccnt[hi] - ccnt[lo]
        with np.errstate(invalid="ignore", divide="ignore"):
            out = total / count
        return np.where(valid, out, np.nan).astype(np.float32)

    return iterate(step, d, iterations, owner="temporal_mean")
