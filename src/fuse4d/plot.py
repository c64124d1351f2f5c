"""Figures (matplotlib, imported lazily; no algorithm code depends on this module).

Uses the object-oriented :class:`matplotlib.figure.Figure` API (no pyplot, no global state,
no GUI backend), so it works headless and in threads.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from .errors import ParameterError
from .io._atomic import atomic_file

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["plot_roughness_map", "save_figure"]


def plot_roughness_map(
    roughness_map: ArrayLike,
    *,
    vmax: float = 10.0,
    vmin: float = 0.0,
    title: str = "",
    cmap: str = "viridis",
    intensity: ArrayLike | None = None,
) -> Figure:
    """Per-pixel roughness Pi rendered on the frame with a *fixed* colour scale (EVALUATION §1).

    Use the same ``vmin``/``vmax`` for every method on one object so that maps are comparable.

    Parameters
    ----------
    roughness_map : (H, W) ndarray
        Pi in mm (:func:`fuse4d.metrics.roughness` of one frame); NaN drawn transparent.
    vmax, vmin : float, optional
        Colour-scale limits in mm (fixed per object).
    title : str, optional
        Axes title.
    cmap : str, optional
        Matplotlib colour map.
    intensity : (H, W) ndarray, optional
        Intensity frame in [0, 1] drawn in gray underneath (visible where Pi is NaN).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    pi = np.asarray(roughness_map, dtype=np.float32)
    if pi.ndim != 2:
        raise ParameterError(f"roughness_map must be (H, W), got shape {pi.shape}")
    if not vmax > vmin:
        raise ParameterError(f"vmax must exceed vmin, got vmin={vmin}, vmax={vmax}")
    h, w = pi.shape
    fig = Figure(figsize=(5.0 * w / max(h, w) + 1.2, 5.0 * h / max(h, w)), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    if intensity is not None:
        ax.imshow(np.asarray(intensity), cmap="gray", vmin=0.0, vmax=1.0, interpolation="nearest")
    image = ax.imshow(
        np.ma.masked_invalid(pi), cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest"
    )
    fig.colorbar(image, ax=ax, label="roughness Π (mm)")
    ax.set_axis_off()
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig


def save_figure(
    fig: Figure, path: str | PathLike[str], *, overwrite: bool = False, dpi: int = 150
) -> Path:
    """Save a figure atomically (temporary file in the same folder, then rename).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or PathLike
        Output file; the format follows the suffix (``.png``, ``.pdf``, ``.svg``).
    overwrite : bool, optional
        Replace an existing file. Default False.
    dpi : int, optional
        Resolution for raster formats.

    Returns
    -------
    Path

    Raises
    ------
    OutputExistsError
        If ``path`` exists and ``overwrite`` is False.
    """
    out = Path(path)
    with atomic_file(out, overwrite=overwrite) as tmp:
        fig.savefig(tmp, dpi=dpi, format=out.suffix.lstrip(".").lower() or "png")
    return out
