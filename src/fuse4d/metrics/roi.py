"""Regions of interest for the metrics: default (any data), the synthetic scenes' ROIs."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._kernels.roi import _default_roi_kernel
from ..camera import Intrinsics
from ..errors import ParameterError, ShapeError
from ..sequence import BallTruth, GroundTruth, PlaneTruth, Sequence, SheetTruth, sanitize_depth

__all__ = [
    "ball_roi",
    "ball_truth",
    "box_mask",
    "central_roi",
    "default_roi",
    "parse_box",
    "scene_roi",
    "static_mask_from_ground_truth",
    "static_pixels",
    "step_limit",
]


def parse_box(text: str) -> tuple[int, int, int, int]:
    """Parse a pixel box ``"R0:R1,C0:C1"`` (rows R0..R1-1, columns C0..C1-1) into
    ``(r0, r1, c0, c1)``: the ``--roi`` of ``fuse4d report`` and ``fuse4d metrics``."""
    try:
        rows, cols = text.split(",")
        r0, r1 = (int(x) for x in rows.split(":"))
        c0, c1 = (int(x) for x in cols.split(":"))
    except ValueError:
        raise ParameterError(
            f"roi must look like R0:R1,C0:C1 (pixel rows, then columns), got {text!r}"
        ) from None
    return r0, r1, c0, c1


def box_mask(box: tuple[int, int, int, int], shape: tuple[int, int]) -> NDArray[np.bool_]:
    """The ``(H, W)`` mask of the pixel box ``(r0, r1, c0, c1)`` (:func:`parse_box`);
    ParameterError where it is not a non-empty region of the image."""
    r0, r1, c0, c1 = (int(v) for v in box)
    h, w = shape
    if not (0 <= r0 < r1 <= h and 0 <= c0 < c1 <= w):
        raise ParameterError(
            f"roi rows {r0}:{r1}, columns {c0}:{c1} is not a non-empty region of the {h}x{w} image"
        )
    mask = np.zeros(shape, dtype=bool)
    mask[r0:r1, c0:c1] = True
    return mask


def _window_size(ndim: int, window: int) -> tuple[int, ...]:
    return (1,) * (ndim - 2) + (window, window)


def _window_inside(mask: NDArray[np.bool_], window: int) -> NDArray[np.bool_]:
    """True where the whole ``window x window`` neighbourhood is True (outside = False)."""
    # imported here: scipy costs ~0.2 s of start-up, and `fuse4d run` / `live` use only the
    # default ROI (a numba kernel); this serves the synthetic scenes' ground-truth ROIs
    from scipy import ndimage

    window = _check_odd_window(window)
    return ndimage.minimum_filter(
        mask, size=_window_size(mask.ndim, window), mode="constant", cval=False
    )


#: Noise levels of the frame's depth-noise model sigma(z) = q z^2 (A22) that a step between
#: neighbouring pixels may span before it counts as a depth edge: the fusion's own rule
#: ``max(max_depth_step, 2.5 q z^2)`` (``fuse4d._kernels.fusion._step_limit``; a test pins the
#: two together).
STEP_NOISE_LEVELS = 2.5
#: Tolerance of :func:`static_pixels`: depth range over time, in quantisation step limits
#: (``STEP_NOISE_LEVELS * q z^2``).
STATIC_LEVELS = 3.0
#: A static pixel's depth range over time may reach this many noise sigmas σ₀: the range of
#: T Gaussian samples is about 4 σ at T = 30 and 6.5 σ at T = 1000.
STATIC_NOISE_RANGE = 8.0
#: ... and its least-squares trend over the clip at most this many of the trend's standard
#: deviations under that noise.
STATIC_TREND_SIGMAS = 4.0


def step_limit(z: ArrayLike, *, max_step: float = 10.0, noise_quad: float = 0.0) -> NDArray:
    """Largest depth change (mm) between neighbouring pixels that is not a depth edge.

    ``max(max_step, 2.5 * noise_quad * z^2)``: the fusion's depth-step rule (A22), so that the
    quantisation steps of far structured-light depth (about 30 mm at 3 m on a Kinect) are not
    mistaken for edges.

    Parameters
    ----------
    z : array_like
        Depth in mm.
    max_step : float, optional
        Fixed floor (mm).
    noise_quad : float, optional
        Quadratic depth-noise coefficient q (mm^-1, :func:`fuse4d.motion.estimate_noise_quad`).

    Returns
    -------
    ndarray of float64
        Step limit in mm, shape of ``z``.
    """
    zz = np.asarray(z, dtype=np.float64)
    return np.maximum(float(max_step), STEP_NOISE_LEVELS * float(noise_quad) * zz * zz)


def _frame_quads(d: NDArray[np.float32], noise_quad: float | ArrayLike | None) -> NDArray:
    """Per-frame q: estimated from each frame (None) or given (scalar or (T,))."""
    if noise_quad is None:
        from ..motion import estimate_noise_quad

        frames = d.reshape(-1, *d.shape[-2:])
        return np.array([estimate_noise_quad(f) for f in frames]).reshape(d.shape[:-2])
    return np.broadcast_to(np.asarray(noise_quad, dtype=np.float64), d.shape[:-2])


def _check_odd_window(window: int, minimum: int = 1) -> int:
    """``window`` (px) as an ``int`` where it is an odd whole number >= ``minimum`` (``5.0``
    and numpy integers included: the kernels need an integer radius); else a ParameterError.
    The one window check of the metrics (roughness needs ``minimum=3``)."""
    try:
        whole = not isinstance(window, bool) and int(window) == window
    except (TypeError, ValueError, OverflowError):  # a word, None, NaN, inf
        whole = False
    if not whole or window < minimum or window % 2 == 0:
        what = "an odd positive integer" if minimum <= 1 else f"an odd integer >= {minimum}"
        raise ParameterError(f"window must be {what} (pixels), got {window!r}")
    return int(window)


def default_roi(
    depth: ArrayLike,
    *,
    window: int = 5,
    max_step: float = 10.0,
    noise_quad: float | ArrayLike | None = None,
) -> NDArray[np.bool_]:
    """The default roughness ROI, usable on any sequence (real or synthetic).

    A pixel is in the ROI if its whole ``window x window`` neighbourhood lies inside the image
    and holds valid depth, and no two horizontally or vertically neighbouring pixels inside it
    differ by more than the depth-step limit ``max(max_step, 2.5 q z^2)`` (:func:`step_limit`,
    the fusion's rule): the window does not straddle a depth discontinuity. Following the
    noise model, the ROI of quantised depth covers whole slanted surfaces, not only the flat
    plateaus between quantisation steps (where raw depth is flat by construction).

    Parameters
    ----------
    depth : (H, W) or (T, H, W) ndarray
        Depth in mm; NaN, 0, negative and inf = invalid.
    window : int, optional
        Window size n (odd, px), the roughness window.
    max_step : float, optional
        Floor of the step limit (mm).
    noise_quad : float or (T,) array, optional
        Depth-noise coefficient q of each frame (mm^-1). Default: estimated per frame with
        :func:`fuse4d.motion.estimate_noise_quad`; 0 gives the fixed ``max_step``.

    Returns
    -------
    ndarray of bool, shape of ``depth``

    Examples
    --------
    >>> d = np.full((8, 8), 500.0); d[:, 5:] = 900.0
    >>> default_roi(d, window=3, noise_quad=0.0)[4].tolist()
    [False, True, True, True, False, False, True, False]
    """
    d = sanitize_depth(depth)  # a 16-bit file's hole is 0, not a surface at 0 mm
    if d.ndim not in (2, 3):
        raise ShapeError("depth", ("T", "H", "W"), d.shape, "a (H, W) or (T, H, W) depth map")
    if not (math.isfinite(max_step) and max_step >= 0):
        raise ParameterError(f"max_step must be a finite number >= 0 (mm), got {max_step!r}")
    window = _check_odd_window(window)
    quads = np.asarray(_frame_quads(d, noise_quad), np.float64).reshape(-1)
    frames = d.reshape(-1, *d.shape[-2:])
    out = np.empty(frames.shape, np.bool_)
    counts = np.empty((2, *frames.shape[1:]), np.int32)
    for k, frame in enumerate(frames):
        _default_roi_kernel(frame, float(quads[k]), float(max_step), window // 2, counts, out[k])
    return out.reshape(d.shape)


def _ground_truth(seq_or_gt: Sequence | GroundTruth) -> GroundTruth:
    gt = seq_or_gt.ground_truth if isinstance(seq_or_gt, Sequence) else seq_or_gt
    if not isinstance(gt, GroundTruth):
        raise ParameterError(
            "this ROI needs ground truth (a synthetic scene from fuse4d.synthetic)"
        )
    return gt


def ball_truth(seq_or_gt: Sequence | GroundTruth, *, what: str = "this metric") -> BallTruth:
    """The typed falling-ball geometry of a scene (``ground_truth.scene``).

    Raises
    ------
    ValueError
        If the scene is not :func:`~fuse4d.synthetic.make_falling_ball` output.
    """
    gt = _ground_truth(seq_or_gt)
    if not isinstance(gt.scene, BallTruth) or gt.mask is None:
        raise ParameterError(
            f"{what} needs the falling-ball ground truth (mask and a BallTruth scene, "
            "from fuse4d.synthetic.make_falling_ball)"
        )
    return gt.scene


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
        A :func:`~fuse4d.synthetic.make_falling_ball` scene (uses ``mask`` and the
        :class:`~fuse4d.sequence.BallTruth` ``center_row``, ``center_col``, ``roi_radius_px``).
    window : int, optional
        Roughness window size n (px).
    radius_px : float, optional
        ROI radius in px. Default ``scene.roi_radius_px``: 100 px at full size, scaled by
        ``pixel_scale`` for the small variant (25 px).

    Returns
    -------
    (T, H, W) ndarray of bool
    """
    ball = ball_truth(seq_or_gt, what="ball_roi")
    mask = np.asarray(_ground_truth(seq_or_gt).mask, dtype=bool)
    rows = np.asarray(ball.center_row, dtype=np.float64).reshape(-1)
    if rows.size != mask.shape[0]:
        raise ShapeError("scene.center_row", (mask.shape[0],), rows.shape, "one row per frame")
    col = ball.center_col
    radius = float(radius_px if radius_px is not None else ball.roi_radius_px)
    h, w = mask.shape[1:]
    vv = np.arange(h, dtype=np.float64)[None, :, None]
    uu = np.arange(w, dtype=np.float64)[None, None, :]
    near = (uu - col) ** 2 + (vv - rows[:, None, None]) ** 2 <= radius**2
    return near & _window_inside(mask, window)


def central_roi(
    seq_or_gt: Sequence | GroundTruth,
    *,
    intrinsics: Intrinsics | None = None,
    fraction: float = 0.8,
    window: int = 5,
) -> NDArray[np.bool_]:
    """ROI of the synthetic plane and sheet (EVALUATION §4 E5): their central part.

    Pixels whose surface point lies in the central ``fraction`` of the object along each side
    (in the object's own, material coordinates: 0.8 -> 96 x 64 mm of the 120 x 80 mm plane,
    96 x 96 mm of the sheet) and whose ``window x window`` neighbourhood is inside the GT mask.

    Parameters
    ----------
    seq_or_gt : Sequence or GroundTruth
        A :func:`~fuse4d.synthetic.make_static_plane` or
        :func:`~fuse4d.synthetic.make_deforming_sheet` scene (its ground truth).
    intrinsics : Intrinsics, optional
        Camera; required when ``seq_or_gt`` is a bare GroundTruth.
    fraction : float, optional
        Linear fraction of each side, in (0, 1].
    window : int, optional
        Roughness window size n (px).

    Returns
    -------
    (T, H, W) ndarray of bool
    """
    if not 0.0 < fraction <= 1.0:
        raise ParameterError(f"fraction must be in (0, 1], got {fraction!r}")
    gt = _ground_truth(seq_or_gt)
    k = seq_or_gt.intrinsics if isinstance(seq_or_gt, Sequence) else intrinsics
    if k is None:
        raise ParameterError("central_roi needs the intrinsics with a bare GroundTruth")
    if gt.depth is None or gt.mask is None:
        raise ParameterError("central_roi needs ground-truth depth and mask")
    truth = gt.scene
    z = np.asarray(gt.depth, dtype=np.float64)
    xn = (np.arange(k.width) - k.cx) / k.fx
    yn = (np.arange(k.height) - k.cy) / k.fy
    x = z * xn[None, None, :]
    y = z * yn[None, :, None]
    if isinstance(truth, PlaneTruth):
        theta = math.radians(truth.tilt_deg)
        z0 = float(np.asarray(truth.center_mm)[2])
        a, b = x, y * math.cos(theta) + (z - z0) * math.sin(theta)
    elif isinstance(truth, SheetTruth):
        cx_mm = np.asarray(truth.center_x_mm, dtype=np.float64).reshape(-1)
        a, b = x - cx_mm[:, None, None], y
    else:
        name = "no scene" if truth is None else truth.scene
        raise ParameterError(f"central_roi applies to the 'plane' and 'sheet' scenes, not {name!r}")
    size = truth.size_mm
    with np.errstate(invalid="ignore"):
        inside = (np.abs(a) <= fraction * size[0] / 2) & (np.abs(b) <= fraction * size[1] / 2)
    return inside & _window_inside(np.asarray(gt.mask, dtype=bool), window)


def scene_roi(
    seq_or_gt: Sequence | GroundTruth, *, intrinsics: Intrinsics | None = None, window: int = 5
) -> tuple[NDArray[np.bool_], str]:
    """The EVALUATION ROI of a synthetic scene and a one-line description.

    ``ball`` -> :func:`ball_roi`; ``plane``/``sheet`` -> :func:`central_roi` (80 %).

    Raises
    ------
    ValueError
        If ``seq_or_gt`` is not a synthetic scene (no ground truth or no typed ``scene``).
    """
    gt = _ground_truth(seq_or_gt)
    if isinstance(gt.scene, BallTruth):
        return (
            ball_roi(gt, window=window),
            (
                f"ball ROI: within {gt.scene.roi_radius_px:g} px of the ball centre, "
                f"{window}x{window} window inside the GT mask"
            ),
        )
    if gt.scene is None:
        raise ParameterError("scene_roi needs a synthetic scene (ground_truth.scene is None)")
    return (
        central_roi(seq_or_gt, intrinsics=intrinsics, window=window),
        f"central 80 % of the {gt.scene.scene}, {window}x{window} window inside the GT mask",
    )


def static_mask_from_ground_truth(gt: GroundTruth) -> NDArray[np.bool_]:
    """``(H, W)`` pixels that see a static surface in every frame (for temporal flicker).

    True where the GT depth is finite and identical in all frames and the GT flow is zero.
    """
    if gt.depth is None:
        raise ParameterError("static_mask_from_ground_truth needs ground-truth depth")
    d = np.asarray(gt.depth)
    static = np.all(np.isfinite(d), axis=0) & np.all(d == d[:1], axis=0)
    if gt.flow is not None and np.asarray(gt.flow).shape[0] > 0:
        static &= np.all(np.asarray(gt.flow) == 0, axis=(0, 3))
    return static


def static_pixels(
    depth: ArrayLike,
    *,
    noise_quad: float | None = None,
    noise_sigma: float | None = None,
    levels: float = STATIC_LEVELS,
) -> NDArray[np.bool_]:
    """``(H, W)`` pixels that see a static surface, detected from the depth video itself.

    A pixel is static if it is valid in every frame and the range (max - min) of its depth
    over time is within what the sensor's noise explains (:func:`is_static`): ``levels``
    quantisation step limits at its mean depth (``levels * 2.5 q z^2``, structured-light
    steps) or :data:`STATIC_NOISE_RANGE` times the depth noise σ₀, whichever is larger, and
    its least-squares trend over the clip is within :data:`STATIC_TREND_SIGMAS` standard
    deviations of a line fitted to that noise (``docs/method_notes.md``, "Evaluation: static
    pixels"). People or objects crossing the pixel change its depth by far more (on
    ``uva_cv2_person_turning``: 99.9 % of the never-masked background, none of the person);
    so does a surface moving towards the camera by more than the noise (the synthetic ball's
    0.9 mm a frame: a fixed 30 mm tolerance called its pixels static, and a lagging filter
    then scored as steady there).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm; NaN, 0, negative and inf = invalid (the raw input: static is a property
        of the scene).
    noise_quad : float, optional
        Depth-noise coefficient q (mm^-1); default: the median over frames of
        :func:`fuse4d.motion.estimate_noise_quad`.
    noise_sigma : float, optional
        Depth noise σ₀ (mm); default: the median of :func:`fuse4d.motion.estimate_depth_noise`
        over up to 8 evenly spaced frames.
    levels : float, optional
        Tolerance in quantisation step limits.

    Returns
    -------
    (H, W) ndarray of bool
    """
    d = sanitize_depth(depth)  # a 16-bit file's hole is 0, not a static surface at 0 mm
    if d.ndim != 3:
        raise ShapeError("depth", ("T", "H", "W"), d.shape, "a (T, H, W) depth video")
    q = float(np.median(_frame_quads(d, None))) if noise_quad is None else float(noise_quad)
    sigma = _median_noise_sigma(d) if noise_sigma is None else float(noise_sigma)
    valid = np.all(np.isfinite(d), axis=0)
    out = np.zeros(d.shape[1:], dtype=bool)
    if valid.any():
        vals = d[:, valid].astype(np.float64)
        n = vals.shape[0]
        trend = depth_trend(vals.sum(axis=0), np.arange(n, dtype=np.float64) @ vals, n)
        out[valid] = is_static(
            vals.min(axis=0), vals.max(axis=0), vals.mean(axis=0), q, noise_sigma=sigma,
            levels=levels, trend=trend, frames=n,
        )  # fmt: skip
    return out


def depth_trend(zsum: ArrayLike, ztsum: ArrayLike, frames: int) -> NDArray[np.float64]:
    """Least-squares change (mm) of each pixel's depth over a clip: the slope of the line
    through its depths at frames t = 0 .. T-1, times T - 1, from ``zsum`` = Σ z and ``ztsum``
    = Σ t z (running sums; 0 for T = 1)."""
    n = int(frames)
    if n < 2:
        return np.zeros(np.shape(zsum))
    sxx = n * (n * n - 1) / 12.0
    slope = (np.asarray(ztsum, np.float64) - 0.5 * (n - 1) * np.asarray(zsum, np.float64)) / sxx
    return slope * (n - 1)


def noise_sigma_frames(total: int, frames: int = 8) -> list[int]:
    """The frames (of ``total``) whose depth noise σ₀ is estimated for the static rule: up
    to ``frames`` evenly spaced ones. One choice for :func:`static_pixels` (``fuse4d
    metrics``), the run summary and the report, so that the three find the same pixels."""
    picks = np.linspace(0, total - 1, min(frames, total)).round().astype(int)
    return [int(k) for k in np.unique(picks)]


def _median_noise_sigma(d: NDArray[np.float32], frames: int = 8) -> float:
    """Median depth noise σ₀ (mm) of up to ``frames`` evenly spaced frames of ``d``."""
    from ..motion import estimate_depth_noise

    picks = noise_sigma_frames(d.shape[0], frames)
    return float(np.median([estimate_depth_noise(d[k]) for k in picks]))


def is_static(
    zmin: ArrayLike,
    zmax: ArrayLike,
    zmean: ArrayLike,
    noise_quad: float,
    *,
    noise_sigma: float = 0.0,
    levels: float = STATIC_LEVELS,
    trend: ArrayLike | None = None,
    frames: int = 0,
) -> NDArray[np.bool_]:
    """The static rule of :func:`static_pixels` on per-pixel temporal min, max and mean (mm).

    ``max - min <= max(levels * 2.5 q mean^2, STATIC_NOISE_RANGE * noise_sigma)``, and where
    ``trend`` (:func:`depth_trend` over ``frames`` frames) is given, no trend beyond
    :data:`STATIC_TREND_SIGMAS` standard deviations of a line fitted to noise of σ(z) =
    max(noise_sigma, q mean^2) (A22): a surface creeping by less than the noise each frame
    (the ball's centre: 0.15 mm a frame under 0.2 mm noise) moves, and a faithful output
    follows it. Split out so that a streaming evaluation (running sums) applies the same rule.
    """
    z = np.asarray(zmean, dtype=np.float64)
    quant = float(noise_quad) * z * z
    limit = np.maximum(levels * STEP_NOISE_LEVELS * quant, STATIC_NOISE_RANGE * float(noise_sigma))
    static = np.asarray(zmax, dtype=np.float64) - np.asarray(zmin, dtype=np.float64) <= limit
    if trend is not None and frames >= 2:
        sigma = np.maximum(quant, float(noise_sigma))
        n = int(frames)
        trend_sd = sigma * (n - 1) / np.sqrt(n * (n * n - 1) / 12.0)
        static &= np.abs(np.asarray(trend, dtype=np.float64)) <= STATIC_TREND_SIGMAS * trend_sd
    return static
