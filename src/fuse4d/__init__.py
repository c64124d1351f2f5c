"""fuse4d: intensity-video-guided 4D fusion of noisy 3D/depth video.

Zhang, Maniatis, Horna, Fisher, *Intensity Video Guided 4D Fusion for Improved Highly Dynamic
3D Reconstruction*. Depth in mm (float32, NaN = invalid), intensity float32 in [0, 1], arrays
``(T, H, W)``, pinhole intrinsics in pixels.

The top level holds what a user needs (the full list with one line each: ``docs/api.md``):

- fusion: :func:`fuse_sequence`, :func:`fuse_stream`, :class:`FusionEngine` (Eq. 2-6), their
  results :class:`FusionResult` / :class:`FusedFrame`, and the knobs :class:`FusionParams`,
  :class:`FlowConfig`, :func:`preset`, :func:`load_config`;
- data: :class:`Sequence`, :class:`Intrinsics`, :func:`load_sequence`, :func:`save_sequence`,
  :func:`depth_to_points`, :func:`project_points`;
- flow and comparisons: :func:`estimate_flow`, :func:`run_baseline`,
  :func:`available_baselines`;
- errors: :class:`Fuse4dError` (the base of all of them), :class:`InputFileError`,
  :class:`InputNotFoundError`, :class:`ParameterError`, :class:`OutputExistsError`,
  :class:`OutputWriteError`, :class:`ShapeError`.

Everything else lives in its subpackage: :mod:`fuse4d.flow` (optical flow, PMBP, cache),
:mod:`fuse4d.io` (readers and writers), :mod:`fuse4d.metrics` (Eq. 7, Eq. 8, RMSE, flicker,
:func:`fuse4d.metrics.evaluate`), :mod:`fuse4d.motion` (Eq. 3-4), :mod:`fuse4d.synthetic`
(scenes with ground truth), :mod:`fuse4d.baselines` (the paper's comparison methods),
:mod:`fuse4d.experiments` (benchmarks, evaluation, demo).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # for type checkers and IDEs; at run time every name loads on first use
    from ._version import __version__
    from .baselines import available_baselines, run_baseline
    from .camera import Intrinsics, depth_to_points, project_points
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
    from .flow import estimate_flow
    from .fusion import FusedFrame, FusionEngine, FusionResult, fuse_sequence, fuse_stream
    from .io import load_sequence, save_sequence
    from .sequence import Sequence

__all__ = [
    "FlowConfig",
    "Fuse4dError",
    "FusedFrame",
    "FusionEngine",
    "FusionParams",
    "FusionResult",
    "InputFileError",
    "InputNotFoundError",
    "Intrinsics",
    "OutputExistsError",
    "OutputWriteError",
    "ParameterError",
    "Sequence",
    "ShapeError",
    "__version__",
    "available_baselines",
    "depth_to_points",
    "estimate_flow",
    "fuse_sequence",
    "fuse_stream",
    "load_config",
    "load_sequence",
    "preset",
    "project_points",
    "run_baseline",
    "save_sequence",
]

#: Every public name -> the module that defines it. Nothing is imported with the package
#: (``import fuse4d`` and ``fuse4d --help`` stay fast: numpy, numba, OpenCV and scipy load
#: when a name that needs them is first used).
_LAZY = {
    "__version__": "_version",
    "available_baselines": "baselines",
    "run_baseline": "baselines",
    "Intrinsics": "camera",
    "depth_to_points": "camera",
    "project_points": "camera",
    "FlowConfig": "config",
    "FusionParams": "config",
    "load_config": "config",
    "preset": "config",
    "Fuse4dError": "errors",
    "InputFileError": "errors",
    "InputNotFoundError": "errors",
    "OutputExistsError": "errors",
    "OutputWriteError": "errors",
    "ParameterError": "errors",
    "ShapeError": "errors",
    "estimate_flow": "flow",
    "FusedFrame": "fusion",
    "FusionEngine": "fusion",
    "FusionResult": "fusion",
    "fuse_sequence": "fusion",
    "fuse_stream": "fusion",
    "load_sequence": "io",
    "save_sequence": "io",
    "Sequence": "sequence",
}
#: Modules reachable as attributes (``fuse4d.metrics.evaluate``), imported on first access.
_SUBPACKAGES = {
    "baselines",
    "bilateral",
    "camera",
    "config",
    "dask",
    "errors",
    "experiments",
    "flow",
    "fusion",
    "holes",
    "io",
    "live",
    "metrics",
    "motion",
    "plot",
    "range_scenes",
    "report",
    "run",
    "sensors",
    "sequence",
    "synthetic",
}


def __getattr__(name: str) -> Any:
    """Load a public name (or a subpackage) on first use and cache it in the package."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    elif name in _SUBPACKAGES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'fuse4d' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names and subpackages, loaded or not (for ``dir()`` and tab completion)."""
    return sorted({*globals(), *__all__, *_SUBPACKAGES})
