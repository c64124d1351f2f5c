"""fuse4d: intensity-video-guided 4D fusion of noisy 3D/depth video.

Zhang, Maniatis, Horna, Fisher, *Intensity Video Guided 4D Fusion for Improved Highly Dynamic
3D Reconstruction*. Depth in mm (float32, NaN = invalid), intensity float32 in [0, 1], arrays
``(T, H, W)``, pinhole intrinsics in pixels.
"""

from __future__ import annotations

from .camera import Intrinsics, depth_to_points, points_to_depth, project_points
from .errors import InputFileError, OutputExistsError, ShapeError
from .sequence import GroundTruth, Sequence, normalize_intensity, sanitize_depth

__version__ = "0.1.0"

__all__ = [
    "GroundTruth",
    "InputFileError",
    "Intrinsics",
    "OutputExistsError",
    "Sequence",
    "ShapeError",
    "__version__",
    "depth_to_points",
    "normalize_intensity",
    "points_to_depth",
    "project_points",
    "sanitize_depth",
]
