"""Helpers shared by every baseline: input checks, the noise scale, NaN fill, iterations."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._params import check_int, check_number
from .._validation import as_float32, check_same_shape, check_shape
from ..camera import Intrinsics

__all__ = [
    "check_inputs",
    "estimate_noise_sigma",
    "frame_median_depth",
    "iterate",
    "normalized_convolution_fill",
    "resolve_noise_sigma",
]

#: MAD → σ for a Gaussian, and the variance factor of r = D − mean(4-neighbours): 1 + 4/16.
_MAD_TO_SIGMA = 1.4826
_NEIGHBOUR_FACTOR = np.sqrt(1.25)
#: residuals used by estimate_noise_sigma (evenly spaced frames beyond that)
_NOISE_SAMPLES = 1_500_000


def check_inputs(
    depth: ArrayLike, intensity: ArrayLike | None, intrinsics: Intrinsics
) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """Validate ``(T, H, W)`` depth (mm) / intensity ([0, 1]) against ``intrinsics``.

    Returns contiguous float32 arrays; depth values <= 0 or non-finite become NaN (copy).
    """
    if not isinstance(intrinsics, Intrinsics):
        raise TypeError(f"intrinsics must be a fuse4d.Intrinsics, got {type(intrinsics).__name__}")
    d = as_float32(depth, name="depth")
    check_shape(d, ("T", "H", "W"), name="depth", hint="Pass a (frames, rows, columns) array.")
    if d.shape[1:] != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth frames are {d.shape[1]}x{d.shape[2]} (HxW) but intrinsics describe "
            f"{intrinsics.height}x{intrinsics.width}"
        )
    bad = ~(np.isfinite(d) & (d > 0))
    if bad.any():
        d = d.copy()
        d[bad] = np.nan
    if intensity is None:
        return d, None
    i = as_float32(intensity, name="intensity")
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
        Depth in mm, NaN = invalid.

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
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim == 2:
        d = d[None]
    # MAD of >= 1.5 M residuals is as good as all of them (standard error < 0.1 %), and long
    # sequences would otherwise dominate a filter's run time: use evenly spaced frames.
    per_frame = max((d.shape[1] - 2) * (d.shape[2] - 2), 1)
    step = max(1, d.shape[0] // max(1, -(-_NOISE_SAMPLES // per_frame)))
    d = d[::step]
    c = d[:, 1:-1, 1:-1]
    nb = (d[:, :-2, 1:-1] + d[:, 2:, 1:-1] + d[:, 1:-1, :-2] + d[:, 1:-1, 2:]) * np.float32(0.25)
    r = c - nb
    r = r[np.abs(r) < 10.0]  # NaN compares False: drops pixels with an invalid neighbour
    if r.size == 0:
        return 0.0
    dev = np.abs(r - np.median(r))
    return float(_MAD_TO_SIGMA * np.median(dev) / _NEIGHBOUR_FACTOR)


def resolve_noise_sigma(
    depth: NDArray[np.float32], noise_sigma: float | None, *, owner: str = "baseline"
) -> float:
    """``noise_sigma`` if given (oracle mode, mm, > 0), else :func:`estimate_noise_sigma`.

    ``owner`` names the calling method in the error message.
    """
    if noise_sigma is None:
        sigma = estimate_noise_sigma(depth)
        # A noise-free input estimates 0: keep a tiny positive scale so range kernels exist.
        return max(sigma, 1e-3)
    return check_number(owner, "noise_sigma", noise_sigma, gt=0)


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
