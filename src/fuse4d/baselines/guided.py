"""Guided filter (He, Sun, Tang, TPAMI 2013) through ``cv2.ximgproc.guidedFilter`` (BASELINES §3)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._params import check_int, check_number
from ..camera import Intrinsics
from ._common import check_inputs, iterate, normalized_convolution_fill

__all__ = ["guided"]


def guided(
    depth: ArrayLike,
    intensity: ArrayLike,
    intrinsics: Intrinsics,
    *,
    size: int = 4,
    iterations: int = 1,
    eps: float = 0.1**2,
) -> NDArray[np.float32]:
    """Intensity-guided filter of depth (guide I, input D).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray
        Guide in [0, 1].
    intrinsics : Intrinsics
        Camera (shape check only).
    size : int, default 4
        ``spatial_radius``: box radius r (px). Sweep 2, 4, 8, 12, 16.
    iterations : int, default 1
        Repeated application to its own output.
    eps : float, default 0.01
        Regulariser ε in guide units² ([0, 1]²), independent of depth units.
        Sweep 0.05², 0.1², 0.2², 0.4².

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm), NaN where the input is NaN.

    Notes
    -----
    NaN depth is first replaced by a normalised-convolution fill (Gaussian σ = 3 px over valid
    pixels); the output is re-masked with the raw validity. Library call:
    ``cv2.ximgproc.guidedFilter(guide=I, src=D, radius=r, eps=ε, dDepth=-1)``. At small ε the
    intensity texture is copied into depth; this artefact is part of the method.
    """
    d, g = check_inputs(depth, intensity, intrinsics)
    radius = check_int("guided", "size", size, minimum=1)
    check_number("guided", "eps", eps, gt=0)
    valid = np.isfinite(d)

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        out = np.empty_like(cur)
        for t in range(cur.shape[0]):
            src = normalized_convolution_fill(cur[t], sigma=3.0)
            out[t] = cv2.ximgproc.guidedFilter(
                guide=g[t], src=src, radius=radius, eps=float(eps), dDepth=-1
            )
        return np.where(valid, out, np.nan).astype(np.float32)

    return iterate(step, d, iterations, owner="guided")
