"""CLI commands: ``run`` (fuse a recording), ``bench`` (speed/memory), ``demo``."""

from __future__ import annotations

import json
from dataclasses import fields
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

PresetOpt = Annotated[
    str, typer.Option("--preset", help="Parameter preset: fast (DIS flow) or paper (PMBP).")
]


def _parse_assignments(items: list[str] | None, what: str) -> dict[str, Any]:
    """``["a=1", "b=x"]`` → ``{"a": "1", "b": "x"}`` (values converted by the receiver)."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            fail(f"{what} must look like KEY=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def _coerce_fusion_value(name: str, text: str) -> Any:
    from ..config import FusionParams

    known = {f.name: f for f in fields(FusionParams)}
    if name not in known:
        fail(f"unknown fusion parameter {name!r}; valid: {', '.join(sorted(known))}")
    default = getattr(FusionParams(), name)
    if isinstance(default, bool):
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        fail(f"fusion parameter {name} must be true or false, got {text!r}")
    if isinstance(default, int):
        try:
            return int(text)
        except ValueError:
            fail(f"fusion parameter {name} must be an integer, got {text!r}")
    if isinstance(default, float):
        try:
            return float(text)
        except ValueError:
            fail(f"fusion parameter {name} must be a number, got {text!r}")
    return text


def _resolve(
    preset_name: str,
    config: Path | None,
    num_frames: int | None,
    causal: bool,
    sets: list[str] | None,
    flow_method: str | None,
    flow_params: list[str] | None,
):
    from ..config import FlowConfig, load_config, preset

    with user_values():
        chosen = load_config(config, base=preset_name) if config else preset(preset_name)
    fusion = chosen.fusion
    changes = {k: _coerce_fusion_value(k, v) for k, v in _parse_assignments(sets, "--set").items()}
    if num_frames is not None:
        changes["num_frames"] = num_frames
    if causal:
        changes["causal"] = True
    if changes:
        with user_values("--set/--frames: "):
            fusion = fusion.replace(**changes)
    flow = chosen.flow
    extra = _parse_assignments(flow_params, "--flow-param")
    if flow_method is not None or extra:
        method = flow_method or flow.method
        base = dict(flow.params) if method == flow.method else {}
        flow = FlowConfig(method, {**base, **extra})
    with user_values("--flow/--flow-param: "):
        flow.build_params()  # validate early, before any frame is read
    return fusion, flow


@app.command("run")
def run_command(
    input: Annotated[Path, typer.Argument(help="Recording: .npz, frame folder, TUM, ...")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Output .npz or folder.")],
    preset_name: PresetOpt = "fast",
    num_frames: Annotated[
        int | None, typer.Option("--frames", help="Frames fused per output frame (n).")
    ] = None,
    config: Annotated[
        Path | None, typer.Option("--config", help="TOML file with [fusion] and [flow].")
    ] = None,
    causal: Annotated[
        bool, typer.Option("--causal", help="Online mode: no look-ahead (live cameras).")
    ] = False,
    sets: Annotated[
        list[str] | None,
        typer.Option("--set", help="Fusion parameter KEY=VALUE (repeatable).", show_default=False),
    ] = None,
    flow_method: Annotated[
        str | None, typer.Option("--flow", help="Flow method (overrides the preset).")
    ] = None,
    flow_params: Annotated[
        list[str] | None,
        typer.Option(
            "--flow-param", help="Flow parameter KEY=VALUE (repeatable).", show_default=False
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing output.")] = False,
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            help="Continue a killed or interrupted run (folder output, same input and options);"
            " the result equals an uninterrupted run.",
        ),
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Fuse a recording (paper Eq. 2-6) and write the same kind of file or folder.

    A folder output is built in OUTPUT.partial (complete frames + a manifest); if the run is
    killed or interrupted (Ctrl-C), the same command with --resume continues it.
    """
    from ..run import fuse_file

    fusion, flow = _resolve(preset_name, config, num_frames, causal, sets, flow_method, flow_params)
    with progress_bar("fusing", None) as progress:
        summary = fuse_file(
            input,
            output,
            fusion=fusion,
            flow=flow,
            overwrite=force,
            progress=progress_callback(progress),
            resume=resume,
        )
    if as_json:
        print(json.dumps(summary.to_dict(), indent=2))
        return
    table = Table(title=f"fuse4d run: {summary.input} -> {summary.output}", show_header=False)
    rows = [
        (
            "frames",
            (
                f"{summary.frames} x {summary.shape[0]}x{summary.shape[1]} "
                f"({summary.input_format} -> {summary.output_format})"
            ),
        ),
        ("tracker", summary.flow_method),
        ("window", f"{fusion.num_frames} frames" + (" (causal)" if fusion.causal else "")),
        (
            "roughness raw -> fused",
            (
                f"{summary.raw_roughness:.3f} -> {summary.fused_roughness:.3f} "
                "mm (Eq. 7, 5x5, default ROI)"
            ),
        ),
        ("temporal support", f"{100 * summary.support_fraction:.1f} % of valid pixels"),
        ("hole-filled", f"{100 * summary.filled_fraction:.2f} % of valid pixels"),
        ("time", f"{summary.seconds:.1f} s ({summary.ms_per_frame:.0f} ms/frame)"),
    ]
    for key, value in rows:
        table.add_row(key, value)
    out_console.print(table)


@app.command("bench")
def bench_command(
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
) -> None:
    """Time each pipeline stage (ms/frame) and report peak memory, on the synthetic ball.

    With --quality: RMSE/roughness/bad pixels/shape of raw, the depth self-guided filter, a
    9-frame mean and fuse4d against ground truth on the 50-frame 600x600 ball.
    """
    from ..bench import benchmark_pipeline
    from ..config import PRESETS

    names = list(PRESETS) if preset_name == "all" else [preset_name]
    for name in names:
        if name not in PRESETS:
            fail(f"unknown preset {name!r}; choose fast, paper or all")
    if quality:
        _quality(names, small, intensity_noise, as_json)
        return
    results = []
    for name in names:
        err_console.print(f"benchmarking preset {name!r} ...")
        results.append(benchmark_pipeline(name, small=small, num_frames=num_frames, window=window))
    if as_json:
        print(json.dumps([r.to_dict() for r in results], indent=2))
        return
    for r in results:
        table = Table(
            title=f"preset {r.preset} ({r.flow_method}), {r.size[0]}x{r.size[1]}, "
            f"{r.window}-frame window, {r.frames} frames"
        )
        table.add_column("stage")
        table.add_column("ms/frame", justify="right")
        for stage, ms in r.stage_ms.items():
            table.add_row(stage, f"{ms:.1f}")
        table.add_row("[bold]total (wall)", f"[bold]{r.ms_per_frame:.1f}")
        out_console.print(table)
        out_console.print(f"warm-up {r.warmup_s:.1f} s, peak RSS {r.peak_rss_mb:.0f} MiB")


@app.command("demo")
def demo_command(
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("fuse4d-demo"),
    small: Annotated[bool, typer.Option("--small", help="150x150 quick scene.")] = False,
    num_frames: Annotated[int, typer.Option("--frames", help="Frames of the ball.")] = 18,
    preset_name: PresetOpt = "fast",
) -> None:
    """Fuse the built-in synthetic falling ball and write figures and a metrics table."""
    from ..demo import run_demo

    err_console.print("fuse4d demo: synthetic falling ball (first run compiles kernels) ...")
    with progress_bar("fusing", None) as progress:
        result = run_demo(
            out,
            small=small,
            num_frames=num_frames,
            preset=preset_name,
            progress=progress_callback(progress),
        )
    table = Table(
        title=f"falling ball, {result.frames} frames, 0.2 mm / 2 % noise "
        "(ball ROI; '>1 mm' over all pixels)"
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
    from ..evaluation import ball_quality_report

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
        print(json.dumps([r.to_dict() for r in reports], indent=2))
        return
    for r in reports:
        for label, scores in (("all frames", r.all_frames), ("interior frames", r.interior)):
            table = Table(
                title=f"ball {r.frames} frames, sigma_d {r.depth_noise} mm, sigma_I "
                f"{r.intensity_noise:.0%}, {label} (flow {r.flow_method})"
            )
            for col in (
                "method",
                "roughness mean",
                "roughness std",
                "RMSE ball ROI",
                ">1 mm (% px)",
                "C_3D (%)",
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
