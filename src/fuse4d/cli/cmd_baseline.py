"""CLI command ``baseline``: run one comparison method on a recording, or list them."""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from ._app import app, eprint, fail, out_console
from ._recording_opts import (
    CameraOverrideOpt,
    DepthTopicOpt,
    DepthUnitOpt,
    IntensityOpt,
    IntensityTopicOpt,
    NoUndistortOpt,
    OutDepthUnitOpt,
    reader_options,
)

__all__ = ["baseline_command"]


def _list_table() -> Table:
    from ..baselines import available_baselines

    table = Table(title="fuse4d baselines")
    for col in (
        "name",
        "description",
        "size: name, meaning (default; sweep)",
        "output",
        "available",
    ):
        table.add_column(col)
    for name, info in available_baselines().items():
        avail = "yes" if info.available else f"no: pip install 'fuse4d[{info.needs}]'"
        sweep = ", ".join(f"{s:g}" for s in info.size_sweep)
        table.add_row(
            name,
            info.description,
            f"{info.size_name}: {info.size_meaning} ({info.default_size:g}; {sweep})",
            "points" if info.returns_points else "depth",
            avail,
        )
    return table


def _size_help() -> str:
    """The ``--size`` help computed from the registry (``SIZE_HELP`` must equal it: tested)."""
    from ..baselines import available_baselines

    names: dict[str, list[str]] = {}
    for name, info in available_baselines().items():
        names.setdefault(info.size_name, []).append(name)
    per_name = "; ".join(f"{k} ({', '.join(v)})" for k, v in names.items())
    return (
        "The method's size knob, a different quantity per method: "
        f"{per_name}. See --list for units and sweeps; -p NAME=VALUE sets it by name."
    )


#: ``_size_help()`` written out, so that the command line does not import the baselines (scipy,
#: numba) to show its help; ``tests/test_cli_startup.py`` checks that the two agree.
SIZE_HELP = (
    "The method's size knob, a different quantity per method: kernel_scale (adgf); "
    "spatial_radius (adbf, guided, dnbf, adjbf); num_frames (ta, temporal-mean); "
    "temporal_radius (stmf, kinectfusion, ed); filter_passes (realsense). "
    "See --list for units and sweeps; -p NAME=VALUE sets it by name."
)


@app.command("baseline")
def baseline_command(
    name: Annotated[
        str | None, typer.Argument(help="Method name (see --list).", show_default=False)
    ] = None,
    input_path: Annotated[
        Path | None,
        typer.Argument(
            help="Input recording (any layout fuse4d reads, camera recordings included).",
            show_default=False,
        ),
    ] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Output .npz file or folder.")
    ] = None,
    size: Annotated[str | None, typer.Option("--size", help=SIZE_HELP)] = None,
    iterations: Annotated[
        str | None, typer.Option("--iterations", help="Repeated applications (>= 1).")
    ] = None,
    knobs: Annotated[
        list[str] | None,
        typer.Option(
            "--param",
            "-p",
            help="Method knob KEY=VALUE (repeatable): a keyword of the method, e.g. "
            "noise_sigma=0.5, or its size by name (spatial_radius=6).",
            show_default=False,
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite OUTPUT.")] = False,
    out_depth_unit_mm: OutDepthUnitOpt = None,
    depth_topic: DepthTopicOpt = None,
    intensity_topic: IntensityTopicOpt = None,
    intensity: IntensityOpt = None,
    no_undistort: NoUndistortOpt = False,
    depth_unit_mm: DepthUnitOpt = None,
    intrinsics: CameraOverrideOpt = None,
    list_methods: Annotated[
        bool, typer.Option("--list", help="List the methods and exit.")
    ] = False,
) -> None:
    """Run one of the paper's comparison methods on a recording and save the filtered depth.

    6D methods return 3D points; their Z (depth along the optical axis) is saved. --size is
    each method's own size knob (a pixel radius, a frame count, a temporal radius or a kernel
    scale): --list shows its name, meaning and unit per method.
    """
    if list_methods:
        out_console.print(_list_table())
        return
    if name is None or input_path is None or output is None:
        fail("usage: fuse4d baseline NAME INPUT -o OUTPUT (or fuse4d baseline --list)")
    import numpy as np

    from .._params import check_number, parse_assignments
    from ..baselines import get_baseline
    from ..io import open_frames, save_sequence
    from ..io._atomic import check_output

    info = get_baseline(name)
    if info.needs is not None and not info.available:
        fail(f"baseline {name!r} needs the optional extra: pip install 'fuse4d[{info.needs}]'")
    # before any work: an existing output needs --force, and the input is never the output
    # (--force used to replace the input itself, or a folder inside it)
    check_output(output, overwrite=force, inputs=[input_path])
    params: dict[str, str] = parse_assignments(knobs, what="--param")
    for option, key, value in (
        ("--size", "size", size),
        ("--iterations", "iterations", iterations),
    ):
        if value is None:
            continue
        if key in params:  # the -p value was dropped silently
            fail(f"give {option} or --param {key}=..., not both")
        params[key] = value
    kwargs = info.knobs(params)  # strings to the method's keyword types, before reading input
    if out_depth_unit_mm is not None:
        check_number("baseline", "out_depth_unit_mm", out_depth_unit_mm, gt=0, finite=True)
    options = reader_options(
        depth_topic, intensity_topic, intensity, no_undistort,
        depth_unit_mm=depth_unit_mm, intrinsics=intrinsics,
    )  # fmt: skip
    with open_frames(input_path, **options) as reader:
        own_unit = reader.depth_unit_mm  # written back in it (below)
        seq = reader.read_sequence()
    unit = out_depth_unit_mm or own_unit or 1.0
    if name == "realsense" and "depth_unit" not in kwargs and own_unit is not None:
        # the chain in the recording's own Z16 unit, as a RealSense user runs it (a 0.1 mm
        # D405 recording ran at 0.02 mm: the SDK's 20-unit delta became 0.4 mm, not 2 mm)
        kwargs["depth_unit"] = own_unit
    start = time.perf_counter()
    result = info.function(seq.depth, seq.intensity, seq.intrinsics, **kwargs)
    elapsed = time.perf_counter() - start
    depth = result[..., 2] if info.returns_points else result
    depth = np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)
    with warnings.catch_warnings():  # "only x % valid" of the output: the input's was said
        warnings.simplefilter("ignore", UserWarning)
        filtered = seq.with_depth(depth)
    written = save_sequence(
        filtered, output, overwrite=force, depth_unit_mm=unit,
        # in the input's own unit no "coarse" warning, as `fuse4d run` writes: the input was
        # stored at that precision (a unit chosen with --out-depth-unit-mm is still checked)
        warn_coarse_unit=out_depth_unit_mm is not None or own_unit is None,
    )  # fmt: skip
    eprint(
        f"{name}: {seq.num_frames} frames in {elapsed:.2f} s "
        f"({1000 * elapsed / max(seq.num_frames, 1):.1f} ms/frame) -> {written}"
    )
