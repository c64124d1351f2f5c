"""fuse4d on sensor-model scenes with ground truth (issue 10 targets).

For each range scene × sensor model (``fuse4d.range_scenes``, ``fuse4d.sensors``) it reports,
on the pixels valid in the raw sensor depth (the same pixels for every method):

* RMSE against the true depth (mm) of raw, fuse4d (n = 9 and n = 1), the self-guided filter
  with radius/eps tuned per scene for its best RMSE, and a 9-frame temporal mean;
* the fraction of pixels more than 1.5 quantisation steps off (steps from the model at each
  pixel's true depth);
* Eq. 7 roughness (5×5) on the static background where the truth is planar;
* hole filling: the fraction of raw holes (true surface present) that the output fills, and
  the RMSE of the filled pixels.

Usage::

    python benchmarks/real_sensors.py [--small] [--frames 30] [--scenes ball,body,room]
        [--sensors kinect,d435,tof] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from fuse4d import FusionParams, depth_to_points, fuse_sequence, preset
from fuse4d.baselines import run_baseline
from fuse4d.experiments.quality import self_guided_filter
from fuse4d.metrics import roughness
from fuse4d.range_scenes import make_range_scene
from fuse4d.sensors import depth_step_mm, get_sensor


def _rmse(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    m = mask & np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean((a[m] - b[m]) ** 2))) if m.any() else float("nan")


def _tuned_guided(depth: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> tuple[float, str]:
    best = (np.inf, "")
    for radius in (1, 2, 4, 8):
        for eps in (1.0, 10.0, 100.0, 1000.0):
            r = _rmse(self_guided_filter(depth, radius=radius, eps=eps), truth, mask)
            best = min(best, (r, f"r={radius}, eps={eps:g}"))
    return best


def _roughness_on(depth: np.ndarray, k, roi: np.ndarray) -> float:
    vals = []
    for t in range(depth.shape[0]):
        pi = roughness(depth_to_points(depth[t], k))
        m = roi[t] & np.isfinite(pi)
        if m.any():
            vals.append(float(pi[m].mean()))
    return float(np.mean(vals)) if vals else float("nan")


def score(scene: str, sensor: str, *, small: bool, frames: int) -> dict:
    seq = make_range_scene(scene, sensor=sensor, small=small, num_frames=frames, rng=0)
    gt = seq.ground_truth
    truth = gt.depth
    k = seq.intrinsics
    raw_valid = np.isfinite(seq.depth)
    model = get_sensor(sensor)
    steps = depth_step_mm(model, 1.0, k.fx) * np.nan_to_num(truth, nan=0.0) ** 2
    steps = np.maximum(steps, 1.0)
    # static, locally planar truth: roughness of the truth itself is ~0 there
    planar = np.zeros_like(raw_valid)
    for t in range(seq.num_frames):
        planar[t] = roughness(depth_to_points(truth[t], k)) < 0.05
    static_roi = planar & ~gt.mask & raw_valid
    row = {"scene": scene, "sensor": sensor, "size": f"{k.width}x{k.height}", "frames": frames}
    methods = {"raw": seq.depth}
    t0 = time.perf_counter()
    fused9 = fuse_sequence(seq.depth, seq.intensity, k, flow=preset("fast").flow)
    row["fuse_ms_per_frame"] = 1000 * (time.perf_counter() - t0) / frames
    methods["fuse4d n=9"] = fused9.depth
    methods["fuse4d n=1"] = fuse_sequence(
        seq.depth, seq.intensity, k, fusion=FusionParams(num_frames=1)
    ).depth
    methods["9-frame mean"] = run_baseline("temporal-mean", seq.depth, None, k, size=9)
    guided_rmse, guided_cfg = _tuned_guided(seq.depth, truth, raw_valid)
    row["guided_tuned"] = guided_cfg
    for name, d in methods.items():
        err = np.abs(d - truth)
        m = raw_valid & np.isfinite(d)
        row[f"rmse {name}"] = _rmse(d, truth, raw_valid)
        row[f">1.5 steps {name} %"] = float(100 * np.mean(err[m] > 1.5 * steps[m]))
        row[f"roughness {name}"] = _roughness_on(d, k, static_roi)
    row["rmse guided (tuned)"] = guided_rmse
    holes = ~raw_valid & np.isfinite(truth)
    filled = holes & np.isfinite(fused9.depth)
    row["raw holes %"] = float(100 * holes.mean())
    row["holes filled %"] = float(100 * filled.sum() / max(holes.sum(), 1))
    row["rmse filled"] = _rmse(fused9.depth, truth, filled)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--small", action="store_true", help="160x120 scenes")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--scenes", default="ball,body,room")
    parser.add_argument("--sensors", default="kinect,d435,tof")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    rows = []
    for scene in args.scenes.split(","):
        for sensor in args.sensors.split(","):
            row = score(scene, sensor, small=args.small, frames=args.frames)
            rows.append(row)
            print(json.dumps(row, indent=None, default=float))
    if args.json:
        with Path(args.json).open("w", encoding="utf-8") as handle:
            json.dump(rows, handle, indent=2, default=float)


if __name__ == "__main__":
    main()
