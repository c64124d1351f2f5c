"""Roughness of a 3D point map (paper Eq. 7; EVALUATION §1)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._kernels.roughness import _roughness_kernel, _roughness_masked_kernel
from .._validation import as_float32, check_shape
from ..errors import ParameterError, ParameterTypeError, ShapeError
from .roi import _check_odd_window, default_roi

__all__ = [
    "RoughnessStats",
    "roughness",
    "roughness_maps",
    "roughness_rms",
    "roughness_stats",
    "stats_from_maps",
]


def _check_window(window: int, min_valid_fraction: float) -> int:
    """``window`` as an int (odd, >= 3 px), after checking it and ``min_valid_fraction``."""
    window = _check_odd_window(window, 3)
    if not 0.0 < float(min_valid_fraction) <= 1.0:
        raise ParameterError(f"min_valid_fraction must be in (0, 1], got {min_valid_fraction!r}")
    return window


#: What the roughness takes, said wherever a depth map was passed instead.
_POINTS_HINT = (
    "pass a (H, W, 3) or (T, H, W, 3) map of 3D points in mm (from depth: "
    "fuse4d.depth_to_points(depth, intrinsics), or Sequence.points())"
)


def _as_points(points: ArrayLike) -> tuple[NDArray[np.float32], bool]:
    p = as_float32(points, name="points")
    if p.ndim == 3 and p.shape[-1] == 3:
        return p[None], True
    check_shape(p, ("T", "H", "W", 3), name="points", hint=_POINTS_HINT)
    return p, False


def roughness_maps(
    points: ArrayLike, *, window: int = 5, min_valid_fraction: float = 0.8
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Per-pixel roughness Pi (Eq. 7) and RMS plane residual R, computed together.

    Parameters
    ----------
    points : (H, W, 3) or (T, H, W, 3) ndarray
        Point maps in mm (e.g. ``Sequence.points()``), NaN = invalid.
    window : int, optional
        Window size n (odd, pixels); the paper's value is n = 5 (EVALUATION §1).
    min_valid_fraction : float, optional
        A pixel is evaluated only if its centre point is valid and at least this fraction of
        the n x n window (pixels outside the image count as invalid) is valid.

    Returns
    -------
    pi, rms : (..., H, W) ndarray of float32
        ``Pi_i = |sum_j (p_i - p_j) . n_i| = N_i |(p_i - c_i) . n_i|`` (mm) and
        ``R_i = sqrt(mean_j ((p_j - c_i) . n_i)^2)`` (mm), with ``c_i`` the centroid and ``n_i``
        the total-least-squares normal of the valid window points; NaN where undefined.
    """
    window = _check_window(window, min_valid_fraction)
    p, single = _as_points(points)
    t, h, w = p.shape[:3]
    out_sum = np.empty((t, h, w), dtype=np.float32)
    out_rms = np.empty((t, h, w), dtype=np.float32)
    min_count = max(1, math.ceil(min_valid_fraction * window * window - 1e-9))
    _roughness_kernel(_planes(p), window // 2, min_count, out_sum, out_rms)
    if single:
        return out_sum[0], out_rms[0]
    return out_sum, out_rms


def _planes(points: NDArray[np.float32]) -> NDArray[np.float32]:
    """(T, H, W, 3) points as (T, 3, H, W) contiguous x, y, z planes (the kernels' layout)."""
    return np.ascontiguousarray(np.moveaxis(points, -1, 1), dtype=np.float32)


def _roughness_maps_on(
    points: NDArray[np.float32], mask: NDArray[np.bool_], *, window: int = 5
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """:func:`roughness_maps` of ``(T, H, W, 3)`` float32 points on the ``mask`` pixels only.

    Where ``mask`` is set the values equal :func:`roughness_maps`' bit for bit; elsewhere NaN.
    For scores restricted to a region anyway (:class:`~fuse4d.metrics.RunningEvaluation`).
    """
    p = np.ascontiguousarray(points, dtype=np.float32)
    t, h, w = p.shape[:3]
    m = np.ascontiguousarray(np.broadcast_to(mask, (t, h, w)), dtype=np.bool_)
    out_sum = np.empty((t, h, w), dtype=np.float32)
    out_rms = np.empty((t, h, w), dtype=np.float32)
    min_count = max(1, math.ceil(0.8 * window * window - 1e-9))
    _roughness_masked_kernel(_planes(p), m, window // 2, min_count, out_sum, out_rms)
    return out_sum, out_rms


def roughness(
    points: ArrayLike, *, window: int = 5, min_valid_fraction: float = 0.8
) -> NDArray[np.float32]:
    """Per-pixel roughness Pi of paper Eq. 7 (mm), as specified in EVALUATION §1.

    ``Pi_i = |sum_{j in W_i} (p_i - p_j) . n_i|`` over the valid points of the n x n window
    ``W_i`` (centre included), with ``n_i`` the unit normal of the total-least-squares plane of
    the window (smallest eigenvector of the scatter matrix). Because that plane passes through
    the centroid ``c_i``, ``Pi_i = N_i |(p_i - c_i) . n_i|``: a *sum*, so it scales with n^2
    (E|Pi| ~ n^2 0.8 sigma_d cos(theta) for depth noise sigma_d).

    Parameters
    ----------
    points : (H, W, 3) or (T, H, W, 3) ndarray
        Point maps in mm, NaN = invalid.
    window : int, optional
        Window size n (odd); default 5, the size that reproduces the paper's 3.75 mm.
    min_valid_fraction : float, optional
        Minimum valid fraction of the window (the centre must be valid too); default 0.8.

    Returns
    -------
    (..., H, W) ndarray of float32
        Pi in mm; NaN where the window is not valid enough.

    Examples
    --------
    >>> from fuse4d import Intrinsics, depth_to_points
    >>> K = Intrinsics(fx=100.0, fy=100.0, cx=4.5, cy=4.5, width=10, height=10)
    >>> plane = np.fromfunction(lambda v, u: 500.0 / (1.0 - 0.2 * (u - 4.5) / 100.0), (10, 10))
    >>> pi = roughness(depth_to_points(plane, K))
    >>> bool(np.nanmax(pi) < 1e-3)
    True
    """
    return roughness_maps(points, window=window, min_valid_fraction=min_valid_fraction)[0]


def roughness_rms(
    points: ArrayLike, *, window: int = 5, min_valid_fraction: float = 0.8
) -> NDArray[np.float32]:
    """Per-pixel RMS plane-fit residual of the n x n window (mm), EVALUATION §1 secondary.

    ``R_i = sqrt((1 / N_i) sum_j ((p_j - c_i) . n_i)^2)``; comparable across window sizes
    (about 0.17 mm on the raw synthetic ball at sigma_d = 0.2 mm). Same arguments as
    :func:`roughness`.
    """
    return roughness_maps(points, window=window, min_valid_fraction=min_valid_fraction)[1]


@dataclass(frozen=True)
class RoughnessStats:
    """Roughness summary of a sequence (EVALUATION §1).

    Attributes
    ----------
    frame_means : (T,) ndarray of float64
        F_t: mean of Pi over the ROI pixels of frame t where Pi is defined (mm; NaN if none).
    frame_rms_means : (T,) ndarray of float64
        The same for the RMS residual R (mm).
    num_pixels : (T,) ndarray of int64
        Number of ROI pixels with Pi defined, per frame.
    mean, std : float
        Mean and std (ddof = 0) of F_t over frames (mm): the paper's "mean roughness" and
        "std of roughness" (temporal fluctuation, not the spread over points).
    rms_mean, rms_std : float
        The same for R.
    """

    frame_means: NDArray[np.float64]
    frame_rms_means: NDArray[np.float64]
    num_pixels: NDArray[np.int64]
    mean: float
    std: float
    rms_mean: float
    rms_std: float

    def interior(self, margin: int) -> tuple[float, float]:
        """``(mean, std)`` over the interior frames ``margin ... T-1-margin`` (mm)."""
        if margin < 0 or 2 * margin >= self.frame_means.size:
            raise ParameterError(
                f"margin must be in [0, {(self.frame_means.size - 1) // 2}] for "
                f"{self.frame_means.size} frames, got {margin}"
            )
        sel = self.frame_means[margin : self.frame_means.size - margin]
        return _mean_std(sel)

    def to_dict(self) -> dict[str, float]:
        """The scalar fields (JSON friendly)."""
        return {
            "roughness_mean": self.mean,
            "roughness_std": self.std,
            "rms_residual": self.rms_mean,
            "rms_residual_std": self.rms_std,
        }


def _mean_std(values: NDArray[np.float64]) -> tuple[float, float]:
    good = values[np.isfinite(values)]
    if good.size == 0:
        return math.nan, math.nan
    # the spread over frames of one frame is undefined (it printed as 0)
    return float(good.mean()), float(good.std(ddof=0)) if good.size > 1 else math.nan


def roughness_stats(
    points: ArrayLike,
    *,
    roi: ArrayLike | None = None,
    window: int = 5,
    min_valid_fraction: float = 0.8,
    max_step: float = 10.0,
) -> RoughnessStats:
    """Per-frame and per-sequence roughness (Eq. 7) and RMS residual over a region of interest.

    Parameters
    ----------
    points : (T, H, W, 3) or (H, W, 3) ndarray
        Point maps in mm, NaN = invalid.
    roi : (T, H, W) or (H, W) array of bool, optional
        Pixels to average over (a 2-D mask applies to every frame). Default:
        :func:`default_roi` of the depth (window fully valid, no step between neighbours
        above the depth-step limit ``max(max_step, 2.5 q z^2)``).
    window : int, optional
        Window size n (default 5).
    min_valid_fraction : float, optional
        See :func:`roughness`.
    max_step : float, optional
        Floor of the default ROI's depth-step limit (mm).

    Returns
    -------
    RoughnessStats
        Frames whose ROI holds no defined Pi get NaN and are left out of mean and std.

    Examples
    --------
    >>> from fuse4d.synthetic import make_falling_ball
    >>> seq = make_falling_ball(small=True, num_frames=2, depth_noise=0.0)
    >>> stats = roughness_stats(seq.points())
    >>> stats.frame_means.shape
    (2,)
    """
    p, _ = _as_points(points)
    pi, rms = roughness_maps(p, window=window, min_valid_fraction=min_valid_fraction)
    if roi is None:
        return stats_from_maps(pi, rms, default_roi(p[..., 2], window=window, max_step=max_step))
    return stats_from_maps(pi, rms, roi)


def stats_from_maps(
    pi: NDArray[np.float32], rms: NDArray[np.float32], roi: ArrayLike
) -> RoughnessStats:
    """:class:`RoughnessStats` of precomputed ``(T, H, W)`` Pi and R maps (mm) over ``roi``.

    ``roi`` is ``(H, W)`` (every frame) or ``(T, H, W)`` bool; pixels where Pi is NaN are
    left out.
    """
    mask = np.asarray(roi)
    if mask.dtype != np.bool_:
        raise ParameterTypeError(f"roi must be a boolean mask, got dtype {mask.dtype}")
    if mask.ndim == 2 and mask.shape == pi.shape[1:]:
        mask = np.broadcast_to(mask, pi.shape)
    if mask.shape != pi.shape:
        raise ShapeError("roi", pi.shape, mask.shape, "a (H, W) or (T, H, W) bool mask")
    used = mask & np.isfinite(pi)
    counts = used.sum(axis=(1, 2)).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        sums = np.where(used, pi, 0.0).sum(axis=(1, 2), dtype=np.float64)
        rsums = np.where(used, rms, 0.0).sum(axis=(1, 2), dtype=np.float64)
        frame_means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
        frame_rms = np.where(counts > 0, rsums / np.maximum(counts, 1), np.nan)
    mean, std = _mean_std(frame_means)
    rms_mean, rms_std = _mean_std(frame_rms)
    return RoughnessStats(frame_means, frame_rms, counts, mean, std, rms_mean, rms_std)
