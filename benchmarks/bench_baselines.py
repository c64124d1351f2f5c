"""Roughness, RMSE and ms/frame of every baseline on the synthetic scenes (600x600).

Usage::

    python benchmarks/bench_baselines.py                     # ball, 12 frames, all methods
    python benchmarks/bench_baselines.py --frames 50 --methods adbf,guided
    python benchmarks/bench_baselines.py --scene plane --methods kinectfusion,ed,temporal-mean

Prints a Markdown table: mean roughness Π (mm, ball ROI), RMS plane residual (mm), depth RMSE
to GT and the fraction of pixels > 1 mm off (on the GT object mask: the ball, or the square
plane itself, ~10 % of the frame, not the wall behind it), and ms/frame (wall time of the
whole call / frames, after a numba warm-up).
6D methods run on ``--frames-6d`` frames (they cost seconds per frame).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from fuse4d.baselines import available_baselines, run_baseline
from fuse4d.camera import depth_to_points
from fuse4d.metrics import bad_pixel_fraction, depth_rmse, roughness_stats
from fuse4d.metrics.roi import scene_roi
from fuse4d.synthetic import make_falling_ball, make_static_plane


def _scene(name: str, frames: int):
    if name == "ball":
        return make_falling_ball(depth_noise=0.2, intensity_noise=0.02, num_frames=frames, rng=0)
    return make_static_plane(num_frames=frames, rng=0)


def _evaluate(seq, depth: np.ndarray, points: np.ndarray, roi: np.ndarray) -> dict[str, float]:
    gt = seq.ground_truth
    mask = gt.mask if gt.mask is not None else np.isfinite(gt.depth)
    stats = roughness_stats(points, roi=roi)
    return {
        "rough": stats.mean,
        "rms": stats.rms_mean,
        "rmse": depth_rmse(gt.depth, depth, roi=mask),
        "bad": 100.0 * bad_pixel_fraction(gt.depth, depth, threshold=1.0, roi=mask),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=("ball", "plane"), default="ball")
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--frames-6d", type=int, default=9)
    parser.add_argument("--size-6d", type=int, default=None, help="temporal radius of 6D methods")
    parser.add_argument("--methods", default="all", help="comma list or 'all'")
    args = parser.parse_args(argv)
    for name in ("frames", "frames_6d"):
        if getattr(args, name) < 2:  # the synthetic scenes have at least 2 frames
            parser.error(f"--{name.replace('_', '-')} must be >= 2, got {getattr(args, name)}")
    if args.size_6d is not None and args.size_6d < 1:
        parser.error(f"--size-6d must be >= 1, got {args.size_6d}")
    infos = available_baselines()
    names = list(infos) if args.methods == "all" else args.methods.split(",")
    unknown = [n for n in names if n not in infos]
    if unknown:
        parser.error(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(infos)}")
    seq_full = _scene(args.scene, max(args.frames, args.frames_6d))
    print(
        f"scene={args.scene} {seq_full.shape} cpus={os.cpu_count()} "
        f"numba_threads={os.environ.get('NUMBA_NUM_THREADS', 'default')}",
        file=sys.stderr,
    )
    rows = []
    for name in ["raw", *names]:
        info = infos.get(name)
        n = args.frames_6d if info is not None and info.returns_points else args.frames
        seq = seq_full.frames(0, n)
        roi, _ = scene_roi(seq)
        if name == "raw":
            depth, points, ms = seq.depth, seq.points(), 0.0
        else:
            if not info.available and name != "kinectfusion":
                print(f"skip {name}: needs extra [{info.needs}]", file=sys.stderr)
                continue
            # warm-up (numba compilation, library imports) on a small crop
            small = seq.frames(0, min(n, 3))
            crop = np.s_[:, :64, :64]
            run_baseline(name, small.depth[crop], small.intensity[crop],
                         small.intrinsics.__class__(**{**small.intrinsics.to_dict(),
                                                       "width": 64, "height": 64}))  # fmt: skip
            params = {"size": args.size_6d} if info.returns_points and args.size_6d else {}
            start = time.perf_counter()
            out = run_baseline(name, seq.depth, seq.intensity, seq.intrinsics, **params)
            ms = 1000.0 * (time.perf_counter() - start) / n
            if info.returns_points:
                points, depth = out, out[..., 2]
            else:
                depth, points = out, depth_to_points(out, seq.intrinsics)
        row = {"method": name, "frames": n, "ms": ms, **_evaluate(seq, depth, points, roi)}
        rows.append(row)
        print(
            f"{name}: rough {row['rough']:.3f} rmse {row['rmse']:.4f} {ms:.1f} ms/frame",
            file=sys.stderr,
        )
    print("| method | frames | roughness Π mm | RMS resid mm | RMSE mm | >1 mm % | ms/frame |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['method']} | {r['frames']} | {r['rough']:.3f} | {r['rms']:.4f} | "
            f"{r['rmse']:.4f} | {r['bad']:.2f} | {r['ms']:.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
