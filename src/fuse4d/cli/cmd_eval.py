"""CLI commands ``synth`` (synthetic scenes with ground truth) and ``metrics`` (evaluation)."""

from __future__ import annotations

import dataclasses
import json
import math
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.table import Table

from ._app import app, err_console, fail, out_console, progress_bar, progress_callback
from ._recording_opts import frame_range

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy as np

    from ..sequence import Sequence

__all__ = ["metrics_command", "synth_command"]


class SceneName(StrEnum):
    """Synthetic scenes of ``fuse4d synth``: paper scenes, or range scenes with ``--sensor``."""

    ball = "ball"
    plane = "plane"
    sheet = "sheet"
    body = "body"
    room = "room"


class SensorName(StrEnum):
    """Sensor models of ``fuse4d synth --sensor`` (:mod:`fuse4d.sensors`)."""

    kinect = "kinect"
    d435 = "d435"
    tof = "tof"


#: scenes of each family
_PAPER_SCENES = ("ball", "plane", "sheet")
_RANGE_SCENES = ("ball", "body", "room")


def _render_and_write(
    what: str, make: Callable[..., Sequence], scene: str, output: Path, force: bool, **options: Any
) -> Sequence:
    """``make(scene, **options)`` written to ``output`` (.npz), with status lines; options that
    are None are left out (the scene maker's defaults apply). Returns the sequence.

    A scene too large for the memory (estimated before rendering, or a MemoryError while
    rendering or writing it) is one error naming ``--frames``."""
    from ..io import write_npz
    from ..synthetic import _SceneTooLarge

    given = {k: v for k, v in options.items() if v is not None}
    frames = given.get("num_frames")
    try:
        with err_console.status(f"rendering {what}"):
            seq = make(scene, **given)
        with err_console.status(f"writing {output}"):
            write_npz(seq, output, overwrite=force)
        return seq
    except _SceneTooLarge as exc:
        problem = f"--frames {exc.num_frames}: {exc.detail}"
    except MemoryError:  # outside the estimate: the arrays are freed before failing
        problem = (
            f"--frames {'(default)' if frames is None else frames}: {what} does not fit in "
            "memory; render fewer frames"
        )
    fail(problem)
    raise AssertionError  # unreachable


@app.command("synth")
def synth_command(
    scene: Annotated[
        SceneName,
        typer.Argument(
            help="Scene: ball, plane or sheet (the paper's: ball centre at 0.7 m, plane at "
            "0.5 m, sheet at 0.55 m, before a wall at 1 m); with --sensor: ball, body or room "
            "at 1-5 m."
        ),
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="Output .npz file.")],
    sensor: Annotated[
        SensorName | None,
        typer.Option(
            help="Sensor model (kinect: structured light, d435: active stereo, tof): switches "
            "to the range scenes (ball at 2 m, walking body at 2.5 m, static room at 4 m; "
            "640x480, 30 fps), seen through that sensor."
        ),
    ] = None,
    depth_noise: Annotated[
        float | None,
        typer.Option(
            help="Depth-noise std in mm; defaults: ball 0.2, plane 0.05 (its base: x1-2 on "
            "dark texture, plus a 0.02 mm fixed pattern), sheet 0.1."
        ),
    ] = None,
    intensity_noise: Annotated[
        float | None,
        typer.Option(help="Intensity-noise std as a fraction of 1.0 (0.02 = 2 %)."),
    ] = None,
    frames: Annotated[
        int | None,
        typer.Option(help="Number of frames (default 50, 12 with --small; 30 with --sensor)."),
    ] = None,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    small: Annotated[
        bool, typer.Option(help="CI-size variant: 150x150 (paper), 160x120 (--sensor).")
    ] = False,
    force: Annotated[bool, typer.Option(help="Overwrite OUTPUT if it exists.")] = False,
) -> None:
    """Render a synthetic scene with ground truth (depth, mask, flow) into an .npz file.

    Without --sensor: the paper's scenes (ball, plane, sheet) at 0.5-0.7 m before a wall at
    1 m, with Gaussian depth noise (--depth-noise; the printed std is measured on depth -
    truth, the plane's texture and fixed pattern included). With --sensor kinect|d435|tof: the range scenes (ball, body, room)
    at 1-5 m through that sensor model (disparity quantisation, correlated noise, shadow
    holes, flying pixels; see docs/sensors.md); --depth-noise does not apply there.
    """
    if output.suffix.lower() != ".npz":
        fail(f"{output}: synth writes an .npz (it keeps the ground truth); give a name ending .npz")
    if output.exists() and not force:
        fail(f"{output}: output exists; pass --force to replace it")
    if frames is not None and frames < 2:
        fail(f"--frames must be >= 2 (a scene moves between frames), got {frames}")
    from ..synthetic import SEED_LIMIT

    if not 0 <= seed < SEED_LIMIT:
        fail(f"--seed must be >= 0 and < 2**64 (what an .npz holds), got {seed}")
    if sensor is not None:
        from ..range_scenes import make_range_scene

        if scene.value not in _RANGE_SCENES:
            fail(
                f"scene {scene.value!r} has no range version; with --sensor choose one of "
                f"{', '.join(_RANGE_SCENES)}"
            )
        if depth_noise is not None:
            fail("--depth-noise applies to the paper scenes; the sensor model sets the noise")
        what = f"the {scene.value} range scene ({sensor.value})"
        seq = _render_and_write(
            what, make_range_scene, scene.value, output, force, sensor=sensor.value,
            small=small, rng=seed, intensity_noise=intensity_noise, num_frames=frames,
        )  # fmt: skip
        t, (h, w) = seq.num_frames, seq.shape
        import numpy as np

        valid = 100.0 * float(np.isfinite(seq.depth).mean())
        err_console.print(
            f"wrote {output}: {scene.value} at range, sensor {sensor.value}, {t} frames "
            f"{w}x{h}, {valid:.1f} % valid depth, seed {seed}"
        )
        return
    from ..synthetic import make_scene

    if scene.value not in _PAPER_SCENES:
        fail(
            f"scene {scene.value!r} is a range scene: give --sensor kinect|d435|tof "
            f"(paper scenes: {', '.join(_PAPER_SCENES)})"
        )
    seq = _render_and_write(
        f"the {scene.value} scene", make_scene, scene.value, output, force, small=small,
        rng=seed, depth_noise=depth_noise, intensity_noise=intensity_noise, num_frames=frames,
    )  # fmt: skip
    t, (h, w) = seq.num_frames, seq.shape
    extra = seq.ground_truth.extra if seq.ground_truth else {}
    err_console.print(
        f"wrote {output}: {scene.value}, {t} frames {w}x{h}, depth noise {_depth_noise(seq)}, "
        f"intensity noise {extra.get('intensity_noise')}, seed {seed}"
    )


def _depth_noise(seq: Sequence) -> str:
    """The depth noise of a paper scene as ``synth`` prints it: the std of depth - truth
    (mm, measured on the valid pixels) and the settings it comes from."""
    import numpy as np

    gt = seq.ground_truth
    assert gt is not None
    assert gt.depth is not None
    n, total, squares = 0, 0.0, 0.0
    for depth, truth in zip(seq.depth, gt.depth, strict=True):  # frame by frame: no T copy
        err = (depth.astype(np.float64) - truth)[np.isfinite(depth) & np.isfinite(truth)]
        n, total, squares = n + err.size, total + err.sum(), squares + (err**2).sum()
    std = math.sqrt(max(squares / n - (total / n) ** 2, 0.0)) if n else float("nan")
    extra = gt.extra
    parts = [f"--depth-noise {extra.get('depth_noise')} mm"]
    if extra.get("texture_correlated"):
        parts.append("x1-2 on dark texture")
    if extra.get("structural_noise"):
        parts.append(f"+ {extra['structural_noise']} mm fixed pattern")
    return f"std {std:.3g} mm (measured on depth - truth: {', '.join(parts)})"


def _box(text: str) -> tuple[int, int, int, int] | None:
    """The pixel box that ``text`` names ("R0:R1,C0:C1": a colon and a comma, and no such
    file; a malformed one is a ParameterError naming the form), else None (a mask file)."""
    from ..metrics.roi import parse_box

    if Path(text).exists() or ":" not in text or "," not in text:
        return None
    return parse_box(text)


def _read_region(text: str, what: str, frames: str | None, shape: tuple[int, int]) -> np.ndarray:
    """A bool mask: the box R0:R1,C0:C1 (:func:`fuse4d.metrics.box_mask`, ``(H, W)``) or a
    mask file through :func:`fuse4d.io.read_mask` (their errors -> one CLI error)."""
    from ..errors import InputFileError, ParameterError
    from ..io import read_mask
    from ..metrics.roi import box_mask

    try:
        box = _box(text)
        return read_mask(Path(text), frames=frames) if box is None else box_mask(box, shape)
    except (InputFileError, ParameterError) as exc:
        fail(f"{what}: {exc}")
        raise AssertionError from None  # unreachable


def _part_of_reference(
    fused: Path, reference: Path | None, frames: str | None
) -> tuple[str | None, str | None]:
    """``(part, fused_frames)``: the part A:B of the reference (RAW, else --gt) that FUSED
    was made from (None: they line up as they are), and the frames of FUSED to read.

    The part is the range a ``fuse4d run`` output folder records (``--frames`` must then name
    the same), else ``--frames``; it is taken where FUSED has exactly its length and the
    reference another. Otherwise ``--frames`` selects the frames of every input."""
    from ..io import count_frames, resolve_frames

    recorded = None
    if fused.is_dir():  # a `fuse4d run` folder (or --engine dask store) records its part
        from ..report._sources import recorded_reader_options

        value = recorded_reader_options(fused).get("frames")
        recorded = None if value is None else str(value)
    if reference is None:
        if recorded is not None and frames is not None:  # its frames are not the input's
            fail(
                f"--frames {frames}: {fused} holds frames {recorded} of its input (its run "
                "records them), numbered from 0 here; drop --frames, or give the input as RAW"
            )
        return None, frames
    if recorded is None and frames is None:
        return None, None
    total = count_frames(reference)
    if (
        recorded is not None
        and frames is not None
        and resolve_frames(frames, total) != resolve_frames(recorded, total)
    ):
        fail(
            f"--frames {frames}: {fused} was fused from frames {recorded} of its input (its "
            "run records them); drop --frames"
        )
    candidate = recorded if recorded is not None else frames
    fused_total = count_frames(fused)
    if fused_total != total and fused_total == len(resolve_frames(candidate, total)):
        return candidate, None
    return None, None if recorded is not None else frames


def _mismatch(
    path: Path,
    shape: tuple[int, ...],
    reference: Path,
    ref_shape: tuple[int, ...],
    part: str | None,
) -> str:
    """The one-line error for inputs that do not line up frame for frame."""
    what = f" (frames {part} of it)" if part is not None else ""
    return (
        f"{path}: {shape[0]} frames of {shape[1]}x{shape[2]}, but {reference}{what} has "
        f"{ref_shape[0]} of {ref_shape[1]}x{ref_shape[2]}: they are scored frame for frame. "
        "For the output of `fuse4d run --frames A:B`, give the same --frames A:B (FUSED is "
        "then read whole, RAW and --gt at A:B)"
    )


@app.command("metrics")
def metrics_command(
    inputs: Annotated[
        list[Path],
        typer.Argument(
            help="INPUT, or RAW FUSED: two sequences scored on one ROI (the ROI of RAW). "
            "Only RAW FUSED compares methods: INPUT alone is scored on its own ROI, static "
            "pixels and noise.",
            show_default=False,
        ),
    ],
    gt: Annotated[
        Path | None,
        typer.Option(
            help="Ground-truth depth: a sequence (its depth_gt or depth), frame for frame "
            "with RAW (INPUT)."
        ),
    ] = None,
    frames: Annotated[
        str | None,
        typer.Option(
            help="Frame range A:B (0-based, B excluded) of every input. Where FUSED (INPUT) "
            "is `fuse4d run --frames A:B`'s output (it has B-A frames, RAW or --gt more), "
            "the part of RAW and --gt it was made from: FUSED is read whole. A `fuse4d run` "
            "output folder records its part; it is read from there (--frames must then name "
            "the same).",
            callback=frame_range,
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="One JSON object on stdout.")] = False,
    roi: Annotated[
        str | None,
        typer.Option(
            help="Pixels to score, for every metric but the shape (Eq. 8 keeps its own region, "
            "EVALUATION §2): a box R0:R1,C0:C1 (px, as in `fuse4d report`), .npz (key "
            "roi/mask/mask_gt) or .npy (nonzero = in), image (>= 50 % = in) or a recording "
            "with masks."
        ),
    ] = None,
    static_mask: Annotated[
        str | None,
        typer.Option(
            "--static-mask",
            help="Pixels known static, for the flicker (as --roi; (T, H, W): static in every "
            "frame).",
        ),
    ] = None,
    window: Annotated[int, typer.Option(help="Roughness window n (odd, px).")] = 5,
    max_step: Annotated[
        float,
        typer.Option(
            "--max-step", help="Default ROI: floor of the depth-step limit between neighbours (mm)."
        ),
    ] = 10.0,
    noise_quad: Annotated[
        float | None,
        typer.Option(
            "--noise-quad",
            help="The sensor's depth-noise coefficient q (1/mm; noise std about q z^2): the "
            "step limit max(1 mm, 2.5 q z^2) of the bad-pixel count at the noise model's "
            "step limit, of the default ROI and of the static pixels. Default: estimated "
            "from RAW (the q that RAW FUSED prints); for INPUT alone that count is n/a "
            "without it.",
        ),
    ] = None,
    shape: Annotated[
        bool, typer.Option(help="Shape correctness for the synthetic ball (slow at full size).")
    ] = True,
) -> None:
    """Roughness (Eq. 7), RMS residual, flicker, and (with GT) RMSE, bad pixels, shape (Eq. 8).

    With two inputs RAW FUSED, both are scored on the same pixels (ROI and static pixels of
    RAW) and the same noise model (q of RAW): the comparable mode. INPUT alone is scored on
    its own ROI and static pixels, so two such scores do not compare methods, and the bad
    pixels at the noise model's step limit need --noise-quad (a smoothed output's own q is
    far smaller than the sensor's). The policy (ROI, static pixels, same pixels) is that of
    fuse4d.metrics.evaluate.
    """
    from ..io import count_frames, load_sequence, resolve_frames
    from ..metrics import evaluate

    if len(inputs) not in (1, 2):
        fail(f"give INPUT or RAW FUSED, got {len(inputs)} paths")
    if window < 3 or window % 2 == 0:
        fail(f"--window must be an odd integer >= 3, got {window}")
    if not (math.isfinite(max_step) and max_step > 0):
        fail(f"--max-step must be a depth step > 0 mm, got {max_step}")
    if noise_quad is not None and not (math.isfinite(noise_quad) and noise_quad >= 0):
        fail(f"--noise-quad must be a depth-noise coefficient q >= 0 (1/mm), got {noise_quad}")
    # RAW (else --gt) is what FUSED (INPUT) is lined up with, frame for frame
    reference = inputs[0] if len(inputs) == 2 else gt
    part, fused_frames = _part_of_reference(inputs[-1], reference, frames)
    ref_frames = fused_frames if part is None else part
    seqs = []
    selections = [fused_frames] if len(inputs) == 1 else [ref_frames, fused_frames]
    for path, selection in zip(inputs, selections, strict=True):
        with progress_bar(f"loading {path.name}", None) as bar:
            seqs.append(load_sequence(path, frames=selection, progress=progress_callback(bar)))
    if len(seqs) == 2 and seqs[0].depth.shape != seqs[1].depth.shape:
        fail(_mismatch(inputs[1], seqs[1].depth.shape, inputs[0], seqs[0].depth.shape, part))
    raw_seq, out_seq = (None, seqs[0]) if len(seqs) == 1 else (seqs[0], seqs[1])
    numbered = reference if part is not None and reference is not None else inputs[0]
    start = resolve_frames(ref_frames, count_frames(numbered)).start if ref_frames else 0
    gtruth = next((s.ground_truth for s in seqs if s.ground_truth is not None), None)
    if gt is not None:
        from ..sequence import GroundTruth

        ref = load_sequence(gt, frames=ref_frames)
        depth_gt = (
            ref.ground_truth.depth
            if ref.ground_truth is not None and ref.ground_truth.depth is not None
            else ref.depth
        )
        if depth_gt.shape != out_seq.depth.shape:
            fail(_mismatch(inputs[-1], out_seq.depth.shape, gt, depth_gt.shape, part))
        base = gtruth if gtruth is not None else GroundTruth()
        gtruth = dataclasses.replace(base, depth=depth_gt)
    t, h, w = out_seq.depth.shape
    if window > min(h, w):
        fail(f"--window {window}: larger than the {w}x{h} image")
    # a (T, H, W) mask file is numbered as the recording it belongs to: RAW's frames
    region = None if roi is None else _read_region(roi, "--roi", ref_frames, (h, w))
    static = (
        None
        if static_mask is None
        else _read_region(static_mask, "--static-mask", ref_frames, (h, w))
    )
    if static is not None and static.ndim == 3:
        if static.shape[0] != t:
            fail(f"--static-mask: mask has {static.shape[0]} frames, the input {t}")
        static = static.all(axis=0)
    for name, mask in (("--roi", region), ("--static-mask", static)):
        if mask is not None and mask.shape[-2:] != (h, w):
            fail(f"{name}: mask is {mask.shape[-2]}x{mask.shape[-1]}, the input {h}x{w}")
        if mask is not None and not mask.any():  # every number was n/a, with no word why
            fail(f"{name}: the mask selects no pixel")
    if region is not None and region.ndim == 3 and region.shape[0] != t:
        fail(f"--roi: mask has {region.shape[0]} frames, the input {t}")
    with progress_bar("scoring", t) as bar:
        report = evaluate(
            out_seq,
            raw=raw_seq,
            ground_truth=gtruth,
            roi=region,
            static=static,
            window=window,
            max_step=max_step,
            noise_quad=noise_quad,
            shape=shape,
            progress=progress_callback(bar),
        )
    result: dict[str, Any] = {
        "inputs": [str(p) for p in inputs],
        "frames": [start, start + t],
        "size": [h, w],
        **report.to_dict(),
    }
    if noise_quad is not None and math.isfinite(report.noise_quad):  # (used: there is GT)
        result["noise_quad_description"] = "given (--noise-quad)"
    if roi is not None:
        box = _box(roi)
        result["roi"]["description"] = (
            f"mask from {roi}"
            if box is None
            else f"box rows {box[0]}:{box[1]}, columns {box[2]}:{box[3]}"
        )
    from .._json import json_safe

    result = json_safe(result)
    if as_json:
        out_console.file.write(json.dumps(result, allow_nan=False) + "\n")
        out_console.file.flush()
        return
    _print_table(result)


def _print_table(result: dict[str, Any]) -> None:
    from ..metrics.evaluate import METRIC_MEANINGS

    def fmt(value: Any, digits: int = 4) -> str:
        return "n/a" if value is None else f"{value:.{digits}g}"

    two = "raw" in result
    names = result["inputs"]
    table = Table(title=f"fuse4d metrics: {' vs '.join(names)}", show_header=True)
    table.add_column("metric")
    if two:
        table.add_column(f"raw ({Path(names[0]).name})", justify="right")
    table.add_column(Path(names[-1]).name if two else "value", justify="right")
    table.add_column("unit / what it means")

    def row(label: str, key: str, note: str, scale: float = 1.0, digits: int = 4) -> None:
        vals = [result[k].get(key) for k in (("raw", "output") if two else ("output",))]
        cells = [fmt(None if v is None else scale * v, digits) for v in vals]
        table.add_row(label, *cells, note)

    def info(label: str, value: str, note: str) -> None:
        table.add_row(label, *([value, ""] if two else [value]), note)

    info("frames", f"{result['frames'][0]}:{result['frames'][1]}", "")
    info("ROI pixels (all frames)", str(result["roi"]["pixels"]), result["roi"]["description"])
    info(
        "ROI pixels scored (all frames)",
        str(result["roi"]["pixels_scored"]),
        "Eq. 7 defined" + (" in both" if two else ""),
    )
    info("static pixels", str(result["static"]["pixels"]), result["static"]["description"])
    for key in ("roughness_mean", "roughness_std", "rms_residual"):
        label, unit = METRIC_MEANINGS[key]
        row(
            label,
            key,
            unit + (f", {result['window']}x{result['window']}" if key != "roughness_std" else ""),
        )
    # the mean is the headline: the median reads 0 on quantised depth whose pixels mostly
    # never leave their level in a short clip, however much the others flicker
    for key in ("flicker_step_mean", "flicker_std_mean", "flicker_std_median"):
        label, unit = METRIC_MEANINGS[key]
        row(label, key, unit)
    row(*METRIC_MEANINGS["fill_rate"][:1], "fill_rate", METRIC_MEANINGS["fill_rate"][1])
    # with ground truth, shown even where the output has no depth at all (bad = 100 %)
    if result["output"].get("bad_1mm") is not None:
        # with --roi the whole-image RMSE is the ROI's, the row above
        given = result["roi"].get("given", False)
        for key in (
            ("rmse_roi", "bad_1mm", "bad_steps")
            if given
            else ("rmse_roi", "rmse", "bad_1mm", "bad_steps")
        ):
            label, unit = METRIC_MEANINGS[key]
            if key == "rmse_roi" and given:
                unit += " (the given one: no whole-image RMSE with --roi)"
            if key == "bad_steps":
                q = result.get("noise_quad")
                unit += (
                    f"; q = {q:.3g} /mm ({result.get('noise_quad_description', '')})"
                    if q is not None
                    else f"; {result.get('noise_quad_description', '')}"
                )
            row(label, key, unit)
    if "shape" in result["output"]:
        for key, label in (
            ("c_3d_mean", "shape C_3D (Eq. 8)"),
            ("c_minimal_mean", "shape C_minimal"),
            ("c_profile_mean", "shape C_profile"),
        ):
            vals = [
                result[k]["shape"].get(key) for k in (("raw", "output") if two else ("output",))
            ]
            note = "%" + ("" if key != "c_3d_mean" else f", {result.get('shape_region', '')}")
            table.add_row(label, *[fmt(None if v is None else 100 * v, 6) for v in vals], note)
    out_console.print(table)
