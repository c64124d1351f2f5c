"""Quality evaluation on the synthetic ball: the comparisons the fusion issue's targets name.

Reference methods users run today, measured in the same run as fuse4d, every one scored by
:func:`fuse4d.metrics.evaluate` against the raw input on the same pixels:

* ``guided (depth self-guided)``: :func:`fuse4d.baselines.guided` with the depth as its own
  guide (radius 2, eps 10 mm^2), the best single-frame filter in PEERS.md;
* ``temporal mean (9)``: a plain 9-frame mean without motion compensation (the ghosting the
  method exists to remove), :func:`fuse4d.baselines.temporal.temporal_mean`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..baselines.guided import guided
from ..baselines.temporal import temporal_mean
from ..camera import depth_to_points
from ..metrics import MetricsReport, evaluate
from ..sequence import Sequence

__all__ = [
    "MethodScore",
    "QualityReport",
    "ball_quality_report",
    "score_on_ball",
    "self_guided",
]


def self_guided(seq: Sequence) -> NDArray[np.float32]:
    """The single-frame reference: the depth guided filter with r = 2 px, eps = 10 mm^2."""
    return guided(seq.depth, None, seq.intrinsics, size=2, eps=10.0, guide="depth")


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

    @classmethod
    def from_report(cls, name: str, report: MetricsReport) -> MethodScore:
        """The table row of one method from its :func:`~fuse4d.metrics.evaluate` report."""
        s = report.output
        return cls(name, s.roughness.mean, s.roughness.std, s.rmse_roi, s.bad_1mm)


def score_on_ball(
    seq: Sequence,
    name: str,
    *,
    depth: NDArray[np.float32] | None = None,
    points: NDArray[np.float32] | None = None,
    frames: slice | None = None,
) -> MethodScore:
    """Score a method's output (depth or points) on a synthetic ball sequence.

    :func:`fuse4d.metrics.evaluate` against the raw depth of ``seq``, on the ball ROI
    (EVALUATION §3): roughness and RMSE on the ROI pixels valid in raw and output alike.

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
    output = points if points is not None else depth
    if output is None:
        raise ValueError("give depth or points")
    report = evaluate(output, intrinsics=seq.intrinsics, raw=seq, frames=frames)
    return MethodScore.from_report(name, report)


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
    shape_frames: list[int] = field(default_factory=list)

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
            "shape_frames": list(self.shape_frames),
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
    from ..synthetic import make_falling_ball

    chosen = get_preset(preset)
    seq = make_falling_ball(
        small=small,
        num_frames=num_frames,
        depth_noise=depth_noise,
        intensity_noise=intensity_noise,
        rng=rng,
    )
    # kernels loaded (or compiled) and OpenCV started before the timing: the first call's
    # 70 ms/frame on the small ball was start-up, 22 steady
    warm = min(3, num_frames)
    fuse_sequence(
        seq.depth[:warm], seq.intensity[:warm], seq.intrinsics, fusion=chosen.fusion,
        flow=chosen.flow,
    )  # fmt: skip
    start = time.perf_counter()
    res = fuse_sequence(
        seq.depth, seq.intensity, seq.intrinsics, fusion=chosen.fusion, flow=chosen.flow
    )
    seconds = time.perf_counter() - start
    outputs = {
        "raw": depth_to_points(seq.depth, seq.intrinsics),
        "guided filter (depth self-guided)": depth_to_points(self_guided(seq), seq.intrinsics),
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
    shape = {}
    for name, pts in outputs.items():
        rep = evaluate(pts, ground_truth=seq.ground_truth, frames=picks, shape=True)
        sc = rep.output.shape
        shape[name] = float(100.0 * np.mean(sc.c_3d)) if sc is not None else float("nan")
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
        [int(p) for p in picks],
    )
