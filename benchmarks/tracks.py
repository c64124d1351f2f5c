"""Composed vs exact tracks (A31, issue 13): speed in one process, alternating.

Runs the streaming engine (fast preset, window 9) over the synthetic 600x600 ball and, where
``../shared/data/uva_cv2_person_turning`` exists, over its first frames in memory (no I/O),
with ``tracks="exact"`` and ``tracks="composed"`` in turn, and prints the medians of wall and
CPU time per frame and of the flow and tracking stages.

Usage::

    python benchmarks/tracks.py [--frames 36] [--real-frames 30] [--repeats 4] [--causal]
                                [--window 9]

With composed tracks the holes of frame t (A26) are chained by the separate time-fill kernel
instead of beside the exact tracks, so the fill stage is printed too.
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np

from fuse4d.config import preset
from fuse4d.fusion import STAGES, FusionEngine
from fuse4d.synthetic import make_falling_ball

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "uva_cv2_person_turning"
MODES = ("exact", "composed")


def _run(
    frames, intrinsics, tracks: str, causal: bool, window: int
) -> tuple[float, float, dict[str, float]]:
    """Wall and CPU ms per frame and the stage ms per frame of one engine run."""
    fusion = preset("fast").fusion.replace(tracks=tracks, causal=causal, num_frames=window)
    timings = dict.fromkeys(STAGES, 0.0)
    engine = FusionEngine(intrinsics, fusion=fusion, flow=preset("fast").flow, timings=timings)
    t0, c0 = time.perf_counter(), time.process_time()
    for depth, intensity in frames:
        engine.push(depth, intensity)
    engine.flush()
    n = len(frames)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return 1000 * wall / n, 1000 * cpu / n, {k: 1000 * v / n for k, v in timings.items()}


def _compare(name, frames, intrinsics, repeats: int, causal: bool, window: int) -> None:
    for tracks in MODES:  # warm-up: kernels loaded
        _run(frames[:5], intrinsics, tracks, causal, window)
    runs: dict[str, list] = {m: [] for m in MODES}
    for _ in range(repeats):
        for tracks in MODES:
            runs[tracks].append(_run(frames, intrinsics, tracks, causal, window))
    for tracks, rs in runs.items():
        wall = np.median([r[0] for r in rs])
        cpu = np.median([r[1] for r in rs])
        flow = np.median([r[2]["flow"] for r in rs])
        tracking = np.median([r[2]["tracking"] for r in rs])
        fill = np.median([r[2]["fill"] for r in rs])
        print(
            f"{name:10s} {tracks:9s} wall {wall:6.1f} ms/frame (runs "
            f"{', '.join(f'{r[0]:.1f}' for r in rs)}), CPU {cpu:6.1f}, flow {flow:5.1f}, "
            f"tracking {tracking:5.1f}, fill {fill:5.1f}, wall / flow {wall / flow:4.2f}"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=36, help="synthetic ball frames")
    ap.add_argument("--real-frames", type=int, default=30, help="uva frames (0: skip)")
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--causal", action="store_true")
    ap.add_argument("--window", type=int, default=9, help="frames fused per output")
    args = ap.parse_args(argv)
    seq = make_falling_ball(num_frames=args.frames)
    ball = list(zip(seq.depth, seq.intensity, strict=True))
    _compare("ball 600", ball, seq.intrinsics, args.repeats, args.causal, args.window)
    if args.real_frames > 0 and REAL.is_dir():
        from fuse4d.io import open_frames

        with open_frames(REAL) as reader:
            first = itertools.islice(reader, args.real_frames)
            real = [(f.depth, f.intensity) for f in first]
            intrinsics = reader.intrinsics
        _compare("uva", real, intrinsics, args.repeats, args.causal, args.window)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
