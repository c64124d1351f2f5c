"""CLI command ``baseline``: run one comparison method on a recording, or list them."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from ..baselines import available_baselines, get_baseline
from ..io import load_sequence, save_sequence
from ._app import app, eprint, fail, out_console

__all__ = ["baseline_command"]


def _list_table() -> Table:
    table = Table(title="fuse4d baselines")
    for col in ("name", "description", "size (default, sweep)", "output", "available"):
        table.add_column(col)
    for name, info in available_baselines().items():
        avail = "yes" if info.available else f"no: pip install 'fuse4d[{info.needs}]'"
        if name == "kinectfusion" and not info.available:
            avail = "fallback (NumPy): pip install 'fuse4d[6d]' for Open3D"
        sweep = ", ".join(f"{s:g}" for s in info.size_sweep)
        table.add_row(
            name,
            info.description,
            f"{info.size_meaning}: {info.default_size:g} ({sweep})",
            "points" if info.returns_points else "depth",
            avail,
        )
    return table


@app.command("baseline")
def baseline_command(
    name: Annotated[
        str | None, typer.Argument(help="Method name (see --list).", show_default=False)
    ] = None,
    input_path: Annotated[
        Path | None,
        typer.Argument(help="Input recording (.npz or sequence folder).", show_default=False),
    ] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Output .npz file or folder.")
    ] = None,
    size: Annotated[
        float | None, typer.Option("--size", help="The method's size knob (see --list).")
    ] = None,
    iterations: Annotated[
        int | None, typer.Option("--iterations", help="Repeated applications (>= 1).")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite OUTPUT.")] = False,
    depth_unit_mm: Annotated[
        float, typer.Option("--depth-unit-mm", help="Folder output: mm per stored depth unit.")
    ] = 1.0,
    list_methods: Annotated[
        bool, typer.Option("--list", help="List the methods and exit.")
    ] = False,
) -> None:
    """Run a comparison method (BASELINES.md) on a recording and save the filtered depth.

    6D methods return 3D points; their Z (depth along the optical axis) is saved.
    """
    if list_methods:
        out_console.print(_list_table())
        return
    if name is None or input_path is None or output is None:
        fail("usage: fuse4d baseline NAME INPUT -o OUTPUT (or fuse4d baseline --list)")
    info = get_baseline(name)
    if info.needs is not None and not info.available and name != "kinectfusion":
        fail(f"baseline {name!r} needs the optional extra: pip install 'fuse4d[{info.needs}]'")
    if output.exists() and not force:
        fail(f"{output}: output exists (use --force to overwrite)")
    params: dict[str, float | int] = {}
    if size is not None:
        params["size"] = int(size) if float(size).is_integer() and name != "adgf" else size
    if iterations is not None:
        params["iterations"] = iterations
    seq = load_sequence(input_path)
    start = time.perf_counter()
    result = info.function(seq.depth, seq.intensity, seq.intrinsics, **params)
    elapsed = time.perf_counter() - start
    depth = result[..., 2] if info.returns_points else result
    depth = np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)
    written = save_sequence(
        seq.with_depth(depth), output, overwrite=force, depth_unit_mm=depth_unit_mm
    )
    eprint(
        f"{name}: {seq.num_frames} frames in {elapsed:.2f} s "
        f"({1000 * elapsed / max(seq.num_frames, 1):.1f} ms/frame) -> {written}"
    )
