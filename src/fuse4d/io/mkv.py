"""Streaming reader of Matroska depth video through PyAV: Azure Kinect / Orbbec Femto
recordings (``k4arecorder``) and fuse4d's own lossless FFV1 depth video (:mod:`.video`).

Azure Kinect: the ``DEPTH`` and ``IR`` tracks (``b16g`` = 16-bit big-endian grey, depth in mm)
come from the same ToF sensor, so IR is pixel-registered with depth and is the intensity. The
intrinsics are those of the ``calibration.json`` attachment, converted from the normalised
sensor calibration to the recorded depth mode (tag ``K4A_DEPTH_MODE``; see
:data:`K4A_DEPTH_MODES`). The depth lens is radially distorted (Brown-Conrady, rational
k1..k6, p1, p2): by default frames are **undistorted** onto a pinhole grid with the same
``fx, fy, cx, cy`` (depth nearest-neighbour, so no depth is invented between surfaces; IR
bilinear) so that fuse4d's pinhole back-projection is exact. Timestamps are the tracks'
``pts`` (µs); in a fuse4d video only when it has a ``FUSE4D_T0`` tag (its writer makes pts up
for frames without times). DEPTH and intensity frames are paired by equal pts.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..camera import Intrinsics
from ..errors import InputFileError
from ._base import (
    Frame,
    IntrinsicsLike,
    SequentialReader,
    check_increasing_times,
    check_sensor_kind,
    depth_unit,
    resolve_intrinsics,
)
from ._extras import require
from ._rosimage import amplitude_to_gray, white_level

__all__ = ["K4A_DEPTH_MODES", "MkvReader", "is_matroska", "k4a_depth_camera"]

#: Depth mode → (calibration resolution, crop offset (x, y), output size (W, H)) in px, from the
#: Azure Kinect SDK's ``mode_specific_calibration.c``.
K4A_DEPTH_MODES: dict[str, tuple[int, tuple[int, int], tuple[int, int]]] = {
    "NFOV_2X2BINNED": (512, (96, 90), (320, 288)),
    "NFOV_UNBINNED": (1024, (192, 180), (640, 576)),
    "WFOV_2X2BINNED": (512, (0, 0), (512, 512)),
    "WFOV_UNBINNED": (1024, (0, 0), (1024, 1024)),
    "PASSIVE_IR": (1024, (0, 0), (1024, 1024)),
}
_EBML = b"\x1a\x45\xdf\xa3"


def _av_errors(av: Any) -> tuple[type[BaseException], ...]:
    """What PyAV raises for damaged files."""
    return (av.FFmpegError, OSError, ValueError, EOFError, LookupError)


def is_matroska(path: str | PathLike[str]) -> bool:
    """Whether ``path`` starts with the EBML signature of Matroska/WebM."""
    try:
        with Path(path).open("rb") as fh:
            return fh.read(4) == _EBML
    except OSError:
        return False


def k4a_depth_camera(
    calibration: dict[str, Any], mode: str, *, path: Path
) -> tuple[Intrinsics, np.ndarray]:
    """Depth intrinsics and OpenCV distortion ``(k1, k2, p1, p2, k3, k4, k5, k6)`` for a mode.

    ``ModelParameters`` are ``cx, cy, fx, fy, k1..k6, codx, cody, p2, p1`` normalised by the
    calibration resolution; ``fx = fx_n W_cal``, ``cx = cx_n W_cal - crop_x - 0.5``.
    """
    if mode not in K4A_DEPTH_MODES:
        raise InputFileError(
            path, f"unknown K4A_DEPTH_MODE {mode!r} (known: {', '.join(K4A_DEPTH_MODES)})"
        )
    try:
        cams = calibration["CalibrationInformation"]["Cameras"]
        depth = next(c for c in cams if c.get("Purpose") == "CALIBRATION_CameraPurposeDepth")
        p = [float(v) for v in depth["Intrinsics"]["ModelParameters"]]
    except (KeyError, TypeError, StopIteration, ValueError):
        raise InputFileError(
            path, "calibration.json has no depth camera (CALIBRATION_CameraPurposeDepth)"
        ) from None
    if len(p) < 14:
        raise InputFileError(path, f"calibration.json: {len(p)} depth model parameters, need 14")
    cal, (ox, oy), (w, h) = K4A_DEPTH_MODES[mode]
    cx, cy, fx, fy = p[0] * cal - ox - 0.5, p[1] * cal - oy - 0.5, p[2] * cal, p[3] * cal
    k1, k2, k3, k4, k5, k6, _, _, p2, p1 = p[4:14]
    return (
        Intrinsics(fx, fy, cx, cy, width=w, height=h),
        np.array([k1, k2, p1, p2, k3, k4, k5, k6], dtype=np.float64),
    )


class MkvReader(SequentialReader):
    """Frame reader for Azure Kinect / Orbbec ``.mkv`` and fuse4d FFV1 ``.mkv`` depth video.

    Parameters
    ----------
    path : str or PathLike
        The Matroska file.
    depth_unit_mm : float, optional
        Overrides the unit (Azure Kinect: 1 mm; fuse4d video: its ``FUSE4D_DEPTH_UNIT_MM``).
    intrinsics : IntrinsicsLike, optional
        Overrides the calibration (then no undistortion is done).
    undistort : bool, optional
        Azure Kinect only: resample frames onto the undistorted pinhole grid (default True).

    Raises
    ------
    InputFileError
        Not Matroska, no DEPTH/IR track, no calibration, truncated file.
    """

    format = "mkv"
    _missing_frame = "DEPTH frame missing"

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        depth_unit_mm: float | None = None,
        intrinsics: IntrinsicsLike | None = None,
        undistort: bool = True,
    ) -> None:
        self.path = Path(path)
        self._av = require("av", what="reading .mkv depth video")
        self._container: Any = None
        self._maps: tuple[np.ndarray, np.ndarray] | None = None
        self._white: float | None = None
        notes: list[str] = []
        if not self.path.is_file():
            raise InputFileError(self.path, "file not found")
        if not is_matroska(self.path):
            raise InputFileError(self.path, "not a Matroska (.mkv) file (no EBML signature)")
        try:
            self._open()
            meta = dict(self._container.metadata)
            self.fuse4d = "FUSE4D_INTRINSICS" in meta
            if self.fuse4d:
                self._setup_fuse4d(meta, depth_unit_mm, intrinsics, notes)
            else:
                self._setup_k4a(meta, depth_unit_mm, intrinsics, undistort, notes)
                self.sensor = "tof"  # the Azure Kinect's depth camera
            self._scan(notes)
        except BaseException:
            self.close()
            raise
        self.notes = tuple(notes)

    def _open(self) -> None:
        try:
            self._container = self._av.open(str(self.path))
        except _av_errors(self._av) as exc:
            raise InputFileError(
                self.path, f"cannot open the Matroska file (truncated or corrupt: {exc})"
            ) from None
        titles = {str(s.metadata.get("title", "")).upper(): s for s in self._container.streams}
        self._tracks = titles

    def _track(self, *names: str) -> Any:
        for n in names:
            if n in self._tracks and self._tracks[n].type == "video":
                return self._tracks[n]
        have = ", ".join(t for t in self._tracks if t) or "none"
        raise InputFileError(self.path, f"no {names[0]} video track (tracks: {have})")

    # ------------------------------------------------------------------ metadata
    def _setup_k4a(
        self,
        meta: dict[str, str],
        unit: float | None,
        spec: IntrinsicsLike | None,
        undistort: bool,
        notes: list[str],
    ) -> None:
        self._depth_s = self._track("DEPTH")
        self._inten_s = self._track("IR")
        mode = str(self._depth_s.metadata.get("K4A_DEPTH_MODE", "")).upper()
        w, h = int(self._depth_s.codec_context.width), int(self._depth_s.codec_context.height)
        iw, ih = int(self._inten_s.codec_context.width), int(self._inten_s.codec_context.height)
        if (iw, ih) != (w, h):
            raise InputFileError(
                self.path, f"IR track is {iw}x{ih} but the DEPTH track is {w}x{h} (frame 0)"
            )
        self.depth_unit_mm = 1.0 if unit is None else depth_unit(unit)  # -1 gave negative mm
        notes.append(
            "Azure Kinect / Orbbec recording: DEPTH track (mm"
            + (")" if unit is None else f", overridden: {unit:g} mm per unit)")
            + ", IR track as registered intensity"
        )
        if spec is not None:
            try:
                self.intrinsics = resolve_intrinsics(spec, width=w, height=h)
            except ValueError as exc:
                raise InputFileError(self.path, str(exc)) from None
            notes.append("intrinsics: given by the caller (no undistortion)")
            return
        calib = self._calibration()
        cam, dist = k4a_depth_camera(calib, mode, path=self.path)
        if cam.shape != (h, w):
            raise InputFileError(
                self.path, f"depth mode {mode} is {cam.width}x{cam.height} but frames are {w}x{h}"
            )
        self.intrinsics = cam
        notes.append(f"intrinsics: calibration.json attachment, depth mode {mode}")
        if undistort and np.any(dist != 0):
            k = cam.matrix
            self._maps = cv2.initUndistortRectifyMap(k, dist, None, k, (w, h), cv2.CV_32FC1)
            notes.append(
                "lens distortion (Brown-Conrady rational) removed: frames resampled onto the "
                "pinhole grid with the same fx, fy, cx, cy (depth nearest, IR bilinear)"
            )
        elif np.any(dist != 0):
            notes.append("lens distortion NOT removed (undistort=False): pinhole approximation")

    def _calibration(self) -> dict[str, Any]:
        for s in self._container.streams:
            if s.type != "attachment":
                continue
            name = str(s.metadata.get("filename", getattr(s, "name", "")))
            if name.lower() == "calibration.json":
                try:
                    return json.loads(bytes(s.data).decode("utf-8"))
                except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                    raise InputFileError(
                        self.path, f"calibration.json attachment is not valid JSON ({exc})"
                    ) from None
        raise InputFileError(
            self.path,
            "no calibration.json attachment (record with k4arecorder, or pass --intrinsics)",
        )

    def _setup_fuse4d(
        self,
        meta: dict[str, str],
        unit: float | None,
        spec: IntrinsicsLike | None,
        notes: list[str],
    ) -> None:
        self._depth_s = self._track("DEPTH")
        self._inten_s = self._track("INTENSITY")
        w, h = int(self._depth_s.codec_context.width), int(self._depth_s.codec_context.height)
        try:
            vals = [float(v) for v in meta["FUSE4D_INTRINSICS"].split(",")]
            stored_unit = float(meta.get("FUSE4D_DEPTH_UNIT_MM", "1"))
            self._t0 = float(meta["FUSE4D_T0"]) if "FUSE4D_T0" in meta else None
            fps = float(meta["FUSE4D_FPS"]) if meta.get("FUSE4D_FPS") else None
        except ValueError as exc:
            raise InputFileError(self.path, f"bad FUSE4D_* tag ({exc})") from None
        self.sensor = check_sensor_kind(meta.get("FUSE4D_SENSOR"), self.path, "tag FUSE4D_SENSOR")
        self.depth_unit_mm = (
            depth_unit(stored_unit, self.path) if unit is None else depth_unit(unit)
        )
        self.intrinsics = (
            Intrinsics.from_array(vals, width=w, height=h)
            if spec is None
            else resolve_intrinsics(spec, width=w, height=h)
        )
        self.fps = fps
        notes.append(f"fuse4d FFV1 depth video, {self.depth_unit_mm:g} mm per unit")

    def _scan(self, notes: list[str]) -> None:
        """Index the packets of both tracks (no decoding) and pair them by pts; what was
        skipped is added to ``notes``."""
        d_pts: list[int] = []
        i_pts: list[int] = []
        try:
            for pkt in self._container.demux(self._depth_s, self._inten_s):
                if pkt.pts is None or pkt.size == 0:
                    continue
                (d_pts if pkt.stream.index == self._depth_s.index else i_pts).append(pkt.pts)
        except _av_errors(self._av) as exc:
            raise InputFileError(
                self.path, f"cannot read the packets (truncated or corrupt: {exc})"
            ) from None
        inten_name = "INTENSITY" if self.fuse4d else "IR"
        for name, pts in (("DEPTH", d_pts), (inten_name, i_pts)):
            if not pts:
                raise InputFileError(
                    self.path, f"the {name} track holds no frame (truncated file?)"
                )
        tb_d, tb_i = float(self._depth_s.time_base), float(self._inten_s.time_base)
        td = np.asarray(d_pts, dtype=np.float64) * tb_d
        ti = np.asarray(i_pts, dtype=np.float64) * tb_i
        for name, times in (("DEPTH", td), (inten_name, ti)):
            # frames are paired and decoded by pts: a repeated one would be ambiguous
            check_increasing_times(times, self.path, f"{name} track: pts")
        pairs = {round(t, 6): j for j, t in enumerate(ti)}
        keep = [k for k, t in enumerate(td) if round(t, 6) in pairs]
        if not keep:
            raise InputFileError(
                self.path, f"no DEPTH frame has an {inten_name} frame with equal pts"
            )
        skipped = td.size - len(keep)
        if skipped and keep[-1] == len(keep) - 1 and td[len(keep)] > ti[-1]:
            notes.append(
                f"the {inten_name} track ends before the DEPTH track (truncated file?): "
                f"the last {skipped} DEPTH frames skipped"
            )
        elif skipped:
            notes.append(
                f"{skipped} DEPTH frames without an {inten_name} frame of equal pts skipped"
            )
        self._d_pts = np.asarray(d_pts, dtype=np.int64)[keep]
        self._i_pts = np.asarray([i_pts[pairs[round(td[k], 6)]] for k in keep], dtype=np.int64)
        ts = td[keep]
        if self.fuse4d:
            # fuse4d's writer makes pts up (at its fps, or 30) for frames without times: only
            # the FUSE4D_T0 tag says they are the frames' times, only FUSE4D_FPS gives a rate
            self.timestamps = None if self._t0 is None else ts + self._t0
        else:
            self.timestamps = ts
        if self.fps is None and not self.fuse4d:
            if ts.size > 1 and np.median(np.diff(ts)) > 0:
                self.fps = float(1.0 / np.median(np.diff(ts)))
            else:
                rate = self._depth_s.average_rate
                self.fps = float(rate) if rate else None
        self._check_length(td[keep], notes)

    def _check_length(self, ts: np.ndarray, notes: list[str]) -> None:
        """Warn where the frames end well before the duration the file's header states: a
        truncated copy (a cut download, a full disk) read silently as a shorter recording."""
        duration = self._container.duration  # microseconds, of the Segment header; None: unset
        if not duration or duration <= 0:
            return
        # a frame's duration: the header's end is the last frame's pts plus it
        period = max(
            float(np.median(np.diff(ts))) if ts.size > 1 else 0.0,
            1.0 / self.fps if self.fps else 1.0 / 30.0,
        )
        end, stated = float(ts[-1] - ts[0]), duration * 1e-6 - float(ts[0])
        if stated - end > 2.0 * max(period, 0.0) + 0.05:
            warnings.warn(
                f"{self.path}: the frames end at {end:.3f} s but the file's header says "
                f"{stated:.3f} s: truncated? ({ts.size} frames read)",
                stacklevel=4,
            )
            notes.append(f"frames end {stated - end:.3f} s before the stated end")

    # ------------------------------------------------------------------ frames
    def __len__(self) -> int:
        return int(self._d_pts.size)

    def _stream(self, k0: int, stop: int | None = None) -> Iterator[Frame]:
        stop = len(self) if stop is None else stop
        want_d = {int(p): k for k, p in enumerate(self._d_pts[k0:stop], start=k0)}
        want_i = {int(p): k for k, p in enumerate(self._i_pts[k0:stop], start=k0)}
        depth: dict[int, np.ndarray] = {}
        inten: dict[int, np.ndarray] = {}
        k = k0
        try:
            if k0 > 0 and not self.fuse4d and self._white is None:
                self._set_white(self._first_ir())  # frame 0's, whatever is read
            self._container.seek(
                int(self._d_pts[k0]), stream=self._depth_s, backward=True, any_frame=False
            )
            for pkt in self._container.demux(self._depth_s, self._inten_s):
                is_depth = pkt.stream.index == self._depth_s.index
                table = want_d if is_depth else want_i
                # every packet from the (key frame) seek point is decoded: FFV1 carries its
                # context state from frame to frame between key frames
                for fr in pkt.decode():  # flush packets (pts None) return delayed frames
                    if fr.pts is not None and int(fr.pts) in table:
                        (depth if is_depth else inten)[table[int(fr.pts)]] = fr.to_ndarray()
                while k < stop and k in depth and k in inten:
                    frame = self._decode(k, depth.pop(k), inten.pop(k))
                    k += 1
                    yield frame
                if k >= stop:
                    return
        except InputFileError:
            raise
        except _av_errors(self._av) as exc:
            raise InputFileError(
                self.path, f"cannot decode (truncated or corrupt: {exc})", frame=k
            ) from None
        if k < stop:
            raise InputFileError(self.path, "frame missing (truncated file?)", frame=k)

    def _decode(self, k: int, d: np.ndarray, ir: np.ndarray) -> Frame:
        h, w = self.intrinsics.shape
        if d.shape != (h, w) or ir.shape != (h, w):
            raise InputFileError(
                self.path, f"frame is {d.shape[1]}x{d.shape[0]}, expected {w}x{h}", frame=k
            )
        if d.dtype != np.uint16:
            raise InputFileError(self.path, f"DEPTH frame is {d.dtype}, expected 16 bit", frame=k)
        if not self.fuse4d and self._white is None:  # frame 0 (a later pass set it first)
            self._set_white(ir)  # before the remap: bilinear blends saturated pixels in
        if self._maps is not None:
            mx, my = self._maps
            d = cv2.remap(d, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
            ir = cv2.remap(ir, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        depth = d.astype(np.float32) * np.float32(self.depth_unit_mm)
        depth[d == 0] = np.nan
        if self.fuse4d:
            gray = ir.astype(np.float32) * np.float32(1.0 / 65535.0)
        else:
            gray = amplitude_to_gray(ir, self._white or 65535.0)
        ts = None if self.timestamps is None else float(self.timestamps[k])
        return Frame(k, depth, gray, timestamp=ts)

    def _first_ir(self) -> np.ndarray:
        """Frame 0's IR image as recorded (not undistorted), decoded on its own."""
        pts = int(self._i_pts[0])
        self._container.seek(pts, stream=self._inten_s, backward=True, any_frame=False)
        for pkt in self._container.demux(self._inten_s):
            for fr in pkt.decode():
                if fr.pts is not None and int(fr.pts) == pts:
                    return fr.to_ndarray()
        raise InputFileError(self.path, "IR frame missing (truncated file?)", frame=0)

    def _set_white(self, ir: np.ndarray) -> None:
        """Fix the file's IR white level from frame 0's raw IR image ``ir``."""
        self._white = white_level(ir)
        note = (
            f"IR shown as sqrt(IR / {self._white:g}) (99.5th percentile of frame 0's raw IR, "
            "the same for every frame; the square root gives the far, dark scene its texture)"
        )
        self.notes = (*self.notes, note)

    def describe_streams(self) -> list[dict[str, Any]]:
        """Tracks of the file, with the role fuse4d gives them."""
        out = []
        for s in self._container.streams if self._container is not None else ():
            title = str(s.metadata.get("title", s.metadata.get("filename", "")))
            cc = s.codec_context if s.type == "video" else None
            used = {self._depth_s.index: "depth", self._inten_s.index: "intensity"}
            count = len(self) if s.index in used else None
            out.append({
                "topic": title or f"track {s.index}",
                "type": s.type,
                "messages": count if count is not None else (s.frames or "?"),
                "encoding": "" if cc is None else f"{cc.name} {cc.pix_fmt}",
                "width": 0 if cc is None else cc.width,
                "height": 0 if cc is None else cc.height,
                "rate_hz": self.fps if s.index in used else None,
                "used_as": used.get(s.index),
            })  # fmt: skip
        return out

    def close(self) -> None:
        self._close_stream()
        container, self._container = self._container, None
        if container is not None:
            container.close()
