"""CLI command: ``experiments`` — the paper's evaluation (E1-E6, real) and the C1-C12 verdicts."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from ._app import STATE, app, eprint, err_console, fail

_NAMES = ("E1", "E2", "E3", "E4", "E5", "E6", "real", "all", "verdicts")


@app.command("experiments")
def experiments_command(
    name: Annotated[
        str,
        typer.Argument(
            help="E1, E2, E3, E4, E5, E6, real, all (every experiment in order), or verdicts "
            "(claims C1-C12 from the CSVs in --out)."
        ),
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="Run folder (created; resumed).")],
    quick: Annotated[
        bool, typer.Option("--quick", help="CI size: 150x150 scenes, 12 frames, one seed.")
    ] = False,
    profile: Annotated[
        str,
        typer.Option(
            "--profile",
            help="Run size: paper (the full protocol), reduced (600x600, short sequences, one "
            "seed) or quick (= --quick).",
        ),
    ] = "paper",
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Worker processes.", min=1)] = 1,
    report: Annotated[
        Path | None,
        typer.Option(
            "--report",
            help="With verdicts: rewrite the generated block of this Markdown file "
            "(e.g. REPRODUCTION.md; created or appended to where it has none).",
        ),
    ] = None,
    publish_to: Annotated[
        Path | None,
        typer.Option(
            "--publish",
            help="After the run: copy CSV/Markdown/JSON/PNG (no row files, no flow cache) to "
            "this folder, e.g. docs/reproduction; --report then judges the claims from it.",
        ),
    ] = None,
    log_file: Annotated[
        Path | None, typer.Option("--log", help="Append one line per finished unit to this file.")
    ] = None,
) -> None:
    """Reproduce the paper's experiments (its Section 4; REPRODUCTION.md) into OUT/<name>/: tidy CSV,
    Markdown summary, PNG plots and a JSON of every parameter. Ctrl-C and rerun to resume."""
    from ..experiments.paper import EXPERIMENTS, publish, run_experiment
    from ..experiments.paper.verdicts import compute_verdicts, update_report, verdict_table

    if name not in _NAMES:
        fail(f"unknown experiment {name!r}; choose one of {', '.join(_NAMES)}")
    if report is not None and (report.is_dir() or not report.parent.is_dir()):
        fail(f"--report {report}: not a Markdown file in an existing folder")
    if name == "verdicts":
        if not out.is_dir():
            fail(f"--out {out}: no such run folder")
        if not any((out / n / f"{n}.csv").is_file() for n in EXPERIMENTS):
            fail(
                f"--out {out} holds no experiment results ({', '.join(EXPERIMENTS)}); "
                f"run `fuse4d experiments all -o {out}` first"
            )
        verdicts = compute_verdicts(out)
        print(verdict_table(verdicts), end="")
        if report is not None:
            update_report(report, out)
            eprint(f"updated {report}")
        return
    prof = _profile_name(quick, profile)
    if report is not None and publish_to is None:
        fail("--report judges published results: pass --publish DIR too, or use `verdicts`")
    _prepare(out, "--out")
    _prepare(publish_to, "--publish")
    _prepare(log_file, "--log", folder=False)

    def log(line: str) -> None:
        if log_file is not None:
            with log_file.open("a") as fh:
                fh.write(f"{time.strftime('%H:%M:%S')} {line}\n")

    names = list(EXPERIMENTS) if name == "all" else [name]
    for n in names:
        t0 = time.perf_counter()
        try:
            result = run_experiment(n, out, profile=prof, jobs=jobs, console=err_console, log=log)
        except KeyboardInterrupt:
            # main prints it as its one line: "fuse4d: interrupted during E1: ..." (exit 130)
            STATE.interrupt_note = (
                f"during {n}: finished units are kept; rerun the same command to resume"
            )
            log(f"interrupted {STATE.interrupt_note}")
            raise
        msg = (
            f"{n}: {result['units']} units, {result['rows']} rows, "
            f"{time.perf_counter() - t0:.0f} s -> {out / n}"
        )
        log(msg)
        eprint(msg)
    if publish_to is not None:
        files = publish(out, publish_to)
        eprint(f"published {len(files)} files to {publish_to}")
        if report is not None:
            update_report(report, publish_to)
            eprint(f"updated {report}")


def _profile_name(quick: bool, profile: str) -> str:
    """The run-size profile that ``--quick`` / ``--profile`` ask for (a clear error on a
    name that does not exist or on the two disagreeing)."""
    from ..experiments.paper import PROFILES

    if profile not in PROFILES:
        fail(f"--profile {profile!r}: choose one of {', '.join(PROFILES)}")
    if quick and profile not in ("paper", "quick"):  # paper is --profile's default
        fail(f"--quick asks for the quick profile, --profile for {profile!r}: pass one")
    return "quick" if quick else profile


def _prepare(path: Path | None, what: str, *, folder: bool = True) -> None:
    """Create the folder (or append-open the file) ``path`` now, so that a path that cannot
    be written fails before hours of compute, not after."""
    if path is None:
        return
    if folder and path.exists() and not path.is_dir():
        fail(f"{what} {path}: exists and is not a folder")
    try:
        if folder:
            path.mkdir(parents=True, exist_ok=True)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            with path.open("a"):
                pass
    except OSError as exc:
        fail(f"{what} {path}: cannot be {'created' if folder else 'written'} ({exc.strerror})")
