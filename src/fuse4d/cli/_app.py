"""The typer application object and helpers shared by every CLI command module.

Command modules (``cli/cmd_*.py``) define functions decorated with ``@app.command()``; they
parse arguments, call the public API, and print. No numerics here.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, TypeVar

import typer
from rich.console import Console

if TYPE_CHECKING:
    from rich.progress import Progress

app = typer.Typer(
    name="fuse4d",
    help="Intensity-video-guided 4D fusion: clean noisy 3D/depth video.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

#: Messages and progress go to stderr so that ``--json`` output on stdout stays clean.
err_console = Console(stderr=True)
out_console = Console()

T = TypeVar("T")


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def fail(message: str) -> None:
    """Abort the command with a one-line message."""
    raise CliError(message)


@contextmanager
def progress_bar(description: str, total: int | None) -> Iterator[Progress]:
    """A rich progress bar on stderr (hidden when stderr is not a terminal)."""
    from rich.progress import (  # loaded when a command first shows progress (fast --help)
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=True,
        disable=not err_console.is_terminal,
    )
    with progress:
        progress.add_task(description, total=total)
        yield progress


def track(iterable: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """Iterate with a progress bar on stderr."""
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    with progress_bar(description, total) as progress:
        task = progress.task_ids[0]
        for item in iterable:
            yield item
            progress.advance(task)


def progress_callback(progress: Progress):
    """Adapter: a ``callback(done, total)`` for library functions that report progress."""
    task = progress.task_ids[0]

    def callback(done: int, total: int) -> None:
        progress.update(task, completed=done, total=total)

    return callback


def eprint(message: str) -> None:
    """Print a status line to stderr."""
    print(message, file=sys.stderr)
