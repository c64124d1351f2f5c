"""Streaming reader of ROS 1 bags, ROS 2 bags (SQLite ``.db3``, MCAP, or their folder) and the
RealSense recordings that librealsense writes in those containers, through ``rosbags``.

Depth and intensity topics are chosen by message type and encoding (``--depth-topic`` /
``--intensity-topic`` override), intensity frames are paired with depth frames by timestamp,
intrinsics come from the sibling ``CameraInfo`` and depth units from the file. Frames are
decoded one at a time; sequential reading walks the bag once (one ``messages()`` pass), random
access re-opens the stream at the frame's bag time. See ``docs/formats.md``.
"""

from __future__ import annotations

import contextlib
import math
import re
import sqlite3
import struct
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Intrinsics
from ..errors import InputFileError, ParameterError
from ._align import align_to_depth
from ._base import (
    Frame,
    IntrinsicsLike,
    SequentialReader,
    check_increasing_times,
    check_stored_intensity,
    depth_unit,
    resolve_intrinsics,
)
from ._extras import require
from ._realsense import (
    is_realsense_topic,
    parse_key_values,
    quaternion_matrix,
    realsense_sensor_kind,
    sensor_prefix,
    stream_prefix,
)
from ._rosimage import (
    amplitude_to_gray,
    decode_compressed,
    decode_image_msg,
    float_white_level,
    image_kind,
    normalise_intensity,
    white_level,
)

__all__ = ["INTENSITY_CHOICES", "RosbagReader", "bag_kind"]

#: Values of ``intensity=`` (CLI ``--intensity``).
INTENSITY_CHOICES = ("auto", "ir", "color")

_IMAGE = "sensor_msgs/msg/Image"
_COMPRESSED = "sensor_msgs/msg/CompressedImage"
_CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
_SUFFIX = {"ros1": ".bag", "sqlite": ".db3", "mcap": ".mcap"}
_IR_FIRST = re.compile(r"infrared_1|infra1|/ir(/|$)|ir_image|infrared/", re.IGNORECASE)
_IR_ANY = re.compile(r"infra|/ir(/|$|_)", re.IGNORECASE)
_COLOR = re.compile(r"colou?r|rgb", re.IGNORECASE)


def bag_kind(path: str | PathLike[str]) -> str | None:
    """``"ros1"``, ``"sqlite"``, ``"mcap"`` or ``"folder"`` (rosbag2 with metadata.yaml) by magic."""
    p = Path(path)
    if p.is_dir():
        return "folder" if (p / "metadata.yaml").is_file() else None
    try:
        with p.open("rb") as fh:
            head = fh.read(16)
    except OSError:
        return None
    if head.startswith(b"#ROSBAG V2.0"):
        return "ros1"
    if head.startswith(b"SQLite format 3\x00"):
        return "sqlite"
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    return None


def _bag_errors() -> tuple[type[BaseException], ...]:
    """What rosbags (and the SQLite/LZ4 layers below it) raise for damaged files."""
    from rosbags.highlevel import AnyReaderError

    errors: tuple[type[BaseException], ...] = (
        AnyReaderError, OSError, ValueError, KeyError, IndexError, EOFError, struct.error,
        sqlite3.Error, RuntimeError)  # fmt: skip
    try:  # newer rosbags read SQLite through apsw, whose errors are not sqlite3's
        import apsw
    except ImportError:
        return errors
    return (*errors, apsw.Error)


def _float32_value(value: object) -> float:
    """A unit stored as float32 (or text), as the decimal its writer meant (1e-4, not 9.99e-5)."""
    if isinstance(value, str):
        return float(value)
    return float(str(np.float32(value)))


@dataclass
class _Stream:
    """One image topic of the bag (as ``fuse4d info`` lists it)."""

    connection: Any
    topic: str
    msgtype: str
    count: int
    encoding: str = ""
    kind: str = ""
    width: int = 0
    height: int = 0
    rate: float | None = None
    role: str = ""

    def describe(self) -> dict[str, Any]:
        return {
            "topic": self.topic,
            "type": self.msgtype,
            "messages": self.count,
            "encoding": self.encoding,
            "width": self.width,
            "height": self.height,
            "rate_hz": self.rate,
            "used_as": self.role or None,
        }


class RosbagReader(SequentialReader):
    """Frame reader for ROS 1/ROS 2/MCAP bags and RealSense ``.bag``/``.db3`` recordings.

    Parameters
    ----------
    path : str or PathLike
        A ROS 1 ``.bag``, a ROS 2 ``.db3`` or ``.mcap`` file (bare or in a rosbag2 folder with
        ``metadata.yaml``), told apart by magic bytes.
    depth_topic, intensity_topic : str, optional
        Topics to use instead of the automatic choice.
    intensity : {"auto", "ir", "color"}, optional
        Which stream guides fusion when ``intensity_topic`` is not given: the (left) infrared
        image, pixel-registered with depth on RealSense D400 and Azure Kinect (``"ir"``), the
        colour image resampled onto the depth grid with the recorded extrinsics (``"color"``),
        or IR when the file has it and colour otherwise (``"auto"``, default).
    depth_unit_mm : float, optional
        Millimetres per stored depth unit, for bags that do not say (or say wrongly).
    intrinsics : IntrinsicsLike, optional
        Overrides the depth ``CameraInfo``.

    Raises
    ------
    InputFileError
        Truncated/corrupt bag, no depth or intensity topic, unknown topic, missing
        ``CameraInfo`` or depth unit, mismatched depth/intensity resolution; the message names
        the file, topic and frame.
    """

    format = "rosbag"

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        depth_topic: str | None = None,
        intensity_topic: str | None = None,
        intensity: str = "auto",
        depth_unit_mm: float | None = None,
        intrinsics: IntrinsicsLike | None = None,
    ) -> None:
        self.path = Path(path)
        if intensity not in INTENSITY_CHOICES:
            raise ParameterError(
                f"intensity must be one of {', '.join(INTENSITY_CHOICES)}, got {intensity!r}"
            )
        self._reader: Any = None
        self._tmpdir: tempfile.TemporaryDirectory[str] | None = None
        self._errors: tuple[type[BaseException], ...] = (OSError,)
        self._notes: list[str] = []
        self._quirk = False
        self._white: float | None = None
        self._white_known = False  # frame 0's intensity seen: _white set (None for 8 bit)
        try:
            self._open_bag()
            self._setup(depth_topic, intensity_topic, intensity, depth_unit_mm, intrinsics)
        except BaseException:
            self.close()
            raise
        self.notes = tuple(self._notes)

    # ------------------------------------------------------------------ opening
    def _open_bag(self) -> None:
        highlevel = require("rosbags.highlevel", what="reading ROS bags")
        typesys = require("rosbags.typesys", what="reading ROS bags")
        self._errors = _bag_errors()
        if not self.path.exists():
            raise InputFileError(self.path, "file or folder not found")
        kind = bag_kind(self.path)
        if kind is None:
            raise InputFileError(
                self.path, "not a ROS bag (no ROS 1, SQLite or MCAP signature at its start)"
            )
        self.container = {"ros1": "ROS 1 bag", "sqlite": "ROS 2 SQLite (.db3)",
                          "mcap": "ROS 2 MCAP", "folder": "rosbag2 folder"}[kind]  # fmt: skip
        target = self.path
        if kind in _SUFFIX and self.path.suffix.lower() != _SUFFIX[kind]:
            # rosbags picks the storage by suffix: give it a correctly named link
            self._tmpdir = tempfile.TemporaryDirectory(prefix="fuse4d-bag-")
            target = Path(self._tmpdir.name) / f"recording{_SUFFIX[kind]}"
            target.symlink_to(self.path.resolve())
        self.is_ros2 = kind != "ros1"
        store = typesys.Stores.ROS2_HUMBLE if self.is_ros2 else typesys.Stores.ROS1_NOETIC
        try:
            reader = highlevel.AnyReader([target], default_typestore=typesys.get_typestore(store))
            reader.open()
        except self._errors as exc:
            raise InputFileError(
                self.path, f"cannot open the {self.container} (truncated or corrupt: {exc})"
            ) from None
        self._reader = reader

    def _messages(self, connections: list[Any], start: int | None = None) -> Iterator[Any]:
        """``(connection, bag_time_ns, raw)`` in bag-time order, with damage as InputFileError."""
        try:
            yield from self._reader.messages(connections=connections, start=start)
        except InputFileError:
            raise
        except self._errors as exc:
            topics = ", ".join(c.topic for c in connections)
            raise InputFileError(
                self.path, f"cannot read messages of {topics} (truncated or corrupt: {exc})"
            ) from None

    def _first(self, connection: Any) -> tuple[Any, bytes] | None:
        gen = self._messages([connection])
        try:
            for _, _, raw in gen:
                return self._deserialize(raw, connection), raw
        finally:
            gen.close()
        return None

    def _deserialize(self, raw: bytes, connection: Any) -> Any:
        """Deserialize, stripping librealsense 2.47-2.57's 4 undeclared trailing bytes."""
        if self._quirk and connection.msgtype == _IMAGE:  # known writer: skip the failing try
            with contextlib.suppress(*self._errors):
                return self._reader.typestore.deserialize_ros1(raw[:-4], connection.msgtype)
        try:
            return self._reader.deserialize(raw, connection.msgtype)
        except self._errors as exc:
            if not self.is_ros2 and "size mismatch" in str(exc) and len(raw) > 4:
                with contextlib.suppress(*self._errors):
                    msg = self._reader.typestore.deserialize_ros1(raw[:-4], connection.msgtype)
                    self._quirk = True
                    return msg
            raise InputFileError(
                self.path, f"topic {connection.topic}: cannot decode message ({exc})"
            ) from None

    # ------------------------------------------------------------------ topic choice
    def _setup(
        self,
        depth_topic: str | None,
        intensity_topic: str | None,
        intensity: str,
        depth_unit_mm: float | None,
        intrinsics: IntrinsicsLike | None,
    ) -> None:
        conns = list(self._reader.connections)
        self._all = conns
        streams = [
            _Stream(c, c.topic, c.msgtype, int(c.msgcount))
            for c in conns
            if c.msgtype in (_IMAGE, _COMPRESSED)
        ]
        for s in streams:
            self._probe(s)
        self.streams = streams
        self.realsense = any(is_realsense_topic(c.topic) for c in conns)
        listing = ", ".join(f"{s.topic} ({s.encoding or s.msgtype})" for s in streams) or "none"
        depth = self._choose_depth(streams, depth_topic, listing)
        inten = self._choose_intensity(streams, depth, intensity_topic, intensity, listing)
        depth.role, inten.role = "depth", "intensity"
        self._depth, self._inten = depth, inten
        by = " written by librealsense" if self.realsense else ""
        self._notes.insert(0, f"container: {self.container}{by}")
        name = self._device_name() if self.realsense else None
        if name:
            self.sensor = realsense_sensor_kind(name)
            kind = f" ({self.sensor})" if self.sensor else ""
            self._notes.append(f"camera: {name}{kind}")
        self._notes.append(f"depth: {depth.topic} ({depth.encoding}, {depth.width}x{depth.height})")
        h, w = depth.height, depth.width
        self._set_intrinsics(intrinsics, w, h)
        self._set_unit(depth_unit_mm)
        self._set_alignment(intensity, intensity_topic)
        self._build_index()

    def _device_name(self) -> str | None:
        """The camera's ``Name`` in librealsense's ``/device_0/info`` (KeyValue messages, or
        ``key=value`` Strings), None when not recorded."""
        for c in self._all:
            if c.topic != "/device_0/info":
                continue
            for _, _, raw in self._messages([c]):
                msg = self._deserialize(raw, c)
                if getattr(msg, "key", None) == "Name":
                    return str(msg.value).strip() or None
                name = parse_key_values(getattr(msg, "data", "")).get("Name")
                if name:
                    return name
        return None

    def _probe(self, s: _Stream) -> None:
        first = self._first(s.connection) if s.count else None
        if first is None:
            return
        msg, _ = first
        if s.msgtype == _IMAGE:
            s.encoding = str(msg.encoding)
            s.width, s.height = int(msg.width), int(msg.height)
        else:
            s.encoding = str(msg.format)
            try:
                img, _ = decode_compressed(msg, gray=True)
                s.height, s.width = img.shape[:2]
            except ValueError:
                pass
        s.kind = image_kind(s.encoding)
        if (
            s.kind == "depth"
            and _IR_ANY.search(s.topic)
            and "compresseddepth" not in (s.encoding.lower())
        ):
            s.kind = "intensity"  # 16-bit IR (Azure Kinect /ir/image_raw, RealSense Y16)

    def _find(self, streams: list[_Stream], topic: str, what: str, listing: str) -> _Stream:
        want = "/" + topic.strip().lstrip("/")
        for s in streams:
            if s.topic == want or s.topic == topic:
                return s
        if any(c.topic in (want, topic) for c in self._all):
            raise InputFileError(self.path, f"{what} topic {topic} holds no image messages")
        raise InputFileError(
            self.path, f"no {what} topic {topic} in the bag; image topics: {listing}"
        )

    def _choose_depth(self, streams: list[_Stream], topic: str | None, listing: str) -> _Stream:
        if topic:
            s = self._find(streams, topic, "depth", listing)
            if s.kind != "depth":
                raise InputFileError(
                    self.path, f"depth topic {s.topic} holds {s.encoding!r}, not depth images"
                )
            return s
        cands = [s for s in streams if s.kind == "depth" and s.count]
        if not cands:
            raise InputFileError(
                self.path,
                "no depth topic (sensor_msgs/Image 16UC1/32FC1/mono16 or CompressedImage "
                f"compressedDepth); image topics: {listing}; pass --depth-topic",
            )

        def score(s: _Stream) -> tuple[int, int]:
            t = s.topic.lower()
            registered = re.search(r"aligned|registered|to_rgb|to_colou?r", t) is not None
            return (("depth" in t) * 2 - registered, s.count)

        cands.sort(key=score, reverse=True)
        if len(cands) > 1:
            others = ", ".join(s.topic for s in cands[1:])
            self._notes.append(f"other depth topics (--depth-topic): {others}")
        return cands[0]

    def _choose_intensity(
        self,
        streams: list[_Stream],
        depth: _Stream,
        topic: str | None,
        mode: str,
        listing: str,
    ) -> _Stream:
        if topic:
            s = self._find(streams, topic, "intensity", listing)
            if s is depth:
                raise InputFileError(self.path, f"topic {s.topic} cannot be depth and intensity")
            return s
        cands = [s for s in streams if s is not depth and s.kind == "intensity" and s.count]
        ir = sorted(
            (s for s in cands if _IR_ANY.search(s.topic)),
            key=lambda s: (_IR_FIRST.search(s.topic) is None, s.topic),
        )
        color = [s for s in cands if _COLOR.search(s.topic) and s not in ir]
        order = {"ir": ir, "color": color, "auto": ir or color}[mode]
        if not order:
            if mode == "auto" and cands:
                order = cands  # a grey image with an unhelpful topic name
            else:
                want = {"ir": "infrared", "color": "colour", "auto": "infrared or colour"}[mode]
                raise InputFileError(
                    self.path,
                    f"no {want} image topic to use as intensity; image topics: {listing}; "
                    "pass --intensity-topic" + (" or --intensity color" if mode == "ir" else ""),
                )
        chosen = order[0]
        if mode == "auto" and not ir and self.realsense:
            self._notes.append("no infrared (Infrared_1) stream in the file: colour is used")
        return chosen

    # ------------------------------------------------------------------ metadata
    def _sibling(self, topic: str, msgtype: str, exclude: str = "") -> Any | None:
        """The connection of ``msgtype`` whose topic shares the longest path prefix."""
        base = re.sub(r"/(compressedDepth|compressed|theora)$", "", topic)
        parts = base.strip("/").split("/")
        best, best_len = None, -1
        for c in self._all:
            if c.msgtype != msgtype or c.topic == exclude or not c.msgcount:
                continue
            other = c.topic.strip("/").split("/")
            n = 0
            while n < min(len(parts), len(other)) and parts[n] == other[n]:
                n += 1
            if n > best_len and n >= max(1, len(parts) - 2):
                best, best_len = c, n
        return best

    def _camera_of(self, stream: _Stream) -> tuple[Intrinsics | None, str]:
        conn = self._sibling(stream.topic, _CAMERA_INFO)
        w, h = stream.width, stream.height
        if conn is not None:
            info, _ = self._first(conn)
            k = np.asarray(getattr(info, "k", getattr(info, "K", None)), dtype=np.float64)
            d = np.asarray(getattr(info, "d", getattr(info, "D", ())), dtype=np.float64)
            iw, ih = int(info.width), int(info.height)
            if (iw, ih) not in ((0, 0), (w, h)):
                raise InputFileError(
                    self.path,
                    f"camera_info {conn.topic} is for {iw}x{ih} images but {stream.topic} "
                    f"is {w}x{h}",
                )
            if k.size == 9 and k[0] > 0 and k[4] > 0:
                cam = Intrinsics(k[0], k[4], k[2], k[5], width=w, height=h)
                if d.size and np.any(d != 0):
                    self._notes.append(
                        f"{conn.topic}: distortion {d.round(5).tolist()} not applied "
                        "(images taken as rectified)"
                    )
                return cam, conn.topic
        prefix = stream_prefix(stream.topic)
        if prefix:
            for c in self._all:
                if c.topic == f"{prefix}/camera_info" and c.msgtype == "std_msgs/msg/String":
                    msg, _ = self._first(c)
                    kv = parse_key_values(msg.data)
                    try:
                        vals = [float(kv[key]) for key in ("fx", "fy", "ppx", "ppy")]
                    except (KeyError, ValueError):
                        continue
                    return Intrinsics(*vals, width=w, height=h), c.topic
        return None, ""

    def _set_intrinsics(self, spec: IntrinsicsLike | None, w: int, h: int) -> None:
        if w < 1 or h < 1:
            raise InputFileError(self.path, f"depth topic {self._depth.topic}: empty images")
        if spec is not None:
            try:
                self.intrinsics = resolve_intrinsics(spec, width=w, height=h)
            except ValueError as exc:
                raise InputFileError(self.path, str(exc)) from None
            self._notes.append("intrinsics: given by the caller")
            return
        cam, source = self._camera_of(self._depth)
        if cam is None:
            raise InputFileError(
                self.path,
                f"no camera_info for depth topic {self._depth.topic}; pass --intrinsics",
            )
        self.intrinsics = cam
        self._notes.append(f"intrinsics: {source}")

    def _option_unit(self) -> tuple[float, str] | None:
        sensor = sensor_prefix(self._depth.topic)
        for c in self._all:
            if not re.search(r"/option/Depth[ _]Units/value$", c.topic):
                continue
            if sensor and not c.topic.startswith(sensor + "/"):
                continue
            msg, _ = self._first(c)
            try:
                metres = _float32_value(msg.data)
            except (TypeError, ValueError):
                continue
            if math.isfinite(metres) and metres > 0:
                return 1000.0 * metres, c.topic
        return None

    def _set_unit(self, override: float | None) -> None:
        enc = self._depth.encoding.lower()
        self._float_depth = enc.split(";")[0].strip() == "32fc1"
        if override is not None:
            self._unit, source = depth_unit(override), "given by the caller"
        elif self._float_depth:
            self._unit, source = 1000.0, "32FC1 = metres"
        elif (opt := self._option_unit()) is not None:
            self._unit, source = opt[0], opt[1]
        elif self._trailing_unit() is not None:
            self._unit = self._trailing_unit()  # type: ignore[assignment]
            source = "float32 after each image (librealsense 2.47-2.57)"
        elif enc.startswith("16uc1"):
            self._unit, source = 1.0, "16UC1 = mm (REP 118; check with --depth-unit-mm)"
        else:
            raise InputFileError(
                self.path,
                f"depth topic {self._depth.topic} ({self._depth.encoding}) does not say its "
                "depth unit; pass --depth-unit-mm (e.g. 1 for mm, 0.1 for the D405)",
            )
        self.depth_unit_mm = None if self._float_depth else self._unit
        self._notes.append(f"depth unit: {self._unit:g} mm ({source})")

    def _trailing_unit(self) -> float | None:
        first = self._first(self._depth.connection)
        if first is None or not self._quirk:
            return None
        metres = _float32_value(struct.unpack("<f", first[1][-4:])[0])
        return 1000.0 * metres if math.isfinite(metres) and metres > 0 else None

    def _set_alignment(self, mode: str, explicit: str | None) -> None:
        d, s = self._depth, self._inten
        self._align: tuple[Intrinsics, np.ndarray, np.ndarray] | None = None
        is_color = bool(_COLOR.search(s.topic)) and not _IR_ANY.search(s.topic)
        extr = self._extrinsics(d.topic, s.topic) if is_color else None
        if is_color and extr is not None:
            cam, _ = self._camera_of(s)
            if cam is not None:
                self._align = (cam, *extr)
                self._notes.append(
                    f"intensity: {s.topic} ({s.encoding}) resampled onto the depth grid "
                    "with the recorded extrinsics (occlusions not modelled)"
                )
                return
        if (s.width, s.height) != (d.width, d.height):
            raise InputFileError(
                self.path,
                f"intensity topic {s.topic} is {s.width}x{s.height} but depth topic {d.topic} "
                f"is {d.width}x{d.height} (frame 0), and the file has no calibration to align "
                "them; pass --intensity-topic with a registered image "
                "(e.g. aligned_depth_to_color depth with colour)",
            )
        how = "registered" if not is_color else "same size, taken as aligned"
        self._notes.append(f"intensity: {s.topic} ({s.encoding}, {how})")

    def _extrinsics(self, depth_topic: str, other_topic: str) -> tuple[np.ndarray, ...] | None:
        """librealsense ``tf``: stream → reference; returns depth → other (R, t in mm)."""
        a, b = stream_prefix(depth_topic), stream_prefix(other_topic)
        if a is None or b is None:
            return None
        ta, tb = self._stream_tf(a), self._stream_tf(b)
        if ta is None or tb is None:
            return None
        (ra, pa), (rb, pb) = ta, tb
        # x_ref = ra x_a + pa = rb x_b + pb  =>  x_b = rb^T (ra x_a + pa - pb)
        rot = rb.T @ ra
        trans = rb.T @ (pa - pb)
        return rot, 1000.0 * trans

    def _stream_tf(self, prefix: str) -> tuple[np.ndarray, np.ndarray] | None:
        for c in self._all:
            if not c.topic.startswith(prefix + "/tf/"):
                continue
            msg, _ = self._first(c)
            if hasattr(msg, "rotation"):
                q = msg.rotation
                rot = quaternion_matrix(q.x, q.y, q.z, q.w)
                t = msg.translation
                return rot, np.array([t.x, t.y, t.z], dtype=np.float64)
            kv = parse_key_values(getattr(msg, "data", ""))
            try:
                r = np.array([float(v) for v in kv["rotation"].split(",")])
                t = np.array([float(v) for v in kv["translation"].split(",")])
            except (KeyError, ValueError):
                continue
            if r.size == 9 and t.size == 3:
                return r.reshape(3, 3).T, t  # rs2_extrinsics: column-major rotation
        return None

    # ------------------------------------------------------------------ frame index
    def _stamp(self, raw: bytes, bag_ns: int) -> float:
        try:
            if self.is_ros2:
                order = "<" if raw[1] == 1 else ">"
                sec, nsec = struct.unpack_from(order + "iI", raw, 4)
            else:
                _, sec, nsec = struct.unpack_from("<III", raw, 0)
        except struct.error:
            return bag_ns * 1e-9
        stamp = sec + nsec * 1e-9
        return stamp if stamp > 0 else bag_ns * 1e-9

    def _build_index(self) -> None:
        dc, ic = self._depth.connection, self._inten.connection
        bt = {dc.id: [], ic.id: []}
        st = {dc.id: [], ic.id: []}
        for conn, t, raw in self._messages([dc, ic]):
            bt[conn.id].append(t)
            st[conn.id].append(self._stamp(raw, t))
        self._bt_depth = np.asarray(bt[dc.id], dtype=np.int64)
        self._bt_inten = np.asarray(bt[ic.id], dtype=np.int64)
        td = np.asarray(st[dc.id], dtype=np.float64)
        ti = np.asarray(st[ic.id], dtype=np.float64)
        if td.size == 0:
            raise InputFileError(self.path, f"depth topic {self._depth.topic} has no message")
        if ti.size == 0:
            raise InputFileError(self.path, f"intensity topic {self._inten.topic} has no message")
        # The header stamps are the frames' times (pairing, output timestamps): a repeated or
        # backwards one means a broken clock or a merged bag, and no order can be trusted.
        check_increasing_times(td, self.path, f"depth topic {self._depth.topic}: header stamp")
        order = np.argsort(ti, kind="stable")
        pos = np.clip(np.searchsorted(ti[order], td), 1, max(ti.size - 1, 1))
        left = order[np.clip(pos - 1, 0, ti.size - 1)]
        right = order[np.clip(pos, 0, ti.size - 1)]
        pick = np.where(np.abs(ti[left] - td) <= np.abs(ti[right] - td), left, right)
        dt = np.abs(ti[pick] - td)
        period = float(np.median(np.diff(np.sort(td)))) if td.size > 1 else math.inf
        tol = 2.0 * period if period > 0 else math.inf
        keep = dt <= tol
        if not keep.any():
            raise InputFileError(
                self.path,
                f"no intensity frame of {self._inten.topic} lies within {1000 * tol:.1f} ms of "
                f"a depth frame of {self._depth.topic}",
            )
        if not keep.all():
            self._notes.append(
                f"{int((~keep).sum())} depth frames without an intensity frame within "
                f"{1000 * tol:.1f} ms skipped"
            )
        self._d_ord = np.nonzero(keep)[0]
        self._i_ord = pick[keep]
        # smallest intensity ordinal still needed from frame k on (streaming buffer purge)
        self._i_need = np.minimum.accumulate(self._i_ord[::-1])[::-1]
        self.timestamps = td[keep]
        for stream, times in ((self._depth, td), (self._inten, ti)):
            span = float(times.max() - times.min()) if times.size > 1 else 0.0
            stream.rate = (times.size - 1) / span if span > 0 else None
        self._pair_dt = float(dt[keep].max())
        if self._pair_dt > 0:
            self._notes.append(f"depth/intensity pairing: max offset {1000 * self._pair_dt:.2f} ms")
        self.fps = self._nominal_fps(self.timestamps)

    def _nominal_fps(self, ts: np.ndarray) -> float | None:
        prefix = stream_prefix(self._depth.topic)
        for c in self._all:
            if prefix and c.topic == f"{prefix}/info":
                msg, _ = self._first(c)
                fps = getattr(msg, "fps", None)
                if fps is None:
                    fps = parse_key_values(getattr(msg, "data", "")).get("fps")
                try:
                    if fps is not None and float(fps) > 0:
                        return float(fps)
                except ValueError:
                    pass
        if ts.size > 1:
            period = float(np.median(np.diff(ts)))
            if period > 0:
                return 1.0 / period
        return None

    # ------------------------------------------------------------------ frames
    def __len__(self) -> int:
        return int(self._d_ord.size)

    def _missing_frame_text(self) -> str:
        return f"depth topic {self._depth.topic}: message missing"

    def _stream(self, k0: int, stop: int | None = None) -> Iterator[Frame]:
        """Decode frames ``k0, k0+1, ...`` in one pass over the bag."""
        stop = len(self) if stop is None else stop
        # the white level is frame 0's (float IR: the first frame with a return), whatever
        # is read
        for j in range(k0):
            if self._white_known:
                break
            self._set_white(self._intensity_image(j))
        dc, ic = self._depth.connection, self._inten.connection
        i_first = int(self._i_need[k0])
        start = int(min(self._bt_depth[self._d_ord[k0]], self._bt_inten[i_first]))
        d_pos = int(np.searchsorted(self._bt_depth, start, side="left"))
        i_pos = int(np.searchsorted(self._bt_inten, start, side="left"))
        want = {int(o): k for k, o in enumerate(self._d_ord[k0:stop], start=k0)}
        pending: dict[int, bytes] = {}
        cache: dict[int, bytes] = {}
        k = k0
        for conn, _, raw in self._messages([dc, ic], start=start):
            if conn.id == dc.id:
                if d_pos in want:
                    pending[want[d_pos]] = raw
                d_pos += 1
            if conn.id == ic.id:
                if i_pos >= self._i_need[k]:
                    cache[i_pos] = raw
                i_pos += 1
            while k < stop and k in pending and int(self._i_ord[k]) in cache:
                frame = self._decode(k, pending.pop(k), cache[int(self._i_ord[k])])
                k += 1
                if k < stop:
                    need = int(self._i_need[k])
                    for o in [o for o in cache if o < need]:
                        del cache[o]
                yield frame
            if k >= stop:
                return
        if k < stop:
            raise InputFileError(
                self.path,
                f"depth topic {self._depth.topic}: message missing (truncated bag?)",
                frame=k,
            )

    def _image(self, raw: bytes, stream: _Stream, k: int, gray: bool) -> np.ndarray:
        msg = self._deserialize(raw, stream.connection)
        try:
            if stream.msgtype == _IMAGE:
                img, _ = decode_image_msg(msg, gray=gray)
            else:
                img, _ = decode_compressed(msg, gray=gray)
        except ValueError as exc:
            raise InputFileError(self.path, f"topic {stream.topic}: {exc}", frame=k) from None
        return img

    def _decode(self, k: int, depth_raw: bytes, inten_raw: bytes) -> Frame:
        h, w = self.intrinsics.height, self.intrinsics.width
        d = self._image(depth_raw, self._depth, k, gray=False)
        if d.shape != (h, w):
            raise InputFileError(
                self.path,
                f"depth topic {self._depth.topic}: image is {d.shape[1]}x{d.shape[0]}, "
                f"expected {w}x{h}",
                frame=k,
            )
        depth = d.astype(np.float32) * np.float32(self._unit)
        depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
        img = self._image(inten_raw, self._inten, k, gray=True)
        gray = self._normalise(img, k)
        if self._align is not None:
            cam, rot, trans = self._align
            if gray.shape != cam.shape:
                raise InputFileError(
                    self.path,
                    f"intensity topic {self._inten.topic}: image is {gray.shape[1]}x"
                    f"{gray.shape[0]}, its camera_info says {cam.width}x{cam.height}",
                    frame=k,
                )
            gray = align_to_depth(depth, gray, self.intrinsics, cam, rot, trans)
        elif gray.shape != (h, w):
            raise InputFileError(
                self.path,
                f"intensity topic {self._inten.topic}: image is {gray.shape[1]}x{gray.shape[0]}"
                f" but depth is {w}x{h}",
                frame=k,
            )
        return Frame(k, depth, gray, timestamp=float(self.timestamps[k]))

    def _intensity_image(self, k: int) -> np.ndarray:
        """The intensity image of frame ``k`` as stored (grey), read on its own."""
        ordinal = int(self._i_ord[k])
        start = int(self._bt_inten[ordinal])
        pos = int(np.searchsorted(self._bt_inten, start, side="left"))
        gen = self._messages([self._inten.connection], start=start)
        try:
            for _, _, raw in gen:
                if pos == ordinal:
                    return self._image(raw, self._inten, k, gray=True)
                pos += 1
        finally:
            gen.close()
        raise InputFileError(
            self.path,
            f"intensity topic {self._inten.topic}: message missing (truncated bag?)",
            frame=k,
        )

    def _set_white(self, first: np.ndarray) -> None:
        """Fix the file's white level from frame 0's intensity image ``first`` (16 bit, and
        float outside [0, 1]). A float frame without any return (no finite value > 0: an
        emitter warming up) fixes nothing: the level is then the first such frame's."""
        if first.dtype.kind == "f":
            finite = first[np.isfinite(first)]
            if not (finite > 0).any():
                return
            self._white_known = True
            self._white = float_white_level(first)
            if self._white is not None:
                self._notes.append(
                    f"float intensity outside [0, 1] scaled by 1/{self._white:g} (99.5th "
                    "percentile of the positive pixels of frame 0, the same for every frame), "
                    "clipped to 1"
                )
                self.notes = tuple(self._notes)
            return
        self._white_known = True
        if first.dtype != np.uint16:
            return
        self._white = white_level(first)
        note = (
            f"16-bit intensity scaled by 1/{self._white:g} (99.5th percentile of the "
            "unsaturated pixels of frame 0, the same for every frame), clipped to 1"
        )
        if self.sensor == "tof":
            note += "; a time-of-flight camera's IR then shown as its square root"
        self._notes.append(note)
        self.notes = tuple(self._notes)

    def _normalise(self, img: np.ndarray, k: int) -> np.ndarray:
        """Frame ``k``'s intensity to float32 [0, 1]: 8 bit / 255; 16 bit / a fixed per-file
        white level, frame 0's (its square root for a time-of-flight camera's IR,
        :func:`amplitude_to_gray`); float (``32FC1``) as is where frame 0 lies in [0, 1], else
        / frame 0's white level (:func:`float_white_level`), NaN (no return) as 0.

        Raises
        ------
        InputFileError
            Float intensity left outside [0, 1] (negative, -inf, above 1 in a file whose frame
            0 lies in [0, 1]), naming the topic and frame.
        """
        tof = img.dtype == np.uint16 and self.sensor == "tof"
        if not self._white_known:  # frame 0: a pass from a later frame set it from frame 0
            self._set_white(img)
        if tof:
            return amplitude_to_gray(img, self._white or 65535.0)
        gray = normalise_intensity(img, self._white)
        if img.dtype.kind == "f":
            check_stored_intensity(gray, self.path, k, what=f"intensity topic {self._inten.topic}")
        return gray

    # ------------------------------------------------------------------ info / close
    def describe_streams(self) -> list[dict[str, Any]]:
        """Image topics of the bag with counts, rate, size and the role fuse4d gives them."""
        dur = None
        with contextlib.suppress(*self._errors):
            dur = (self._reader.end_time - self._reader.start_time) * 1e-9
        out = []
        for s in self.streams:
            if s.rate is None and dur and s.count > 1:
                s.rate = (s.count - 1) / dur if dur > 0 else None
            out.append(s.describe())
        return out

    def close(self) -> None:
        self._close_stream()
        reader, self._reader = self._reader, None
        if reader is not None:
            with contextlib.suppress(*self._errors):  # already closed or never opened
                reader.close()
        if self._tmpdir is not None:
            self._tmpdir.cleanup()
            self._tmpdir = None
