"""Recordings of depth cameras: detection by magic bytes and the options their readers take.

=========  ===========================================  ==========================  =========
format     files                                        reader                      needs
=========  ===========================================  ==========================  =========
rosbag     ROS 1 ``.bag``; ROS 2 ``.db3``/``.mcap`` (bare  :class:`.RosbagReader`      rosbags
           or rosbag2 folder); RealSense ``.bag``/``.db3``
mkv        Azure Kinect / Orbbec ``.mkv``; fuse4d FFV1    :class:`.MkvReader`         av
zarr       ``*.zarr`` v3 store written by fuse4d          :class:`.ZarrReader`        zarr
=========  ===========================================  ==========================  =========

All three need the ``sensors`` extra: ``pip install "fuse4d[sensors]"``.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

from ..errors import ParameterError
from .mkv import is_matroska
from .rosbag import bag_kind
from .zarrstore import is_zarr_store

__all__ = ["SENSOR_FORMATS", "SENSOR_OPTIONS", "check_sensor_options", "detect_sensor_format"]

#: Layouts read from camera recordings (see the table above).
SENSOR_FORMATS = ("rosbag", "mkv", "zarr")
#: Reader options beyond ``depth_unit_mm``/``intrinsics``, by layout.
SENSOR_OPTIONS: dict[str, tuple[str, ...]] = {
    "rosbag": ("depth_topic", "intensity_topic", "intensity"),
    "mkv": ("undistort",),
    "zarr": (),
}


def detect_sensor_format(path: str | PathLike[str]) -> str | None:
    """``"rosbag"``, ``"mkv"`` or ``"zarr"`` when ``path`` is such a recording, else None.

    Files are recognised by their first bytes (``#ROSBAG V2.0``, ``SQLite format 3``,
    ``\\x89MCAP``, the EBML signature of Matroska), whatever their extension; folders by a
    rosbag2 ``metadata.yaml`` or a zarr store (v3 ``zarr.json``, v2 ``.zgroup``).
    """
    p = Path(path)
    if bag_kind(p) is not None:
        return "rosbag"
    if p.is_file() and is_matroska(p):
        return "mkv"
    if is_zarr_store(p):
        return "zarr"
    return None


def check_sensor_options(fmt: str, options: dict[str, Any]) -> dict[str, Any]:
    """The options that were set (not None), refusing those that ``fmt`` does not take."""
    given = {k: v for k, v in options.items() if v is not None}
    allowed = SENSOR_OPTIONS.get(fmt, ())
    wrong = [k for k in given if k not in allowed]
    if wrong:
        where = ", ".join(f for f, opts in SENSOR_OPTIONS.items() if wrong[0] in opts) or "no"
        raise ParameterError(
            f"option {wrong[0]} does not apply to {fmt} input (it applies to {where} input)"
        )
    return given
