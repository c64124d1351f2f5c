"""The two-stage dask graph: pair flows once per pair, then fusion per time chunk with a halo.

Stage 1 (:func:`flows`): pair chunk k holds pairs ``[k c, (k+1) c)`` (c = ``chunk_frames``) and
reads the intensity frames ``[k c, (k+1) c + 1)`` — a one-frame halo. Each pair's forward and
backward flow is solved exactly once in the whole graph.

Warm starts (METHOD §2.3, on by default in :func:`fuse4d.fuse_sequence` and the streaming
engine) chain every pair's forward solve to the previous pair's result, so no pair can be solved
independently of all earlier ones without changing its bits. Two modes, both bit-identical to
the in-memory path run with the same setting:

- ``warm_start=True`` (default, = ``fuse_sequence`` defaults): pair chunk k starts from a tiny
  "seed" task holding the last forward flow of chunk k-1. Stage 1 is then a serial chain per
  recording (flow is ~7-10 % of the work with DIS), while stage 2 runs in parallel as soon as
  its flows exist.
- ``warm_start=False``: every pair chunk is independent (fully parallel stage 1); equal to
  ``FusionEngine(..., warm_start=False)`` and to ``fuse_sequence`` with
  ``estimate_sequence_flow(..., warm_start=False)`` flows.

Stage 2 (:func:`fuse`): time chunk ``[s, e)`` runs a :class:`fuse4d.FusionEngine` (new, or the
process's previous chunk engine reset: the same bits, :func:`chunk_engine`) over the
frames ``[max(0, s - past), min(T, e + future))`` with the precomputed pair flows and keeps the
frames ``[s, e)``; the engine is flushed only when the chunk reaches the end of the sequence,
so the truncated windows at both ends are exactly the in-memory ones. The halo (``past`` before,
``future`` after; ``num_frames - 1`` before and none after in causal mode) is read by slicing the
input dask arrays, which works for any halo/chunk ratio and for inputs of different ndim.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import dask
import dask.array as da
import numpy as np
from numpy.typing import NDArray

from .._validation import as_float32
from ..camera import Intrinsics, check_intrinsics
from ..config import FlowConfig, FusionParams, fusion_params, preset
from ..errors import ParameterError, ShapeError
from ..flow import (
    FlowCache,
    FlowMethod,
    Roi,
    SequenceFlow,
    estimate_flow,
    estimate_flow_pair,
    get_flow_method,
)
from ..fusion import FusionEngine
from ..sequence import normalize_intensity

__all__ = [
    "DaskFlows",
    "DaskFusion",
    "as_dask_video",
    "chunk_bounds",
    "delayed_blocks",
    "even_chunk_frames",
    "flows",
    "fuse",
]


@dataclass(frozen=True)
class DaskFlows:
    """Lazy forward/backward flows of every consecutive pair.

    Attributes
    ----------
    forward, backward : dask.array.Array, (T-1, H, W, 2) float32
        px, same conventions as :class:`fuse4d.flow.SequenceFlow`; chunked by
        ``chunk_frames`` pairs along the first axis.
    method : str
        Flow method name ("precomputed" for given flows).
    warm_start : bool
        Whether the pairs were warm-started (see the module docstring).
    """

    forward: da.Array
    backward: da.Array
    method: str = "precomputed"
    warm_start: bool = False

    @property
    def num_pairs(self) -> int:
        """T - 1."""
        return int(self.forward.shape[0])

    def compute(self, **kwargs: Any) -> SequenceFlow:
        """Both flows as an in-memory :class:`~fuse4d.flow.SequenceFlow` (``kwargs`` go to
        :func:`dask.compute`)."""
        fwd, bwd = dask.compute(self.forward, self.backward, **kwargs)
        return SequenceFlow(np.asarray(fwd), np.asarray(bwd), method=self.method)


@dataclass(frozen=True)
class DaskFusion:
    """Lazy result of :func:`fuse`; compute what you need in one :func:`dask.compute` call so
    that shared tasks run once.

    Attributes
    ----------
    points : dask.array.Array, (T, H, W, 3) float32
        Fused 3D points, mm.
    depth : dask.array.Array, (T, H, W) float32
        Fused depth (Z of ``points``), mm, NaN = invalid.
    support : dask.array.Array, (T, H, W) uint8
        Temporal support (frames whose track passed every check).
    filled : dask.array.Array, (T, H, W) bool
        Pixels filled by Eq. 6.
    flows : DaskFlows
        The pair flows the fusion used.
    chunk_frames : int
        Frames per time chunk of the outputs.
    params : FusionParams
    """

    points: da.Array
    depth: da.Array
    support: da.Array
    filled: da.Array
    flows: DaskFlows
    chunk_frames: int
    params: FusionParams
    #: Futures of inputs scattered to the caller's client, kept alive with the result.
    scattered: tuple[Any, ...] = ()
    #: (T, H, W) uint8: where each value comes from (:attr:`fuse4d.FusedFrame.source`).
    source: da.Array | None = None
    #: (T, H, W) float32: fraction of the window's frames that measured it (``confidence``).
    confidence: da.Array | None = None

    @property
    def num_chunks(self) -> int:
        """Number of time chunks."""
        return len(self.depth.chunks[0])


# ------------------------------------------------------------------------------------ inputs
def chunk_bounds(total: int, chunk_frames: int) -> list[tuple[int, int]]:
    """Half-open ``[start, stop)`` frame ranges of the time chunks of a ``total``-frame video.

    Examples
    --------
    >>> chunk_bounds(7, 3)
    [(0, 3), (3, 6), (6, 7)]
    """
    if chunk_frames < 1:
        raise ParameterError(f"chunk_frames must be >= 1, got {chunk_frames}")
    return [(s, min(s + chunk_frames, total)) for s in range(0, total, chunk_frames)]


def even_chunk_frames(total: int, max_frames: int) -> int:
    """The chunk length that splits a ``total``-frame recording into the fewest chunks of at
    most ``max_frames`` frames, as evenly as a constant chunk length allows.

    A plain ``max_frames`` split can leave a short last chunk (300 frames by 32: nine of 32
    and one of 12), which finishes early and leaves a worker idle at the end of the run while
    the others fuse full chunks (measured: ~2-4 s of one worker's time at 600 x 600); the
    halo costs the same per chunk, so fewer frames in the last chunk buy nothing. The length
    stays constant (zarr shards form a regular grid), so only the last chunk may be shorter,
    by less than the number of chunks.

    Examples
    --------
    >>> even_chunk_frames(300, 32), even_chunk_frames(1200, 32), even_chunk_frames(20, 32)
    (30, 32, 20)
    """
    if max_frames < 1:
        raise ParameterError(f"chunk_frames must be >= 1, got {max_frames}")
    if total < 1:
        return max_frames
    chunks = -(-total // max_frames)
    return -(-total // chunks)


def as_dask_video(x: Any, name: str, *, ndim: int) -> da.Array:
    """``x`` (numpy, dask or zarr array, or anything array-like) as a dask array of ``ndim``
    dimensions whose frames are whole (one chunk over every non-time axis)."""
    if isinstance(x, da.Array):
        arr = x
    else:
        # numpy: one chunk (already in memory); zarr and other chunked stores: their time chunks
        stored = getattr(x, "chunks", None)
        time_chunk = stored[0] if isinstance(stored, tuple) and stored else -1
        arr = da.from_array(x, chunks=(time_chunk, *([-1] * (ndim - 1))), asarray=True)
    if arr.ndim != ndim:
        raise ShapeError(name, ("T", "H", "W", *(["C"] if ndim == 4 else [])), arr.shape)
    if any(len(c) > 1 for c in arr.chunks[1:]):
        arr = arr.rechunk({i: -1 for i in range(1, ndim)})
    return arr


def delayed_blocks(x: da.Array) -> list[Any]:
    """The time chunks of ``x`` (whole frames) as Delayed objects that keep their keys.

    Passing a dask array straight to :func:`dask.delayed` would optimise (rename and fuse) a
    private copy of its graph for every consumer, so a task shared by two consumers (a flow
    chunk read by two halos, a fusion chunk written as three arrays) would run once per
    consumer; ``optimize_graph=False`` keeps one shared task per key.
    """
    return list(x.to_delayed(optimize_graph=False).ravel())


def _frames(blocks: list[NDArray[Any]] | None) -> Iterator[NDArray[Any]]:
    """The frames of a list of time chunks, in order (views, no copy)."""
    for block in blocks or []:
        yield from block


def _intensity_frame(frame: NDArray[Any]) -> NDArray[np.float32]:
    """The float32 [0, 1] frame that :meth:`FusionEngine.push` keeps (and tracks on)."""
    return normalize_intensity(frame) if frame.dtype.kind != "f" else as_float32(frame, name="i")


def _flow_config(flow: FlowConfig | str | None) -> FlowConfig:
    if flow is None:
        return preset("fast").flow
    return FlowConfig(flow) if isinstance(flow, str) else flow


# ------------------------------------------------------------------------------------ stage 1
def _flow_chain(
    frames: Iterable[NDArray[Any]],
    method: FlowMethod,
    params: Any,
    seed: NDArray[np.float32] | None,
    chained: bool,
    roi: Roi | None,
    cache: FlowCache | None,
    *,
    backward: bool = True,
) -> Iterator[tuple[NDArray[np.float32], NDArray[np.float32] | None]]:
    """Forward and backward flow (px, float32 ``(H, W, 2)``) of each consecutive pair of
    ``frames`` (n+1 intensity frames -> n pairs, read lazily in order), chained like
    :class:`fuse4d.flow.SequenceFlowEstimator`.

    Parameters
    ----------
    frames : iterable of (H, W) arrays
        Intensity frames as :meth:`fuse4d.FusionEngine.push` takes them ([0, 1] floats, or
        uint8/uint16 divided by 255/65535).
    method, params, roi, cache
        As in :func:`fuse4d.flow.estimate_flow_pair`.
    seed : (H, W, 2) float32 array, optional
        Warm start of the first pair's forward solve (the previous pair's forward flow, px).
    chained : bool
        Warm-start each forward solve from ``seed`` and then from the previous pair's forward
        flow (the caller checks ``method.supports_init``); False: no warm starts at all.
    backward : bool
        False: the forward solves only, each as :func:`fuse4d.flow.estimate_flow_pair` runs
        it (for methods without a pair function; ``cache`` must be None), and None for the
        backward flow.

    Yields
    ------
    forward, backward : (H, W, 2) float32 arrays
        Flow of pair j, px, as :func:`fuse4d.flow.estimate_flow_pair` returns it.
    """
    it = iter(frames)
    init = seed if chained else None
    previous = _intensity_frame(np.asarray(next(it)))
    for frame in it:
        current = _intensity_frame(np.asarray(frame))
        if backward:
            forward, back = estimate_flow_pair(
                previous,
                current,
                method=method,
                params=params,
                init_forward=init,
                roi=roi,
                cache=cache,
            )
            yield np.asarray(forward, np.float32), np.asarray(back, np.float32)
        else:
            forward = estimate_flow(
                previous, current, method=method, params=params, init=init, roi=roi
            )
            yield forward, None
        if chained:
            init = forward
        previous = current


def _flow_block(
    blocks: list[NDArray[Any]],
    seed: NDArray[np.float32] | None,
    config: FlowConfig,
    warm_start: bool,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Flows of the pairs of the intensity frames in ``blocks`` (n+1 frames -> n pairs),
    chained like :class:`fuse4d.flow.SequenceFlowEstimator` starting from ``seed``."""
    intensity = list(_frames(blocks))
    method = get_flow_method(config.method)
    params = config.build_params()
    cache = None if config.cache_dir is None else FlowCache(config.cache_dir)
    n = len(intensity) - 1
    h, w = intensity[0].shape
    forward = np.empty((n, h, w, 2), np.float32)
    backward = np.empty((n, h, w, 2), np.float32)
    chain = _flow_chain(
        intensity, method, params, seed, warm_start and method.supports_init, config.roi, cache
    )
    for j, (f, g) in enumerate(chain):
        assert g is not None
        forward[j], backward[j] = f, g
    return forward, backward


def _last_forward(block: tuple[NDArray[np.float32], NDArray[np.float32]]) -> NDArray[np.float32]:
    return np.array(block[0][-1])


def flows(
    intensity: Any,
    *,
    flow: FlowConfig | str | None = None,
    chunk_frames: int = 32,
    warm_start: bool = True,
) -> DaskFlows:
    """Forward and backward flow of every consecutive pair, each solved once, as dask arrays.

    Parameters
    ----------
    intensity : (T, H, W) numpy, dask or zarr array
        Registered intensity, [0, 1] floats or uint8/uint16 (divided by 255/65535), exactly
        as :meth:`fuse4d.FusionEngine.push` takes it.
    flow : FlowConfig or str, optional
        Tracker, its parameters, cache folder and ROI (default: the "fast" preset, DIS).
    chunk_frames : int
        Pairs per chunk (each chunk reads one extra frame).
    warm_start : bool
        Chain warm starts across pairs exactly like the in-memory path (serial stage 1 per
        recording); False solves every chunk independently (see the module docstring).

    Returns
    -------
    DaskFlows
        ``(T-1, H, W, 2)`` float32 px arrays, bit-identical to
        :func:`fuse4d.flow.estimate_sequence_flow` with the same ``warm_start``.
    """
    config = _flow_config(flow)
    config.build_params()  # validate before building the graph
    video = as_dask_video(intensity, "intensity", ndim=3)
    total, h, w = video.shape
    pairs = max(total - 1, 0)
    shape = (h, w, 2)
    if pairs == 0:
        empty = da.zeros((0, *shape), np.float32, chunks=(1, *shape))
        return DaskFlows(empty, empty, config.method, warm_start)
    forward, backward = [], []
    seed = None
    chained = warm_start and get_flow_method(config.method).supports_init
    for a, b in chunk_bounds(pairs, chunk_frames):
        block = dask.delayed(_flow_block, nout=2, pure=True)(
            delayed_blocks(video[a : b + 1]), seed, config, warm_start
        )
        forward.append(da.from_delayed(block[0], (b - a, *shape), np.float32))
        backward.append(da.from_delayed(block[1], (b - a, *shape), np.float32))
        if chained:
            seed = dask.delayed(_last_forward, pure=True)(block)
    return DaskFlows(
        da.concatenate(forward), da.concatenate(backward), config.method, bool(chained)
    )


def _as_dask_flows(flow: Any, total: int, h: int, w: int) -> DaskFlows:
    """Given flows (DaskFlows, SequenceFlow, (forward, backward) of numpy/dask/zarr)."""
    if isinstance(flow, DaskFlows):
        result = flow
    else:
        if isinstance(flow, tuple | list) and len(flow) == 2:
            fwd, bwd, method = flow[0], flow[1], "precomputed"
        elif hasattr(flow, "forward") and hasattr(flow, "backward"):
            fwd, bwd = flow.forward, flow.backward
            method = getattr(flow, "method", "precomputed")
        else:
            raise TypeError(
                "flow must be a FlowConfig, a method name, DaskFlows, a SequenceFlow or a "
                f"(forward, backward) pair of (T-1, H, W, 2) arrays, got {type(flow).__name__}"
            )
        result = DaskFlows(
            as_dask_video(fwd, "flow.forward", ndim=4),
            as_dask_video(bwd, "flow.backward", ndim=4),
            method,
        )
    expected = (max(total - 1, 0), h, w, 2)
    for name, f in (("flow.forward", result.forward), ("flow.backward", result.backward)):
        if tuple(f.shape) != expected:
            raise ShapeError(name, expected, f.shape)
    return result


# ------------------------------------------------------------------------------------ stage 2
class _EnginePool:
    """The idle chunk engine of this process, handed from one fusion task to the next.

    A :class:`fuse4d.FusionEngine` allocates and writes its ring buffers (and, with composed
    tracks (A31), its track tables) when it is built: ≈ 0.3 GB at 600 x 600 and a window of 9,
    about 0.15-0.25 s of page faults on this machine, which a chunk of 16 frames paid again
    per task. A finished task gives its engine back; the next task with the same camera and
    parameters takes it and :meth:`fuse4d.FusionEngine.reset` starts it anew (bit for bit a
    new engine). At most one idle engine is kept (a process running several tasks at once
    builds the others), so a worker holds no more than the engine it was using anyway."""

    def __init__(self) -> None:
        self._idle: tuple[tuple[Intrinsics, FusionParams], FusionEngine] | None = None
        self._lock = threading.Lock()
        #: engines built and engines reused by this process's tasks so far (tests)
        self.built = 0
        self.reused = 0

    def take(self, intrinsics: Intrinsics, params: FusionParams) -> FusionEngine:
        with self._lock:
            idle, self._idle = self._idle, None
            if idle is not None and idle[0] == (intrinsics, params):
                self.reused += 1
                engine = idle[1]
                engine.reset()
                return engine
            self.built += 1
        return FusionEngine(intrinsics, fusion=params, warm_start=False)

    def give_back(self, intrinsics: Intrinsics, params: FusionParams, engine: FusionEngine) -> None:
        with self._lock:
            self._idle = ((intrinsics, params), engine)

    def clear(self) -> int:
        """Drop the idle engine (its memory goes back when nothing else holds it); returns
        the number of engines dropped (0 or 1)."""
        with self._lock:
            idle, self._idle = self._idle, None
        return int(idle is not None)


_ENGINES = _EnginePool()


def release_engines(client: Any = None) -> int:
    """Give back the memory of the idle chunk engines that fusion tasks keep between chunks.

    A process that ran a fusion task of :func:`fuse` or of ``fuse4d run --engine dask``
    keeps that task's :class:`fuse4d.FusionEngine` (≈ 0.3 GB at 600 x 600 and a window of 9)
    so that its next chunk need not build one. Call this when no more chunks will come: in
    this process (the threads and synchronous schedulers run the tasks here) and, given a
    ``distributed.Client``, in each of its workers. ``fuse4d run --engine dask`` calls it when
    its run ends; engines in use by running tasks are not touched.

    Parameters
    ----------
    client : distributed.Client, optional
        Also release the engines of this client's workers.

    Returns
    -------
    int
        Engines released (this process's and the workers').
    """
    released = _release_idle_engine()
    if client is not None:
        released += sum(client.run(_release_idle_engine).values())
    return released


def _release_idle_engine() -> int:
    """This process's :meth:`_EnginePool.clear` (a module function: a worker imports it)."""
    return _ENGINES.clear()


@contextmanager
def chunk_engine(
    intrinsics: Intrinsics,
    params: FusionParams,
    keep: tuple[int, int],
    frames: int,
    *,
    stream_start: bool = False,
) -> Iterator[FusionEngine]:
    """A streaming engine for one time chunk: ``frames`` pushed, the local frames
    ``keep = (a, b)`` emitted (the halo frames before ``a`` and from ``b`` on are sources
    only: not tracked, not fused, and no composed tracks (A31) built for them).

    ``stream_start``: the chunk emits the recording's frame 0 (and this is the first fusion
    pass), so the engine warns of dark intensity as a whole-stream engine does, with the same
    frame numbers (over the frames the chunk holds, look-ahead halo included, where they are
    fewer than the check takes); the other chunks do not check (every chunk warned, each
    numbering its own frames from 0).

    The engine comes from this process's :class:`_EnginePool` (reset) or is built; it goes
    back to the pool when the block ends without an exception."""
    a, b = keep
    engine = _ENGINES.take(intrinsics, params)
    engine.set_output_range(a, b if b < frames else None)
    engine._check_dark_intensity(stream_start)
    yield engine  # an exception leaves the engine to the garbage collector
    engine._end_dark_check()  # (a chunk of fewer frames than the check takes)
    _ENGINES.give_back(intrinsics, params, engine)


def _fuse_block(
    inputs: dict[str, list[NDArray[Any]] | None],
    intrinsics: Intrinsics,
    params: FusionParams,
    keep: tuple[int, int],
    at_end: bool,
    stream_start: bool = False,
) -> tuple[NDArray[np.float32], NDArray[np.uint8], NDArray[np.bool_]]:
    """One pass of the streaming engine over a chunk with its halo.

    ``inputs`` holds the time chunks of ``depth``/``intensity`` (and ``points``) covering the
    frames ``[lo, hi)`` and of ``forward``/``backward`` covering the pairs ``[lo, hi - 1)``;
    ``keep`` = the local ``[start, stop)`` returned; ``at_end`` = ``hi`` is the end of the
    sequence (flush: truncated windows); ``stream_start``: see :func:`chunk_engine`."""
    depth = list(_frames(inputs["depth"]))  # views into the blocks: no copy of the halo
    n = len(depth)
    h, w = depth[0].shape
    intensity = list(_frames(inputs["intensity"]))
    forward = list(_frames(inputs["forward"]))
    backward = list(_frames(inputs["backward"]))
    points = None if inputs["points"] is None else list(_frames(inputs["points"]))
    a, b = keep
    out_points = np.empty((b - a, h, w, 3), np.float32)
    support = np.empty((b - a, h, w), np.uint8)
    filled = np.empty((b - a, h, w), np.bool_)
    source = np.empty((b - a, h, w), np.uint8)
    confidence = np.empty((b - a, h, w), np.float32)

    def take(frames: list[Any]) -> None:
        for fr in frames:
            if a <= fr.index < b:
                out_points[fr.index - a] = fr.points
                support[fr.index - a] = fr.support
                filled[fr.index - a] = fr.filled
                source[fr.index - a] = fr.source
                confidence[fr.index - a] = fr.confidence

    with chunk_engine(intrinsics, params, keep, n, stream_start=stream_start) as engine:
        for j in range(n):
            pair = None if j == 0 else (forward[j - 1], backward[j - 1])
            take(
                engine.push(
                    depth[j],
                    intensity[j],
                    pair_flow=pair,
                    points=None if points is None else points[j],
                )
            )
        if at_end:
            take(engine.flush())
    return out_points, support, filled, source, confidence


def _depth_of(points: NDArray[np.float32]) -> NDArray[np.float32]:
    return np.ascontiguousarray(points[..., 2])


def fuse(
    depth: Any,
    intensity: Any,
    intrinsics: Intrinsics,
    *,
    fusion: FusionParams | None = None,
    flow: FlowConfig | str | DaskFlows | SequenceFlow | tuple | None = None,
    chunk_frames: int = 32,
    warm_start: bool = True,
    client: Any = None,
) -> DaskFusion:
    """4D fusion (paper Eq. 2-6) as a lazy dask graph, bit-identical to
    :func:`fuse4d.fuse_sequence` and to the streaming :class:`fuse4d.FusionEngine`.

    Parameters
    ----------
    depth : (T, H, W) numpy, dask or zarr array
        Depth in mm, NaN (or 0) = invalid.
    intensity : (T, H, W) numpy, dask or zarr array
        Registered intensity in [0, 1] (uint8/uint16 divided by 255/65535).
    intrinsics : Intrinsics
        Pinhole camera (px).
    fusion : FusionParams, optional
        Fusion knobs (default: METHOD §5.3); ``iterations`` > 1 chains one stage-2 pass per
        iteration, like ``fuse_sequence``.
    flow : FlowConfig, str, DaskFlows, SequenceFlow or (forward, backward), optional
        Tracker for stage 1 (default: the "fast" preset, DIS), or precomputed flows (numpy,
        dask or zarr ``(T-1, H, W, 2)`` px arrays, e.g. from :func:`flows`).
    chunk_frames : int
        Output frames per task (default 32). Each task also processes the halo: ``past``
        frames before and ``future`` after (``num_frames - 1`` before in causal mode).
    warm_start : bool
        Chain flow warm starts across pairs (the in-memory default; serial stage 1 per
        recording). False: independent chunks, bit-identical to the in-memory path with
        ``warm_start=False`` (see the module docstring).
    client : dask.distributed.Client, optional
        The caller's client. Numpy inputs are then scattered to its workers once instead of
        travelling inside the task graph, and its workers are checked for distributed's
        ``MALLOC_TRIM_THRESHOLD_`` (a warning: see :data:`fuse4d.scale.cluster.ALLOCATOR_ENV`).
        None: nothing is sent anywhere; compute with any scheduler (the threaded one by
        default, or the active client).

    Returns
    -------
    DaskFusion
        Lazy ``points``, ``depth``, ``support``, ``filled`` chunked by ``chunk_frames`` frames,
        and the ``flows`` used.

    Raises
    ------
    ShapeError
        If depth, intensity, intrinsics or flows disagree in shape.
    """
    check_intrinsics(intrinsics)
    params = fusion_params(fusion)
    if chunk_frames < 1:
        raise ParameterError(f"chunk_frames must be >= 1, got {chunk_frames}")
    if params.num_frames > 256:
        raise ParameterError("num_frames must be <= 256 (support is stored as uint8)")
    if client is not None:
        from .cluster import warn_if_slow_allocator

        warn_if_slow_allocator(client)
    keep: list[Any] = []
    d = as_dask_video(_scattered(depth, client, chunk_frames, keep), "depth", ndim=3)
    inten = as_dask_video(_scattered(intensity, client, chunk_frames, keep), "intensity", ndim=3)
    if inten.shape != d.shape:
        raise ShapeError("intensity", d.shape, inten.shape, "it must match depth frame for frame")
    total, h, w = d.shape
    if total < 1:
        raise ParameterError("fuse needs at least one frame, got T = 0")
    if (h, w) != (intrinsics.height, intrinsics.width):
        raise ShapeError(
            "depth", ("T", intrinsics.height, intrinsics.width), d.shape,
            "the intrinsics describe another image size",
        )  # fmt: skip
    if flow is None or isinstance(flow, FlowConfig | str):
        pair_flows = flows(inten, flow=flow, chunk_frames=chunk_frames, warm_start=warm_start)
    else:
        pair_flows = _as_dask_flows(flow, total, h, w)
    past, future = params.past_frames, params.future_frames
    points = None
    filled = None
    support = None
    source = confidence = None
    for iteration in range(params.iterations):
        pieces: list[tuple[da.Array, ...]] = []
        for s, e in chunk_bounds(total, chunk_frames):
            lo, hi = max(0, s - past), min(total, e + future)
            inputs = {
                "depth": delayed_blocks(d[lo:hi]),
                "intensity": delayed_blocks(inten[lo:hi]),
                "forward": delayed_blocks(pair_flows.forward[lo : max(lo, hi - 1)]),
                "backward": delayed_blocks(pair_flows.backward[lo : max(lo, hi - 1)]),
                "points": None if points is None else delayed_blocks(points[lo:hi]),
            }
            block = dask.delayed(_fuse_block, nout=5, pure=True)(
                inputs,
                intrinsics,
                params,
                (s - lo, e - lo),
                hi == total,
                s == 0 and iteration == 0,
            )
            n = e - s
            pieces.append(
                (
                    da.from_delayed(block[0], (n, h, w, 3), np.float32),
                    da.from_delayed(block[1], (n, h, w), np.uint8),
                    da.from_delayed(block[2], (n, h, w), np.bool_),
                    da.from_delayed(block[3], (n, h, w), np.uint8),
                    da.from_delayed(block[4], (n, h, w), np.float32),
                )
            )
        points = da.concatenate([p[0] for p in pieces])
        support = da.concatenate([p[1] for p in pieces])
        filled = da.concatenate([p[2] for p in pieces])  # the last pass's, as support
        source = da.concatenate([p[3] for p in pieces])  # the last pass's
        confidence = da.concatenate([p[4] for p in pieces])
    assert points is not None
    assert support is not None
    assert filled is not None
    depth_out = points.map_blocks(_depth_of, drop_axis=3, dtype=np.float32)
    return DaskFusion(
        points,
        depth_out,
        support,
        filled,
        pair_flows,
        chunk_frames,
        params,
        tuple(keep),
        source=source,
        confidence=confidence,
    )


def _scattered(x: Any, client: Any, chunk_frames: int, keep: list[Any]) -> Any:
    """Numpy inputs scattered to ``client``'s workers, one future per time chunk (appended to
    ``keep``: the graph alone does not keep the data on the cluster)."""
    if client is None or not isinstance(x, np.ndarray) or x.ndim < 1 or x.shape[0] == 0:
        return x
    bounds = chunk_bounds(x.shape[0], chunk_frames)
    futures = client.scatter([x[a:b] for a, b in bounds])
    keep.extend(futures)
    pieces = [
        da.from_delayed(f, (b - a, *x.shape[1:]), x.dtype)
        for f, (a, b) in zip(futures, bounds, strict=True)
    ]
    return da.concatenate(pieces)
