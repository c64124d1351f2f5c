"""Flow visualisation with the standard Middlebury colour wheel (Baker et al., IJCV 2011).

Hue = direction, saturation = magnitude (white = no motion, fully saturated = ``max_magnitude``).
Same wheel as the Middlebury ``flowToColor.m`` / ``computeColor.m`` (55 colours: 15 red→yellow,
6 yellow→green, 4 green→cyan, 11 cyan→blue, 13 blue→magenta, 6 magenta→red). With image rows
going down: flow to the right (+du) is red, down (+dv) orange-yellow, left cyan, up blue-violet.
Beyond ``max_magnitude`` colours are darkened to 75 %. Unknown flow (NaN, inf or |value| > 1e9,
the ``.flo`` "unknown" code) is black.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .._validation import as_float32, check_shape
from ..errors import ParameterError
from ..io._atomic import atomic_file
from ..io._images import encode_png

__all__ = ["flow_to_color", "make_color_wheel", "write_flow_png"]

#: Segment lengths of the Middlebury wheel: RY, YG, GC, CB, BM, MR.
_SEGMENTS = (15, 6, 4, 11, 13, 6)

#: Values with a larger magnitude are "unknown" in Middlebury ``.flo`` files.
UNKNOWN_FLOW_THRESHOLD = 1e9


def make_color_wheel() -> NDArray[np.uint8]:
    """The 55 × 3 RGB colour wheel of the Middlebury flow benchmark (uint8)."""
    ry, yg, gc, cb, bm, mr = _SEGMENTS
    wheel = np.zeros((sum(_SEGMENTS), 3), np.int32)
    col = 0

    def ramp(n: int) -> NDArray[np.int32]:
        return np.floor(255 * np.arange(n) / n).astype(np.int32)

    wheel[col : col + ry, 0] = 255
    wheel[col : col + ry, 1] = ramp(ry)
    col += ry
    wheel[col : col + yg, 0] = 255 - ramp(yg)
    wheel[col : col + yg, 1] = 255
    col += yg
    wheel[col : col + gc, 1] = 255
    wheel[col : col + gc, 2] = ramp(gc)
    col += gc
    wheel[col : col + cb, 1] = 255 - ramp(cb)
    wheel[col : col + cb, 2] = 255
    col += cb
    wheel[col : col + bm, 2] = 255
    wheel[col : col + bm, 0] = ramp(bm)
    col += bm
    wheel[col : col + mr, 2] = 255 - ramp(mr)
    wheel[col : col + mr, 0] = 255
    return wheel.astype(np.uint8)


def flow_to_color(
    flow: NDArray[np.floating], *, max_magnitude: float | None = None
) -> NDArray[np.uint8]:
    """Colour-code a flow field (Middlebury colour wheel).

    Parameters
    ----------
    flow : (H, W, 2) ndarray
        Flow in px, ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row).
    max_magnitude : float, optional
        Magnitude (px) shown fully saturated. Default: the largest magnitude of the known flow
        (so pictures of different fields are not comparable unless you fix it).

    Returns
    -------
    (H, W, 3) ndarray of uint8
        RGB image (convert to BGR before ``cv2.imwrite``).

    Examples
    --------
    >>> flow = np.zeros((1, 3, 2), np.float32)
    >>> flow[0, 1] = (1.0, 0.0)  # rightwards
    >>> flow[0, 2] = (np.nan, 0.0)  # unknown
    >>> flow_to_color(flow, max_magnitude=1.0)[0].tolist()
    [[255, 255, 255], [255, 0, 0], [0, 0, 0]]
    """
    f = as_float32(flow, name="flow")
    check_shape(f, ("H", "W", 2), name="flow", hint="A flow field is (H, W, 2) px: du, dv")
    u = f[..., 0].astype(np.float64)
    v = f[..., 1].astype(np.float64)
    known = np.isfinite(u) & np.isfinite(v)
    known &= (np.abs(u) <= UNKNOWN_FLOW_THRESHOLD) & (np.abs(v) <= UNKNOWN_FLOW_THRESHOLD)
    u = np.where(known, u, 0.0)
    v = np.where(known, v, 0.0)
    radius = np.hypot(u, v)
    if max_magnitude is None:
        max_magnitude = float(radius.max()) if radius.size else 0.0
    elif not (np.isfinite(max_magnitude) and max_magnitude > 0):
        raise ParameterError(f"max_magnitude must be a positive number, got {max_magnitude!r}")
    scale = 1.0 / max(float(max_magnitude), np.finfo(np.float64).eps)
    u *= scale
    v *= scale
    radius *= scale

    wheel = make_color_wheel().astype(np.float64) / 255.0
    ncols = wheel.shape[0]
    angle = np.arctan2(-v, -u) / np.pi  # in [-1, 1]
    fk = (angle + 1.0) / 2.0 * (ncols - 1)
    k0 = np.floor(fk).astype(np.int64)
    k1 = k0 + 1
    k1[k1 == ncols] = 0
    frac = (fk - k0)[..., None]
    col = (1.0 - frac) * wheel[k0] + frac * wheel[k1]
    inside = (radius <= 1.0)[..., None]
    col = np.where(inside, 1.0 - radius[..., None] * (1.0 - col), col * 0.75)
    rgb = np.floor(255.0 * col).astype(np.uint8)
    rgb[~known] = 0
    return rgb


def write_flow_png(
    flow: NDArray[np.float32],
    path: str | PathLike[str],
    *,
    max_magnitude: float | None = None,
    overwrite: bool = False,
) -> Path:
    """Write the Middlebury colour coding of ``flow`` as an 8-bit RGB PNG, atomically.

    Parameters
    ----------
    flow : (H, W, 2) ndarray
        Flow in px (du, dv).
    path : str or PathLike
        Output ``.png``.
    max_magnitude : float, optional
        Magnitude (px) drawn fully saturated (default: the field's largest).
    overwrite : bool, optional
        Replace an existing file.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ParameterError
        If ``path`` does not end in ``.png`` (PNG bytes under another name).
    """
    if Path(path).suffix.lower() != ".png":
        raise ParameterError(f"{path}: the flow colour image is written as PNG; name it *.png")
    rgb = flow_to_color(flow, max_magnitude=max_magnitude)
    with atomic_file(path, overwrite=overwrite) as tmp:
        encode_png(np.ascontiguousarray(rgb[..., ::-1]), tmp)  # OpenCV writes BGR
    return Path(path)
