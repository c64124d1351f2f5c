"""Quality evaluation on the synthetic ball: the comparisons the fusion issue's targets name.

Reference methods users run today, measured in the same run as fuse4d:

* ``guided (depth self-guided)``: OpenCV ``cv2.ximgproc.guidedFilter`` with the depth as its own
  guide (radius 2, eps 10 mm^2), the best single-frame filter in PEERS.md;
* ``temporal mean (9)``: a plain 9-frame mean without motion compensation (the ghosting the
  method exists to remove), :func:`fuse4d.baselines.temporal.temporal_mean`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..baselines.temporal import temporal_mean
from ..camera import depth_to_points
from ..metrics import bad_pixel_fraction, ball_roi, depth_rmse, roughness_stats
from ..sequence import Sequence

__all__ = [
    "MethodScore",
    "QualityReport",
    "ball_quality_report",
    "score_on_ball",
    "self_guided_filter",
]


def self_guided_filter(depth: NDArray[np.float32], *, radius: int = 2, eps: float = 10.0):
    """OpenCV guided filter with each depth frame as its own guide (NaN-safe; NaN stays NaN).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    radius : int
        Box radius in px.
    eps : float
        Regularisation in mm^2.
    """
    out = np.empty_like(depth, dtype=np.float32)
    for t, frame in enumerate(depth):
        valid = np.isfinite(frame)
        filled = np.where(valid, frame, np.nanmedian(frame) if valid.any() else 0.0)
        filled = filled.astype(np.float32)
        res = cv2.ximgproc.guidedFilter(guide=filled, src=filled, radius=radius, eps=eps, dDepth=-1)
        out[t] = np.where(valid, res, np.nan)
    return out


@dataclass
class MethodScore:
    """Scores of one method on the ball (EVALUATION §1, §3).

    Attributes
    ----------
    name : str
    roughness_mean, roughness_std : float
        Eq. 7 (5x5) over the ball ROI, mean and std over frames, mm.
    rmse : float
        RMSE to GT depth over the ball ROI, mm.
    bad_1mm : float
        Fraction of all pixels more than 1 mm from GT (NaN counted bad).
    """

    name: str
    roughness_mean: float
    roughness_std: float
    rmse: float
    bad_1mm: float

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def score_on_ball(
    seq: Sequence,
    name: str,
    *,
    depth: NDArray[np.float32] | None = None,
    points: NDArray[np.float32] | None = None,
    frames: slice | None = None,
) -> MethodScore:
    """Score a method's output (depth or points) on a synthetic ball sequence.

    Parameters
    ----------
    seq : Sequence
        The ball (``make_falling_ball``), with ground truth.
    name : str
        Method label.
    depth, points : ndarray
        The output as depth (T,H,W) mm or points (T,H,W,3) mm (one of them).
    frames : slice, optional
        Frames to score (default all).
    """
    gt = seq.ground_truth
    if gt is None or gt.depth is None:
        raise ValueError("score_on_ball needs a sequence with ground-truth depth")
    if points is None:
        if depth is None:
            raise ValueError("give depth or points")
        points = depth_to_points(depth, seq.intrinsics)
    sl = frames or slice(None)
    roi = ball_roi(seq)[sl]
    pts = points[sl]
    stats = roughness_stats(pts, roi=roi)
    z = pts[..., 2]
    return MethodScore(
        name=name,
        roughness_mean=float(stats.mean),
        roughness_std=float(stats.std),
        rmse=float(depth_rmse(gt.depth[sl], z, mask=roi)),
        bad_1mm=float(bad_pixel_fraction(gt.depth[sl], z)),
    )


@dataclass
class QualityReport:
    """Ball quality comparison (the fusion issue's targets), one intensity-noise level."""

    intensity_noise: float
    depth_noise: float
    frames: int
    preset: str
    flow_method: str
    all_frames: list[MethodScore]
    interior: list[MethodScore]
    shape_c3d: dict[str, float]
    fusion_ms_per_frame: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "intensity_noise": self.intensity_noise,
            "depth_noise": self.depth_noise,
            "frames": self.frames,
            "preset": self.preset,
            "flow_method": self.flow_method,
            "all_frames": [s.to_dict() for s in self.all_frames],
            "interior_frames": [s.to_dict() for s in self.interior],
            "shape_c3d_percent": self.shape_c3d,
            "fusion_ms_per_frame": self.fusion_ms_per_frame,
        }


def ball_quality_report(
    *,
    preset: str = "fast",
    intensity_noise: float = 0.02,
    depth_noise: float = 0.2,
    num_frames: int = 50,
    small: bool = False,
    shape_frames: int = 3,
    rng: int = 0,
) -> QualityReport:
    """Score raw, the self-guided filter, the 9-frame mean and fuse4d on the falling ball.

    Scores over all frames and over the interior frames (full 9-frame window). Shape
    correctness C_3D (Eq. 8, MLESAC, in %) on ``shape_frames`` evenly spaced frames (it costs
    ~1 s per frame at 600x600).
    """
    import time

    from ..config import preset as get_preset
    from ..fusion import fuse_sequence
    from ..metrics import shape_correctness
    from ..synthetic import make_falling_ball

    chosen = get_preset(preset)
    seq = make_falling_ball(
        small=small,
        num_frames=num_frames,
        depth_noise=depth_noise,
        intensity_noise=intensity_noise,
        rng=rng,
    )
    start = time.perf_counter()
    res = fuse_sequence(
        seq.depth, seq.intensity, seq.intrinsics, fusion=chosen.fusion, flow=chosen.flow
    )
    seconds = time.perf_counter() - start
    outputs = {
        "raw": depth_to_points(seq.depth, seq.intrinsics),
        "guided filter (depth self-guided)": depth_to_points(
            self_guided_filter(seq.depth), seq.intrinsics
        ),
        "temporal mean (9, no motion comp.)": depth_to_points(
            temporal_mean(seq.depth, None, seq.intrinsics), seq.intrinsics
        ),
        f"fuse4d {preset}": res.points,
    }
    h = chosen.fusion.past_frames
    interior = slice(h, num_frames - chosen.fusion.future_frames)
    every = [score_on_ball(seq, name, points=pts) for name, pts in outputs.items()]
    inner = [score_on_ball(seq, name, points=pts, frames=interior) for name, pts in outputs.items()]
    picks = np.linspace(0, num_frames - 1, shape_frames).round().astype(int)
    sub = seq.frames(0, num_frames)
    shape = {}
    for name, pts in outputs.items():
        sc = shape_correctness(pts[picks], _subset(sub, picks))
        shape[name] = float(100.0 * np.mean(sc.c_3d))
    return QualityReport(
        intensity_noise,
        depth_noise,
        num_frames,
        preset,
        res.flow_method,
        every,
        inner,
        shape,
        1000.0 * seconds / num_frames,
    )


def _subset(seq: Sequence, picks: NDArray[np.int64]):
    """Ground truth of selected frames (for shape correctness)."""
    from dataclasses import replace

    gt = seq.ground_truth
    extra = {
        k: (v[picks] if isinstance(v, np.ndarray) and v.shape[:1] == (seq.num_frames,) else v)
        for k, v in gt.extra.items()
    }
    return replace(gt, depth=gt.depth[picks], mask=gt.mask[picks], flow=None, extra=extra)
