"""The paper's evaluation, end to end: EVALUATION.md §4 (E1-E6), the real recordings, §6 verdicts.

``fuse4d experiments NAME --out DIR [--profile paper|reduced|quick] [--jobs N]`` runs one
experiment (or ``all``) and writes, per experiment, ``DIR/<NAME>/``:

* ``<NAME>.csv`` — tidy rows, one per method x setting x seed x frame;
* ``<NAME>.md`` — the summary table(s);
* ``*.png`` — the plots in the paper's form;
* ``<NAME>.json`` — every parameter (profile, method settings), the package version and the
  wall time, so that a rerun is exact.

Finished units are kept in ``DIR/<NAME>/rows/``: an interrupted run resumes where it stopped.
``fuse4d experiments verdicts --out DIR`` computes the claims C1-C12 from the CSVs;
``--publish DOCS`` copies the small outputs (no row files, no flow cache) to a folder that can
be committed, and ``--report REPRODUCTION.md`` rewrites that report's verdict table from them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

from rich.console import Console

from ._common import Context
from ._config import PROFILES, Profile, get_profile
from ._runner import run_units, write_json, write_rows

__all__ = ["EXPERIMENTS", "PROFILES", "Profile", "get_profile", "publish", "run_experiment"]

#: Experiment names in run order (``all`` runs them in this order).
EXPERIMENTS: tuple[str, ...] = ("E1", "E2", "E3", "E4", "E5", "E6", "real")


def _module(name: str) -> ModuleType:
    import importlib

    return importlib.import_module(f".{'real' if name == 'real' else name.lower()}", __name__)


def run_experiment(
    name: str,
    out: str | Path,
    *,
    profile: str | Profile = "paper",
    jobs: int = 1,
    console: Console | None = None,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run experiment ``name`` (resuming), write its CSV, summary, plots and JSON.

    Parameters
    ----------
    name : str
        One of :data:`EXPERIMENTS`.
    out : path
        Run folder; the experiment writes ``out/<name>/``.
    profile : str or Profile
        Run size (:data:`PROFILES`).
    jobs : int
        Worker processes.
    console : rich Console, optional
        Progress-bar console.
    log : callable, optional
        One line per finished unit.

    Returns
    -------
    dict
        The JSON written to ``out/<name>/<name>.json``.
    """
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}")
    prof = get_profile(profile) if isinstance(profile, str) else profile
    ctx = Context(prof, Path(out))
    mod = _module(name)
    exp_dir = ctx.exp_dir(name)
    exp_dir.mkdir(parents=True, exist_ok=True)
    _claim_folder(exp_dir, name, prof)
    units = mod.units(ctx)
    ledger = exp_dir / f".{name}-seconds"  # every call's compute time, an interrupted one too
    before = _previous_seconds(ledger, exp_dir / f"{name}.json")
    t0 = time.perf_counter()
    try:
        rows, seconds = run_units(
            name,
            units,
            exp_dir,
            jobs=jobs,
            console=console,
            log=log,
            columns=getattr(mod, "ROW_COLUMNS", ()),
        )
    except BaseException:  # Ctrl-C: its time counts in the resumed run's total
        _add_seconds(ledger, before + time.perf_counter() - t0)
        raise
    _add_seconds(ledger, before + seconds)
    write_rows(exp_dir / f"{name}.csv", rows)
    summary = mod.summarize(ctx, rows)
    payload = {
        "experiment": name,
        "title": mod.TITLE,
        "profile": prof.to_dict(),
        "parameters": mod.parameters(ctx) if hasattr(mod, "parameters") else {},
        "units": len(units),
        "rows": len(rows),
        "seconds_this_call": round(seconds, 1),
        # compute time summed over every (resumed) call of this run folder
        "seconds_compute_total": round(before + seconds, 1),
        "seconds_total_with_summary": round(time.perf_counter() - t0, 1),
        "summary": summary,
    }
    write_json(exp_dir / f"{name}.json", payload)
    return payload


def _claim_folder(exp_dir: Path, name: str, prof: Profile) -> None:
    """Record which profile and fuse4d version fill ``exp_dir`` (``.<name>-run.json``), and
    refuse another: a unit's rows are kept by key alone, so a ``--profile reduced`` run in a
    ``--quick`` run's folder took its 150x150 rows as done and mixed them with 600x600 ones.

    Raises
    ------
    ParameterError
        The folder holds rows of another profile or fuse4d version.
    """
    import json

    from ..._version import __version__
    from ...errors import ParameterError

    stamp = exp_dir / f".{name}-run.json"
    mine = {"profile": prof.to_dict(), "fuse4d": __version__}
    mine = json.loads(json.dumps(mine))  # tuples as lists, as read back
    if stamp.exists():
        try:
            theirs = json.loads(stamp.read_text())
        except ValueError:
            theirs = None
        if theirs != mine:
            was = theirs.get("profile", {}).get("name") if isinstance(theirs, dict) else None
            raise ParameterError(
                f"{exp_dir}: holds the rows of a {name} run with another profile "
                f"({was or 'unknown'}) or fuse4d version, which this {prof.name} run would "
                "take as its own; use another --out (or delete the folder)"
            )
        return
    tmp = stamp.with_name(stamp.name + ".tmp")
    tmp.write_text(json.dumps(mine, indent=2) + "\n")
    tmp.replace(stamp)


def _previous_seconds(ledger: Path, json_path: Path) -> float:
    """Compute seconds of the earlier calls on this run folder: the ledger, else (a folder
    from before it) the last JSON's total."""
    import json

    if ledger.exists():
        try:
            return float(ledger.read_text().strip() or 0.0)
        except ValueError:
            return 0.0
    if not json_path.exists():
        return 0.0
    old = json.loads(json_path.read_text())
    return float(old.get("seconds_compute_total", old.get("seconds_this_call", 0.0)))


def _add_seconds(ledger: Path, total: float) -> None:
    """Record the compute seconds of every call so far (a one-number file, replaced whole)."""
    tmp = ledger.with_name(ledger.name + ".tmp")
    tmp.write_text(f"{total:.3f}\n")
    tmp.replace(ledger)


def publish(out: str | Path, dest: str | Path) -> list[Path]:
    """Copy a run's small outputs (CSV, Markdown, JSON, PNG per experiment) to ``dest``.

    Row files, the flow cache and intermediate arrays stay behind, so ``dest`` can be
    committed (``docs/reproduction``). Returns the copied files.
    """
    import shutil

    src, dst = Path(out), Path(dest)
    copied = []
    for name in EXPERIMENTS:
        d = src / name
        if not (d / f"{name}.csv").exists():
            continue
        (dst / name).mkdir(parents=True, exist_ok=True)
        for f in sorted(d.iterdir()):
            # not the hidden bookkeeping (.<name>-run.json, .<name>-seconds)
            if f.is_file() and f.suffix in (".csv", ".md", ".json", ".png") and f.name[0] != ".":
                shutil.copy2(f, dst / name / f.name)
                copied.append(dst / name / f.name)
    return copied
