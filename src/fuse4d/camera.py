"""Pinhole camera model: intrinsics, back-projection (paper Eq. 2) and projection.

Conventions: pixel centres at integer coordinates, 0-based; ``u`` = column, ``v`` = row;
camera frame X right, Y down, Z forward; lengths in millimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_float32, check_shape
from .errors import ParameterError, ParameterTypeError

#: The largest and the smallest normal magnitude of float32, in which the kernels compute.
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_FLOAT32_TINY = float(np.finfo(np.float32).tiny)

__all__ = ["Intrinsics", "depth_to_points", "points_to_depth", "project_points"]


def _as_float64(values: ArrayLike, *, name: str) -> NDArray[np.float64]:
    """``values`` as a float64 array; a ParameterTypeError naming ``name`` where they are not
    numbers (a word raised numpy's ValueError)."""
    arr = np.asarray(values)
    if arr.dtype.kind not in "fiub":
        raise ParameterTypeError(f"{name} must hold numbers, got dtype {arr.dtype}")
    return arr.astype(np.float64)


#: The entries of a pinhole camera matrix that are not parameters: (row, column) -> value.
_MATRIX_FIXED = {(0, 1): 0.0, (1, 0): 0.0, (2, 0): 0.0, (2, 1): 0.0, (2, 2): 1.0}


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics (immutable).

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels (paper :math:`f_x, f_y`). Must be finite and > 0.
    cx, cy : float
        Principal point in pixels (paper :math:`u_0, v_0`); ``cx`` is a column, ``cy`` a row.
    width, height : int
        Image size in pixels.

    Examples
    --------
    >>> K = Intrinsics(fx=1000.0, fy=1000.0, cx=299.5, cy=299.5, width=600, height=600)
    >>> float(K.matrix[0, 2])
    299.5
    >>> K.scaled(0.5).fx
    500.0
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ParameterTypeError(
                    f"Intrinsics.{name} must be a number, got {value!r}"
                ) from None
            if not math.isfinite(value):
                raise ParameterError(f"Intrinsics.{name} must be finite, got {value}")
            if abs(value) > _FLOAT32_MAX:  # the kernels compute in float32: it became inf
                raise ParameterError(
                    f"Intrinsics.{name} must be at most {_FLOAT32_MAX:.3g} pixels in size "
                    f"(float32), got {value}"
                )
            object.__setattr__(self, name, value)
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if value <= 0:
                raise ParameterError(f"Intrinsics.{name} must be > 0 pixels, got {value}")
            if value < _FLOAT32_TINY:  # 0 in float32: every point at infinity, no error
                raise ParameterError(
                    f"Intrinsics.{name} must be at least {_FLOAT32_TINY:.3g} pixels "
                    f"(float32), got {value}"
                )
        for name in ("width", "height"):
            value = getattr(self, name)
            try:
                whole = not isinstance(value, bool) and int(value) == value and int(value) >= 1
            except (TypeError, ValueError, OverflowError):
                whole = False
            if not whole:
                raise ParameterError(f"Intrinsics.{name} must be a positive integer, got {value!r}")
            object.__setattr__(self, name, int(value))

    @classmethod
    def from_array(cls, values: ArrayLike, *, width: int, height: int) -> Intrinsics:
        """Build from ``[fx, fy, cx, cy]`` (the npz ``intrinsics`` key).

        Raises
        ------
        ValueError
            If ``values`` does not hold exactly 4 numbers.
        """
        arr = _as_float64(values, name="intrinsics").ravel()
        if arr.size != 4:
            raise ParameterError(
                f"intrinsics must be [fx, fy, cx, cy] (4 numbers), got {arr.size} values"
            )
        return cls(*(float(x) for x in arr), width=width, height=height)

    @classmethod
    def from_matrix(cls, matrix: ArrayLike, *, width: int, height: int) -> Intrinsics:
        """Build from a 3x3 camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.

        Raises
        ------
        ParameterError
            If the matrix is not 3x3, or an entry other than fx, fy, cx, cy differs from
            that form (a skew ``K[0, 1]``, a ``K[2, 2]`` other than 1): fuse4d's pinhole model
            has no skew, and ignoring them would give the wrong points.
        """
        mat = _as_float64(matrix, name="camera matrix")
        if mat.shape != (3, 3):
            raise ParameterError(f"camera matrix must be 3x3, got shape {mat.shape}")
        for (row, col), want in _MATRIX_FIXED.items():
            if mat[row, col] != want:
                hint = (
                    "divide the matrix by K[2,2]"
                    if (row, col) == (2, 2)
                    else "fuse4d's pinhole model is [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "
                    "without skew"
                )
                raise ParameterError(
                    f"camera matrix entry K[{row},{col}] must be {want:g}, got "
                    f"{mat[row, col]:g} ({hint})"
                )
        return cls(mat[0, 0], mat[1, 1], mat[0, 2], mat[1, 2], width=width, height=height)

    def as_array(self) -> NDArray[np.float64]:
        """``[fx, fy, cx, cy]`` as float64."""
        return np.array([self.fx, self.fy, self.cx, self.cy], dtype=np.float64)

    @property
    def matrix(self) -> NDArray[np.float64]:
        """The 3x3 camera matrix K."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)``."""
        return (self.height, self.width)

    def scaled(self, factor: float) -> Intrinsics:
        """Intrinsics of the image resized by ``factor`` (pixel-centre convention kept).

        Raises
        ------
        ParameterTypeError
            If ``factor`` is not a number.
        ParameterError
            If it is not finite and > 0, or the resized image would not be finite in size.
        """
        if isinstance(factor, bool) or not isinstance(factor, Real):
            raise ParameterTypeError(f"factor must be a number, got {factor!r}")
        f = float(factor)
        if not (math.isfinite(f) and f > 0):
            raise ParameterError(f"factor must be a finite number > 0, got {factor!r}")
        width, height = self.width * f, self.height * f
        if not (math.isfinite(width) and math.isfinite(height)):
            raise ParameterError(
                f"factor {factor!r} is too large for a {self.height}x{self.width} image"
            )
        return Intrinsics(
            fx=self.fx * f,
            fy=self.fy * f,
            cx=(self.cx + 0.5) * f - 0.5,
            cy=(self.cy + 0.5) * f - 0.5,
            width=max(1, round(width)),
            height=max(1, round(height)),
        )

    def to_dict(self) -> dict[str, float | int]:
        """Plain-dict form (JSON/TOML friendly)."""
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
        }


def check_intrinsics(intrinsics: object) -> Intrinsics:
    """``intrinsics`` itself where it is an :class:`Intrinsics`; else a
    :class:`~fuse4d.ParameterTypeError` saying how to make one (a tuple failed later as an
    AttributeError)."""
    if not isinstance(intrinsics, Intrinsics):
        raise ParameterTypeError(
            f"intrinsics must be a fuse4d.Intrinsics, got {type(intrinsics).__name__}; e.g. "
            "Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480) (px)"
        )
    return intrinsics


def depth_to_points(depth: ArrayLike, intrinsics: Intrinsics) -> NDArray[np.float32]:
    """Back-project depth to 3D points (paper Eq. 2).

    ``P[v, u] = D[v, u] * ((u - cx) / fx, (v - cy) / fy, 1)``.

    Parameters
    ----------
    depth : (..., H, W) ndarray
        Depth in mm along the optical axis; NaN (or <= 0, inf) = invalid.
    intrinsics : Intrinsics
        Camera; its ``width``/``height`` must match the last two axes.

    Returns
    -------
    points : (..., H, W, 3) ndarray of float32
        X, Y, Z in mm; NaN where depth is invalid.

    Examples
    --------
    >>> K = Intrinsics(fx=100.0, fy=100.0, cx=1.0, cy=1.0, width=3, height=3)
    >>> p = depth_to_points(np.full((3, 3), 500.0), K)
    >>> p[1, 2].tolist()
    [5.0, 0.0, 500.0]
    """
    check_intrinsics(intrinsics)
    d = as_float32(depth, name="depth")
    check_shape(
        d,
        ("*", intrinsics.height, intrinsics.width),
        name="depth",
        hint=f"the intrinsics say the image is {intrinsics.height}x{intrinsics.width} (HxW)",
    )
    from ._kernels.camera import _back_project_kernel  # numba loads on first use, not import

    u = (np.arange(intrinsics.width, dtype=np.float32) - np.float32(intrinsics.cx)) / np.float32(
        intrinsics.fx
    )
    v = (np.arange(intrinsics.height, dtype=np.float32) - np.float32(intrinsics.cy)) / np.float32(
        intrinsics.fy
    )
    points = np.empty((*d.shape, 3), dtype=np.float32)
    _back_project_kernel(
        d.reshape(-1, intrinsics.height, intrinsics.width),
        u,
        v,
        points.reshape(-1, intrinsics.height, intrinsics.width * 3),
    )
    return points


def points_to_depth(points: ArrayLike) -> NDArray[np.float32]:
    """Depth (Z component, mm) of a ``(..., 3)`` point map; NaN stays NaN."""
    p = as_float32(points, name="points")
    check_shape(p, ("*", 3), name="points")
    return np.ascontiguousarray(p[..., 2])


def project_points(
    points: ArrayLike, intrinsics: Intrinsics
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Project 3D points (mm) to continuous pixel coordinates.

    Parameters
    ----------
    points : (..., 3) ndarray
        X, Y, Z in mm, camera frame.
    intrinsics : Intrinsics

    Returns
    -------
    u, v : (...) ndarray of float32
        Column and row coordinates in pixels; NaN where Z is not > 0.
    """
    check_intrinsics(intrinsics)
    p = _as_float64(points, name="points")
    check_shape(p, ("*", 3), name="points")
    z = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        good = z > 0
        u = np.where(good, intrinsics.fx * p[..., 0] / z + intrinsics.cx, np.nan)
        v = np.where(good, intrinsics.fy * p[..., 1] / z + intrinsics.cy, np.nan)
    return u.astype(np.float32), v.astype(np.float32)
