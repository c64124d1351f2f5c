"""The typer application object and helpers shared by every CLI command module.

Command modules (``cli/cmd_*.py``) define functions decorated with ``@app.command()``; they
parse arguments, call the public API, and print. No numerics here.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Annotated, TypeVar

import typer
from rich.console import Console

if TYPE_CHECKING:
    from rich.progress import Progress

from ..errors import Fuse4dError

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


class CliError(Fuse4dError):
    """A user-facing error: printed as one line, exit code 2."""


class _State:
    """Options of the ``fuse4d`` group itself (set by :func:`_root`)."""

    debug = False
    #: what an interrupt of the running command leaves, said on main's one line
    #: ("fuse4d: interrupted <note>"); set by a command just before it lets the interrupt go
    interrupt_note = ""


STATE = _State()


def _print_version(value: bool) -> None:
    """``fuse4d --version``: fuse4d's version and those of the packages behind its numbers
    (read from the installed metadata, so nothing heavy is imported)."""
    if not value:
        return
    import platform
    from importlib import metadata

    from .._version import __version__

    parts = []
    for package in ("numpy", "numba", "opencv-contrib-python-headless", "scipy"):
        try:
            parts.append(f"{package} {metadata.version(package)}")
        except metadata.PackageNotFoundError:
            continue
    print(f"fuse4d {__version__} (Python {platform.python_version()}; {', '.join(parts)})")
    raise typer.Exit()


@app.callback()
def _root(
    debug: Annotated[
        bool,
        typer.Option(
            "--debug",
            help="Show the full traceback of any error (also: environment FUSE4D_DEBUG=1).",
        ),
    ] = False,
    version: Annotated[
        bool,
        typer.Option(
            "--version",
            help="Print fuse4d's version (and numpy's, numba's, OpenCV's) and exit.",
            callback=_print_version,
            is_eager=True,
        ),
    ] = False,
) -> None:
    """Intensity-video-guided 4D fusion: clean noisy 3D/depth video."""
    STATE.debug = debug


def fail(message: str) -> None:
    """Abort the command with a one-line message."""
    raise CliError(message)


@contextmanager
def user_values(what: str = "") -> Iterator[None]:
    """Report a ``ValueError``/``TypeError`` raised while the block turns values the user
    typed (option values, method names) into parameter objects as a user error (exit 2).

    Wrap only the construction of parameter objects, never a computation: an exception from
    a computation is a bug and must reach the crash report.

    Parameters
    ----------
    what : str, optional
        Prefix of the message (e.g. ``"--flow-param: "``), also of a fuse4d error's (a
        parameter object's range check: "--window 0: FusionParams.num_frames must be ...").
    """
    try:
        yield
    except Fuse4dError as exc:
        if not what:
            raise
        raise CliError(f"{what}{exc}") from exc
    except (ValueError, TypeError) as exc:
        raise CliError(f"{what}{exc}") from exc


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
