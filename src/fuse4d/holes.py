"""Filling sensor holes where the data supports it (issue 10; decisions A26, A27).

Depth cameras leave holes: shadow bands beside foreground edges (structured light, stereo),
dark or grazing surfaces, specular spots, flying-pixel filters. The paper's Eq. 6 fills only
pixels *with* depth but without temporal support; the sensor's own holes stayed holes. Two
stages fill them, each switchable in :class:`fuse4d.FusionParams`:

1. **From time** (A26, ``fill_from_time``): a pixel without depth at t is tracked through the
   intensity video like any other; where the track lands on valid depth in other frames of the
   window, the motion-trajectory line through those frames' reference points is evaluated at t
   (the A21 trajectory base, without frame t's own sample). This fills holes that a moving
   object uncovers or that flicker from frame to frame — the data says what is there.
2. **In space** (A27, ``fill_max_hole_px``): each remaining hole *component* (8-connected) that
   is small (at most ``fill_max_hole_px`` pixels) and does not touch the image border (no
   extrapolation beyond the sensor's field of view) gets an intensity-weighted mean of valid
   neighbours within ``fill_space_radius`` px, from the far side only: the valid neighbours
   within the depth-step limit (A22) of the farthest one. A shadow band beside a foreground
   edge belongs to the background, so the fill never bridges a depth discontinuity.

Every filled pixel is flagged (:data:`SOURCE_TIME`, :data:`SOURCE_SPACE` in
:attr:`fuse4d.FusedFrame.source`), so a user can drop them.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels.holes import _spatial_fill_kernel
from ._validation import as_float32, check_shape

__all__ = [
    "SOURCE_FUSED",
    "SOURCE_MEASURED",
    "SOURCE_NONE",
    "SOURCE_SPACE",
    "SOURCE_TIME",
    "fill_small_holes",
    "small_hole_mask",
]

#: :attr:`fuse4d.FusedFrame.source` codes: where each output pixel's value comes from.
SOURCE_NONE = 0  # no depth (a hole that was not filled)
SOURCE_MEASURED = 1  # raw depth, no temporal support (spatial bilateral / Eq. 6 only)
SOURCE_FUSED = 2  # raw depth fused with >= 1 tracked frame (Eq. 5)
SOURCE_TIME = 3  # a sensor hole filled from other frames along its track (A26)
SOURCE_SPACE = 4  # a small sensor hole filled from its far-side neighbours (A27)


def small_hole_mask(holes: ArrayLike, max_area_px: int) -> NDArray[np.bool_]:
    """Pixels of hole components (8-connected) small enough to fill spatially.

    Parameters
    ----------
    holes : (H, W) ndarray of bool
        True where there is no depth.
    max_area_px : int
        Largest component (pixels) that is filled; 0 = none.

    Returns
    -------
    (H, W) ndarray of bool
        Pixels of the components with at most ``max_area_px`` pixels that do not touch the
        image border.

    Examples
    --------
    >>> h = np.zeros((6, 6), bool); h[2:4, 2:4] = True; h[0, 5] = True
    >>> small_hole_mask(h, 4).sum()  # the 2x2 inside hole; the border pixel is left
    np.int64(4)
    """
    mask = np.asarray(holes, dtype=bool)
    if max_area_px <= 0 or not mask.any():
        return np.zeros(mask.shape, bool)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    x, y, w, h, area = (stats[:, i] for i in range(5))
    height, width = mask.shape
    inside = (x > 0) & (y > 0) & (x + w < width) & (y + h < height)
    keep = inside & (area <= max_area_px)
    keep[0] = False  # label 0 is the background (pixels with depth)
    return keep[labels] & mask


def fill_small_holes(
    depth: ArrayLike,
    intensity: ArrayLike,
    *,
    max_area_px: int = 64,
    radius: int = 4,
    sigma_intensity: float = 0.1,
    sigma_space: float = 2.0,
    max_step: float = 10.0,
    noise_quad: float = 0.0,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Fill small sensor holes from their far-side neighbours (A27).

    Parameters
    ----------
    depth : (H, W) ndarray
        Depth in mm, NaN = hole.
    intensity : (H, W) ndarray
        Registered intensity in [0, 1]: neighbours of similar intensity weigh more.
    max_area_px : int
        Largest hole component filled (pixels); components touching the image border are
        never filled.
    radius : int
        Neighbourhood radius (px).
    sigma_intensity : float
        Intensity scale of the weights ([0, 1] units).
    sigma_space : float
        Spatial scale of the weights (px).
    max_step : float
        tau_jump (mm): neighbours farther than the depth-step limit from the farthest
        neighbour are not used.
    noise_quad : float
        Depth-noise coefficient (mm^-1, A22); the step limit is max(max_step, 2.5 q z^2).

    Returns
    -------
    depth : (H, W) ndarray of float32
        Depth with the small holes filled (mm).
    filled : (H, W) ndarray of bool
        The pixels that were filled.

    Examples
    --------
    >>> d = np.full((9, 9), 2000.0, np.float32); d[:, 6:] = 1000.0  # foreground on the right
    >>> d[3:6, 4:6] = np.nan  # a shadow hole beside the foreground edge
    >>> out, filled = fill_small_holes(d, np.full_like(d, 0.5))
    >>> float(out[4, 5]), int(filled.sum())  # filled with the background, not a blend
    (2000.0, 6)
    """
    d = as_float32(depth, name="depth")
    check_shape(d, ("H", "W"), name="depth")
    inten = as_float32(intensity, name="intensity")
    check_shape(inten, d.shape, name="intensity")
    target = small_hole_mask(np.isnan(d), int(max_area_px))
    out = d.copy()
    if target.any():
        _spatial_fill_kernel(
            d,
            inten,
            target,
            int(radius),
            1.0 / (2.0 * sigma_intensity**2),
            1.0 / (2.0 * sigma_space**2),
            float(max_step),
            float(noise_quad),
            out,
        )
    filled = target & np.isfinite(out)
    return out, filled
