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

REC defaults to ``$FUSE4D_DATA/uva_cv2_person_turning``, else
``../shared/data/uva_cv2_person_turning``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
from pathlib import Path

from fuse4d import load_sequence
from fuse4d.experiments.speed import BenchResult, benchmark_pipeline, benchmark_recording

KINDS = ("synthetic", "stream", "engine")


def _default_input() -> Path:
    root = os.environ.get("FUSE4D_DATA") or str(
        Path(__file__).resolve().parents[2] / "shared" / "data"
    )
    return Path(root) / "uva_cv2_person_turning"


def _round(rec: Path, sequence, args) -> dict[str, BenchResult]:
    common = {"num_frames": args.frames, "window": args.window, "causal": args.causal}
    return {
        "synthetic": benchmark_pipeline("fast", **common),
        "stream": benchmark_recording(rec, "fast", summary=False, **common),
        "engine": benchmark_pipeline("fast", sequence=sequence, **common),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--input", type=Path, default=None, help="recording (default: uva)")
    parser.add_argument("--frames", type=int, default=18, help="frames timed per run")
    parser.add_argument("--window", type=int, default=9, help="frames fused per output")
    parser.add_argument("--causal", action="store_true", help="the causal engine")
    parser.add_argument("--repeats", type=int, default=3, help="rounds of the three runs")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args()
    rec = args.input or _default_input()
    if not rec.exists():
        raise SystemExit(f"{rec}: no such recording (give --input or set FUSE4D_DATA)")
    sequence = load_sequence(rec, frames=slice(0, args.frames))
    rounds = []
    for i in range(args.repeats):
        runs = _round(rec, sequence, args)
        us = {k: r.us_per_pixel for k, r in runs.items()}
        rounds.append({"runs": runs, "us": us})
        if not args.json:
            print(
                f"round {i + 1}: µs/px synthetic {us['synthetic']:.3f}, stream "
                f"{us['stream']:.3f}, engine {us['engine']:.3f}; stream / synthetic "
                f"{us['stream'] / us['synthetic']:.2f}, engine / synthetic "
                f"{us['engine'] / us['synthetic']:.2f}",
                flush=True,
            )
    stream_ratio = [r["us"]["stream"] / r["us"]["synthetic"] for r in rounds]
    engine_ratio = [r["us"]["engine"] / r["us"]["synthetic"] for r in rounds]
    stages = {
        kind: {
            stage: statistics.median(r["runs"][kind].stage_ms[stage] for r in rounds)
            for stage in rounds[0]["runs"][kind].stage_ms
        }
        for kind in KINDS
    }
    ms = {kind: statistics.median(r["runs"][kind].ms_per_frame for r in rounds) for kind in KINDS}
    if args.json:
        print(
            json.dumps(
                {
                    "input": str(rec),
                    "frames": args.frames,
                    "window": args.window,
                    "causal": args.causal,
                    "rounds": [{k: r.to_dict() for k, r in rd["runs"].items()} for rd in rounds],
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
