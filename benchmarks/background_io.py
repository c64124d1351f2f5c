"""Do the lowered I/O threads make ``fuse4d run`` faster? (issue 13; ``fuse4d/_background.py``)

Times ``fuse4d run``'s streaming path on a recording (``fuse4d bench --input REC
--no-summary``: read-ahead and write-behind threads, I/O included) in one process, in
rounds whose order alternates, two ways:

* ``lowered``: as fuse4d runs, the I/O threads drop to nice 19 once the fusion has taken two
  frames (Linux);
* ``normal``: :meth:`fuse4d._background.BackgroundLoop.lower_priority` patched out, the I/O
  threads stay at the fusion's priority (fuse4d before stop 50, with the flow overlapped).

``--load N`` starts N busy loops (other programs keeping the cores busy) for the whole
comparison: the case where the lowered threads starve and hand their work to
normal-priority threads. Prints each round, the medians, the per-round ratios lowered /
normal with a bootstrap interval (``ab_revisions.paired_summary``), and how many runs
handed over.

Usage::

    python benchmarks/background_io.py [--input REC] [--frames 30] [--window 9] [--causal]
        [--rounds 4] [--load 0] [--json]

REC defaults to the person recording of the ``real`` experiment in its data folder
(``$FUSE4D_DATA``, else ``../shared/data``).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import statistics
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from fuse4d import _background
from fuse4d.experiments.paper.real import RECORDINGS, data_dir
from fuse4d.experiments.speed import benchmark_recording

MODES = ("normal", "lowered")


def _paired_summary():
    """``paired_summary`` of the sibling ``ab_revisions.py`` (one home for the statistics)."""
    path = Path(__file__).with_name("ab_revisions.py")
    spec = importlib.util.spec_from_file_location("ab_revisions", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.paired_summary


@contextlib.contextmanager
def io_priority(lowered: bool, handovers: list[int]) -> Iterator[None]:
    """Run with the I/O threads lowered as fuse4d does (or never lowered); each hand-over of a
    lowered thread appends 1 to ``handovers``."""
    loop = _background.BackgroundLoop
    lower, promote_one = loop.lower_priority, loop._promote_one

    def counted(self: _background.BackgroundLoop) -> None:
        if self.lowered:
            handovers.append(1)
        promote_one(self)

    if not lowered:
        loop.lower_priority = lambda self: None  # type: ignore[method-assign]
    loop._promote_one = counted  # type: ignore[method-assign]
    try:
        yield
    finally:
        loop.lower_priority = lower  # type: ignore[method-assign]
        loop._promote_one = promote_one  # type: ignore[method-assign]


@contextlib.contextmanager
def busy_loops(n: int) -> Iterator[None]:
    """``n`` processes spinning on a core each, for as long as the block runs."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def compare(rec: Path, args: argparse.Namespace, echo: bool = True) -> dict:
    """The rounds of both modes; see the module doc."""
    ms: dict[str, list[float]] = {m: [] for m in MODES}
    stages: dict[str, list[dict[str, float]]] = {m: [] for m in MODES}
    handovers: dict[str, list[int]] = {m: [] for m in MODES}
    with busy_loops(args.load):
        for i in range(args.rounds):
            for mode in MODES if i % 2 == 0 else MODES[::-1]:
                with io_priority(mode == "lowered", handovers[mode]):
                    run = benchmark_recording(
                        rec,
                        "fast",
                        num_frames=args.frames,
                        window=args.window,
                        summary=False,
                        causal=args.causal,
                    )
                ms[mode].append(run.ms_per_frame)
                stages[mode].append(run.stage_ms)
            if echo:
                cells = ", ".join(f"{m} {ms[m][-1]:.1f}" for m in MODES)
                print(f"round {i + 1}: ms/frame {cells}", flush=True)
    return {
        "input": str(rec),
        "frames": args.frames,
        "window": args.window,
        "causal": args.causal,
        "load": args.load,
        "ms_per_frame": ms,
        "median_stage_ms": {
            m: {k: statistics.median(s[k] for s in stages[m]) for k in stages[m][0]} for m in MODES
        },
        "handovers": {m: len(h) for m, h in handovers.items()},
        "lowered_over_normal": _paired_summary()(ms["normal"], ms["lowered"]),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--input", type=Path, default=None, help="recording (default: uva)")
    parser.add_argument("--frames", type=int, default=30, help="frames timed per run")
    parser.add_argument("--window", type=int, default=9, help="frames fused per output")
    parser.add_argument("--causal", action="store_true", help="the causal engine")
    parser.add_argument("--rounds", type=int, default=4, help="rounds of the two modes")
    parser.add_argument("--load", type=int, default=0, help="busy loops beside the runs")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args(argv)
    for name in ("frames", "window", "rounds"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1, got {getattr(args, name)}")
    if args.load < 0:
        parser.error(f"--load must be >= 0, got {args.load}")
    rec = args.input or data_dir() / RECORDINGS["person"]
    if not rec.exists():
        raise SystemExit(f"{rec}: no such recording (give --input or set FUSE4D_DATA)")
    result = compare(rec, args, echo=not args.json)
    if args.json:
        print(json.dumps(result, indent=2))
        return
    s = result["lowered_over_normal"]
    for m in MODES:
        values = " ".join(f"{v:.1f}" for v in result["ms_per_frame"][m])
        median = statistics.median(result["ms_per_frame"][m])
        print(f"{m:>8}: median {median:.1f} ms/frame ({values})")
    print(
        f"lowered / normal per round: median {s['ratio_median']:.3f} (90 % "
        f"{s['ratio_low']:.3f}-{s['ratio_high']:.3f}), lowered faster in {s['new_faster']} of "
        f"{s['pairs']}; threads handed over (warm-ups included): "
        f"{result['handovers']['lowered']}"
    )
    for m in MODES:
        st = result["median_stage_ms"][m]
        print(f"{m:>8} stages: " + ", ".join(f"{k} {v:.1f}" for k, v in st.items()))


if __name__ == "__main__":
    main()
