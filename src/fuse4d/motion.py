"""Tracks and 3D motion fields from 2D flow (paper Eq. 2–4, METHOD.md §3–§4).

Everything here works on the pixel grid: a pixel x_i of frame t is followed through the
consecutive flows with sub-pixel accumulation (bilinear flow sampling), validated per step by
the forward–backward check (Eq. 4, in px), valid depth and a depth-jump gate, and looked up at
the rounded position ``floor(X + 0.5)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels.fusion import (
    _pair_diagnostics_kernel,
    _segment_box_rows_kernel,
    _track_kernel,
)
from ._validation import as_float32, check_shape
from .camera import Intrinsics, depth_to_points
from .config import FusionParams

__all__ = [
    "Tracks",
    "compute_motion_field",
    "estimate_depth_noise",
    "estimate_noise_quad",
    "motion_reference_depth",
    "track_frame",
]


def motion_reference_depth(
    depth: ArrayLike, *, sigma: float = 12.0, max_step: float = 10.0, noise_quad: float = 0.0
) -> NDArray[np.float32]:
    """Edge-limited smoothing of one depth frame: the motion-reference depth D~ (A3).

    METHOD §4.3 asks for a normalised Gaussian (sigma_m) over valid pixels that never mixes
    depths more than ``max_step`` apart. We compute it as two box-filter passes along rows and
    two along columns (a separable triangle kernel with the same variance as the Gaussian),
    each a local-linear fit over its window (so truncated windows at borders and edges carry no
    slope bias),
    each pass confined to *depth-continuous segments*: runs of valid pixels whose consecutive
    depths differ by less than ``max_step`` mm. Windows are truncated at segment ends and
    renormalised. Compared with METHOD's centre-relative range gate this is identical on smooth
    surfaces, likewise never crosses a depth discontinuity or a hole, and costs O(1) per pixel
    (prefix sums) instead of O(sigma), which matters at sigma_m = 12 px (our deviation; see the
    ``FusionParams.motion_sigma`` docs).

    Parameters
    ----------
    depth : (H, W) ndarray
        Depth in mm, NaN = invalid.
    sigma : float
        sigma_m in px (box radius r with (2r+1)^2 = 6 sigma^2 + 1, at least 1).
    max_step : float
        tau_jump in mm: a larger step between neighbouring pixels ends a segment.
    noise_quad : float
        Quadratic depth-noise coefficient (mm^-1, see :func:`estimate_noise_model`): at depth z
        the step limit is ``max(max_step, 2.5 * noise_quad * z^2)``, so quantisation steps of far
        structured-light depth do not cut segments.

    Returns
    -------
    (H, W) ndarray of float32
        Smoothed depth in mm, NaN where ``depth`` is NaN.

    Examples
    --------
    >>> d = np.full((5, 5), 500.0, np.float32); d[2, 2] = np.nan; d[:, 4] = 900.0
    >>> r = motion_reference_depth(d, sigma=1.0)
    >>> float(r[0, 0]), float(r[0, 4]), bool(np.isnan(r[2, 2]))
    (500.0, 900.0, True)
    """
    d = as_float32(depth, name="depth")
    check_shape(d, ("H", "W"), name="depth")
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0 px, got {sigma}")
    radius = max(1, round((np.sqrt(6.0 * sigma**2 + 1.0) - 1.0) / 2.0))
    step = float(max_step)
    a = d.copy()
    b = np.empty_like(d)
    for _ in range(2):
        _segment_box_rows_kernel(a, d, radius, step, float(noise_quad), b)
        a, b = b, a
    at = np.ascontiguousarray(a.T)
    dt = np.ascontiguousarray(d.T)
    bt = np.empty_like(at)
    for _ in range(2):
        _segment_box_rows_kernel(at, dt, radius, step, float(noise_quad), bt)
        at, bt = bt, at
    return np.ascontiguousarray(at.T)


def estimate_noise_quad(depth: ArrayLike) -> float:
    """Quadratic coefficient of a frame's depth-noise model sigma(z) = quad * z^2 (A22), mm^-1.

    Structured-light and stereo depth is noisier, and quantised more coarsely, further away
    (step ~ z^2). ``quad`` is the median over pixels (every 2nd row) of |second difference
    along the row| / z^2, over non-zero values below 5 % of the depth (edges excluded), divided
    by 1.65: second differences cancel surface slope; for Gaussian noise their median
    magnitude is 1.65 sigma, on quantised depth it is one quantisation level. Returns 0.0 when
    no pixel qualifies.
    """
    d = as_float32(depth, name="depth")
    check_shape(d, ("H", "W"), name="depth")
    sub = d[::2].astype(np.float64)
    second = np.abs(sub[:, :-2] - 2.0 * sub[:, 1:-1] + sub[:, 2:]).ravel()
    z = sub[:, 1:-1].ravel()
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(second) & (second > 0) & (second < 0.05 * z)
    return float(np.median(second[ok] / z[ok] ** 2) / 1.65) if ok.any() else 0.0


def estimate_depth_noise(depth: ArrayLike, *, reference: ArrayLike | None = None) -> float:
    """Robust estimate of the per-pixel depth noise of one frame, in mm.

    The residual r between the depth and a small-scale edge-limited smoothing (sigma = 2 px,
    or ``reference`` when given), subsampled 2x2, summarised as ``1.2533 * mean(|r|)`` over
    the residuals below their 95th percentile (a trimmed mean absolute deviation, scaled to a
    Gaussian sigma; trimming ignores depth edges). Unlike the median absolute deviation it does
    not collapse to 0 on quantised depth (structured-light cameras, where most residuals are
    exactly 0). Returns 0.0 for a frame without valid depth.
    """
    d = as_float32(depth, name="depth")
    check_shape(d, ("H", "W"), name="depth")
    ref = motion_reference_depth(d, sigma=2.0) if reference is None else np.asarray(reference)
    r = np.abs(d[::2, ::2] - ref[::2, ::2]).ravel()
    r = r[np.isfinite(r)]
    if r.size == 0:
        return 0.0
    keep = r[r <= np.quantile(r, 0.95)]
    return float(1.2533 * keep.mean()) if keep.size else 0.0


@dataclass(frozen=True)
class Tracks:
    """Tracks of every pixel of frame ``t`` through its temporal window.

    Attributes
    ----------
    t : int
        Reference frame.
    frames : (K,) ndarray of int
        The other frames T of the window, increasing (t excluded).
    rows, cols : (K, H, W) ndarray of int32
        Rounded landing pixel x^_i^T (row, column) of the track from pixel i.
    valid : (K, H, W) ndarray of bool
        nu_i^{t,T}: AND of the per-step checks along the chain (METHOD §4.1).
    """

    t: int
    frames: NDArray[np.int64]
    rows: NDArray[np.int32]
    cols: NDArray[np.int32]
    valid: NDArray[np.bool_]


def _pair_ring(flow: NDArray[np.float32]) -> NDArray[np.float32]:
    """(T-1,H,W,2) pair flows -> (T,H,W,2) ring where slot T holds pair (T-1, T)."""
    return np.concatenate([np.zeros_like(flow[:1]), flow], axis=0)


def track_frame(
    flow_forward: ArrayLike,
    flow_backward: ArrayLike,
    depth: ArrayLike,
    t: int,
    *,
    params: FusionParams | None = None,
) -> Tracks:
    """Chain the flows from every pixel of frame ``t`` over its window (METHOD §4.1).

    Parameters
    ----------
    flow_forward : (T-1, H, W, 2) ndarray
        s^{t,t+1} in px on frame t's grid (``[..., 0]`` = du, column).
    flow_backward : (T-1, H, W, 2) ndarray
        s^{t+1,t} in px on frame t+1's grid.
    depth : (T, H, W) ndarray
        Raw depth in mm (NaN = invalid): validity and depth-jump gate.
    t : int
        Reference frame.
    params : FusionParams, optional
        Window (``num_frames``, ``causal``), ``fb_threshold``, ``max_depth_step``, ``quantize``.

    Returns
    -------
    Tracks

    Notes
    -----
    The depth-jump gate is ``max(max_depth_step, 2.5 quad z^2)`` with ``quad`` from
    :func:`estimate_noise_quad` on frame t, exactly as in the fusion engine (A22).
    """
    params = params or FusionParams()
    d = as_float32(depth, name="depth")
    check_shape(d, ("T", "H", "W"), name="depth")
    n, h, w = d.shape
    fwd = as_float32(flow_forward, name="flow_forward")
    bwd = as_float32(flow_backward, name="flow_backward")
    check_shape(fwd, (n - 1, h, w, 2), name="flow_forward")
    check_shape(bwd, (n - 1, h, w, 2), name="flow_backward")
    if not 0 <= t < n:
        raise ValueError(f"t must be in [0, {n - 1}], got {t}")
    first = max(0, t - params.past_frames)
    last = min(n - 1, t + params.future_frames)
    k = last - first
    rows = np.empty((k, h, w), np.int32)
    cols = np.empty((k, h, w), np.int32)
    valid = np.empty((k, h, w), np.bool_)
    _track_kernel(
        _pair_ring(fwd),
        _pair_ring(bwd),
        d,
        np.arange(first, last + 1, dtype=np.int64),
        t,
        first,
        last,
        params.fb_threshold,
        params.max_depth_step,
        estimate_noise_quad(d[t]),
        params.quantize == "per_step",
        rows,
        cols,
        valid,
    )
    frames = np.array([T for T in range(first, last + 1) if t != T], dtype=np.int64)
    return Tracks(t=t, frames=frames, rows=rows, cols=cols, valid=valid)


def compute_motion_field(
    flow_forward: ArrayLike,
    flow_backward: ArrayLike,
    depth: ArrayLike,
    intrinsics: Intrinsics,
    *,
    params: FusionParams | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Per-step 3D motion field m^{t,t+1} (Eq. 3) and the forward–backward error (Eq. 4).

    Parameters
    ----------
    flow_forward, flow_backward : (T-1, H, W, 2) ndarray
        Consecutive-pair flows in px.
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intrinsics : Intrinsics
    params : FusionParams, optional
        ``motion_depth`` ("smoothed": motion from D~, A3; "raw": literal), ``motion_sigma``,
        ``fb_threshold``, ``max_depth_step``, ``quantize``.

    Returns
    -------
    motion : (T-1, H, W, 3) ndarray of float32
        P~^{t+1}[x^] - P~^t[x] in mm (scene flow), NaN where the step is invalid.
    fb_error : (T-1, H, W) ndarray of float32
        |s^{t,t+1}(x) + s^{t+1,t}(x + s^{t,t+1}(x))| in px; NaN where the step leaves the image.
    """
    params = params or FusionParams()
    d = as_float32(depth, name="depth")
    check_shape(d, ("T", "H", "W"), name="depth")
    n, h, w = d.shape
    fwd = as_float32(flow_forward, name="flow_forward")
    bwd = as_float32(flow_backward, name="flow_backward")
    check_shape(fwd, (n - 1, h, w, 2), name="flow_forward")
    check_shape(bwd, (n - 1, h, w, 2), name="flow_backward")
    if params.motion_depth == "smoothed":
        ref_depth = np.stack(
            [
                motion_reference_depth(
                    f,
                    sigma=params.motion_sigma,
                    max_step=params.max_depth_step,
                    noise_quad=estimate_noise_quad(f),
                )
                for f in d
            ]
        )
    else:
        ref_depth = d
    ref = depth_to_points(ref_depth, intrinsics)
    motion = np.empty((max(n - 1, 0), h, w, 3), np.float32)
    fb = np.empty((max(n - 1, 0), h, w), np.float32)
    fwd_ring = _pair_ring(fwd)
    bwd_ring = _pair_ring(bwd)
    for t in range(n - 1):
        _pair_diagnostics_kernel(
            fwd_ring,
            bwd_ring,
            t + 1,
            ref[t],
            ref[t + 1],
            d[t],
            d[t + 1],
            params.fb_threshold,
            params.max_depth_step,
            params.quantize == "per_step",
            fb[t],
            motion[t],
        )
    return motion, fb
