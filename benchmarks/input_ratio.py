"""Is a real recording fused as fast per pixel as the synthetic bench? (issue 13 target)

Issue 13 asks ``fuse4d bench --input`` on ``uva_cv2_person_turning`` (640 x 480, I/O
included) to cost at most 1.2x the synthetic bench (600 x 600 ball) per pixel. One run of
each says little on a machine whose neighbours move timings by 10-20 %, so each round here
times, back to back in one process:

* ``synthetic``: ``fuse4d bench`` (the engine on the ball, in memory);
* ``stream``: ``fuse4d bench --input REC --no-summary`` (``fuse4d run``'s streaming path: the
  read-ahead and write-behind threads decode and encode PNGs beside the fusion);
* ``engine``: the same frames of REC loaded into memory first, the engine alone
  (:func:`fuse4d.experiments.speed.benchmark_pipeline` with ``sequence=``): what the recording
  costs without its I/O.

and prints each round's µs per pixel, the ratios ``stream / synthetic`` (the target) and
``engine / synthetic`` (the recording's own compute: its holes, its motion), and the median
ms per frame of every stage over the rounds.

Usage::

    python benchmarks/input_ratio.py [--input REC] [--frames 18] [--window 9] [--causal]
        [--repeats 3] [--json]

REC defaults to the person recording of the ``real`` experiment in its data folder
(:func:`fuse4d.experiments.paper.real.data_dir`: ``$FUSE4D_DATA``, else ``../shared/data``).
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from fuse4d import load_sequence
from fuse4d.experiments.paper.real import RECORDINGS, data_dir
from fuse4d.experiments.speed import BenchResult, benchmark_pipeline, benchmark_recording

KINDS = ("synthetic", "stream", "engine")


def _round(rec: Path, sequence, args) -> dict[str, BenchResult]:
    common = {"num_frames": args.frames, "window": args.window, "causal": args.causal}
    return {
        "synthetic": benchmark_pipeline("fast", **common),
        "stream": benchmark_recording(rec, "fast", summary=False, **common),
        "engine": benchmark_pipeline("fast", sequence=sequence, **common),
    }


def _over_synthetic(runs: dict[str, BenchResult], kind: str) -> float:
    """µs per pixel of ``kind`` relative to the synthetic bench of the same round."""
    return runs[kind].us_per_pixel / runs["synthetic"].us_per_pixel


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--input", type=Path, default=None, help="recording (default: uva)")
    parser.add_argument("--frames", type=int, default=18, help="frames timed per run")
    parser.add_argument("--window", type=int, default=9, help="frames fused per output")
    parser.add_argument("--causal", action="store_true", help="the causal engine")
    parser.add_argument("--repeats", type=int, default=3, help="rounds of the three runs")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    if args.frames < 2:  # the synthetic bench renders at least 2 frames
        parser.error(f"--frames must be >= 2, got {args.frames}")
    if args.window < 1:
        parser.error(f"--window must be >= 1, got {args.window}")
    rec = args.input or data_dir() / RECORDINGS["person"]
    if not rec.exists():
        raise SystemExit(f"{rec}: no such recording (give --input or set FUSE4D_DATA)")
    sequence = load_sequence(rec, frames=slice(0, args.frames))
    rounds = []
    for i in range(args.repeats):
        runs = _round(rec, sequence, args)
        rounds.append(runs)
        if not args.json:
            us = {k: r.us_per_pixel for k, r in runs.items()}
            print(
                f"round {i + 1}: µs/px synthetic {us['synthetic']:.3f}, stream "
                f"{us['stream']:.3f}, engine {us['engine']:.3f}; stream / synthetic "
                f"{_over_synthetic(runs, 'stream'):.2f}, engine / synthetic "
                f"{_over_synthetic(runs, 'engine'):.2f}",
                flush=True,
            )
    stream_ratio = [_over_synthetic(runs, "stream") for runs in rounds]
    engine_ratio = [_over_synthetic(runs, "engine") for runs in rounds]
    stages = {
        kind: {
            stage: statistics.median(runs[kind].stage_ms[stage] for runs in rounds)
            for stage in rounds[0][kind].stage_ms
        }
        for kind in KINDS
    }
    ms = {kind: statistics.median(runs[kind].ms_per_frame for runs in rounds) for kind in KINDS}
    if args.json:
        print(
            json.dumps(
                {
                    "input": str(rec),
                    "frames": args.frames,
                    "window": args.window,
                    "causal": args.causal,
                    "rounds": [{k: r.to_dict() for k, r in runs.items()} for runs in rounds],
                    "stream_over_synthetic": stream_ratio,
                    "engine_over_synthetic": engine_ratio,
                    "median_ms_per_frame": ms,
                    "median_stage_ms": stages,
                },
                indent=2,
            )
        )
        return
    print(
        f"stream / synthetic per pixel: median {statistics.median(stream_ratio):.2f} "
        f"(range {min(stream_ratio):.2f}-{max(stream_ratio):.2f}; issue 13 target <= 1.2); "
        f"engine / synthetic: median {statistics.median(engine_ratio):.2f}"
    )
    names = list(stages["stream"])
    widths = [max(7, len(n)) for n in ["total", *names]]
    print(
        "median ms/frame "
        + " ".join(f"{n:>{w}}" for n, w in zip(["total", *names], widths, strict=True))
    )
    for kind in KINDS:
        values = [ms[kind]] + [stages[kind].get(n) for n in names]
        cells = [
            f"{'-':>{w}}" if v is None else f"{v:{w}.1f}"
            for v, w in zip(values, widths, strict=True)
        ]
        print(f"{kind:>15} " + " ".join(cells))


if __name__ == "__main__":
    main()
