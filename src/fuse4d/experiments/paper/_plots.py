"""One matplotlib style for every figure of the paper experiments.

Figures are written at screen size (about 1000 px wide, 100 dpi) with the Agg backend. Every
method has one colour and marker across all figures; legends use the paper's method names
(:data:`~._scenes.LABELS`).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from ._scenes import LABELS

__all__ = ["STYLE", "figure", "label", "method_style"]

#: rcParams applied to every figure.
STYLE: dict[str, Any] = {
    "figure.dpi": 100,
    "savefig.dpi": 100,
    "font.size": 10,
    "axes.titlesize": 11,
    "axes.labelsize": 10,
    "legend.fontsize": 8.5,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "lines.linewidth": 1.6,
    "lines.markersize": 5,
}

_STYLES: dict[str, dict[str, Any]] = {
    "raw": {"color": "#7f7f7f", "marker": "x", "linestyle": "--"},
    "adgf": {"color": "#bcbd22", "marker": "v"},
    "adbf": {"color": "#17becf", "marker": "^"},
    "guided": {"color": "#2ca02c", "marker": "s"},
    "dnbf": {"color": "#9467bd", "marker": "D"},
    "ta": {"color": "#8c564b", "marker": "P"},
    "adjbf": {"color": "#1f77b4", "marker": "o"},
    "stmf": {"color": "#e377c2", "marker": "*"},
    "kinectfusion": {"color": "#ff7f0e", "marker": "h"},
    "ed": {"color": "#000000", "marker": "X"},
    "ours": {"color": "#d62728", "marker": "o", "linewidth": 2.6},
    "realsense": {"color": "#ff7f0e", "marker": "h"},
    "temporal-mean": {"color": "#8c564b", "marker": "P"},
}


def method_style(method: str) -> dict[str, Any]:
    """Line keywords (colour, marker, ...) of ``method``, the same in every figure."""
    return dict(_STYLES.get(method, {"color": "#333333", "marker": "."}))


def label(method: str) -> str:
    """The paper's name of ``method``."""
    return LABELS.get(method, method)


@contextmanager
def figure(
    path: Path,
    ncols: int = 1,
    nrows: int = 1,
    *,
    size: tuple[float, float] | None = None,
    **kwargs: Any,
) -> Iterator[tuple[Figure, Any]]:
    """Create a styled figure, yield ``(fig, axes)``, then save it to ``path`` and close it."""
    with plt.rc_context(STYLE):
        w, h = size or (min(5.2 * ncols, 15.0), 4.2 * nrows)
        fig, axes = plt.subplots(
            nrows, ncols, figsize=(w, h), squeeze=False, layout="constrained", **kwargs
        )
        try:
            yield fig, axes if axes.size > 1 else axes[0, 0]
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.stem}.tmp.png")
            fig.savefig(tmp)
            tmp.replace(path)
        finally:
            plt.close(fig)
