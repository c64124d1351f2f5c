"""CLI commands ``synth`` (synthetic scenes with ground truth) and ``metrics`` (evaluation)."""

from __future__ import annotations

import json
import math
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.table import Table

from ._app import app, err_console, fail, out_console, progress_bar, progress_callback

__all__ = ["metrics_command", "synth_command"]


class SceneName(StrEnum):
    """Synthetic scenes of ``fuse4d synth``."""

    ball = "ball"
    plane = "plane"
    sheet = "sheet"


@app.command("synth")
def synth_command(
    scene: Annotated[SceneName, typer.Argument(help="Scene: ball, plane or sheet.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Output .npz file.")],
    depth_noise: Annotated[
        float | None, typer.Option(help="Depth-noise std in mm (scene default if omitted).")
    ] = None,
    intensity_noise: Annotated[
        float | None,
        typer.Option(help="Intensity-noise std as a fraction of 1.0 (0.02 = 2 %)."),
    ] = None,
    frames: Annotated[
        int | None, typer.Option(help="Number of frames (default 50; 12 small).")
    ] = None,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    small: Annotated[bool, typer.Option(help="150x150 CI-size variant.")] = False,
    force: Annotated[bool, typer.Option(help="Overwrite OUTPUT if it exists.")] = False,
) -> None:
    """Render a synthetic scene with ground truth (depth, mask, flow) into an .npz file."""
    from ..io import write_npz
    from ..synthetic import make_scene

    if output.exists() and not force:
        fail(f"{output}: output exists; pass --force to replace it")
    kwargs: dict[str, Any] = {"small": small, "rng": seed}
    if depth_noise is not None:
        kwargs["depth_noise"] = depth_noise
    if intensity_noise is not None:
        kwargs["intensity_noise"] = intensity_noise
    if frames is not None:
        kwargs["num_frames"] = frames
    with err_console.status(f"rendering the {scene.value} scene"):
        seq = make_scene(scene.value, **kwargs)
    with err_console.status(f"writing {output}"):
        write_npz(seq, output, overwrite=force)
    t, (h, w) = seq.num_frames, seq.shape
    extra = seq.ground_truth.extra if seq.ground_truth else {}
    err_console.print(
        f"wrote {output}: {scene.value}, {t} frames {h}x{w}, depth noise "
        f"{extra.get('depth_noise')} mm, intensity noise {extra.get('intensity_noise')}, "
        f"seed {seed}"
    )


def _load_roi(path: Path, shape: tuple[int, int, int], start: int, total: int) -> np.ndarray:
    """A (T, H, W) bool ROI from an .npz (key ``mask`` or ``roi``) or an image (nonzero)."""
    t, h, w = shape
    if path.suffix.lower() == ".npz":
        from ..io import read_mask  # corrupt or missing files are InputFileErrors there

        roi = read_mask(path)
    else:
        from ..io._images import read_mask_image

        roi = read_mask_image(path)
    if roi.shape == (h, w):
        return np.broadcast_to(roi, shape)
    if roi.shape == shape:
        return roi
    if roi.ndim == 3 and roi.shape[0] == total and roi.shape[1:] == (h, w):
        return roi[start : start + t]
    fail(f"{path}: ROI has shape {roi.shape}, expected ({h}, {w}) or ({t}, {h}, {w})")
    raise AssertionError  # unreachable


def _clean(value: Any) -> Any:
    """JSON-safe: NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@app.command("metrics")
def metrics_command(
    input: Annotated[Path, typer.Argument(help="Sequence: .npz, frame folder, TUM, ...")],
    gt: Annotated[
        Path | None, typer.Option(help="Ground-truth depth: a sequence (its depth_gt or depth).")
    ] = None,
    frames: Annotated[
        str | None, typer.Option(help="Frame range A:B (0-based, B excluded).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="One JSON object on stdout.")] = False,
    roi: Annotated[
        Path | None, typer.Option(help="ROI mask: .npz (key mask/roi) or PNG (nonzero = in).")
    ] = None,
    window: Annotated[int, typer.Option(help="Roughness window n (odd, px).")] = 5,
    edge_mm: Annotated[
        float, typer.Option(help="Default ROI: largest depth range inside a window (mm).")
    ] = 10.0,
    shape: Annotated[
        bool, typer.Option(help="Shape correctness for the synthetic ball (slow at full size).")
    ] = True,
) -> None:
    """Roughness (Eq. 7), RMS residual, flicker, and (with GT) RMSE, bad pixels, shape (Eq. 8).

    ROI: --roi if given; else the scene ROI of a synthetic scene (ball ROI, central 80 % of
    plane/sheet); else every pixel whose window is fully valid with depth range <= --edge-mm.
    Flicker: median over pixels of the per-pixel depth std over time, on pixels valid in all
    frames (and static in the ground truth, when there is one).
    """
    from ..io import count_frames, load_sequence, resolve_frames
    from ..metrics import (
        bad_pixel_fraction,
        default_roi,
        depth_rmse,
        roughness_stats,
        scene_roi,
        shape_correctness,
        static_mask_from_ground_truth,
        temporal_flicker,
    )

    if window < 3 or window % 2 == 0:
        fail(f"--window must be an odd integer >= 3, got {window}")
    with progress_bar(f"loading {input.name}", None) as bar:
        seq = load_sequence(input, frames=frames, progress=progress_callback(bar))
    start = resolve_frames(frames, count_frames(input)).start if frames else 0
    gtruth = seq.ground_truth
    depth_gt = None if gtruth is None else gtruth.depth
    if gt is not None:
        ref = load_sequence(gt, frames=frames)
        depth_gt = (
            ref.ground_truth.depth
            if ref.ground_truth is not None and ref.ground_truth.depth is not None
            else ref.depth
        )
        if depth_gt.shape != seq.depth.shape:
            fail(f"{gt}: ground truth has shape {depth_gt.shape}, input {seq.depth.shape}")
    points = seq.points()
    t, h, w = seq.depth.shape
    if roi is not None:
        mask = _load_roi(roi, (t, h, w), start, start + t)
        roi_desc = f"mask from {roi}"
    elif gtruth is not None and "scene" in gtruth.extra:
        mask, roi_desc = scene_roi(seq, window=window)
    else:
        mask = default_roi(seq.depth, window=window, edge_mm=edge_mm)
        roi_desc = f"default: {window}x{window} window fully valid, depth range <= {edge_mm:g} mm"
    with err_console.status("roughness"):
        stats = roughness_stats(points, roi=mask, window=window)
    result: dict[str, Any] = {
        "input": str(input),
        "frames": [start, start + t],
        "num_frames": t,
        "size": [h, w],
        "window": window,
        "roi": {
            "description": roi_desc,
            "pixels": int(mask.sum()),
            "pixels_per_frame": float(mask.sum() / t),
            "pixels_evaluated": int(stats.num_pixels.sum()),
        },
        **stats.to_dict(),
        "roughness_frame_means": stats.frame_means.tolist(),
    }
    static = None
    flicker_desc = "pixels valid in all frames"
    if gtruth is not None and gtruth.depth is not None:
        static = static_mask_from_ground_truth(gtruth)
        flicker_desc = "pixels valid in all frames and static in the ground truth"
    if t >= 2:
        flick = temporal_flicker(seq.depth, static_mask=static)
        result.update(
            flicker=flick.median,
            flicker_mean=flick.mean,
            flicker_pixels=flick.num_pixels,
            flicker_region=flicker_desc,
        )
    else:
        result.update(flicker=None, flicker_mean=None, flicker_pixels=0, flicker_region="T < 2")
    if depth_gt is not None:
        result["rmse"] = depth_rmse(depth_gt, seq.depth)
        result["bad_1mm"] = bad_pixel_fraction(depth_gt, seq.depth, threshold=1.0)
        result["rmse_roi"] = depth_rmse(depth_gt, seq.depth, mask=mask)
    if shape and gtruth is not None and gtruth.mask is not None and "center_row" in gtruth.extra:
        with progress_bar("shape correctness", t) as bar:
            sc = shape_correctness(points, gtruth, progress=progress_callback(bar))
        result["shape"] = {
            **sc.to_dict(),
            "radius_3d_mean": float(np.nanmean(sc.radius_3d)),
            "true_radius": sc.true_radius,
        }
    result = _clean(result)
    if as_json:
        out_console.file.write(json.dumps(result) + "\n")
        out_console.file.flush()
        return
    _print_table(result)


def _print_table(result: dict[str, Any]) -> None:
    def fmt(value: Any, digits: int = 4) -> str:
        return "n/a" if value is None else f"{value:.{digits}g}"

    table = Table(title=f"fuse4d metrics: {result['input']}", show_header=True)
    table.add_column("metric")
    table.add_column("value", justify="right")
    table.add_column("unit / note")
    table.add_row("frames", f"{result['frames'][0]}:{result['frames'][1]}", "")
    table.add_row("ROI", str(result["roi"]["pixels"]), result["roi"]["description"])
    table.add_row(
        "roughness mean (Eq. 7)",
        fmt(result["roughness_mean"]),
        f"mm, {result['window']}x{result['window']}",
    )
    table.add_row("roughness std (over frames)", fmt(result["roughness_std"]), "mm")
    table.add_row("RMS plane residual", fmt(result["rms_residual"]), "mm")
    table.add_row("flicker (median)", fmt(result["flicker"]), f"mm, {result['flicker_region']}")
    table.add_row("flicker (mean)", fmt(result["flicker_mean"]), "mm")
    if "rmse" in result:
        table.add_row("RMSE to GT", fmt(result["rmse"]), "mm")
        table.add_row("bad pixels > 1 mm", fmt(result["bad_1mm"]), "fraction")
    if "shape" in result:
        s = result["shape"]
        table.add_row(
            "shape C_3D", fmt(None if s["c_3d_mean"] is None else 100 * s["c_3d_mean"], 6), "%"
        )
        table.add_row(
            "shape C_minimal",
            fmt(None if s["c_minimal_mean"] is None else 100 * s["c_minimal_mean"], 6),
            "%",
        )
        table.add_row(
            "shape C_profile",
            fmt(None if s["c_profile_mean"] is None else 100 * s["c_profile_mean"], 6),
            "%",
        )
    out_console.print(table)
