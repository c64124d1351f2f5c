"""Stage 1 — dense intensity tracking: flow fields of frames, pairs and sequences (METHOD §2).

Conventions (STYLE.md): intensity images are float32 ``(H, W)`` in [0, 1]; a flow field is
float32 ``(H, W, 2)`` in px with ``[..., 0]`` = du (column) and ``[..., 1]`` = dv (row), defined
on the grid of its *source* image: ``image0[v, u] ≈ image1[v + dv, u + du]``. For a sequence,
``forward[t]`` = s^{t,t+1} (on frame t's grid) and ``backward[t]`` = s^{t+1,t} (on frame t+1's
grid), both ``(T-1, H, W, 2)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import as_float32, check_shape
from .._version import __version__
from ..errors import Fuse4dError, ParameterError, ParameterTypeError, ShapeError
from ..sequence import normalize_intensity
from ._checks import check_flow_field, check_image, check_roi
from ._registry import FlowMethod, Roi, get_flow_method, resolve_flow_params
from .cache import FlowCache, hash_parts

__all__ = [
    "FLOW_CODE_VERSION",
    "SequenceFlow",
    "SequenceFlowEstimator",
    "estimate_flow",
    "estimate_flow_pair",
    "estimate_sequence_flow",
    "warp_image",
]

#: Bumped whenever a change in this module or a registered method changes flow results; part
#: of every cache key (together with the fuse4d and OpenCV versions).
FLOW_CODE_VERSION = "2"  # 2: PMBP post-steps (A23)

# --------------------------------------------------------------------------------------------
# Single flow field
# --------------------------------------------------------------------------------------------


def _run_cropped(
    m: FlowMethod,
    function: Callable[..., Any],
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    params: Any,
    init: NDArray[np.float32] | None,
    roi: Roi | None,
    directions: tuple[str, ...] = ("image0 -> image1",),
) -> list[NDArray[np.float32]]:
    """Call ``function`` (a method's single or pair function; inputs validated) on the ``roi``
    crop, and return its flow field(s) checked and zero-padded to the full image;
    ``directions`` names each returned field in errors."""
    init = init if m.supports_init else None
    shape = image0.shape
    r0, r1, c0, c1 = roi if roi is not None else (0, shape[0], 0, shape[1])
    crop = (slice(r0, r1), slice(c0, c1))
    if roi is not None:
        image0 = np.ascontiguousarray(image0[crop])
        image1 = np.ascontiguousarray(image1[crop])
        init = None if init is None else np.ascontiguousarray(init[crop])
    result = function(image0, image1, params, init)
    fields = list(result) if isinstance(result, tuple) else [result]
    fields = [
        _check_output(m, f, (r1 - r0, c1 - c0), what)
        for f, what in zip(fields, directions, strict=False)
    ]
    if roi is None:
        return fields
    padded = []
    for f in fields:
        full = np.zeros((*shape, 2), np.float32)
        full[crop] = f
        padded.append(full)
    return padded


def _run_method(
    m: FlowMethod,
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    params: Any,
    init: NDArray[np.float32] | None,
    roi: Roi | None,
    direction: str = "image0 -> image1",
) -> NDArray[np.float32]:
    """One direction with ``m.function`` (see :func:`_run_cropped`)."""
    return _run_cropped(m, m.function, image0, image1, params, init, roi, (direction,))[0]


def _check_output(
    m: FlowMethod, flow: Any, shape: tuple[int, ...], direction: str
) -> NDArray[np.float32]:
    """The method's flow as float32 ``(H, W, 2)``; a method bug (wrong shape) is a
    RuntimeError, a non-finite flow (a parameter value the solver cannot take, such as a
    vanishing epsilon) a :class:`ParameterError` naming the method and the direction, so that
    it never reaches the fusion or another solve as a warm start."""
    arr = np.asarray(flow)
    if arr.shape != (*shape, 2):
        raise RuntimeError(
            f"flow method {m.name!r} returned shape {arr.shape}, expected {(*shape, 2)}"
        )
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    if np.isfinite(arr).all():  # (0.1 ms a 600 x 600 field; the count below is 4 ms)
        return arr
    bad = ~np.isfinite(arr).all(axis=-1)
    if bad.any():
        raise ParameterError(
            f"flow method {m.name!r} returned NaN or inf at {int(bad.sum())} of {bad.size} px "
            f"of the flow {direction}; check its parameters"
        )
    return arr


def estimate_flow(
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    *,
    method: str | FlowMethod = "dis",
    params: Any = None,
    init: NDArray[np.float32] | None = None,
    roi: Roi | None = None,
) -> NDArray[np.float32]:
    """Dense optical flow from ``image0`` to ``image1``.

    Parameters
    ----------
    image0, image1 : (H, W) ndarray
        Intensity frames, float in [0, 1]; uint8/uint16 are divided by 255/65535 (a
        ``cv2.imread`` uint8 frame by 255), as :class:`fuse4d.FusionEngine` does. Floats far
        outside [0, 1] (0-255) are refused.
    method : str or FlowMethod, optional
        A name from :func:`available_flow_methods` (``"dis"`` by default; ``"pmbp"`` is the
        paper's tracker once registered).
    params : dataclass or mapping, optional
        The method's parameters (see :func:`resolve_flow_params`); default: its defaults.
    init : (H, W, 2) ndarray, optional
        Initial flow (px) for methods with ``supports_init``; ignored by the others.
    roi : (row0, row1, col0, col1), optional
        Solve only inside this half-open box (px); the flow is 0 outside it. The method sees
        the cropped images, so a match must lie inside the box too.

    Returns
    -------
    flow : (H, W, 2) ndarray of float32
        Flow in px on image0's grid, ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row):
        ``image0[v, u] ≈ image1[v + dv, u + du]``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> image = cv2.GaussianBlur(rng.random((64, 64)).astype(np.float32), (0, 0), 2)
    >>> flow = estimate_flow(image, image, method="dis")
    >>> flow.shape, bool(np.abs(flow).max() < 0.05)
    ((64, 64, 2), True)
    """
    m, p, a, b, init_arr, box = _check_call(method, params, image0, image1, init, "init", roi)
    return _run_method(m, a, b, p, init_arr, box)


def _check_call(
    method: str | FlowMethod,
    params: Any,
    image0: Any,
    image1: Any,
    init: Any,
    init_name: str,
    roi: Roi | None,
) -> tuple[FlowMethod, Any, NDArray[np.float32], NDArray[np.float32], Any, Roi | None]:
    """Resolve the method and its params and validate the images, warm start and roi."""
    m = get_flow_method(method)
    p = resolve_flow_params(m, params)
    a = check_image(image0, "image0")
    b = check_image(image1, "image1")
    if a.shape != b.shape:
        raise ShapeError("image1", a.shape, b.shape, f"It must match image0 {a.shape}")
    init_arr = None if init is None else check_flow_field(init, a.shape, init_name)
    return m, p, a, b, init_arr, check_roi(roi, a.shape)


# --------------------------------------------------------------------------------------------
# Pairs and sequences
# --------------------------------------------------------------------------------------------


def _pair_cache_key(
    m: FlowMethod,
    params: Any,
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    init_forward: NDArray[np.float32] | None,
    roi: Roi | None,
) -> str:
    return hash_parts(
        "fuse4d-flow-pair",
        FLOW_CODE_VERSION,
        __version__,
        cv2.__version__,
        m.name,
        repr(params),
        repr(roi),
        image0,
        image1,
        init_forward if m.supports_init else None,
    )


def estimate_flow_pair(
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    *,
    method: str | FlowMethod = "dis",
    params: Any = None,
    init_forward: NDArray[np.float32] | None = None,
    roi: Roi | None = None,
    cache: FlowCache | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Forward and backward flow of one frame pair (METHOD §2.4), each solved once.

    Parameters
    ----------
    image0, image1 : (H, W) ndarray
        Frames t and t+1, float in [0, 1] (integers: as in :func:`estimate_flow`).
    method, params, roi
        As in :func:`estimate_flow`.
    init_forward : (H, W, 2) ndarray, optional
        Warm start of the forward solve (usually the previous pair's forward flow). The
        backward solve is always warm-started with ``-forward`` (METHOD §2.3) when the method
        supports init.
    cache : FlowCache, optional
        On-disk cache. The key covers both frames' bytes, the method, ``repr(params)``, the ROI,
        the warm start, and the fuse4d / flow-code / OpenCV versions.

    Returns
    -------
    forward : (H, W, 2) ndarray of float32
        s^{t,t+1} on frame t's grid, px (du, dv).
    backward : (H, W, 2) ndarray of float32
        s^{t+1,t} on frame t+1's grid, px (du, dv).
    """
    m, p, a, b, init, box = _check_call(
        method, params, image0, image1, init_forward, "init_forward", roi
    )
    key = None
    if cache is not None:
        key = _pair_cache_key(m, p, a, b, init, box)
        hit = cache.load(key)
        if hit is not None and hit.shape == (2, *a.shape, 2) and hit.dtype == np.float32:
            return hit[0], hit[1]
    directions = ("image0 -> image1 (forward)", "image1 -> image0 (backward)")
    if m.pair_function is not None:
        forward, backward = _run_cropped(m, m.pair_function, a, b, p, init, box, directions)
    else:
        forward = _run_method(m, a, b, p, init, box, directions[0])
        backward_init = -forward if m.supports_init else None
        backward = _run_method(m, b, a, p, backward_init, box, directions[1])
    if cache is not None and key is not None:
        cache.store(key, np.stack([forward, backward]))
    return forward, backward


@dataclass(frozen=True)
class SequenceFlow:
    """Forward and backward flow of every consecutive pair of a video.

    The one way to hand flows to the fusion (:func:`fuse4d.fuse_sequence` ``flow=``): what
    :func:`estimate_sequence_flow` returns, or flows computed elsewhere (ground truth, another
    tool) wrapped as ``SequenceFlow(forward, backward)``; :func:`as_sequence_flow` also accepts
    a plain ``(forward, backward)`` pair of arrays.

    Attributes
    ----------
    forward : (T-1, H, W, 2) ndarray of float32
        ``forward[t]`` = s^{t,t+1} on frame t's grid, px, ``[..., 0]`` = du (column).
    backward : (T-1, H, W, 2) ndarray of float32
        ``backward[t]`` = s^{t+1,t} on frame t+1's grid, px.
    method : str
        Registry name of the method that produced it (``"precomputed"`` when unknown).
    params : dataclass or None
        The parameters used, if known.
    paper_method : bool
        False when the flow does not come from the paper's tracker (PMBP): results built on it
        must say so (METHOD §2.5 item 7).
    """

    forward: NDArray[np.float32]
    backward: NDArray[np.float32]
    method: str = "precomputed"
    params: Any = None
    paper_method: bool = False

    @property
    def num_pairs(self) -> int:
        """Number of frame pairs, T-1."""
        return int(self.forward.shape[0])


def as_sequence_flow(flow: Any, shape: tuple[int, int, int] | None = None) -> SequenceFlow:
    """``flow`` as a :class:`SequenceFlow`, checked against a ``(T, H, W)`` video shape.

    Parameters
    ----------
    flow : SequenceFlow, (forward, backward) tuple, or an object with ``.forward``/``.backward``
        Pair flows, each ``(T-1, H, W, 2)`` px.
    shape : (T, H, W), optional
        The video the flows belong to; when given, both arrays must be ``(T-1, H, W, 2)``.

    Returns
    -------
    SequenceFlow

    Raises
    ------
    ParameterTypeError
        If ``flow`` is none of the accepted forms (also a :class:`TypeError`).
    ShapeError
        If an array does not fit ``shape``.
    """
    if isinstance(flow, SequenceFlow):
        result = flow
    elif isinstance(flow, tuple | list) and len(flow) == 2:
        result = SequenceFlow(np.asarray(flow[0]), np.asarray(flow[1]))
    elif hasattr(flow, "forward") and hasattr(flow, "backward"):
        result = SequenceFlow(np.asarray(flow.forward), np.asarray(flow.backward))
    else:
        got = type(flow).__name__
        if isinstance(flow, np.ndarray):
            got = f"one array of shape {flow.shape} (pass the backward flows too)"
        raise ParameterTypeError(
            "flow: precomputed flows must be a SequenceFlow or a (forward, backward) pair of "
            f"(T-1, H, W, 2) arrays, px, got {got}"
        )
    if shape is not None:
        n, h, w = shape
        for name, f in (("flow.forward", result.forward), ("flow.backward", result.backward)):
            check_shape(np.asarray(f), (max(n - 1, 0), h, w, 2), name=name)
    return result


class SequenceFlowEstimator:
    """Pair-by-pair flow for a stream of frames, with warm starts across pairs.

    Call it with consecutive pairs ``(I^t, I^{t+1})``. When ``warm_start`` is on and the method
    supports init, the forward solve of a pair starts from the previous pair's forward flow,
    provided that the new ``image0`` equals the previous ``image1`` (checked, so that a jump in
    the stream silently falls back to a cold start). The backward solve starts from
    ``-forward`` (METHOD §2.3).

    Parameters
    ----------
    method, params, roi, cache
        As in :func:`estimate_flow_pair`.
    warm_start : bool, optional
        Use warm starts (default True).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> frames = [cv2.GaussianBlur(rng.random((48, 48)).astype(np.float32), (0, 0), 2)] * 3
    >>> estimator = SequenceFlowEstimator(method="farneback")
    >>> forward, backward = estimator(frames[0], frames[1])
    >>> forward, backward = estimator(frames[1], frames[2])  # warm-started
    >>> estimator.warm_starts
    1
    """

    def __init__(
        self,
        *,
        method: str | FlowMethod = "dis",
        params: Any = None,
        warm_start: bool = True,
        roi: Roi | None = None,
        cache: FlowCache | None = None,
    ) -> None:
        self.method = get_flow_method(method)
        self.params = resolve_flow_params(self.method, params)
        self.warm_start = bool(warm_start)
        self.roi = roi
        self.cache = cache
        self.warm_starts = 0
        self._last_image1: NDArray[np.float32] | None = None
        self._last_forward: NDArray[np.float32] | None = None

    def reset(self) -> None:
        """Forget the previous pair (the next call starts cold)."""
        self._last_image1 = None
        self._last_forward = None

    def prime(self, image1: NDArray[np.float32], forward: NDArray[np.float32]) -> None:
        """Continue a stream: behave as if the previous pair ended on ``image1`` with forward
        flow ``forward`` (px), so that the next pair starting at ``image1`` is warm-started
        from it exactly as in one uninterrupted run (resumed runs)."""
        self._last_image1 = np.array(image1, dtype=np.float32, copy=True)
        self._last_forward = np.array(forward, dtype=np.float32, copy=True)

    def __call__(
        self, image0: NDArray[np.float32], image1: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Forward and backward flow of the pair; see :func:`estimate_flow_pair`."""
        init = None
        use_init = self.warm_start and self.method.supports_init
        if use_init and self._last_forward is not None and self._last_image1 is not None:
            a = np.asarray(image0)
            if a.shape == self._last_image1.shape and np.array_equal(a, self._last_image1):
                init = self._last_forward
                self.warm_starts += 1
        forward, backward = estimate_flow_pair(
            image0,
            image1,
            method=self.method,
            params=self.params,
            init_forward=init,
            roi=self.roi,
            cache=self.cache,
        )
        if use_init:
            self._last_image1 = np.array(image1, dtype=np.float32, copy=True)
            self._last_forward = forward
        return forward, backward


def estimate_sequence_flow(
    intensity: NDArray[np.float32],
    *,
    method: str | FlowMethod = "dis",
    params: Any = None,
    warm_start: bool = True,
    roi: Roi | None = None,
    cache: FlowCache | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SequenceFlow:
    """Forward and backward flow for every consecutive pair of an intensity video.

    Parameters
    ----------
    intensity : (T, H, W) ndarray
        Intensity frames, float in [0, 1] (uint8/uint16 divided by 255/65535),
        T >= 2.
    method, params, roi, cache
        As in :func:`estimate_flow_pair` (``roi`` = (row0, row1, col0, col1), flow 0 outside).
    warm_start : bool, optional
        Warm starts across pairs (METHOD §2.3) for methods that support init: forward t starts
        from forward t-1, backward t from -forward t.
    progress : callable, optional
        ``progress(done, total)`` after each pair (total = T-1).

    Returns
    -------
    SequenceFlow
        ``.forward`` and ``.backward``, each ``(T-1, H, W, 2)`` float32 px.
    """
    video = np.asarray(intensity)
    if video.dtype.kind in "uib":  # as check_image does per frame
        video = normalize_intensity(video, name="intensity")
    video = as_float32(video, name="intensity")
    check_shape(video, ("T", "H", "W"), name="intensity")
    num_frames = video.shape[0]
    if num_frames < 2:
        raise ParameterError(f"intensity needs at least 2 frames for flow, got {num_frames}")
    estimator = SequenceFlowEstimator(
        method=method, params=params, warm_start=warm_start, roi=roi, cache=cache
    )
    shape = (num_frames - 1, *video.shape[1:], 2)
    forward = np.empty(shape, np.float32)
    backward = np.empty(shape, np.float32)
    for t in range(num_frames - 1):
        try:
            forward[t], backward[t] = estimator(video[t], video[t + 1])
        except ValueError as exc:  # (a fuse4d input error stays one)
            error = ParameterError if isinstance(exc, Fuse4dError) else ValueError
            raise error(f"frame pair ({t}, {t + 1}): {exc}") from exc
        if progress is not None:
            progress(t + 1, num_frames - 1)
    return SequenceFlow(
        forward=forward,
        backward=backward,
        method=estimator.method.name,
        params=estimator.params,
        paper_method=estimator.method.paper_method,
    )


def warp_image(
    image: NDArray[np.floating],
    flow: NDArray[np.float32],
    *,
    border: Literal["replicate", "nan"] = "replicate",
) -> NDArray[np.float32]:
    """Backward-warp ``image`` with ``flow``: ``out[v, u] = image[v + dv, u + du]`` (bilinear).

    With the forward flow s^{t,t+1}, ``warp_image(I^{t+1}, s)`` ≈ ``I^t``.

    Parameters
    ----------
    image : (H, W) or (H, W, C) ndarray
        Image to sample (converted to float32).
    flow : (H, W, 2) ndarray
        Flow in px, ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row).
    border : {"replicate", "nan"}, optional
        Samples outside the image repeat the edge, or become NaN.

    Returns
    -------
    (H, W) or (H, W, C) ndarray of float32
    """
    img = as_float32(image, name="image")
    check_shape(img, ("*", "H", "W"), name="image")
    if img.ndim not in (2, 3):
        raise ShapeError("image", ("H", "W", "[C]"), img.shape)
    f = as_float32(flow, name="flow")
    check_shape(f, (*img.shape[:2], 2), name="flow", hint="It must match the image's (H, W)")
    h, w = img.shape[:2]
    grid_v, grid_u = np.mgrid[0:h, 0:w].astype(np.float32)
    map_u = grid_u + f[..., 0]
    map_v = grid_v + f[..., 1]
    if border not in ("replicate", "nan"):
        raise ParameterError(f"border must be 'replicate' or 'nan', got {border!r}")
    out = cv2.remap(img, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if border == "nan":
        # Not BORDER_CONSTANT=NaN: OpenCV would blend the NaN in with weight 0 (NaN * 0 = NaN)
        # at samples that lie exactly on the last row/column.
        outside = (map_u < 0) | (map_u > w - 1) | (map_v < 0) | (map_v > h - 1)
        out[outside] = np.nan
    return out
