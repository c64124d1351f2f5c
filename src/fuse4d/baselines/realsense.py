"""The RealSense SDK post-processing chain (spatial → temporal → hole filling) on numpy frames.

Drives librealsense's own filters through ``pyrealsense2.software_device`` (PEERS.md §3): each
depth frame is injected as Z16 into a software depth sensor and the resulting ``rs.frame`` is
passed through ``spatial_filter``, ``temporal_filter`` and ``hole_filling_filter``. Needs the
optional extra ``fuse4d[realsense]`` (``pyrealsense2``) and, on Debian/Ubuntu, the system
package ``libusb-1.0-0``.

The chain runs in the depth domain (no disparity transform: a software sensor without a
stereo baseline passes Z16 through ``disparity_transform`` unchanged, PEERS.md §3), with the
SDK's default options **in the recording's depth units**, as a RealSense user runs it: depth
that is in whole mm (a Kinect / RealSense / ToF recording) is sent in 1 mm units, so the
SDK's default ``filter_smooth_delta`` of 20 units is 20 mm; continuous (float) depth, which
has no units of its own, is sent in 20 µm units (the finest that fits 16 bits up to 1.3 m),
where 20 units are 0.4 mm (the paper's 0.2 mm sensor). The deltas can also be given in mm.

``domain="disparity"`` (the default for whole-mm recordings) runs the SDK's recommended
order for stereo depth: depth → disparity → spatial → temporal → depth → hole filling, with
the SDK's own ``disparity_transform`` pair: the software sensor declares a
``stereo_baseline`` (``baseline_mm``, 50 mm as on a D4xx) besides its depth units, so the
transform gives the SDK's float disparity (``disparity32``, 1/32 px with the recording's
focal length) and the filters run their float path, as on a D4xx. The SDK's default delta
of 20 units is then 0.625 px of disparity — on Kinect-class depth, whose disparity steps are
1/8 px, the filters act as on a D4xx. (Disparity sent as integer Z16 steps instead biased
depth towards the camera: the SDK's integer spatial filter adds ~+4 steps to the mean, up to
-50 mm at 4.5 m.) Float depth stays in the depth domain.
"""

from __future__ import annotations

import importlib.util
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._params import check_choice, check_int, check_number
from ..camera import Intrinsics
from ..errors import ParameterError
from ._common import check_inputs, iterate

__all__ = ["have_pyrealsense2", "realsense_chain", "recording_depth_unit"]

_HOLE_MODES = {"fill_from_left": 0, "farest_from_around": 1, "nearest_from_around": 2}


#: the SDK's default filter_smooth_delta of the spatial and temporal filters, depth units
_SDK_DELTA_UNITS = 20


def recording_depth_unit(depth: ArrayLike) -> float:
    """The depth unit (mm) a RealSense user would record ``depth`` in.

    Parameters
    ----------
    depth : ndarray
        Depth in mm, NaN = invalid.

    Returns
    -------
    float
        1.0 when every valid value is a whole number of mm (a 16-bit sensor recording) and
        fits 16 bits; else 0.02 mm (20 µm), or coarser (max depth / 65000) when 20 µm would
        overflow 16 bits.

    Examples
    --------
    >>> recording_depth_unit(np.array([1000.0, 2345.0, np.nan]))
    1.0
    >>> recording_depth_unit(np.array([1000.3, 999.8]))
    0.02
    """
    d = np.asarray(depth, dtype=np.float64)
    valid = d[np.isfinite(d) & (d > 0)]
    if valid.size == 0:
        return 0.02
    top = float(valid.max())
    if top <= 65535 and np.array_equal(valid, np.rint(valid)):
        return 1.0
    return max(0.02, top / 65000.0)


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


def _software_sensor(rs, intrinsics: Intrinsics, unit_m: float, baseline_mm: float | None = None):
    """A started ``software_device`` depth sensor: (device, sensor, profile, queue).

    ``unit_m``: its depth units (m); ``baseline_mm``: the stereo baseline it declares (mm),
    which makes ``rs.disparity_transform`` convert its frames (None: passed through).
    """
    w, h = intrinsics.width, intrinsics.height
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
    sensor.add_read_only_option(rs.option.depth_units, unit_m)
    if baseline_mm is not None:
        sensor.add_read_only_option(rs.option.stereo_baseline, float(baseline_mm))
    queue = rs.frame_queue(2, keep_frames=True)
    sensor.open(profile)
    sensor.start(queue)
    return device, sensor, profile, queue


def _push(rs, handle, z16: NDArray, t: int, unit_m: float):
    """Inject one Z16 frame into the software sensor; the rs.frame that comes out."""
    _device, sensor, profile, queue = handle
    frame = rs.software_video_frame()
    frame.pixels = np.ascontiguousarray(z16.astype(np.uint16))
    frame.stride, frame.bpp = 2 * z16.shape[1], 2
    frame.timestamp = t * 1000.0 / 30.0
    frame.domain = rs.timestamp_domain.hardware_clock
    frame.frame_number = t + 1
    frame.profile = profile.as_video_stream_profile()
    frame.depth_units = unit_m
    sensor.on_video_frame(frame)
    return queue.wait_for_frame(5000)


def realsense_chain(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 2,
    iterations: int = 1,
    depth_unit: float | None = None,
    domain: str = "auto",
    baseline_mm: float = 50.0,
    spatial_alpha: float = 0.5,
    spatial_delta: float | None = None,
    temporal_alpha: float = 0.4,
    temporal_delta: float | None = None,
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
        Camera (passed to the software sensor's stream profile; ``fx`` for disparity).
    size : int, default 2
        ``filter_passes``: the SDK's ``filter_magnitude`` of the spatial filter (number of
        its passes, 1–5; SDK default 2).
    iterations : int, default 1
        Repeated application of the whole chain (fresh filter state each time).
    depth_unit : float, optional
        Z16 quantisation step in mm; default: the recording's own unit, 1 mm when every
        valid depth is a whole number of mm (:func:`recording_depth_unit`), else 0.02 mm
        (20 µm), coarser if the deepest pixel would overflow 16 bits.
    domain : {"auto", "depth", "disparity"}, default "auto"
        Where the spatial and temporal filters run (module docstring): "auto" = disparity
        for whole-mm recordings (``depth_unit`` 1 mm), depth otherwise.
    baseline_mm : float, default 50
        Stereo baseline of the disparity transform, mm (D4xx: 50).
    spatial_alpha, temporal_alpha : float, default 0.5, 0.4
        ``filter_smooth_alpha`` of the spatial / temporal filters (SDK defaults).
    spatial_delta, temporal_delta : float, optional
        ``filter_smooth_delta``; default the SDK's default of 20 units (depth domain: 20
        depth units, 20 mm for whole-mm recordings and 0.4 mm for float depth; disparity
        domain: 20/32 px). Given: in mm (depth domain) or in 1/32 px (disparity domain).
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
    check_choice("realsense_chain", "domain", domain, ("auto", "depth", "disparity"))
    check_number("realsense_chain", "baseline_mm", baseline_mm, gt=0, finite=True)
    for name, value in (("spatial_delta", spatial_delta), ("temporal_delta", temporal_delta)):
        if value is not None:  # NaN / inf were internal errors, -5 acted as one step
            check_number("realsense_chain", name, value, gt=0, finite=True)
    rs = _import_rs()
    finite = d[np.isfinite(d)]
    finite_max = float(finite.max()) if finite.size else 1.0
    finite_min = float(finite.min()) if finite.size else 1.0
    if depth_unit is not None:
        check_number("realsense_chain", "depth_unit", depth_unit, gt=0, finite=True)
    unit_mm = float(depth_unit) if depth_unit is not None else recording_depth_unit(d)
    if not unit_mm > 0 or finite_max / unit_mm > 65535:
        raise ParameterError(
            f"realsense_chain.depth_unit {unit_mm:g} mm cannot represent depth up to "
            f"{finite_max:.0f} mm in 16 bits; give a unit > {finite_max / 65535:.3g} mm"
        )
    if finite.size and finite_min / unit_mm < 0.5:  # rounded to 0 = no depth: all NaN out
        raise ParameterError(
            f"realsense_chain.depth_unit {unit_mm:g} mm rounds the nearest depth "
            f"({finite_min:.4g} mm) to 0 (no depth); give a unit < {2 * finite_min:.4g} mm"
        )
    if domain == "auto":
        domain = "disparity" if unit_mm == 1.0 else "depth"

    def to_units(value: float | None) -> float:
        """A delta in the SDK's units: depth units, or 1/32 px of disparity."""
        if value is None:
            return float(_SDK_DELTA_UNITS)
        if domain == "disparity":
            return max(1.0, round(float(value)))
        return max(1.0, round(float(value) / unit_mm))

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        n = cur.shape[0]
        unit_m = unit_mm / 1000.0
        disparity = domain == "disparity"
        sensor = _software_sensor(rs, intrinsics, unit_m, baseline_mm if disparity else None)
        to_disparity, to_depth = rs.disparity_transform(True), rs.disparity_transform(False)
        spatial = rs.spatial_filter()
        _set_option(spatial, rs.option.filter_magnitude, magnitude, "size")
        _set_option(spatial, rs.option.filter_smooth_alpha, float(spatial_alpha), "spatial_alpha")
        _set_option(
            spatial, rs.option.filter_smooth_delta, to_units(spatial_delta), "spatial_delta"
        )
        temporal = rs.temporal_filter()
        _set_option(
            temporal, rs.option.filter_smooth_alpha, float(temporal_alpha), "temporal_alpha"
        )
        _set_option(
            temporal, rs.option.filter_smooth_delta, to_units(temporal_delta), "temporal_delta"
        )
        _set_option(temporal, rs.option.holes_fill, int(persistence), "persistence")
        holes = None
        if hole_filling is not None:
            holes = rs.hole_filling_filter()
            holes.set_option(rs.option.holes_fill, _HOLE_MODES[hole_filling])
        out = np.empty_like(cur)
        try:
            for t in range(n):
                ok = np.isfinite(cur[t])
                z = np.where(ok, np.rint(cur[t] / unit_mm), 0)
                result = _push(rs, sensor, z, t, unit_m)
                if disparity:
                    result = to_disparity.process(result)
                result = temporal.process(spatial.process(result))
                if disparity:
                    result = to_depth.process(result)
                if holes is not None:
                    result = holes.process(result)
                data = np.asanyarray(result.get_data()).astype(np.float64) * unit_mm
                out[t] = np.where(data > 0, data, np.nan).astype(np.float32)
        finally:
            sensor[1].stop()
            sensor[1].close()
        return out

    return iterate(step, d, iterations, owner="realsense_chain")


def _set_option(block: Any, option: Any, value: float, knob: str) -> None:
    """``block.set_option(option, value)``, with a value outside the SDK's range named as the
    knob it came from (pyrealsense2 raises a bare 'out of range value for argument')."""
    rng = block.get_option_range(option)
    if not rng.min <= value <= rng.max:
        raise ParameterError(
            f"realsense_chain.{knob}: {value:g} is outside the SDK's range "
            f"[{rng.min:g}, {rng.max:g}]"
            + (
                " (in SDK steps: the knob's mm or disparity value converted)"
                if "delta" in knob
                else ""
            )
        )
    block.set_option(option, value)
