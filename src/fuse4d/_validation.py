"""Shared input guards: shape contracts and dtype conversion with uniform messages."""

from __future__ import annotations

from collections.abc import Sequence as Seq

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import ShapeError

__all__ = ["as_float32", "check_same_shape", "check_shape"]


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


def as_float32(array: ArrayLike, *, name: str) -> NDArray[np.float32]:
    """Return a C-contiguous float32 copy-or-view of ``array``.

    Raises
    ------
    TypeError
        If ``array`` is not numeric (e.g. object or string arrays).
    """
    arr = np.asarray(array)
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"{name} must be a numeric array, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float32)
