"""CLI commands: ``flow`` (one optical-flow field to ``.flo``) and ``bench-flow``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from ._app import app, eprint, fail, out_console, progress_bar, progress_callback, user_values


def _parse_params(method: str, items: list[str]) -> object:
    from .._params import parse_assignments
    from ..flow import flow_params_from_mapping

    return flow_params_from_mapping(method, parse_assignments(items, what="--param"))


def _check_out(path: Path, force: bool, inputs: tuple[Path, ...]) -> None:
    from ..io import check_output

    resolved = path.resolve()
    if any(resolved == p.resolve() for p in inputs):
        fail(f"{path}: output would overwrite an input; choose another path")
    if not resolved.parent.is_dir():
        fail(f"{path}: output folder {path.parent} does not exist")
    if path.is_dir():
        fail(f"{path}: is a folder; give the output file's name")
    if path.exists() and not force:
        fail(f"{path}: output exists; pass --force to replace it")
    check_output(path, overwrite=force)  # the folder tried before the solve (read-only)


@app.command("flow")
def flow_command(
    image0: Annotated[Path, typer.Argument(help="First frame: 8/16-bit image (colour → gray).")],
    image1: Annotated[Path, typer.Argument(help="Second frame, same size.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="Middlebury .flo output file.")],
    method: Annotated[
        str,
        typer.Option(
            "--method", "-m", help="Flow method: dis, farneback, tvl1, deepflow, pmbp, pmbp-fast."
        ),
    ] = "dis",
    param: Annotated[
        list[str] | None,
        typer.Option(
            "--param",
            "-p",
            help="Method parameter KEY=VALUE (repeatable), e.g. -p preset=fast for DIS, "
            "-p num_particles=1 for PMBP.",
        ),
    ] = None,
    vis: Annotated[
        Path | None,
        typer.Option("--vis", help="Also write a Middlebury colour-wheel PNG of the flow."),
    ] = None,
    max_magnitude: Annotated[
        float | None,
        typer.Option("--max-magnitude", help="Flow magnitude (px) drawn fully saturated in --vis."),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite existing outputs.")] = False,
) -> None:
    """Optical flow from IMAGE0 to IMAGE1, written as Middlebury .flo (u = column shift, px)."""
    from ..flow import estimate_flow, get_flow_method, write_flo
    from ..flow.vis import write_flow_png
    from ..io import read_intensity_image

    with user_values():
        m = get_flow_method(method.strip().lower())
        params = _parse_params(m.name, param or [])
    if max_magnitude is not None:  # every output check comes before the solve
        if vis is None:
            fail("--max-magnitude sets the --vis colour scale; give --vis too")
        if not (math.isfinite(max_magnitude) and max_magnitude > 0):
            fail(f"--max-magnitude must be a number of pixels > 0, got {max_magnitude:g}")
    _check_out(output, force, (image0, image1))
    if vis is not None:
        _check_out(vis, force, (image0, image1))
        if vis.resolve() == output.resolve():
            fail("--vis and --output must be different files")
        if vis.suffix.lower() != ".png":
            fail(f"--vis {vis}: the colour-wheel image is written as PNG; name it *.png")
    a = read_intensity_image(image0)
    b = read_intensity_image(image1)
    if a.shape != b.shape:
        fail(
            f"{image1}: size {b.shape[1]}x{b.shape[0]} differs from {image0} "
            f"({a.shape[1]}x{a.shape[0]})"
        )
    if min(a.shape) < 2:
        fail(f"{image0}: {a.shape[1]}x{a.shape[0]} px; flow needs at least 2 px on each side")
    flow = estimate_flow(a, b, method=m, params=params)
    write_flo(flow, output, overwrite=force)
    if vis is not None:
        write_flow_png(flow, vis, max_magnitude=max_magnitude, overwrite=force)
    note = "" if m.paper_method else " (not the paper's tracker)"
    eprint(
        f"wrote {output}: {a.shape[1]}x{a.shape[0]} flow, method {m.name}{note}, "
        f"max |flow| {float((flow**2).sum(-1).max() ** 0.5):.2f} px"
    )
    if m.name == "dis":
        from ..flow.opencv import _dis_levels_note

        levels = _dis_levels_note(*a.shape, params)  # type: ignore[arg-type]
        if levels:
            eprint(f"note: {levels}")


def _data_root(data: Path | None) -> Path:
    """``data``, else the data folder of ``fuse4d experiments`` (``$FUSE4D_DATA``, else the
    ``shared/data`` beside the source checkout), whatever the working folder."""
    if data is not None:
        return data
    from ..experiments.paper.real import data_dir

    return data_dir()


def _middlebury_dir(root: Path) -> Path:
    return root if (root / "other-gt-flow").is_dir() else root / "middlebury_flow"


@app.command("bench-flow")
def bench_flow_command(
    methods: Annotated[
        str | None,
        typer.Option(
            "--methods",
            help="Comma-separated labels or method names (dis = all DIS presets). Default: all.",
        ),
    ] = None,
    data: Annotated[
        Path | None,
        typer.Option(
            "--data",
            help="Shared data folder holding middlebury_flow/ (or that folder itself). "
            "Default: $FUSE4D_DATA, else the shared/data beside the fuse4d checkout "
            "(as fuse4d experiments).",
        ),
    ] = None,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print JSON instead of a table.")
    ] = False,
    small: Annotated[
        bool, typer.Option("--small", help="Small synthetic ball (quick check).")
    ] = False,
    skip_ball: Annotated[bool, typer.Option("--no-ball", help="Skip the synthetic ball.")] = False,
    skip_middlebury: Annotated[
        bool, typer.Option("--no-middlebury", help="Skip Middlebury.")
    ] = False,
) -> None:
    """EPE / AAE / ms per pair of every flow method on Middlebury and the synthetic ball."""
    import cv2

    from ..experiments.flow_accuracy import (
        ball_interior_erosion,
        ball_pairs,
        default_bench_entries,
        middlebury_pairs,
        run_flow_benchmark,
        summarize_flow_benchmark,
    )

    with user_values():
        entries = default_bench_entries(None if methods is None else methods.split(","))
    if not entries:  # an empty table, exit 0
        fail(f"--methods {methods!r} names no flow method")
    if data is not None and not skip_middlebury and not data.exists():
        fail(f"--data {data}: folder not found")
    pairs = []
    skipped = {}
    if not skip_middlebury:
        found, reason = middlebury_pairs(_middlebury_dir(_data_root(data)))
        pairs.extend(found)
        if reason:
            skipped["middlebury"] = reason
            eprint(f"bench-flow: skipping Middlebury: {reason}")
    if not skip_ball:
        try:
            for noise in (0.02, 0.10):
                pairs.extend(ball_pairs(intensity_noise=noise, small=small))
        except (ImportError, ValueError) as exc:
            skipped["ball"] = str(exc)
            eprint(f"bench-flow: skipping the synthetic ball: {exc}")
    if not pairs:
        if skip_middlebury:
            skipped.setdefault("middlebury", "--no-middlebury")
        if skip_ball:
            skipped.setdefault("ball", "--no-ball")
        fail("no benchmark data: " + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
    with progress_bar("bench-flow", len(entries) * len(pairs)) as bar:
        results = run_flow_benchmark(entries, pairs, progress=progress_callback(bar))
    rows = summarize_flow_benchmark(results)
    if json_output:
        report = {
            "opencv_version": cv2.__version__,
            "opencv_threads": cv2.getNumThreads(),
            "small": small,
            "skipped": skipped,
            "summary": rows,
            "pairs": [r.to_dict() for r in results],
        }
        from .._json import dumps

        out_console.print_json(dumps(report))
        return
    out_console.print(_table(rows))
    out_console.print(
        f"EPE px / AAE deg, mean over pairs; ms = one forward solve per pair "
        f"(OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads). "
        + ("" if skip_middlebury else "Middlebury: frame10→11, unknown GT excluded; ")
        + (
            ""
            if skip_ball
            else f"ball: interior (GT mask eroded {ball_interior_erosion(small=small)} px); "
        )
        + "pairs: the number averaged per dataset (--json). * = not the paper's tracker."
    )


def _table(rows: list[dict]) -> Table:
    datasets = list(dict.fromkeys(r["dataset"] for r in rows))
    labels = list(dict.fromkeys(r["label"] for r in rows))
    by_key = {(r["label"], r["dataset"]): r for r in rows}
    table = Table(title="fuse4d bench-flow")
    table.add_column("method")
    for ds in datasets:
        table.add_column(f"{ds}\nEPE px", justify="right")
        table.add_column("AAE °", justify="right")
        table.add_column("ms/pair", justify="right")
    for label in labels:
        paper = next(r["paper_method"] for r in rows if r["label"] == label)
        star = "" if paper else "*"
        cells = [label + star]
        for ds in datasets:
            r = by_key.get((label, ds))
            if r is None:
                cells += ["-", "-", "-"]
            else:
                cells += [f"{r['epe_px']:.3f}", f"{r['aae_deg']:.2f}", f"{r['ms']:.0f}"]
        table.add_row(*cells)
    return table
