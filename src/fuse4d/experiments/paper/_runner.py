"""Run an experiment's work units with resume, progress and optional worker processes.

An experiment is a list of :class:`Unit` s; each unit is one (method, setting, seed) and
returns its tidy rows (one per frame). A finished unit's rows are written atomically to
``DIR/<experiment>/rows/<key>.csv``; on a rerun every unit whose row file exists is skipped, so a
run interrupted with Ctrl-C resumes where it stopped and finished rows are never recomputed.
At the end all row files are concatenated into ``DIR/<experiment>/<experiment>.csv``.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from ..._version import __version__

__all__ = [
    "Unit",
    "read_rows",
    "run_units",
    "unit_file",
    "write_json",
    "write_rows",
]

Row = dict[str, Any]


@dataclass(frozen=True)
class Unit:
    """One piece of work: ``func(**kwargs)`` returns the unit's rows.

    Attributes
    ----------
    key : str
        Unique name within the experiment (becomes the row file's name).
    func : callable
        A module-level function (picklable, for worker processes).
    kwargs : dict
        Its keyword arguments (picklable).
    """

    key: str
    func: Callable[..., list[Row]]
    kwargs: dict[str, Any] = field(default_factory=dict)


def unit_file(exp_dir: Path, key: str) -> Path:
    """Path of the row file of unit ``key``."""
    safe = re.sub(r"[^A-Za-z0-9_.=+-]", "_", key)
    return exp_dir / "rows" / f"{safe}.csv"


def write_rows(path: Path, rows: Iterable[Row]) -> None:
    """Write rows as CSV atomically (the union of their keys as columns, first-seen order)."""
    rows = list(rows)
    columns: list[str] = []
    for row in rows:
        columns.extend(k for k in row if k not in columns)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with tmp.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns, restval="")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _fmt(v) for k, v in row.items()})
    tmp.replace(path)


def _fmt(value: Any) -> Any:
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.6g}"  # NaN -> empty
    return value


def read_rows(path: Path) -> list[Row]:
    """Read a CSV written by :func:`write_rows`; numbers become float, empty cells NaN."""
    with Path(path).open(newline="") as fh:
        return [{k: _parse(v) for k, v in row.items()} for row in csv.DictReader(fh)]


def _parse(text: str | None) -> Any:
    if text is None or text == "":
        return float("nan")
    try:
        return float(text)
    except ValueError:
        return text


def write_json(path: Path, payload: Mapping[str, Any]) -> None:
    """Write ``payload`` (plus the package version) as indented JSON, atomically."""
    data = {"fuse4d_version": __version__, **payload}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=False, default=str) + "\n")
    tmp.replace(path)


def _progress(console: Console | None) -> Progress:
    console = console or Console(stderr=True)
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=console,
        disable=not console.is_terminal,
    )


def run_units(
    name: str,
    units: list[Unit],
    exp_dir: Path,
    *,
    jobs: int = 1,
    console: Console | None = None,
    log: Callable[[str], None] | None = None,
    columns: Iterable[str] = (),
) -> tuple[list[Row], float]:
    """Run the units not done yet, then return every unit's rows (in unit order).

    Parameters
    ----------
    name : str
        Experiment name (progress-bar label).
    units : list of Unit
        All units of the experiment; keys must be unique.
    exp_dir : Path
        The experiment's output folder.
    jobs : int
        Worker processes (1 = run in this process).
    console : rich Console, optional
        Where the progress bar goes (stderr by default; hidden when not a terminal).
    log : callable, optional
        Receives one line per finished unit (e.g. for a log file when there is no terminal).
    columns : iterable of str
        Columns the experiment's summary reads: a unit whose row file (from an earlier
        version of the experiment) lacks one is run again, so that its figures are not n/a.

    Returns
    -------
    rows : list of dict
        All rows, finished before or now.
    seconds : float
        Wall time spent in this call on new units.
    """
    keys = [u.key for u in units]
    if len(set(keys)) != len(keys):
        raise ValueError(f"{name}: duplicate unit keys")
    todo = [u for u in units if not _is_done(unit_file(exp_dir, u.key), columns)]
    start = time.perf_counter()
    with _progress(console) as progress:
        task = progress.add_task(name, total=len(units), completed=len(units) - len(todo))

        def finished(unit: Unit, rows: list[Row], seconds: float) -> None:
            # every row carries its unit's wall time: compute time survives kills and resumes
            rows = [{**r, "unit_seconds": round(seconds, 2)} for r in rows]
            write_rows(unit_file(exp_dir, unit.key), rows)
            progress.advance(task)
            if log is not None:
                done = progress.tasks[0].completed
                log(f"{name}: {unit.key} ({seconds:.1f} s) [{done:.0f}/{len(units)}]")

        if jobs <= 1 or len(todo) <= 1:
            for unit in todo:
                t0 = time.perf_counter()
                rows = unit.func(**unit.kwargs)
                finished(unit, rows, time.perf_counter() - t0)
        else:
            _run_parallel(todo, jobs, finished)
    rows: list[Row] = []
    for key in keys:
        rows.extend(read_rows(unit_file(exp_dir, key)))
    return rows, time.perf_counter() - start


def _is_done(path: Path, columns: Iterable[str]) -> bool:
    """Whether the row file ``path`` exists and has every one of ``columns``."""
    if not path.exists():
        return False
    needed = set(columns)
    if not needed:
        return True
    with path.open(newline="") as f:
        header = next(csv.reader(f), [])
    return needed <= set(header)


def _timed(func: Callable[..., list[Row]], kwargs: dict[str, Any]) -> tuple[list[Row], float]:
    t0 = time.perf_counter()
    rows = func(**kwargs)
    return rows, time.perf_counter() - t0


def _run_parallel(
    todo: list[Unit], jobs: int, finished: Callable[[Unit, list[Row], float], None]
) -> None:
    # spawn, not fork: numba and OpenCV hold threads, and forking a threaded process is unsafe
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
        pending: dict[Future[tuple[list[Row], float]], Unit] = {
            pool.submit(_timed, u.func, u.kwargs): u for u in todo
        }
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    unit = pending.pop(fut)
                    rows, seconds = fut.result()
                    finished(unit, rows, seconds)
        except BaseException:
            for fut in pending:
                fut.cancel()
            raise
