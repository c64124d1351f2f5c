"""Guided filter (He, Sun, Tang, TPAMI 2013) through ``cv2.ximgproc.guidedFilter`` (BASELINES §3).

The one guided filter of fuse4d: intensity-guided (the baseline) or self-guided by the depth
(the single-frame reference of ``bench --quality`` and ``demo``).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._params import check_int, check_number
from ..camera import Intrinsics
from ..errors import ParameterError
from ._common import MAX_WINDOW_RADIUS, check_inputs, iterate, normalized_convolution_fill

__all__ = ["guided"]


def guided(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 4,
    iterations: int = 1,
    eps: float = 0.1**2,
    guide: Literal["intensity", "depth"] = "intensity",
) -> NDArray[np.float32]:
    """Guided filter of depth: intensity-guided (guide I, input D) or self-guided (guide D).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray or None
        Guide in [0, 1] (unused, may be None, with ``guide="depth"``).
    intrinsics : Intrinsics
        Camera (shape check only).
    size : int, default 4
        ``spatial_radius``: box radius r (px). Sweep 2, 4, 8, 12, 16.
    iterations : int, default 1
        Repeated application to its own output.
    eps : float, default 0.01
        Regulariser ε in guide units²: [0, 1]² for the intensity guide (sweep 0.05², 0.1²,
        0.2², 0.4²), mm² for the depth guide (``bench --quality`` uses r = 2, ε = 10 mm², the
        best single-frame filter in PEERS.md).
    guide : {"intensity", "depth"}, default "intensity"
        The guide image: the registered intensity, or the (hole-filled) depth frame itself.

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm), NaN where the input is NaN.

    Notes
    -----
    NaN depth is first replaced by a normalised-convolution fill (Gaussian σ = 3 px over valid
    pixels), a local fill that does not pull depth near a hole towards a far-away value; the
    output is re-masked with the raw validity. Intensity guide, library call:
    ``cv2.ximgproc.guidedFilter(guide=G, src=D, radius=r, eps=ε, dDepth=-1)``. At small ε the
    intensity texture is copied into depth; this artefact is part of the method. Depth guide:
    the same filter (box means, ``BORDER_REFLECT`` as OpenCV's) in float64 about the frame's
    mean, with ``a = var / (var + ε)``, var clamped at 0 (:func:`_self_guided`): OpenCV's
    float32 ``mean(D²) − mean(D)²`` cancels at depths of metres (NaN even on a constant
    frame of 3955 mm), which turned most valid depth into NaN.
    """
    if guide not in ("intensity", "depth"):
        raise ParameterError(f"guide must be 'intensity' or 'depth', got {guide!r}")
    d, g = check_inputs(
        depth,
        intensity if guide == "intensity" else None,
        intrinsics,
        guided_by="guided with guide='intensity'" if guide == "intensity" else None,
    )
    radius = check_int("guided", "size", size, minimum=1, maximum=MAX_WINDOW_RADIUS)
    check_number("guided", "eps", eps, gt=0)
    valid = np.isfinite(d)

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        out = np.empty_like(cur)
        for t in range(cur.shape[0]):
            src = normalized_convolution_fill(cur[t], sigma=3.0)
            if g is None:
                out[t] = _self_guided(src, radius, float(eps))
            else:
                out[t] = cv2.ximgproc.guidedFilter(
                    guide=g[t], src=src, radius=radius, eps=float(eps), dDepth=-1
                )
        return np.where(valid, out, np.nan).astype(np.float32)

    return iterate(step, d, iterations, owner="guided")


def _self_guided(depth: NDArray[np.float32], radius: int, eps: float) -> NDArray[np.float64]:
    """Self-guided filter (guide = input) of one NaN-free depth frame (mm), in float64.

    He et al.'s Algorithm 1 with guide = input: ``a = var / (var + ε)``, ``b = (1 − a) mean``,
    ``q = mean(a) D + mean(b)``, box means of radius ``radius`` px with OpenCV's border
    (``BORDER_REFLECT``). Computed about the frame's mean depth and with the variance clamped
    at 0, so that ``a`` lies in [0, 1) and no finite input gives NaN; ``eps`` in mm².
    """
    centre = float(np.mean(depth, dtype=np.float64))
    x = depth.astype(np.float64) - centre
    ksize = (2 * radius + 1, 2 * radius + 1)

    def box(v: NDArray[np.float64]) -> NDArray[np.float64]:
        return cv2.boxFilter(v, -1, ksize, normalize=True, borderType=cv2.BORDER_REFLECT)

    mean = box(x)
    var = np.maximum(box(x * x) - mean * mean, 0.0)
    a = var / (var + eps)
    b = (1.0 - a) * mean
    return box(a) * x + box(b) + centre
