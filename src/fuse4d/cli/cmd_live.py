"""CLI command ``live``: causal fusion of a RealSense camera or a recording played in real time."""

from __future__ import annotations

import contextlib
import math
import threading
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from ._app import app, eprint, fail, out_console
from ._fusion_opts import FlowMethodOpt, FlowParamOpt, PresetOpt, SetOpt
from ._recording_opts import (
    CameraOverrideOpt,
    DepthTopicOpt,
    DepthUnitOpt,
    IntensityOpt,
    IntensityTopicOpt,
    NoUndistortOpt,
    reader_options,
)

__all__ = ["live_command"]


@app.command("live")
def live_command(
    ctx: typer.Context,
    input_path: Annotated[
        Path | None,
        typer.Argument(
            metavar="INPUT",
            help="A recording to play back (any layout fuse4d run reads). Omitted: the first "
            "attached RealSense camera.",
            show_default=False,
        ),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option("-o", "--output", help="Write the fused frames: folder, .mkv, .zarr or .npz."),
    ] = None,
    show: Annotated[
        bool, typer.Option("--show", help="Raw | fused side by side in a window (q quits).")
    ] = False,
    realtime: Annotated[
        bool,
        typer.Option(
            "--realtime",
            help="Play a recording at its recorded rate (timestamps, or --fps), dropping frames "
            "when the fusion falls behind. Without it: as fast as possible, nothing dropped.",
        ),
    ] = False,
    fps: Annotated[
        float | None,
        typer.Option(
            "--fps", help="Playback rate (frames/s; implies --realtime), or the camera's rate."
        ),
    ] = None,
    preset_name: PresetOpt = "fast",
    window: Annotated[
        int | None, typer.Option("--window", help="Frames fused per output frame (causal).")
    ] = None,
    config: Annotated[
        Path | None, typer.Option("--config", help="TOML file with fusion and flow tables.")
    ] = None,
    sets: SetOpt = None,
    flow_method: FlowMethodOpt = None,
    flow_params: FlowParamOpt = None,
    queue_size: Annotated[
        int,
        typer.Option("--queue", help="Frames waiting for the fusion at most (oldest dropped)."),
    ] = 2,
    on_gap: Annotated[
        str,
        typer.Option(
            "--on-gap",
            help="After a dropped frame: restart (new window and flow warm start) or track "
            "(across the gap as if consecutive).",
        ),
    ] = "restart",
    decimate: Annotated[
        int,
        typer.Option(
            "--decimate",
            help="Fuse at 1/N of the resolution (N x N blocks, as the RealSense decimation "
            "filter: lower median of the valid depths for N = 2-3, mean for 4-8); 1 = off.",
        ),
    ] = 1,
    max_frames: Annotated[
        int | None, typer.Option("--frames", help="Stop after this many frames.")
    ] = None,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds.")
    ] = None,
    width: Annotated[
        int | None, typer.Option("--width", help="Camera: stream width (px). [default: 640]")
    ] = None,
    height: Annotated[
        int | None, typer.Option("--height", help="Camera: stream height (px). [default: 480]")
    ] = None,
    serial: Annotated[
        str | None, typer.Option("--serial", help="Camera: serial number of the device.")
    ] = None,
    delay_ms: Annotated[
        float,
        typer.Option("--simulate-delay-ms", help="Extra ms per fusion step (test overload)."),
    ] = 0.0,
    overlap_flow: Annotated[
        bool,
        typer.Option(
            "--overlap-flow/--no-overlap-flow",
            help="Compute each frame's flow in a worker thread while the frame is filtered "
            "(same output).",
        ),
    ] = True,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing output.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
    depth_topic: DepthTopicOpt = None,
    intensity_topic: IntensityTopicOpt = None,
    intensity: IntensityOpt = None,
    no_undistort: NoUndistortOpt = False,
    depth_unit_mm: DepthUnitOpt = None,
    intrinsics: CameraOverrideOpt = None,
) -> None:
    """Fuse a camera or a recording live (causal engine, bounded queue); report fps and latency.

    Frames go through a queue of --queue frames; when the fusion falls behind, the oldest
    waiting frame is dropped, so latency stays bounded. At a gap the engine restarts (its
    window and flow warm start begin again) unless --on-gap track.
    """
    from ..decimate import MAX_DECIMATION
    from ..errors import ParameterError
    from ..live import (
        DecimatedSource,
        LiveWriter,
        RealSenseSource,
        RecordingSource,
        _stop_on_signals,
        display_problem,
        realsense_available,
        run_live,
    )
    from .cmd_fuse import _given, _resolve, print_json

    if on_gap not in ("restart", "track"):
        fail(f"--on-gap must be restart or track, got {on_gap!r}")
    if queue_size < 1:
        fail(f"--queue must be >= 1, got {queue_size}")
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        fail(f"--fps must be a number > 0, got {fps}")
    if max_frames is not None and max_frames < 1:
        fail(f"--frames must be >= 1, got {max_frames}")
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        fail(f"--duration must be a number of seconds > 0, got {duration}")
    if not (math.isfinite(delay_ms) and delay_ms >= 0):
        fail(f"--simulate-delay-ms must be >= 0, got {delay_ms}")
    camera_only = {"--width": width, "--height": height, "--serial": serial}
    if input_path is not None and any(v is not None for v in camera_only.values()):
        given = ", ".join(k for k, v in camera_only.items() if v is not None)
        fail(f"{given}: for a camera; {input_path} is a recording, played at its own size")
    for name, value in (("--width", width), ("--height", height)):
        if value is not None and value < 1:
            fail(f"{name} must be >= 1 px, got {value}")
    if not 1 <= decimate <= MAX_DECIMATION:
        fail(f"--decimate must be 1..{MAX_DECIMATION}, got {decimate}")
    if input_path is None and fps is not None and fps != int(fps):
        fail(f"--fps: a camera streams at a whole number of frames per second, got {fps:g}")
    fusion, flow, _ = _resolve(
        preset_name,
        config,
        window,
        True,
        sets,
        flow_method,
        flow_params,
        preset_given=bool(_given(ctx, "preset_name")),
    )
    if input_path is None:
        if not realsense_available():
            fail("no RealSense camera attached; give a recording to play back")
        source: Any = RealSenseSource(
            width=width or 640, height=height or 480, fps=int(fps or 30), serial=serial
        )
        realtime = True
    else:
        options = reader_options(
            depth_topic, intensity_topic, intensity, no_undistort,
            depth_unit_mm=depth_unit_mm, intrinsics=intrinsics,
        )  # fmt: skip
        realtime = realtime or fps is not None
        source = RecordingSource(input_path, realtime=realtime, fps=fps, **options)
    if decimate > 1:
        try:
            source = DecimatedSource(source, decimate)
        except ParameterError as exc:
            source.close()
            fail(f"{'camera' if input_path is None else input_path}: --decimate {decimate}: {exc}")
    sinks: list[Any] = []
    stop = threading.Event()
    # Ctrl-C stops the run (run_live) and then lets the output be finished: outside this
    # guard, one while the .npz was saved (or a stream flushed) threw the whole run away
    with _stop_on_signals(stop) as signals, contextlib.ExitStack() as stack:
        stack.callback(source.close)
        if output is not None:
            from ..io import check_output

            check_output(output, overwrite=force, inputs=[] if input_path is None else [input_path])
            writer = LiveWriter(
                output,
                source.intrinsics,
                depth_unit_mm=source.depth_unit_mm,
                fps=source.output_fps,
                overwrite=force,
                # the camera's own unit: no "coarse unit" warning (see QuantizationReport)
                warn_coarse_unit=source.depth_unit_mm is None,
                sensor=getattr(source, "sensor", None),
            )
            sinks.append(stack.enter_context(writer))
        no_window = display_problem() if show else None
        if no_window:
            eprint(f"fuse4d live: {no_window}: --show skipped")
        elif show:
            sinks.append(_window_sink(stop))
            stack.callback(_close_windows)

        def sink(captured: Any, fused: Any) -> None:
            for s in sinks:
                s(captured, fused)

        eprint(
            "fuse4d live: "
            + ("camera" if input_path is None else str(input_path))
            + (f" at {source.pace}" if realtime and source.pace else "")
            + (
                f", decimated {decimate}x to {source.intrinsics.width}x{source.intrinsics.height}"
                if decimate > 1
                else ""
            )
            + f", window {fusion.num_frames} (causal), queue {queue_size}, Ctrl-C stops"
        )
        stats = run_live(
            source,
            fusion=fusion,
            flow=flow,
            queue_size=queue_size,
            on_gap=on_gap,  # type: ignore[arg-type]
            sink=sink if sinks else None,
            max_frames=max_frames,
            duration_s=duration,
            stop=stop,
            block=not realtime,
            extra_delay_s=delay_ms / 1000.0,
            overlap_flow=overlap_flow,
        )
    stats.interrupted = stats.interrupted or signals.interrupted  # (while finishing)
    summary = {
        "input": "camera" if input_path is None else str(input_path),
        "output": None if output is None else str(output),
        "window": fusion.num_frames,
        "decimate": decimate,
        "size": [source.intrinsics.width, source.intrinsics.height],
        "flow_method": flow.method,
        "realtime": realtime,
        # the recording's own rate (None where not known) and the rate it was played at
        # (--fps): "source 10 fps" was said of a 30 Hz recording played with --fps 10
        "source_fps": _recorded_fps(source, fps if input_path is not None else None),
        "playback_fps": source.fps if realtime else None,
        "queue": queue_size,
        "on_gap": on_gap,
        "overlap_flow": overlap_flow,
        **stats.to_dict(),
    }
    advice = _overload_advice(summary)
    if advice:
        eprint(advice)
    if as_json:
        print_json(summary)
    else:
        out_console.print(_table(summary))
    if stats.source_error:  # the camera failed mid-run: what was fused is written, exit 2
        kept = (
            f"; the {stats.frames_fused} frames fused before it are in {output}" if output else ""
        )
        eprint(f"fuse4d: error: {stats.source_error}{kept}")
        raise typer.Exit(2)


def _recorded_fps(source: Any, playback_fps: float | None) -> float | None:
    """The frame rate of the recording (or camera) itself, frames/s; None where it is not
    known. ``playback_fps``: the ``--fps`` a recording is played at (None: not given)."""
    # fuse4d's sources say it (recorded_fps); another FrameSource played at its own rate is
    # its own fps, and one played at --fps does not say
    return getattr(source, "recorded_fps", source.fps if playback_fps is None else None)


#: Dropped frames (fraction of the captured ones) above which ``fuse4d live`` says what to do.
OVERLOAD_DROP_FRACTION = 0.1


def _overload_advice(s: dict[str, Any]) -> str | None:
    """A few lines for stderr when the fusion could not keep up (None when it did)."""
    captured, dropped = s["frames_captured"], s["dropped"]
    if not captured or dropped <= OVERLOAD_DROP_FRACTION * captured:
        return None
    head = (
        f"fuse4d live: the fusion fell behind: {dropped} of {captured} frames dropped "
        f"({_rate(s['fps'])} fps fused of {_rate(s['input_fps'])} in); each output fused "
        f"{s['mean_window']:.1f} of up to {s['window']} frames on average"
    )
    lines = [head]
    if s["on_gap"] == "restart" and s["mean_window"] < 0.6 * s["window"]:
        lines.append(
            "  every drop restarts the window, so little was fused: --on-gap track keeps "
            "fusing across drops"
        )
    if s["decimate"] == 1:
        lines.append("  --decimate 2 fuses at half resolution, about 3x the rate (docs/live.md)")
    if s["window"] > 3:
        lines.append(f"  a smaller --window (now {s['window']}) costs less per frame")
    return "\n".join(lines)


def _rate(fps: float | None) -> str:
    """A measured rate (frames/s) for the summary: "n/a" where it could not be measured."""
    return "n/a" if fps is None or not math.isfinite(fps) else f"{fps:.1f}"


def _window_sink(stop: Any) -> Any:
    """A sink showing raw | fused depth in an OpenCV window; q or Esc sets ``stop``."""
    import cv2

    from ..live import display_range, side_by_side

    scale: list[Any] = []  # the colour scale of the first frame with depth, kept (steady, cheap)

    def sink(captured: Any, fused: Any) -> None:
        if not scale:
            lo_hi = display_range(captured.depth)
            if lo_hi is not None:
                scale.append(lo_hi)
        image = side_by_side(captured.depth, fused.depth, scale[0] if scale else None)
        cv2.imshow("fuse4d live: raw | fused", image)
        if cv2.waitKey(1) & 0xFF in (ord("q"), 27):
            stop.set()

    return sink


def _close_windows() -> None:
    import cv2

    cv2.destroyAllWindows()


def _table(s: dict[str, Any]) -> Table:
    lat = s["latency_ms"]
    table = Table(title=f"fuse4d live: {s['input']}", show_header=False)
    table.add_column("")
    table.add_column("")
    rows = [
        (
            "window",
            (
                f"{s['window']} frames (causal), flow {s['flow_method']}; "
                f"{s['mean_window']:.2f} frames fused per output on average"
            ),
        ),
        (
            "size",
            f"{s['size'][0]}x{s['size'][1]}"
            + (f" (decimated {s['decimate']}x)" if s["decimate"] > 1 else ""),
        ),
        (
            "frames",
            f"{s['frames_captured']} captured, {s['frames_fused']} fused, {s['dropped']} dropped"
            + (f", {s['unfused_at_stop']} not fused at the stop" if s["unfused_at_stop"] else "")
            + (" (stopped by Ctrl-C or a signal)" if s["interrupted"] else ""),
        ),
        (
            "gaps",
            f"{s['gaps']} ({s['restarts']} engine restarts, {s['tracked_gaps']} tracked across)",
        ),
        (
            "rate",
            f"{_rate(s['fps'])} fps fused, {_rate(s['input_fps'])} fps in"
            + (f" (source {s['source_fps']:g} fps)" if s["source_fps"] else "")
            + (
                f" (played at {s['playback_fps']:g} fps)"
                if s["playback_fps"] and s["playback_fps"] != s["source_fps"]
                else ""
            ),
        ),
        (
            "latency",
            "n/a"
            if not lat
            else f"p50 {lat['p50']:.0f} ms, p95 {lat['p95']:.0f} ms, max {lat['max']:.0f} ms "
            "(capture to output)",
        ),
        (
            "fusion step",
            "n/a" if not s["step_ms"] else f"{s['step_ms']['p50']:.0f} ms (median)",
        ),
        ("time", f"{s['seconds']:.1f} s"),
    ]
    if s["output"]:
        rows.append(("output", s["output"]))
    for key, value in rows:
        table.add_row(key, value)
    return table
