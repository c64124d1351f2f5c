"""CLI commands ``info`` (describe a recording), ``convert`` (another layout, or a part) and
``export-ply`` (one frame as a point cloud)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import typer

from ._app import app, fail, out_console, progress_bar, progress_callback, track
from ._recording_opts import (
    DepthTopicOpt,
    IntensityOpt,
    IntensityTopicOpt,
    NoUndistortOpt,
    OutDepthUnitOpt,
    frame_range,
    reader_options,
)

__all__ = ["convert_command", "export_ply_command", "info_command"]

#: The names of :data:`fuse4d.io.CAMERA_PRESETS`, written out so that ``--help`` does not
#: import the readers (``tests/test_cli_startup.py`` checks that they agree).
#: Frames ``fuse4d info`` reads for the valid fraction and depth range (``--all-frames``: all).
INFO_SAMPLE_FRAMES = 10

CAMERA_PRESET_NAMES = ("freiburg1", "freiburg2", "freiburg3", "kinect-v1")

_INTRINSICS_HELP = (
    "Camera override: a preset (" + ", ".join(CAMERA_PRESET_NAMES) + "), 'fx,fy,cx,cy' in px, "
    "or a camera.json path. Required for TUM folders without camera.json."
)

InputArg = Annotated[
    Path,
    typer.Argument(
        metavar="INPUT",
        help="A .npz file, a sequence folder (frame folder, TUM, cv2-xml, frames-json), a "
        "ROS/RealSense .bag/.db3/.mcap, an Azure Kinect or FFV1 .mkv, or a .zarr store.",
        show_default=False,
    ),
]
IntrinsicsOpt = Annotated[str | None, typer.Option("--intrinsics", help=_INTRINSICS_HELP)]
UnitOpt = Annotated[
    float | None,
    typer.Option(
        "--depth-unit-mm",
        "--depth-unit",
        help="Millimetres per stored depth unit (overrides the file; e.g. 0.1 for a D405).",
    ),
]
FormatOpt = Annotated[
    str | None,
    typer.Option(
        "--format",
        help="Force the input layout: npz, folder, tum, cv2-xml, frames-json, rosbag, mkv, zarr.",
    ),
]


@app.command("info")
def info_command(
    input_path: InputArg,
    intrinsics: IntrinsicsOpt = None,
    depth_unit_mm: UnitOpt = None,
    input_format: FormatOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    depth_topic: DepthTopicOpt = None,
    intensity_topic: IntensityTopicOpt = None,
    intensity: IntensityOpt = None,
    no_undistort: NoUndistortOpt = False,
    all_frames: Annotated[
        bool,
        typer.Option(
            "--all-frames",
            help=f"Valid fraction and depth range over every frame (default: at most "
            f"{INFO_SAMPLE_FRAMES} evenly spaced frames, so that info answers at once).",
        ),
    ] = False,
) -> None:
    """Describe a recording: layout, frames, size, valid fraction, depth range, camera, GT.

    For camera recordings also the streams/topics (messages, rate, size, encoding) and which
    of them are used as depth and intensity. The valid fraction and depth range are computed
    on at most 10 evenly spaced frames (first and last included; the output says how many),
    or on all of them with --all-frames.
    """
    import numpy as np

    from ..fov import field_of_view
    from ..io import open_frames

    reader = open_frames(
        input_path,
        format=input_format,
        **reader_options(
            depth_topic, intensity_topic, intensity, no_undistort,
            depth_unit_mm=depth_unit_mm, intrinsics=intrinsics,
        ),
    )  # fmt: skip
    with reader:
        n_valid = 0
        lo, hi = math.inf, -math.inf
        picked = stats_frames(len(reader), None if all_frames else INFO_SAMPLE_FRAMES)
        seen = np.zeros(reader.intrinsics.shape, bool)  # pixels with depth in some frame
        for index in track(picked, "reading frames", total=len(picked)):
            frame = reader.read_frame(index)
            valid = np.isfinite(frame.depth)
            seen |= valid
            count = int(valid.sum())
            if count:
                n_valid += count
                lo = min(lo, float(np.nanmin(frame.depth)))
                hi = max(hi, float(np.nanmax(frame.depth)))
        k = reader.intrinsics
        total = len(picked) * k.width * k.height
        # the depth camera's field of view (A38: nothing is filled outside it)
        inside = field_of_view(np.where(seen, np.float32(1.0), np.float32(np.nan)))
        fov_px = int(inside.sum())
        ts = reader.timestamps
        summary = {
            "input": str(input_path),
            "format": reader.format,
            "frames": len(reader),
            "width": k.width,
            "height": k.height,
            "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy},
            "depth_unit_mm": reader.depth_unit_mm,
            "sensor": reader.sensor,
            "fps": reader.fps,
            "duration_s": None if ts is None else float(ts[-1] - ts[0]),
            "valid_fraction": n_valid / total if total else 0.0,
            "field_of_view_fraction": fov_px / inside.size,
            "valid_fraction_inside": n_valid / (len(picked) * fov_px) if fov_px else 0.0,
            "stats_frames": len(picked),
            "depth_min_mm": lo if n_valid else None,
            "depth_max_mm": hi if n_valid else None,
            "ground_truth": list(reader.ground_truth_keys),
            "notes": list(reader.notes),
            "streams": _streams(reader),
        }
    if as_json:
        from .._json import dumps

        print(dumps(summary))
        return
    sampled = (
        ""
        if len(picked) == len(reader)
        else f" ({len(picked)} of {len(reader)} frames, evenly spaced; --all-frames for all)"
    )
    rows = [
        ("input", summary["input"]),
        ("format", summary["format"]),
        ("frames", str(summary["frames"])),
        ("size", f"{k.width} x {k.height} px (W x H)"),
        ("intrinsics", f"fx={k.fx:g} fy={k.fy:g} cx={k.cx:g} cy={k.cy:g} px"),
        (
            "depth unit",
            "float mm"
            if reader.depth_unit_mm is None
            else f"{reader.depth_unit_mm:g} mm per stored unit",
        ),
        (
            "camera kind",
            "not stated"
            if reader.sensor is None
            else reader.sensor
            + (" (flying pixels removed by fuse4d run, A36)" if reader.sensor == "tof" else ""),
        ),
        ("fps", "not stored" if reader.fps is None else f"{reader.fps:g}"),
        (
            "timestamps",
            "not stored" if ts is None else f"{ts[0]:.6f} .. {ts[-1]:.6f} s ({len(ts)} values)",
        ),
        ("valid pixels", f"{100.0 * summary['valid_fraction']:.1f} %{sampled}"),
        ("depth covers", _field_of_view_row(inside, summary)),
        (
            "depth range",
            "no valid depth" if not n_valid else f"{lo:.1f} .. {hi:.1f} mm{sampled}",
        ),
        ("ground truth", ", ".join(summary["ground_truth"]) or "none"),
    ]
    rows += [("note", note) for note in summary["notes"]]
    rows += [("stream", _stream_row(s)) for s in summary["streams"]]
    for key, value in rows:
        out_console.print(f"{key + ':':<14}{value}", highlight=False, markup=False, soft_wrap=True)


def _field_of_view_row(inside: Any, summary: dict[str, Any]) -> str:
    """``fuse4d info``'s line on the depth camera's field of view (A38)."""
    if not summary["field_of_view_fraction"]:
        return "no valid depth"
    rows, cols = inside.any(axis=1).nonzero()[0], inside.any(axis=0).nonzero()[0]
    return (
        f"{100.0 * summary['field_of_view_fraction']:.1f} % of the image (rows "
        f"{rows[0]}-{rows[-1]}, columns {cols[0]}-{cols[-1]}: the depth camera's field of view, "
        f"where fuse4d run fills holes); {100.0 * summary['valid_fraction_inside']:.1f} % of its "
        "pixels valid"
    )


@app.command("convert")
def convert_command(
    input_path: InputArg,
    output: Annotated[
        Path,
        typer.Argument(
            metavar="OUTPUT",
            help="A .npz (keeps ground truth), an FFV1 .mkv, a .zarr store, else a frame folder.",
            show_default=False,
        ),
    ],
    frames: Annotated[
        str | None,
        typer.Option(
            "--frames",
            help="Only frames A:B (0-based, B excluded; 'A:' to the end).",
            callback=frame_range,
        ),
    ] = None,
    out_depth_unit_mm: OutDepthUnitOpt = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing output.")] = False,
    intrinsics: IntrinsicsOpt = None,
    depth_unit_mm: UnitOpt = None,
    input_format: FormatOpt = None,
    depth_topic: DepthTopicOpt = None,
    intensity_topic: IntensityTopicOpt = None,
    intensity: IntensityOpt = None,
    no_undistort: NoUndistortOpt = False,
) -> None:
    """Write a recording, or frames A:B of it, in another layout (streamed frame by frame).

    E.g. a RealSense .bag into a frame folder to share, a part of a long recording into a
    small .npz, or any input into the .npz that --set iterations=2 needs.
    """
    from ..io import convert_recording, open_frames

    options = reader_options(
        depth_topic, intensity_topic, intensity, no_undistort,
        depth_unit_mm=depth_unit_mm, intrinsics=intrinsics,
    )  # fmt: skip
    with progress_bar("converting", None) as bar:
        path = convert_recording(
            input_path,
            output,
            frames=frames,
            format=input_format,
            out_depth_unit_mm=out_depth_unit_mm,
            overwrite=force,
            progress=progress_callback(bar),
            **options,
        )
    with open_frames(path) as written:
        n, (h, w), fmt = len(written), written.shape, written.format
    part = ""
    if frames is not None:  # the frames written (a range past the end is cut, as in Python)
        part = f" (frames {_written_part(frames, n)} of {input_path})"
    out_console.print(
        f"wrote {path}: {fmt}, {n} frame{'' if n == 1 else 's'}{part}, {w}x{h} px (WxH)",
        highlight=False,
        markup=False,
        soft_wrap=True,
    )


def _written_part(frames: str, count: int) -> str:
    """The input's frames that ``convert --frames`` wrote, from the selection and the count
    written, without opening the input again (a bag's reader passes over its messages): A:A+n
    for a start counted from the beginning; the selection itself for one counted from the end."""
    from ..io._base import _parse_frame_string

    start = _parse_frame_string(frames).start
    if start is None or start >= 0:
        first = start or 0
        return f"{first}:{first + count}"
    return frames.strip()


@app.command("export-ply")
def export_ply_command(
    input_path: InputArg,
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Output .ply file.", show_default=False)
    ],
    frame: Annotated[
        int, typer.Option("--frame", help="0-based frame index (negative: from end).")
    ] = 0,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing output.")] = False,
    no_color: Annotated[
        bool, typer.Option("--no-color", help="Do not store intensity as gray colour.")
    ] = False,
    intrinsics: IntrinsicsOpt = None,
    depth_unit_mm: UnitOpt = None,
    input_format: FormatOpt = None,
    depth_topic: DepthTopicOpt = None,
    intensity_topic: IntensityTopicOpt = None,
    intensity: IntensityOpt = None,
    no_undistort: NoUndistortOpt = False,
) -> None:
    """Write one frame as a binary PLY point cloud (mm, camera frame; intensity as gray)."""
    import numpy as np

    from ..camera import depth_to_points
    from ..io import check_output, open_frames, write_ply

    check_output(output, overwrite=force, inputs=[input_path])
    if output.suffix.lower() != ".ply":
        fail(f"{output}: export-ply writes a PLY point cloud; give a name ending .ply")
    with open_frames(
        input_path,
        format=input_format,
        **reader_options(
            depth_topic, intensity_topic, intensity, no_undistort,
            depth_unit_mm=depth_unit_mm, intrinsics=intrinsics,
        ),
    ) as reader:  # fmt: skip
        n = len(reader)
        if not -n <= frame < n:
            fail(f"--frame {frame} is out of range: {input_path} has {n} frames (0..{n - 1})")
        data = reader.read_frame(frame)
        points = depth_to_points(data.depth, reader.intrinsics)
    if not np.isfinite(points).all(axis=-1).any():  # Open3D & co refuse a 0-vertex PLY
        fail(f"{input_path} (frame {data.index}): no valid depth, no point to export")
    count = write_ply(points, output, colors=None if no_color else data.intensity, overwrite=force)
    out_console.print(
        f"wrote {count} points (frame {data.index}) to {output}",
        highlight=False,
        markup=False,
        soft_wrap=True,
    )


def stats_frames(total: int, limit: int | None) -> list[int]:
    """Indices of the frames ``info`` reads: all, or ``limit`` evenly spaced ones.

    Parameters
    ----------
    total : int
        Frames in the recording.
    limit : int or None
        Most frames to read (``None``: all). The first and the last frame are always read.

    Returns
    -------
    list of int
        Sorted, distinct 0-based frame indices.
    """
    if limit is None or total <= limit:
        return list(range(total))
    if limit <= 1:
        return [0]
    return sorted({round(i * (total - 1) / (limit - 1)) for i in range(limit)})


def _streams(reader: object) -> list[dict[str, object]]:
    """Streams/topics of a camera recording (empty for other layouts)."""
    describe = getattr(reader, "describe_streams", None)
    return describe() if callable(describe) else []


def _stream_row(s: dict[str, object]) -> str:
    rate = s.get("rate_hz")
    used = f"  <- used as {s['used_as']}" if s.get("used_as") else ""
    return (
        f"{s['topic']}  [{s['type']}, {s['encoding'] or '?'}] {s['width']}x{s['height']}, "
        f"{s['messages']} msgs" + (f", {rate:.3g} Hz" if rate else "") + used
    )
