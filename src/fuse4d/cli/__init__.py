"""Command-line interface: ``fuse4d COMMAND ...`` (``fuse4d --help`` lists the commands).

Every error caused by the input (bad file, bad value) ends the program with exit code 2 and a
single ``fuse4d: error: ...`` line on stderr, never a traceback. Set ``FUSE4D_DEBUG=1`` to see
the traceback.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

import typer

from ._app import CliError, app

# Command modules register their commands on `app` when imported (one line each, sorted).
from . import (  # noqa: F401  isort: skip
    cmd_baseline,  # baseline
    cmd_flow,  # flow, bench-flow
    cmd_fuse,  # run, bench, demo
    cmd_eval,  # synth, metrics
    cmd_experiments,  # experiments
    cmd_io,  # info, export-ply
)

__all__ = ["app", "main"]

# typer >= 0.2x vendors click (typer._click); older typer uses the click package. Take the
# exception classes from typer's own public ones so both work.
_ClickException = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (also used as the console-script entry point)."""
    command = typer.main.get_command(app)
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        result = command.main(args=args, prog_name="fuse4d", standalone_mode=False)
    except typer.Exit as exc:
        return _finish(exc.exit_code, argv)
    except typer.Abort:
        print("fuse4d: aborted", file=sys.stderr)
        return _finish(130, argv)
    except _ClickException as exc:
        exc.show(file=sys.stderr)
        return _finish(exc.exit_code, argv)
    except (CliError, ValueError, OSError, KeyError) as exc:
        if os.environ.get("FUSE4D_DEBUG"):
            raise
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in message:
            message = f"{exc.filename}: {message}"
        print(f"fuse4d: error: {message}", file=sys.stderr)
        return _finish(2, argv)
    code = result if isinstance(result, int) else 0
    return _finish(code, argv)


def _finish(code: int, argv: Sequence[str] | None) -> int:
    if argv is None:  # console-script use
        sys.exit(code)
    return code
