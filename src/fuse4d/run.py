"""File-to-file fusion: read any layout that :mod:`fuse4d.io` reads, fuse, write the same kind.

``.npz`` input gives ``.npz`` output (``depth`` = fused depth in mm, plus the input's other keys,
the ``support``/``filled``/``source``/``confidence`` arrays and the run's parameters as the JSON
text :data:`NPZ_PARAMS_KEY`); every folder layout gives a frame folder of 16-bit PNG with
the input's depth unit, written frame by frame while the input streams in, so memory does not
grow with the recording's length.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from . import _signals
from ._background import LOWER_AFTER_FRAMES, BackgroundLoop
from .camera import depth_to_points
from .config import FlowConfig, FusionParams, fusion_params, preset
from .errors import ParameterError
from .flying_pixels import resolve_flying_pixels
from .fusion import STAGES, FusedFrame, FusionEngine, fuse_sequence
from .holes import _SourceTally
from .io import check_output, detect_format, open_frames, read_npz_extra
from .io import write_npz as _write_npz
from .io._base import FrameSelection
from .io.api import output_layout, stream_writer
from .io.resume import ResumableFolderWriter, partial_path, run_identity
from .metrics import RunningEvaluation

__all__ = ["IO_STAGES", "SUMMARY_EVERY", "RunSummary", "fuse_file"]

#: Timings of the streaming run outside the engine's :data:`~fuse4d.fusion.STAGES` (seconds):
#: ``read`` (decode, in the read-ahead thread), ``write`` (encode, in the write-behind thread),
#: ``summary`` (the before/after quality tally), ``io_wait`` (the fusion thread waiting for a
#: frame or for room in the write queue: the part of the I/O that did not overlap).
IO_STAGES = ("read", "write", "summary", "io_wait")

#: Key of an ``.npz`` output that holds the run's parameters, JSON text
#: ``{"fusion": FusionParams.to_dict(), "flow": {"method", "params"[, "roi"]}}``: what a
#: folder output's manifest records (its identity's ``fusion`` and ``flow``).
NPZ_PARAMS_KEY = "fuse4d_params"

#: ``fuse4d run``'s summary scores the roughness on one frame in this many (the two Eq. 7 maps
#: of a 640x480 frame cost almost as much as its fusion stage); the flicker on every frame.
SUMMARY_EVERY = 4


@dataclass
class RunSummary:
    """What :func:`fuse_file` did, with before/after quality figures.

    Attributes
    ----------
    input, output : Path
    input_format, output_format : str
    frames : int
        Frames of the output (all of them, those of an interrupted run continued with
        ``resume`` included).
    shape : (int, int)
    flow_method : str
    params : FusionParams
    raw_roughness, fused_roughness : float
        Mean over frames of the frame-mean roughness (Eq. 7 on n x n windows, n =
        ``roughness_window``; mm) of raw and fused, on the same pixels: the default ROI of the
        raw frame (n x n window fully valid, no step between neighbours above the noise
        model's step limit max(10 mm, 2.5 q z^2)) where Eq. 7 is defined in both
        (:class:`~fuse4d.metrics.RunningEvaluation`).
    raw_rms_residual, fused_rms_residual : float
        The same for the RMS plane-fit residual of the n x n window (mm): "spatial precision".
    roughness_window : int
        n (px): the side of the windows of the roughness and the plane-fit residual.
    raw_flicker, fused_flicker : float
        Mean frame-to-frame |Δ| of the depth (mm) on static pixels (detected from the raw
        video: valid in every frame, depth range over time within 3 step limits).
    roughness_pixels, static_pixels : int
        Pixels the roughness (summed over frames) and the flicker were scored on.
    roughness_frames : int
        Frames the roughness and the residual were scored on: one in ``summary_every``
        (:data:`SUMMARY_EVERY` by default), from the first frame fused now; the flicker uses
        every frame fused now. The quality figures cover the frames fused in this session
        (:attr:`frames_fused`): those of the interrupted run a ``resume`` continued are not
        read back.
    support_fraction : float
        Fraction of valid pixels tracked into at least one other frame.
    filled_fraction : float
        Fraction of the raw-valid pixels whose output came from Eq. 6's hole filling
        (pixels where the fusion found too little support), not sensor holes filled.
    rejected_fraction : float
        Fraction of the raw-valid pixels removed as ToF flying pixels (A36; left empty).
    hole_fraction : float
        Fraction of all pixels (x frames) without raw depth: the sensor's holes.
    hole_outside_fraction : float
        Fraction of those holes outside the sensor's field of view (A38: the band a
        registered depth image leaves around the colour image; never filled).
    hole_time_fraction, hole_space_fraction : float
        Fraction of the holes inside the field of view filled from other frames along the
        track (A26) / in space from one side of the depth edges (A27).
    seconds : float
        Wall time of this call (I/O included): of this session only where ``resume``
        continued an interrupted run (the manifest's ``seconds`` add the sessions up,
        :func:`fuse4d.io.resume.run_seconds`).
    frames_resumed : int
        Frames already written by the interrupted run that ``resume`` continued (not fused
        now; all of them where :attr:`already_complete`); 0 for a run from the start.
    already_complete : bool
        ``resume`` found the output finished by an earlier run of the same input, options and
        versions: nothing was fused now (the quality figures are NaN).
    first_output_seconds : float
        Wall time from the start until the first fused frame was handed to the writer: the
        start-up (opening the input, loading the compiled kernels, engine buffers) and the
        first window's frames (s; NaN when no frame was fused now).
    steady_ms_per_frame : float
        Wall time per fused frame once running, I/O included (ms): between the hand-overs of
        the first and the last frame that followed a new input frame (a centred window's last
        ``future_frames`` come out of the flush, cheaper); NaN with fewer than two such frames
        or ``iterations`` > 1. The rate of a long run; :attr:`ms_per_frame` also carries the
        start-up, which dominates a short clip (10 frames of a 640x480 recording: about 1 s
        of start-up on 2 cores).
    timings : dict
        Seconds per pipeline stage (of this session); ``"setup"`` (streaming runs) is the
        one-off time of opening the reader and the writer, building and closing the engine
        and closing the writer, not a per-frame stage; ``"flow_worker"`` (the flow overlapped
        in its own thread) is the flow's own time there, beside ``"flow"`` (the wait for it):
        not additive with the other stages.
    """

    input: Path
    output: Path
    input_format: str
    output_format: str
    frames: int
    shape: tuple[int, int]
    flow_method: str
    params: FusionParams
    raw_roughness: float = float("nan")
    fused_roughness: float = float("nan")
    raw_rms_residual: float = float("nan")
    fused_rms_residual: float = float("nan")
    raw_flicker: float = float("nan")
    fused_flicker: float = float("nan")
    roughness_pixels: int = 0
    roughness_frames: int = 0
    roughness_window: int = 5
    static_pixels: int = 0
    support_fraction: float = float("nan")
    filled_fraction: float = float("nan")
    rejected_fraction: float = float("nan")
    hole_fraction: float = float("nan")
    hole_outside_fraction: float = float("nan")
    hole_time_fraction: float = float("nan")
    hole_space_fraction: float = float("nan")
    seconds: float = 0.0
    frames_resumed: int = 0
    already_complete: bool = False
    first_output_seconds: float = float("nan")
    steady_ms_per_frame: float = float("nan")
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def frames_fused(self) -> int:
        """Frames fused and written in this session: :attr:`frames` less
        :attr:`frames_resumed`."""
        return self.frames - self.frames_resumed

    @property
    def ms_per_frame(self) -> float:
        """Wall time per frame fused in this session in ms, start-up included (see
        :attr:`steady_ms_per_frame`); NaN where none was (:attr:`already_complete`)."""
        if self.frames_fused <= 0:
            return float("nan")
        return 1000.0 * self.seconds / self.frames_fused

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        return {
            "input": str(self.input),
            "output": str(self.output),
            "input_format": self.input_format,
            "output_format": self.output_format,
            "frames": self.frames,
            "shape": list(self.shape),
            "flow_method": self.flow_method,
            "params": self.params.to_dict(),
            "raw_roughness_mm": self.raw_roughness,
            "fused_roughness_mm": self.fused_roughness,
            "raw_rms_residual_mm": self.raw_rms_residual,
            "fused_rms_residual_mm": self.fused_rms_residual,
            "raw_flicker_mm": self.raw_flicker,
            "fused_flicker_mm": self.fused_flicker,
            "roughness_pixels": self.roughness_pixels,
            "roughness_frames": self.roughness_frames,
            "roughness_window": self.roughness_window,
            "static_pixels": self.static_pixels,
            "support_fraction": self.support_fraction,
            "filled_fraction": self.filled_fraction,
            "rejected_fraction": self.rejected_fraction,
            "hole_fraction": self.hole_fraction,
            "hole_outside_fraction": self.hole_outside_fraction,
            "hole_time_fraction": self.hole_time_fraction,
            "hole_space_fraction": self.hole_space_fraction,
            "seconds": self.seconds,
            "frames_fused": self.frames_fused,
            "frames_resumed": self.frames_resumed,
            "already_complete": self.already_complete,
            "ms_per_frame": self.ms_per_frame,
            "first_output_seconds": self.first_output_seconds,
            "steady_ms_per_frame": self.steady_ms_per_frame,
            # per frame fused now: the resumed frames took none of this session's time
            "timings_ms_per_frame": {
                k: 1000.0 * v / self.frames_fused if self.frames_fused > 0 else float("nan")
                for k, v in self.timings.items()
                if k != "setup"
            },
            "setup_ms": 1000.0 * self.timings["setup"] if "setup" in self.timings else None,
        }


def _as_stored(frame: FusedFrame, unit_mm: float) -> FusedFrame:
    """``frame`` with its depth as a 16-bit file stores it: rounded to ``unit_mm`` (each
    point moved along its ray), 0 (NaN) where out of range."""
    from .io._images import depth_to_units

    stored = depth_to_units(frame.depth, unit_mm).astype(np.float32) * np.float32(unit_mm)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(stored > 0, stored / frame.depth, np.nan).astype(np.float32)
    return dataclasses.replace(frame, points=frame.points * scale[..., None])


class _QualityTally:
    """Before/after scores over streamed frames (:class:`~fuse4d.metrics.RunningEvaluation`)
    plus the fusion's own support and fill fractions."""

    def __init__(self, every: int = 1, total_frames: int | None = None) -> None:
        self.scores = RunningEvaluation(every=every, total_frames=total_frames)
        self.valid = 0
        self.supported = 0
        self.filled = 0
        self.pixels = 0
        self.sources = _SourceTally()

    def add(
        self,
        raw_points: np.ndarray,
        frame: FusedFrame,
        noise_quad: float | None = None,
        noise_sigma: float | None = None,
    ) -> None:
        from ._kernels.tally import FILLED, SOURCES, SUPPORTED, VALID, _frame_counts_kernel

        self.scores.add(raw_points, frame.points, noise_quad=noise_quad, noise_sigma=noise_sigma)
        raw_depth = raw_points[..., 2]
        counts = np.zeros(SOURCES + len(self.sources.counts), np.int64)
        codes = frame.source if frame.source is not None else np.zeros((0, 0), np.uint8)
        _frame_counts_kernel(raw_depth, frame.support, frame.filled, codes, counts)
        self.valid += int(counts[VALID])
        self.supported += int(counts[SUPPORTED])
        self.filled += int(counts[FILLED])
        self.pixels += raw_depth.size
        if frame.source is not None:
            self.sources.add_counts(counts[SOURCES:], raw_depth.size, int(counts[VALID]))

    def fill(self, summary: RunSummary) -> None:
        res = self.scores.result()
        summary.raw_roughness = res["raw_roughness"]
        summary.fused_roughness = res["output_roughness"]
        summary.raw_rms_residual = res["raw_rms_residual"]
        summary.fused_rms_residual = res["output_rms_residual"]
        summary.raw_flicker = res["raw_flicker"]
        summary.fused_flicker = res["output_flicker"]
        summary.roughness_pixels = res["roughness_pixels"]
        summary.roughness_frames = res["roughness_frames"]
        summary.roughness_window = self.scores.window
        summary.static_pixels = res["static_pixels"]
        if self.valid:
            summary.support_fraction = self.supported / self.valid
            summary.filled_fraction = self.filled / self.valid
        if self.pixels:
            summary.hole_fraction = (self.pixels - self.valid) / self.pixels
        for name, share in self.sources.shares().items():
            if share is not None:
                setattr(summary, name, share)


def fuse_file(
    input: str | PathLike[str],
    output: str | PathLike[str],
    *,
    fusion: FusionParams | None = None,
    flow: FlowConfig | None = None,
    overwrite: bool = False,
    quality: bool = True,
    progress: Callable[[int, int], None] | None = None,
    reader_options: dict[str, Any] | None = None,
    resume: bool = False,
    io_queue: int = 2,
    summary_every: int = SUMMARY_EVERY,
    frames: FrameSelection = None,
) -> RunSummary:
    """Fuse a recording on disk and write the result next to nothing it reads.

    Parameters
    ----------
    input : path
        ``.npz``, frame folder, TUM folder, cv2-xml or frames-json layout (see
        ``docs/formats.md``).
    output : path
        ``.npz`` for npz input; otherwise a frame folder, or by suffix an FFV1 ``.mkv`` depth
        video or a ``.zarr`` store. Written under a temporary name and renamed into place at
        the end, so a failed run leaves nothing half-written.
    fusion, flow : optional
        Parameters (default: the "fast" preset).
    overwrite : bool
        Replace an existing output (never the input).
    quality : bool
        Compute the before/after roughness (costs ~2 roughness maps per scored frame);
        ``False`` leaves the summary's quality figures NaN (``fuse4d run --no-summary``).
    summary_every : int
        With ``quality``: score the roughness on one frame in ``summary_every`` (frames 0,
        n, 2n, ...; raw and fused on the same frames and pixels; 1 = all frames). The flicker
        is scored on every frame. :attr:`RunSummary.roughness_frames` says how many.
    io_queue : int
        Streaming layouts: frames decoded ahead by a reader thread and frames queued for a
        writer thread, each (bounded queues, so memory stays flat); 0 reads and writes in the
        fusion thread.
    progress : callable, optional
        ``progress(done, total)`` per output frame.
    reader_options : dict, optional
        Passed to :func:`~fuse4d.io.open_frames` (``depth_topic``, ``intensity``,
        ``depth_unit_mm``, ``intrinsics``, ...) for camera recordings.
    resume : bool
        Folder output only: continue the unfinished run in ``output.partial`` (left by a
        killed or interrupted run; see :mod:`fuse4d.io.resume`). The result equals an
        uninterrupted run bit for bit; the quality figures cover the frames fused now. Where
        ``output`` holds this run finished already (same input, options and versions), nothing
        is done (:attr:`RunSummary.already_complete`).
    frames : slice, range, (start, stop) or "A:B", optional
        Fuse only this contiguous part of the recording, as if it were the whole (the output
        has its frames, numbered from 0; ``fuse4d run --frames``). Default: all frames.

    Returns
    -------
    RunSummary
    """
    params = fusion_params(fusion)
    src = Path(input)
    dst = Path(output)
    fmt = detect_format(src)
    # (a --resume of a finished run writes nothing: its folder is not tried)
    check_output(dst, overwrite=overwrite or resume, inputs=[src], probe=not resume)
    check_output(partial_path(dst), overwrite=True, inputs=[src], probe=not resume)
    layout = output_layout(dst)  # refuses a file suffix fuse4d does not write (out.mp4)
    if fmt == "npz" and layout != "npz":
        raise ParameterError(f"{dst}: npz input is written as .npz; give an output ending in .npz")
    if fmt != "npz" and layout == "npz":
        raise ParameterError(
            f"{dst}: {fmt} input is written as a frame folder, .mkv or .zarr; not .npz"
        )
    if resume and fmt == "npz":
        raise ParameterError("--resume applies to frame-folder outputs; .npz is written at once")
    start = time.perf_counter()
    clock = _OutputClock(progress)
    if fmt == "npz":
        summary = _fuse_npz(
            src, dst, params, flow, overwrite, quality, clock, summary_every, frames,
            reader_options or {},
        )  # fmt: skip
    else:
        options = dict(reader_options or {})
        if frames is not None:
            options["frames"] = frames
        summary = _fuse_streaming(
            src,
            dst,
            fmt,
            params,
            flow,
            overwrite,
            quality,
            clock,
            options,
            resume=resume,
            io_queue=io_queue,
            summary_every=summary_every,
        )
    summary.seconds = time.perf_counter() - start
    clock.fill(summary, start)
    return summary


class _OutputClock:
    """``fuse_file``'s progress callback: passes each call on to the user's ``progress`` and
    notes when each fused frame was handed over (perf_counter s, one float a frame)."""

    def __init__(self, progress: Callable[[int, int], None] | None) -> None:
        self.progress = progress
        self.times: list[float] = []

    def __call__(self, done: int, total: int) -> None:
        self.times.append(time.perf_counter())
        if self.progress is not None:
            self.progress(done, total)

    def fill(self, summary: RunSummary, start: float) -> None:
        """Set ``summary``'s first-output time and steady rate (run started at ``start``).

        The steady rate is taken over the frames that each followed the push of a new input
        frame: the last ``future_frames`` of a centred window come out of the engine's flush
        without a new frame's flow and filtering, and would make a short clip look faster
        than a long run. Not set for ``iterations`` > 1 (several passes over the frames)."""
        if not self.times:
            return
        summary.first_output_seconds = self.times[0] - start
        summary.steady_ms_per_frame = self.steady_ms(summary.params)

    def steady_ms(self, params: FusionParams) -> float:
        """Wall time per frame (ms) over the frames that followed a push (see :meth:`fill`);
        NaN for fewer than two of them or ``iterations`` > 1."""
        # (a clip shorter than the look-ahead has no frame that followed a push: none left,
        # where a negative stop kept all but the last)
        pushed = self.times[: max(0, len(self.times) - params.future_frames)]
        if params.iterations == 1 and len(pushed) > 1:
            return 1000.0 * (pushed[-1] - pushed[0]) / (len(pushed) - 1)
        return float("nan")


def _fuse_npz(
    src,
    dst,
    params,
    flow,
    overwrite,
    quality,
    progress,
    summary_every=SUMMARY_EVERY,
    frames=None,
    reader_options=None,
) -> RunSummary:
    from .io import load_sequence

    # (an .npz takes no recording options: open_frames refuses any given, they were ignored)
    seq = load_sequence(src, frames=frames, **(reader_options or {}))
    params = resolve_flying_pixels(params, seq.sensor)  # A36
    result = fuse_sequence(
        seq.depth, seq.intensity, seq.intrinsics, fusion=params, flow=flow, progress=progress
    )
    summary = RunSummary(
        input=src,
        output=dst,
        input_format="npz",
        output_format="npz",
        frames=seq.num_frames,
        shape=seq.shape,
        flow_method=result.flow_method,
        params=params,
        timings=result.timings,
    )
    if quality:
        tally = _QualityTally(summary_every, seq.num_frames)
        raw_points = seq.points()
        for t in range(seq.num_frames):
            frame = FusedFrame(
                t,
                result.points[t],
                result.support[t],
                result.filled[t],
                np.zeros(seq.shape, bool),
                source=result.source[t],
            )
            tally.add(raw_points[t], frame)
        tally.fill(summary)
    extra = read_npz_extra(src, frames=frames)
    record = {"fusion": params.to_dict(), "flow": _flow_record(_flow_config(flow))}
    extra.update(
        {
            "support": result.support,
            "filled": result.filled,
            "source": result.source,
            "confidence": result.confidence,
            NPZ_PARAMS_KEY: np.str_(json.dumps(record, sort_keys=True, default=str)),
        }
    )
    _write_npz(seq.with_depth(result.depth), dst, extra=extra, overwrite=overwrite)
    return summary


class _ReadAhead:
    """Iterate ``frames`` in a daemon thread, at most ``depth`` items ahead of the consumer.

    Decoding (OpenCV, PNG, video) releases the GIL, and so do the numba kernels, so frame
    t + 1 is read while frame t fuses. An exception of the reader is raised in the consumer.
    Seconds spent producing items accumulate in ``timings["read"]``. The thread is a
    :class:`~fuse4d._background.BackgroundLoop`: :meth:`lower_priority` lets the fusion's
    kernels go first, and a wait of :data:`~fuse4d._background.STARVED_S` for a frame
    (:meth:`~fuse4d._background.BackgroundLoop.wait`) hands the reading back to a
    normal-priority thread.
    """

    _END = object()

    def __init__(
        self,
        frames: Iterable[Any],
        depth: int,
        timings: dict[str, float],
        group: list[BackgroundLoop] | None = None,
    ) -> None:
        self._queue: queue.Queue = queue.Queue(maxsize=max(depth, 1))
        self._stop = threading.Event()
        self._timings = timings
        self._frames = iter(frames)
        self._worker = BackgroundLoop(self._run, "fuse4d-read", group)

    def _put(self, item: Any) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self, worker: BackgroundLoop) -> None:
        try:
            while not self._stop.is_set():
                if worker.handing_over():
                    return  # the next thread goes on with the next frame
                t0 = time.perf_counter()
                try:
                    item = next(self._frames)
                except StopIteration:
                    break
                self._timings["read"] += time.perf_counter() - t0
                if not self._put((True, item)):
                    worker.done = True
                    return
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            self._put((False, exc))
            worker.done = True
            return
        self._put((True, self._END))
        worker.done = True

    def lower_priority(self) -> None:
        """Let the fusion go first (:meth:`~fuse4d._background.BackgroundLoop.lower_priority`)."""
        self._worker.lower_priority()

    def __iter__(self) -> Iterator[Any]:
        while True:
            t0 = time.perf_counter()
            ok, item = self._worker.wait(lambda timeout: self._queue.get(timeout=timeout))
            self._timings["io_wait"] += time.perf_counter() - t0
            if not ok:
                raise item
            if item is self._END:
                return
            yield item

    def close(self) -> None:
        """Stop the thread (it may be blocked on a full queue) and wait for it."""
        self._stop.set()
        self._worker.join()


class _WriteBehind:
    """Run ``write(*args, **kwargs)`` calls in a daemon thread, in order, at most ``depth``
    queued; the first exception of the writer is raised by the next :meth:`submit` or by
    :meth:`close`. Seconds spent writing accumulate in ``timings["write"]``. The thread is a
    :class:`~fuse4d._background.BackgroundLoop`, as :class:`_ReadAhead`'s (a wait of
    :data:`~fuse4d._background.STARVED_S` for room in the queue hands it back)."""

    def __init__(
        self,
        write: Callable[..., Any],
        depth: int,
        timings: dict[str, float],
        group: list[BackgroundLoop] | None = None,
    ) -> None:
        self._write = write
        self._queue: queue.Queue = queue.Queue(maxsize=max(depth, 1))
        self._timings = timings
        self._error: BaseException | None = None
        self._abort = False
        self._taken: Any = None  # a job taken by a thread that then handed over
        self._worker = BackgroundLoop(self._run, "fuse4d-write", group)

    def _run(self, worker: BackgroundLoop) -> None:
        while True:
            if worker.handing_over():
                return
            if self._taken is not None:
                job, self._taken = self._taken, None
            else:
                job = self._queue.get()
            if job is None:
                worker.done = True
                return
            if worker.handing_over():
                self._taken = job  # the next thread runs it
                return
            if self._error is not None or self._abort:
                continue  # drain after a failure or an interrupt
            t0 = time.perf_counter()
            try:
                job[0](*job[1], **job[2])
            except BaseException as exc:  # noqa: BLE001 - re-raised in the fusion thread
                self._error = exc
            self._timings["write"] += time.perf_counter() - t0

    def lower_priority(self) -> None:
        """Let the fusion go first (:meth:`~fuse4d._background.BackgroundLoop.lower_priority`)."""
        self._worker.lower_priority()

    def _put(self, job: Any) -> None:
        self._worker.wait(lambda timeout: self._queue.put(job, timeout=timeout))

    def submit(self, *args: Any, **kwargs: Any) -> None:
        """Queue ``write(*args, **kwargs)``."""
        self.call(self._write, *args, **kwargs)

    def call(self, func: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """Queue ``func(*args, **kwargs)``, run after every job queued before it."""
        if self._error is not None:
            raise self._error
        t0 = time.perf_counter()
        self._put((func, args, kwargs))
        self._timings["io_wait"] += time.perf_counter() - t0

    def close(self, abort: bool = False) -> None:
        """Wait for the queued writes; raise the writer's exception, if any.

        ``abort`` (the fusion thread failed or was interrupted): drop the writes not yet
        started, wait for the one in progress, raise nothing (the caller's exception wins).
        """
        self._abort = abort
        self._put(None)
        with _signals.held():  # an interrupted join let the abort delete under a write
            self._worker.join()
        if self._error is not None and not abort:
            raise self._error


class _Inline:
    """The single-thread stand-in of :class:`_WriteBehind` (``io_queue=0``)."""

    def __init__(self, write: Callable[..., Any], timings: dict[str, float]) -> None:
        self._write = write
        self._timings = timings

    def submit(self, *args: Any, **kwargs: Any) -> None:
        self.call(self._write, *args, **kwargs)

    def call(self, func: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        t0 = time.perf_counter()
        func(*args, **kwargs)
        self._timings["write"] += time.perf_counter() - t0

    def close(self, abort: bool = False) -> None:
        pass


def _timed(frames: Iterable[Any], timings: dict[str, float]) -> Iterator[Any]:
    """``frames`` with the time spent producing each one added to ``timings["read"]``."""
    it = iter(frames)
    while True:
        t0 = time.perf_counter()
        try:
            item = next(it)
        except StopIteration:
            return
        timings["read"] += time.perf_counter() - t0
        yield item


def _fuse_streaming(
    src,
    dst,
    fmt,
    params,
    flow,
    overwrite,
    quality,
    progress,
    options,
    *,
    resume: bool = False,
    io_queue: int = 2,
    limit: int | None = None,
    summary_every: int = SUMMARY_EVERY,
) -> RunSummary:
    """The streaming run; ``limit`` fuses the first ``limit`` frames only (``fuse4d bench
    --input``)."""
    if params.iterations != 1:
        raise ParameterError(
            "iterations > 1 needs the whole sequence in memory; convert the input to .npz first "
            "(fuse4d convert INPUT INPUT.npz)"
        )
    timings = dict.fromkeys(STAGES + IO_STAGES, 0.0)
    setup_start = time.perf_counter()  # timings["setup"]: reader, writer, engine; closing
    writer_cls, out_fmt = stream_writer(dst)
    with open_frames(src, **options) as reader:
        params = resolve_flying_pixels(params, reader.sensor)  # A36
        total = len(reader) if limit is None else min(limit, len(reader))
        source = reader if limit is None else itertools.islice(reader, total)
        k = reader.intrinsics
        flow_config = _flow_config(flow)
        if "frames" in options:  # one spelling of the range for the manifest: "A:B"
            options = {**options, "frames": f"{reader.first_frame}:{reader.first_frame + total}"}
        identity = run_identity(
            src,
            frames=total,
            reader_options=options,
            shape=(k.height, k.width),
            depth_unit_mm=reader.depth_unit_mm,
            fusion=params.to_dict(),
            flow=_flow_record(flow_config),
        )
        summary = RunSummary(
            input=src,
            output=dst,
            input_format=fmt,
            output_format=out_fmt,
            frames=total,
            shape=(k.height, k.width),
            flow_method=flow_config.method,
            params=params,
            timings=timings,
        )
        unit = reader.depth_unit_mm or 1.0  # float-depth inputs (32FC1 bags, zarr): 1 mm steps
        # written back in the input's own unit: no "coarse unit" warning (the input already
        # had that precision; the smoothed output is less noisy than it on near surfaces)
        warn_coarse = reader.depth_unit_mm is None
        # the summary scores what is written: a frame folder or .mkv stores depth in whole
        # units (the input's), and the float result scored 27 % smoother than its files
        stored_unit = unit if out_fmt in ("folder", "mkv") else None
        resumable = out_fmt == "folder"
        if resumable:
            writer = ResumableFolderWriter(
                dst,
                k,
                identity=identity,
                depth_unit_mm=unit,
                fps=reader.fps,
                overwrite=overwrite,
                resume=resume,
                warn_coarse_unit=warn_coarse,
                sensor=reader.sensor,  # a ToF recording's output stays one (A36), as convert's
            )
        else:
            if resume:
                raise ParameterError(
                    f"{dst}: --resume continues folder outputs (and .zarr with --engine dask); "
                    f"a {out_fmt} output is written in one go"
                )
            writer = writer_cls(
                dst,
                k,
                depth_unit_mm=unit,
                fps=reader.fps,
                overwrite=overwrite,
                warn_coarse_unit=warn_coarse,
                sensor=reader.sensor,
            )
        if resumable and writer.already_complete:  # --resume of a finished run: nothing to do
            summary.already_complete = True
            summary.frames_resumed = total
            return summary
        with writer:
            # Resume = restart the (deterministic) engine `past` frames before the checkpoint,
            # warm-started with the flow stored there; frames before it only fill the window.
            restart = writer.restart_frame if resumable else 0
            first = max(0, restart - params.past_frames)
            engine = FusionEngine(
                k,
                fusion=params,
                flow=flow_config,
                timings=timings,
                initial_flow=writer.seed if resumable and first > 0 else None,
                # the flow beside the frame's filtering, the same output bit for bit (closed
                # below); with the I/O threads lowered this is faster (fuse4d._background)
                overlap_flow=io_queue > 0,
            )
            timings["setup"] = time.perf_counter() - setup_start
            pending: dict[int, Any] = {}  # raw frames waiting for their fused output
            written = 0
            # random access only when resuming; recordings are read in stream order
            todo = source if first == 0 else (reader.read_frame(t) for t in range(first, total))
            background: tuple[Any, ...] = ()  # the I/O threads (lowered once fusion runs)
            if io_queue > 0:
                group: list[BackgroundLoop] = []  # one starved thread promotes both
                frames: Any = _ReadAhead(todo, io_queue, timings, group)
                # a resumable folder's checkpoints are queued behind the writes they follow, so
                # a checkpoint on disk only ever names frames already on disk
                sink: Any = _WriteBehind(writer.write, io_queue, timings, group)
                background = (frames, sink)
            else:
                frames = _timed(todo, timings)
                sink = _Inline(writer.write, timings)

            # per-pixel source codes and confidence go with the depth where the writer stores them
            stores_flags = writer.stores_flags
            # frames handed to the writer (the writer thread's `frames_done` lags behind it)
            queued = writer.frames_done if resumable else 0
            summary.frames_resumed = queued  # on disk already: neither fused nor scored now
            # the summary scores the frames fused now (the resumed ones are not read back)
            tally = _QualityTally(summary_every, total - queued) if quality else None

            def emit(fused: list[FusedFrame]) -> None:
                nonlocal written, queued
                for fr in fused:
                    t = first + fr.index
                    raw = pending.pop(t)
                    if resumable and t < queued:  # before the checkpoint / already on disk
                        continue
                    if tally is not None:
                        t0 = time.perf_counter()
                        # q of the raw depth: the engine's (the same estimator). σ₀ not: the
                        # engine's is measured against its quad-aware reference (5.3 mm on
                        # uva, against 0.19 mm for `fuse4d metrics`), which let the turning
                        # person pass as static and raised the summary's flicker by a third
                        quad = engine.input_noise_quad(fr.index)
                        scored = fr if stored_unit is None else _as_stored(fr, stored_unit)
                        tally.add(depth_to_points(raw.depth, k), scored, quad, None)
                        timings["summary"] += time.perf_counter() - t0
                    flags = (
                        {"source": fr.source, "confidence": fr.confidence} if stores_flags else {}
                    )
                    sink.submit(
                        fr.depth, raw.intensity, mask=raw.mask, timestamp=raw.timestamp, **flags
                    )
                    written += 1
                    queued += 1
                    if resumable and queued % writer.checkpoint_every == 0 and queued < total:
                        # the seed is the engine's state now; the writer stores it after frame
                        # `queued - 1` is on disk
                        seed = _seed(engine, first, queued - engine.past, writer.seed)
                        sink.call(writer.checkpoint, seed)
                    if progress is not None:
                        progress(queued, total)

            try:
                for order, frame in enumerate(frames):
                    pending[first + order] = frame
                    emit(engine.push(frame.depth, frame.intensity))
                    if order + 1 == LOWER_AFTER_FRAMES:
                        for thread in background:
                            thread.lower_priority()
                emit(engine.flush())
            except BaseException:
                frames.close()
                sink.close(abort=True)  # Ctrl-C or a failure: only the write in progress ends
                raise
            finally:
                t0 = time.perf_counter()
                engine.close()  # the flow worker thread
                timings["setup"] += time.perf_counter() - t0
            frames.close()  # the read-ahead thread, or the inline generator
            sink.close()  # all writes done before the writer is closed
            if resumable and isinstance(progress, _OutputClock):  # for a later report
                writer.set_steady_rate(progress.steady_ms(params))
            closing = time.perf_counter()
        timings["setup"] += time.perf_counter() - closing  # the writer's close (rename)
        if tally is not None:
            t0 = time.perf_counter()
            tally.fill(summary)
            timings["summary"] += time.perf_counter() - t0
    return summary


def _flow_config(flow: FlowConfig | str | None) -> FlowConfig:
    """The tracker the engine will use (same rule as :class:`FusionEngine`)."""
    if isinstance(flow, str):
        return FlowConfig(flow)
    return flow or preset("fast").flow


def _flow_record(flow: FlowConfig) -> dict[str, Any]:
    """What an output records of its tracker: method, parameters and ROI (the ROI too, as
    ``--engine dask``'s: a resume with another ``--flow-roi`` mixed the two)."""
    return {
        "method": flow.method,
        "params": flow.params,
        **({"roi": list(flow.roi)} if flow.roi else {}),
    }


def _seed(engine: FusionEngine, first: int, start: int, seed: np.ndarray | None):
    """Warm start for an engine that starts at frame ``start``: the flow of pair
    (start - 1, start) (``seed`` if that is the pair before ``engine``'s first frame), or
    None at the start of the recording and for a window of one frame (no flow is computed, so
    none warms a resumed engine; the pair would not even have been pushed yet)."""
    if start <= 0 or engine.past + engine.future == 0:
        return None
    if start == first:
        return seed
    return engine.forward_flow(start - first)
