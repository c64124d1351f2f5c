"""Accuracy against ground truth (depth RMSE, bad pixels, flow errors) and temporal flicker."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from numbers import Real

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import as_float32, check_same_shape, check_shape
from ..errors import ParameterError, ParameterTypeError, ShapeError
from ..sequence import sanitize_depth
from .roi import step_limit

__all__ = [
    "FlickerStats",
    "bad_pixel_fraction",
    "depth_rmse",
    "flow_angular_error",
    "flow_endpoint_error",
    "temporal_flicker",
]


def _renamed(
    new: ArrayLike | None, old: ArrayLike | None, names: tuple[str, str]
) -> ArrayLike | None:
    """The region argument under its one name (``roi=`` / ``static=``); old name deprecated."""
    if old is None:
        return new
    if new is not None:
        raise TypeError(f"give {names[0]}= only ({names[1]}= is its deprecated name)")
    warnings.warn(
        f"{names[1]}= is deprecated; the region argument is called {names[0]}=",
        DeprecationWarning,
        stacklevel=3,
    )
    return old


def _pair(
    true: ArrayLike, test: ArrayLike, roi: ArrayLike | None, names: tuple[str, str]
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_]]:
    # 0, negative and inf depth are invalid (a 16-bit file's hole is 0, not a depth of 0 mm)
    a = sanitize_depth(as_float32(true, name=names[0]))
    b = sanitize_depth(as_float32(test, name=names[1]))
    check_same_shape(a, b, names=names)
    if roi is None:
        m = np.ones(a.shape, dtype=bool)
    else:
        m = np.asarray(roi)
        if m.dtype != np.bool_:
            raise ParameterTypeError(f"roi must be a boolean array, got dtype {m.dtype}")
    return a, b, m


def _broadcast_mask(mask: NDArray[np.bool_], shape: tuple[int, ...]) -> NDArray[np.bool_]:
    try:
        return np.broadcast_to(mask, shape)
    except ValueError:
        raise ShapeError("roi", shape, mask.shape, "it must broadcast to the data") from None


def depth_rmse(
    depth_true: ArrayLike,
    depth_test: ArrayLike,
    *,
    roi: ArrayLike | None = None,
    mask: ArrayLike | None = None,
) -> float:
    """Root-mean-square depth error (mm) over pixels valid in both maps (and in ``roi``).

    Parameters
    ----------
    depth_true, depth_test : (..., H, W) ndarray
        Ground-truth and estimated depth in mm; NaN, 0, negative and inf = invalid.
    roi : array of bool, optional
        Pixels to score (broadcast to the depth shape). ``mask=`` is its deprecated name.

    Returns
    -------
    float
        RMSE in mm; NaN if no pixel qualifies. Missing test depth is *not* counted here (see
        :func:`bad_pixel_fraction`, which counts it as bad).

    Examples
    --------
    >>> depth_rmse(np.array([1.0, 2.0, np.nan]), np.array([1.0, 4.0, 3.0]))
    1.4142135623730951
    """
    roi = _renamed(roi, mask, ("roi", "mask"))
    a, b, m = _pair(depth_true, depth_test, roi, ("depth_true", "depth_test"))
    use = _broadcast_mask(m, a.shape) & np.isfinite(a) & np.isfinite(b)
    if not use.any():
        return math.nan
    diff = a[use].astype(np.float64) - b[use]
    return float(np.sqrt(np.mean(diff**2)))


def bad_pixel_fraction(
    depth_true: ArrayLike,
    depth_test: ArrayLike,
    *,
    threshold: float = 1.0,
    roi: ArrayLike | None = None,
    mask: ArrayLike | None = None,
    noise_quad: float = 0.0,
) -> float:
    """Fraction of GT-valid pixels whose depth error exceeds ``threshold`` mm (or, with
    ``noise_quad``, the depth-noise model's step limit at the true depth, if larger).

    Pixels where the truth is valid but the test depth is NaN count as bad.

    Parameters
    ----------
    depth_true, depth_test : (..., H, W) ndarray
        Depth in mm; NaN, 0, negative and inf = invalid.
    threshold : float, optional
        Error threshold in mm (``bad_1mm`` uses 1.0).
    roi : array of bool, optional
        Pixels to score. ``mask=`` is its deprecated name.
    noise_quad : float, optional
        Depth-noise coefficient q (mm^-1, :func:`fuse4d.motion.estimate_noise_quad` of the
        raw video): the threshold at a pixel of true depth z is then
        ``max(threshold, 2.5 q z^2)`` (:func:`~fuse4d.metrics.step_limit`), 1.5 quantisation
        steps of structured-light depth (about 45 mm at 3 m on a Kinect), where a fixed
        1 mm calls every pixel bad, and any averaging that moves a value by less than a
        step "better". 0 = the fixed threshold.

    Returns
    -------
    float
        In [0, 1]; NaN if no GT-valid pixel.

    Examples
    --------
    >>> bad_pixel_fraction(np.array([1.0, 2.0, 3.0, 4.0]), np.array([1.5, 4.0, np.nan, 4.0]))
    0.5
    """
    for name, value, unit in (("threshold", threshold, "mm"), ("noise_quad", noise_quad, "1/mm")):
        if isinstance(value, bool) or not isinstance(value, Real):
            raise ParameterTypeError(f"{name} must be a number ({unit}), got {value!r}")
        if not (math.isfinite(value) and value >= 0):
            raise ParameterError(f"{name} must be a finite number >= 0 ({unit}), got {value!r}")
    roi = _renamed(roi, mask, ("roi", "mask"))
    a, b, m = _pair(depth_true, depth_test, roi, ("depth_true", "depth_test"))
    use = _broadcast_mask(m, a.shape) & np.isfinite(a)
    total = int(use.sum())
    if total == 0:
        return math.nan
    limit: np.floating | NDArray = np.float32(threshold)
    if noise_quad > 0:
        limit = step_limit(a[use], max_step=threshold, noise_quad=noise_quad).astype(np.float32)
    with np.errstate(invalid="ignore"):
        good = np.abs(a[use] - b[use]) <= limit
    return float(1.0 - good.sum() / total)


@dataclass(frozen=True)
class FlickerStats:
    """Temporal flicker of static pixels, mm: per-pixel std over time and frame-to-frame |Δ|.

    Attributes
    ----------
    median : float
        Median over pixels of the per-pixel std over time (ddof = 0): a secondary value. On
        quantised sensor depth over a short clip most static pixels never leave their
        quantisation level, so the median reads 0 mm for raw depth that flickers by whole
        steps at the other pixels (Kinect-model ball, 4 frames: raw median 0 against a fused
        1.9 mm, while the means read 24.9 and 2.7 mm).
    mean : float
        Mean over pixels of the per-pixel std over time: the headline temporal precision
        (every pixel's flicker counts, so a majority of quiet pixels cannot hide the rest).
    num_pixels : int
        Number of pixels evaluated (valid in every frame and in the static region).
    std_map : (H, W) ndarray of float32
        The per-pixel std (NaN where not evaluated).
    step_mean : float
        Mean over the same pixels and all consecutive frame pairs of ``|d_{t+1} - d_t|``
        (mm): the frame-to-frame change a viewer sees as flicker.
    step_median : float
        Median over pixels of the per-pixel mean ``|d_{t+1} - d_t|`` (mm).
    """

    median: float
    mean: float
    num_pixels: int
    std_map: NDArray[np.float32]
    step_mean: float = math.nan
    step_median: float = math.nan


def temporal_flicker(
    depth: ArrayLike,
    *,
    static: ArrayLike | None = None,
    static_mask: ArrayLike | None = None,
) -> FlickerStats:
    """Temporal flicker of a depth video on static pixels: std over time and frame-to-frame |Δ|.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm (NaN, 0, negative and inf = invalid); T >= 2.
    static : (H, W) array of bool, optional
        Pixels known to see a static surface (e.g.
        :func:`~fuse4d.metrics.static_mask_from_ground_truth` or
        :func:`~fuse4d.metrics.static_pixels`). Default: all pixels. Only pixels valid in
        *every* frame are used in any case. ``static_mask=`` is its deprecated name.

    Returns
    -------
    FlickerStats
        ``mean`` (headline) and ``median`` of the per-pixel std, ``step_mean`` of the
        frame-to-frame |Δ|, mm; NaN if no pixel.

    Examples
    --------
    >>> d = np.stack([np.full((2, 2), 500.0), np.full((2, 2), 502.0)])
    >>> f = temporal_flicker(d)
    >>> f.mean, f.median, f.step_mean
    (1.0, 1.0, 2.0)
    """
    static = _renamed(static, static_mask, ("static", "static_mask"))
    d = sanitize_depth(as_float32(depth, name="depth"))
    check_shape(d, ("T", "H", "W"), name="depth")
    if d.shape[0] < 2:
        raise ParameterError(f"temporal_flicker needs at least 2 frames, got {d.shape[0]}")
    use = np.all(np.isfinite(d), axis=0)
    if static is not None:
        sm = np.asarray(static)
        if sm.dtype != np.bool_:
            raise ParameterTypeError(f"static must be a boolean array, got dtype {sm.dtype}")
        if sm.shape != d.shape[1:]:
            raise ShapeError("static", d.shape[1:], sm.shape, "one (H, W) mask")
        use &= sm
    std_map = np.full(d.shape[1:], np.nan, dtype=np.float32)
    if use.any():
        vals = d[:, use].astype(np.float64)
        std_map[use] = vals.std(axis=0)
        per = std_map[use].astype(np.float64)
        steps = np.abs(np.diff(vals, axis=0))
        return FlickerStats(
            float(np.median(per)),
            float(per.mean()),
            int(use.sum()),
            std_map,
            float(steps.mean()),
            float(np.median(steps.mean(axis=0))),
        )
    return FlickerStats(math.nan, math.nan, 0, std_map)


def _flow_pair(
    flow_true: ArrayLike, flow_test: ArrayLike, roi: ArrayLike | None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    a = as_float32(flow_true, name="flow_true")
    b = as_float32(flow_test, name="flow_test")
    check_shape(a, ("*", "H", "W", 2), name="flow_true")
    check_same_shape(a, b, names=("flow_true", "flow_test"))
    use = np.all(np.isfinite(a), axis=-1) & np.all(np.isfinite(b), axis=-1)
    if roi is not None:
        m = np.asarray(roi)
        if m.dtype != np.bool_:
            raise ParameterTypeError(f"roi must be a boolean array, got dtype {m.dtype}")
        use &= _broadcast_mask(m, use.shape)
    return a[use].astype(np.float64), b[use].astype(np.float64)


def flow_endpoint_error(
    flow_true: ArrayLike,
    flow_test: ArrayLike,
    *,
    roi: ArrayLike | None = None,
    mask: ArrayLike | None = None,
) -> float:
    """Mean end-point error ``|f_test - f_true|`` in px.

    Parameters
    ----------
    flow_true, flow_test : (..., H, W, 2) ndarray
        Flows in px, ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row).
    roi : array of bool, optional
        Pixels to score (broadcast to ``(..., H, W)``). ``mask=`` is its deprecated name.

    Returns
    -------
    float
        Mean EPE (px) over pixels where both flows are finite (unknown GT, e.g. NaN or the
        Middlebury "unknown" value converted to NaN, is excluded); NaN if none.

    Examples
    --------
    >>> f0 = np.zeros((1, 2, 2, 2)); f1 = f0.copy(); f1[..., 0] = 3.0; f1[..., 1] = 4.0
    >>> flow_endpoint_error(f0, f1)
    5.0
    """
    a, b = _flow_pair(flow_true, flow_test, _renamed(roi, mask, ("roi", "mask")))
    if a.shape[0] == 0:
        return math.nan
    return float(np.mean(np.hypot(*(b - a).T)))


def flow_angular_error(
    flow_true: ArrayLike,
    flow_test: ArrayLike,
    *,
    roi: ArrayLike | None = None,
    mask: ArrayLike | None = None,
) -> float:
    """Mean angular error (degrees), Middlebury definition (Baker et al., IJCV 2011).

    The angle between the space-time vectors ``(u, v, 1)`` of the two flows:
    ``arccos((1 + u u_t + v v_t) / (sqrt(1 + u^2 + v^2) sqrt(1 + u_t^2 + v_t^2)))``.

    Parameters
    ----------
    flow_true, flow_test : (..., H, W, 2) ndarray
        Flows in px.
    roi : array of bool, optional
        Pixels to score. ``mask=`` is its deprecated name.

    Returns
    -------
    float
        Mean AAE in degrees; NaN if no pixel.

    Examples
    --------
    >>> f0 = np.zeros((1, 1, 1, 2)); f1 = np.ones((1, 1, 1, 2))
    >>> round(flow_angular_error(f0, f1), 4)
    54.7356
    """
    a, b = _flow_pair(flow_true, flow_test, _renamed(roi, mask, ("roi", "mask")))
    if a.shape[0] == 0:
        return math.nan
    num = 1.0 + np.sum(a * b, axis=1)
    den = np.sqrt(1.0 + np.sum(a * a, axis=1)) * np.sqrt(1.0 + np.sum(b * b, axis=1))
    return float(np.degrees(np.mean(np.arccos(np.clip(num / den, -1.0, 1.0)))))
