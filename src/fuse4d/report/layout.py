"""The comparison video's frame layout (OpenCV drawing; no per-pixel Python).

::

    frame t of 0-(T-1) (input frame t + A, for a run of part A:B of the input)
    raw depth          | fused depth          | |raw - fused|
    [depth colour bar, fixed range]           | [difference colour bar]
    raw, normal-shaded | fused, normal-shaded | support (frames fused)
                                              | [support colour bar]
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .render import colorize

__all__ = ["VideoLayout"]

#: Names and colours of the ``source`` codes 0-6 (:attr:`fuse4d.FusedFrame.source`,
#: ``fuse4d.holes.SOURCE_*``): the page's source map and the video's sixth panel.
SOURCE_STYLE = (
    ("no depth", "#000000"),
    ("measured", "#b4b4b4"),
    ("fused", "#3c9a5a"),
    ("hole, from time", "#f0a02a"),
    ("hole, in space", "#2a78e6"),
    ("rejected (ToF)", "#e62a2a"),
    ("outside the field of view", "#4b3c78"),
)
#: The same colours as RGB, and short names for the video's legend.
SOURCE_RGB = np.array(
    [[int(c[i : i + 2], 16) for i in (1, 3, 5)] for _, c in SOURCE_STYLE], dtype=np.uint8
)
SOURCE_SHORT = ("no depth", "measured", "fused", "from time", "in space", "rejected", "outside")


def source_rgb(codes: NDArray[np.integer]) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 RGB of a frame's ``source`` codes (clipped to 0-6)."""
    return SOURCE_RGB[np.clip(np.asarray(codes), 0, len(SOURCE_RGB) - 1)]


_BG = (16, 16, 20)
_FG = (235, 235, 235)
_FONT = 0  # cv2.FONT_HERSHEY_SIMPLEX


def _nice(value: float) -> str:
    return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"


class VideoLayout:
    """Compose the six panels of one frame into a single RGB image with labels.

    Parameters
    ----------
    shape : (int, int)
        Input frame shape (H, W).
    depth_range : (float, float)
        Fixed depth colour range (mm).
    diff_max : float
        Upper end of the |raw - fused| colour range (mm).
    support_max : float
        Upper end of the support colour range (frames).
    panel_width : (int, int), optional
        Panels are scaled (nearest neighbour up, area down) to a width in this range (px).
    show_support : bool, optional
        Draw the support colour bar (False when the fused result stores no support).
    show_source : bool, optional
        Without support: the sixth panel shows where each value comes from (the
        ``source`` codes, :func:`source_rgb`) with their legend, instead of "not stored".
    """

    def __init__(
        self,
        shape: tuple[int, int],
        *,
        depth_range: tuple[float, float],
        diff_max: float,
        support_max: float,
        panel_width: tuple[int, int] = (300, 400),
        show_support: bool = True,
        show_source: bool = False,
    ) -> None:
        h, w = shape
        lo, hi = panel_width
        if w < lo:
            self.scale = float(math.ceil(lo / w))
        elif w > hi:
            self.scale = hi / w
        else:
            self.scale = 1.0
        self.pw = max(2, round(w * self.scale))
        self.ph = max(2, round(h * self.scale))
        self.depth_range = depth_range
        self.diff_max = diff_max
        self.support_max = max(support_max, 1.0)
        self.show_support = show_support
        self.show_source = show_source and not show_support
        self.gap = 6
        self.title_h = 22
        self.bar_h = 36
        self.header_h = 28
        # an empty band under the panels: a browser's video controls cover the bottom ~45 px
        # of the frame (they hid the support colour bar and the panels' lower edge)
        self.footer_h = 72  # two rows of controls where the video is narrow
        self.width = 3 * self.pw + 4 * self.gap
        self.height = self.header_h + 2 * (self.title_h + self.ph + self.bar_h) + self.footer_h
        self.width += self.width % 2
        self.height += self.height % 2
        self._template = self._make_template()

    def _x(self, col: int) -> int:
        return self.gap + col * (self.pw + self.gap)

    def _y(self, row: int) -> int:
        return self.header_h + row * (self.title_h + self.ph + self.bar_h) + self.title_h

    def _text(self, img: NDArray[np.uint8], text: str, x: int, y: int, size: float = 0.45) -> None:
        import cv2

        cv2.putText(img, text, (x, y), _FONT, size, _FG, 1, cv2.LINE_AA)

    def _bar(
        self,
        img: NDArray[np.uint8],
        x: int,
        y: int,
        width: int,
        vmin: float,
        vmax: float,
        cmap: str,
        unit: str,
    ) -> None:
        ramp = np.linspace(vmin, vmax, width)[None, :].repeat(10, axis=0)
        img[y + 4 : y + 14, x : x + width] = colorize(ramp, vmin=vmin, vmax=vmax, cmap=cmap)
        import cv2

        for frac in (0.0, 0.5, 1.0):
            label = _nice(vmin + frac * (vmax - vmin))
            if frac == 1.0:
                label += f" {unit}"
            (tw, _), _ = cv2.getTextSize(label, _FONT, 0.4, 1)
            tx = x + int(frac * (width - 1)) - int(frac * tw)  # left, centred, right-aligned
            self._text(img, label, max(x, tx), y + 30, 0.4)

    def _make_template(self) -> NDArray[np.uint8]:
        img = np.empty((self.height, self.width, 3), dtype=np.uint8)
        img[:] = _BG
        sixth = "source of each value" if self.show_source else "support (frames fused)"
        titles = (
            ("raw depth", "fused depth", "|raw - fused|"),
            ("raw, normal-shaded", "fused, normal-shaded", sixth),
        )
        for row, names in enumerate(titles):
            for col, name in enumerate(names):
                self._text(img, name, self._x(col) + 2, self._y(row) - 6, 0.5)
        by = self._y(0) + self.ph
        lo, hi = self.depth_range
        self._bar(img, self._x(0), by, 2 * self.pw + self.gap, lo, hi, "turbo", "mm")
        self._bar(img, self._x(2), by, self.pw, 0.0, self.diff_max, "magma", "mm")
        if self.show_support:
            by = self._y(1) + self.ph
            self._bar(img, self._x(2), by, self.pw, 0.0, self.support_max, "viridis", "frames")
        elif self.show_source:
            self._source_legend(img, self._x(2), self._y(1) + self.ph)
        return img

    def _source_legend(self, img: NDArray[np.uint8], x: int, y: int) -> None:
        """The source codes' colours and short names, in two rows under the panel."""
        per_row = (len(SOURCE_SHORT) + 1) // 2
        step = self.pw // per_row
        for k, name in enumerate(SOURCE_SHORT):
            row, col = divmod(k, per_row)
            bx, by = x + col * step, y + 5 + 15 * row
            img[by : by + 9, bx : bx + 9] = SOURCE_RGB[k]
            self._text(img, name, bx + 12, by + 9, 0.33)

    def fit_values(self, values: NDArray[np.floating]) -> NDArray[np.float32]:
        """A scalar map (H, W) resampled (nearest neighbour) to the panel size.

        Colour-mapping after this is cheaper when panels are smaller than the frames.
        """
        import cv2

        v = np.asarray(values, dtype=np.float32)
        if v.shape == (self.ph, self.pw):
            return v
        return cv2.resize(v, (self.pw, self.ph), interpolation=cv2.INTER_NEAREST)

    def _fit(self, panel: NDArray[np.uint8]) -> NDArray[np.uint8]:
        import cv2

        if panel.shape[:2] == (self.ph, self.pw):
            return panel
        interp = cv2.INTER_NEAREST if self.scale > 1 else cv2.INTER_AREA
        return cv2.resize(panel, (self.pw, self.ph), interpolation=interp)

    def compose(
        self,
        index: int,
        total: int,
        panels: tuple[NDArray[np.uint8], ...],
        *,
        label: str = "",
        input_frame: int | None = None,
    ) -> NDArray[np.uint8]:
        """One video frame from six (H, W, 3) uint8 panels (row-major order, see module doc).

        Panels of another size than the panel size are resampled. A panel may be None
        (drawn as "not stored").

        Parameters
        ----------
        index : int
            The frame's number, 0-based (as the report's ``frame`` and ``--frame``).
        total : int
            Frames in the video.
        panels : tuple of six (H, W, 3) uint8 ndarray or None
            The panels.
        label : str, optional
            Text after the frame number (the input's name).
        input_frame : int, optional
            The input's own frame number where it differs from ``index`` (a run of part of
            the input, ``--frames``).
        """
        img = self._template.copy()
        head = f"frame {index} of 0-{total - 1}"
        if input_frame is not None:
            head += f" (input frame {input_frame})"
        self._text(img, f"{head}   {label}", self.gap, 19, 0.55)
        for k, panel in enumerate(panels):
            row, col = divmod(k, 3)
            x, y = self._x(col), self._y(row)
            if panel is None:
                self._text(img, "not stored in the fused input", x + 10, y + self.ph // 2, 0.5)
                continue
            img[y : y + self.ph, x : x + self.pw] = self._fit(panel)
        return img
