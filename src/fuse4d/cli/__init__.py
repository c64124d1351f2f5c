"""Command-line interface: ``fuse4d COMMAND ...`` (``fuse4d --help`` lists the commands).

Error contract (see :mod:`fuse4d.errors`):

* a problem with the input, the options or the environment (a :class:`~fuse4d.Fuse4dError`,
  or an :class:`OSError` such as a full disk) prints one ``fuse4d: error: ...`` line on
  stderr and exits with code 2;
* any other exception is a bug in fuse4d: one line says so, with the path of a crash report
  (traceback, versions, command, platform), exit code 70;
* Ctrl-C (or SIGTERM) exits with code 130 (outputs are complete or absent; see
  ``fuse4d run --resume``). The same signal again within 0.2 s is taken for the first one
  delivered twice (GNU ``timeout -s INT`` sends it to the process, then to its group) and
  ignored (:func:`fuse4d._signals.is_echo`).

``fuse4d --debug COMMAND`` (or ``FUSE4D_DEBUG=1``) shows the traceback instead. Warnings
(e.g. a coarse output depth unit) print as one ``fuse4d: warning: ...`` line each.
"""

from __future__ import annotations

import functools
import inspect
import os
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import typer

from .. import _signals
from .._signals import INTERRUPTED as _INTERRUPTED
from ..errors import Fuse4dError
from ._app import STATE, app
from ._crash import write_crash_report

# Command modules register their commands on `app` when imported (one line each, sorted).
from . import (  # noqa: F401  isort: skip
    cmd_baseline,  # baseline
    cmd_flow,  # flow, bench-flow
    cmd_fuse,  # run, bench, demo
    cmd_eval,  # synth, metrics
    cmd_experiments,  # experiments
    cmd_io,  # info, export-ply
    cmd_live,  # live
    cmd_report,  # report
)

__all__ = ["EXIT_BUG", "EXIT_INTERRUPTED", "EXIT_USAGE", "app", "main"]

# typer >= 0.2x vendors click (typer._click); older typer uses the click package. Take the
# exception classes from typer's own public ones so both work.
_ClickException = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (also used as the console-script entry point)."""
    command = typer.main.get_command(app)
    _tidy_help(command)
    args = list(sys.argv[1:] if argv is None else argv)
    STATE.debug = False
    STATE.interrupt_note = ""
    _signals.reset()  # the flag, and the time of the last signal
    if argv is None and threading.current_thread() is threading.main_thread():
        # console script: `kill` (SIGTERM) and a closed terminal or ssh session (SIGHUP) stop
        # as cleanly as Ctrl-C (complete outputs only; SIGHUP left staged files behind); each
        # is remembered, since one raised inside numba's compiler is turned into another error
        signal.signal(signal.SIGINT, _terminate)
        signal.signal(signal.SIGTERM, _terminate)
        if hasattr(signal, "SIGHUP"):  # not on Windows
            signal.signal(signal.SIGHUP, _terminate)
        if not _debug():  # a warning reads as one line, not Python's file, line and source
            warnings.showwarning = _show_warning
    unraisablehook = sys.unraisablehook
    sys.unraisablehook = functools.partial(_drop_interrupt, unraisablehook)
    try:
        return _run(command, args, argv)
    finally:
        if argv is not None:  # (the console script keeps it: the shutdown runs __del__s too)
            sys.unraisablehook = unraisablehook


def _run(command: Any, args: list[str], argv: Sequence[str] | None) -> int:
    """:func:`main` once the signal handlers are in place: the command, then its exit code."""
    try:
        result = command.main(args=args, prog_name="fuse4d", standalone_mode=False)
    except typer.Exit as exc:
        if exc.exit_code == 0 and _INTERRUPTED.is_set():  # see below
            _say_interrupted()
            return _finish(EXIT_INTERRUPTED, argv)
        return _finish(exc.exit_code, argv)
    except (typer.Abort, KeyboardInterrupt):
        _say_interrupted()
        return _finish(EXIT_INTERRUPTED, argv)
    except _ClickException as exc:
        exc.show(file=sys.stderr)
        return _finish(exc.exit_code, argv)
    except (Fuse4dError, OSError) as exc:
        if _debug():
            raise
        print(f"fuse4d: error: {_one_line(exc)}", file=sys.stderr)
        return _finish(EXIT_USAGE, argv)
    except Exception as exc:  # an internal bug: report it as one, never as a user error
        if _INTERRUPTED.is_set():
            # Ctrl-C inside numba's compiler (a ctypes callback) surfaced as "RuntimeError: no
            # compiled object yet for <Library ...>": an interrupt, not a bug
            _say_interrupted()
            return _finish(EXIT_INTERRUPTED, argv)
        if _debug():
            raise
        report = write_crash_report(exc, args)
        where = f"crash report: {report}" if report else "no crash report could be written"
        print(
            f"fuse4d: internal error (a bug in fuse4d, not in your input): "
            f"{type(exc).__name__}: {_one_line(exc)}; {where}; please report it "
            "(see SECURITY.md / the issue tracker), or rerun with --debug for the traceback",
            file=sys.stderr,
        )
        return _finish(EXIT_BUG, argv)
    code = result if isinstance(result, int) else 0
    if _INTERRUPTED.is_set():
        # the KeyboardInterrupt of a signal was raised inside a weakref callback or a
        # __del__, where Python drops it (_drop_interrupt) and the command went on: still an
        # interrupt (a command that takes a signal as a normal stop, as `fuse4d live` does,
        # leaves the flag unset)
        code = EXIT_INTERRUPTED
    if code == EXIT_INTERRUPTED:  # typer turned Ctrl-C into this exit code
        _say_interrupted()
    return _finish(code, argv)


def _say_interrupted() -> None:
    """The one line of an interrupted command, with what the command said it leaves."""
    note = STATE.interrupt_note
    print("fuse4d: interrupted" + (f" {note}" if note else ""), file=sys.stderr)


#: Exit codes: bad input/options/environment, internal bug (BSD EX_SOFTWARE), Ctrl-C.
EXIT_USAGE = 2
EXIT_BUG = 70
EXIT_INTERRUPTED = 130


def _terminate(signum: int, frame: object) -> None:
    if _signals.is_echo(signum):  # the same signal delivered twice (GNU timeout -s INT)
        return
    _INTERRUPTED.set()
    raise KeyboardInterrupt


def _drop_interrupt(hook: Callable[[Any], object], unraisable: Any) -> None:
    """``sys.unraisablehook`` while a command runs: a KeyboardInterrupt that a signal raised
    inside a weakref callback or a ``__del__`` cannot propagate (Python printed "Exception
    ignored in ..." with a traceback and the command went on, to exit 0); once the interrupt
    is noted (:data:`fuse4d._signals.INTERRUPTED`) it is dropped silently, and :func:`main`
    exits 130 when the command returns. Anything else goes to ``hook``, the previous one."""
    if issubclass(unraisable.exc_type, KeyboardInterrupt) and _INTERRUPTED.is_set():
        return
    hook(unraisable)


#: Warnings the console script has printed: each text once per command (a recording with
#: few valid pixels warned again for every sequence made from it, e.g. a filtered result).
_SHOWN_WARNINGS: set[str] = set()


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` of the console script: ``fuse4d: warning: MESSAGE``, once."""
    text = str(message)
    if text in _SHOWN_WARNINGS:
        return
    _SHOWN_WARNINGS.add(text)
    print(f"fuse4d: warning: {text}", file=sys.stderr if file is None else file)


def _tidy_help(command) -> None:
    """What ``--help`` shows: each command's docstring reflowed (``_reflow``), and no type
    column for a flag (typer >= 0.2x shows ``--small <bool>``, as if it took a value; click
    itself never shows a flag's metavar, so an empty one changes only typer's panel)."""
    subcommands = list(getattr(command, "commands", {}).values())
    for sub in subcommands:
        sub.help = _reflow(sub.help)
    for cmd in [command, *subcommands]:
        help_option = cmd.get_help_option(cmd.context_class(cmd))  # created once, cached
        for param in [*cmd.params, help_option]:
            if getattr(param, "is_flag", False) and param.metavar is None:
                param.metavar = ""


def _reflow(text: str | None) -> str | None:
    """A docstring's paragraphs each on one line, so that ``--help`` wraps them to the
    terminal's width (typer >= 0.2x keeps a docstring's single line breaks, and at 80
    columns every source line then ends in a ragged break)."""
    if not text:
        return text
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(" ".join(line.strip() for line in p.splitlines()) for p in paragraphs)


def _debug() -> bool:
    return STATE.debug or os.environ.get("FUSE4D_DEBUG", "") not in ("", "0")


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    message = text.splitlines()[0] if text else type(exc).__name__
    filename = getattr(exc, "filename", None)
    if isinstance(exc, OSError) and filename and str(filename) not in message:
        message = f"{filename}: {message}"
    return message


def _finish(code: int, argv: Sequence[str] | None) -> int:
    if argv is None:  # console-script use
        sys.exit(code)
    return code
