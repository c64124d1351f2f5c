"""Ad-GF, Ad-BF, Ad-JBF and DNBF: four public faces of one joint-bilateral kernel.

All four call :func:`fuse4d._kernels.joint_bilateral._joint_bilateral_kernel` (BASELINES.md §1,
§2, §4, §6). The window is a disc of the given radius (as in OpenCV's bilateral filters; the
spec's square window for Ad-GF differs only in corners whose weight is < exp(-4.5)).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._kernels._common import MAX_GAUSS_FACTOR, gauss_factor
from .._kernels.baselines import _pca_view_angle_kernel, _region_grow_kernel
from .._kernels.joint_bilateral import _joint_bilateral_kernel
from .._params import check_bool, check_int, check_number
from ..camera import Intrinsics, depth_to_points
from ..errors import ParameterError
from ..fov import field_of_view
from ._common import (
    MAX_WINDOW_RADIUS,
    DepthNoiseModel,
    check_inputs,
    estimate_noise_model,
    frame_median_depth,
    iterate,
    resolve_noise_sigma,
)

__all__ = ["adaptive_bilateral", "adaptive_gaussian", "adaptive_joint_bilateral", "dnbf"]

F32 = NDArray[np.float32]


def _run_kernel(
    depth: F32,
    intensity: F32 | None,
    ref: int,
    *,
    time_weight: F32 | None = None,
    radius: NDArray[np.int32] | int,
    sigma_spatial: F32 | float,
    sigma_intensity: float | None = None,
    sigma_range: F32 | float | None = None,
    relative: bool = False,
) -> F32:
    """Validate-free driver: broadcast the (scalar or per-pixel) sigmas, allocate, call.

    Range and intensity sigmas give the factors 1 / (2 sigma^2) of
    :func:`fuse4d._kernels._common.gauss_factor`, capped at ``MAX_GAUSS_FACTOR``: a tiny (or
    underflowed, 0) sigma is the limit of a narrow kernel (only equal values weigh), never
    "off". A kernel is off only when its sigma is None (or inf, or NaN for a range sigma:
    the NaN centre pixels, whose output is NaN anyway).
    """
    n, h, w = depth.shape
    shape = (h, w)
    rad = np.broadcast_to(np.asarray(radius, dtype=np.int32), shape)
    s_s = np.broadcast_to(np.asarray(sigma_spatial, dtype=np.float32), shape)
    spatial_coeff = (0.5 / (s_s.astype(np.float64) ** 2)).astype(np.float32)
    if sigma_range is None:
        range_coeff = np.zeros(shape, np.float32)
    else:
        s_r = np.broadcast_to(np.asarray(sigma_range, dtype=np.float64), shape)
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            # gauss_factor per pixel: min(1 / (2 sigma^2), MAX_GAUSS_FACTOR); 0 for inf
            range_coeff = np.minimum(0.5 / (s_r * s_r), MAX_GAUSS_FACTOR)
        range_coeff = np.where(np.isnan(s_r), 0.0, range_coeff).astype(np.float32)
    int_coeff = 0.0 if sigma_intensity is None else gauss_factor(sigma_intensity)
    guide = depth if intensity is None or int_coeff == 0 else intensity  # unread when 0
    if guide.shape != depth.shape:
        raise ParameterError("intensity window must match the depth window")
    tw = np.ones(n, np.float32) if time_weight is None else time_weight.astype(np.float32)
    out = np.empty(shape, np.float32)
    _joint_bilateral_kernel(
        np.ascontiguousarray(depth),
        np.ascontiguousarray(guide),
        int(ref),
        tw,
        np.ascontiguousarray(rad),
        np.ascontiguousarray(spatial_coeff),
        float(int_coeff),
        np.ascontiguousarray(range_coeff),
        bool(relative),
        out,
    )
    return out


def joint_bilateral_frame(
    depth: ArrayLike,
    intensity: ArrayLike | None = None,
    *,
    radius: int,
    sigma_spatial: float,
    sigma_intensity: float | None = None,
    sigma_depth: float | None = None,
) -> F32:
    """Non-adaptive (joint) bilateral filter of one depth frame, skipping NaNs.

    The plain-sigma face of the shared kernel (used by the OpenCV golden tests).

    Parameters
    ----------
    depth : (H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (H, W) ndarray, optional
        Guide in [0, 1]; required when ``sigma_intensity`` is given.
    radius : int
        Disc radius (px).
    sigma_spatial : float
        Spatial sigma (px).
    sigma_intensity : float, optional
        Intensity sigma ([0, 1] units); None = no intensity kernel.
    sigma_depth : float, optional
        Depth-range sigma (mm); None = no range kernel.

    Returns
    -------
    (H, W) ndarray of float32
        Filtered depth (mm), NaN where the input is NaN.
    """
    d = np.ascontiguousarray(depth, dtype=np.float32)[None]
    g = None if intensity is None else np.ascontiguousarray(intensity, dtype=np.float32)[None]
    return _run_kernel(
        d,
        g,
        0,
        radius=radius,
        sigma_spatial=sigma_spatial,
        sigma_intensity=sigma_intensity,
        sigma_range=sigma_depth,
    )


# ----------------------------------------------------------------------------------------------
# Ad-GF (BASELINES §1)


#: View angle clamp (rad) of :func:`_view_angle`, and ADGF's lateral sigma there (px, 1.08):
#: the largest sigma_L(theta) = 0.8 + 0.035 theta / (pi/2 - theta) per unit of ``size``.
MAX_VIEW_ANGLE = float(np.deg2rad(80.0))
ADGF_MAX_LATERAL_SIGMA_PX = 0.8 + 0.035 * MAX_VIEW_ANGLE / (np.pi / 2 - MAX_VIEW_ANGLE)


def _view_angle(points: F32) -> F32:
    """Angle θ (rad) between the PCA normal (5×5 window) and the camera ray, clamped ≤ 80°."""
    pts = np.ascontiguousarray(points, dtype=np.float32)
    out = np.empty(points.shape[:2], np.float32)
    _pca_view_angle_kernel(pts, 2, 3, out)
    return np.minimum(out, np.float32(MAX_VIEW_ANGLE))


def _kinect_sigma_z(z_m: float, theta: np.ndarray) -> np.ndarray:
    """Nguyen et al. 2012 axial noise σ_z(z, θ) in metres (z in metres, θ in rad)."""
    base = 0.0012 + 0.0019 * (z_m - 0.4) ** 2
    extra = 0.0001 / math.sqrt(z_m) * theta**2 / (np.pi / 2 - theta) ** 2
    return base + np.where(theta > np.pi / 3, extra, 0.0)


def adaptive_gaussian(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: float = 1.0,
    iterations: int = 1,
    noise_sigma: float | None = None,
) -> F32:
    """Ad-GF: per-pixel adaptive Gaussian from the Kinect noise model (Nguyen et al. 2012).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray or None
        Unused (accepted for the common signature).
    intrinsics : Intrinsics
        Camera (for the normals of the raw point map).
    size : float, default 1
        ``kernel_scale``: scale ``s`` (σ_s = s·σ_L(θ) px, radius ⌈3 s σ_L⌉). Sweep 1, 1.5,
        2, 3, 4, 6.
    iterations : int, default 1
        Repeated application to its own output (normals and σ from the raw input).
    noise_sigma : float, optional
        σ_d in mm (oracle mode, one value for every pixel); default: the noise model
        σ(z) = max(σ0, q z²) estimated from ``depth`` (A22), at each pixel's depth.

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm), NaN where the input is NaN.

    Notes
    -----
    [R] reconstruction (BASELINES §1): lateral σ_L(θ) = 0.8 + 0.035 θ/(π/2 − θ) px and the
    angular dependence of σ_z rescaled to the measured noise,
    σ_z(i) = σ̂_d(D_i) · σ_z^K(1 m, θ_i) / σ_z^K(1 m, 0); depth gate 3 σ_z(i).
    """
    d, _ = check_inputs(depth, intensity, intrinsics)
    # the largest lateral sigma is 1.08 px at the 80 degree clamp: radius ceil(3 * 1.08 s)
    # stays within MAX_WINDOW_RADIUS (size 1e6 looped over 3e6 px per pixel: hours)
    scale = check_number(
        "adaptive_gaussian", "size", size, gt=0, finite=True,
        le=MAX_WINDOW_RADIUS / (3.0 * ADGF_MAX_LATERAL_SIGMA_PX),
    )  # fmt: skip
    if noise_sigma is None:
        model = estimate_noise_model(d)
    else:
        sigma = check_number("adaptive_gaussian", "noise_sigma", noise_sigma, gt=0, finite=True)
        model = DepthNoiseModel(sigma0=sigma, quad=0.0, z_med=float("nan"))
    points = depth_to_points(d, intrinsics)
    params = []
    for t in range(d.shape[0]):
        theta = _view_angle(points[t]).astype(np.float64)
        sigma_l = scale * (0.8 + 0.035 * theta / (np.pi / 2 - theta))
        radius = np.maximum(np.ceil(3.0 * sigma_l), 1).astype(np.int32)
        ratio = _kinect_sigma_z(1.0, theta) / _kinect_sigma_z(1.0, np.zeros(1))
        sigma_d = np.maximum(model.sigma_at(d[t]), 1e-3)  # per pixel (A22)
        params.append((radius, sigma_l.astype(np.float32), (3.0 * sigma_d * ratio)))

    def step(cur: F32) -> F32:
        out = np.empty_like(cur)
        for t in range(cur.shape[0]):
            radius, s_l, s_r = params[t]
            out[t] = _run_kernel(
                cur[t : t + 1], None, 0, radius=radius, sigma_spatial=s_l, sigma_range=s_r
            )
        return out

    return iterate(step, d, iterations, owner="adaptive_gaussian")


# ----------------------------------------------------------------------------------------------
# Ad-BF (BASELINES §2)


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(mask.astype(np.uint8), kernel) > 0


def region_growing_repair(
    depth: F32,
    intensity: F32,
    *,
    depth_edge: float = 10.0,
    intensity_threshold: float = 0.05,
    canny_low: float = 0.05,
    canny_high: float = 0.15,
    max_rounds: int | None = None,
    inside: NDArray[np.bool_] | None = None,
) -> F32:
    """Ad-BF step 1 (Chen et al. 2012, [R]): drop unreliable edge pixels, regrow holes.

    Unreliable: within 2 px of a depth edge (|∇D| > ``depth_edge`` mm/px) but not within 2 px
    of an intensity edge (Canny on I, thresholds ``canny_low``/``canny_high`` in [0, 1] units,
    applied to ``255·I``). Invalid and unreliable pixels are then filled from valid
    8-neighbours whose intensity differs by < ``intensity_threshold`` (mean of the accepted
    neighbours), round after round until nothing changes. Pixels never reached stay NaN.
    One frame: ``depth``, ``intensity`` are (H, W). ``inside`` (H, W) bool: the only pixels
    that may be filled (the sensor's field of view); None: all.
    """
    d = depth.astype(np.float32, copy=True)
    valid = np.isfinite(d)
    gy, gx = np.gradient(np.where(valid, d, np.nan))
    with np.errstate(invalid="ignore"):
        depth_edges = np.hypot(gx, gy) > depth_edge
    i8 = np.clip(np.round(intensity * 255.0), 0, 255).astype(np.uint8)
    int_edges = cv2.Canny(i8, 255.0 * canny_low, 255.0 * canny_high, L2gradient=True) > 0
    unreliable = _dilate(depth_edges, 2) & ~_dilate(int_edges, 2) & valid
    d[unreliable] = np.nan
    todo = ~np.isfinite(d)
    if inside is not None:
        todo &= inside
    if not todo.any():
        return d
    h, w = d.shape
    rounds = max_rounds if max_rounds is not None else h + w
    _region_grow_kernel(
        d,
        np.ascontiguousarray(intensity, dtype=np.float32),
        todo,
        np.float32(intensity_threshold),
        np.int64(rounds),
    )
    return d


def _depth_law_sigma(frame: F32, sigma_d: float) -> NDArray[np.float64]:
    """σ(i) = 3 σ̂_d (D(i)/D_med)² (mm), the quadratic depth law of Ad-BF / Ad-JBF.

    Float64: a tiny σ̂_d (1e-46 mm) is 0 in float32, which the range kernel took as "off".
    """
    med = frame_median_depth(frame)
    return 3.0 * float(sigma_d) * (frame.astype(np.float64) / med) ** 2


def adaptive_bilateral(
    depth: ArrayLike,
    intensity: ArrayLike,
    intrinsics: Intrinsics,
    *,
    size: int = 4,
    iterations: int = 1,
    noise_sigma: float | None = None,
    hole_repair: bool = True,
) -> F32:
    """Ad-BF: region-growing hole repair + depth-adaptive bilateral filter (Chen et al. 2012).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray
        Intensity in [0, 1] (used only by the hole repair).
    intrinsics : Intrinsics
        Camera (shape check only).
    size : int, default 4
        ``spatial_radius``: window radius r (px); σ_s = r/2. Sweep 1, 2, 3, 4, 6, 8, 12.
    iterations : int, default 1
        Repeated application (repair + filter) to its own output.
    noise_sigma : float, optional
        σ_d in mm (oracle); default: the noise model max(σ0, q z²) at the median depth
        (:func:`fuse4d.baselines._common.estimate_noise_model`, A22).
    hole_repair : bool, default True
        Run step 1 (region growing). It fills holes by definition, inside the sensor's field
        of view only (Notes); with False, NaN stays NaN.

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm); NaN outside the raw depth's field of view.

    Notes
    -----
    [R] (BASELINES §2): σ_r(i) = 3 σ̂_d (D(i)/D_med)², D_med = median valid depth of the frame.

    The region growing fills only pixels inside the field of view of the raw depth
    (:func:`fuse4d.fov.field_of_view` of all input frames, as ``fuse4d info`` reports it). This
    is our decision, not Chen et al.'s: unconfined, the growing (up to H + W rounds) flooded
    the no-depth band that a registered depth image leaves around the colour image (99.6 % of
    it on ``uva_cv2_person_turning``) with invented depth. fuse4d's own fills never leave the
    sensor's field of view (A38), and comparing fill rates needs the same rule.
    """
    d, g = check_inputs(depth, intensity, intrinsics, guided_by="adbf")
    radius = check_int("adaptive_bilateral", "size", size, minimum=1, maximum=MAX_WINDOW_RADIUS)
    check_bool("adaptive_bilateral", "hole_repair", hole_repair)
    sigma_d = resolve_noise_sigma(d, noise_sigma, owner="adaptive_bilateral")
    inside = field_of_view(d) if hole_repair else None  # of the raw input (A38)

    def step(cur: F32) -> F32:
        out = np.empty_like(cur)
        for t in range(cur.shape[0]):
            frame = region_growing_repair(cur[t], g[t], inside=inside) if hole_repair else cur[t]
            out[t] = _run_kernel(
                frame[None],
                None,
                0,
                radius=radius,
                sigma_spatial=radius / 2.0,
                sigma_range=_depth_law_sigma(frame, sigma_d),
            )
        return out

    return iterate(step, d, iterations, owner="adaptive_bilateral")


# ----------------------------------------------------------------------------------------------
# Ad-JBF (BASELINES §6)


def _kalman_depth(depth: F32, sigma_meas: F32, sigma_d: float) -> F32:
    """Per-pixel scalar Kalman filter on depth (q = (0.5 σ̂_d)², R = σ_D², reset at 3√(P+R)).

    NaN measurements leave the state untouched (prediction only) and stay NaN in the output.
    """
    q = (0.5 * sigma_d) ** 2
    out = np.empty_like(depth)
    x = np.full(depth.shape[1:], np.nan)
    p = np.zeros(depth.shape[1:])
    for t in range(depth.shape[0]):
        z = depth[t].astype(np.float64)
        r = sigma_meas[t].astype(np.float64) ** 2
        p_pred = p + q
        has_z = np.isfinite(z)
        with np.errstate(invalid="ignore"):
            far = np.abs(z - x) > 3.0 * np.sqrt(p_pred + r)
        init = has_z & (~np.isfinite(x) | far)
        update = has_z & ~init
        gain = p_pred / np.maximum(p_pred + r, 1e-30)
        x = np.where(init, z, np.where(update, x + gain * (z - x), x))
        p = np.where(init, r, np.where(update, (1.0 - gain) * p_pred, p_pred))
        out[t] = np.where(has_z, x, np.nan)
    return out


def adaptive_joint_bilateral(
    depth: ArrayLike,
    intensity: ArrayLike,
    intrinsics: Intrinsics,
    *,
    size: int = 4,
    iterations: int = 1,
    noise_sigma: float | None = None,
    sigma_intensity: float = 0.1,
    temporal: bool = False,
) -> F32:
    """Ad-JBF: joint bilateral with an intensity and a depth-adaptive range kernel.

    Camplani et al. 2013, [R] (BASELINES §6).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray
        Intensity guide in [0, 1].
    intrinsics : Intrinsics
        Camera (shape check only).
    size : int, default 4
        ``spatial_radius``: window radius r (px); σ_s = r/2. Sweep 1–12.
    iterations : int, default 1
        Repeated application to its own output.
    noise_sigma : float, optional
        σ_d in mm (oracle); default: the noise model max(σ0, q z²) at the median depth
        (:func:`fuse4d.baselines._common.estimate_noise_model`, A22).
    sigma_intensity : float, default 0.1
        σ_I in [0, 1] units.
    temporal : bool, default False
        Add the per-pixel scalar Kalman filter after the spatial stage.

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm), NaN where the input is NaN.
    """
    d, g = check_inputs(depth, intensity, intrinsics, guided_by="adjbf")
    radius = check_int(
        "adaptive_joint_bilateral", "size", size, minimum=1, maximum=MAX_WINDOW_RADIUS
    )
    check_number("adaptive_joint_bilateral", "sigma_intensity", sigma_intensity, gt=0)
    check_bool("adaptive_joint_bilateral", "temporal", temporal)
    sigma_d = resolve_noise_sigma(d, noise_sigma, owner="adaptive_joint_bilateral")

    def step(cur: F32) -> F32:
        out = np.empty_like(cur)
        sig = np.empty(cur.shape, np.float64)
        for t in range(cur.shape[0]):
            sig[t] = _depth_law_sigma(cur[t], sigma_d)
            out[t] = _run_kernel(
                cur[t : t + 1],
                g[t : t + 1],
                0,
                radius=radius,
                sigma_spatial=radius / 2.0,
                sigma_intensity=float(sigma_intensity),
                sigma_range=sig[t],
            )
        if temporal:
            out = _kalman_depth(out, sig, sigma_d)
        return out

    return iterate(step, d, iterations, owner="adaptive_joint_bilateral")


# ----------------------------------------------------------------------------------------------
# DNBF (BASELINES §4)


def dnbf(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 3,
    iterations: int = 1,
    noise_sigma: float | None = None,
    num_previous: int = 2,
    sigma_temporal: float = 1.0,
) -> F32:
    """DNBF: causal spatio-temporal bilateral with a divisively normalised range kernel.

    Fu et al. 2012, [R] (BASELINES §4). No intensity, no motion compensation.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray or None
        Unused (common signature).
    intrinsics : Intrinsics
        Camera (shape check only).
    size : int, default 3
        ``spatial_radius``: window radius r (px); σ_s = 2r/3 px (2 px at the default).
        Sweep 1–12.
    iterations : int, default 1
        Repeated application to its own output sequence.
    noise_sigma : float, optional
        σ_d in mm (oracle); default: the noise model max(σ0, q z²) at the median depth
        (:func:`fuse4d.baselines._common.estimate_noise_model`, A22).
    num_previous : int, default 2
        k, the number of previous frames in the causal window (truncated at the start).
    sigma_temporal : float, default 1
        σ_t in frames.

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm), NaN where the input is NaN.

    Notes
    -----
    ρ = (D_τ(j) − D_t(i)) / D_t(i), σ_ρ = 3 σ̂_d / D_med(t). σ_s scaling with ``size`` (2r/3)
    is our choice: the spec fixes σ_s = 2 px only at the default radius 3.
    """
    d, _ = check_inputs(depth, intensity, intrinsics)
    radius = check_int("dnbf", "size", size, minimum=1, maximum=MAX_WINDOW_RADIUS)
    k = check_int("dnbf", "num_previous", num_previous, minimum=0)
    check_number("dnbf", "sigma_temporal", sigma_temporal, gt=0)
    sigma_d = resolve_noise_sigma(d, noise_sigma, owner="dnbf")
    sigma_s = 2.0 * radius / 3.0

    def step(cur: F32) -> F32:
        out = np.empty_like(cur)
        for t in range(cur.shape[0]):
            t0 = max(0, t - k)
            window = cur[t0 : t + 1]
            lags = np.arange(t - t0, -1, -1, dtype=np.float64)  # frame t0 .. t
            tw = np.exp(-(lags**2) * gauss_factor(sigma_temporal)).astype(np.float32)
            sigma_rho = 3.0 * sigma_d / frame_median_depth(cur[t])
            out[t] = _run_kernel(
                window,
                None,
                t - t0,
                time_weight=tw,
                radius=radius,
                sigma_spatial=sigma_s,
                sigma_range=sigma_rho,
                relative=True,
            )
        return out

    return iterate(step, d, iterations, owner="dnbf")
