"""Scenes, flows and methods shared by the paper experiments.

Scenes are generated once per process (small LRU cache). Flows depend only on the intensity
frames, so they are computed once per intensity sequence and cached on disk
(:class:`fuse4d.flow.FlowCache` in ``DIR/flow_cache``): every depth-noise level, method and
sweep setting reuses them, and so does a resumed run.
"""

from __future__ import annotations

import time
from dataclasses import fields, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ... import synthetic
from ...camera import depth_to_points
from ...config import FusionParams
from ...flow import FlowCache, SequenceFlow, estimate_sequence_flow, flow_params_from_mapping
from ...fusion import FusionResult, fuse_sequence
from ...sequence import Sequence
from ._config import Profile

__all__ = [
    "FILTERS",
    "LABELS",
    "MethodOutput",
    "ball",
    "flow_for",
    "ours_params",
    "run_method",
    "scene",
    "subset",
]

#: The paper's names of the methods (legends, tables).
LABELS: dict[str, str] = {
    "raw": "Raw",
    "adgf": "Ad-GF",
    "adbf": "Ad-BF",
    "guided": "Guided filter",
    "dnbf": "DNBF",
    "ta": "TA",
    "adjbf": "Ad-JBF",
    "stmf": "ST-MF",
    "kinectfusion": "6D rigid (KinectFusion)",
    "ed": "6D non-rigid (ED)",
    "ours": "Ours (9 frames)",
    "realsense": "RealSense chain",
    "temporal-mean": "9-frame mean",
}

#: The seven filters of the synthetic comparison (BASELINES §1-7), in the paper's order.
FILTERS: tuple[str, ...] = ("adgf", "adbf", "guided", "dnbf", "ta", "adjbf", "stmf")


@lru_cache(maxsize=6)
def scene(name: str, small: bool, num_frames: int, seed: int, **kwargs: Any) -> Sequence:
    """A synthetic scene (cached per process): ``ball``, ``plane`` or ``sheet``.

    ``kwargs`` go to the generator (``depth_noise``, ``intensity_noise``, ...).
    """
    makers = {
        "ball": synthetic.make_falling_ball,
        "plane": synthetic.make_static_plane,
        "sheet": synthetic.make_deforming_sheet,
    }
    return makers[name](small=small, num_frames=num_frames, rng=seed, **kwargs)


def ball(profile: Profile, seed: int, sigma_d: float = 0.2, sigma_i: float = 0.02) -> Sequence:
    """The falling ball of EVALUATION §3 at the profile's size."""
    return scene(
        "ball",
        profile.small,
        profile.num_frames,
        seed,
        depth_noise=float(sigma_d),
        intensity_noise=float(sigma_i),
    )


def flow_for(
    seq: Sequence,
    method: str,
    cache_dir: Path | None,
    params: dict[str, Any] | None = None,
) -> SequenceFlow:
    """Forward/backward flow of ``seq``'s intensity video, from the disk cache when present."""
    cache = FlowCache(cache_dir) if cache_dir is not None else None
    p = flow_params_from_mapping(method, params) if params else None
    return estimate_sequence_flow(seq.intensity, method=method, params=p, cache=cache)


def ours_params(**overrides: Any) -> FusionParams:
    """METHOD defaults (9 frames) with ``overrides``; unknown names raise ``TypeError``."""
    names = {f.name for f in fields(FusionParams)}
    bad = set(overrides) - names
    if bad:
        raise TypeError(f"unknown FusionParams fields: {sorted(bad)}")
    return replace(FusionParams(), **overrides)


class MethodOutput:
    """A method's output on a sequence.

    Attributes
    ----------
    points : (T, H, W, 3) ndarray of float32
        Output point maps, mm.
    seconds : float
        Wall time of the method (flow excluded).
    result : FusionResult or None
        The full fusion result for Ours.
    """

    def __init__(
        self, points: NDArray[np.float32], seconds: float, result: FusionResult | None = None
    ) -> None:
        self.points = points
        self.seconds = seconds
        self.result = result


def run_method(
    method: str,
    seq: Sequence,
    *,
    flow: SequenceFlow | None = None,
    fusion: FusionParams | None = None,
    **params: Any,
) -> MethodOutput:
    """Run ``method`` (``raw``, ``ours`` or a baseline name) on ``seq``.

    Parameters
    ----------
    method : str
        ``raw``, ``ours`` or a :func:`fuse4d.baselines.available_baselines` name.
    seq : Sequence
        Input video.
    flow : SequenceFlow, optional
        Precomputed flow for ``ours``.
    fusion : FusionParams, optional
        Parameters of ``ours`` (default: METHOD defaults).
    **params
        Baseline keywords (``size``, ``iterations``, ...).
    """
    t0 = time.perf_counter()
    if method == "raw":
        return MethodOutput(depth_to_points(seq.depth, seq.intrinsics), 0.0)
    if method == "ours":
        res = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=fusion, flow=flow)
        return MethodOutput(res.points, time.perf_counter() - t0, res)
    from ...baselines import run_baseline

    out = run_baseline(method, seq.depth, seq.intensity, seq.intrinsics, **params)
    seconds = time.perf_counter() - t0
    pts = out if out.ndim == 4 else depth_to_points(out, seq.intrinsics)
    return MethodOutput(np.asarray(pts, np.float32), seconds)


def subset(seq: Sequence, frames: list[int] | NDArray[np.integer]) -> Sequence:
    """``seq`` restricted to the (not necessarily contiguous) frame indices ``frames``.

    The ground truth is sliced to match (its flow is dropped: it needs consecutive frames).
    """
    idx = np.asarray(frames, dtype=np.int64)
    gt = seq.ground_truth
    if gt is not None:
        gt = gt.select(idx, seq.num_frames)  # typed scene geometry sliced too; flow dropped
    return replace(
        seq,
        depth=seq.depth[idx],
        intensity=seq.intensity[idx],
        timestamps=None if seq.timestamps is None else seq.timestamps[idx],
        ground_truth=gt,
    )
