"""OpenCV optical-flow trackers behind named, validated parameters (not the paper's method).

Four dense trackers from OpenCV (``opencv-contrib-python-headless``), each wrapped as a
:data:`fuse4d.flow.FlowFunction` ``(image0, image1, params, init) -> flow``:

========== ====================================== ============ ===================================
name       OpenCV call                            input        warm start (``init``)
========== ====================================== ============ ===================================
dis        ``cv2.DISOpticalFlow``                 uint8        yes: extra "temporal" candidates
farneback  ``cv2.calcOpticalFlowFarneback``       uint8        yes: ``OPTFLOW_USE_INITIAL_FLOW``
tvl1       ``cv2.optflow.DualTVL1OpticalFlow``    float [0,1]  yes: ``useInitialFlow``
deepflow   ``cv2.optflow.createOptFlow_DeepFlow`` float 0-255  no (OpenCV discards the input flow)
========== ====================================== ============ ===================================

Intensities arrive as float32 in [0, 1]. They are converted inside each wrapper only: rounded
to uint8 (``round(255 I)``, clipped) where OpenCV demands 8 bit; TV-L1 takes float32 in [0, 1]
(OpenCV scales it by 255 itself); DeepFlow takes float32 scaled to 0-255 (its parameters are
tuned for that range; it converts to float without scaling). Output: float32 ``(H, W, 2)``,
``[..., 0]`` = du (column), ``[..., 1]`` = dv (row), in px, flow from image0 to image1
(``image0[v, u] ≈ image1[v + dv, u + du]``).

Threads: the wrappers never call ``cv2.setNumThreads``. OpenCV's own default (all cores) is
left in place, because the thread count is process-global state shared with the caller's
other OpenCV code; call ``cv2.setNumThreads(n)`` yourself to change it.

A fresh OpenCV object is created per call (≈ 10 µs): DIS keeps the last initial flow in its
internal buffers, so reusing one object across calls with and without ``init`` would leak a
stale warm start; fresh objects are also safe to use from several threads.

The DeepFlow variant of OpenCV exposes no parameters to Python (its C++ fields ``sigma``,
``alpha``, ``delta``, ``gamma``, ``omega``, ... are fixed at their defaults), so
:class:`DeepFlowParams` has no fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, ClassVar, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from .._params import param, validate
from ..errors import ParameterError
from ._checks import to_uint8
from ._registry import FlowMethod, register_flow_method

__all__ = [
    "DISParams",
    "DeepFlowParams",
    "FarnebackParams",
    "TVL1Params",
    "deepflow_flow",
    "dis_flow",
    "farneback_flow",
    "tvl1_flow",
]

DISPreset = Literal["ultrafast", "fast", "medium"]


def _init_or_none(init: NDArray[np.float32] | None) -> NDArray[np.float32] | None:
    return None if init is None else np.ascontiguousarray(init, dtype=np.float32).copy()


# --------------------------------------------------------------------------------------------
# DIS
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DISParams:
    """Parameters of OpenCV's Dense Inverse Search flow (Kroeger et al., ECCV 2016).

    Defaults are OpenCV 5's ``PRESET_FAST`` — the tracker of the ``fast`` fusion preset, so
    ``flow="dis"``, ``--flow dis`` and the default flow are one setting; :meth:`from_preset`
    gives ``ultrafast`` and ``medium``.

    Parameters
    ----------
    finest_scale : int
        Finest pyramid level that is solved (0 = full resolution; the result is upsampled).
        On an image too small for it (OpenCV's coarsest level, from the image size and
        ``patch_size``, is below ``finest_scale``), OpenCV chooses the levels itself from the
        image width: finest level ``max(floor(log2(2 W / (5 P))) - k, 0)`` with ``P`` its own
        patch size (8; 12 for ``finest_scale`` 3 or 4) and ``k`` 2 (4 for 3, 5 for 4), so
        ``finest_scale`` 9 solves the same levels as 0 on a 140 px wide image. ``fuse4d flow``
        prints the finest level OpenCV chose.
    patch_size : int
        Side of the square patches, px. Where OpenCV would choose the levels itself (see
        ``finest_scale``) it would also replace ``patch_size`` by its own ``P``; fuse4d
        refuses that case (:class:`~fuse4d.errors.ParameterError` naming a ``finest_scale``
        and a ``patch_size`` that run) instead of solving with another patch size. Images
        too small for a patch are padded (edge replication), but a ``patch_size`` above 12 px
        that needs more than 4 times the image's area is refused too.
    patch_stride : int
        Distance between neighbouring patches, px (smaller = denser, slower); at most
        ``patch_size``.
    gradient_descent_iterations : int
        Inverse-search gradient-descent iterations per patch.
    variational_refinement_iterations : int
        Fixed-point iterations of the variational refinement per level (0 = off).
    variational_refinement_alpha : float
        Smoothness weight of the variational refinement.
    variational_refinement_gamma : float
        Gradient-constancy weight of the variational refinement.
    variational_refinement_delta : float
        Colour-constancy weight of the variational refinement.
    variational_refinement_epsilon : float
        Charbonnier-penalty epsilon of the variational refinement, >= 1e-6 (OpenCV squares it
        in float32: below about 1e-22 that underflows and every flow vector becomes NaN).
    use_mean_normalization : bool
        Normalise patch means (robust to illumination change).
    use_spatial_propagation : bool
        Propagate good patch matches to neighbours.
    """

    finest_scale: int = param(2, ge=0)
    patch_size: int = param(8, ge=2, le=512)  # larger: gigabytes, no use
    patch_stride: int = param(4, ge=1)
    gradient_descent_iterations: int = param(16, ge=1)
    variational_refinement_iterations: int = param(5, ge=0)
    variational_refinement_alpha: float = param(20.0, ge=0)
    variational_refinement_gamma: float = param(10.0, ge=0)
    variational_refinement_delta: float = param(5.0, ge=0)
    variational_refinement_epsilon: float = param(0.01, ge=1e-6)  # 1e-23: all-NaN flow
    use_mean_normalization: bool = True
    use_spatial_propagation: bool = True

    #: Values that differ between OpenCV 5's presets (the rest are shared).
    PRESETS: ClassVar[dict[str, dict[str, int]]] = {
        "ultrafast": {
            "finest_scale": 2,
            "patch_stride": 4,
            "gradient_descent_iterations": 12,
            "variational_refinement_iterations": 0,
        },
        "fast": {},
        "medium": {
            "finest_scale": 1,
            "patch_stride": 3,
            "gradient_descent_iterations": 25,
            "variational_refinement_iterations": 5,
        },
    }

    def __post_init__(self) -> None:
        validate(self, finite=True)
        if self.patch_stride > self.patch_size:
            raise ParameterError(
                f"DISParams.patch_stride must be <= patch_size ({self.patch_size}), "
                f"got {self.patch_stride!r}"
            )

    @classmethod
    def from_preset(cls, preset: DISPreset, **overrides: Any) -> DISParams:
        """Parameters of OpenCV's ``ultrafast``, ``fast`` or ``medium`` preset, plus overrides."""
        if preset not in cls.PRESETS:
            raise ParameterError(
                f"unknown DIS preset {preset!r}; choose one of {', '.join(cls.PRESETS)}"
            )
        return cls(**{**cls.PRESETS[preset], **overrides})


def _make_dis(params: DISParams) -> cv2.DISOpticalFlow:
    dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    dis.setFinestScale(int(params.finest_scale))
    dis.setPatchSize(int(params.patch_size))
    dis.setPatchStride(int(params.patch_stride))
    dis.setGradientDescentIterations(int(params.gradient_descent_iterations))
    dis.setVariationalRefinementIterations(int(params.variational_refinement_iterations))
    dis.setVariationalRefinementAlpha(float(params.variational_refinement_alpha))
    dis.setVariationalRefinementGamma(float(params.variational_refinement_gamma))
    dis.setVariationalRefinementDelta(float(params.variational_refinement_delta))
    dis.setVariationalRefinementEpsilon(float(params.variational_refinement_epsilon))
    dis.setUseMeanNormalization(bool(params.use_mean_normalization))
    dis.setUseSpatialPropagation(bool(params.use_spatial_propagation))
    return dis


def dis_flow(
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    params: DISParams,
    init: NDArray[np.float32] | None,
) -> NDArray[np.float32]:
    """DIS flow from image0 to image1 (px, ``(H, W, 2)`` du, dv).

    ``init`` (a same-size flow) is handed to ``DISOpticalFlow.calc``, which resamples it to
    every pyramid level and tries it as an extra candidate for each patch (OpenCV's "temporal
    candidates"); it does not replace the coarse-to-fine search.

    Images that OpenCV's DIS cannot take (under 12 px; short and wide ones such as 12 x 40 px,
    on which OpenCV 4.x-5.x crashes the process, see :func:`_dis_accepts`) are padded by edge
    replication to the nearest size it takes, and the flow of the original pixels is returned.

    Raises
    ------
    ParameterError
        Where OpenCV would replace ``patch_size`` by its own (an image too small for
        ``finest_scale``; with ``patch_stride`` above OpenCV's patch it would crash), or
        where a ``patch_size`` above 12 px needs the image padded to more than 4 times its
        area (see :class:`DISParams`). The message names the values that fit.
    """
    h, w = image0.shape[:2]
    need_h, need_w = _dis_checked_shape(h, w, params)
    dis = _make_dis(params)
    if (need_h, need_w) == (h, w):
        return dis.calc(to_uint8(image0), to_uint8(image1), _init_or_none(init))

    def padded(a: NDArray) -> NDArray:
        return cv2.copyMakeBorder(a, 0, need_h - h, 0, need_w - w, cv2.BORDER_REPLICATE)

    flow = dis.calc(
        padded(to_uint8(image0)),
        padded(to_uint8(image1)),
        None if init is None else padded(_init_or_none(init)),
    )
    return np.ascontiguousarray(flow[:h, :w])


def _dis_accepts(height: int, width: int, params: DISParams) -> bool:
    """Whether OpenCV's ``DISOpticalFlow.calc`` runs on a ``height x width`` image.

    Mirrors ``DISOpticalFlowImpl::calc`` (OpenCV 4.5-5.x): the coarsest pyramid level is
    ``min(int(log2(max side / (4 patch)) + 0.5), int(log2(min side // patch)))``; below 0 it
    raises; below ``finest_scale`` it replaces the scales and patch size with a choice from
    the image *width* alone (``autoSelectPatchSizeAndScales``), whose coarsest level can be
    shorter than a patch on a short, wide image, and then it reads out of bounds. This test
    asks that level to hold a patch of the larger candidate size (12 px), which is
    conservative: it may refuse sizes OpenCV would take (they are then padded, not lost).
    Checked against OpenCV 5.1 on 1440 shapes and settings; ``tests/test_flow.py`` runs
    :func:`dis_flow` on every shape up to 64 px (and 640 px wide) in a child process.
    """
    patch, finest = int(params.patch_size), int(params.finest_scale)
    if min(height, width) // patch < 1:
        return False
    coarsest = _dis_coarsest(height, width, patch)
    if coarsest < 0:
        return False
    if coarsest >= finest:
        return True
    auto_coarsest = max(0, math.floor(math.log2(2.0 * width / (5.0 * 8))))
    return min(height, width) >> auto_coarsest >= 12


def _dis_padded_shape(height: int, width: int, params: DISParams) -> tuple[int, int]:
    """The given shape, or the nearest one (shorter side grown 1 px at a time) that
    :func:`_dis_accepts`."""
    while not _dis_accepts(height, width, params):
        if height <= width:
            height += 1
        else:
            width += 1
    return height, width


#: A patch_size above OpenCV's own (12 px) may make DIS pad an image to at most this many
#: times its area (the sizes of OpenCV's own pad tiny or thin crops to whatever they need).
_DIS_MAX_PAD_FACTOR = 4
_DIS_OWN_PATCH = 12


def _dis_coarsest(height: int, width: int, patch: int) -> int:
    """OpenCV's coarsest DIS pyramid level for a ``height x width`` image (an image that
    :func:`_dis_accepts`, whose shorter side holds a patch)."""
    short, long = min(height, width), max(height, width)
    ln2 = math.log(2.0)  # the same double expressions as OpenCV's (truncation toward zero)
    return min(int(math.log(long / (4.0 * patch)) / ln2 + 0.5), int(math.log(short // patch) / ln2))


def _dis_auto_levels(height: int, width: int, params: DISParams) -> tuple[int, int] | None:
    """``(patch size, finest level)`` that OpenCV's DIS chooses itself on a ``height x width``
    image that :func:`_dis_accepts` (``autoSelectPatchSizeAndScales``: its coarsest level is
    below ``finest_scale``), or None where it solves with ``params`` as given."""
    finest = int(params.finest_scale)
    if _dis_coarsest(height, width, int(params.patch_size)) >= finest:
        return None
    patch = 12 if finest in (3, 4) else 8
    coarsest = max(0, math.floor(math.log2(2.0 * width / (5.0 * patch))))
    return patch, max(coarsest - {3: 4, 4: 5}.get(finest, 2), 0)


def _dis_problem(height: int, width: int, params: DISParams) -> tuple[str, tuple[int, int]]:
    """Why DIS cannot solve a ``height x width`` image with ``params`` as asked ('' if it can),
    and the shape it solves on (:func:`_dis_padded_shape`)."""
    need_h, need_w = _dis_padded_shape(height, width, params)
    if (
        params.patch_size > _DIS_OWN_PATCH
        and need_h * need_w > _DIS_MAX_PAD_FACTOR * height * width
    ):
        return (
            f"DIS patch_size={params.patch_size} is too large for a {width} x {height} px "
            f"image (it would have to be padded to {need_w} x {need_h} px)"
        ), (need_h, need_w)
    auto = _dis_auto_levels(need_h, need_w, params)
    if auto is not None and auto[0] != params.patch_size:
        coarsest = _dis_coarsest(need_h, need_w, int(params.patch_size))
        crash = (
            f", and crash with patch_stride={params.patch_stride} > {auto[0]}"
            if params.patch_stride > auto[0]
            else ""
        )
        return (
            f"DIS finest_scale={params.finest_scale} with patch_size={params.patch_size} does "
            f"not fit a {width} x {height} px image: its coarsest pyramid level is {coarsest}, "
            f"and below finest_scale OpenCV would replace patch_size by {auto[0]}{crash}"
        ), (need_h, need_w)
    return "", (need_h, need_w)


def _dis_checked_shape(height: int, width: int, params: DISParams) -> tuple[int, int]:
    """The shape DIS solves a ``height x width`` image on (:func:`_dis_padded_shape`), or a
    :class:`ParameterError` (see :func:`_dis_problem`) naming the largest smaller
    ``finest_scale`` and ``patch_size`` (>= 8) that fit."""
    problem, shape = _dis_problem(height, width, params)
    if not problem:
        return shape
    hints = []
    for finest in range(int(params.finest_scale) - 1, -1, -1):
        if not _dis_problem(height, width, replace(params, finest_scale=finest))[0]:
            hints.append(f"finest_scale={finest}")
            break
    for patch in range(min(int(params.patch_size) - 1, max(min(height, width), 8)), 7, -1):
        smaller = replace(params, patch_size=patch, patch_stride=min(params.patch_stride, patch))
        if not _dis_problem(height, width, smaller)[0]:
            stride = f" (patch_stride <= {patch})" if params.patch_stride > patch else ""
            hints.append(f"patch_size={patch}{stride}")
            break
    raise ParameterError(problem + ("; it runs with " + " or ".join(hints) if hints else ""))


def _dis_levels_note(height: int, width: int, params: DISParams) -> str:
    """What OpenCV's DIS solves instead of ``finest_scale`` on a ``height x width`` image (''
    where it keeps it): for a user-facing note (``fuse4d flow``)."""
    shape = _dis_checked_shape(height, width, params)
    auto = _dis_auto_levels(*shape, params)
    if auto is None:
        return ""
    return (
        f"the {width} x {height} px image is too small for DIS finest_scale="
        f"{params.finest_scale}: OpenCV chose finest level {auto[1]} instead"
    )


# --------------------------------------------------------------------------------------------
# Farneback
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FarnebackParams:
    """Parameters of Farneback's polynomial-expansion flow (``cv2.calcOpticalFlowFarneback``).

    Parameters
    ----------
    pyr_scale : float
        Scale between pyramid levels, in (0, 1) (0.5 = classical pyramid).
    levels : int
        Number of pyramid levels including the full-size image.
    winsize : int
        Averaging window side, px (larger = more robust to noise, blurrier flow).
    iterations : int
        Iterations per pyramid level.
    poly_n : int
        Neighbourhood size of the polynomial expansion (5 or 7 are typical).
    poly_sigma : float
        Gaussian sigma of the polynomial expansion, px (1.1 for poly_n=5, 1.5 for 7).
    gaussian_window : bool
        Use a Gaussian instead of a box window (``OPTFLOW_FARNEBACK_GAUSSIAN``).
    """

    pyr_scale: float = param(0.5, gt=0, lt=1)
    levels: int = param(5, ge=1)
    winsize: int = param(15, ge=1)
    iterations: int = param(3, ge=1)
    poly_n: int = param(5, ge=1, le=255)  # OpenCV: typically 5 or 7; 1e5 hung
    poly_sigma: float = param(1.1, gt=0)
    gaussian_window: bool = False

    def __post_init__(self) -> None:
        validate(self, finite=True)


def farneback_flow(
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    params: FarnebackParams,
    init: NDArray[np.float32] | None,
) -> NDArray[np.float32]:
    """Farneback flow from image0 to image1 (px, ``(H, W, 2)`` du, dv).

    With ``init`` the flag ``OPTFLOW_USE_INITIAL_FLOW`` is set and the solve starts from it.
    """
    flags = cv2.OPTFLOW_FARNEBACK_GAUSSIAN if params.gaussian_window else 0
    flow = _init_or_none(init)
    if flow is not None:
        flags |= cv2.OPTFLOW_USE_INITIAL_FLOW
    return cv2.calcOpticalFlowFarneback(
        to_uint8(image0),
        to_uint8(image1),
        flow,
        pyr_scale=float(params.pyr_scale),
        levels=int(params.levels),
        winsize=int(params.winsize),
        iterations=int(params.iterations),
        poly_n=int(params.poly_n),
        poly_sigma=float(params.poly_sigma),
        flags=flags,
    )


# --------------------------------------------------------------------------------------------
# Dual TV-L1
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TVL1Params:
    """Parameters of Dual TV-L1 flow (Zach, Pock, Bischof 2007; ``cv2.optflow.DualTVL1``).

    Defaults are OpenCV's. OpenCV's names are given in brackets.

    Parameters
    ----------
    tau : float
        Time step of the numerical scheme [tau].
    data_weight : float
        Weight of the data term, λ; smaller = smoother [lambda].
    theta : float
        Tightness of the coupling between the two sub-problems [theta].
    num_scales : int
        Pyramid levels [nscales].
    num_warps : int
        Warpings per level [warps].
    epsilon : float
        Stopping threshold per level [epsilon].
    inner_iterations : int
        Inner iterations per warping [innnerIterations].
    outer_iterations : int
        Outer iterations per warping [outerIterations].
    scale_step : float
        Scale between pyramid levels, in (0, 1) [scaleStep].
    gamma : float
        Weight of the illumination-change term (0 = off) [gamma].
    median_filtering : int
        Median-filter size applied to the flow between warps: 1 (off), 3 or 5, the sizes
        OpenCV's float median filter takes [medianFiltering].
    """

    tau: float = param(0.25, gt=0)
    data_weight: float = param(0.15, gt=0)
    theta: float = param(0.3, gt=0)
    num_scales: int = param(5, ge=1)
    num_warps: int = param(5, ge=1)
    epsilon: float = param(0.01, gt=0)
    inner_iterations: int = param(30, ge=1)
    outer_iterations: int = param(10, ge=1)
    scale_step: float = param(0.8, gt=0, lt=1)
    gamma: float = param(0.0, ge=0)
    median_filtering: int = param(5, ge=1, le=5)  # OpenCV's float median: 1, 3, 5 only

    def __post_init__(self) -> None:
        validate(self, finite=True)
        if self.median_filtering % 2 == 0:
            raise ParameterError(
                f"TVL1Params.median_filtering must be 1 (off), 3 or 5, got "
                f"{self.median_filtering!r}"
            )


def tvl1_flow(
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    params: TVL1Params,
    init: NDArray[np.float32] | None,
) -> NDArray[np.float32]:
    """Dual TV-L1 flow from image0 to image1 (px, ``(H, W, 2)`` du, dv).

    Images go in as float32 in [0, 1] (no 8-bit quantisation). With ``init`` OpenCV's
    ``useInitialFlow`` is switched on and the finest level starts from it (coarser levels
    start from the downsampled init).
    """
    flow = _init_or_none(init)
    tvl1 = cv2.optflow.DualTVL1OpticalFlow_create(
        tau=float(params.tau),
        lambda_=float(params.data_weight),
        theta=float(params.theta),
        nscales=int(params.num_scales),
        warps=int(params.num_warps),
        epsilon=float(params.epsilon),
        innnerIterations=int(params.inner_iterations),
        outerIterations=int(params.outer_iterations),
        scaleStep=float(params.scale_step),
        gamma=float(params.gamma),
        medianFiltering=int(params.median_filtering),
        useInitialFlow=flow is not None,
    )
    a = np.ascontiguousarray(image0, dtype=np.float32)
    b = np.ascontiguousarray(image1, dtype=np.float32)
    return tvl1.calc(a, b, flow)


# --------------------------------------------------------------------------------------------
# DeepFlow
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DeepFlowParams:
    """DeepFlow (Weinzaepfel et al., ICCV 2013, without DeepMatching) — no tunable fields.

    OpenCV's Python binding of ``createOptFlow_DeepFlow`` exposes no setters, so the
    parameters are OpenCV's fixed defaults (``sigma=0.6``, ``alpha=1``, ``delta=0.5``,
    ``gamma=5``, ``omega=1.6``, ``fixedPointIterations=5``, ``sorIterations=25``, pyramid
    factor 0.95 down to 25 px).
    """

    def __post_init__(self) -> None:
        if fields(self):  # pragma: no cover - guard against accidental additions
            raise AssertionError("DeepFlowParams must stay empty")


def deepflow_flow(
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    params: DeepFlowParams,
    init: NDArray[np.float32] | None,
) -> NDArray[np.float32]:
    """DeepFlow from image0 to image1 (px, ``(H, W, 2)`` du, dv); ``init`` is not supported."""
    del params, init  # no parameters; OpenCV discards any input flow
    scale = np.float32(255.0)
    deep = cv2.optflow.createOptFlow_DeepFlow()
    return deep.calc(image0 * scale, image1 * scale, None)


def register() -> None:
    """Register the four OpenCV trackers (``dis``, ``farneback``, ``tvl1``, ``deepflow``)."""
    register_flow_method(
        FlowMethod(
            name="dis",
            function=dis_flow,
            params_type=DISParams,
            description="OpenCV Dense Inverse Search (fast; presets ultrafast/fast/medium)",
            supports_init=True,
            paper_method=False,
        )
    )
    register_flow_method(
        FlowMethod(
            name="farneback",
            function=farneback_flow,
            params_type=FarnebackParams,
            description="OpenCV Farneback polynomial expansion",
            supports_init=True,
            paper_method=False,
        )
    )
    register_flow_method(
        FlowMethod(
            name="tvl1",
            function=tvl1_flow,
            params_type=TVL1Params,
            description="OpenCV Dual TV-L1 (slow)",
            supports_init=True,
            paper_method=False,
        )
    )
    register_flow_method(
        FlowMethod(
            name="deepflow",
            function=deepflow_flow,
            params_type=DeepFlowParams,
            description="OpenCV DeepFlow (most accurate OpenCV tracker; no warm start)",
            supports_init=False,
            paper_method=False,
        )
    )

    # --- PMBP registration (pmbp.py) ---
    # The paper's tracker registers "pmbp" and "pmbp-fast". Kept at the very end: pmbp.py imports
