"""Decimation: depth, intensity and camera at 1/f of the resolution (``fuse4d live --decimate``).

The first block of the RealSense post-processing chain (``rs.decimation_filter``), and the
usual way to buy frame rate on a small machine: fuse4d's cost is about proportional to the
number of pixels (``fuse4d bench``), so a factor of 2 fuses a 640 x 480 camera at 320 x 240
for about a quarter of the work. Like the SDK's filter, each f x f block of depth becomes

* for f = 2 and 3, the **lower median** of its valid depths (the ((n - 1) // 2)-th of the n
  sorted values): a measured depth, never an average across a depth edge (no new flying
  pixels);
* for f >= 4, their **mean**;
* invalid (NaN) where the block has no valid depth.

Depth 0 (a 16-bit file's "no measurement"), negative and infinite values are invalid as NaN
is, as everywhere in fuse4d (:func:`fuse4d.sequence.sanitize_depth`): never averaged into a
block.

Tested against ``rs.decimation_filter`` (``tests/test_decimate.py``: equal for f = 2, within
its integer truncation for f = 4). Two deliberate differences from the SDK: the output is
``(H // f, W // f)`` (the SDK pads width and height up to a multiple of 4), and the principal
point keeps the pixel-centre convention of :meth:`Intrinsics.scaled`, ``(c + 0.5) / f - 0.5``,
where the SDK reports ``c / f`` (0.25 px apart at f = 2). The intensity is the block mean,
in [0, 1] (uint8 and uint16 intensity are scaled as :func:`fuse4d.sequence.normalize_intensity`
does).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels.decimate import _decimate_depth_kernel
from ._validation import as_float32
from .camera import Intrinsics
from .errors import ParameterError
from .sequence import normalize_intensity

__all__ = [
    "MAX_DECIMATION",
    "decimate_depth",
    "decimate_intensity",
    "decimate_intrinsics",
    "decimate_mask",
]

#: The largest factor (the RealSense SDK's range is 1-8).
MAX_DECIMATION = 8


def _check_factor(factor: int) -> int:
    if isinstance(factor, bool) or int(factor) != factor or not 1 <= factor <= MAX_DECIMATION:
        raise ParameterError(
            f"decimation factor must be an integer 1..{MAX_DECIMATION}, got {factor!r}"
        )
    return int(factor)


def _check_size(shape: tuple[int, ...], factor: int, name: str) -> None:
    if len(shape) != 2:
        raise ParameterError(f"{name} must have shape (H, W), got {shape}")
    if shape[0] < factor or shape[1] < factor:
        raise ParameterError(
            f"{name} of {shape[0]} x {shape[1]} px is smaller than one {factor} x {factor} block"
        )


def decimate_depth(depth: ArrayLike, factor: int) -> NDArray[np.float32]:
    """Depth (mm, NaN = invalid) of each ``factor`` x ``factor`` block (module docstring).

    Parameters
    ----------
    depth : (H, W) array
        Depth in mm; NaN, 0 (a 16-bit file's invalid), negative and infinite values are
        invalid.
    factor : int
        Block side f, 1-8 (1 returns a float32 copy, the invalid values NaN).

    Returns
    -------
    (H // f, W // f) ndarray of float32
        Lower median (f <= 3) or mean (f >= 4) of each block's valid depths, mm; NaN where a
        block has none.

    Examples
    --------
    >>> d = np.array([[1000, 1002, 3000, np.nan], [1001, np.nan, np.nan, np.nan]], np.float32)
    >>> decimate_depth(d, 2).tolist()
    [[1001.0, 3000.0]]
    """
    f = _check_factor(factor)
    d = as_float32(depth, name="depth")
    _check_size(d.shape, f, "depth")
    if f == 1:
        return np.where(np.isfinite(d) & (d > 0), d, np.float32(np.nan))
    out = np.empty((d.shape[0] // f, d.shape[1] // f), np.float32)
    _decimate_depth_kernel(np.ascontiguousarray(d), f, f <= 3, out)
    return out


def decimate_intensity(intensity: ArrayLike, factor: int) -> NDArray[np.float32]:
    """Mean of each ``factor`` x ``factor`` block of a (H, W) intensity image (float32).

    Parameters
    ----------
    intensity : (H, W) array
        Float intensity in [0, 1] (kept as it is), or uint8 / uint16 / bool (divided by 255 /
        65535, as :func:`fuse4d.sequence.normalize_intensity`; other integer types refused).
    factor : int
        Block side f, 1-8.

    Returns
    -------
    (H // f, W // f) ndarray of float32
        The block means, in the input's [0, 1] scale.
    """
    f = _check_factor(factor)
    i = np.asarray(intensity)
    # integers are scaled as everywhere else (uint8 / 255); floats are taken as they are,
    # frame by frame (no per-frame rescaling of out-of-range floats)
    i = normalize_intensity(i) if i.dtype.kind in "biu" else as_float32(i, name="intensity")
    _check_size(i.shape, f, "intensity")
    h, w = i.shape[0] // f, i.shape[1] // f
    if f == 1:
        return i.copy()
    crop = np.ascontiguousarray(i[: h * f, : w * f])
    return cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA)


def decimate_mask(mask: ArrayLike, factor: int) -> NDArray[np.bool_]:
    """True for each ``factor`` x ``factor`` block of a (H, W) mask that holds a True pixel."""
    f = _check_factor(factor)
    m = np.asarray(mask, dtype=bool)
    _check_size(m.shape, f, "mask")
    h, w = m.shape[0] // f, m.shape[1] // f
    return m[: h * f, : w * f].reshape(h, f, w, f).any(axis=(1, 3))


def decimate_intrinsics(intrinsics: Intrinsics, factor: int) -> Intrinsics:
    """The camera of the decimated image: focal lengths / f, principal point
    ``(c + 0.5) / f - 0.5`` (pixel centres), size ``(H // f, W // f)``."""
    f = _check_factor(factor)
    _check_size((intrinsics.height, intrinsics.width), f, "the camera's image")
    scaled = intrinsics.scaled(1.0 / f)
    return dataclasses.replace(scaled, width=intrinsics.width // f, height=intrinsics.height // f)
