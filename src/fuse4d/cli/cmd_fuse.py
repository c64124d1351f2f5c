"""CLI commands: ``run`` (fuse a recording), ``bench`` (speed/memory), ``demo``."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from ._app import (
    app,
    err_console,
    fail,
    out_console,
    progress_bar,
    progress_callback,
    user_values,
)
from ._fusion_opts import FlowMethodOpt, FlowParamOpt, PresetOpt, SetOpt
from ._recording_opts import (
    CameraOverrideOpt,
    DepthTopicOpt,
    DepthUnitOpt,
    IntensityOpt,
    IntensityTopicOpt,
    NoUndistortOpt,
    frame_range,
    reader_options,
)

#: What the columns of the ``demo`` table mean.
QUALITY_CAPTION = (
    "roughness: Eq. 7 (5x5, mm) on the ball ROI, on the pixels where it is defined in raw and "
    "the method alike; RMSE to GT on the same ROI pixels; '>1 mm': GT-valid pixels of the whole "
    "image more than 1 mm off (missing = bad)"
)
#: ... and of the ``bench --quality`` tables, which also have these columns.
BENCH_QUALITY_CAPTION = QUALITY_CAPTION + "; roughness std: over frames; C_3D: Eq. 8 (MLESAC)"


def _resolve(
    preset_name: str,
    config: Path | None,
    window: int | None,
    causal: bool,
    sets: list[str] | None,
    flow_method: str | None,
    flow_params: list[str] | None,
    flow_cache: Path | None = None,
    flow_roi: str | None = None,
    *,
    preset_given: bool = False,
):
    """The fusion and flow settings of the options, and the name of the preset they start
    from: ``--preset`` where given on the command line (``preset_given``), else the config
    file's ``preset``, else ``preset_name`` (the option's default); then the config file's
    tables, then ``--set``, ``--window``, ``--flow`` ... on top."""
    from .._params import coerce_fields, parse_assignments
    from ..config import FlowConfig, FusionParams, load_config, preset

    changes = coerce_fields(
        FusionParams,
        parse_assignments(sets, what="--set"),
        owner="the fusion (--set, FusionParams)",
    )
    # one replace, so that the cross-field checks see the config file, --set, --window and
    # --causal together (--window 16 with min_temporal_support=12 was refused against the
    # preset's 9 frames)
    if window is not None:
        changes["num_frames"] = window
    if causal:
        changes["causal"] = True
    with user_values():
        chosen = (
            load_config(
                config, base=preset_name, override_preset=preset_given, fusion_changes=changes
            )
            if config
            else preset(preset_name)
        )
    fusion = chosen.fusion
    if changes and not config:
        given = (["--set"] if set(changes) - {"num_frames", "causal"} else []) + (
            [f"--window {window}"] if window is not None else []
        )
        with user_values(f"{', '.join(given)}: " if given else ""):
            fusion = fusion.replace(**changes)
    flow = chosen.flow
    extra = parse_assignments(flow_params, what="--flow-param")
    if flow_method is not None or extra:
        method = flow_method or flow.method
        base = dict(flow.params) if method == flow.method else {}
        flow = dataclasses.replace(flow, method=method, params={**base, **extra})
    if flow_cache is not None:
        flow = dataclasses.replace(flow, cache_dir=str(flow_cache))
    if flow_roi is not None:
        from ..metrics.roi import parse_box

        text = ",".join(flow_roi.replace(",", " ").split())
        try:  # R0:R1,C0:C1 as --roi of report and metrics, or the config's ROW0,ROW1,COL0,COL1
            roi = (
                parse_box(text) if ":" in text else coerce_fields(FlowConfig, {"roi": text})["roi"]
            )
        except ValueError:
            roi = ()
        if len(roi or ()) != 4:
            fail(
                f"--flow-roi must be R0:R1,C0:C1 or ROW0,ROW1,COL0,COL1 (px, half-open), "
                f"got {flow_roi!r}"
            )
        flow = dataclasses.replace(flow, roi=roi)
    assert isinstance(flow, FlowConfig)
    with user_values("--flow/--flow-param: "):
        flow.build_params()  # validate early, before any frame is read
    return fusion, flow, chosen.name


def _given(ctx: typer.Context, *names: str) -> set[str]:
    """Which of the parameters ``names`` were typed on the command line (not defaults)."""
    # by name: typer vendors its own click (typer._click), whose enum is not click's
    return {
        name
        for name in names
        if getattr(ctx.get_parameter_source(name), "name", "") == "COMMANDLINE"
    }


@app.command("run")
def run_command(
    ctx: typer.Context,
    inputs: Annotated[
        list[Path],
        typer.Argument(
            help="Recording(s): .npz, frame folder, TUM, ROS/RealSense bag, .mkv, ... "
            "(several only with --engine dask)",
            metavar="INPUT",
        ),
    ],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Output .npz, folder, .mkv (FFV1) or .zarr.")
    ],
    preset_name: PresetOpt = "fast",
    window: Annotated[
        int | None, typer.Option("--window", help="Frames fused per output frame (n, paper: 9).")
    ] = None,
    config: Annotated[
        Path | None, typer.Option("--config", help="TOML file with \\[fusion] and \\[flow] tables.")
    ] = None,
    causal: Annotated[
        bool, typer.Option("--causal", help="Online mode: no look-ahead (live cameras).")
    ] = False,
    sets: SetOpt = None,
    flow_method: FlowMethodOpt = None,
    flow_params: FlowParamOpt = None,
    flow_cache: Annotated[
        Path | None,
        typer.Option(
            "--flow-cache",
            help="Folder of an on-disk flow cache: flows are stored and reused by later runs.",
        ),
    ] = None,
    flow_roi: Annotated[
        str | None,
        typer.Option(
            "--flow-roi",
            help="Solve flow only in rows R0..R1-1, columns C0..C1-1: R0:R1,C0:C1 (as --roi "
            "elsewhere) or R0,R1,C0,C1 (px); 0 flow outside.",
        ),
    ] = None,
    frames: Annotated[
        str | None,
        typer.Option(
            "--frames",
            help="Fuse only frames A:B of the recording (0-based, B excluded; 'A:' to the end),"
            " as if they were the whole; the output is numbered from 0.",
            callback=frame_range,
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing output.")] = False,
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            help="Continue a killed or interrupted run (folder output, or a .zarr with"
            " --engine dask; same input and options): the result equals an uninterrupted run.",
        ),
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
    no_summary: Annotated[
        bool,
        typer.Option("--no-summary", help="Skip the before/after quality figures (faster)."),
    ] = False,
    summary_every: Annotated[
        int,
        typer.Option(
            "--summary-every",
            min=1,
            help="Score the summary's roughness on one frame in N (1: all; flicker: all).",
        ),
    ] = 4,
    depth_topic: DepthTopicOpt = None,
    intensity_topic: IntensityTopicOpt = None,
    intensity: IntensityOpt = None,
    no_undistort: NoUndistortOpt = False,
    depth_unit_mm: DepthUnitOpt = None,
    intrinsics: CameraOverrideOpt = None,
    report: Annotated[
        Path | None,
        typer.Option("--report", help="Also write an HTML report folder (see fuse4d report)."),
    ] = None,
    engine: Annotated[
        str, typer.Option("--engine", help="stream (one process) or dask (zarr v3 output).")
    ] = "stream",
    chunk_frames: Annotated[
        int,
        typer.Option(
            "--chunk-frames",
            help="dask: most frames per task and zarr shard (evened out over the recording).",
        ),
    ] = 16,  # fuse4d.scale.cli.RUN_CHUNK_FRAMES (not imported here: dask loads lazily)
    scheduler: Annotated[
        str, typer.Option("--scheduler", help="dask: threads, processes or tcp://HOST:PORT.")
    ] = "threads",
    workers: Annotated[
        int | None, typer.Option("--workers", help="dask: local threads/processes (all CPUs).")
    ] = None,
    warm_start: Annotated[
        bool,
        typer.Option("--warm-start/--no-warm-start", help="dask: chain flow warm starts."),
    ] = True,
    save_flows: Annotated[
        bool, typer.Option("--save-flows", help="dask: also store the pair flows (px).")
    ] = False,
) -> None:
    """Fuse a recording (paper Eq. 2-6) and write the same kind of file or folder.

    Camera recordings (.bag/.db3/.mcap/.mkv) are read directly; the output is a frame folder,
    an FFV1 .mkv or a .zarr store, chosen by the output's suffix. --engine dask: chunked
    fusion on a dask cluster to zarr v3, many recordings at once (docs/scaling.md).

    A folder output is built in OUTPUT.partial (complete frames + a manifest); if the run is
    killed or interrupted (Ctrl-C), the same command with --resume continues it.
    """
    from ..run import fuse_file

    options = reader_options(
        depth_topic, intensity_topic, intensity, no_undistort,
        depth_unit_mm=depth_unit_mm, intrinsics=intrinsics,
    )  # fmt: skip

    fusion, flow, preset_used = _resolve(
        preset_name,
        config,
        window,
        causal,
        sets,
        flow_method,
        flow_params,
        flow_cache,
        flow_roi,
        preset_given=bool(_given(ctx, "preset_name")),
    )
    if engine not in ("stream", "dask") or (engine == "stream" and len(inputs) != 1):
        fail("--engine must be stream or dask; several inputs need --engine dask")
    # options of the other engine were accepted and ignored (exit 0, not what was asked)
    other = _DASK_ONLY if engine == "stream" else _STREAM_ONLY
    ignored = [option for name, option in other.items() if name in _given(ctx, *other)]
    if ignored:
        fail(
            f"{', '.join(ignored)}: "
            + (
                "options of --engine dask (the stream engine does not use them)"
                if engine == "stream"
                else "options of the stream engine's quality summary (--engine dask has none)"
            )
        )
    if flow.cache_dir:  # it writes folders of flows: never into an input or the output
        from ..flow import FlowCache

        named = "--flow-cache" if flow_cache is not None else "the config's [flow] cache_dir"
        cache = FlowCache(flow.cache_dir).directory.resolve()  # (~ expanded as the cache does)
        for place in (*inputs, output):
            where = Path(place).resolve()
            if cache == where or where in cache.parents:
                fail(f"{named} {flow.cache_dir}: it lies inside {place}; choose another folder")
    all_options = options if frames is None else {**options, "frames": frames}
    if report is not None:
        from ..io import check_output

        if len(inputs) != 1:
            fail(
                "--report writes the report of one input; for several, run "
                "`fuse4d report INPUT OUTPUT.zarr -o DIR` for each after this run"
            )
        check_output(report, overwrite=force, inputs=[inputs[0], output])  # fail before fusing
    if engine == "dask":
        try:
            from ..scale.cli import print_dask_run
        except ImportError as exc:  # the [scale] extra is missing
            fail(str(exc))
        opts = {"chunk_frames": chunk_frames, "scheduler": scheduler, "workers": workers}
        opts["save_flows"] = save_flows
        opts["reader_options"] = all_options
        done = print_dask_run(
            inputs, output, fusion, flow, opts, resume, force, warm_start, as_json
        )
        if report is not None:
            from .cmd_report import make_report

            # the parameters as run (A36 resolved for the camera) come from the store's metadata
            page = make_report(
                inputs[0],
                done[0].output,
                report,
                params=None,
                # a resumed (or already complete) store: this session's time is not the run's,
                # and the store does not record the earlier sessions'
                fusion_seconds=None if done[0].skipped else done[0].seconds,
                overwrite=force,
                reader_options=all_options,
            )
            err_console.print(f"wrote {page}")
        return
    input = inputs[0]
    with progress_bar("fusing", None) as progress:
        summary = fuse_file(
            input,
            output,
            fusion=fusion,
            flow=flow,
            overwrite=force,
            quality=not no_summary,
            progress=progress_callback(progress),
            reader_options=options,
            resume=resume,
            summary_every=summary_every,
            frames=frames,
        )
    if summary.already_complete:
        err_console.print(
            f"{output}: already complete (an earlier run of the same input, options and "
            "versions); nothing fused now (--force redoes it)"
        )
    if report is not None:
        from .cmd_report import make_report

        # as run: flying_pixels "auto" resolved for the camera (A36)
        params = {
            **summary.params.to_dict(),
            "flow_method": summary.flow_method,
            "preset": preset_used,
        }
        page = make_report(
            input,
            output,
            report,
            params=params,
            # a finished run found by --resume, or a resumed one (this session's time is not
            # the run's): the report reads the run's time from the manifest (all sessions)
            fusion_seconds=None if summary.frames_resumed else summary.seconds,
            fusion_steady_ms=summary.steady_ms_per_frame,
            overwrite=force,
            reader_options=all_options,
        )
        err_console.print(f"wrote {page}")
    if as_json:
        print_json(summary.to_dict())
        return
    if not summary.already_complete:
        out_console.print(run_summary_table(summary, fusion, scored=not no_summary))


#: ``fuse4d run`` options that only ``--engine dask`` uses (parameter name: option) ...
_DASK_ONLY = {
    "chunk_frames": "--chunk-frames",
    "scheduler": "--scheduler",
    "workers": "--workers",
    "warm_start": "--warm-start/--no-warm-start",
    "save_flows": "--save-flows",
}
#: ... and those that only the stream engine uses (its quality summary; ``--no-summary`` is
#: what ``--engine dask`` does anyway, so scripts may pass it to both engines).
_STREAM_ONLY = {"summary_every": "--summary-every"}


def print_json(data: Any) -> None:
    """Print ``data`` as strict JSON on stdout: NaN/inf as null (bare NaN is not JSON)."""
    from .._json import dumps

    print(dumps(data, indent=2))


def _time_note(summary: Any) -> str:
    """The summary's time row: the steady rate apart from the start-up, which dominates the
    average of a short clip (too few frames for a steady rate: the average alone). After
    ``--resume``: of this session, per frame fused in it."""
    steady = summary.steady_ms_per_frame
    session = (
        f" (this session: {summary.frames_fused} fused, {summary.frames_resumed} resumed)"
        if summary.frames_resumed
        else ""
    )
    if not math.isfinite(steady):
        return f"{summary.ms_per_frame:.0f} ms/frame, start-up and I/O included" + session
    return (
        f"{steady:.0f} ms/frame once running, I/O included; the first frame came after "
        f"{summary.first_output_seconds:.1f} s (start-up: input opened, kernels loaded, the "
        f"first window); {summary.ms_per_frame:.0f} ms/frame on average" + session
    )


def run_summary_table(summary: Any, fusion: Any, *, scored: bool = True) -> Table:
    """The ``fuse4d run`` summary: what was done, and what each quality number means
    (``scored`` False: the run skipped the quality figures, ``--no-summary``)."""

    def pair(raw: float, fused: float, words: tuple[str, str], missing: str = "n/a") -> str:
        if not (math.isfinite(raw) and math.isfinite(fused)):  # nothing scored
            return missing
        verdict = words[0] if fused < raw else words[1] if fused > raw else "unchanged"
        return f"{raw:.3f} -> {fused:.3f} mm ({verdict})"

    def percent(fraction: float, digits: int) -> str:
        return f"{100 * fraction:.{digits}f} %" if math.isfinite(fraction) else "n/a"

    def share(fraction: float) -> str:  # of a step that is on: counted with the summary only
        return percent(fraction, 2) if scored else "on"

    smooth = ("smoother", "rougher")
    unsupported = "valid pixels without temporal support"
    eq6 = (
        (
            share(summary.filled_fraction),
            f"{unsupported}, filled from neighbours (not sensor holes)",
        )
        if fusion.fill_holes
        else (
            "off",
            f"{unsupported} are left empty (fill_fallback=nan)"
            if fusion.fill_fallback == "nan"
            else f"{unsupported} keep their own bilateral value (A35)",
        )
    )
    flying = (
        (
            share(summary.rejected_fraction),
            "valid pixels removed as ToF flying pixels (between the two sides of an edge), "
            + "left empty (A36)",
        )
        if summary.params.flying_pixels == "on"
        else ("off", "on for time-of-flight recordings, or with --set flying_pixels=on (A36)")
    )

    filled_holes = summary.hole_time_fraction + summary.hole_space_fraction
    holes = (
        "none" if summary.hole_fraction == 0 else percent(filled_holes, 1),
        (
            f"of the raw pixels without depth inside the sensor's field of view "
            f"({percent(summary.hole_fraction, 1)} of the image has no depth, "
            f"{percent(summary.hole_outside_fraction, 1)} of that outside the field of view, "
            f"never filled, A38): {percent(summary.hole_time_fraction, 1)} from other frames "
            f"along the track (A26), {percent(summary.hole_space_fraction, 1)} in space from "
            "one side of the depth edges (A27); the rest stay empty"
        ),
    )

    table = Table(title=f"fuse4d run: {summary.input} -> {summary.output}", show_header=True)
    table.add_column("")
    table.add_column("raw -> fused")
    table.add_column("what it means")
    n = summary.roughness_window
    frame_rows = [
        (
            "frames",
            f"{summary.frames} x {summary.shape[0]}x{summary.shape[1]}",
            f"{summary.input_format} -> {summary.output_format}",
        ),
        ("tracker", summary.flow_method, "optical flow of the temporal tracks"),
        (
            "window",
            f"{fusion.num_frames} frames" + (" (causal)" if fusion.causal else ""),
            "frames fused per output frame",
        ),
    ]
    quality_rows = [
        (
            "roughness (Eq. 7)",
            pair(summary.raw_roughness, summary.fused_roughness, smooth),
            (
                f"N x the centre point's distance to the plane fitted to its {n}x{n} window (N: "
                "its valid points), mean over frames; the same "
                f"{summary.roughness_pixels} pixels (x frames) for both: raw windows free of "
                "depth edges by the noise model's step limit"
                + (
                    f"; scored on {summary.roughness_frames} of {summary.frames_fused} frames"
                    if 0 < summary.roughness_frames < summary.frames_fused
                    else ""
                )
            ),
        ),
        (
            "plane-fit residual",
            pair(summary.raw_rms_residual, summary.fused_rms_residual, smooth),
            f"RMS distance to the {n}x{n} window's plane (spatial precision), same pixels",
        ),
        (
            "flicker",
            pair(
                summary.raw_flicker,
                summary.fused_flicker,
                ("steadier", "less steady"),
                "n/a (fewer than 2 frames or no static pixel)",
            ),
            (
                f"mean frame-to-frame |change| on {summary.static_pixels} static pixels "
                "(detected in the raw video, with output depth in every frame)"
            ),
        ),
        (
            "temporal support",
            percent(summary.support_fraction, 1),
            "valid pixels tracked into at least one other frame",
        ),
    ]
    hole_rows = [("sensor holes filled", *holes)]
    if summary.frames_resumed:  # --resume: the frames of the interrupted run are not read back
        quality_rows.insert(
            0,
            (
                "scored frames",
                f"{summary.frames_resumed}-{summary.frames - 1}",
                (
                    f"the rows below cover the {summary.frames_fused} frames fused in this "
                    f"session; frames 0-{summary.frames_resumed - 1}, written by the "
                    "interrupted run, were not scored"
                ),
            ),
        )
    if not scored:
        quality_rows = [
            (
                "quality",
                "skipped (--no-summary)",
                (
                    "roughness (Eq. 7), plane-fit residual, flicker, temporal support and the "
                    "fills were not scored"
                ),
            )
        ]
        hole_rows = []
    rows = [
        *frame_rows,
        *quality_rows,
        ("Eq. 6 filled", *eq6),
        ("flying pixels", *flying),
        *hole_rows,
        ("time", f"{summary.seconds:.1f} s", _time_note(summary)),
    ]
    for key, value, note in rows:
        table.add_row(key, value, note)
    return table


@app.command("bench")
def bench_command(
    ctx: typer.Context,
    preset_name: Annotated[str, typer.Option("--preset", help="fast, paper or all.")] = "fast",
    small: Annotated[bool, typer.Option("--small", help="150x150 CI scene.")] = False,
    num_frames: Annotated[int, typer.Option("--frames", help="Frames timed.")] = 18,
    window: Annotated[int, typer.Option("--window", help="Frames fused per output.")] = 9,
    quality: Annotated[
        bool,
        typer.Option("--quality", help="Instead: score quality vs GT on the 50-frame ball."),
    ] = False,
    intensity_noise: Annotated[
        float, typer.Option("--intensity-noise", help="With --quality: sigma_I (fraction).")
    ] = 0.02,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    recording: Annotated[
        Path | None,
        typer.Option(
            "--input", help="Instead: time `fuse4d run` on this recording (--frames of it)."
        ),
    ] = None,
    no_summary: Annotated[
        bool, typer.Option("--no-summary", help="With --input: skip the quality summary.")
    ] = False,
    causal: Annotated[
        bool,
        typer.Option("--causal", help="Time the causal engine (no look-ahead, as `fuse4d live`)."),
    ] = False,
) -> None:
    """Time each pipeline stage (ms/frame) and report peak memory, on the synthetic ball.

    With --input REC: a real recording end to end through the streaming path of `fuse4d run`
    (read, write and summary are stages; reading and writing overlap the fusion).

    With --causal: the causal engine (each frame fused with the --window - 1 previous ones,
    as `fuse4d run --causal` and `fuse4d live`), stage by stage alike.

    With --quality: RMSE/roughness/bad pixels/shape of raw, the depth self-guided filter, a
    9-frame mean and fuse4d against ground truth on the 50-frame 600x600 ball.
    """
    from ..config import PRESETS
    from ..experiments.speed import benchmark_pipeline, benchmark_recording

    names = list(PRESETS) if preset_name == "all" else [preset_name]
    for name in names:
        if name not in PRESETS:
            fail(f"unknown preset {name!r}; choose fast, paper or all")
    if quality and causal:
        fail("--quality scores the centred engine; drop --causal")
    # options a mode does not use were accepted and ignored (exit 0, another run measured)
    given = _given(ctx, "num_frames", "window", "intensity_noise")
    if quality and (recording is not None or given & {"num_frames", "window"}):
        fail(
            "--quality scores the fixed ball (50 frames, 12 with --small) with the preset's "
            "window; drop --input, --frames and --window"
        )
    if not quality and "intensity_noise" in given:
        fail("--intensity-noise applies to --quality only")
    if no_summary and recording is None:
        fail("--no-summary applies to --input only (the synthetic bench has no summary)")
    if small and recording is not None:
        fail("--small is the synthetic ball's size; --input times the recording at its own")
    fewest = 1 if recording is not None else 2  # the synthetic ball needs a pair to move
    if not quality and num_frames < fewest:
        fail(f"--frames must be >= {fewest}, got {num_frames}")
    if quality:
        _quality(names, small, intensity_noise, as_json)
        return
    results = []
    for name in names:
        err_console.print(f"benchmarking preset {name!r} ...")
        if recording is not None:
            results.append(
                benchmark_recording(
                    recording,
                    name,
                    num_frames=num_frames,
                    window=window,
                    summary=not no_summary,
                    causal=causal,
                )
            )
        else:
            results.append(
                benchmark_pipeline(
                    name, small=small, num_frames=num_frames, window=window, causal=causal
                )
            )
    if as_json:
        print_json([r.to_dict() for r in results])
        return
    for r in results:
        height, width = r.size
        # a heading line, not the table's title: a title wraps at the (narrow) table's width
        out_console.print(
            f"[bold]preset {r.preset}[/bold] ({r.flow_method}), {width}x{height} px, "
            f"{r.window}-frame {'causal ' if r.causal else ''}window, {r.frames} frames"
            + (f": {r.input}" if r.input else ""),
            soft_wrap=True,
        )
        table = Table()
        table.add_column("stage")
        table.add_column("ms/frame", justify="right")
        stages = dict(r.stage_ms)
        worker = stages.pop("flow_worker", None)  # (overlapped flow: its own time, by flow)
        for stage, ms in stages.items():
            table.add_row(stage, f"{ms:.1f}")
            if stage == "flow" and worker is not None:
                table.add_row("flow (in its worker)", f"{worker:.1f}")
        table.add_row("[bold]steady (wall)", f"[bold]{r.ms_per_frame:.1f}")
        if math.isfinite(r.setup_ms):
            table.add_row("setup (once)", f"{r.setup_ms:.0f} ms")
            table.add_row("total (wall, setup spread)", f"{r.wall_ms_per_frame:.1f}")
        table.add_row("per pixel", f"{r.us_per_pixel:.3f} µs")
        out_console.print(table)
        out_console.print(
            "steady: from the engine built to the last frame out; setup: the engine (and a "
            "recording's reader and writer) opened and closed, once"
            + (
                "; read, write and the flow's worker overlap the fusion (flow: the wait for it)"
                if r.input
                else ""
            ),
            soft_wrap=True,
        )
        held = f", {r.input_mb:.0f} MiB of it the frames held in memory" if r.input_mb else ""
        out_console.print(
            f"warm-up {r.warmup_s:.1f} s, peak RSS {r.peak_rss_mb:.0f} MiB during the timed "
            f"run{held}"
        )


@app.command("demo")
def demo_command(
    ctx: typer.Context,
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="Output folder. The default one is rerun in place (the demo's own files, "
            "unchanged since it wrote them, are replaced); other existing files need --force.",
        ),
    ] = Path("fuse4d-demo"),
    small: Annotated[bool, typer.Option("--small", help="150x150 quick scene.")] = False,
    num_frames: Annotated[int, typer.Option("--frames", help="Frames of the ball.")] = 18,
    preset_name: PresetOpt = "fast",
    force: Annotated[
        bool, typer.Option("--force", help="Replace existing output files of the same names.")
    ] = False,
) -> None:
    """Fuse the built-in synthetic falling ball and write figures and a metrics table."""
    from ..experiments.demo import run_demo

    err_console.print("fuse4d demo: synthetic falling ball (first run compiles kernels) ...")
    with progress_bar("fusing", None) as progress:
        result = run_demo(
            out,
            small=small,
            num_frames=num_frames,
            preset=preset_name,
            overwrite=force,
            # plain `fuse4d demo` (the README's first command) reruns into its own folder
            replace_own="out" not in _given(ctx, "out"),
            progress=progress_callback(progress),
        )
    table = Table(
        title=f"falling ball, {result.frames} frames, 0.2 mm / 2 % noise",
        caption=QUALITY_CAPTION,
    )
    for col in ("method", "roughness mean (mm)", "RMSE (mm)", ">1 mm off (%)"):
        table.add_column(col, justify="left" if col == "method" else "right")
    for s in result.scores:
        table.add_row(s.name, f"{s.roughness_mean:.3f}", f"{s.rmse:.4f}", f"{100 * s.bad_1mm:.3f}")
    out_console.print(table)
    out_console.print(
        f"fusion: {1000 * result.seconds_fusion / result.frames:.0f} ms/frame "
        f"(first run includes compilation), temporal support "
        f"{100 * result.support_fraction:.1f} %"
    )
    for path in result.files:
        out_console.print(f"wrote {path}")


def _quality(names: list[str], small: bool, intensity_noise: float, as_json: bool) -> None:
    from ..experiments.quality import ball_quality_report

    reports = []
    for name in names:
        err_console.print(f"scoring preset {name!r} on the ball (sigma_I = {intensity_noise}) ...")
        reports.append(
            ball_quality_report(
                preset=name,
                intensity_noise=intensity_noise,
                small=small,
                num_frames=12 if small else 50,
            )
        )
    if as_json:
        print_json([r.to_dict() for r in reports])
        return
    for r in reports:
        for label, scores in (("all frames", r.all_frames), ("interior frames", r.interior)):
            table = Table(
                title=f"ball {r.frames} frames, sigma_d {r.depth_noise} mm, sigma_I "
                f"{100 * r.intensity_noise:g}%, {label} (flow {r.flow_method})",
                caption=BENCH_QUALITY_CAPTION,
            )
            for col in (
                "method",
                "roughness mean",
                "roughness std",
                "RMSE ball ROI",
                ">1 mm (% px)",
                # Eq. 8 costs ~1 s a frame: one set of frames for both tables, named
                f"C_3D (%, frames {', '.join(map(str, r.shape_frames))})",
            ):
                table.add_column(col, justify="left" if col == "method" else "right")
            for s in scores:
                table.add_row(
                    s.name,
                    f"{s.roughness_mean:.3f}",
                    f"{s.roughness_std:.4f}",
                    f"{s.rmse:.4f}",
                    f"{100 * s.bad_1mm:.3f}",
                    f"{r.shape_c3d[s.name]:.4f}",
                )
            out_console.print(table)
        out_console.print(f"fusion {r.fusion_ms_per_frame:.0f} ms/frame (wall, in-memory)")
