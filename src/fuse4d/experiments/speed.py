"""Speed and memory benchmark of the fusion pipeline (``fuse4d bench``).

Measures, on the synthetic falling ball (or any :class:`~fuse4d.Sequence` in memory), the wall
time per output frame of each stage (flow, bilateral, motion reference, tracking, fusion, fill)
in the streaming engine, after a warm-up run that compiles the numba kernels, and the peak
resident memory of the process; or
(:func:`benchmark_recording`, ``fuse4d bench --input``) a real recording end to end through
``fuse4d run``'s streaming path, reading, writing and the summary included as stages. Both
time the centred engine or, with ``causal=True`` (``fuse4d bench --causal``), the causal one
(every frame fused with its n - 1 predecessors, as ``fuse4d live``), stage by stage alike.

One rule for both: :attr:`BenchResult.ms_per_frame` is the steady cost per frame, the
one-off set-up and tear-down (building the engine's buffers and closing it; for a recording
also opening the reader and the writer and closing them) apart in
:attr:`BenchResult.setup_ms`.
"""

from __future__ import annotations

import contextlib
import gc
import math
import resource
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Intrinsics
from ..config import FlowConfig, FusionParams
from ..config import preset as get_preset
from ..errors import ParameterError
from ..flying_pixels import resolve_flying_pixels
from ..fusion import STAGES, FusionEngine
from ..sequence import Sequence
from ..synthetic import make_falling_ball

__all__ = ["BenchResult", "benchmark_pipeline", "benchmark_recording"]


@dataclass
class BenchResult:
    """One benchmark run.

    Attributes
    ----------
    preset, flow_method : str
    size : (int, int)
        Frame shape (H, W).
    frames : int
        Frames timed (after the warm-up).
    window : int
        Frames fused per output frame (configured; with fewer ``frames`` than it no output
        fuses more than ``frames``, and the benchmark warns).
    causal : bool
        The causal engine (no look-ahead) instead of the centred one.
    ms_per_frame : float
        Steady wall time per output frame, ms: from the engine built to the last frame out
        (flows included; for a recording also the I/O and the summary), the one-off
        ``setup_ms`` excluded in both modes.
    stage_ms : dict
        ms per frame of each stage. For a recording also ``read`` / ``write`` (decode and
        encode, in their own threads, overlapping the fusion), ``summary`` (before/after
        tally) and ``io_wait`` (fusion waiting on I/O). With the flow overlapped (a
        recording), ``flow`` is only the fusion's wait for the flow worker thread.
    setup_ms : float
        One-off set-up and tear-down, ms in all (not per frame): building the engine (its
        ring buffers) and closing it; for a recording also opening the reader and the writer
        and closing them. NaN where the run did not measure it (``ms_per_frame`` then
        includes it).
    warmup_s : float
        Wall time of the warm-up run (numba compilation or cache load included).
    peak_rss_mb : float
        Peak resident set size of the process during the timed run, MiB (Linux: the
        kernel's high-water mark reset before it; elsewhere the process's peak so far). It
        includes the frames held in memory (``input_mb``).
    input_mb : float
        The timed frames held in memory (depth and intensity, MiB; 0 for a recording, read
        frame by frame).
    """

    preset: str
    flow_method: str
    size: tuple[int, int]
    frames: int
    window: int
    ms_per_frame: float
    stage_ms: dict[str, float] = field(default_factory=dict)
    warmup_s: float = 0.0
    peak_rss_mb: float = 0.0
    input: str = ""
    input_mb: float = 0.0
    causal: bool = False
    setup_ms: float = 0.0

    @property
    def us_per_pixel(self) -> float:
        """Wall time per output pixel (µs): compares frame sizes."""
        return 1000.0 * self.ms_per_frame / (self.size[0] * self.size[1])

    @property
    def wall_ms_per_frame(self) -> float:
        """Wall time per output frame with the one-off ``setup_ms`` spread over the frames
        (ms): the whole run's."""
        setup = self.setup_ms if math.isfinite(self.setup_ms) else 0.0
        return self.ms_per_frame + setup / max(self.frames, 1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        return {
            "preset": self.preset,
            "flow_method": self.flow_method,
            "size": list(self.size),
            "frames": self.frames,
            "window": self.window,
            "causal": self.causal,
            "ms_per_frame": self.ms_per_frame,
            "setup_ms": self.setup_ms,
            "wall_ms_per_frame": self.wall_ms_per_frame,
            "stage_ms": self.stage_ms,
            "warmup_s": self.warmup_s,
            "peak_rss_mb": self.peak_rss_mb,
            "input_mb": self.input_mb,
            "input": self.input,
            "us_per_pixel": self.us_per_pixel,
            "covers": FIGURES,
        }


#: What each figure of :meth:`BenchResult.to_dict` covers (``fuse4d bench --json``).
FIGURES = {
    "ms_per_frame": "steady wall ms per frame: engine built to last frame out, setup excluded",
    "setup_ms": "one-off ms in all: engine built and closed (a recording: reader and writer "
    "opened and closed too)",
    "wall_ms_per_frame": "ms_per_frame + setup_ms / frames: the whole run per frame",
    "stage_ms": "ms per frame of each stage, setup excluded; read/write overlap the fusion in "
    "their own threads; with the flow overlapped (--input) flow is the wait for its worker "
    "and flow_worker the flow's own time in that thread (beside the others: not additive)",
    "us_per_pixel": "ms_per_frame per pixel, microseconds",
}


def _peak_rss_mb() -> float:
    """Peak RSS (MiB) since :func:`_reset_peak_rss` (Linux), else of the process so far."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0  # kB
    except (OSError, ValueError, IndexError):
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


def _reset_peak_rss() -> None:
    """Reset the kernel's peak-RSS mark of this process (Linux >= 4.0), so that the peak
    reported is the timed run's: it was the process's, and grew with ``--frames`` by the
    whole synthetic scene (ground truth included) rendered before the run."""
    with contextlib.suppress(OSError):
        Path("/proc/self/clear_refs").write_text("5")


def _window_warning(window: int, frames: int) -> None:
    """Warn that a run of ``frames`` frames never reaches a ``window``-frame window."""
    if frames < window:
        warnings.warn(
            f"window {window} is longer than the {frames} frames timed: no output fuses more "
            f"than {frames} frames; time at least {window} frames (--frames) for the steady "
            f"state of a {window}-frame window",
            stacklevel=3,
        )


def _engine(
    intrinsics: Intrinsics,
    fusion: FusionParams,
    flow: FlowConfig,
    timings: dict[str, float] | None = None,
) -> FusionEngine:
    """The engine of the synthetic bench; its buffers not fitting in memory are a
    :class:`ParameterError` naming the window and the frame size."""
    try:
        return FusionEngine(intrinsics, fusion=fusion, flow=flow, timings=timings)
    except MemoryError:
        raise ParameterError(
            f"window={fusion.num_frames} (--window): the engine's buffers for a "
            f"{fusion.num_frames}-frame window of {intrinsics.width}x{intrinsics.height} px "
            "frames do not fit in memory; use a smaller window"
        ) from None


def benchmark_pipeline(
    preset: str = "fast",
    *,
    small: bool = False,
    num_frames: int = 18,
    window: int = 9,
    causal: bool = False,
    sequence: Sequence | None = None,
) -> BenchResult:
    """Time the streaming engine on the synthetic ball (or on ``sequence``, in memory).

    Parameters
    ----------
    preset : {"fast", "paper"}
    small : bool
        Use the 150x150 CI scene instead of 600x600.
    num_frames : int
        Frames pushed through the engine in the timed run (>= window for steady state; a
        warning otherwise).
    window : int
        ``num_frames`` of the fusion (frames fused per output).
    causal : bool
        Time the causal engine (``FusionParams(causal=True)``: each frame fused with the
        ``window - 1`` previous ones, emitted as soon as it is pushed).
    sequence : Sequence, optional
        Frames to time instead of the ball (its first ``num_frames``; ``small`` is ignored):
        a loaded recording's compute alone, without the reading and writing of
        :func:`benchmark_recording`.

    Returns
    -------
    BenchResult
        ``ms_per_frame`` from the engine built to its flush; building and closing the engine
        in ``setup_ms``.

    Raises
    ------
    ParameterError
        No frame to time, or the ball or the engine's buffers do not fit in memory.
    """
    chosen = get_preset(preset)
    try:
        seq = (
            make_falling_ball(small=small, num_frames=num_frames) if sequence is None else sequence
        )
    except MemoryError:  # rendered whole, with its ground truth (--frames 100000000)
        raise ParameterError(
            f"num_frames={num_frames}: the synthetic ball of that many frames does not fit in "
            "memory; time fewer frames"
        ) from None
    # A36 as `fuse4d run` decides it for the recording's camera (the ball: none, "off")
    fusion = resolve_flying_pixels(
        chosen.fusion.replace(num_frames=window, causal=causal), seq.sensor
    )
    # the timed frames only (views of depth and intensity): the scene's ground truth, freed
    # with ``seq``, is not part of the run
    depth = np.ascontiguousarray(seq.depth[:num_frames])
    intensity = np.ascontiguousarray(seq.intensity[:num_frames])
    intrinsics, shape = seq.intrinsics, seq.shape
    del seq
    frames = list(zip(depth, intensity, strict=True))
    if not frames:
        raise ParameterError("benchmark_pipeline: the sequence has no frame to time")

    _window_warning(window, len(frames))

    def run_once() -> tuple[float, float, dict[str, float]]:
        """(steady seconds, setup seconds, stage seconds) of one timed run."""
        timings = dict.fromkeys(STAGES, 0.0)
        setup_start = time.perf_counter()
        engine = _engine(intrinsics, fusion, chosen.flow, timings)
        start = time.perf_counter()
        emitted = 0
        for depth, intensity in frames:
            emitted += len(engine.push(depth, intensity))
        emitted += len(engine.flush())
        end = time.perf_counter()
        engine.close()
        setup = (start - setup_start) + (time.perf_counter() - end)
        return end - start, setup, timings

    warm_start = time.perf_counter()
    engine = _engine(intrinsics, fusion, chosen.flow)
    for d, i in frames[: min(3, len(frames))]:
        engine.push(d, i)
    engine.flush()
    engine.close()
    del engine  # (its ring buffers are not part of the timed run's memory)
    warmup = time.perf_counter() - warm_start
    gc.collect()
    _reset_peak_rss()
    seconds, setup, timings = run_once()
    n = len(frames)
    return BenchResult(
        preset=preset,
        flow_method=chosen.flow.method,
        size=shape,
        frames=n,
        window=window,
        ms_per_frame=1000.0 * seconds / n,
        stage_ms={k: 1000.0 * v / n for k, v in timings.items()},
        warmup_s=warmup,
        peak_rss_mb=_peak_rss_mb(),
        causal=causal,
        input_mb=(depth.nbytes + intensity.nbytes) / 2**20,
        setup_ms=1000.0 * setup,
    )


def benchmark_recording(
    path: str | Path,
    preset: str = "fast",
    *,
    num_frames: int | None = 30,
    window: int = 9,
    summary: bool = True,
    reader_options: dict[str, Any] | None = None,
    causal: bool = False,
) -> BenchResult:
    """Time ``fuse4d run`` on a recording, end to end, stage by stage (I/O included).

    The streaming path of :func:`fuse4d.run.fuse_file` (read-ahead and write-behind threads)
    writes a frame folder into a temporary directory; a warm-up run on 3 frames compiles or
    loads the numba kernels first.

    Parameters
    ----------
    path : path
        A recording in any layout :func:`fuse4d.io.open_frames` reads (not ``.npz``).
    preset : {"fast", "paper"}
    num_frames : int or None
        Frames timed from the start of the recording (None: all).
    window : int
        ``num_frames`` of the fusion.
    summary : bool
        Include the before/after quality tally (``fuse4d run``'s default) as a stage.
    reader_options : dict, optional
        Passed to :func:`~fuse4d.io.open_frames`.
    causal : bool
        Time the causal engine (``fuse4d run --causal``) instead of the centred one.

    Returns
    -------
    BenchResult
        ``ms_per_frame`` without the one-off ``setup_ms`` (opening the reader and the writer,
        building the engine, closing them: ``timings["setup"]`` of the streaming run), as
        :func:`benchmark_pipeline`'s.
    """
    from ..io import detect_format
    from ..run import _fuse_streaming

    if num_frames is not None and num_frames < 1:
        raise ParameterError(f"num_frames must be >= 1 (or None: all), got {num_frames}")
    chosen = get_preset(preset)
    fusion = chosen.fusion.replace(num_frames=window, causal=causal)
    src = Path(path)
    fmt = detect_format(src)
    if fmt == "npz":
        raise ParameterError(
            f"{src}: bench --input times the streaming path of `fuse4d run`, and an .npz is "
            "read whole into memory, not streamed; give a recording (frame folder, .zarr, "
            f".mkv, ROS bag, ...), e.g. `fuse4d convert {src} {src.with_suffix('.zarr')}`"
        )
    common = {
        "src": src,
        "fmt": fmt,
        "params": fusion,
        "flow": chosen.flow,
        "overwrite": False,
        "quality": summary,
        "progress": None,
        "options": dict(reader_options or {}),
    }
    with tempfile.TemporaryDirectory(prefix="fuse4d-bench-") as tmp:
        warm_start = time.perf_counter()
        _fuse_streaming(**common, dst=Path(tmp) / "warm", limit=3)
        warmup = time.perf_counter() - warm_start
        _reset_peak_rss()
        start = time.perf_counter()
        run = _fuse_streaming(**common, dst=Path(tmp) / "out", limit=num_frames)
        seconds = time.perf_counter() - start
    n = max(run.frames, 1)
    _window_warning(window, run.frames)
    timings = dict(run.timings)
    # the one-off set-up and tear-down, where the streaming run measured it (NaN: not
    # measured, and left in ms_per_frame)
    setup = timings.pop("setup", math.nan)
    steady = seconds - setup if math.isfinite(setup) else seconds
    return BenchResult(
        preset=preset,
        flow_method=run.flow_method,
        size=run.shape,
        frames=run.frames,
        window=window,
        ms_per_frame=1000.0 * steady / n,
        setup_ms=1000.0 * setup,
        stage_ms={k: 1000.0 * v / n for k, v in timings.items()},
        warmup_s=warmup,
        peak_rss_mb=_peak_rss_mb(),
        input=str(src),
        causal=causal,
    )
