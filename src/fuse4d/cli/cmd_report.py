"""CLI command ``report``: the HTML page of a fusion run (video, x–t slices, flicker, ...)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from ._app import app, err_console, fail, out_console, progress_bar, progress_callback
from ._recording_opts import frame_range

__all__ = ["make_report", "report_command"]


def split_methods(text: str | None) -> list[str]:
    """``"realsense,temporal-mean"`` -> ``["realsense", "temporal-mean"]``."""
    return [m.strip() for m in (text or "").split(",") if m.strip()]


def make_report(input: Any, fused: Any, out: Path, **kwargs: Any) -> Path:
    """Call :func:`fuse4d.report.write_report` behind a progress bar; print what was written."""
    from ..report import write_report

    err_console.print(f"writing the report {out} ...")
    with progress_bar("report", None) as bar:
        return write_report(input, fused, out, progress=progress_callback(bar), **kwargs)


def _same_frames(given: str, recorded: str, input_path: Path, options: dict) -> bool:
    """Whether two ``--frames`` ranges select the same frames of the input ("9:" and "9:12"
    of a 12-frame recording do; the input is opened only where the texts differ)."""
    if given.strip() == recorded.strip():
        return True
    from ..io import open_frames, resolve_frames

    with open_frames(input_path, **{k: v for k, v in options.items() if k != "frames"}) as r:
        total = len(r)
    return resolve_frames(given, total) == resolve_frames(recorded, total)


@app.command("report")
def report_command(
    input: Annotated[Path, typer.Argument(help="Raw recording: .npz, frame folder, TUM, ...")],
    fused: Annotated[Path, typer.Argument(help="Its fused result (from fuse4d run).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Report folder to create.")],
    compare: Annotated[
        str | None,
        typer.Option(
            "--compare", help="Baselines to show too, comma-separated (e.g. temporal-mean)."
        ),
    ] = None,
    row: Annotated[
        int | None, typer.Option("--row", help="Image row of the x–t slice (default: most motion).")
    ] = None,
    col: Annotated[
        int | None, typer.Option("--col", help="Image column of the slice (instead of a row).")
    ] = None,
    roi: Annotated[
        str | None,
        typer.Option(
            "--roi",
            help="Flat static target R0:R1,C0:C1 (px): spatial/temporal precision measured there.",
        ),
    ] = None,
    gt: Annotated[
        Path | None,
        typer.Option("--gt", help="Ground-truth depth sequence (its depth_gt or depth)."),
    ] = None,
    frame: Annotated[
        int | None,
        typer.Option(
            "--frame",
            help="Frame of the maps and point cloud, counted from 0 (with --frames A:B, from"
            " input frame A) (default: the frame with depth nearest the middle).",
        ),
    ] = None,
    fps: Annotated[float | None, typer.Option("--fps", help="Video frame rate.")] = None,
    rerun: Annotated[
        Path | None,
        typer.Option(
            "--rerun", help="Also log raw/fused depth to a Rerun .rrd (needs the viz extra)."
        ),
    ] = None,
    frames: Annotated[
        str | None,
        typer.Option(
            "--frames",
            help="The part A:B of INPUT that FUSED was made from (fuse4d run --frames; a run"
            " folder records it).",
            callback=frame_range,
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing report.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print metrics.json to stdout.")] = False,
) -> None:
    """Write DIR/report.html (self-contained), DIR/compare.mp4 and DIR/metrics.json.

    A frame folder written by `fuse4d run` records how the run read INPUT (streams, camera,
    frame range), an --engine dask store its frame range; the report reads it the same way.
    Where FUSED's stored intensity is not INPUT's (a result of another recording, other
    frames, or of INPUT read with other options), a warning says so.
    """
    from ..report import parse_roi
    from ..report._sources import recorded_reader_options

    if rerun is not None:
        from ..io import check_output
        from ..report.rerun import have_rerun

        if not have_rerun():
            fail("--rerun needs rerun-sdk: pip install 'fuse4d[viz]'")
        check_output(rerun, overwrite=force, inputs=[input, fused])  # fail before the report
    options = recorded_reader_options(fused)
    if frames is not None:
        recorded = options.get("frames")
        # raw and fused frames mismatched (raw 50-55 scored against fused 10-15)
        if recorded is not None and not _same_frames(frames, str(recorded), input, options):
            fail(
                f"--frames {frames}: {fused} was fused from frames {recorded} of its input "
                "(its run records them); drop --frames"
            )
        options["frames"] = frames
    page = make_report(
        input,
        fused,
        output,
        compare=split_methods(compare),
        row=row,
        col=col,
        roi=None if roi is None else parse_roi(roi),
        ground_truth=gt,
        frame=frame,
        fps=fps,
        overwrite=force,
        reader_options=options,
    )
    if rerun is not None:
        from ..report.rerun import write_rerun

        with progress_bar("rerun", None) as bar:
            write_rerun(
                input,
                fused,
                rerun,
                overwrite=force,
                progress=progress_callback(bar),
                reader_options=options,
            )
        err_console.print(f"wrote {rerun} (open it with: rerun {rerun})")
    print_report_summary(page, as_json=as_json)


def print_report_summary(page: Path, *, as_json: bool = False) -> None:
    """Print the headline numbers of a written report (or its metrics.json)."""
    metrics = json.loads((page.parent / "metrics.json").read_text())
    if as_json:
        print(json.dumps(metrics, indent=2))
        return
    names = metrics["methods"]
    table = Table(title=f"fuse4d report: {page}")
    table.add_column("metric")
    for name in names:
        table.add_column(name, justify="right")
    rows = (
        ("roughness mean (Eq. 7, mm)", "roughness_mean", 1.0),
        ("spatial precision (plane RMS, mm)", "spatial_precision", 1.0),
        ("flicker / temporal precision (mean std, mm)", "flicker_mean", 1.0),
        ("flicker, median std (mm)", "flicker_median", 1.0),
        ("fill rate (%)", "fill_rate", 100.0),
        ("RMSE to GT (mm)", "rmse", 1.0),
        ("bad pixels > 1 mm (%)", "bad_pixels", 100.0),
        ("bad pixels > step limit (%)", "bad_steps", 100.0),
    )
    for label, key, scale in rows:
        values = [metrics["metrics"][n].get(key, "absent") for n in names]
        if all(v == "absent" for v in values):
            continue
        table.add_row(
            label,
            *("n/a" if not isinstance(v, int | float) else f"{scale * v:.4g}" for v in values),
        )
    out_console.print(table)
    timing = metrics["timing"]
    fusion_ms = timing.get("fusion_ms_per_frame")
    steady_ms = timing.get("fusion_steady_ms_per_frame")
    fusion = (
        "" if fusion_ms is None
        else f", fusion {fusion_ms:.1f} ms/frame" if steady_ms is None
        else f", fusion {steady_ms:.1f} ms/frame once running ({fusion_ms:.1f} with start-up)"
    )  # fmt: skip
    out_console.print(
        f"report {timing['report_ms_per_frame']:.1f} ms/frame"
        + fusion
        + f"; wrote {page}, compare.mp4 ({metrics['video']['codec']}), metrics.json"
    )
