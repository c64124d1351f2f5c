"""Crash reports: what the CLI writes when fuse4d itself fails (a bug, exit code 70).

The report holds the traceback, the fuse4d/Python/NumPy/numba/OpenCV versions, the platform
and the command line; it is written atomically (temporary name + rename) to
``$FUSE4D_CRASH_DIR``, else ``$XDG_CACHE_HOME/fuse4d/crash`` (``~/.cache/fuse4d/crash``),
else the system temporary folder.
"""

from __future__ import annotations

import os
import platform
import sys
import tempfile
import time
import traceback
from collections.abc import Sequence
from pathlib import Path

__all__ = ["crash_dir", "write_crash_report"]


def crash_dir() -> list[Path]:
    """Folders tried for crash reports, in order."""
    env = os.environ.get("FUSE4D_CRASH_DIR")
    if env:
        return [Path(env)]
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return [Path(cache) / "fuse4d" / "crash", Path(tempfile.gettempdir()) / "fuse4d-crash"]


def _versions() -> list[str]:
    lines = []
    for name in ("fuse4d", "numpy", "numba", "cv2", "typer"):
        module = sys.modules.get(name)
        version = getattr(module, "__version__", None) if module else None
        lines.append(f"{name}: {version or 'not imported'}")
    return lines


def report_text(exc: BaseException, argv: Sequence[str]) -> str:
    """The text of a crash report for ``exc`` raised by ``fuse4d ARGV``."""
    tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    return "\n".join(
        [
            "fuse4d crash report (an internal error: a bug in fuse4d, not in your input)",
            f"time: {time.strftime('%Y-%m-%dT%H:%M:%S%z')}",
            "command: fuse4d " + " ".join(argv),
            f"python: {sys.version.split()[0]} ({sys.executable})",
            f"platform: {platform.platform()} ({platform.machine()})",
            *_versions(),
            "",
            tb,
        ]
    )


def write_crash_report(exc: BaseException, argv: Sequence[str]) -> Path | None:
    """Write a crash report for ``exc``; returns its path, or None if no folder was writable."""
    text = report_text(exc, argv)
    name = f"crash-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.txt"
    for folder in crash_dir():
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=".crash-", suffix=".tmp", dir=folder)
            try:
                with os.fdopen(fd, "w", encoding="utf-8") as handle:
                    handle.write(text)
                final = folder / name
                Path(tmp).replace(final)
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        except OSError:
            continue
        return final
    return None
