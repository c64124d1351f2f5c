"""Gradient-directed hole filling of fused point maps (paper Eq. 6, METHOD §6.2).

A hole is a pixel with valid raw depth but too little temporal support to be fused (Eq. 5).
It gets a weighted average of first-order extrapolations from the fused neighbours n in its
(2 r_h + 1)^2 window::

    p_i = sum_n h(P_i, p_n) (p_n + J_n (x_i - x_n)) / sum_n h(P_i, p_n),
    h(P_i, p_n) = exp(-|P_i - p_n|^2 / (2 delta_h^2)),

with J_n the 3x2 Jacobian of the fused surface at n (central / one-sided differences over the
fused set F) and P_i the raw point of the hole. Onion peeling: each pass fills the holes with at
least ``min_neighbours`` neighbours in F as F stood at the start of the pass, then adds them to
F. A fill is accepted only within ``gate`` mm of the hole's current (fallback) value (A20).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels.fusion import _fill_holes_kernel
from ._validation import as_float32, check_shape
from .config import FusionParams

__all__ = ["fill_holes"]


def _fill_holes(
    points: NDArray[np.float32],
    raw_points: NDArray[np.float32],
    hole: NDArray[np.bool_],
    *,
    radius: int,
    sigma: float,
    passes: int,
    min_neighbours: int,
    gate: float,
) -> NDArray[np.bool_]:
    """Unvalidated Eq. 6, in place on ``points`` and ``hole`` (cleared where filled).

    Returns the (H, W) bool mask of the pixels filled.
    """
    filled = np.zeros(hole.shape, np.bool_)
    _fill_holes_kernel(
        points,
        raw_points,
        hole,
        int(radius),
        1.0 / (2.0 * sigma**2),
        int(passes),
        int(min_neighbours),
        float(gate),
        filled,
    )
    return filled


def fill_holes(
    points: ArrayLike,
    raw_points: ArrayLike,
    hole: ArrayLike,
    *,
    radius: int = FusionParams.fill_radius,
    sigma: float = FusionParams.sigma_fill,
    passes: int = FusionParams.fill_passes,
    min_neighbours: int = 3,
    gate: float = math.inf,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Fill the holes of a fused point map by gradient-directed extrapolation (Eq. 6).

    Parameters
    ----------
    points : (H, W, 3) ndarray
        Fused points in mm; holes hold their fallback value (the engine uses the bilateral-only
        point B^t), NaN = no depth (never filled, never used).
    raw_points : (H, W, 3) ndarray
        Raw points P^t in mm (the weights compare a hole's raw point with its neighbours).
    hole : (H, W) bool ndarray
        Pixels to fill.
    radius : int
        r_h in px (default ``FusionParams.fill_radius``).
    sigma : float
        delta_h in mm (default ``FusionParams.sigma_fill``).
    passes : int
        Maximum onion-peeling passes (default ``FusionParams.fill_passes``).
    min_neighbours : int
        Fused neighbours a hole needs in its window to be filled in a pass.
    gate : float
        A20 acceptance gate in mm: a fill farther than this from the hole's current value is
        rejected (the engine uses the frame's temporal gate); ``math.inf`` = literal Eq. 6.

    Returns
    -------
    points : (H, W, 3) ndarray of float32
        A copy of ``points`` with the accepted fills (mm).
    filled : (H, W) ndarray of bool
        Holes that were filled; ``hole & ~filled`` keep their fallback value.

    Examples
    --------
    >>> p = np.zeros((5, 5, 3), np.float32); p[..., 2] = 500.0 + np.arange(5)
    >>> hole = np.zeros((5, 5), bool); hole[2, 2] = True
    >>> out, filled = fill_holes(np.where(hole[..., None], 0, p), p, hole)
    >>> bool(filled[2, 2]), round(float(out[2, 2, 2]), 3)
    (True, 502.0)
    """
    pts = as_float32(points, name="points").copy()
    check_shape(pts, ("H", "W", 3), name="points")
    raw = as_float32(raw_points, name="raw_points")
    check_shape(raw, pts.shape, name="raw_points")
    mask = np.array(hole, dtype=np.bool_, copy=True)
    check_shape(mask, pts.shape[:2], name="hole")
    for name, value in (("radius", radius), ("passes", passes), ("min_neighbours", min_neighbours)):
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0 mm, got {sigma}")
    if not gate > 0:
        raise ValueError(f"gate must be > 0 mm, got {gate}")
    filled = _fill_holes(
        pts,
        raw,
        mask,
        radius=radius,
        sigma=sigma,
        passes=passes,
        min_neighbours=min_neighbours,
        gate=gate,
    )
    return pts, filled
