"""Helpers shared by every baseline: input checks, the noise scale, NaN fill, iterations."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._params import check_int, check_number
from .._validation import as_float32, check_same_shape, check_shape
from ..camera import Intrinsics, check_intrinsics
from ..errors import ParameterTypeError, ShapeError
from ..sequence import as_unit_intensity, sanitize_depth

__all__ = [
    "MAX_WINDOW_RADIUS",
    "DepthNoiseModel",
    "check_inputs",
    "estimate_noise_model",
    "estimate_noise_sigma",
    "frame_median_depth",
    "iterate",
    "normalized_convolution_fill",
    "resolve_noise_sigma",
]

#: Largest pixel radius of a baseline's window (size, STMF's half window, block and search):
#: 4x the largest of the size sweeps (16). A window of (2r + 1)^2 pixels per pixel beyond it
#: takes hours on a VGA frame (``-p size=1000000`` hung) and no sensor's image needs it.
MAX_WINDOW_RADIUS = 64

#: MAD → σ for a Gaussian, and the variance factor of r = D − mean(4-neighbours): 1 + 4/16.
_MAD_TO_SIGMA = 1.4826
_NEIGHBOUR_FACTOR = np.sqrt(1.25)
#: residuals used by estimate_noise_sigma (evenly spaced frames beyond that)
_NOISE_SAMPLES = 1_500_000


def check_inputs(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    guided_by: str | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """Validate ``(T, H, W)`` depth (mm) / intensity ([0, 1]) against ``intrinsics``.

    Returns contiguous float32 arrays; depth values <= 0 or non-finite become NaN (copy).
    uint8/uint16 intensity is divided by 255/65535 (other integer types are refused) and float intensity must lie in
    [0, 1], as for the fusion (a uint8 guide was taken as 0-255: every range weight ~0).
    ``guided_by``: the name of a method that needs the intensity; None intensity is then
    refused with a :class:`~fuse4d.errors.ParameterTypeError` naming it.
    """
    if intensity is None and guided_by is not None:
        raise ParameterTypeError(
            f"{guided_by} needs intensity: it is guided by the registered intensity (IR or "
            "gray) video; baselines without a guide (e.g. temporal-mean, ta) take "
            "intensity=None"
        )
    check_intrinsics(intrinsics)
    d = as_float32(depth, name="depth")
    check_shape(d, ("T", "H", "W"), name="depth", hint="Pass a (frames, rows, columns) array.")
    if d.shape[1:] != (intrinsics.height, intrinsics.width):
        raise ShapeError(
            "depth",
            ("T", intrinsics.height, intrinsics.width),
            d.shape,
            "Its frames must have the intrinsics' height x width",
        )
    bad = ~(np.isfinite(d) & (d > 0))
    if bad.any():
        d = d.copy()
        d[bad] = np.nan
    if intensity is None:
        return d, None
    i = as_unit_intensity(intensity)
    check_same_shape(d, i, names=("depth", "intensity"))
    return d, i


def estimate_noise_sigma(depth: ArrayLike) -> float:
    """Estimate the depth noise σ̂_d (mm) of a sequence (BASELINES.md, common conventions).

    ``r(x) = D(x) − mean of the 4-neighbours`` over pixels whose 4 neighbours are valid and
    ``|r| < 10 mm``; ``σ̂_d = 1.4826 · MAD(r) / √1.25``. Long sequences use evenly spaced
    frames, at least 1.5 M residuals (the MAD's standard error is then < 0.1 %).

    Parameters
    ----------
    depth : (T, H, W) or (H, W) ndarray
        Depth in mm; NaN, 0 (a 16-bit file's "no depth"), negative or inf = invalid.

    Returns
    -------
    float
        σ̂_d in mm (0.0 if no pixel qualifies).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> d = 500 + rng.normal(0, 0.2, (4, 64, 64))
    >>> round(estimate_noise_sigma(d), 1)
    0.2
    """
    d = np.asarray(depth)
    if d.ndim == 2:
        d = d[None]
    # MAD of >= 1.5 M residuals is as good as all of them (standard error < 0.1 %), and long
    # sequences would otherwise dominate a filter's run time: use evenly spaced frames.
    per_frame = max((d.shape[1] - 2) * (d.shape[2] - 2), 1)
    step = max(1, d.shape[0] // max(1, -(-_NOISE_SAMPLES // per_frame)))
    d = sanitize_depth(d[::step])  # 0 = no depth (16-bit files): zero holes read as no noise
    c = d[:, 1:-1, 1:-1]
    nb = (d[:, :-2, 1:-1] + d[:, 2:, 1:-1] + d[:, 1:-1, :-2] + d[:, 1:-1, 2:]) * np.float32(0.25)
    r = c - nb
    r = r[np.abs(r) < 10.0]  # NaN compares False: drops pixels with an invalid neighbour
    if r.size == 0:
        return 0.0
    dev = np.abs(r - np.median(r))
    return float(_MAD_TO_SIGMA * np.median(dev) / _NEIGHBOUR_FACTOR)


#: frames sampled (evenly spaced) by estimate_noise_model
_MODEL_FRAMES = 5
#: the MAD is trusted (quadratic term dropped) when sigma0 >= this x quad z_med^2
_MAD_TRUSTED = 0.5


@dataclass(frozen=True)
class DepthNoiseModel:
    """Depth-noise model sigma(z) = max(sigma0, quad z^2) of a recording (A22), in mm.

    Attributes
    ----------
    sigma0 : float
        Floor of the noise, mm (:func:`estimate_noise_sigma`: the MAD of neighbour residuals;
        it is the whole model for the continuous noise of the paper's sensor).
    quad : float
        Quadratic coefficient, mm^-1 (:func:`fuse4d.motion.estimate_noise_quad`: one
        quantisation level / 1.65 on disparity-quantised depth, whose steps grow as z^2).
    z_med : float
        Median valid depth of the sampled frames, mm (NaN without valid depth).
    """

    sigma0: float
    quad: float
    z_med: float

    def sigma_at(self, z: ArrayLike) -> NDArray[np.float64]:
        """sigma(z) = max(sigma0, quad z^2) in mm at depth(s) ``z`` (mm); NaN stays NaN."""
        z = np.asarray(z, dtype=np.float64)
        return np.maximum(self.sigma0, self.quad * z * z)

    @property
    def sigma_median(self) -> float:
        """sigma at the median depth, mm (at least 1e-3 so that range kernels exist)."""
        value = float(self.sigma_at(self.z_med)) if np.isfinite(self.z_med) else self.sigma0
        return max(value, 1e-3)


def estimate_noise_model(depth: ArrayLike) -> DepthNoiseModel:
    """Estimate the depth-noise model sigma(z) = max(sigma0, quad z^2) of a sequence (mm).

    ``sigma0`` is :func:`estimate_noise_sigma` (continuous noise, e.g. 0.2 mm on the paper's
    sensor); ``quad`` the median of :func:`fuse4d.motion.estimate_noise_quad` over up to 5
    evenly spaced frames. On quantised structured-light depth the MAD collapses towards 0
    (most neighbour residuals are exactly 0) while ``quad z^2`` is about one depth step / 1.65,
    so the model follows the sensor's units and noise. When the MAD has not collapsed
    (``sigma0 >= 0.5 quad z_med^2``: continuous noise such as the paper's 0.2 mm sensor) the
    quadratic term is dropped (``quad = 0``): there the MAD is the more accurate estimate
    (second differences also see surface curvature: 0.27 vs 0.20 mm on the paper's ball), and
    the thresholds of every baseline stay what they were.

    Parameters
    ----------
    depth : (T, H, W) or (H, W) ndarray
        Depth in mm; NaN, 0 (a 16-bit file's "no depth"), negative or inf = invalid.

    Returns
    -------
    DepthNoiseModel

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> model = estimate_noise_model(1000 + rng.normal(0, 0.2, (3, 64, 64)))
    >>> round(model.sigma_median, 1)
    0.2
    """
    from ..motion import estimate_noise_quad

    d = np.asarray(depth)
    if d.ndim == 2:
        d = d[None]
    picks = np.unique(np.linspace(0, d.shape[0] - 1, min(_MODEL_FRAMES, d.shape[0])).astype(int))
    sample = sanitize_depth(d[picks])  # 0 = no depth (16-bit files), as NaN
    quads = [estimate_noise_quad(sample[i]) for i in range(sample.shape[0])]
    finite = sample[np.isfinite(sample)]
    z_med = float(np.median(finite)) if finite.size else float("nan")
    sigma0 = estimate_noise_sigma(d)
    quad = float(np.median(quads))
    if np.isfinite(z_med) and sigma0 >= _MAD_TRUSTED * quad * z_med**2:
        # Continuous noise: the MAD is the better estimate (second differences also see the
        # surface's curvature); keep it alone so thresholds on such data do not move.
        quad = 0.0
    return DepthNoiseModel(sigma0=sigma0, quad=quad, z_med=z_med)


def resolve_noise_sigma(
    depth: NDArray[np.float32], noise_sigma: float | None, *, owner: str = "baseline"
) -> float:
    """``noise_sigma`` if given (oracle mode, mm, > 0), else the noise model at the median depth.

    The estimate is :attr:`DepthNoiseModel.sigma_median` of :func:`estimate_noise_model`:
    ``max(sigma0, quad z_med^2)``, so that thresholds follow the sensor's units and noise
    (a quantised Kinect recording at 3 m: ~20 mm, not the 0 mm of the MAD). ``owner`` names
    the calling method in the error message.
    """
    if noise_sigma is None:
        # A noise-free input estimates 0: sigma_median keeps a tiny positive scale.
        return estimate_noise_model(depth).sigma_median
    return check_number(owner, "noise_sigma", noise_sigma, gt=0, finite=True)


def frame_median_depth(frame: NDArray[np.float32]) -> float:
    """Median valid depth (mm) of one frame (``D_med``); NaN if the frame has no valid pixel."""
    valid = frame[np.isfinite(frame)]
    return float(np.median(valid)) if valid.size else float("nan")


def normalized_convolution_fill(frame: NDArray[np.float32], *, sigma: float = 3.0) -> NDArray:
    """Fill NaNs of one depth frame by normalised convolution (Gaussian σ px over valid pixels).

    Valid pixels keep their value. Pixels with no valid support within the Gaussian's reach
    are filled with the frame's median (so that filters that cannot skip NaN never see one).
    """
    valid = np.isfinite(frame)
    if valid.all():
        return frame.copy()
    if not valid.any():
        return np.zeros_like(frame)
    data = np.where(valid, frame, 0).astype(np.float32)
    weight = valid.astype(np.float32)
    ksize = (0, 0)
    num = cv2.GaussianBlur(data, ksize, sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    den = cv2.GaussianBlur(weight, ksize, sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    fill = np.full_like(data, np.median(frame[valid]))
    ok = den > 1e-6
    fill[ok] = num[ok] / den[ok]
    return np.where(valid, frame, fill).astype(np.float32)


def iterate(
    step: Callable[[NDArray[np.float32]], NDArray[np.float32]],
    depth: NDArray[np.float32],
    iterations: int,
    *,
    owner: str = "baseline",
) -> NDArray[np.float32]:
    """Apply ``step`` ``iterations`` (>= 1) times to its own output (the E3 knob).

    ``owner`` names the calling method in the error message.
    """
    iterations = check_int(owner, "iterations", iterations, minimum=1)
    out = depth
    for _ in range(iterations):
        out = step(out)
    return out
