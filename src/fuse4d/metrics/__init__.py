"""Evaluation metrics of fuse4d (EVALUATION.md §1, §2).

:func:`evaluate` is the one scoring policy (ROI, same pixels for raw and output, static
pixels, ground truth); the functions below are the single metrics it combines.

* roughness (paper Eq. 7) per pixel, its RMS-residual variant, and per-sequence statistics;
* regions of interest (default edge-aware ROI, the synthetic scenes' ROIs);
* shape correctness (paper Eq. 8) with MLESAC sphere fits;
* depth RMSE, bad-pixel fraction, temporal flicker, flow end-point and angular errors.
"""

from __future__ import annotations

from .accuracy import (
    FlickerStats,
    bad_pixel_fraction,
    depth_rmse,
    flow_angular_error,
    flow_endpoint_error,
    temporal_flicker,
)
from .evaluate import MetricsReport, RunningEvaluation, Scores, evaluate
from .roi import (
    ball_roi,
    box_mask,
    central_roi,
    default_roi,
    parse_box,
    scene_roi,
    static_mask_from_ground_truth,
    static_pixels,
    step_limit,
)
from .roughness import RoughnessStats, roughness, roughness_maps, roughness_rms, roughness_stats
from .shape import (
    ShapeCorrectness,
    SphereFit,
    circle_fit_mlesac,
    shape_correctness,
    sphere_fit_mlesac,
)

__all__ = [
    "FlickerStats",
    "MetricsReport",
    "RoughnessStats",
    "RunningEvaluation",
    "Scores",
    "ShapeCorrectness",
    "SphereFit",
    "bad_pixel_fraction",
    "ball_roi",
    "box_mask",
    "central_roi",
    "circle_fit_mlesac",
    "default_roi",
    "depth_rmse",
    "evaluate",
    "flow_angular_error",
    "flow_endpoint_error",
    "parse_box",
    "roughness",
    "roughness_maps",
    "roughness_rms",
    "roughness_stats",
    "scene_roi",
    "shape_correctness",
    "sphere_fit_mlesac",
    "static_mask_from_ground_truth",
    "static_pixels",
    "step_limit",
    "temporal_flicker",
]
