"""Command-line options shared by the commands that read camera recordings (info, run, baseline, …).

ROS bags and RealSense files: ``--depth-topic``, ``--intensity-topic``, ``--intensity``;
Azure Kinect ``.mkv``: ``--no-undistort``; ``run``, ``live`` and ``baseline`` also share
``--depth-unit-mm`` and ``--intrinsics``; ``convert`` and ``baseline`` the output's unit
(``--out-depth-unit-mm``). :func:`reader_options` turns the given ones into
keyword arguments of :func:`fuse4d.io.open_frames` (options left unset are not passed, so
other layouts are unaffected).
"""

from __future__ import annotations

from typing import Annotated, Any

import typer

__all__ = [
    "CameraOverrideOpt",
    "DepthTopicOpt",
    "DepthUnitOpt",
    "IntensityOpt",
    "IntensityTopicOpt",
    "NoUndistortOpt",
    "OutDepthUnitOpt",
    "frame_range",
    "reader_options",
]

DepthTopicOpt = Annotated[
    str | None,
    typer.Option("--depth-topic", help="ROS bag: depth topic (default: chosen by encoding)."),
]
IntensityTopicOpt = Annotated[
    str | None,
    typer.Option("--intensity-topic", help="ROS bag: intensity topic (default: IR, else colour)."),
]
IntensityOpt = Annotated[
    str | None,
    typer.Option(
        "--intensity",
        help="ROS bag / RealSense: guide stream: auto (IR if recorded, else colour), ir, or "
        "color (resampled onto the depth grid with the recorded extrinsics).",
    ),
]
NoUndistortOpt = Annotated[
    bool,
    typer.Option("--no-undistort", help="Azure Kinect .mkv: keep the lens distortion."),
]

DepthUnitOpt = Annotated[
    float | None,
    typer.Option("--depth-unit-mm", "--depth-unit", help="Millimetres per stored depth unit."),
]
OutDepthUnitOpt = Annotated[
    float | None,
    typer.Option(
        "--out-depth-unit-mm",
        help="Folder / .mkv output: mm per stored depth unit (default: the input's own, "
        "or 1 mm for float depth).",
    ),
]
CameraOverrideOpt = Annotated[
    str | None, typer.Option("--intrinsics", help="Camera override: 'fx,fy,cx,cy' or file.")
]


def frame_range(value: str | None) -> str | None:
    """``--frames`` of run, convert, metrics and report: a range ``A:B``, never a bare number.

    ``bench``, ``live``, ``synth`` and ``demo`` take ``--frames N`` as a count, so ``run
    --frames 12`` reads as "12 frames", while the range syntax alone (Python indexing) would
    take frame 12 alone; the bare number is refused with both spellings named.
    """
    text = (value or "").strip()
    if text.lstrip("+-").isdigit():
        k = int(text)
        count = f"':{k}' is the first {k} frames" if k >= 0 else f"'{k}:' is the last {-k} frames"
        alone = f"{k}:{k + 1}" if k != -1 else "-1:"
        raise typer.BadParameter(
            f"expects a range A:B, got {value!r}: {count}, '{alone}' frame {k} alone"
        )
    return value


def reader_options(
    depth_topic: str | None = None,
    intensity_topic: str | None = None,
    intensity: str | None = None,
    no_undistort: bool = False,
    *,
    depth_unit_mm: float | None = None,
    intrinsics: str | None = None,
) -> dict[str, Any]:
    """Keyword arguments for :func:`fuse4d.io.open_frames` from the options that were given
    (``depth_unit_mm`` in mm per stored unit and the ``intrinsics`` override last)."""
    out: dict[str, Any] = {
        "depth_topic": depth_topic,
        "intensity_topic": intensity_topic,
        "intensity": intensity,
        "undistort": False if no_undistort else None,
        "depth_unit_mm": depth_unit_mm,
        "intrinsics": intrinsics,
    }
    return {k: v for k, v in out.items() if v is not None}
