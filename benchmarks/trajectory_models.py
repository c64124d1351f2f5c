"""Which trajectory model of Eq. 5's base suits moving objects? (issue 10, A21/A28/A32)

On the Kinect-model range scenes (``fuse4d.range_scenes``: a bouncing ball, a walking body,
640×480) fuse4d's ``fast`` preset is run with each ``base`` (``frame``, the A21 line
``trajectory``, the A28 parabola ``quadratic``, the A32 per-pixel choice ``adaptive``) and
with one frame, and scored against the true depth on the frames whose 9-frame window is
complete (4 .. T-5):

* ``rmse``: RMSE (mm) on every raw-valid pixel;
* ``obj``: RMSE (mm) on the moving object's raw-valid pixels;
* ``obj interior``: the same on the object mask eroded by 4 px (no silhouette rim).

``--per-frame N`` adds, for the ball, the object RMSE of every frame of an N-frame clip
(window ends and the bounce at frame 12 included) for one frame vs the default base.

``--tracks`` adds the reference check behind A32: the motion reference P~ (A3) of the ball
sampled along the *true* tracks (ground-truth flow, chained forward from frame 2 over 9
frames, object pixels 4 px inside the mask), and the RMS error (mm) of one frame's sample vs
the mean over the 9 frames: how much temporal averaging along tracks can remove at all.

Usage::

    python benchmarks/trajectory_models.py [--frames 14] [--scenes ball,body] [--tracks]
        [--per-frame 20]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from fuse4d import fuse_sequence, preset
from fuse4d.motion import estimate_noise_quad, motion_reference_depth
from fuse4d.range_scenes import make_range_scene

BASES = ("frame", "trajectory", "quadratic", "adaptive")


def _erode(mask: np.ndarray, px: int) -> np.ndarray:
    kernel = np.ones((2 * px + 1, 2 * px + 1), np.uint8)
    return np.stack([cv2.erode(m.astype(np.uint8), kernel).astype(bool) for m in mask])


def _rmse(out: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    m = mask & np.isfinite(out) & np.isfinite(truth)
    return float(np.sqrt(np.mean((out[m] - truth[m]) ** 2))) if m.any() else float("nan")


def score(scene: str, frames: int) -> list[tuple[str, float, float, float]]:
    """(variant, rmse, obj, obj interior) on the full-window frames of one scene."""
    seq = make_range_scene(scene, sensor="kinect", num_frames=frames, rng=0)
    truth = seq.ground_truth.depth
    valid = np.isfinite(seq.depth)
    obj = seq.ground_truth.mask & valid
    inner = _erode(obj, 4)
    full = slice(4, frames - 4)
    variants = {"raw": None, "n=1": preset("fast").fusion.replace(num_frames=1)}
    variants.update({f"n=9 {b}": preset("fast").fusion.replace(base=b) for b in BASES})
    rows = []
    for name, params in variants.items():
        if params is None:
            out = seq.depth
        else:
            out = fuse_sequence(
                seq.depth, seq.intensity, seq.intrinsics, fusion=params, flow=preset("fast").flow
            ).depth
        rows.append(
            (
                name,
                _rmse(out[full], truth[full], valid[full]),
                _rmse(out[full], truth[full], obj[full]),
                _rmse(out[full], truth[full], inner[full]),
            )
        )
    return rows


def per_frame(frames: int) -> list[tuple[int, float, float]]:
    """(frame, object RMSE one frame, object RMSE default) on every frame of the ball."""
    seq = make_range_scene("ball", sensor="kinect", num_frames=frames, rng=0)
    truth = seq.ground_truth.depth
    obj = seq.ground_truth.mask & np.isfinite(seq.depth)
    outs = [
        fuse_sequence(
            seq.depth, seq.intensity, seq.intrinsics, fusion=params, flow=preset("fast").flow
        ).depth
        for params in (preset("fast").fusion.replace(num_frames=1), preset("fast").fusion)
    ]
    return [(t, *(_rmse(o[t], truth[t], obj[t]) for o in outs)) for t in range(frames)]


def track_averaging(start: int = 2, length: int = 9) -> dict[str, tuple[float, float]]:
    """RMS error (mm) of one sample vs the mean of ``length`` samples along the true tracks
    of the ball, for the motion reference P~ and the raw depth."""
    seq = make_range_scene("ball", sensor="kinect", num_frames=start + length, rng=0)
    gt = seq.ground_truth
    ref = np.stack(
        [
            motion_reference_depth(d, sigma=3.0, max_step=10.0, noise_quad=estimate_noise_quad(d))
            for d in seq.depth
        ]
    )
    h, w = gt.depth.shape[1:]
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
    inner = _erode(gt.mask & np.isfinite(seq.depth), 4)[start]
    x, y = uu[inner].copy(), vv[inner].copy()
    alive = np.ones(x.size, bool)
    samples: dict[str, list[np.ndarray]] = {"P~": [], "raw": []}
    for t in range(start, start + length):
        iu, iv = np.rint(x).astype(int), np.rint(y).astype(int)
        alive &= (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
        alive &= gt.mask[t, np.clip(iv, 0, h - 1), np.clip(iu, 0, w - 1)]
        mx, my = x.reshape(1, -1), y.reshape(1, -1)
        true = cv2.remap(gt.depth[t], mx, my, cv2.INTER_LINEAR).ravel()
        samples["P~"].append(cv2.remap(ref[t], mx, my, cv2.INTER_LINEAR).ravel() - true)
        samples["raw"].append(cv2.remap(seq.depth[t], mx, my, cv2.INTER_NEAREST).ravel() - true)
        if t + 1 < start + length:
            f = cv2.remap(gt.flow[t], mx, my, cv2.INTER_LINEAR).reshape(-1, 2)
            x, y = x + f[:, 0], y + f[:, 1]
    out = {}
    for name, errs in samples.items():
        e = np.array(errs)[:, alive]
        e = e[:, np.isfinite(e).all(axis=0)]
        out[name] = (float(np.sqrt(np.mean(e[0] ** 2))), float(np.sqrt(np.mean(e.mean(0) ** 2))))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=14)
    parser.add_argument("--scenes", default="ball,body")
    parser.add_argument("--tracks", action="store_true", help="also the true-track check")
    parser.add_argument("--per-frame", type=int, default=0, help="ball frames scored per frame")
    args = parser.parse_args(argv)
    if args.frames < 9:
        parser.error("--frames must be >= 9 (a full 9-frame window)")
    for scene in args.scenes.split(","):
        print(f"### {scene} (kinect, 640x480, frames 4..{args.frames - 5})\n")
        print("| variant | RMSE mm | object RMSE mm | object interior RMSE mm |")
        print("|---|---|---|---|")
        for name, rmse, obj, inner in score(scene, args.frames):
            print(f"| {name} | {rmse:.2f} | {obj:.2f} | {inner:.2f} |")
        print()
    if args.per_frame:
        print(f"### ball: object RMSE per frame ({args.per_frame} frames)\n")
        print("| frame | one frame, mm | default (9 frames), mm |")
        print("|---|---|---|")
        for t, one, fused in per_frame(args.per_frame):
            print(f"| {t} | {one:.2f} | {fused:.2f} |")
        print()
    if args.tracks:
        print("### ball: error along the true tracks (9 frames)\n")
        print("| samples | one frame, RMS mm | mean of 9, RMS mm |")
        print("|---|---|---|")
        for name, (one, mean) in track_averaging().items():
            print(f"| {name} | {one:.2f} | {mean:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
