"""Shared input guards: shape contracts and dtype conversion with uniform messages."""

from __future__ import annotations

from collections.abc import Sequence as Seq

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import ParameterError, ParameterTypeError, ShapeError

__all__ = ["as_float32", "check_output_buffer", "check_same_shape", "check_shape"]


def check_shape(array: np.ndarray, expected: Seq[object], *, name: str, hint: str = "") -> None:
    """Check ``array.shape`` against a symbolic shape.

    Parameters
    ----------
    array : ndarray
        Array to check.
    expected : sequence of int or str
        Integers must match exactly; strings are free symbolic dimensions (``"T"``).
        ``"*"`` as the first entry matches any number of leading dimensions.
    name : str
        Parameter name used in the error message.
    hint : str, optional
        Appended to the message.

    Raises
    ------
    ShapeError
        If the number of dimensions or a fixed dimension differs.
    """
    shape = tuple(array.shape)
    exp = list(expected)
    if exp and exp[0] == "*":
        tail = exp[1:]
        ok = len(shape) >= len(tail) and _dims_match(shape[len(shape) - len(tail) :], tail)
    else:
        ok = len(shape) == len(exp) and _dims_match(shape, exp)
    if not ok:
        raise ShapeError(name, tuple(exp), shape, hint)


def _dims_match(shape: tuple[int, ...], expected: Seq[object]) -> bool:
    return all(not isinstance(e, int) or s == e for s, e in zip(shape, expected, strict=True))


def check_same_shape(a: np.ndarray, b: np.ndarray, *, names: tuple[str, str]) -> None:
    """Raise :class:`ShapeError` unless ``a`` and ``b`` have the same shape."""
    if a.shape != b.shape:
        raise ShapeError(
            names[1], a.shape, b.shape, f"It must match the shape of {names[0]} {a.shape}"
        )


def check_output_buffer(out: object, shape: tuple[int, ...], *, name: str) -> None:
    """Refuse an output buffer that a kernel could not write through safely: not a
    C-contiguous, writeable float32 array of exactly ``shape``.

    Raises
    ------
    ParameterTypeError
        If ``out`` is not a float32 ndarray.
    ShapeError
        If its shape differs.
    ParameterError
        If it is not C-contiguous or not writeable.
    """
    if not isinstance(out, np.ndarray) or out.dtype != np.float32:
        what = out.dtype if isinstance(out, np.ndarray) else type(out).__name__
        raise ParameterTypeError(f"{name} must be a float32 ndarray, got {what}")
    if out.shape != tuple(shape):
        raise ShapeError(name, tuple(shape), out.shape)
    if not (out.flags.c_contiguous and out.flags.writeable):
        raise ParameterError(f"{name} must be a C-contiguous, writeable array")


def as_float32(array: ArrayLike, *, name: str) -> NDArray[np.float32]:
    """Return a C-contiguous float32 copy-or-view of ``array``.

    Raises
    ------
    ParameterTypeError
        If ``array`` is not numeric (e.g. object or string arrays); a ``TypeError``.
    """
    arr = np.asarray(array)
    if arr.dtype.kind not in "fiub":
        raise ParameterTypeError(f"{name} must be a numeric array, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float32)
