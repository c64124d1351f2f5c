"""Stage 1 — dense intensity tracking: optical flow between consecutive frames (METHOD §2).

The flow stage is a registry of methods behind one signature, so that the paper's PMBP
tracker (:mod:`fuse4d.flow.pmbp`, registered as ``"pmbp"`` / ``"pmbp-fast"``) and the OpenCV
trackers (:mod:`fuse4d.flow.opencv`: ``"dis"``, ``"farneback"``, ``"tvl1"``, ``"deepflow"``,
which are *not* the paper's method) are interchangeable.

Layout (one job per module; none imports the package root):

==================  =========================================================================
``_registry``       :class:`FlowMethod`, the registry, parameter objects from mappings
``_checks``         input checks and the [0, 1] → uint8 conversion shared by the methods
``opencv``          the four OpenCV trackers and their parameter dataclasses
``pmbp``            PatchMatch Belief Propagation (the paper's tracker)
``estimate``        :func:`estimate_flow`, :func:`estimate_flow_pair`,
                    :class:`SequenceFlowEstimator`, :func:`estimate_sequence_flow`,
                    :class:`SequenceFlow`, :func:`warp_image`
``cache``           :class:`FlowCache`, the on-disk cache of pair flows
``vis``             Middlebury colour coding (:func:`flow_to_color`)
``flo``             Middlebury ``.flo`` files (:func:`read_flo`, :func:`write_flo`)
==================  =========================================================================

Conventions: intensity float32 ``(H, W)`` in [0, 1]; a flow field is float32 ``(H, W, 2)`` in
px, ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row), on the grid of its source image.
"""

from __future__ import annotations

from . import opencv as _opencv
from . import pmbp as _pmbp
from ._registry import (
    FlowFunction,
    FlowMethod,
    FlowPairFunction,
    Roi,
    available_flow_methods,
    flow_params_from_mapping,
    get_flow_method,
    register_flow_method,
    resolve_flow_params,
)
from .cache import FlowCache
from .estimate import (
    FLOW_CODE_VERSION,
    SequenceFlow,
    SequenceFlowEstimator,
    as_sequence_flow,
    estimate_flow,
    estimate_flow_pair,
    estimate_sequence_flow,
    warp_image,
)
from .flo import read_flo, write_flo
from .opencv import DeepFlowParams, DISParams, FarnebackParams, TVL1Params
from .pmbp import PMBP_FAST, PMBPFastParams, PMBPParams, pmbp_flow, pmbp_flow_pair
from .vis import flow_to_color

__all__ = [
    "FLOW_CODE_VERSION",
    "PMBP_FAST",
    "DISParams",
    "DeepFlowParams",
    "FarnebackParams",
    "FlowCache",
    "FlowFunction",
    "FlowMethod",
    "FlowPairFunction",
    "PMBPFastParams",
    "PMBPParams",
    "Roi",
    "SequenceFlow",
    "SequenceFlowEstimator",
    "TVL1Params",
    "as_sequence_flow",
    "available_flow_methods",
    "estimate_flow",
    "estimate_flow_pair",
    "estimate_sequence_flow",
    "flow_params_from_mapping",
    "flow_to_color",
    "get_flow_method",
    "pmbp_flow",
    "pmbp_flow_pair",
    "read_flo",
    "register_flow_method",
    "resolve_flow_params",
    "warp_image",
    "write_flo",
]

# Built-in methods, in the order ``available_flow_methods()`` lists them.
_opencv.register()
_pmbp.register()
