"""Command-line options shared by the commands that run the fusion (``run``, ``live``, ``bench``).

One declaration per option, so that its name, help text and default are the same in every
command; :func:`fuse4d.cli.cmd_fuse._resolve` turns the given ones into fusion and flow
parameters.
"""

from __future__ import annotations

from typing import Annotated

import typer

__all__ = ["FlowMethodOpt", "FlowParamOpt", "PresetOpt", "SetOpt"]

PresetOpt = Annotated[
    str, typer.Option("--preset", help="Parameter preset: fast (DIS flow) or paper (PMBP).")
]
SetOpt = Annotated[
    list[str] | None,
    typer.Option("--set", help="Fusion parameter KEY=VALUE (repeatable).", show_default=False),
]
FlowMethodOpt = Annotated[
    str | None, typer.Option("--flow", help="Flow method (overrides the preset).")
]
FlowParamOpt = Annotated[
    list[str] | None,
    typer.Option("--flow-param", help="Flow parameter KEY=VALUE (repeatable).", show_default=False),
]
