"""Spatio-temporal 4D fusion (paper Eq. 5) with hole filling (Eq. 6): streaming engine and
in-memory face.

The engine keeps a ring buffer of ``num_frames`` frames — raw depth, the intensity-guided 3D
bilateral ``B^T`` (computed once per frame, METHOD §5.1/§7) and the motion-reference points
``P~^T`` (A3) — plus the forward/backward flows of the pairs inside the window, each computed
once. Frame t is emitted as soon as frame t + h_future has arrived, so memory does not grow with
the sequence length. :func:`fuse_sequence` drives the same engine over in-memory arrays.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels._common import gauss_factor
from ._kernels._numba import kernel_threads
from ._kernels.camera import _valid_depth_kernel
from ._kernels.fov import _inside_extents_kernel, _valid_extents_kernel
from ._kernels.fusion import _fuse_kernel, _project_to_rays_kernel, _static_smoothing_kernel
from ._kernels.holes import _put_on_rays_kernel, _source_confidence_kernel
from ._kernels.noise import _finite_median32
from ._kernels.smooth_base import _smooth_base_cols_kernel, _smooth_base_rows_kernel
from ._memory import available_memory, committed
from ._validation import as_float32, check_shape
from .bilateral import _residual_bilateral, bilateral_filter_points
from .camera import Intrinsics, check_intrinsics, depth_to_points
from .config import FlowConfig, FusionParams, fusion_params, preset
from .errors import ParameterError, ParameterTypeError, ShapeError
from .flow import SequenceFlow, as_sequence_flow
from .flying_pixels import flying_pixel_mask, resolve_flying_pixels
from .holes import (
    SOURCE_FUSED,
    SOURCE_MEASURED,
    SOURCE_OUTSIDE,
    SOURCE_REJECTED,
    SOURCE_SPACE,
    SOURCE_TIME,
    _fill_from_time,
    _fill_holes,
    _fill_small_holes,
    _hole_sides,
    _side_consistent,
)
from .motion import (
    _box_radius,
    _ComposedTracks,
    _depth_noise,
    _pair_motion,
    _TimeFill,
    _track_window,
    _window,
    estimate_noise_quad,
    motion_reference_depth,
)
from .sequence import INTENSITY_REQUIRED, as_unit_intensity
from .static_tracks import STATIC_DEPTH_TOLERANCE, static_pixels

__all__ = [
    "FrameState",
    "FusedFrame",
    "FusionEngine",
    "FusionResult",
    "fuse_sequence",
    "fuse_stream",
]

#: "no fused points to check" for the source kernel (outputs without NaN: every fallback but
#: ``fill_fallback="nan"`` leaves a value at each pixel with depth)
_NO_POINTS = np.empty((0, 0, 3), np.float32)

#: ``FusionParams.base`` -> the fusion kernel's ``trajectory`` code
_BASE_CODES = {"frame": 0, "trajectory": 1, "quadratic": 2, "adaptive": 3}

#: significance level of the A32 curvature test (``base="adaptive"``): a pixel's trajectory is
#: a parabola where the line is rejected at this level (Bonferroni over the three coordinates:
#: each coordinate's F test at a third of it)
CURVATURE_TEST_LEVEL = 0.05
#: F(1, k) = t(k)^2 of A32's test at CURVATURE_TEST_LEVEL for k = 1..62 (windows of up to 64
#: frames): ``scipy.special.stdtrit(k, 1 - level / 6) ** 2`` (scipy 1.17), kept as numbers
#: because importing scipy.special took 0.23 s of every engine's start-up on a 2-core machine
#: (``fuse4d run``, ``live``); other levels and longer windows compute them, and
#: ``tests/test_fusion.py`` checks the table against scipy
# fmt: off
_F_CRITICAL = np.array([
    1458.358423480592, 58.50420168067247, 23.587119865139854, 15.687829562095,
    12.489938468539947, 10.807361409865731, 9.781583228143646, 9.094819456825068,
    8.6043902074351, 8.237316474746873, 7.952590069122161, 7.725470723524656,
    7.540179471418592, 7.386193106770218, 7.25623151978516, 7.145101604364696,
    7.04900154869571, 6.965085377850276, 6.891181055637244, 6.825602592647069,
    6.767021575663301, 6.714377327448648, 6.666812812338242, 6.623628084595241,
    6.584245929723801, 6.548186133428797, 6.515045955260815, 6.484485130830167,
    6.456214224189951, 6.4299854895355315, 6.405585633993121, 6.382830035973007,
    6.361558088924791, 6.341629423166792, 6.322920818644201, 6.3053236656755995,
    6.288741863550418, 6.2730900714153774, 6.258292244465671, 6.244280402618582,
    6.230993589729796, 6.218376989837229, 6.206381173485751, 6.194961452341814,
    6.1840773243792295, 6.17369199515349, 6.163771963268413, 6.15428666021704,
    6.145208136457544, 6.136510786947558, 6.128171110471751, 6.120167498007926,
    6.11248004612627, 6.105090392035158, 6.0979815674006534, 6.091137868494035,
    6.084544740579336, 6.078188674752257, 6.072057115694005, 6.066138379016555,
    6.06042157705596, 6.054896552123533,
])
# fmt: on
#: ... and where the parabola moves the pixel's base by more than this many times its depth
#: noise sigma(z) (A22): a significant but small curvature (a hand-held camera's jitter on a
#: static room) keeps the steadier line
CURVATURE_MIN_BIAS = 0.5


def curvature_f_critical(max_df: int, level: float = CURVATURE_TEST_LEVEL) -> NDArray[np.float64]:
    """Per-coordinate critical values of A32's curvature test, F(1, k) at ``level`` / 3 for
    k = 0..``max_df`` (entry 0 unused, inf). F(1, k) = t(k)^2, so the two-sided Student-t
    quantile gives it without importing ``scipy.stats``."""
    out = np.full(max(max_df, 1) + 1, np.inf)
    if level == CURVATURE_TEST_LEVEL and out.size - 1 <= _F_CRITICAL.size:
        out[1:] = _F_CRITICAL[: out.size - 1]
        return out
    from scipy.special import stdtrit

    k = np.arange(1, out.size)
    out[1:] = stdtrit(k, 1.0 - level / 6.0) ** 2
    return out


#: the engine's timed stages (``timings`` keys, seconds); ``motion_reference`` includes the
#: frame's noise model (A22: q, the median depth, sigma0)
STAGES = ("flow", "bilateral", "motion_reference", "tracking", "fusion", "fill")
#: seconds the flows took in the worker thread of ``overlap_flow`` (``timings`` key, present
#: only with it): spent beside the :data:`STAGES` (during ``bilateral`` and
#: ``motion_reference``), not in addition to them, so not part of a sum of the stages; the
#: ``flow`` stage is then the wait for the worker only
FLOW_WORKER = "flow_worker"


@dataclass
class FusedFrame:
    """One output frame of the engine.

    Attributes
    ----------
    index : int
        Frame index t.
    points : (H, W, 3) ndarray of float32
        Fused 3D points p^_i^t in mm (NaN where the raw depth was invalid).
    support : (H, W) ndarray of uint8
        Number of other frames fused into the pixel (Eq. 5): those whose track passed all
        checks; 0 where fewer than ``min_temporal_support`` did (the pixel keeps B^t).
    filled : (H, W) ndarray of bool
        Pixels without temporal support whose value comes from hole filling (Eq. 6).
    unfilled : (H, W) ndarray of bool
        Holes that hole filling could not reach (they hold the fallback value).
    source : (H, W) ndarray of uint8
        Where each value comes from: :data:`fuse4d.holes.SOURCE_NONE` (0, no depth),
        ``SOURCE_MEASURED`` (1, raw depth without temporal support), ``SOURCE_FUSED`` (2,
        fused with >= 1 tracked frame), ``SOURCE_TIME`` (3, a sensor hole filled from other
        frames, A26), ``SOURCE_SPACE`` (4, a small sensor hole filled in space, A27),
        ``SOURCE_REJECTED`` (5, raw depth removed as a ToF flying pixel, A36; no depth),
        ``SOURCE_OUTSIDE`` (6, no depth, outside the sensor's field of view, A38).
    confidence : (H, W) ndarray of float32
        Fraction of the n window frames that measured the value: (1 + support) / n for raw
        pixels, (tracked frames with depth) / n for time-filled holes, 0 for space-filled
        holes and pixels without depth.
    """

    index: int
    points: NDArray[np.float32]
    support: NDArray[np.uint8]
    filled: NDArray[np.bool_]
    unfilled: NDArray[np.bool_]
    source: NDArray[np.uint8] | None = None
    confidence: NDArray[np.float32] | None = None

    @property
    def depth(self) -> NDArray[np.float32]:
        """Fused depth (Z of the fused points) in mm."""
        return self.points[..., 2]


@dataclass(frozen=True)
class FrameState:
    """What :meth:`FusionEngine.push` derives from one frame alone (METHOD §7: computed once
    per frame): handed to another engine with the same camera and parameters, it replaces
    that work, with the same output bit for bit.

    Attributes
    ----------
    smooth : (H, W, 3) ndarray
        Local reference surface (A17, A18), back-projected, mm; NaN where the frame has no
        depth.
    reference : (H, W, 3) ndarray or None
        Motion reference P~ (A3) where it differs from ``smooth`` (``motion_sigma`` !=
        ``reference_sigma``); None where the engine uses ``smooth`` or the raw points.
    bilateral : (H, W, 3) ndarray
        Intensity-guided 3D bilateral B (Eq. 5's spatial term), mm.
    noise : (3,) ndarray
        Depth-noise model of the frame: sigma0 (mm), quad (1/mm) and the median depth (mm)
        (A22).
    """

    smooth: NDArray[np.float32]
    reference: NDArray[np.float32] | None
    bilateral: NDArray[np.float32]
    noise: NDArray[np.float64]


@dataclass
class _PairOutput:
    index: int  # pair (index, index + 1)
    forward: NDArray[np.float32]
    backward: NDArray[np.float32]
    motion: NDArray[np.float32]
    fb_error: NDArray[np.float32]


class FusionEngine:
    """Streaming 4D fusion over a ring buffer (METHOD §7).

    Push frames in order with :meth:`push`; each call returns the frames that became complete.
    Call :meth:`flush` at the end of the stream for the last ``h_future`` frames (truncated
    windows, A13), and :meth:`reset` to start another stream on the same buffers;
    :meth:`set_output_range` emits only part of a stream (a time chunk with its halo). In
    ``causal`` mode (``FusionParams(causal=True)``) every frame is emitted as soon as it is
    pushed, fused with the n - 1 previous frames only.

    Parameters
    ----------
    intrinsics : Intrinsics
        Camera (its size fixes the frame shape).
    fusion : FusionParams, optional
        Fusion knobs (defaults: METHOD §5.3). ``iterations`` > 1 is handled by
        :func:`fuse_sequence`, not by a single engine.
    flow : FlowConfig, str, SequenceFlow or (forward, backward), optional
        Tracker, its parameters, flow cache and flow ROI (default: the "fast" preset's: OpenCV
        DIS), driven through :class:`fuse4d.flow.SequenceFlowEstimator` (warm starts, cache,
        ROI); or precomputed flows of the whole stream (pair (t-1, t) is used when frame t is
        pushed). Ignored for pairs whose flows are passed to :meth:`push`.
    ring_size : int, optional
        Frames kept; at least ``num_frames`` (default). Larger values only cost memory.
    warm_start : bool
        Initialise each pair's flow with the previous pair's (methods that accept it).
    on_pair : callable, optional
        ``on_pair(pair)`` receives each pair's flows, 3D motion and FB error as computed.
    timings : dict, optional
        Accumulates seconds per stage (keys ``STAGES``; with ``overlap_flow`` also
        :data:`FLOW_WORKER`).
    initial_flow : (H, W, 2) ndarray, optional
        Resuming a stream: the forward flow of the pair just before the first pushed frame
        (see :meth:`forward_flow`), the warm start of the first pair, so that the frames
        emitted equal those of one uninterrupted run bit for bit.
    overlap_flow : bool
        Compute each pair's flow in a worker thread while :meth:`push` computes the new
        frame's motion reference and bilateral filter (OpenCV and the numba kernels release
        the GIL), instead of after them; while the worker runs, those kernels use one numba
        thread (the worker holds a core). The same flows and output bit for bit; the ``flow``
        timing is then only the wait for the worker, and ``timings["flow_worker"]``
        (:data:`FLOW_WORKER`) the seconds the flows took in the worker thread. ``fuse4d
        live``, :func:`fuse_sequence`, :func:`fuse_stream` and ``fuse4d run`` on a streamed
        recording with its I/O threads (``io_queue`` > 0, also ``fuse4d bench --input``) use
        it (on ``uva_cv2_person_turning``, centred 9, the engine alone in six alternating
        pairs: median 65.8 -> 61.0 ms a frame, stop 39); ``fuse4d bench`` on a synthetic
        scene does not: its flow stage is the flow's own time. Call :meth:`close` (or use the
        engine as a context manager) to stop the worker.

    Raises
    ------
    ParameterError
        If the engine's buffers, all allocated here (the composed tracks of a large window
        grow with its square), need more memory than is available to the process.
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        *,
        fusion: FusionParams | None = None,
        flow: FlowConfig | str | SequenceFlow | tuple | None = None,
        ring_size: int | None = None,
        warm_start: bool = True,
        on_pair: Callable[[_PairOutput], None] | None = None,
        timings: dict[str, float] | None = None,
        initial_flow: np.ndarray | None = None,
        overlap_flow: bool = False,
    ) -> None:
        self.intrinsics = check_intrinsics(intrinsics)
        self._initial_flow = (
            None if initial_flow is None else as_float32(initial_flow, name="initial_flow")
        )
        self.params = fusion_params(fusion)
        self.precomputed: SequenceFlow | None = None
        if isinstance(flow, str):
            flow = FlowConfig(flow)
        elif flow is not None and not isinstance(flow, FlowConfig):
            self.precomputed = as_sequence_flow(flow)
            flow = None
        self.flow_config = flow or preset("fast").flow
        if self.precomputed is None:  # an unknown method or key fails here, not at frame 1
            self.flow_config.build_params()
        self.warm_start = warm_start
        # the tracker (built on the first pair that needs it, so precomputed runs never load it)
        self._flow_estimator: Any = None
        self.on_pair = on_pair
        self.timings = timings if timings is not None else dict.fromkeys(STAGES, 0.0)
        for stage in STAGES:
            self.timings.setdefault(stage, 0.0)
        p = self.params
        self.past = p.past_frames
        self.future = p.future_frames
        if ring_size is not None and (
            isinstance(ring_size, bool) or not isinstance(ring_size, int | np.integer)
        ):
            raise ParameterTypeError(f"ring_size must be an integer, got {ring_size!r}")
        if ring_size is not None and ring_size < 0:
            raise ParameterError(f"ring_size must be >= 0 (0: the window), got {ring_size}")
        self.ring = max(ring_size or 0, p.num_frames)
        h, w = intrinsics.height, intrinsics.width
        if p.num_frames > 1 and min(h, w) < 2:  # the flow said "image0 must have shape ..."
            raise ShapeError(
                "depth frames",
                ("H >= 2", "W >= 2"),
                (h, w),
                "A frame 1 px wide or high has no optical flow; fuse a window of 1 frame "
                "(num_frames=1) or give larger frames",
            )
        s = self.ring
        # the buffers below are all allocated now: refuse a window whose buffers cannot fit
        # (the composed tracks grow with the square of the window) with a ParameterError
        # instead of a MemoryError or the system's OOM killer
        available = available_memory()
        _check_engine_memory(p, h, w, s, available)
        try:
            # every ring buffer is written now (committed), not during the first frames
            self._depth = committed((s, h, w), np.float32, np.nan)
            # A36: the flying pixels removed from each frame's raw depth (None: "off" / "auto")
            self._rejected = (
                committed((s, h, w), np.bool_, False) if p.flying_pixels == "on" else None
            )
            # A38: first and last valid pixel of each row / column of each frame (its part of the
            # sensor's field of view), computed once per frame
            self._row_extent = committed((s, h, 2), np.int32, 0)
            self._col_extent = committed((s, w, 2), np.int32, 0)
            # (x_n, y_n, 1) of every pixel: depth z on the pixel's ray is z * ray (filled holes)
            self._rays = depth_to_points(np.ones((h, w), np.float32), intrinsics)
            # per-frame depth-noise model sigma(z) = max(sigma0, quad z^2) (A22) and median
            # depth z_med (mm, for the gate and delta_d): (sigma0, quad, z_med)
            self._noise = np.zeros((s, 3), np.float64)
            self._input_quad = np.full(s, np.nan)  # q of each frame's depth as pushed
            self._intensity = committed((s, h, w), np.float32, 0.0)
            self._bilateral = committed((s, h, w, 3), np.float32, np.nan)
            # the residual bilateral's planar inputs, rebuilt every frame (_residual_bilateral)
            self._bilateral_scratch = (
                committed((2, 3, h, w), np.float32, 0.0) if p.bilateral == "residual" else None
            )
            # local reference surface (A17, A18) and motion reference P~ (A3)
            self._smooth = committed((s, h, w, 3), np.float32, np.nan)
            # with motion_sigma == reference_sigma (the default) D~ and the local reference are the
            # same surface: one buffer, computed once per frame
            self._shared_reference = p.motion_depth == "smoothed" and (
                p.motion_sigma == p.reference_sigma
            )
            self._reference = (
                self._smooth
                if self._shared_reference
                else committed((s, h, w, 3), np.float32, np.nan)
            )
            self._fwd = committed((s, h, w, 2), np.float32, 0.0)
            self._bwd = committed((s, h, w, 2), np.float32, 0.0)
            # the tracks of the frame being emitted (landing row, column, validity per other
            # frame of the window): one set of buffers, refilled for every output frame
            k = self.past + self.future
            # A31: tracks composed as the pairs arrive (None: each output frame chains its own)
            composed = p.tracks == "composed" and p.quantize == "final" and k > 0
            self._composed = _ComposedTracks(h, w, self.past, self.future) if composed else None
            kt = 0 if composed else k
            self._tracks = (
                committed((kt, h, w), np.int32, 0),
                committed((kt, h, w), np.int32, 0),
                committed((kt, h, w), np.bool_, False),
            )
            # the holes that the tracking pass fills from time (A26, :meth:`_time_fill`) and its
            # output, refilled for every output frame; not with quantize="per_step" (the fill's
            # chains take bilinear flow samples where those tracks round every step)
            chained_fill = p.fill_from_time and not composed and k > 0 and p.quantize == "final"
            hf, wf = (h, w) if chained_fill else (0, 0)
            self._fill_target = committed((hf, wf), np.bool_, False)
            self._fill_samples = (
                committed((hf, wf, 3), np.float32, np.nan),
                committed((hf, wf), np.uint8, 0),
            )
        except MemoryError as exc:  # the estimate fit, the allocation did not
            raise ParameterError(
                _engine_memory_message(p, h, w, s, available, failed=True)
            ) from exc
        tw = np.arange(max(self.past, self.future) + 1, dtype=np.float64)
        # sigma_temporal = inf: factor 0, equal weights
        self._temporal_weight = np.exp(-(tw**2) * gauss_factor(p.sigma_temporal))
        # A32's F test: samples in a window = past + future + 1, parameters 3
        self._f_critical = (
            curvature_f_critical(self.past + self.future - 2)
            if p.base == "adaptive"
            else np.full(2, np.inf)
        )
        self._no_static = np.zeros((h, w), np.bool_)  # A33 off, or a window of one frame
        self._dark = _DarkIntensityCheck()  # warns once if the stream's first frames are dark
        self._pushed = 0  # frames received
        self._emitted = 0  # frames emitted
        # frames from this one on are never emitted (set_output_range; None: all are): their
        # composed tracks (A31) are not built
        self._emit_stop: int | None = None
        self._closed = False
        # overlap_flow: one worker thread, created on the first pair
        self.overlap_flow = bool(overlap_flow)
        if self.overlap_flow:
            self.timings.setdefault(FLOW_WORKER, 0.0)
        self._flow_worker: Any = None
        self._pending_flow: Any = None
        self._flow_state: Any = None
        # (index, P^index) of the last pushed frame, reused by its emit (causal mode)
        self._last_points: tuple[int, NDArray[np.float32]] | None = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the flow worker thread of ``overlap_flow`` (nothing else; idempotent)."""
        worker, self._flow_worker = self._flow_worker, None
        if worker is not None:
            worker.shutdown(wait=True)

    def reset(self, *, initial_flow: np.ndarray | None = None) -> None:
        """Start a new stream with the same camera and parameters, keeping the buffers.

        What a new engine would do from here on, bit for bit (frame indices, windows and the
        tracker's warm start begin again), without allocating and writing its ring buffers
        again (about 45 MB at 640x480 and a window of 3; ``fuse4d live`` restarts at every
        gap). Also undoes :meth:`flush`. ``initial_flow``: as in the constructor.
        """
        # (no flow is pending between pushes: a push collects its pair's flow or drops it)
        self._flow_estimator = None
        self._initial_flow = (
            None if initial_flow is None else as_float32(initial_flow, name="initial_flow")
        )
        self._pushed = 0
        self._emitted = 0
        self._emit_stop = None
        self._closed = False
        self._last_points = None

    def _check_dark_intensity(self, on: bool) -> None:
        """Check this stream's first frames for dark intensity (a new check) or not at all.

        The dask chunk engines check only in the chunk that starts the recording (each chunk
        would warn, numbering its own frames from 0); a whole-stream engine checks once."""
        self._dark = _DarkIntensityCheck()
        self._dark.done = not on

    def _end_dark_check(self) -> None:
        """Warn now if every frame pushed so far was dark (a chunk shorter than
        :data:`DARK_CHECK_FRAMES` frames ends before the check would)."""
        self._dark.finish()

    def set_output_range(self, first: int = 0, stop: int | None = None) -> None:
        """Emit only the frames ``first <= t < stop`` of this stream (None: to its end).

        The other frames are sources only: they are pushed as usual (their depth, intensity
        and flows feed the windows of the emitted frames) but never fused, never returned by
        :meth:`push` or :meth:`flush`, and the composed tracks (A31) that only they would use
        are not built. The emitted frames are those of an engine that emits every frame, bit
        for bit. A time chunk of a longer recording with its halo (the dask graphs,
        :func:`fuse4d.scale.graph.chunk_engine`) is pushed this way. Call before the first
        :meth:`push` (after :meth:`reset` for a new stream, which emits every frame again).

        Raises
        ------
        RuntimeError
            Frames were already pushed to this stream.
        ValueError
            ``first`` < 0 or ``stop`` <= ``first``.
        """
        if self._pushed:
            raise RuntimeError(
                f"set_output_range must come before the first push ({self._pushed} frames "
                "pushed); call reset() to start a new stream"
            )
        for name, value in (("first", first), ("stop", stop)):
            if value is not None and (
                isinstance(value, bool) or not isinstance(value, int | np.integer)
            ):
                raise ParameterTypeError(f"output range: {name} must be an integer, got {value!r}")
        if first < 0 or (stop is not None and stop <= first):
            raise ParameterError(f"output range needs 0 <= first < stop, got [{first}, {stop})")
        self._emitted = int(first)
        self._emit_stop = None if stop is None else int(stop)

    def _emit_end(self) -> int:
        """Frames before this index may be emitted (pushed ones, within the output range)."""
        return self._pushed if self._emit_stop is None else min(self._pushed, self._emit_stop)

    # ------------------------------------------------------------------ public
    @property
    def latency(self) -> int:
        """Frames of look-ahead: frame t is emitted after frame t + latency arrives."""
        return self.future

    def push(
        self,
        depth: ArrayLike,
        intensity: ArrayLike,
        *,
        points: ArrayLike | None = None,
        pair_flow: tuple[np.ndarray, np.ndarray] | None = None,
        state: FrameState | None = None,
    ) -> list[FusedFrame]:
        """Add the next frame; return the frames completed by it (oldest first).

        Parameters
        ----------
        depth : (H, W) ndarray
            Depth in mm, NaN (or 0) = invalid.
        intensity : (H, W) ndarray
            Registered intensity, [0, 1] (uint8/uint16 divided by 255/65535).
        points : (H, W, 3) ndarray, optional
            Use these 3D points (mm) instead of back-projecting ``depth`` (fusion iterations).
        pair_flow : (forward, backward), optional
            Flows of the pair (previous frame, this frame), each (H, W, 2) px; computed with the
            engine's tracker when omitted.
        state : FrameState, optional
            This frame's :meth:`frame_state` from an engine with the same camera and
            parameters (the frame pushed there with the same depth and intensity, no
            ``points``): stored instead of computed. The dask graph passes the frames that
            two neighbouring chunks both push (the halo) this way.
        """
        if self._closed:
            raise RuntimeError(
                "engine was flushed; call reset() to start a new stream (or create a new "
                "FusionEngine)"
            )
        if intensity is None:
            raise ParameterTypeError(INTENSITY_REQUIRED)
        if pair_flow is not None and not (
            isinstance(pair_flow, tuple | list) and len(pair_flow) == 2
        ):
            raise ParameterTypeError(
                "pair_flow must be a (forward, backward) pair of (H, W, 2) px arrays, got "
                + (f"an array of shape {np.shape(pair_flow)}" if hasattr(pair_flow, "shape")
                   else type(pair_flow).__name__)
            )  # fmt: skip
        h, w = self.intrinsics.height, self.intrinsics.width
        index = self._pushed
        d = as_float32(depth, name="depth")
        check_shape(d, (h, w), name=f"depth (frame {index})")
        valid = np.empty((h, w), np.float32)  # (the caller's array is not written to)
        _valid_depth_kernel(d, valid)  # NaN = invalid
        d = valid
        if index == 0:
            _warn_if_not_millimetres(d)
        slot = index % self.ring
        input_quad = math.nan  # q of the depth as pushed (input_noise_quad)
        if self._rejected is not None:  # A36, before anything sees the depth
            t0 = time.perf_counter()
            input_quad = estimate_noise_quad(d)
            rejected = flying_pixel_mask(d, self.intrinsics, quad=input_quad)
            d[rejected] = np.nan
            self._rejected[slot] = rejected
            self.timings["motion_reference"] += time.perf_counter() - t0
        inten = np.asarray(intensity)
        check_shape(inten, (h, w), name=f"intensity (frame {index})")
        inten = as_unit_intensity(inten, name=f"intensity (frame {index})")
        self._dark.add(inten)
        if state is not None:
            if points is not None:
                raise ParameterError("push takes points or a frame state, not both")
            _check_state(state, (h, w), index, separate=self._separate_reference)
        needs_pair = index > 0 and (self.past + self.future > 0 or pair_flow is not None)
        if needs_pair and pair_flow is None and self.overlap_flow and self.precomputed is None:
            self._start_flow(index, inten)
        try:
            self._prepare(index, slot, d, inten, points, needs_pair, pair_flow, state)
        except BaseException:
            self._drop_pending_flow()
            raise
        if self._rejected is None:  # the noise model's q is the input depth's
            input_quad = self._noise[slot, 1]
        self._input_quad[slot] = math.nan if points is not None else input_quad
        self._pushed += 1
        out = []
        while self._emitted + self.future < self._pushed and self._emitted < self._emit_end():
            out.append(self._emit(self._emitted))
        return out

    def _drop_pending_flow(self) -> None:
        """A push failed: wait for the flow the worker is computing, discard it and put the
        tracker's warm-start state back, so that a retried push computes what a serial
        engine would."""
        pending, self._pending_flow = self._pending_flow, None
        if pending is None:
            return
        pending.exception()  # waits; the push's own error is the one raised
        if self._flow_state is None:
            self._flow_estimator = None  # built (and primed) again by the next pair
        else:
            self._flow_estimator._last_image1, self._flow_estimator._last_forward = self._flow_state

    def _prepare(self, index, slot, d, inten, points, needs_pair, pair_flow, state) -> None:
        """The per-frame part of :meth:`push`: noise model, references, bilateral, pair."""
        if state is None:
            d = self._derive(index, slot, d, inten, points)
        else:
            self._last_points = (index, depth_to_points(d, self.intrinsics))
            self._smooth[slot] = state.smooth
            if self.params.motion_depth == "raw":
                self._reference[slot] = self._last_points[1]
            elif state.reference is not None:
                self._reference[slot] = state.reference
            self._bilateral[slot] = state.bilateral
            self._noise[slot] = state.noise
        self._depth[slot] = d
        _valid_extents_kernel(d, self._row_extent[slot], self._col_extent[slot])  # A38
        self._intensity[slot] = inten
        # a window of one frame uses no pair: no flows, no tracks (issue 13); flows that are
        # passed in are still stored (and reported through ``on_pair``)
        if needs_pair:
            self._add_pair(index, pair_flow)

    def _derive(self, index, slot, d, inten, points) -> NDArray[np.float32]:
        """Frame ``index``'s :class:`FrameState`, computed into its ring slot; returns the
        frame's depth (the z of ``points`` where given)."""
        h, w = self.intrinsics.height, self.intrinsics.width
        p = self.params
        t0 = time.perf_counter()
        if points is None:
            pts = depth_to_points(d, self.intrinsics)
            self._last_points = (index, pts)  # = depth_to_points(self._depth[slot]), kept
        else:
            self._last_points = None
            pts = as_float32(points, name="points")
            check_shape(pts, (h, w, 3), name=f"points (frame {index})")
            # a later iteration fuses the previous output where the sensor measured depth:
            # its filled holes go back to holes, so that the hole fills, the field of view
            # and the source codes describe the recording's own holes, as in iteration 1
            # (and where the previous pass output none, fill_fallback="nan", the sensor's own
            # point: the pass sees exactly the recording's valid pixels)
            sensor_hole = np.isnan(d)
            lost = np.isnan(pts[..., 2])
            lost &= ~sensor_hole
            if sensor_hole.any() or lost.any():
                pts = pts.copy() if np.may_share_memory(pts, points) else pts
                pts[sensor_hole] = np.nan
                if lost.any():
                    pts[lost] = depth_to_points(d, self.intrinsics)[lost]
            d = np.ascontiguousarray(pts[..., 2])
        quad = estimate_noise_quad(d)  # depth-noise model, part 1 (A22)
        z_med = _finite_median32(d)  # np.median of the valid depth, bit for bit (issue 13)
        if math.isnan(z_med):
            z_med = 0.0
        # local reference (A18) for the residual bilateral and the output normals (A17)
        with kernel_threads(self._threads_beside_flow()):
            self._smooth[slot] = self._smoothed_points(
                d, pts, points is not None, p.reference_sigma, quad
            )
            if p.motion_depth == "raw":
                self._reference[slot] = pts  # literal Eq. 3 (ablation)
            elif not self._shared_reference:  # motion reference P~ (A3) with its own sigma_m
                self._reference[slot] = self._smoothed_points(
                    d, pts, points is not None, p.motion_sigma, quad
                )
        smooth = self._smooth[slot]
        t1 = time.perf_counter()
        sigma_distance = self._frame_sigma_distance(z_med, quad)
        with kernel_threads(self._threads_beside_flow()):
            if p.bilateral == "residual":
                _residual_bilateral(
                    pts,
                    inten,
                    smooth,
                    p.spatial_radius,
                    sigma_distance,
                    p.sigma_intensity,
                    scratch=self._bilateral_scratch,
                    out=self._bilateral[slot],
                )
            else:
                bilateral_filter_points(
                    pts,
                    inten,
                    radius=p.spatial_radius,
                    sigma_distance=sigma_distance,
                    sigma_intensity=p.sigma_intensity,
                    out=self._bilateral[slot],
                )
        t2 = time.perf_counter()
        sigma0 = _depth_noise(d, self._smooth[slot], 2)  # estimate_depth_noise, ref. z~
        self._noise[slot] = (sigma0, quad, z_med)
        # the noise model (quad, z_med, sigma0) is timed with the motion reference
        self.timings["motion_reference"] += t1 - t0 + time.perf_counter() - t2
        self.timings["bilateral"] += t2 - t1
        return d

    def _threads_beside_flow(self) -> int | None:
        """1 while this frame's flows are still being computed by the flow worker
        (``overlap_flow``), else None (numba's own count). The worker holds one core; numba
        splits a kernel's rows into equal halves per thread up front (OpenMP's static
        schedule), so a kernel on two threads waited for the half whose thread shared that
        core. One thread beside the flow was 0.6-4 ms per 640x480 frame faster (issue 13)."""
        pending = self._pending_flow
        return 1 if pending is not None and not pending.done() else None

    @property
    def _separate_reference(self) -> bool:
        """Whether the motion reference is a surface of its own (in :class:`FrameState`)."""
        return self.params.motion_depth != "raw" and not self._shared_reference

    def frame_state(self, index: int) -> FrameState:
        """A copy of frame ``index``'s :class:`FrameState` while it is in the ring buffer
        (pass it to :meth:`push` of another engine that pushes the same frame)."""
        if not max(0, self._pushed - self.ring) <= index < self._pushed:
            raise IndexError(f"frame {index} is not in the ring buffer")
        slot = index % self.ring
        return FrameState(
            self._smooth[slot].copy(),
            self._reference[slot].copy() if self._separate_reference else None,
            self._bilateral[slot].copy(),
            self._noise[slot].copy(),
        )

    def forward_flow(self, index: int) -> NDArray[np.float32]:
        """Forward flow of the pair (``index`` - 1, ``index``) while it is in the ring buffer
        (a resume checkpoint: pass it as ``initial_flow`` to an engine starting at ``index``).
        """
        if not max(1, self._pushed - self.ring) <= index < self._pushed:
            raise IndexError(f"pair ({index - 1}, {index}) is not in the ring buffer")
        return self._fwd[index % self.ring].copy()

    def input_noise_quad(self, index: int) -> float | None:
        """The depth-noise coefficient q (1/mm, A22, :func:`~fuse4d.motion.estimate_noise_quad`)
        of frame ``index``'s depth as pushed, while the frame is in the ring buffer: the
        noise model's q, or with A36 the q that found the flying pixels (the noise model's is
        estimated again without them). None for a frame pushed as ``points``. ``fuse4d run``'s
        summary scores the raw depth with it instead of estimating it again (issue 13).
        """
        if not max(0, self._pushed - self.ring) <= index < self._pushed:
            raise IndexError(f"frame {index} is not in the ring buffer")
        quad = float(self._input_quad[index % self.ring])
        return None if math.isnan(quad) else quad

    def input_noise_sigma(self, index: int) -> float | None:
        """The depth noise σ₀ (mm, A22) of frame ``index``'s depth, while the frame is in the
        ring buffer; None for a frame pushed as ``points``. It is
        :func:`~fuse4d.motion.estimate_depth_noise`'s trimmed residual against the engine's
        quad-aware reference z~ (not the default sigma-2 reference: on quantised depth that
        one stops at every step and reads far less, 0.19 against 5.3 mm on
        ``uva_cv2_person_turning``), the σ₀ of the fusion's own noise model.
        """
        if not max(0, self._pushed - self.ring) <= index < self._pushed:
            raise IndexError(f"frame {index} is not in the ring buffer")
        slot = index % self.ring
        return None if math.isnan(self._input_quad[slot]) else float(self._noise[slot, 0])

    def flush(self) -> list[FusedFrame]:
        """End of stream: emit the remaining frames with truncated windows."""
        self._dark.finish()  # a stream shorter than DARK_CHECK_FRAMES
        out = []
        while self._emitted < self._emit_end():
            out.append(self._emit(self._emitted))
        self._closed = True
        return out

    # ------------------------------------------------------------------ internals
    def _smoothed_points(self, depth, points, given: bool, sigma: float, quad: float):
        """Back-projected edge-limited smoothing of ``depth`` (see motion_reference_depth)."""
        smooth_depth = motion_reference_depth(
            depth, sigma=sigma, max_step=self.params.max_depth_step, noise_quad=quad
        )
        if not given:
            return depth_to_points(smooth_depth, self.intrinsics)
        # keep the lateral position of given points (fusion iterations)
        return points * np.where(np.isfinite(depth), smooth_depth / depth, np.nan)[..., None]

    def _start_flow(self, index: int, intensity: NDArray[np.float32]) -> None:
        """Submit the flow of the pair (index-1, index) to the worker (``overlap_flow``); the
        previous frame's intensity stays in its ring slot until :meth:`_add_pair` collects it,
        ``intensity`` (frame index) is not written to by :meth:`push`."""
        if self._flow_worker is None:
            from concurrent.futures import ThreadPoolExecutor

            self._flow_worker = ThreadPoolExecutor(1, thread_name_prefix="fuse4d-flow")
        est = self._flow_estimator  # its warm-start state, restored if the push fails
        self._flow_state = None if est is None else (est._last_image1, est._last_forward)
        self._pending_flow = self._flow_worker.submit(self._timed_flow_pair, index, intensity)

    def _timed_flow_pair(
        self, index: int, intensity: NDArray[np.float32]
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """:meth:`_flow_pair` in the worker thread, with the seconds it took (added to
        ``timings["flow_worker"]`` by :meth:`_add_pair`, in the pushing thread)."""
        t0 = time.perf_counter()
        fwd, bwd = self._flow_pair(index, intensity)
        return fwd, bwd, time.perf_counter() - t0

    def _flow_pair(
        self, index: int, intensity: NDArray[np.float32] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Flows of the pair (index-1, index): precomputed, or from the tracker (frame index's
        intensity from its ring slot unless given)."""
        if self.precomputed is not None:
            if index - 1 >= self.precomputed.num_pairs:
                raise ParameterError(
                    f"precomputed flows cover {self.precomputed.num_pairs} pairs; frame {index} "
                    "needs one more"
                )
            return self.precomputed.forward[index - 1], self.precomputed.backward[index - 1]
        prev = (index - 1) % self.ring
        if self._flow_estimator is None:
            self._flow_estimator = self.flow_config.estimator(warm_start=self.warm_start)
            if self._initial_flow is not None and index == 1:  # resuming: the pair before
                self._flow_estimator.prime(self._intensity[prev], self._initial_flow)
        current = self._intensity[index % self.ring] if intensity is None else intensity
        return self._flow_estimator(self._intensity[prev], current)

    def _raw_points(self, t: int) -> NDArray[np.float32]:
        """P^t: frame t's back-projected raw depth (the last pushed frame's from
        :meth:`_prepare`, as in causal mode, instead of projecting it again)."""
        last = self._last_points
        if last is not None and last[0] == t:
            return last[1]
        return depth_to_points(self._depth[t % self.ring], self.intrinsics)

    def _frame_sigma_distance(self, z_med: float, quad: float) -> float:
        """delta_d (mm) of a frame with median depth ``z_med`` (mm) and noise coefficient
        ``quad``: max(sigma_distance, scale * q * z_med^2) (A25)."""
        p = self.params
        return max(p.sigma_distance, p.distance_noise_scale * quad * z_med * z_med)

    def _add_pair(self, index: int, pair_flow) -> None:
        """Flows, FB error and one-step motion of the pair (index-1, index)."""
        h, w = self.intrinsics.height, self.intrinsics.width
        slot = index % self.ring
        prev = (index - 1) % self.ring
        t0 = time.perf_counter()
        if pair_flow is not None:
            fwd, bwd = pair_flow
        elif self._pending_flow is not None:  # overlap_flow: computed during the prep
            pending, self._pending_flow = self._pending_flow, None
            fwd, bwd, worker_s = pending.result()
            self.timings[FLOW_WORKER] += worker_s
        else:
            fwd, bwd = self._flow_pair(index)
        fwd = as_float32(fwd, name="forward flow")
        bwd = as_float32(bwd, name="backward flow")
        for name, f in (("forward flow", fwd), ("backward flow", bwd)):
            if f.shape != (h, w, 2):
                raise ShapeError(f"{name} (pair {index - 1}->{index})", (h, w, 2), f.shape)
        self._fwd[slot] = fwd
        self._bwd[slot] = bwd
        t1 = time.perf_counter()
        self.timings["flow"] += t1 - t0
        if self._composed is not None:
            p = self.params
            self._composed.add_frame(
                index,
                self._fwd,
                self._bwd,
                self._depth,
                self._noise[:, 1],
                fb_threshold=p.fb_threshold,
                max_step=p.max_depth_step,
                first_output=self._emitted,
                stop_output=self._emit_stop,
            )
            self.timings["tracking"] += time.perf_counter() - t1
        if self.on_pair is not None:
            p = self.params
            motion, fb = _pair_motion(
                self._fwd,
                self._bwd,
                self._reference,
                self._depth,
                index - 1,
                fb_threshold=p.fb_threshold,
                max_step=p.max_depth_step,
                quad=self._noise[prev, 1],
                per_step=p.quantize == "per_step",
            )
            self.on_pair(
                _PairOutput(index - 1, self._fwd[slot].copy(), self._bwd[slot].copy(), motion, fb)
            )

    def _emit(self, t: int) -> FusedFrame:
        p = self.params
        h, w = self.intrinsics.height, self.intrinsics.width
        first, last = _window(t, self.past, self.future, self._pushed)
        t0 = time.perf_counter()
        sigma0, quad, z_med = self._noise[t % self.ring]
        frame_slot = np.arange(first, last + 1, dtype=np.int64) % self.ring
        # A38: nothing is filled outside the field of view that the window's frames show
        inside = np.empty((h, w), np.bool_)
        _inside_extents_kernel(self._row_extent, self._col_extent, frame_slot, inside)
        time_fill = self._time_fill(t, first, last, inside)
        if self._composed is not None:  # A31: built as the pairs arrived
            rows, cols, ok = self._composed.window(t, first, last)
        else:
            frame_slot, rows, cols, ok = _track_window(
                self._fwd,
                self._bwd,
                self._depth,
                t,
                first,
                last,
                fb_threshold=p.fb_threshold,
                max_step=p.max_depth_step,
                quad=quad,
                per_step=p.quantize == "per_step",
                out=self._tracks,
                fill=time_fill,
            )
        if p.static_tracks and last > first:  # A33: static pixels keep still
            static = static_pixels(
                self._reference,
                self._intensity,
                self._depth[t % self.ring],
                frame_slot,
                t,
                first,
                (rows, cols, ok),
                quad,
            )
        else:
            static = self._no_static
        t1 = time.perf_counter()
        points = np.empty((h, w, 3), np.float32)
        support = np.empty((h, w), np.uint8)
        hole = np.empty((h, w), np.bool_)
        base = np.empty((h, w, 3), np.float32)
        frame_gate = max(p.temporal_gate * max(sigma0, quad * z_med**2), p.min_gate_mm)
        _fuse_kernel(
            self._bilateral,
            self._reference,
            frame_slot,
            t,
            first,
            rows,
            cols,
            ok,
            self._temporal_weight,
            p.min_temporal_support,
            p.temporal_gate,
            sigma0,
            quad,
            p.min_gate_mm,
            _BASE_CODES[p.base],
            self._f_critical,
            CURVATURE_MIN_BIAS,
            static,
            STATIC_DEPTH_TOLERANCE * quad,
            points,
            support,
            hole,
            base,
        )
        if p.min_temporal_support > 1:  # below the minimum: not fused (B^t), support 0
            support[hole] = 0
        if p.base_smoothing > 0 and p.base != "frame":
            _smooth_base(
                points,
                base,
                self._depth[t % self.ring],
                hole,
                sigma=p.base_smoothing,
                max_step=p.max_depth_step,
                quad=quad,
                limit_quad=p.base_fine_limit * quad,
            )
        t2 = time.perf_counter()
        if p.fill_holes and hole.any():
            filled = _fill_holes(
                points,
                self._raw_points(t),
                hole,
                radius=p.fill_radius,
                sigma=p.sigma_fill,
                passes=p.fill_passes,
                min_neighbours=3,
                gate=frame_gate,
            )
        else:
            filled = np.zeros((h, w), np.bool_)
        if p.fill_fallback == "nan":
            points[hole] = np.nan
        if p.output == "ray":
            k = self.intrinsics
            on_ray = np.empty_like(points)
            _project_to_rays_kernel(
                points,
                self._smooth[t % self.ring],
                k.fx,
                k.fy,
                k.cx,
                k.cy,
                p.max_depth_step,
                quad,
                on_ray,
            )
            points = on_ray
        smoothing_s = 0.0
        if p.static_smoothing > 0 and static is not self._no_static:  # A42
            t_s = time.perf_counter()
            smooth_z = motion_reference_depth(
                points[..., 2], sigma=p.static_smoothing, max_step=p.max_depth_step, noise_quad=quad
            )
            _static_smoothing_kernel(points, smooth_z, static, p.static_smoothing_limit * quad)
            smoothing_s = time.perf_counter() - t_s
        source, confidence = self._fill_sensor_holes(
            t, first, last, frame_slot, points, support, inside, time_fill
        )
        t3 = time.perf_counter()
        self.timings["tracking"] += t1 - t0
        self.timings["fusion"] += t2 - t1 + smoothing_s
        self.timings["fill"] += t3 - t2 - smoothing_s
        self._emitted += 1
        return FusedFrame(
            index=t,
            points=points,
            support=support,
            filled=filled,
            unfilled=hole,
            source=source,
            confidence=confidence,
        )

    def _time_fill(self, t, first, last, inside) -> _TimeFill | None:
        """The A26 fill of frame t's holes that the tracking pass does beside the tracks
        (None: no fill from time; or composed tracks, whose window chains no pixel, or
        ``quantize="per_step"``, whose tracks round every step where the fill's chains do
        not: then :meth:`_fill_sensor_holes` runs the separate kernel). The targets are the
        holes inside the field of view (``inside``) that are not flying pixels (A36)."""
        if self._fill_target.size == 0 or last == first:
            return None
        slot = t % self.ring
        target = self._fill_target
        np.isnan(self._depth[slot], out=target)
        target &= inside
        if self._rejected is not None:
            target &= ~self._rejected[slot]
        return _TimeFill(target, self._reference, self._temporal_weight, 1, *self._fill_samples)

    def _fill_sensor_holes(self, t, first, last, frame_slot, points, support, inside, time_fill):
        """Fill frame t's sensor holes in place (A26 from time, then A27 in space); returns
        the per-pixel source codes and confidence (see :class:`FusedFrame`). ``inside``: the
        window's field of view (A38); ``time_fill``: the A26 fill done by the tracking pass
        (None: computed here)."""
        p = self.params
        n = float(p.num_frames)
        slot = t % self.ring
        # SOURCE_NONE / SOURCE_MEASURED / SOURCE_FUSED and (1 + support) / n in one pass
        shape = support.shape
        source = np.empty(shape, np.uint8)
        confidence = np.empty(shape, np.float32)
        holes = np.empty(shape, np.bool_)
        if not _source_confidence_kernel(
            self._depth[slot],
            points if p.fill_fallback == "nan" else _NO_POINTS,  # else no output NaN there
            support,
            n,
            source,
            confidence,
            holes,
        ):
            return source, confidence
        source[~inside] = SOURCE_OUTSIDE
        rejected = None if self._rejected is None else self._rejected[slot]
        if rejected is not None and rejected.any():  # A36: kept empty
            source[rejected] = SOURCE_REJECTED
            holes &= ~rejected
        fill_time = p.fill_from_time and last > first
        if not (fill_time or p.fill_max_hole_px > 0):  # both sensor-hole fills off
            return source, confidence
        _, quad, _ = self._noise[slot]
        sides = _hole_sides(
            self._depth[slot], focal_px=self.intrinsics.fx, max_step=p.max_depth_step, quad=quad
        )
        sensor_holes = holes.copy() if fill_time and p.fill_max_hole_px > 0 else None
        if fill_time:
            if time_fill is not None:  # chained by the tracking pass (its targets: these holes)
                targets = time_fill.target
                filled_points, count = time_fill.points, time_fill.count
            else:
                targets = holes & inside
                filled_points, count = _fill_from_time(
                    self._fwd,
                    self._bwd,
                    self._depth,
                    self._reference,
                    frame_slot,
                    t,
                    first,
                    last,
                    targets,
                    fb_threshold=p.fb_threshold,
                    max_step=p.max_depth_step,
                    quad=quad,
                    temporal_weight=self._temporal_weight,
                )
            # the side check only for the holes the time fill reached (exact: the kernel's
            # value at a pixel does not depend on the other targets); most sensor holes of a
            # real recording (glass, range, shadows of static objects) are never reached
            reached = count > 0
            reached &= targets
            got = _side_consistent(
                filled_points[..., 2],
                self._depth[slot],
                self._intensity[slot],
                reached,
                sides,
                radius=p.fill_space_radius,
                sigma_intensity=p.sigma_intensity,
                max_step=p.max_depth_step,
                quad=quad,
            )
            if got.any():
                if p.output == "ray":  # the trajectory's depth on the pixel's own ray
                    _put_on_rays_kernel(
                        got, filled_points[..., 2], self._rays, points, source, SOURCE_TIME
                    )
                else:
                    points[got] = filled_points[got]
                    source[got] = SOURCE_TIME
                confidence[got] = count[got] / n
                holes &= ~got
        if p.fill_max_hole_px > 0 and holes.any():
            depth, got = _fill_small_holes(
                np.ascontiguousarray(points[..., 2]),
                self._intensity[slot],
                holes,
                sides,
                max_area_px=p.fill_max_hole_px,
                radius=p.fill_space_radius,
                sigma_intensity=p.sigma_intensity,
                max_step=p.max_depth_step,
                quad=quad,
                sensor_holes=sensor_holes,
            )
            got &= inside  # (a hole outside joins the image border: A27 leaves it anyway)
            if got.any():
                _put_on_rays_kernel(got, depth, self._rays, points, source, SOURCE_SPACE)
        return source, confidence


def _engine_buffer_bytes(params: FusionParams, height: int, width: int, ring: int) -> int:
    """Bytes of the buffers :class:`FusionEngine` allocates at construction (``ring`` frames
    of ``height`` x ``width`` px): the ring buffers (48-61 B per pixel and frame), the
    composed-track tables (A31, :meth:`fuse4d.motion._ComposedTracks.buffer_bytes`, quadratic
    in the window) or the one output frame's tracks (``tracks="exact"``: 9 B per pixel and
    other frame), and the per-frame scratch buffers."""
    p = params
    pixels = int(height) * int(width)
    k = p.past_frames + p.future_frames
    composed = p.tracks == "composed" and p.quantize == "final" and k > 0
    shared = p.motion_depth == "smoothed" and p.motion_sigma == p.reference_sigma
    # depth 4, intensity 4, bilateral 12, local reference 12, forward and backward flow 8 + 8;
    # the motion reference 12 unless shared, the flying-pixel mask 1
    per_frame = 48 + (0 if shared else 12) + (1 if p.flying_pixels == "on" else 0)
    ring_bytes = ring * (pixels * per_frame + (height + width) * 8)  # + the A38 extents
    # rays 12, no-static mask 1, the residual bilateral's scratch 24, the A26 fill's 14
    fixed = 13 + (24 if p.bilateral == "residual" else 0)
    if p.fill_from_time and not composed and k > 0 and p.quantize == "final":
        fixed += 14
    if composed:
        tracks = _ComposedTracks.buffer_bytes(height, width, p.past_frames, p.future_frames)
    else:
        tracks = k * pixels * 9
    return ring_bytes + fixed * pixels + tracks


def _engine_memory_message(
    params: FusionParams,
    height: int,
    width: int,
    ring: int,
    available: int | None,
    failed: bool = False,
) -> str:
    """Why an engine's buffers do not fit, and the ways out (:func:`_check_engine_memory`);
    ``failed``: the estimate fit ``available`` but the allocation failed."""

    def size(n: int) -> str:
        return f"{n / 2**30:,.1f} GiB" if n >= 2**30 // 10 else f"{n / 2**20:,.1f} MiB"

    need = _engine_buffer_bytes(params, height, width, ring)
    if failed or available is None:
        room = "the allocation failed" + (
            f" although about {size(available)} appeared available" if available else ""
        )
    else:
        room = f"{size(available)} is available"
    text = (
        f"a window of num_frames={params.num_frames} frames at {width}x{height} px needs about "
        f"{size(need)} of fusion buffers, {room}: use a smaller window (num_frames, --window)"
    )
    if params.tracks == "composed":
        exact = _engine_buffer_bytes(params.replace(tracks="exact"), height, width, ring)
        if exact < need:
            text += (
                f" or tracks='exact' (--set tracks=exact; no composed-track tables: about "
                f"{size(exact)}, slower tracking)"
            )
    return text


def _check_engine_memory(
    params: FusionParams, height: int, width: int, ring: int, available: int | None
) -> None:
    """Refuse an engine whose buffers (:func:`_engine_buffer_bytes`) exceed ``available``
    bytes (None: unknown, not checked).

    Raises
    ------
    ParameterError
        Naming the window, the frame size, the memory needed and available and the way out.
    """
    if available is not None and _engine_buffer_bytes(params, height, width, ring) > available:
        raise ParameterError(_engine_memory_message(params, height, width, ring, available))


def _check_state(state: FrameState, shape: tuple[int, int], index: int, *, separate: bool) -> None:
    """ShapeError / ValueError where ``state`` cannot be frame ``index``'s of this engine."""
    h, w = shape
    for name in ("smooth", "bilateral"):
        check_shape(getattr(state, name), (h, w, 3), name=f"state.{name} (frame {index})")
    if separate != (state.reference is not None):
        raise ParameterError(
            f"frame {index}: the state's motion reference does not match the engine's "
            "parameters (a state from an engine with other FusionParams?)"
        )
    if state.reference is not None:
        check_shape(state.reference, (h, w, 3), name=f"state.reference (frame {index})")
    if np.shape(state.noise) != (3,):
        raise ShapeError(f"state.noise (frame {index})", (3,), np.shape(state.noise))


def _smooth_base(
    points: NDArray[np.float32],
    base: NDArray[np.float32],
    depth: NDArray[np.float32],
    hole: NDArray[np.bool_],
    *,
    sigma: float,
    max_step: float,
    quad: float,
    limit_quad: float,
) -> None:
    """Limit the fine-scale part of each pixel's trajectory base offset (A29). In place.

    ``base`` (H, W, 3) mm is the offset the trajectory fit added to P~^t (the fusion kernel's
    ``base_out``). Its edge-limited spatial mean S (:func:`fuse4d.motion._segment_smooth`'s
    values, bit for bit, in two sweeps of ``_kernels/smooth_base.py``),
    ``sigma`` px, over frame t's depth-continuous segments without the ``hole`` pixels, step
    limit ``max(max_step, 2.5 quad z^2)``) is kept, and of the rest (offset - S) only what
    lies within +-``limit_quad`` z^2 mm (a fraction of the quantisation part q z^2 of the A22
    noise model, z = frame t's depth); ``points`` (H, W, 3) mm are corrected by the change.

    Why: on a turning surface the line's chord bias grows with the number of frames a pixel
    was tracked through, which changes from pixel to pixel (tracks end at folds and
    silhouettes), so the offset field steps by mm along support boundaries (9 frames rougher
    than 1 on the real person). The offset's small fine-scale part cancels frame t's own
    reference noise (hundredths of a mm on the 0.2 mm ball) and is kept.
    """
    if math.isinf(limit_quad):
        return  # every fine-scale part kept: no change
    h, w = depth.shape
    radius = _box_radius(sigma)
    step, q = float(max_step), float(quad)
    # two sweeps, each finding a line's segments once for the three channels and both box
    # passes: the values, bit for bit, of three _segment_smooth calls (a frame without any
    # fused pixel, e.g. the first of a causal window, has no segment: nothing changes)
    rows_t = np.empty((w, 3, h), np.float32)
    seg_t = np.empty((w, h), np.float32)
    bound_t = np.empty((w, h), np.float32)
    base32 = np.ascontiguousarray(base, dtype=np.float32)
    _smooth_base_rows_kernel(
        base32,
        np.ascontiguousarray(depth, dtype=np.float32),
        np.ascontiguousarray(hole, dtype=np.bool_),
        radius,
        step,
        q,
        float(limit_quad),
        rows_t,
        seg_t,
        bound_t,
    )
    _smooth_base_cols_kernel(rows_t, seg_t, bound_t, base32, radius, step, q, points)


@dataclass
class FusionResult:
    """Output of :func:`fuse_sequence` (METHOD §8).

    Attributes
    ----------
    points : (T, H, W, 3) ndarray of float32
        Fused 3D points in mm (paper p^_i^t); NaN where there is no depth (a sensor hole
        that A26/A27 did not fill).
    depth : (T, H, W) ndarray of float32
        Z of ``points`` in mm.
    support : (T, H, W) ndarray of uint8
        Temporal support: other frames whose track passed every check.
    filled : (T, H, W) ndarray of bool
        Pixels filled by Eq. 6 (valid raw depth, no temporal support).
    source : (T, H, W) ndarray of uint8
        Where each value comes from (measured / fused / filled from time / filled in space;
        codes in :mod:`fuse4d.holes`, see :class:`FusedFrame`).
    confidence : (T, H, W) ndarray of float32
        Fraction of the window's frames that measured the value (see :class:`FusedFrame`).
    flow_forward, flow_backward : (T-1, H, W, 2) ndarray of float32
        The flows used (px); zero (and ``motion``, ``fb_error`` NaN) with ``num_frames=1``,
        whose one-frame window uses no pair and computes no flow.
    motion : (T-1, H, W, 3) ndarray of float32
        One-step 3D motion field (scene flow) m^{t,t+1} in mm; NaN where the step is invalid.
    fb_error : (T-1, H, W) ndarray of float32
        Forward-backward error of each forward flow vector, px.
    timings : dict
        Seconds spent per stage.
    params : FusionParams
    flow_method : str
        Name of the tracker ("precomputed" for given flows).
    """

    points: NDArray[np.float32]
    depth: NDArray[np.float32]
    support: NDArray[np.uint8]
    filled: NDArray[np.bool_]
    flow_forward: NDArray[np.float32]
    flow_backward: NDArray[np.float32]
    motion: NDArray[np.float32]
    fb_error: NDArray[np.float32]
    timings: dict[str, float] = field(default_factory=dict)
    params: FusionParams = field(default_factory=FusionParams)
    flow_method: str = ""
    source: NDArray[np.uint8] | None = None
    confidence: NDArray[np.float32] | None = None

    @property
    def support_fraction(self) -> float:
        """Fraction of measured output pixels with temporal support >= 1 (tracked into another
        frame); sensor holes filled by A26/A27 do not count."""
        valid = np.isfinite(self.depth)
        if self.source is not None:
            valid &= (self.source == SOURCE_MEASURED) | (self.source == SOURCE_FUSED)
        return float((self.support[valid] > 0).mean()) if valid.any() else 0.0


#: Median depth (mm) below which a stream's first frame is probably not in millimetres: no 3D
#: video sensor measures a scene closer than ~0.1 m, so depth in metres has a median of 0.1-10.
MILLIMETRE_MEDIAN_FLOOR = 20.0


def _warn_if_not_millimetres(depth: NDArray[np.float32]) -> None:
    """Warn once per stream where the first frame's median valid depth (mm) is below
    :data:`MILLIMETRE_MEDIAN_FLOOR`: depth in metres ran silently, every mm scale (noise
    model, gates, kernels) 1000x too large for it, and the output hardly changed."""
    finite = depth[np.isfinite(depth)]
    if finite.size and (median := float(np.median(finite))) < MILLIMETRE_MEDIAN_FLOOR:
        warnings.warn(
            f"depth (frame 0) has a median of {median:.3g} mm: fuse4d takes depth in "
            "millimetres; if it is in metres, multiply it by 1000 (a frame folder's or camera "
            "recording's unit: --depth-unit-mm 1000)",
            stacklevel=3,
        )


#: 99.5th intensity percentile below which a frame is too dark to track: the flow methods
#: see [0, 1] in 8 bits, so fewer than ~26 gray levels would be left.
DARK_INTENSITY_CEILING = 0.1
#: Frames at the start of a stream that must all be dark for the warning: a camera's
#: auto-exposure may still be settling in the first ones.
DARK_CHECK_FRAMES = 8


class _DarkIntensityCheck:
    """Warns once where the first :data:`DARK_CHECK_FRAMES` frames of a stream (all of a
    shorter one, at :meth:`finish`) have a 99.5th intensity percentile below
    :data:`DARK_INTENSITY_CEILING`: 16-bit IR stored raw (e.g. Azure Kinect IR of 0-3000
    divided by 65535) reached the flow as a few gray levels and tracked silently badly."""

    def __init__(self) -> None:
        self.frames = 0
        self.brightest = 0.0
        self.done = False

    def add(self, intensity: NDArray[np.float32]) -> None:
        """Take the next frame's intensity ([0, 1])."""
        if self.done:
            return
        bright = float(np.percentile(intensity, 99.5)) if intensity.size else 1.0
        self.brightest = max(self.brightest, bright)
        self.frames += 1
        if self.brightest >= DARK_INTENSITY_CEILING:
            self.done = True
        elif self.frames == DARK_CHECK_FRAMES:
            self.finish()

    def finish(self) -> None:
        """Warn now if every frame taken was dark (and no warning was given yet)."""
        if self.done or not self.frames:
            return
        self.done = True
        frames = "frame 0" if self.frames == 1 else f"frames 0-{self.frames - 1}"
        if self.brightest == 0.0:
            what = "black (99.5 % of the pixels are 0): the optical flow has nothing to track"
        else:
            what = (
                f"dark: 99.5 % of the pixels are at most {self.brightest:.3g} of the [0, 1] "
                f"range, so the optical flow sees about {max(2, round(255 * self.brightest) + 1)}"
                " gray levels"
            )
        warnings.warn(
            f"intensity ({frames}) is {what}; scale it to fill [0, 1] (16-bit IR stored raw? "
            "divide it by its 99.5th percentile and clip, as fuse4d's .bag and .mkv readers do; "
            "a time-of-flight camera's IR then by its square root)",
            stacklevel=4,
        )


def fuse_sequence(
    depth: ArrayLike,
    intensity: ArrayLike,
    intrinsics: Intrinsics,
    *,
    fusion: FusionParams | None = None,
    flow: FlowConfig | str | SequenceFlow | tuple | None = None,
    progress: Callable[[int, int], None] | None = None,
    sensor: str | None = None,
) -> FusionResult:
    """Denoise a 3D video by intensity-guided 4D fusion (paper Eq. 2–6).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN (or 0) = invalid.
    intensity : (T, H, W) ndarray
        Registered intensity in [0, 1] (uint8/uint16 divided by 255/65535).
    intrinsics : Intrinsics
        Pinhole camera (px).
    fusion : FusionParams, optional
        Fusion knobs; ``None`` = METHOD.md §5.3 defaults (9 frames).
    flow : FlowConfig, str, SequenceFlow or (forward, backward), optional
        Tracker (method name or config with its cache and ROI; default: the "fast" preset,
        OpenCV DIS), or precomputed flows: a :class:`fuse4d.flow.SequenceFlow` (e.g. from
        :func:`fuse4d.flow.estimate_sequence_flow`) or a pair of ``(T-1, H, W, 2)`` px arrays.
    progress : callable, optional
        ``progress(done, total)`` after every output frame.
    sensor : str, optional
        The kind of depth camera (:attr:`fuse4d.Sequence.sensor`, e.g. ``"tof"``): decides
        ``flying_pixels="auto"`` (A36, :func:`fuse4d.flying_pixels.resolve_flying_pixels`);
        None = unknown ("auto" is off).

    Returns
    -------
    FusionResult

    Raises
    ------
    ShapeError
        If depth, intensity, intrinsics or flows disagree in shape.
    ParameterError
        If T < 1.

    Notes
    -----
    Each pair's flow is computed in a worker thread while the frame is filtered
    (:class:`FusionEngine` ``overlap_flow``): the same result bit for bit, the flow stage of
    ``timings`` only the wait for it (the flow's own seconds are ``timings["flow_worker"]``,
    spent beside the other stages). A frame without any valid depth is allowed: its pixels
    are sensor holes, which the fill from other frames (A26) may reach.

    Examples
    --------
    >>> from fuse4d.synthetic import make_falling_ball
    >>> seq = make_falling_ball(small=True, num_frames=4)
    >>> res = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics)
    >>> res.points.shape
    (4, 150, 150, 3)
    """
    check_intrinsics(intrinsics)
    params = resolve_flying_pixels(fusion_params(fusion), sensor)
    d = as_float32(depth, name="depth")
    check_shape(d, ("T", "H", "W"), name="depth")
    if intensity is None:
        raise ParameterTypeError(INTENSITY_REQUIRED)
    inten = np.asarray(intensity)
    if inten.shape != d.shape:
        raise ShapeError("intensity", d.shape, inten.shape, "it must match depth frame for frame")
    n, h, w = d.shape
    if n < 1:
        raise ParameterError("fuse_sequence needs at least one frame, got T = 0")
    if (h, w) != (intrinsics.height, intrinsics.width):
        raise ShapeError(
            "depth",
            ("T", intrinsics.height, intrinsics.width),
            d.shape,
            "the intrinsics describe another image size",
        )
    precomputed = None
    if flow is not None and not isinstance(flow, FlowConfig | str):
        precomputed = as_sequence_flow(flow, shape=(n, h, w))
    flow_cfg = None if precomputed is not None else flow
    fwd_all = np.zeros((max(n - 1, 0), h, w, 2), np.float32)
    bwd_all = np.zeros_like(fwd_all)
    motion_all = np.full((max(n - 1, 0), h, w, 3), np.nan, np.float32)
    fb_all = np.full((max(n - 1, 0), h, w), np.nan, np.float32)
    timings = dict.fromkeys(STAGES, 0.0)
    total = n * params.iterations
    done = 0
    current_points: NDArray[np.float32] | None = None
    support = np.zeros((n, h, w), np.uint8)
    filled = np.zeros((n, h, w), np.bool_)
    source = np.zeros((n, h, w), np.uint8)
    confidence = np.zeros((n, h, w), np.float32)
    flow_method = precomputed.method if precomputed is not None else ""
    for iteration in range(params.iterations):

        def on_pair(pair: _PairOutput) -> None:
            fwd_all[pair.index] = pair.forward
            bwd_all[pair.index] = pair.backward
            motion_all[pair.index] = pair.motion
            fb_all[pair.index] = pair.fb_error

        engine = FusionEngine(
            intrinsics,
            fusion=params,
            flow=flow_cfg,
            ring_size=None,
            on_pair=on_pair if iteration == 0 else None,
            timings=timings,
            overlap_flow=True,  # the flow beside the frame's filtering (closed below)
        )
        if not flow_method:
            flow_method = engine.flow_config.method
        out_points = np.empty((n, h, w, 3), np.float32)

        def pushed_frames(engine=engine, iteration=iteration, previous=current_points):
            """Push every frame (pair flows reused after the first pass), then flush."""
            for t in range(n):
                if (iteration == 0 and precomputed is None) or t == 0:
                    pair = None
                elif iteration == 0:
                    pair = (precomputed.forward[t - 1], precomputed.backward[t - 1])
                else:
                    pair = (fwd_all[t - 1], bwd_all[t - 1])
                yield from engine.push(
                    d[t],
                    inten[t],
                    pair_flow=pair,
                    points=None if previous is None else previous[t],
                )
            yield from engine.flush()

        with engine:  # stops the flow worker, also when a frame or the caller fails
            for fr in pushed_frames():
                out_points[fr.index] = fr.points
                support[fr.index] = fr.support
                filled[fr.index] = fr.filled  # the last pass's, as support and source
                source[fr.index] = fr.source
                confidence[fr.index] = fr.confidence
                done += 1
                if progress is not None:
                    progress(done, total)
        current_points = out_points
    assert current_points is not None
    return FusionResult(
        points=current_points,
        depth=np.ascontiguousarray(current_points[..., 2]),
        support=support,
        filled=filled,
        source=source,
        confidence=confidence,
        flow_forward=fwd_all,
        flow_backward=bwd_all,
        motion=motion_all,
        fb_error=fb_all,
        timings=timings,
        params=params,
        flow_method=flow_method,
    )


def fuse_stream(
    frames: Iterable[Any],
    intrinsics: Intrinsics,
    *,
    fusion: FusionParams | None = None,
    flow: FlowConfig | str | SequenceFlow | tuple | None = None,
    timings: dict[str, float] | None = None,
    sensor: str | None = None,
) -> Iterator[FusedFrame]:
    """Fuse a stream of ``(depth, intensity)`` frames with bounded memory.

    Yields :class:`FusedFrame` objects in frame order, each as soon as its window is complete
    (``fusion.future_frames`` frames of latency; zero with ``causal=True``). Memory does not
    grow with the stream length: the engine's buffers, allocated when the stream starts, hold
    ``num_frames`` frames (48-61 B per pixel each) plus the composed tracks of
    ``tracks="composed"`` (A31), which grow with the square of the window
    ((future + 1) x (num_frames - 1) x 5 B per pixel: 60 MB at 640x480 and n = 9, 47 GiB at
    n = 256); a window whose buffers do not fit in the memory available raises
    :class:`~fuse4d.errors.ParameterError`. ``iterations`` > 1 is not supported in streaming
    (use :func:`fuse_sequence`).

    Parameters
    ----------
    frames : iterable of (depth, intensity) or of fuse4d.io.Frame
        ``(H, W)`` depth in mm (NaN or 0 = invalid) and registered intensity in [0, 1], in
        frame order: pairs (e.g. ``zip(depth, intensity)``) or a reader's frames (e.g.
        ``fuse4d.io.iter_frames(path)``, which used to fail to unpack).
    intrinsics : Intrinsics
        Pinhole camera (px); its size fixes the frame shape.
    fusion : FusionParams, optional
        Fusion knobs (default ``FusionParams()``).
    flow : FlowConfig, str, SequenceFlow or (forward, backward), optional
        Tracker (default: the "fast" preset's DIS) or precomputed flows, as in
        :class:`FusionEngine`.
    timings : dict, optional
        Accumulates seconds per pipeline stage.
    sensor : str, optional
        The kind of depth camera (:attr:`fuse4d.Sequence.sensor`, e.g. ``"tof"``; the
        ``sensor`` of the reader's recording): decides ``flying_pixels="auto"`` (A36,
        :func:`fuse4d.flying_pixels.resolve_flying_pixels`), as in :func:`fuse_sequence`;
        None = unknown ("auto" is off). The frames of :func:`fuse4d.io.iter_frames` do not
        carry it: pass ``sensor="tof"`` for an Azure Kinect recording.

    Yields
    ------
    FusedFrame
        Fused points (mm), support and fill masks of frame ``index``.

    Raises
    ------
    ParameterError
        ``iterations`` > 1, or a window whose buffers do not fit in memory.

    Examples
    --------
    >>> from fuse4d.synthetic import make_falling_ball
    >>> seq = make_falling_ball(small=True, num_frames=4)
    >>> frames = zip(seq.depth, seq.intensity)
    >>> [f.index for f in fuse_stream(frames, seq.intrinsics, fusion=FusionParams(num_frames=3))]
    [0, 1, 2, 3]
    """
    params = resolve_flying_pixels(fusion_params(fusion), sensor)
    if params.iterations != 1:
        raise ParameterError("fuse_stream supports iterations=1 only; use fuse_sequence for more")
    engine = FusionEngine(intrinsics, fusion=params, flow=flow, timings=timings, overlap_flow=True)
    with engine:  # stops the flow worker when the stream ends or is abandoned
        for k, frame in enumerate(frames):
            yield from engine.push(*_depth_and_intensity(frame, k))
        yield from engine.flush()


def _depth_and_intensity(frame: Any, k: int) -> tuple[Any, Any]:
    """One item of :func:`fuse_stream`'s input: a ``(depth, intensity)`` pair or a reader's
    ``fuse4d.io.Frame`` (anything with ``depth`` and ``intensity``)."""
    if hasattr(frame, "depth") and hasattr(frame, "intensity"):
        return frame.depth, frame.intensity
    if isinstance(frame, tuple | list) and len(frame) == 2:
        return frame[0], frame[1]
    raise ParameterTypeError(
        f"fuse_stream takes (depth, intensity) pairs or fuse4d.io frames; item {k} is a "
        f"{type(frame).__name__} (e.g. zip(depth_frames, intensity_frames))"
    )
