"""Live fusion: the causal engine on a RealSense camera or a recording played back in real time.

A capture thread reads frames from a :class:`FrameSource` (a camera, or a recording paced at
its recorded rate) into a bounded queue; the fusion loop takes them out, fuses each with the
``n - 1`` previous frames (:class:`fuse4d.FusionEngine` with ``FusionParams(causal=True)``: no
look-ahead) and hands raw and fused frame to a sink (a writer, a window).

Drop policy
-----------
When the fusion falls behind, the queue fills; the capture thread then drops the **oldest**
unprocessed frame, so a frame never waits behind more than ``queue_size`` others and latency
stays bounded (about ``(queue_size + 1)`` fusion steps). A dropped frame leaves a gap in the
frame numbers (so does a frame the camera itself dropped). The engine has no notion of gaps:
:meth:`fuse4d.FusionEngine.push` treats every pushed frame as the successor of the previous
one and warm-starts its flow from the previous pair. So by default (``on_gap="restart"``) the
fusion loop starts a new engine at every gap: the window and the flow warm start begin again
from the frame after the gap (the next ``n - 1`` frames are fused with truncated windows), and
nothing is tracked across a gap. ``on_gap="track"`` keeps the engine instead and tracks across
the gap as if the frames were consecutive (a wider-baseline pair); every such gap is counted in
:attr:`LiveStats.tracked_gaps`. Without drops the output equals a causal
:func:`fuse4d.fuse_sequence` of the same frames bit for bit.

Latency is measured from the moment a frame enters the pipeline (the camera delivered it, or
the player released it at its due time) to the moment its fused frame has been passed to the
sink (shown, or queued for writing: :class:`LiveWriter` writes in a background thread).
"""

from __future__ import annotations

import collections
import contextlib
import math
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import Any, Literal, Protocol, Self

import numpy as np
from numpy.typing import NDArray

from . import _signals
from ._background import LOWER_AFTER_FRAMES
from .camera import Intrinsics
from .config import FlowConfig, FusionParams, fusion_params
from .errors import CameraError, ParameterError
from .flying_pixels import resolve_flying_pixels
from .fusion import FusedFrame, FusionEngine

__all__ = [
    "CapturedFrame",
    "DecimatedSource",
    "DropOldestQueue",
    "FrameSource",
    "LiveStats",
    "LiveWriter",
    "RealSenseSource",
    "RecordingSource",
    "display_available",
    "display_problem",
    "display_range",
    "realsense_available",
    "run_live",
    "side_by_side",
]

#: Longest wait (s) between two frames of a recording played in real time; a longer jump in
#: its timestamps is played without the wait (with a warning).
MAX_PLAYBACK_WAIT_S = 5.0


@dataclass
class CapturedFrame:
    """One frame as it entered the live pipeline.

    Attributes
    ----------
    index : int
        Source frame number: consecutive unless frames were dropped (by the camera or by the
        queue).
    depth : (H, W) ndarray of float32
        Depth in mm, NaN = invalid.
    intensity : (H, W) ndarray of float32
        Registered intensity in [0, 1].
    timestamp : float or None
        Recording or camera time of the frame in seconds.
    captured : float
        ``time.perf_counter()`` (s) when the frame entered the pipeline.
    mask : (H, W) ndarray of bool or None
        Object mask of the recording, if it stores one (passed to the writer).
    """

    index: int
    depth: NDArray[np.float32]
    intensity: NDArray[np.float32]
    timestamp: float | None
    captured: float
    mask: NDArray[np.bool_] | None = None


class FrameSource(Protocol):
    """What :func:`run_live` reads: a camera or a paced recording."""

    intrinsics: Intrinsics
    fps: float | None
    depth_unit_mm: float | None

    def __iter__(self) -> Iterator[CapturedFrame]:
        """Frames in capture order, each released when it is captured (or due)."""
        ...

    def close(self) -> None:
        """Release the device or the file."""
        ...


class RecordingSource:
    """A recording (any layout :func:`fuse4d.io.open_frames` reads) as a live source.

    Parameters
    ----------
    path : path-like
        The recording.
    realtime : bool
        Release each frame at its recorded time (timestamps from the reader; ``fps``
        overrides them). ``False``: as fast as they can be read.
    fps : float, optional
        Playback rate in frames per second instead of the recorded timestamps.
    frames : str, slice or sequence of int, optional
        Frames to play (as ``open_frames(...).iter_frames``).
    **reader_options
        Passed to :func:`fuse4d.io.open_frames` (``format``, ``intrinsics``,
        ``depth_unit_mm``, topics, ...).

    Raises
    ------
    ValueError
        With ``realtime`` when the recording stores neither timestamps nor a frame rate and
        ``fps`` is not given; or when ``fps`` <= 0.
    """

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        realtime: bool = True,
        fps: float | None = None,
        frames: Any = None,
        **reader_options: Any,
    ) -> None:
        from .io import open_frames

        if fps is not None and not (math.isfinite(fps) and fps > 0):
            raise ParameterError(f"fps must be > 0, got {fps}")
        self.path = Path(path)
        self._reader = open_frames(path, **reader_options)
        self.intrinsics = self._reader.intrinsics
        self.depth_unit_mm = self._reader.depth_unit_mm
        self.sensor = self._reader.sensor  # the kind of depth camera, if the file says (A36)
        self.realtime = realtime
        self._frames = frames
        timestamps = self._reader.timestamps
        self._timestamps = None if fps is not None else timestamps
        # (n - 1) / span made one 20 s pause in 20 frames at 20 Hz a rate of 0.9 fps
        stamped = _timestamp_rate(timestamps)
        recorded = self._reader.fps if self._reader.fps is not None else stamped
        #: the playback rate (frames/s): ``fps``; else the rate the recorded timestamps pace
        #: it at (1 / their median interval: a stored fps of 30 beside 10 Hz timestamps
        #: was reported as the playback rate), else the recording's own
        self.fps = fps if fps is not None else (stamped or recorded)
        #: the recording's own rate (stored, else 1 / the median interval of its timestamps;
        #: None: unknown), whatever the playback rate ``fps``
        self.recorded_fps = recorded
        #: the rate an output states: the recording's own (``--fps 10`` wrote fps 10 for a
        #: 30 fps recording), else the playback rate ``fps``
        self.output_fps = recorded if recorded is not None else self.fps
        #: how playback is paced, in words (the banner said "at 30 fps" while a recording
        #: with uneven timestamps played at 20)
        self.pace = (
            "its recorded timestamps"
            if self._timestamps is not None
            else (f"{self.fps:g} fps" if self.fps else "")
        )
        if realtime and self._timestamps is None and self.fps is None:
            self._reader.close()
            raise ParameterError(
                f"{path}: the recording stores no timestamps or frame rate; give the "
                "playback rate (--fps)"
            )

    def _due(self, order: int, index: int) -> float:
        """Seconds after the start at which frame ``index`` (the ``order``-th played) is due."""
        ts = self._timestamps
        if ts is not None and np.isfinite(ts[index]) and np.isfinite(ts[self._first]):
            return float(ts[index] - ts[self._first])
        assert self.fps is not None
        return order / self.fps

    def __iter__(self) -> Iterator[CapturedFrame]:
        start = None
        self._first = 0
        for order, frame in enumerate(self._reader.iter_frames(self._frames)):
            if order == 0:
                self._first = frame.index
                start = time.perf_counter()
            if self.realtime:
                assert start is not None
                wait = start + self._due(order, frame.index) - time.perf_counter()
                if wait > MAX_PLAYBACK_WAIT_S and self._timestamps is not None:
                    # a jump in the timestamps (a paused recording, ns stored as s): played
                    # without the wait; time.sleep(1e10) raised OverflowError, or hung
                    warnings.warn(
                        f"{self.path} (frame {frame.index}): the timestamps jump by "
                        f"{wait:.4g} s; played on without waiting",
                        stacklevel=2,
                    )
                    start -= wait
                elif wait > 0:
                    time.sleep(wait)
            timestamp = frame.timestamp
            if timestamp is None and self.recorded_fps:
                # the frame's time at the recording's own rate (not the playback rate: --fps
                # 10 labelled a 30 fps recording's frames 0.1 s apart): an output of a run
                # that dropped frames keeps the gaps (fps alone says they are consecutive)
                timestamp = (frame.index - self._first) / self.recorded_fps
            elif timestamp is None and self.fps is not None:  # its rate unknown: --fps's
                timestamp = self._due(order, frame.index)
            yield CapturedFrame(
                index=frame.index,
                depth=frame.depth,
                intensity=frame.intensity,
                timestamp=timestamp,
                captured=time.perf_counter(),
                mask=frame.mask,
            )

    def close(self) -> None:
        """Close the reader."""
        self._reader.close()


def _timestamp_rate(timestamps: NDArray[np.float64] | None) -> float | None:
    """Frames per second that timestamps (s) give: 1 / the median interval between
    consecutive frames (finite, > 0), so that a pause does not lower it; None when there is
    no such interval."""
    if timestamps is None:
        return None
    steps = np.diff(np.asarray(timestamps, dtype=np.float64))
    steps = steps[np.isfinite(steps) & (steps > 0)]
    return float(1.0 / np.median(steps)) if steps.size else None


class DecimatedSource:
    """Another source's frames at 1/``factor`` of the resolution (:mod:`fuse4d.decimate`,
    the RealSense decimation filter): ``fuse4d live --decimate``.

    The frames are decimated in the capture thread as they arrive (their ``captured`` time is
    the source's, so the latency includes the decimation); the fusion, the window and the
    output see the smaller frames and :attr:`intrinsics`.

    Parameters
    ----------
    source : FrameSource
        The camera or recording.
    factor : int
        Block side, 1-8 (depth: lower median for 2-3, mean for 4-8; intensity: block mean).
    """

    def __init__(self, source: FrameSource, factor: int) -> None:
        from .decimate import decimate_intrinsics

        self.source = source
        self.factor = int(factor)
        self.intrinsics = decimate_intrinsics(source.intrinsics, self.factor)
        self.fps = source.fps
        self.recorded_fps = getattr(source, "recorded_fps", source.fps)
        self.output_fps = getattr(source, "output_fps", source.fps)
        self.pace = getattr(source, "pace", f"{source.fps:g} fps" if source.fps else "")
        self.depth_unit_mm = source.depth_unit_mm
        self.sensor = getattr(source, "sensor", None)

    def __iter__(self) -> Iterator[CapturedFrame]:
        from .decimate import decimate_depth, decimate_intensity, decimate_mask

        f = self.factor
        for frame in self.source:
            yield replace(
                frame,
                depth=decimate_depth(frame.depth, f),
                intensity=decimate_intensity(frame.intensity, f),
                mask=None if frame.mask is None else decimate_mask(frame.mask, f),
            )

    def close(self) -> None:
        """Close the source."""
        self.source.close()


def realsense_available() -> bool:
    """True when pyrealsense2 is installed and at least one RealSense device is attached."""
    try:
        import pyrealsense2 as rs  # type: ignore[import-not-found]
    except ImportError:
        return False
    try:
        return len(rs.context().query_devices()) > 0
    except RuntimeError:
        return False


class RealSenseSource:
    """A RealSense depth camera through the pyrealsense2 pipeline.

    Streams depth (z16) and the left infrared imager (y8), which is pixel-registered with the
    depth by construction on the D400 series (the guide intensity, no resampling needed).

    Parameters
    ----------
    width, height : int
        Stream size in px (both streams).
    fps : int
        Camera frame rate (frames per second).
    serial : str, optional
        Serial number of the device to use (default: the first one).
    emitter : bool, optional
        Switch the IR projector on or off (default: the device's setting). Off gives a clean
        IR guide image but sparser depth on texture-less surfaces.
    timeout_ms : int
        Longest wait for a frameset before giving up (ms).

    Raises
    ------
    RuntimeError
        If pyrealsense2 is missing or no device is attached.
    """

    def __init__(
        self,
        *,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        serial: str | None = None,
        emitter: bool | None = None,
        timeout_ms: int = 5000,
    ) -> None:
        try:
            import pyrealsense2 as rs  # type: ignore[import-not-found]
        except ImportError as exc:
            raise RuntimeError("the RealSense source needs pyrealsense2") from exc
        if not realsense_available():
            raise RuntimeError("no RealSense camera attached")
        self._rs = rs
        self._timeout_ms = timeout_ms
        self._pipeline = rs.pipeline()
        config = rs.config()
        if serial is not None:
            config.enable_device(serial)
        config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
        config.enable_stream(rs.stream.infrared, 1, width, height, rs.format.y8, fps)
        #: the camera, for messages
        self.name = f"RealSense camera{'' if serial is None else ' ' + serial}"
        try:
            profile = self._pipeline.start(config)
        except RuntimeError as exc:  # pyrealsense2's error for a mode the camera lacks
            raise CameraError(
                f"{self.name}: cannot stream depth z16 + IR y8 at {width}x{height}, {fps} fps "
                f"({exc})"
            ) from None
        from .io._realsense import realsense_sensor_kind

        device = profile.get_device()
        #: the depth technology from the camera's name (D4xx active stereo, L5xx ToF: A36)
        self.sensor = realsense_sensor_kind(str(device.get_info(rs.camera_info.name)))
        sensor = device.first_depth_sensor()
        if emitter is not None and sensor.supports(rs.option.emitter_enabled):
            sensor.set_option(rs.option.emitter_enabled, 1.0 if emitter else 0.0)
        #: millimetres per z16 unit (the device's depth scale is in metres)
        self.depth_unit_mm = float(sensor.get_depth_scale()) * 1000.0
        k = profile.get_stream(rs.stream.depth).as_video_stream_profile().get_intrinsics()
        self.intrinsics = Intrinsics(
            fx=float(k.fx), fy=float(k.fy), cx=float(k.ppx), cy=float(k.ppy), width=k.width,
            height=k.height,
        )  # fmt: skip
        self.fps: float | None = float(fps)
        self.recorded_fps = self.fps
        self.output_fps = self.fps
        self.pace = f"{fps} fps"
        self._stopped = False

    def __iter__(self) -> Iterator[CapturedFrame]:
        while not self._stopped:
            try:
                frames = self._pipeline.wait_for_frames(self._timeout_ms)
            except RuntimeError as exc:  # "Frame didn't arrive within 5000"
                if self._stopped:
                    return
                raise CameraError(
                    f"{self.name}: no frame within {self._timeout_ms} ms (disconnected?): {exc}"
                ) from None
            captured = time.perf_counter()
            depth_frame = frames.get_depth_frame()
            ir_frame = frames.get_infrared_frame(1)
            if not depth_frame or not ir_frame:
                continue
            raw = np.asanyarray(depth_frame.get_data())
            depth = raw.astype(np.float32) * np.float32(self.depth_unit_mm)
            depth[raw == 0] = np.nan
            intensity = np.asanyarray(ir_frame.get_data()).astype(np.float32) / np.float32(255)
            yield CapturedFrame(
                index=int(depth_frame.get_frame_number()),
                depth=depth,
                intensity=intensity,
                timestamp=float(depth_frame.get_timestamp()) / 1000.0,
                captured=captured,
            )

    def close(self) -> None:
        """Stop the camera pipeline."""
        if not self._stopped:
            self._stopped = True
            self._pipeline.stop()


class DropOldestQueue:
    """A bounded FIFO whose :meth:`put` drops the oldest item when full (never blocks).

    Parameters
    ----------
    maxsize : int
        Items held at most (>= 1).
    block : bool
        ``True``: :meth:`put` waits for room instead of dropping (no frame lost; for
        playback that is not in real time).
    """

    def __init__(self, maxsize: int, *, block: bool = False) -> None:
        if maxsize < 1:
            raise ParameterError(f"queue size must be >= 1, got {maxsize}")
        self.maxsize = maxsize
        self.block = block
        self._items: collections.deque[Any] = collections.deque()
        self._cond = threading.Condition()
        self._closed = False
        self.dropped = 0

    def put(self, item: Any) -> Any | None:
        """Add ``item``; return the item dropped to make room (None if none was)."""
        with self._cond:
            dropped = None
            if self.block:
                while len(self._items) >= self.maxsize and not self._closed:
                    self._cond.wait()
            elif len(self._items) >= self.maxsize:
                dropped = self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify_all()
            return dropped

    def get(self, timeout: float | None = None) -> Any | None:
        """The oldest item; None once the queue is closed and empty (or on timeout)."""
        with self._cond:
            end = None if timeout is None else time.monotonic() + timeout
            while not self._items and not self._closed:
                left = None if end is None else end - time.monotonic()
                if left is not None and left <= 0:
                    return None
                self._cond.wait(left)
            if not self._items:
                return None
            item = self._items.popleft()
            self._cond.notify_all()
            return item

    def close(self) -> None:
        """No more items: :meth:`get` returns None when the queue has run empty."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


@dataclass
class LiveStats:
    """What a live run achieved.

    Attributes
    ----------
    frames_captured : int
        Frames that entered the pipeline.
    frames_fused : int
        Frames fused and passed to the sink.
    dropped : int
        Frames the queue dropped (oldest first) because the fusion was behind.
    unfused_at_stop : int
        Frames captured but neither fused nor dropped: waiting or being fused when the run
        was stopped (Ctrl-C); ``frames_captured = frames_fused + dropped + unfused_at_stop``.
    gaps : int
        Breaks in the frame numbers seen by the fusion (queue drops and camera drops).
    restarts : int
        Engine restarts at gaps (``on_gap="restart"``).
    tracked_gaps : int
        Gaps tracked across as if consecutive (``on_gap="track"``).
    seconds : float
        Wall time from the first frame captured to the last frame output (s).
    fps : float or None
        Output rate: frames output per second between the first and the last output (None:
        fewer than two frames output, not measured).
    input_fps : float or None
        Capture rate: frames captured per second between the first and the last capture
        (None: fewer than two frames captured).
    latency_ms : dict
        Capture-to-output latency, ``p50``, ``p95``, ``max`` and ``mean`` in ms.
    step_ms : dict
        Wall time of one fusion step (:meth:`fuse4d.FusionEngine.push`), ``p50`` and ``mean``
        in ms: the rate the pipeline can sustain is about 1000 / step.
    indices : list of int
        Source frame numbers of the output frames, in order.
    window_frames : list of int
        Frames of history each output frame was fused with (itself included): ``n`` once
        the window is full, fewer after a start or a restart.
    interrupted : bool
        Stopped by Ctrl-C, SIGTERM or SIGHUP (the frames fused until then are complete).
    source_error : str
        Why the source stopped delivering frames when it failed after the first one (a
        camera disconnected: :class:`~fuse4d.errors.CameraError`); empty otherwise.
    """

    frames_captured: int = 0
    frames_fused: int = 0
    dropped: int = 0
    unfused_at_stop: int = 0
    gaps: int = 0
    restarts: int = 0
    tracked_gaps: int = 0
    seconds: float = 0.0
    fps: float | None = None
    input_fps: float | None = None
    latency_ms: dict[str, float] = field(default_factory=dict)
    step_ms: dict[str, float] = field(default_factory=dict)
    indices: list[int] = field(default_factory=list)
    window_frames: list[int] = field(default_factory=list)
    latencies_s: list[float] = field(default_factory=list, repr=False)
    interrupted: bool = False
    source_error: str = ""
    first_output_s: float = field(default=0.0, repr=False)  # perf_counter times
    last_output_s: float = field(default=0.0, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no per-frame lists)."""
        keys = ("frames_captured", "frames_fused", "dropped", "unfused_at_stop", "gaps", "restarts")
        out: dict[str, Any] = {k: getattr(self, k) for k in keys}
        out.update(
            tracked_gaps=self.tracked_gaps,
            seconds=self.seconds,
            fps=self.fps,
            input_fps=self.input_fps,
            latency_ms=dict(self.latency_ms),
            step_ms=dict(self.step_ms),
            mean_window=(float(np.mean(self.window_frames)) if self.window_frames else 0.0),
            interrupted=self.interrupted,
            source_error=self.source_error,
        )
        return out


#: ``sink(captured, fused)``: receives every output frame (raw and fused) in order.
Sink = Callable[[CapturedFrame, FusedFrame], None]


def run_live(
    source: FrameSource,
    *,
    fusion: FusionParams | None = None,
    flow: FlowConfig | str | None = None,
    queue_size: int = 2,
    on_gap: Literal["restart", "track"] = "restart",
    sink: Sink | None = None,
    max_frames: int | None = None,
    duration_s: float | None = None,
    stop: threading.Event | None = None,
    block: bool = False,
    extra_delay_s: float = 0.0,
    warmup: bool = True,
    overlap_flow: bool = True,
) -> LiveStats:
    """Fuse a live source causally, with a bounded queue that drops the oldest frame.

    Parameters
    ----------
    source : FrameSource
        :class:`RealSenseSource`, :class:`RecordingSource` or any object with
        ``intrinsics`` and an iterator of :class:`CapturedFrame`.
    fusion : FusionParams, optional
        Fusion knobs; ``causal`` is forced on (default ``FusionParams(causal=True)``).
    flow : FlowConfig or str, optional
        Tracker (default: the fast preset's DIS).
    queue_size : int
        Frames waiting between capture and fusion at most; when full the oldest is dropped.
    on_gap : {"restart", "track"}
        At a gap in the frame numbers: start a new engine (window and flow warm start begin
        again; default), or track across the gap as if consecutive (counted).
    sink : callable, optional
        ``sink(captured, fused)`` for each output frame (writer, window), in the fusion thread.
    max_frames : int, optional
        Stop after this many frames captured.
    duration_s : float, optional
        Stop capturing after this many seconds.
    stop : threading.Event, optional
        Set it to stop (e.g. from a window's key handler or a signal).
    block : bool
        Never drop: the capture waits for room (non-real-time playback).
    extra_delay_s : float
        Extra seconds spent in every fusion step (simulates a slower machine; tests).
    warmup : bool
        Before capturing, fuse two synthetic frames on a throw-away engine so that the numba
        kernels and the tracker are loaded (otherwise the first frames wait for them).
    overlap_flow : bool
        Compute each frame's flow in a worker thread while the engine filters the frame
        (:class:`~fuse4d.FusionEngine` ``overlap_flow``): a shorter fusion step, the same
        output bit for bit.

    Returns
    -------
    LiveStats
        Achieved rate, drops, gaps, restarts and capture-to-output latency.
    """
    if on_gap not in ("restart", "track"):
        raise ParameterError(f"on_gap must be 'restart' or 'track', got {on_gap!r}")
    if max_frames is not None and max_frames < 1:
        raise ParameterError(f"max_frames must be >= 1, got {max_frames}")
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise ParameterError(f"duration_s must be > 0 s, got {duration_s}")
    params = fusion_params(fusion).replace(causal=True)
    params = resolve_flying_pixels(params, getattr(source, "sensor", None))  # A36
    if params.iterations != 1:
        raise ParameterError(
            f"live fusion fuses each frame once (iterations=1), got iterations={params.iterations}"
        )
    queue = DropOldestQueue(queue_size, block=block)
    stop = stop or threading.Event()
    stats = LiveStats()
    steps: list[float] = []
    errors: list[BaseException] = []
    first_capture: list[float] = []
    last_capture: list[float] = [0.0]

    def capture() -> None:
        try:
            start = time.perf_counter()
            for frame in source:
                if stop.is_set():
                    break
                if not first_capture:
                    first_capture.append(frame.captured)
                stats.frames_captured += 1
                last_capture[0] = frame.captured
                queue.put(frame)
                if max_frames is not None and stats.frames_captured >= max_frames:
                    break
                if duration_s is not None and time.perf_counter() - start >= duration_s:
                    break
        except Exception as exc:  # noqa: BLE001  (re-raised by the fusion thread)
            errors.append(exc)
        finally:
            queue.close()

    with _stop_on_signals(stop, stats) as signals:
        if warmup and not stats.interrupted:
            _warm_up(source.intrinsics, params, flow, overlap_flow)
        if stats.interrupted:  # before or during the warm-up: nothing was captured
            raise KeyboardInterrupt
        signals.armed.set()  # from now on a second signal interrupts at once
        _fuse_live(source, params, flow, overlap_flow, queue, capture, sink, on_gap, stop,
                   stats, steps, extra_delay_s)  # fmt: skip
    if stats.interrupted and stats.frames_fused == 0:  # before the first frame: nothing out
        raise KeyboardInterrupt
    if errors:
        if isinstance(errors[0], CameraError) and stats.frames_captured:
            # a camera lost mid-run: the frames fused so far are kept (a recording can be
            # played again; a camera's frames cannot)
            stats.source_error = str(errors[0])
        else:
            raise errors[0]
    stats.dropped = queue.dropped
    stats.unfused_at_stop = max(stats.frames_captured - stats.frames_fused - stats.dropped, 0)
    if first_capture:
        stats.seconds = max(stats.last_output_s - first_capture[0], 0.0)
    if stats.frames_fused > 1 and stats.last_output_s > stats.first_output_s:
        stats.fps = (stats.frames_fused - 1) / (stats.last_output_s - stats.first_output_s)
    if stats.frames_captured > 1 and last_capture[0] > first_capture[0]:
        stats.input_fps = (stats.frames_captured - 1) / (last_capture[0] - first_capture[0])
    if stats.latencies_s:
        lat = np.asarray(stats.latencies_s) * 1000.0
        stats.latency_ms = {
            "p50": float(np.percentile(lat, 50)),
            "p95": float(np.percentile(lat, 95)),
            "max": float(lat.max()),
            "mean": float(lat.mean()),
        }
    if steps:
        step = np.asarray(steps) * 1000.0
        stats.step_ms = {"p50": float(np.median(step)), "mean": float(step.mean())}
    return stats


class _SignalStop:
    """What Ctrl-C, SIGTERM and SIGHUP do while :func:`_stop_on_signals` is in force."""

    def __init__(self) -> None:
        #: set once the numba kernels are loaded: from then on a second signal interrupts
        self.armed = threading.Event()
        #: a signal came: the run stops as after q
        self.interrupted = False
        #: a second signal raised KeyboardInterrupt: later ones are ignored while it unwinds
        #: (one in the writer's abort left its staged output behind)
        self.aborted = False
        self._stops: list[threading.Event] = []
        self._stats: list[LiveStats] = []

    def add(self, stop: threading.Event, stats: LiveStats | None) -> None:
        """Set ``stop`` and ``stats.interrupted`` at a signal (at once if one came before)."""
        self._stops.append(stop)
        if stats is not None:
            self._stats.append(stats)
        if self.interrupted:
            self._stop()

    def remove(self, stop: threading.Event, stats: LiveStats | None) -> None:
        """Undo :meth:`add`."""
        self._stops.remove(stop)
        if stats is not None:
            self._stats.remove(stats)

    def _stop(self) -> None:
        self.interrupted = True
        for stats in self._stats:
            stats.interrupted = True
        for stop in self._stops:
            stop.set()

    def handler(self, signum: int, frame: object) -> None:
        """The signal handler."""
        if self.aborted or _signals.is_echo(signum):  # (GNU timeout -s INT sends it twice)
            return
        if not self.armed.is_set():
            # while the kernels load, numba may turn an interrupt into another error: the
            # CLI reads that as the interrupt (later, a bug during the stop stays a bug)
            _signals.INTERRUPTED.set()
        elif self.interrupted:
            self.aborted = True
            _signals.INTERRUPTED.set()  # an interrupt even where Python drops it (a __del__)
            raise KeyboardInterrupt
        self._stop()


@contextlib.contextmanager
def _stop_on_signals(
    stop: threading.Event, stats: LiveStats | None = None
) -> Iterator[_SignalStop]:
    """Ctrl-C, SIGTERM and SIGHUP set ``stop`` (and ``stats.interrupted``) instead of raising:
    the run ends as after q, with the frames fused until then. Raised in the middle of
    loading the numba kernels, a KeyboardInterrupt was swallowed by a ctypes callback and the
    run went on. Once the caller sets the yielded guard's ``armed`` (the kernels are loaded),
    a second signal raises KeyboardInterrupt (once; later ones are ignored while it unwinds);
    before, it only stops (raised inside numba's compiler it printed a ctypes traceback). The
    same signal again within :data:`fuse4d._signals.ECHO_S` is ignored (GNU ``timeout -s
    INT`` delivers it twice).

    Nested in another (``fuse4d live`` keeps one until its output is written: a Ctrl-C while
    an .npz was saved threw the whole run away), it shares the outer guard: one signal before
    stops both, and ``armed`` stays set after the inner one ends. Main thread only (elsewhere
    no signal is delivered)."""
    names = ("SIGINT", "SIGTERM", "SIGHUP")
    sigs = [getattr(signal, n) for n in names if hasattr(signal, n)]
    if threading.current_thread() is not threading.main_thread():
        yield _SignalStop()
        return
    outer = getattr(signal.getsignal(sigs[0]), "__self__", None)
    guard = outer if isinstance(outer, _SignalStop) else _SignalStop()
    guard.add(stop, stats)
    previous = {} if guard is outer else {s: signal.signal(s, guard.handler) for s in sigs}
    try:
        yield guard
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        guard.remove(stop, stats)


def _fuse_live(
    source: FrameSource,
    params: FusionParams,
    flow: FlowConfig | str | None,
    overlap_flow: bool,
    queue: DropOldestQueue,
    capture: Callable[[], None],
    sink: Sink | None,
    on_gap: str,
    stop: threading.Event,
    stats: LiveStats,
    steps: list[float],
    extra_delay_s: float,
) -> None:
    """The fusion loop of :func:`run_live` (capture runs in its own thread)."""
    thread = threading.Thread(target=capture, name="fuse4d-live-capture", daemon=True)
    engine = FusionEngine(source.intrinsics, fusion=params, flow=flow, overlap_flow=overlap_flow)
    last_index: int | None = None
    history = 0
    stats.last_output_s = stats.first_output_s = time.perf_counter()
    thread.start()
    try:
        while True:
            frame = queue.get()
            if frame is None or stop.is_set():
                break
            if last_index is not None and frame.index != last_index + 1:
                stats.gaps += 1
                if on_gap == "restart":  # a new stream on the same buffers
                    engine.reset()
                    stats.restarts += 1
                    history = 0
                else:
                    stats.tracked_gaps += 1
            last_index = frame.index
            if extra_delay_s > 0:
                time.sleep(extra_delay_s)
            t0 = time.perf_counter()
            fused = engine.push(frame.depth, frame.intensity)
            steps.append(time.perf_counter() - t0)
            history = min(history + 1, params.num_frames)
            for out in fused:  # causal: exactly the frame just pushed
                if sink is not None:
                    sink(frame, out)
                stats.last_output_s = time.perf_counter()
                if stats.frames_fused == 0:
                    stats.first_output_s = stats.last_output_s
                stats.latencies_s.append(stats.last_output_s - frame.captured)
                stats.indices.append(frame.index)
                stats.window_frames.append(history)
                stats.frames_fused += 1
    finally:
        stop.set()
        queue.close()
        engine.close()
        while queue.get(timeout=0) is not None:  # let a blocked capture thread finish
            pass
        thread.join(timeout=10.0)


def _warm_up(
    intrinsics: Intrinsics,
    params: FusionParams,
    flow: FlowConfig | str | None,
    overlap_flow: bool = False,
) -> None:
    """Fuse three synthetic frames (a noisy plane with a step, sensor holes and a moving
    texture) so that every kernel, hole filling included, is compiled or loaded."""
    h, w = intrinsics.height, intrinsics.width
    rng = np.random.default_rng(0)
    texture = rng.uniform(0.2, 0.8, (h, w + 3)).astype(np.float32)
    with FusionEngine(intrinsics, fusion=params, flow=flow, overlap_flow=overlap_flow) as engine:
        for t in range(3):
            depth = (1000.0 + rng.normal(0.0, 1.0, (h, w))).astype(np.float32)
            depth[:, w // 2 :] += 300.0  # a depth edge
            depth[rng.random((h, w)) < 0.01] = np.nan  # scattered holes
            depth[h // 4 : h // 4 + max(h // 8, 1), w // 4 : w // 4 + max(w // 8, 1)] = np.nan
            engine.push(depth, np.ascontiguousarray(texture[:, t : t + w]))


def display_available() -> bool:
    """True when an OpenCV window can be opened: OpenCV was built with a GUI, and on Linux a
    display is set (:func:`display_problem` says which is missing)."""
    return display_problem() is None


def display_problem() -> str | None:
    """Why no OpenCV window can be opened, in words (None: one can).

    fuse4d depends on the headless OpenCV build (no GUI: ``cv2.imshow`` raised "The function
    is not implemented" on a desktop, and the run's output was lost).
    """
    import re

    import cv2

    gui = re.search(r"^\s*GUI:\s*(\S+)", cv2.getBuildInformation(), re.MULTILINE)
    if gui is not None and gui.group(1).upper() == "NONE":
        return (
            "this OpenCV has no GUI (a headless build; `pip install opencv-contrib-python` "
            "in place of opencv-contrib-python-headless gives one)"
        )
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return "no display"
    return None


def display_range(depth: NDArray[np.float32]) -> tuple[float, float] | None:
    """The 2nd-98th percentile (mm) of a depth map's valid pixels (None: no valid pixel).

    The colour scale of :func:`side_by_side`; ``fuse4d live --show`` takes it from the first
    frame and keeps it (a steady scale, and no percentile per frame).
    """
    valid = depth[np.isfinite(depth)]
    if not valid.size:
        return None
    lo, hi = np.percentile(valid, [2, 98])
    return float(lo), float(hi)


def side_by_side(
    raw_depth: NDArray[np.float32],
    fused_depth: NDArray[np.float32],
    depth_range: tuple[float, float] | None = None,
) -> NDArray[np.uint8]:
    """Raw | fused depth as one colour image (BGR, invalid = black) on one colour scale.

    Parameters
    ----------
    raw_depth, fused_depth : (H, W) ndarray
        Depth in mm, NaN = invalid.
    depth_range : (near, far), optional
        Depth (mm) mapped to the ends of the colour map (default: 2nd-98th percentile of raw).

    Returns
    -------
    (H, 2W, 3) ndarray of uint8
    """
    import cv2

    if depth_range is None:
        depth_range = display_range(raw_depth) or (0.0, 1.0)
    near, far = depth_range
    scale = 255.0 / max(far - near, 1e-6)
    panels = []
    for d in (raw_depth, fused_depth):
        v = np.clip((np.nan_to_num(d, nan=near) - near) * scale, 0, 255).astype(np.uint8)
        img = cv2.applyColorMap(v, cv2.COLORMAP_TURBO)
        img[~np.isfinite(d)] = 0
        panels.append(img)
    return np.concatenate(panels, axis=1)


class LiveWriter:
    """A sink that writes the fused frames: a frame folder, an FFV1 ``.mkv``, a ``.zarr``
    store (streamed, as ``fuse4d run``), or an ``.npz`` (kept in memory, written at the end).

    Parameters
    ----------
    path : path-like
        Output; its suffix picks the format.
    intrinsics : Intrinsics
        Camera of the frames.
    depth_unit_mm : float, optional
        Millimetres per stored unit for 16-bit outputs (default 1 mm).
    fps : float, optional
        Frame rate stored with the output.
    overwrite : bool
        Replace an existing output.
    behind : int
        Streamed outputs: encode and write in a background thread, at most ``behind`` frames
        queued (the fusion thread blocks when the queue is full: no output frame is dropped),
        so PNG/FFV1 encoding overlaps the next fusion step; 0 writes in the caller's thread.
        The latency of :func:`run_live` then ends when the frame is queued for writing.
    warn_coarse_unit : bool
        As for :class:`~fuse4d.io.FrameFolderWriter`: False where ``depth_unit_mm`` is the
        camera's own unit (``fuse4d live``).
    sensor : str, optional
        The camera kind (``"tof"``, ...), stored with the output as ``fuse4d run`` does.
    """

    def __init__(
        self,
        path: str | PathLike[str],
        intrinsics: Intrinsics,
        *,
        depth_unit_mm: float | None = None,
        fps: float | None = None,
        overwrite: bool = False,
        behind: int = 2,
        warn_coarse_unit: bool = True,
        sensor: str | None = None,
    ) -> None:
        from .io import check_output
        from .io.api import output_layout, stream_writer

        self.behind = int(behind)
        self._sink: Any = None
        self._submitted = 0  # frames queued for the writer thread
        #: seconds spent writing (in the writer thread) and waiting for room in its queue
        self.timings = {"write": 0.0, "io_wait": 0.0}
        self.path = Path(path)
        self.intrinsics = intrinsics
        self.fps = fps
        self.sensor = sensor
        self.overwrite = overwrite
        self._frames: list[tuple[np.ndarray, np.ndarray, float | None]] | None = None
        self._writer: Any = None
        if output_layout(self.path) == "npz":
            check_output(self.path, overwrite=overwrite)
            self._frames = []
        else:
            cls, _ = stream_writer(self.path)
            self._writer = cls(
                self.path,
                intrinsics,
                depth_unit_mm=depth_unit_mm or 1.0,
                fps=fps,
                overwrite=overwrite,
                warn_coarse_unit=warn_coarse_unit,
                sensor=sensor,
            )

    def __enter__(self) -> Self:
        if self._writer is not None:
            self._writer.__enter__()
            if self.behind > 0:
                from .run import _WriteBehind

                self._sink = _WriteBehind(self._writer.write, self.behind, self.timings)
        return self

    def __call__(self, captured: CapturedFrame, fused: FusedFrame) -> None:
        """Write one output frame (fused depth, the raw intensity, mask, timestamp and, but
        for an .mkv or .npz, the per-pixel source codes and confidence)."""
        if self._frames is not None:
            self._frames.append((fused.depth.copy(), captured.intensity, captured.timestamp))
            return
        args = (fused.depth, captured.intensity)
        kwargs = {"mask": captured.mask, "timestamp": captured.timestamp}
        if self._writer.stores_flags and getattr(fused, "source", None) is not None:
            kwargs.update(source=fused.source, confidence=fused.confidence)
        if self._sink is not None:
            self._sink.submit(*args, **kwargs)  # FusedFrame arrays are not reused by the engine
            self._submitted += 1
            if self._submitted == LOWER_AFTER_FRAMES:  # (causal: as many frames fused)
                self._sink.lower_priority()
        else:
            self._writer.write(*args, **kwargs)

    def __exit__(self, *exc: object) -> None:
        if self._writer is not None:
            sink, self._sink = self._sink, None
            if sink is not None:
                try:
                    with _signals.held():
                        sink.close(abort=exc[0] is not None)
                except BaseException:
                    with _signals.held():  # (close's error): the writes end first
                        sink.close(abort=True)
                    self._writer.__exit__(*sys.exc_info())
                    raise
            try:
                self._writer.__exit__(*exc)
            except BaseException:
                if exc[0] is None:  # (a Ctrl-C as it finished): discard the staged output
                    self._writer.__exit__(*sys.exc_info())
                raise
            return
        if exc[0] is not None:
            return
        if not self._frames:  # as the streamed writers say (it exited 0 naming no file)
            raise ParameterError(f"{self.path}: no frame was written")
        from .io import save_sequence
        from .sequence import Sequence

        ts = [t for _, _, t in self._frames]
        seq = Sequence(
            depth=np.stack([d for d, _, _ in self._frames]),
            intensity=np.stack([i for _, i, _ in self._frames]),
            intrinsics=self.intrinsics,
            timestamps=None if any(t is None for t in ts) else np.asarray(ts, np.float64),
            fps=self.fps,
            sensor=self.sensor,
        )
        save_sequence(seq, self.path, overwrite=self.overwrite)
