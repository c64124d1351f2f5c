"""fuse4d: intensity-video-guided 4D fusion of noisy 3D/depth video.

Zhang, Maniatis, Horna, Fisher, *Intensity Video Guided 4D Fusion for Improved Highly Dynamic
3D Reconstruction*. Depth in mm (float32, NaN = invalid), intensity float32 in [0, 1], arrays
``(T, H, W)``, pinhole intrinsics in pixels.

Main entry points
-----------------
- :func:`fuse_sequence` / :func:`fuse_stream` / :class:`FusionEngine`: the fusion (Eq. 2-6).
- :mod:`fuse4d.io`: read and write recordings (``load_sequence``, ``save_sequence``, ...).
- :mod:`fuse4d.flow`: optical flow (OpenCV methods and the paper's PMBP).
- :mod:`fuse4d.metrics`: roughness (Eq. 7), shape correctness (Eq. 8), RMSE, flicker, EPE.
- :mod:`fuse4d.synthetic`: scenes with ground truth (falling ball, plane, deforming sheet).
- :mod:`fuse4d.baselines`: the paper's comparison methods behind one interface.
"""

from __future__ import annotations

from .baselines import available_baselines, run_baseline
from .camera import Intrinsics, depth_to_points, points_to_depth, project_points
from .config import FlowConfig, FusionParams, load_config, preset
from .errors import (
    Fuse4dError,
    InputFileError,
    InputNotFoundError,
    OutputExistsError,
    OutputWriteError,
    ParameterError,
    ShapeError,
)
from .flow import (
    FlowCache,
    SequenceFlow,
    available_flow_methods,
    estimate_flow,
    estimate_flow_pair,
    estimate_sequence_flow,
)
from .fusion import (
    FusedFrame,
    FusionEngine,
    FusionResult,
    PrecomputedFlow,
    fuse_sequence,
    fuse_stream,
)
from .io import load_sequence, open_frames, read_flo, save_sequence, write_flo, write_ply
from .pmbp import PMBPFastParams, PMBPParams, pmbp_flow
from .sequence import GroundTruth, Sequence, normalize_intensity, sanitize_depth

__version__ = "0.1.0"

__all__ = [
    "FlowCache",
    "FlowConfig",
    "Fuse4dError",
    "FusedFrame",
    "FusionEngine",
    "FusionParams",
    "FusionResult",
    "GroundTruth",
    "InputFileError",
    "InputNotFoundError",
    "Intrinsics",
    "OutputExistsError",
    "OutputWriteError",
    "PMBPFastParams",
    "PMBPParams",
    "ParameterError",
    "PrecomputedFlow",
    "Sequence",
    "SequenceFlow",
    "ShapeError",
    "__version__",
    "available_baselines",
    "available_flow_methods",
    "depth_to_points",
    "estimate_flow",
    "estimate_flow_pair",
    "estimate_sequence_flow",
    "fuse_sequence",
    "fuse_stream",
    "load_config",
    "load_sequence",
    "normalize_intensity",
    "open_frames",
    "pmbp_flow",
    "points_to_depth",
    "preset",
    "project_points",
    "read_flo",
    "run_baseline",
    "sanitize_depth",
    "save_sequence",
    "write_flo",
    "write_ply",
]
