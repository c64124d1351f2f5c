"""The RealSense SDK post-processing chain (spatial → temporal → hole filling) on numpy frames.

Drives librealsense's own filters through ``pyrealsense2.software_device`` (PEERS.md §3): each
depth frame is injected as Z16 into a software depth sensor and the resulting ``rs.frame`` is
passed through ``spatial_filter``, ``temporal_filter`` and ``hole_filling_filter``. Needs the
optional extra ``fuse4d[realsense]`` (``pyrealsense2``) and, on Debian/Ubuntu, the system
package ``libusb-1.0-0``.

The chain runs in the depth domain (no disparity transform: a software sensor without a
stereo baseline passes Z16 through ``disparity_transform`` unchanged, PEERS.md §3). Depth is
quantised to ``depth_unit`` mm (20 µm by default), so the SDK's ``filter_smooth_delta``
thresholds are given here in mm and converted to units.
"""

from __future__ import annotations

import importlib.util

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._params import check_choice, check_int
from ..camera import Intrinsics
from ._common import check_inputs, iterate

__all__ = ["have_pyrealsense2", "realsense_chain"]

_HOLE_MODES = {"fill_from_left": 0, "farest_from_around": 1, "nearest_from_around": 2}


def have_pyrealsense2() -> bool:
    """True when ``pyrealsense2`` is importable (it also needs ``libusb-1.0-0`` at import)."""
    if importlib.util.find_spec("pyrealsense2") is None:
        return False
    try:
        import pyrealsense2  # noqa: F401
    except ImportError:
        return False
    return True


def _import_rs():
    try:
        import pyrealsense2 as rs
    except ImportError as exc:
        raise ImportError(
            "the 'realsense' baseline needs pyrealsense2: pip install 'fuse4d[realsense]' "
            f"(and apt-get install libusb-1.0-0) [{exc}]"
        ) from exc
    return rs


def realsense_chain(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 2,
    iterations: int = 1,
    depth_unit: float | None = None,
    spatial_alpha: float = 0.5,
    spatial_delta: float = 0.4,
    temporal_alpha: float = 0.4,
    temporal_delta: float = 0.4,
    persistence: int = 3,
    hole_filling: str | None = "farest_from_around",
) -> NDArray[np.float32]:
    """Intel RealSense SDK post-processing (spatial + temporal + hole filling).

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid (sent as 0).
    intensity : (T, H, W) ndarray or None
        Unused (common signature).
    intrinsics : Intrinsics
        Camera (passed to the software sensor's stream profile).
    size : int, default 2
        ``filter_passes``: the SDK's ``filter_magnitude`` of the spatial filter (number of
        its passes, 1–5; SDK default 2).
    iterations : int, default 1
        Repeated application of the whole chain (fresh filter state each time).
    depth_unit : float, optional
        Z16 quantisation step in mm; default 0.02 mm (20 µm) or coarser if the deepest pixel
        would overflow 16 bits.
    spatial_alpha, temporal_alpha : float, default 0.5, 0.4
        ``filter_smooth_alpha`` of the spatial / temporal filters (SDK defaults).
    spatial_delta, temporal_delta : float, default 0.4, 0.4
        ``filter_smooth_delta`` in mm (20 units of 20 µm, the SDK's default 20).
    persistence : int, default 3
        Temporal ``holes_fill`` persistency index (SDK default 3: valid in 2 of the last 4).
    hole_filling : {"fill_from_left", "farest_from_around", "nearest_from_around"} or None
        Mode of the hole-filling filter (SDK default "farest_from_around"); None skips it.

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm), quantised to ``depth_unit``; holes are filled by the chain's
        temporal persistence and hole-filling filter (part of the method); NaN where the
        output is 0.
    """
    d, _ = check_inputs(depth, intensity, intrinsics)
    magnitude = check_int("realsense_chain", "size", size, minimum=1, maximum=5)
    check_choice("realsense_chain", "hole_filling", hole_filling, (*_HOLE_MODES, None))
    rs = _import_rs()
    finite_max = float(np.nanmax(d)) if np.isfinite(d).any() else 1.0
    unit_mm = float(depth_unit) if depth_unit is not None else max(0.02, finite_max / 65000.0)
    if not unit_mm > 0 or finite_max / unit_mm > 65535:
        raise ValueError(f"depth_unit {unit_mm} mm cannot represent depth up to {finite_max} mm")

    def to_units(mm: float) -> float:
        return max(1.0, round(mm / unit_mm))

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        n, h, w = cur.shape
        device = rs.software_device()
        sensor = device.add_sensor("Depth")
        intr = rs.intrinsics()
        intr.width, intr.height = w, h
        intr.fx, intr.fy = intrinsics.fx, intrinsics.fy
        intr.ppx, intr.ppy = intrinsics.cx, intrinsics.cy
        intr.model = rs.distortion.none
        intr.coeffs = [0.0] * 5
        stream = rs.video_stream()
        stream.type, stream.index, stream.uid = rs.stream.depth, 0, 0
        stream.width, stream.height, stream.fps = w, h, 30
        stream.bpp, stream.fmt, stream.intrinsics = 2, rs.format.z16, intr
        profile = sensor.add_video_stream(stream)
        sensor.add_read_only_option(rs.option.depth_units, unit_mm / 1000.0)
        queue = rs.frame_queue(2, keep_frames=True)
        sensor.open(profile)
        sensor.start(queue)
        spatial = rs.spatial_filter()
        spatial.set_option(rs.option.filter_magnitude, magnitude)
        spatial.set_option(rs.option.filter_smooth_alpha, float(spatial_alpha))
        spatial.set_option(rs.option.filter_smooth_delta, to_units(spatial_delta))
        temporal = rs.temporal_filter()
        temporal.set_option(rs.option.filter_smooth_alpha, float(temporal_alpha))
        temporal.set_option(rs.option.filter_smooth_delta, to_units(temporal_delta))
        temporal.set_option(rs.option.holes_fill, int(persistence))
        holes = None
        if hole_filling is not None:
            holes = rs.hole_filling_filter()
            holes.set_option(rs.option.holes_fill, _HOLE_MODES[hole_filling])
        out = np.empty_like(cur)
        try:
            for t in range(n):
                z = np.where(np.isfinite(cur[t]), np.rint(cur[t] / unit_mm), 0)
                frame = rs.software_video_frame()
                frame.pixels = np.ascontiguousarray(z.astype(np.uint16))
                frame.stride, frame.bpp = 2 * w, 2
                frame.timestamp = t * 1000.0 / 30.0
                frame.domain = rs.timestamp_domain.hardware_clock
                frame.frame_number = t + 1
                frame.profile = profile.as_video_stream_profile()
                frame.depth_units = unit_mm / 1000.0
                sensor.on_video_frame(frame)
                result = temporal.process(spatial.process(queue.wait_for_frame(5000)))
                if holes is not None:
                    result = holes.process(result)
                data = np.asanyarray(result.get_data()).astype(np.float32) * np.float32(unit_mm)
                out[t] = np.where(data > 0, data, np.nan)
        finally:
            sensor.stop()
            sensor.close()
        return out

    return iterate(step, d, iterations, owner="realsense_chain")
