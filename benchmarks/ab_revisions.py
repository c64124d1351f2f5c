"""Is this checkout faster than another revision? Paired, alternating engine timings.

On a machine whose neighbours move a run's time by 10-20 %, a 3-5 % change in fuse4d's speed
does not show in one run of each. This script times the engine (``fuse4d bench``'s
:func:`fuse4d.experiments.speed.benchmark_pipeline`: the frames in memory, no I/O) of two
source trees in *pairs* of fresh processes, base and new back to back, the order alternating
from pair to pair, and reports the median of the per-pair ratios new / base with a bootstrap
interval: the machine's drift cancels within a pair.

* ``BASE``: a git revision (checked out into a temporary worktree, removed afterwards) or a
  folder holding a ``src/fuse4d`` tree.
* ``--new``: the same; default this checkout (uncommitted edits included).

Each side keeps its own numba cache (beside its sources); each process warms up on a few
frames first and reports the best of ``--runs`` timed runs, with that run's stage split
(``fuse4d bench``'s stages): below the summary, each stage's medians and the median of its
per-pair ratios, which shows a change confined to one stage that the total's noise hides.

Usage::

    python benchmarks/ab_revisions.py BASE [--new REV_OR_DIR] [--input REC | --ball]
        [--window 9] [--causal] [--frames 30] [--pairs 10] [--runs 2] [--json]

REC defaults to the person recording of the ``real`` experiment
(:func:`fuse4d.experiments.paper.real.data_dir`: ``$FUSE4D_DATA``, else ``../shared/data``);
``--ball`` times the synthetic 600 x 600 bench instead.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: the child: one side's timings, as JSON on its last line of stdout
_CHILD = r"""
import json, sys
from pathlib import Path
from fuse4d import load_sequence
from fuse4d.experiments.speed import benchmark_pipeline
rec, window, causal, frames, runs = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1", int(sys.argv[4]), int(sys.argv[5])
seq = None if rec == "-" else load_sequence(Path(rec), frames=slice(0, frames))
kw = {"sequence": seq, "window": window, "causal": causal}
benchmark_pipeline("fast", num_frames=min(frames, 6), **kw)
runs = [benchmark_pipeline("fast", num_frames=frames, **kw) for _ in range(runs)]
print(json.dumps([[r.ms_per_frame, getattr(r, "stage_ms", {})] for r in runs]))
"""


@contextlib.contextmanager
def source_tree(spec: str | None) -> Iterator[Path]:
    """The ``src`` folder of ``spec``: this checkout (None), a folder, or a git revision
    checked out into a temporary worktree for the duration."""
    if spec is None:
        yield REPO / "src"
        return
    folder = Path(spec).resolve()  # the child runs elsewhere (cwd: the temp folder)
    if (folder / "src" / "fuse4d").is_dir():
        yield folder / "src"
        return
    with tempfile.TemporaryDirectory(prefix="fuse4d-ab-") as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(
            ["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(tree), spec],
            check=True,
        )
        try:
            yield tree / "src"
        finally:
            subprocess.run(
                ["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], check=False
            )


def time_side(src: Path, args: argparse.Namespace, rec: str) -> tuple[float, dict[str, float]]:
    """Best ms per frame of one fresh process running ``src``'s engine, and the stage split
    (ms per frame) of that run."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    cmd = [sys.executable, "-c", _CHILD, rec, str(args.window), str(int(args.causal))]
    cmd += [str(args.frames), str(args.runs)]
    done = subprocess.run(
        cmd, env=env, capture_output=True, text=True, cwd=tempfile.gettempdir(), check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"timing {src} failed:\n{done.stderr[-3000:]}")
    total, stages = min(json.loads(done.stdout.strip().splitlines()[-1]), key=lambda r: r[0])
    return total, stages


def stage_summary(base: list[dict[str, float]], new: list[dict[str, float]]) -> dict:
    """Per stage (those timed in every run of both sides): the medians (ms per frame) and the
    median of the per-pair ratios new / base (stages at 0 ms in a base run are skipped)."""
    names = [k for k in base[0] if all(k in d for d in base + new)]
    out = {}
    for k in names:
        ratios = [n[k] / b[k] for b, n in zip(base, new, strict=True) if b[k] > 0]
        out[k] = {
            "base_median_ms": statistics.median(d[k] for d in base),
            "new_median_ms": statistics.median(d[k] for d in new),
            "ratio_median": statistics.median(ratios) if ratios else float("nan"),
        }
    return out


def paired_summary(base: list[float], new: list[float], seed: int = 0) -> dict[str, float]:
    """Median of the ratios new / base of each pair, its bootstrap 90 % interval (2000
    resamples of the pairs) and the number of pairs in which new was faster."""
    ratios = [n / b for b, n in zip(base, new, strict=True)]
    rng = random.Random(seed)
    boot = sorted(statistics.median(rng.choices(ratios, k=len(ratios))) for _ in range(2000))
    return {
        "ratio_median": statistics.median(ratios),
        "ratio_low": boot[100],
        "ratio_high": boot[1899],
        "new_faster": sum(r < 1.0 for r in ratios),
        "pairs": len(ratios),
        "base_median_ms": statistics.median(base),
        "new_median_ms": statistics.median(new),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", help="git revision or folder with src/fuse4d")
    parser.add_argument("--new", default=None, help="git revision or folder (default: here)")
    parser.add_argument("--input", type=Path, default=None, help="recording (default: uva)")
    parser.add_argument("--ball", action="store_true", help="the synthetic 600x600 bench")
    parser.add_argument("--window", type=int, default=9, help="frames fused per output")
    parser.add_argument("--causal", action="store_true", help="the causal engine")
    parser.add_argument("--frames", type=int, default=30, help="frames timed per run")
    parser.add_argument("--pairs", type=int, default=10, help="pairs of processes")
    parser.add_argument("--runs", type=int, default=2, help="timed runs per process (best)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args(argv)
    for name in ("window", "frames", "pairs", "runs"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1, got {getattr(args, name)}")
    if args.ball:
        rec = "-"
    else:
        if args.input is None:
            from fuse4d.experiments.paper.real import RECORDINGS, data_dir

            args.input = data_dir() / RECORDINGS["person"]
        if not args.input.exists():
            raise SystemExit(f"{args.input}: no such recording (give --input, or --ball)")
        rec = str(args.input.resolve())  # the child runs in the temp folder
    base_ms: list[float] = []
    new_ms: list[float] = []
    base_stages: list[dict[str, float]] = []
    new_stages: list[dict[str, float]] = []
    with source_tree(args.base) as base_src, source_tree(args.new) as new_src:
        for i in range(args.pairs):
            order = [("base", base_src), ("new", new_src)]
            if i % 2:  # every other pair starts with new
                order.reverse()
            got = {name: time_side(src, args, rec) for name, src in order}
            (b, b_stages), (n, n_stages) = got["base"], got["new"]
            base_ms.append(b)
            new_ms.append(n)
            base_stages.append(b_stages)
            new_stages.append(n_stages)
            if not args.json:
                print(
                    f"pair {i + 1}: base {b:.1f}, new {n:.1f} ms/frame, new / base {n / b:.3f}",
                    flush=True,
                )
    summary = paired_summary(base_ms, new_ms)
    stages = stage_summary(base_stages, new_stages)
    what = "the ball" if args.ball else args.input.name
    mode = f"{'causal' if args.causal else 'centred'} window {args.window}"
    if args.json:
        print(json.dumps({"input": what, "mode": mode, "base_ms": base_ms, "new_ms": new_ms,
                          **summary, "stages": stages}, indent=2))  # fmt: skip
        return
    print(
        f"{what}, {mode}, {args.frames} frames: base {summary['base_median_ms']:.1f}, new "
        f"{summary['new_median_ms']:.1f} ms/frame (medians); new / base, median of "
        f"{summary['pairs']} pairs: {summary['ratio_median']:.3f} (bootstrap 90 % "
        f"{summary['ratio_low']:.3f}-{summary['ratio_high']:.3f}); new faster in "
        f"{summary['new_faster']} of {summary['pairs']}"
    )
    if stages:
        print("stage (ms/frame, medians)   base     new   new / base (median of pairs)")
        for k, st in stages.items():
            print(
                f"  {k:24s} {st['base_median_ms']:7.2f} {st['new_median_ms']:7.2f}   "
                f"{st['ratio_median']:.3f}"
            )


if __name__ == "__main__":
    main()
