"""Input checks and conversions shared by the flow methods and the estimators."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validation import as_float32, check_shape
from ..errors import ParameterError, ShapeError
from ..sequence import check_unit_slack, normalize_intensity
from ._registry import Roi

__all__ = ["check_flow_field", "check_image", "check_roi", "to_uint8"]


def check_image(image: Any, name: str) -> NDArray[np.float32]:
    """One gray intensity frame as float32 ``(H, W)``, about [0, 1], at least 2 px a side.

    uint8/uint16 are divided by 255/65535 and other integer types refused, as
    :class:`fuse4d.FusionEngine` does (a ``cv2.imread`` uint8 frame was taken as 0-255 and
    saturated: a near-zero flow). Floats
    must be finite and within ``sequence.UNIT_RANGE_SLACK`` of [0, 1] (0-255 floats were
    saturated the same way).
    """
    arr = np.asarray(image)
    if arr.dtype.kind in "uib":
        arr = normalize_intensity(arr, name=name)
    arr = as_float32(arr, name=name)
    check_shape(arr, ("H", "W"), name=name, hint="Pass one gray-scale intensity frame")
    if arr.shape[0] < 2 or arr.shape[1] < 2:
        raise ShapeError(name, ("H", "W"), arr.shape, "Each side must be at least 2 px")
    lo, hi = float(arr.min()), float(arr.max())
    if not (math.isfinite(lo) and math.isfinite(hi)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise ParameterError(f"{name} has {bad} NaN or inf pixel(s); intensity must be finite")
    check_unit_slack(lo, hi, name=name)
    return arr


def check_flow_field(flow: Any, shape: tuple[int, int], name: str) -> NDArray[np.float32]:
    """A finite float32 ``(H, W, 2)`` flow field (px) of the given image shape."""
    arr = as_float32(flow, name=name)
    check_shape(arr, (*shape, 2), name=name, hint="A flow field is (H, W, 2) px: du, dv")
    if not np.isfinite(arr).all():
        raise ParameterError(f"{name} contains NaN or inf")
    return arr


def check_roi(roi: Any, shape: tuple[int, int] | None) -> Roi | None:
    """``(row0, row1, col0, col1)`` half-open box inside ``shape`` (px), or None.

    The values must be whole numbers (0.5 was truncated to 0). ``shape`` None checks what
    does not depend on the frame size (a configuration file's ROI, before any frame is read).
    """
    if roi is None:
        return None
    try:
        r0, r1, c0, c1 = (_whole_px(v) for v in roi)
    except (TypeError, ValueError):
        raise ParameterError(
            f"roi must be (row0, row1, col0, col1), four whole numbers of px, got {roi!r}"
        ) from None
    h, w = (math.inf, math.inf) if shape is None else shape
    if not (0 <= r0 < r1 <= h and 0 <= c0 < c1 <= w) or r1 - r0 < 2 or c1 - c0 < 2:
        bounds = ("", "") if shape is None else (f" <= {h}", f" <= {w}")
        raise ParameterError(
            f"roi {(r0, r1, c0, c1)} must satisfy 0 <= row0 < row1{bounds[0]}, "
            f"0 <= col0 < col1{bounds[1]}, at least 2 px each way (half-open, px)"
        )
    return (r0, r1, c0, c1)


def _whole_px(value: Any) -> int:
    """A pixel index that is a whole number (an int, or a float or text such as 100.0);
    ValueError for a fraction, inf or NaN, TypeError for a bool or non-number."""
    if isinstance(value, bool):
        raise TypeError("a bool is not a pixel index")
    if isinstance(value, numbers.Integral):
        return int(value)
    number = float(value.strip() if isinstance(value, str) else value)
    if not number.is_integer():
        raise ValueError(f"{value!r} is not a whole number")
    return int(number)


def to_uint8(image: NDArray[np.float32]) -> NDArray[np.uint8]:
    """[0, 1] float → uint8 with rounding and saturation (like ``Mat.convertTo(CV_8U, 255)``):
    ``clip(image * 255 + 0.5, 0, 255)`` in float32, truncated.

    A 2-D float32 image goes through one numba pass (0.09 -> 0.015 ms at 640 x 480, the same
    bytes; DIS converts both images of each of the pair's two solves, stop 48); the kernel
    module is imported on first use, so that importing the flow methods loads no kernel.
    """
    out = np.empty(image.shape, np.uint8)
    if image.ndim == 2 and image.dtype == np.float32:
        from .._kernels.io import _unit_to_uint8_kernel

        _unit_to_uint8_kernel(image, out)
        return out
    np.clip(image * np.float32(255.0) + np.float32(0.5), 0.0, 255.0, out=out, casting="unsafe")
    return out
