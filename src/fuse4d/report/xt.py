"""x–t slices: one image row (or column) stacked over time, accumulated frame by frame.

In an x–t slice a static surface is a vertical stripe of constant colour; temporal flicker
shows as speckle along time, and a trail (a value dragged along a motion) as a smear.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["MotionProfile", "XtSlice", "choose_line"]


class MotionProfile:
    """Per-row and per-column motion energy of a video, accumulated frame by frame.

    The energy of a row is the sum over its pixels and over time of ``|I_t - I_{t-1}|``
    (intensity, [0, 1]) plus ``min(|D_t - D_{t-1}| / 50 mm, 1)`` where both depths are valid.
    """

    def __init__(self, shape: tuple[int, int]) -> None:
        self.rows = np.zeros(shape[0], dtype=np.float64)
        self.cols = np.zeros(shape[1], dtype=np.float64)
        self._last: tuple[NDArray[np.float32], NDArray[np.float32]] | None = None

    def add(self, depth: NDArray[np.float32], intensity: NDArray[np.float32]) -> None:
        """Add one frame (depth mm, NaN invalid; intensity [0, 1]), in time order."""
        if self._last is not None:
            d0, i0 = self._last
            with np.errstate(invalid="ignore"):
                dd = np.abs(depth - d0) / np.float32(50.0)
            energy = np.abs(intensity - i0) + np.where(np.isfinite(dd), np.minimum(dd, 1.0), 0)
            self.rows += energy.sum(axis=1)
            self.cols += energy.sum(axis=0)
        self._last = (depth, intensity)


def choose_line(energy: ArrayLike, *, margin: int = 2, smooth: int = 5) -> int:
    """Index of the row (or column) with the most motion energy.

    Parameters
    ----------
    energy : (N,) array
        :attr:`MotionProfile.rows` or ``.cols``.
    margin : int, optional
        Lines this close to the border are not chosen.
    smooth : int, optional
        Width of the box filter applied first (so one noisy line does not win).

    Returns
    -------
    int
        The chosen index; the middle line when there is no motion at all.
    """
    e = np.asarray(energy, dtype=np.float64)
    n = e.size
    if n == 0:
        raise ValueError("energy is empty")
    kernel = np.ones(max(1, smooth)) / max(1, smooth)
    s = np.convolve(e, kernel, mode="same")
    lo, hi = min(margin, n - 1), max(n - margin, min(margin, n - 1) + 1)
    window = s[lo:hi]
    if not np.any(window > 0):
        return n // 2
    ties = np.flatnonzero(window >= window.max() * (1.0 - 1e-12))
    return lo + int(ties[np.argmax(e[lo + ties])])


class XtSlice:
    """One row (``axis="row"``) or column (``axis="col"``) of every frame, stacked over time.

    Memory is one line per frame (W or H float32 values), never a whole frame.

    Parameters
    ----------
    index : int
        The row or column index.
    axis : {"row", "col"}, optional
        Which kind of line.
    """

    def __init__(self, index: int, *, axis: str = "row") -> None:
        if axis not in ("row", "col"):
            raise ValueError(f"axis must be 'row' or 'col', got {axis!r}")
        self.index = int(index)
        self.axis = axis
        self._lines: list[NDArray[np.float32]] = []

    def add(self, frame: NDArray[np.floating]) -> None:
        """Append the line of one (H, W) frame."""
        line = frame[self.index] if self.axis == "row" else frame[:, self.index]
        self._lines.append(np.array(line, dtype=np.float32))

    def image(self) -> NDArray[np.float32]:
        """(T, N) array: time down, position across (N = W for a row, H for a column)."""
        if not self._lines:
            return np.zeros((0, 0), dtype=np.float32)
        return np.stack(self._lines)
