"""Regions of interest for the metrics: default (any data), the synthetic scenes' ROIs."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from .._validation import as_float32
from ..errors import ShapeError
from ..sequence import GroundTruth, Sequence

__all__ = [
    "ball_roi",
    "central_roi",
    "default_roi",
    "scene_roi",
    "static_mask_from_ground_truth",
]


def _window_size(ndim: int, window: int) -> tuple[int, ...]:
    return (1,) * (ndim - 2) + (window, window)


def _window_inside(mask: NDArray[np.bool_], window: int) -> NDArray[np.bool_]:
    """True where the whole ``window x window`` neighbourhood is True (outside = False)."""
    return ndimage.minimum_filter(
        mask, size=_window_size(mask.ndim, window), mode="constant", cval=False
    )


def default_roi(depth: ArrayLike, *, window: int = 5, edge_mm: float = 10.0) -> NDArray[np.bool_]:
    """The default roughness ROI, usable on any sequence (real or synthetic).

    A pixel is in the ROI if its whole ``window x window`` neighbourhood lies inside the image
    and holds valid depth, and the depth range (max - min) inside it is at most ``edge_mm``,
    i.e. the window does not straddle a depth discontinuity.

    Parameters
    ----------
    depth : (H, W) or (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    window : int, optional
        Window size n (odd, px), the roughness window.
    edge_mm : float, optional
        Largest depth range (mm) inside the window.

    Returns
    -------
    ndarray of bool, shape of ``depth``

    Examples
    --------
    >>> d = np.full((8, 8), 500.0); d[:, 5:] = 900.0
    >>> default_roi(d, window=3)[4].tolist()
    [False, True, True, True, False, False, True, False]
    """
    d = as_float32(depth, name="depth")
    if d.ndim not in (2, 3):
        raise ShapeError("depth", ("T", "H", "W"), d.shape, "a (H, W) or (T, H, W) depth map")
    if not (math.isfinite(edge_mm) and edge_mm >= 0):
        raise ValueError(f"edge_mm must be a finite number >= 0 (mm), got {edge_mm!r}")
    if isinstance(window, bool) or int(window) != window or window < 1 or window % 2 == 0:
        raise ValueError(f"window must be an odd positive integer (pixels), got {window!r}")
    valid = np.isfinite(d)
    size = _window_size(d.ndim, window)
    full = _window_inside(valid, window)
    dmax = ndimage.maximum_filter(np.where(valid, d, -np.inf), size=size, mode="nearest")
    dmin = ndimage.minimum_filter(np.where(valid, d, np.inf), size=size, mode="nearest")
    with np.errstate(invalid="ignore"):
        return full & (dmax - dmin <= np.float32(edge_mm))


def _ground_truth(seq_or_gt: Sequence | GroundTruth) -> GroundTruth:
    gt = seq_or_gt.ground_truth if isinstance(seq_or_gt, Sequence) else seq_or_gt
    if not isinstance(gt, GroundTruth):
        raise ValueError(  # noqa: TRY004  (missing data, not a wrong type)
            "this ROI needs ground truth (a synthetic scene from fuse4d.synthetic)"
        )
    return gt


def _extra(gt: GroundTruth, key: str, default: object = None) -> object:
    if key in gt.extra:
        return gt.extra[key]
    if default is None:
        raise ValueError(f"ground truth lacks extra[{key!r}]; is this a fuse4d.synthetic scene?")
    return default


def ball_roi(
    seq_or_gt: Sequence | GroundTruth, *, window: int = 5, radius_px: float | None = None
) -> NDArray[np.bool_]:
    """ROI of the synthetic falling ball (EVALUATION §3).

    Pixels within ``radius_px`` of the ball's projected centre ``(center_col, v_c(t))`` whose
    whole ``window x window`` neighbourhood lies inside the GT ball mask (surface normals within
    about 30 degrees of the view direction).

    Parameters
    ----------
    seq_or_gt : Sequence or GroundTruth
        A :func:`~fuse4d.synthetic.make_falling_ball` scene (uses ``mask`` and ``extra``
        ``center_row``, ``center_col``, ``roi_radius_px``).
    window : int, optional
        Roughness window size n (px).
    radius_px : float, optional
        ROI radius in px. Default ``extra["roi_radius_px"]``: 100 px at full size, scaled by
        ``pixel_scale`` for the small variant (25 px).

    Returns
    -------
    (T, H, W) ndarray of bool
    """
    gt = _ground_truth(seq_or_gt)
    if gt.mask is None:
        raise ValueError("ball_roi needs the ground-truth ball mask")
    mask = np.asarray(gt.mask, dtype=bool)
    rows = np.asarray(_extra(gt, "center_row"), dtype=np.float64).reshape(-1)
    if rows.size != mask.shape[0]:
        raise ShapeError("extra['center_row']", (mask.shape[0],), rows.shape, "one row per frame")
    col = float(_extra(gt, "center_col"))  # type: ignore[arg-type]
    radius = float(radius_px if radius_px is not None else _extra(gt, "roi_radius_px", 100.0))  # type: ignore[arg-type]
    h, w = mask.shape[1:]
    vv = np.arange(h, dtype=np.float64)[None, :, None]
    uu = np.arange(w, dtype=np.float64)[None, None, :]
    near = (uu - col) ** 2 + (vv - rows[:, None, None]) ** 2 <= radius**2
    return near & _window_inside(mask, window)


def central_roi(seq: Sequence, *, fraction: float = 0.8, window: int = 5) -> NDArray[np.bool_]:
    """ROI of the synthetic plane and sheet (EVALUATION §4 E5): their central part.

    Pixels whose surface point lies in the central ``fraction`` of the object along each side
    (in the object's own, material coordinates: 0.8 -> 96 x 64 mm of the 120 x 80 mm plane,
    96 x 96 mm of the sheet) and whose ``window x window`` neighbourhood is inside the GT mask.

    Parameters
    ----------
    seq : Sequence
        A :func:`~fuse4d.synthetic.make_static_plane` or
        :func:`~fuse4d.synthetic.make_deforming_sheet` scene.
    fraction : float, optional
        Linear fraction of each side, in (0, 1].
    window : int, optional
        Roughness window size n (px).

    Returns
    -------
    (T, H, W) ndarray of bool
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    gt = _ground_truth(seq)
    if gt.depth is None or gt.mask is None:
        raise ValueError("central_roi needs ground-truth depth and mask")
    scene = _extra(gt, "scene")
    k = seq.intrinsics
    z = np.asarray(gt.depth, dtype=np.float64)
    xn = (np.arange(k.width) - k.cx) / k.fx
    yn = (np.arange(k.height) - k.cy) / k.fy
    x = z * xn[None, None, :]
    y = z * yn[None, :, None]
    size = np.asarray(_extra(gt, "size_mm"), dtype=np.float64)
    if scene == "plane":
        theta = math.radians(float(_extra(gt, "tilt_deg")))  # type: ignore[arg-type]
        z0 = float(np.asarray(_extra(gt, "center_mm"))[2])
        a, b = x, y * math.cos(theta) + (z - z0) * math.sin(theta)
    elif scene == "sheet":
        cx_mm = np.asarray(_extra(gt, "center_x_mm"), dtype=np.float64).reshape(-1)
        a, b = x - cx_mm[:, None, None], y
    else:
        raise ValueError(f"central_roi applies to the 'plane' and 'sheet' scenes, not {scene!r}")
    with np.errstate(invalid="ignore"):
        inside = (np.abs(a) <= fraction * size[0] / 2) & (np.abs(b) <= fraction * size[1] / 2)
    return inside & _window_inside(np.asarray(gt.mask, dtype=bool), window)


def scene_roi(seq: Sequence, *, window: int = 5) -> tuple[NDArray[np.bool_], str]:
    """The EVALUATION ROI of a synthetic scene and a one-line description.

    ``ball`` -> :func:`ball_roi`; ``plane``/``sheet`` -> :func:`central_roi` (80 %).

    Raises
    ------
    ValueError
        If ``seq`` is not a synthetic scene (no ground truth or no ``extra["scene"]``).
    """
    gt = _ground_truth(seq)
    scene = _extra(gt, "scene")
    if scene == "ball":
        radius = float(_extra(gt, "roi_radius_px", 100.0))  # type: ignore[arg-type]
        return (
            ball_roi(seq, window=window),
            (
                f"ball ROI: within {radius:g} px of the ball centre, {window}x{window} window "
                "inside the GT mask"
            ),
        )
    return (
        central_roi(seq, window=window),
        f"central 80 % of the {scene}, {window}x{window} window inside the GT mask",
    )


def static_mask_from_ground_truth(gt: GroundTruth) -> NDArray[np.bool_]:
    """``(H, W)`` pixels that see a static surface in every frame (for temporal flicker).

    True where the GT depth is finite and identical in all frames and the GT flow is zero.
    """
    if gt.depth is None:
        raise ValueError("static_mask_from_ground_truth needs ground-truth depth")
    d = np.asarray(gt.depth)
    static = np.all(np.isfinite(d), axis=0) & np.all(d == d[:1], axis=0)
    if gt.flow is not None and np.asarray(gt.flow).shape[0] > 0:
        static &= np.all(np.asarray(gt.flow) == 0, axis=(0, 3))
    return static
