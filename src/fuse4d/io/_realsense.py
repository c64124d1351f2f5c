"""What librealsense writes next to the images of a RealSense recording (``.bag``/``.db3``).

Topics follow ``/device_0/sensor_N/<Stream>_<index>/...`` (see ``docs/formats.md``):
depth units as an option (ROS 1 ``std_msgs/Float32`` in metres under ``option/Depth Units`` or
``option/Depth_Units``; ROS 2 a ``std_msgs/String`` such as ``'0.000100'``), per-stream
extrinsics under ``<Stream>/tf/<ref>`` (ROS 1 ``geometry_msgs/Transform``; ROS 2 a String
``rotation=r0,...,r8;translation=x,y,z`` with the rotation column-major, librealsense's
``rs2_extrinsics``) mapping the stream's frame to the reference stream's, and a nominal frame
rate in ``<Stream>/info`` (``realsense_msgs/StreamInfo`` or String ``encoding=Z16;fps=30``),
and the camera's name in ``/device_0/info`` (``diagnostic_msgs/KeyValue`` ``Name``, e.g.
``Intel RealSense D435``), from which :func:`realsense_sensor_kind` tells the depth technology.
"""

from __future__ import annotations

import re

import numpy as np

__all__ = [
    "is_realsense_topic",
    "parse_key_values",
    "quaternion_matrix",
    "realsense_sensor_kind",
    "sensor_prefix",
    "stream_prefix",
]

_STREAM = re.compile(r"^(/device_\d+/sensor_\d+/[A-Za-z]+_\d+)/")
_SENSOR = re.compile(r"^(/device_\d+/sensor_\d+)/")


def is_realsense_topic(topic: str) -> bool:
    """Whether a topic follows librealsense's recorder layout."""
    return _STREAM.match(topic) is not None


def stream_prefix(topic: str) -> str | None:
    """``/device_0/sensor_0/Depth_0`` for any topic of that stream, else None."""
    m = _STREAM.match(topic)
    return m.group(1) if m else None


def sensor_prefix(topic: str) -> str | None:
    """``/device_0/sensor_0`` for any topic of that sensor, else None."""
    m = _SENSOR.match(topic)
    return m.group(1) if m else None


#: RealSense product lines by model number: D4xx active stereo, L5xx lidar (time of flight,
#: mixed pixels at edges), SR3xx coded (structured) light.
_KINDS = (
    (re.compile(r"\bD4\d\d"), "active-stereo"),
    (re.compile(r"\bL5\d\d"), "tof"),
    (re.compile(r"\bSR3\d\d"), "structured-light"),
)


def realsense_sensor_kind(name: str) -> str | None:
    """The depth technology of a RealSense camera from its name (``Intel RealSense D435`` ->
    ``"active-stereo"``, ``... L515`` -> ``"tof"``, ``... SR305`` -> ``"structured-light"``);
    None for other names (a software device)."""
    for pattern, kind in _KINDS:
        if pattern.search(str(name).upper()):
            return kind
    return None


def parse_key_values(text: str) -> dict[str, str]:
    """``'a=1;b=x'`` → ``{"a": "1", "b": "x"}`` (librealsense's ROS 2 String messages)."""
    out: dict[str, str] = {}
    for item in str(text).split(";"):
        key, sep, value = item.partition("=")
        if sep:
            out[key.strip()] = value.strip()
    return out


def quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (normalised first; sign-invariant)."""
    q = np.array([w, x, y, z], dtype=np.float64)
    n = float(np.linalg.norm(q))
    if n == 0.0:
        return np.eye(3)
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
