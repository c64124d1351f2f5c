"""The report's static figures (matplotlib's object API, no pyplot), returned as PNG bytes."""

from __future__ import annotations

import io
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .layout import SOURCE_STYLE

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "cloud_figure",
    "flicker_figure",
    "png_bytes",
    "regions_figure",
    "roughness_figure",
    "support_figure",
    "timeseries_figure",
    "xt_figure",
]

#: Colour of each method in plots (raw gray, fused blue, others from tab10).
_COLORS = {"raw": "#7f7f7f", "fused": "#1f77b4"}
_OTHERS = ("#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2")


def method_color(name: str, order: int) -> str:
    """Plot colour of a method (stable across figures)."""
    return _COLORS.get(name, _OTHERS[order % len(_OTHERS)])


def png_bytes(fig: Figure, *, dpi: int = 100) -> bytes:
    """Render a figure to PNG bytes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _figure(width: float, height: float) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100, layout="constrained")


def _masked(a: NDArray[np.floating]) -> np.ma.MaskedArray:
    return np.ma.masked_invalid(np.asarray(a, dtype=np.float32))


def _cmap(name: str):
    import matplotlib

    return matplotlib.colormaps[name].with_extremes(bad="#303030")


def xt_figure(
    slices: dict[str, NDArray[np.float32]],
    *,
    axis: str,
    index: int,
    vmin: float,
    vmax: float,
    change_range: float,
) -> bytes:
    """x–t slices of every method: depth (top) and frame-to-frame change (bottom).

    Parameters
    ----------
    slices : dict of str to (T, N) ndarray
        Depth (mm) of the chosen line over time, per method.
    axis : {"row", "col"}
        What the line is.
    index : int
        Its index.
    vmin, vmax : float
        Depth colour range (mm), the same for all methods.
    change_range : float
        Half range (mm) of the change ``D_t - D_{t-1}`` colour scale.
    """
    from matplotlib.ticker import MaxNLocator

    names = list(slices)
    t, n = next(iter(slices.values())).shape
    aspect = max(0.25, min(4.0, n / max(t, 1)))
    width = min(max(5.5 * len(names), 11.0), 18.0)
    height = 2 * width / len(names) / aspect + 1.2
    fig = _figure(width, min(height, 11.0))
    axes = fig.subplots(2, len(names), squeeze=False, sharex=True, sharey=True)
    pos = "column" if axis == "row" else "row"
    for j, name in enumerate(names):
        s = slices[name]
        im0 = axes[0, j].imshow(
            _masked(s),
            cmap=_cmap("turbo"),
            vmin=vmin,
            vmax=vmax,
            aspect="auto",
            interpolation="nearest",
        )
        change = np.full_like(s, np.nan)
        change[1:] = s[1:] - s[:-1]
        im1 = axes[1, j].imshow(
            _masked(change),
            cmap=_cmap("RdBu_r"),
            vmin=-change_range,
            vmax=change_range,
            aspect="auto",
            interpolation="nearest",
        )
        axes[0, j].set_title(name)
        axes[1, j].set_xlabel(f"{pos} (px)")
    for ax in axes.flat:
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # frames, not 2.5
    axes[0, 0].set_ylabel(f"frame (time ↓)\n{axis} {index}: depth")
    axes[1, 0].set_ylabel("frame\nchange D_t − D_t−1")
    fig.colorbar(im0, ax=axes[0, :].tolist(), label="depth (mm)", shrink=0.9)
    fig.colorbar(im1, ax=axes[1, :].tolist(), label="change (mm)", shrink=0.9)
    return png_bytes(fig)


def flicker_figure(
    std_maps: dict[str, NDArray[np.float32]],
    static: NDArray[np.bool_],
    *,
    vmax: float,
) -> bytes:
    """Per-pixel temporal std maps (same scale) and their histograms on static pixels."""
    names = list(std_maps)
    fig = _figure(3.6 * len(names) + 4.5, 3.6)
    grid = fig.add_gridspec(1, len(names) + 1, width_ratios=[1.0] * len(names) + [1.3])
    image = None
    for j, name in enumerate(names):
        ax = fig.add_subplot(grid[0, j])
        shown = np.where(static, std_maps[name], np.nan)
        image = ax.imshow(_masked(shown), cmap=_cmap("magma"), vmin=0.0, vmax=vmax)
        ax.set_title(f"{name}: temporal std")
        ax.set_axis_off()
    if image is not None:
        fig.colorbar(image, ax=fig.axes, label="std over time (mm)", shrink=0.85)
    ax = fig.add_subplot(grid[0, -1])
    edges = np.linspace(0.0, vmax, 61)
    drawn = False
    for j, name in enumerate(names):
        vals = std_maps[name][static & np.isfinite(std_maps[name])]
        if vals.size:
            drawn = True
            ax.hist(
                np.minimum(vals, vmax),
                bins=edges,
                histtype="step",
                linewidth=1.6,
                color=method_color(name, j),
                label=f"{name} (mean {vals.mean(dtype=np.float64):.3g}, median {np.median(vals):.3g} mm)",
            )
    ax.set_xlabel("temporal std (mm), static pixels")
    ax.set_ylabel("pixels")
    if drawn:
        ax.legend(fontsize=8)
    else:  # one frame, or no pixel static and valid throughout
        ax.text(0.5, 0.5, "no static pixels", ha="center", va="center", transform=ax.transAxes)
    return png_bytes(fig)


def timeseries_figure(
    series: dict[str, NDArray[np.float32]],
    pixels: list[tuple[int, int, str]],
) -> bytes:
    """Depth over time at a few pixels, every method in one axes per pixel.

    Parameters
    ----------
    series : dict of str to (T, P) ndarray
        Depth (mm) per method, one column per pixel.
    pixels : list of (row, col, label)
        The pixels.
    """
    from matplotlib.ticker import MaxNLocator

    fig = _figure(max(6.0, 3.6 * len(pixels)), 2.8)
    axes = fig.subplots(1, len(pixels), squeeze=False)[0]
    for k, (r, c, label) in enumerate(pixels):
        ax = axes[k]
        for j, (name, values) in enumerate(series.items()):
            ax.plot(
                values[:, k],
                color=method_color(name, j),
                linewidth=2.0 if name == "fused" else 1,
                label=name,
            )
        # two lines: "busiest on the x–t row" ran past the figure's right edge
        ax.set_title(f"{k + 1}: pixel (row {r}, col {c})\n{label}", fontsize=9)
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        ax.set_xlabel("frame")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # frames, not 2.5
        ax.set_ylabel("depth (mm)")
    axes[0].legend(fontsize=8)
    return png_bytes(fig)


def roughness_figure(
    maps: dict[str, NDArray[np.float32]],
    hist: dict[str, NDArray[np.int64]],
    edges: NDArray[np.float64],
    *,
    frame: int,
    means: dict[str, float] | None = None,
) -> bytes:
    """Roughness maps (Eq. 7) of one frame on a fixed scale and histograms over all frames.

    Parameters
    ----------
    maps : dict of str to (H, W) ndarray
        Roughness Pi (mm) of frame ``frame`` per method.
    hist : dict of str to (B,) ndarray
        Histogram counts per method over ``edges`` (the last bin holds the overflow).
    edges : (B + 1,) ndarray
        Bin edges (mm); the maps' colour scale is 0 to ``edges[-1]``.
    frame : int
        The maps' frame (0-based), for the titles.
    means : dict of str to float, optional
        Roughness mean (mm) per method, drawn as a dotted line (the metrics table's
        ``roughness_mean``: mean over frames of the frame means); NaN: not drawn.
    """
    names = list(maps)
    vmax = float(edges[-1])
    fig = _figure(3.6 * len(names) + 4.5, 3.6)
    grid = fig.add_gridspec(1, len(names) + 1, width_ratios=[1.0] * len(names) + [1.3])
    image = None
    for j, name in enumerate(names):
        ax = fig.add_subplot(grid[0, j])
        image = ax.imshow(_masked(maps[name]), cmap=_cmap("viridis"), vmin=0.0, vmax=vmax)
        ax.set_title(f"{name}: Π, frame {frame}")
        ax.set_axis_off()
    if image is not None:
        fig.colorbar(image, ax=fig.axes, label="roughness Π (mm)", shrink=0.85)
    ax = fig.add_subplot(grid[0, -1])
    for j, name in enumerate(names):
        # the table's mean (of the frame means), not one from the clipped, binned pixels
        mean = (means or {}).get(name, float("nan"))
        label = name if not np.isfinite(mean) else f"{name} (mean {mean:.4g} mm)"
        ax.stairs(hist[name], edges, color=method_color(name, j), linewidth=1.6, label=label)
        if np.isfinite(mean):
            ax.axvline(mean, color=method_color(name, j), linestyle=":", linewidth=1)
    ax.set_xlabel("roughness Π (mm), ROI pixels of all frames")
    if any(hist[name].any() for name in names):
        ax.set_ylabel("pixels (log scale)")
        ax.set_yscale("log")
    else:  # no ROI pixel in any frame (an empty result): a log axis has nothing to show
        ax.set_ylabel("pixels")
        ax.text(0.5, 0.5, "no ROI pixels", ha="center", va="center", transform=ax.transAxes)
    ax.legend(fontsize=8)
    return png_bytes(fig)


def support_figure(
    support_mean: NDArray[np.float32] | None,
    filled_fraction: NDArray[np.float32] | None,
    support_frame: NDArray[np.float32] | None,
    *,
    frame: int,
    max_support: float,
    source_frame: NDArray[np.uint8] | None = None,
) -> bytes:
    """Support (frames fused per pixel) maps, and where frame ``frame``'s values come from
    (``source_frame``, :attr:`fuse4d.FusedFrame.source` codes) or, without it, the Eq. 6
    hole-filling map."""
    panels = [
        (support_frame, f"support, frame {frame}", "viridis", max_support, "frames"),
        (support_mean, "support, mean over frames", "viridis", max_support, "frames"),
        (filled_fraction, "hole-filled (Eq. 6), fraction of frames", "inferno", 1.0, "fraction"),
    ]
    if source_frame is not None:
        panels[2] = (source_frame, "source", "", 0.0, "")
    # only what the fused result stores (a frame folder has no support maps: two empty
    # "not stored" panels filled the row)
    shown = [p for p in panels if p[0] is not None] or [panels[0]]
    fig = _figure(11.5 * len(shown) / 3 + 0.8 * (len(shown) < 3), 3.6)
    axes = fig.subplots(1, len(shown), squeeze=False)[0]
    for ax, (data, title, cmap, vmax, unit) in zip(axes, shown, strict=True):
        ax.set_axis_off()
        ax.set_title(title, fontsize=10)
        if data is source_frame and source_frame is not None:
            _source_panel(ax, source_frame, frame)
            continue
        if data is None:
            ax.text(0.5, 0.5, "not stored\nin the fused result", ha="center", va="center")
            continue
        im = ax.imshow(_masked(data), cmap=_cmap(cmap), vmin=0.0, vmax=max(vmax, 1e-6))
        fig.colorbar(im, ax=ax, label=unit, shrink=0.85)
    return png_bytes(fig)


def _source_panel(ax: Any, source: NDArray[np.uint8], frame: int) -> None:
    """Categorical map of one frame's source codes with a legend of the codes present."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    codes = np.clip(np.asarray(source), 0, len(SOURCE_STYLE) - 1)
    cmap = ListedColormap([c for _, c in SOURCE_STYLE])
    ax.imshow(codes, cmap=cmap, vmin=-0.5, vmax=len(SOURCE_STYLE) - 0.5, interpolation="nearest")
    ax.set_title(f"source, frame {frame}", fontsize=10)
    total = codes.size
    handles = [
        Patch(color=color, label=f"{name} {100 * np.count_nonzero(codes == k) / total:.1f} %")
        for k, (name, color) in enumerate(SOURCE_STYLE)
        if np.any(codes == k)
    ]
    ax.legend(
        handles=handles, loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=7, frameon=False
    )


def cloud_figure(renders: dict[str, NDArray[np.uint8]], *, frame: int) -> bytes:
    """Side-by-side point-cloud renders (already rasterised) with titles."""
    names = list(renders)
    h, w = next(iter(renders.values())).shape[:2]
    fig = _figure(4.2 * len(names), 4.2 * h / w + 0.4)
    axes = fig.subplots(1, len(names), squeeze=False)[0]
    for ax, name in zip(axes, names, strict=True):
        ax.imshow(renders[name], interpolation="lanczos")
        ax.set_title(f"{name}, frame {frame}")
        ax.set_axis_off()
    return png_bytes(fig)


def regions_figure(
    intensity: NDArray[np.float32],
    static: NDArray[np.bool_],
    planes: list[NDArray[np.bool_]],
    *,
    line_axis: str,
    line: int,
    pixels: list[tuple[int, int, str]],
    roi: tuple[int, int, int, int] | None,
    roughness_roi: NDArray[np.bool_] | None = None,
) -> bytes:
    """Where the numbers come from: roughness ROI, static pixels, plane regions, x–t line,
    picked pixels."""
    h, w = intensity.shape
    fig = _figure(6.4, 6.4 * h / w + 0.3)
    ax = fig.add_subplot(1, 1, 1)
    gray = np.clip(np.nan_to_num(np.asarray(intensity, dtype=np.float32)), 0, 1)
    rgb = np.repeat(0.25 + 0.6 * gray[..., None], 3, axis=-1)
    if roughness_roi is not None:
        rgb[roughness_roi] = 0.7 * rgb[roughness_roi] + 0.3 * np.array([0.15, 0.35, 0.95])
    rgb[static] = 0.55 * rgb[static] + 0.45 * np.array([0.1, 0.8, 0.2])
    ax.imshow(rgb, interpolation="nearest")
    import cv2

    for k, plane_mask in enumerate(planes):
        # outline of the region (closed for display: outlier pixels inside are not drawn)
        mask = cv2.morphologyEx(
            plane_mask.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((9, 9), np.uint8)
        ).astype(bool)
        if mask.any():
            ax.contour(
                mask.astype(np.float32), levels=[0.5], colors=[_OTHERS[k % 6]], linewidths=1.5
            )
    if line_axis == "row":
        ax.axhline(line, color="red", linewidth=1.2)
    else:
        ax.axvline(line, color="red", linewidth=1.2)
    for k, (r, c, _) in enumerate(pixels):
        ax.plot(c, r, "o", markersize=7, markerfacecolor="none", markeredgecolor="yellow")
        ax.annotate(
            str(k + 1),
            (c, r),
            xytext=(5, 5),
            textcoords="offset points",
            color="yellow",
            fontsize=10,
            fontweight="bold",
        )
    if roi is not None:
        r0, r1, c0, c1 = roi
        ax.plot([c0, c1, c1, c0, c0], [r0, r0, r1, r1, r0], color="white", linestyle="--")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_axis_off()
    return png_bytes(fig)
