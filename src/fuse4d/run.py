"""File-to-file fusion: read any layout that :mod:`fuse4d.io` reads, fuse, write the same kind.

``.npz`` input gives ``.npz`` output (``depth`` = fused depth in mm, plus the input's other keys
and ``support``/``filled`` arrays); every folder layout gives a frame folder of 16-bit PNG with
the input's depth unit, written frame by frame while the input streams in, so memory does not
grow with the recording's length.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from .camera import depth_to_points
from .config import FlowConfig, FusionParams, preset
from .errors import ParameterError
from .fusion import STAGES, FusedFrame, FusionEngine, fuse_sequence
from .io import check_output, detect_format, open_frames, read_npz_extra
from .io import write_npz as _write_npz
from .io.resume import ResumableFolderWriter, partial_path, run_identity
from .metrics import RunningEvaluation

__all__ = ["RunSummary", "fuse_file"]


@dataclass
class RunSummary:
    """What :func:`fuse_file` did, with before/after quality figures.

    Attributes
    ----------
    input, output : Path
    input_format, output_format : str
    frames : int
    shape : (int, int)
    flow_method : str
    params : FusionParams
    raw_roughness, fused_roughness : float
        Mean over frames of the frame-mean roughness (Eq. 7, 5x5, mm) of raw and fused, on
        the same pixels: the default ROI of the raw frame (5x5 window fully valid, no step
        between neighbours above the noise model's step limit max(10 mm, 2.5 q z^2)) where
        Eq. 7 is defined in both (:class:`~fuse4d.metrics.RunningEvaluation`).
    raw_rms_residual, fused_rms_residual : float
        The same for the RMS plane-fit residual of the 5x5 window (mm): "spatial precision".
    raw_flicker, fused_flicker : float
        Mean frame-to-frame |Δ| of the depth (mm) on static pixels (detected from the raw
        video: valid in every frame, depth range over time within 3 step limits).
    roughness_pixels, static_pixels : int
        Pixels the roughness (summed over frames) and the flicker were scored on.
    support_fraction : float
        Fraction of valid pixels tracked into at least one other frame.
    filled_fraction : float
        Fraction of the raw-valid pixels whose output came from Eq. 6's hole filling
        (pixels where the fusion found too little support), not sensor holes filled.
    seconds : float
        Wall time of the whole run (I/O included).
    timings : dict
        Seconds per pipeline stage.
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
    static_pixels: int = 0
    support_fraction: float = float("nan")
    filled_fraction: float = float("nan")
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def ms_per_frame(self) -> float:
        """Wall time per frame in ms."""
        return 1000.0 * self.seconds / max(self.frames, 1)

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
            "static_pixels": self.static_pixels,
            "support_fraction": self.support_fraction,
            "filled_fraction": self.filled_fraction,
            "seconds": self.seconds,
            "ms_per_frame": self.ms_per_frame,
            "timings_ms_per_frame": {
                k: 1000.0 * v / max(self.frames, 1) for k, v in self.timings.items()
            },
        }


class _QualityTally:
    """Before/after scores over streamed frames (:class:`~fuse4d.metrics.RunningEvaluation`)
    plus the fusion's own support and fill fractions."""

    def __init__(self) -> None:
        self.scores = RunningEvaluation()
        self.valid = 0
        self.supported = 0
        self.filled = 0

    def add(self, raw_points: np.ndarray, frame: FusedFrame) -> None:
        self.scores.add(raw_points, frame.points)
        valid = np.isfinite(raw_points[..., 2])
        self.valid += int(valid.sum())
        self.supported += int((frame.support[valid] > 0).sum())
        self.filled += int(frame.filled[valid].sum())

    def fill(self, summary: RunSummary) -> None:
        res = self.scores.result()
        summary.raw_roughness = res["raw_roughness"]
        summary.fused_roughness = res["output_roughness"]
        summary.raw_rms_residual = res["raw_rms_residual"]
        summary.fused_rms_residual = res["output_rms_residual"]
        summary.raw_flicker = res["raw_flicker"]
        summary.fused_flicker = res["output_flicker"]
        summary.roughness_pixels = res["roughness_pixels"]
        summary.static_pixels = res["static_pixels"]
        if self.valid:
            summary.support_fraction = self.supported / self.valid
            summary.filled_fraction = self.filled / self.valid


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
        Compute the before/after roughness (costs ~2 roughness maps per frame).
    progress : callable, optional
        ``progress(done, total)`` per output frame.
    reader_options : dict, optional
        Passed to :func:`~fuse4d.io.open_frames` (``depth_topic``, ``intensity``,
        ``depth_unit_mm``, ``intrinsics``, ...) for camera recordings.
    resume : bool
        Folder output only: continue the unfinished run in ``output.partial`` (left by a
        killed or interrupted run; see :mod:`fuse4d.io.resume`). The result equals an
        uninterrupted run bit for bit; the quality figures cover the frames fused now.

    Returns
    -------
    RunSummary
    """
    params = fusion or FusionParams()
    src = Path(input)
    dst = Path(output)
    fmt = detect_format(src)
    check_output(dst, overwrite=overwrite or resume, inputs=[src])
    check_output(partial_path(dst), overwrite=True, inputs=[src])
    if fmt == "npz" and dst.suffix.lower() != ".npz":
        raise ParameterError(f"{dst}: npz input is written as .npz; give an output ending in .npz")
    if fmt != "npz" and dst.suffix.lower() == ".npz":
        raise ParameterError(
            f"{dst}: {fmt} input is written as a frame folder, .mkv or .zarr; not .npz"
        )
    if resume and fmt == "npz":
        raise ParameterError("--resume applies to frame-folder outputs; .npz is written at once")
    start = time.perf_counter()
    if fmt == "npz":
        summary = _fuse_npz(src, dst, params, flow, overwrite, quality, progress)
    else:
        summary = _fuse_streaming(
            src, dst, fmt, params, flow, overwrite, quality, progress, reader_options or {}, resume
        )
    summary.seconds = time.perf_counter() - start
    return summary


def _fuse_npz(src, dst, params, flow, overwrite, quality, progress) -> RunSummary:
    from .io import load_sequence

    seq = load_sequence(src)
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
        tally = _QualityTally()
        raw_points = seq.points()
        for t in range(seq.num_frames):
            frame = FusedFrame(
                t, result.points[t], result.support[t], result.filled[t], np.zeros(seq.shape, bool)
            )
            tally.add(raw_points[t], frame)
        tally.fill(summary)
    extra = read_npz_extra(src)
    extra.update({"support": result.support, "filled": result.filled})
    _write_npz(seq.with_depth(result.depth), dst, extra=extra, overwrite=overwrite)
    return summary


def _fuse_streaming(
    src, dst, fmt, params, flow, overwrite, quality, progress, options, resume=False
) -> RunSummary:
    if params.iterations != 1:
        raise ParameterError(
            "iterations > 1 needs the whole sequence in memory; convert the input to .npz first"
        )
    timings = dict.fromkeys(STAGES, 0.0)
    writer_cls, out_fmt = _writer_for(dst)
    with open_frames(src, **options) as reader:
        total = len(reader)
        k = reader.intrinsics
        flow_config = _flow_config(flow)
        identity = run_identity(
            src,
            frames=total,
            shape=(k.height, k.width),
            depth_unit_mm=reader.depth_unit_mm,
            fusion=params.to_dict(),
            flow={"method": flow_config.method, "params": flow_config.params},
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
        tally = _QualityTally() if quality else None
        unit = reader.depth_unit_mm or 1.0  # float-depth inputs (32FC1 bags, zarr): 1 mm steps
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
            )
        else:
            if resume:
                raise ParameterError(
                    f"{dst}: --resume continues folder outputs (and .zarr with --engine dask); "
                    f"a {out_fmt} output is written in one go"
                )
            writer = writer_cls(dst, k, depth_unit_mm=unit, fps=reader.fps, overwrite=overwrite)
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
            )
            pending: dict[int, Any] = {}  # raw frames waiting for their fused output
            written = 0

            def emit(frames: list[FusedFrame]) -> None:
                nonlocal written
                for fr in frames:
                    t = first + fr.index
                    raw = pending.pop(t)
                    if resumable and t < writer.frames_done:  # before the checkpoint / on disk
                        continue
                    if tally is not None:
                        tally.add(depth_to_points(raw.depth, k), fr)
                    writer.write(fr.depth, raw.intensity, mask=raw.mask, timestamp=raw.timestamp)
                    written += 1
                    if resumable and writer.wants_checkpoint() and writer.frames_done < total:
                        start = writer.frames_done - engine.past
                        writer.checkpoint(_seed(engine, first, start, writer.seed))
                    if progress is not None:
                        progress(writer.frames_done if resumable else written, total)

            # random access only when resuming; recordings are read in stream order
            frames = (
                enumerate(reader)
                if first == 0
                else ((t, reader.read_frame(t)) for t in range(first, total))
            )
            for t, frame in frames:
                pending[t] = frame
                emit(engine.push(frame.depth, frame.intensity))
            emit(engine.flush())
        if tally is not None:
            tally.fill(summary)
    return summary


def _writer_for(dst: Path) -> tuple[type, str]:
    """Streaming writer by output suffix: ``.mkv`` FFV1 video, ``.zarr`` store, else folder."""
    from .io import DepthVideoWriter, FrameFolderWriter, ZarrWriter

    suffix = dst.suffix.lower()
    if suffix == ".mkv":
        return DepthVideoWriter, "mkv"
    if suffix == ".zarr":
        return ZarrWriter, "zarr"
    return FrameFolderWriter, "folder"


def _flow_config(flow: FlowConfig | str | None) -> FlowConfig:
    """The tracker the engine will use (same rule as :class:`FusionEngine`)."""
    if isinstance(flow, str):
        return FlowConfig(flow)
    return flow or preset("fast").flow


def _seed(engine: FusionEngine, first: int, start: int, seed: np.ndarray | None):
    """Warm start for an engine that starts at frame ``start``: the flow of pair
    (start - 1, start) (``seed`` if that is the pair before ``engine``'s first frame), or
    None at the start of the recording."""
    if start <= 0:
        return None
    if start == first:
        return seed
    return engine.forward_flow(start - first)
