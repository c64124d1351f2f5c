"""Per-frame scores of a method's output (the only place the experiments call metrics).

Kept in one small module so that it can switch to :func:`fuse4d.metrics.evaluate` later.
Every score is per frame; sequence means and stds are taken when summarising.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...metrics import (
    ball_roi,
    depth_rmse,
    flow_endpoint_error,
    roughness_stats,
    scene_roi,
    shape_correctness,
)
from ...sequence import Sequence
from ._scenes import subset

__all__ = ["evenly_spaced", "flow_epe_frames", "score_frames", "support_frames"]


def evenly_spaced(num_frames: int, count: int | None, *, margin: int = 0) -> list[int]:
    """``count`` frame indices spread over ``[margin, num_frames - 1 - margin]`` (all if None)."""
    lo, hi = margin, num_frames - 1 - margin
    if hi < lo:
        lo, hi = 0, num_frames - 1
    if count is None or count >= hi - lo + 1:
        return list(range(lo, hi + 1))
    return sorted({round(x) for x in np.linspace(lo, hi, count)})


def score_frames(
    points: NDArray[np.float32],
    seq: Sequence,
    *,
    shape_frames: list[int] | None = None,
    frames: list[int] | None = None,
    roi: NDArray[np.bool_] | None = None,
) -> list[dict[str, Any]]:
    """Roughness (Eq. 7), RMS residual, depth RMSE and, on ``shape_frames``, shape C (Eq. 8).

    Parameters
    ----------
    points : (T, H, W, 3) ndarray
        Output point maps (mm) for the frames of ``seq`` (or for ``frames`` of it).
    seq : Sequence
        The input scene, with ground truth.
    shape_frames : list of int, optional
        Frame indices (of ``seq``) at which C is computed (ball only); None = none.
    frames : list of int, optional
        Which frames of ``seq`` the ``points`` are (default all, in order).
    roi : (T, H, W) bool ndarray, optional
        Roughness ROI (default: the scene's EVALUATION ROI).

    Returns
    -------
    list of dict
        One per frame: ``frame``, ``roughness`` (mm), ``roughness_rms`` (mm), ``rmse`` (mm),
        ``n_roi``, ``c_3d``, ``c_profile``, ``c_minimal`` (fractions; NaN where not computed).
    """
    idx = list(range(seq.num_frames)) if frames is None else list(frames)
    sub = seq if frames is None else subset(seq, idx)
    if roi is None:
        roi = scene_roi(sub)[0]
    stats = roughness_stats(points, roi=roi)
    gt = sub.ground_truth
    shape: dict[int, tuple[float, float, float]] = {}
    if shape_frames:
        want = [i for i, f in enumerate(idx) if f in set(shape_frames)]
        if want:
            sc = shape_correctness(subset(sub, want), points[want], rng=0)
            for j, i in enumerate(want):
                shape[i] = (float(sc.c_3d[j]), float(sc.c_profile[j]), float(sc.c_minimal[j]))
    rows = []
    for i, f in enumerate(idx):
        rmse = math.nan
        if gt is not None and gt.depth is not None:
            rmse = float(depth_rmse(gt.depth[i], points[i, ..., 2], roi=roi[i]))
        c3, cp, cm = shape.get(i, (math.nan, math.nan, math.nan))
        rows.append(
            {
                "frame": f,
                "roughness": float(stats.frame_means[i]),
                "roughness_rms": float(stats.frame_rms_means[i]),
                "rmse": rmse,
                "n_roi": int(stats.num_pixels[i]),
                "c_3d": c3,
                "c_profile": cp,
                "c_minimal": cm,
            }
        )
    return rows


def flow_epe_frames(forward: NDArray[np.float32], seq: Sequence) -> list[float]:
    """Per-pair end-point error (px) of the forward flow on the ball's roughness ROI of frame t.

    The last frame has no forward flow: its value is NaN.
    """
    gt = seq.ground_truth
    if gt is None or gt.flow is None:
        return [math.nan] * seq.num_frames
    roi = ball_roi(seq)
    out = [
        float(flow_endpoint_error(gt.flow[t], forward[t], roi=roi[t]))
        for t in range(seq.num_frames - 1)
    ]
    return [*out, math.nan]


def support_frames(support: NDArray[np.uint8], seq: Sequence, num_frames: int) -> list[float]:
    """Fraction of ball ROI pixels of each frame whose track reached every window frame.

    The window of frame t is the (truncated) ``num_frames`` window of METHOD §4.1, so a pixel
    has full support when ``support == window length - 1`` (8 for 9 frames in the interior).
    """
    roi = ball_roi(seq)
    n = seq.num_frames
    back, ahead = (num_frames - 1) // 2, num_frames // 2
    out = []
    for t in range(n):
        expected = min(n - 1, t + ahead) - max(0, t - back)
        m = roi[t]
        out.append(float((support[t][m] >= expected).mean()) if m.any() else math.nan)
    return out
