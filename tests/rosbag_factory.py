"""Small ROS 1 / ROS 2 / MCAP bags for reader tests and benchmarks, written with rosbags."""

from __future__ import annotations

import struct
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Self

import cv2
import numpy as np

from fuse4d.io.rvl import encode_rvl

DEPTH_TOPIC = "/camera/depth/image_rect_raw"
IR_TOPIC = "/camera/infra1/image_rect_raw"
INFO_TOPIC = "/camera/depth/camera_info"
K = (60.0, 61.0, 15.5, 11.5)  # fx, fy, cx, cy of the synthetic camera


class BagWriter:
    """Open a bag of ``kind`` ("ros1", "ros2" = SQLite, "mcap"); ``add``/``write`` messages.

    ROS 2 kinds produce a rosbag2 folder ``path``; :attr:`file` is the storage file inside.
    """

    def __init__(self, path: Path, kind: str = "ros2") -> None:
        from rosbags.typesys import Stores, get_typestore

        self.kind = kind
        self.ros1 = kind == "ros1"
        self.ts = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if self.ros1:
            from rosbags.rosbag1 import Writer

            self.writer = Writer(path)
            self.file = path
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(path, version=9, storage_plugin=plugin)
            self.file = path / f"{path.name}.{'mcap' if kind == 'mcap' else 'db3'}"
        self.conns: dict[str, Any] = {}
        self.writer.open()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.writer.close()

    def header(self, t_ns: int) -> Any:
        t = self.ts.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        hdr = self.ts.types["std_msgs/msg/Header"]
        return hdr(seq=0, stamp=t, frame_id="cam") if self.ros1 else hdr(stamp=t, frame_id="cam")

    def write(self, topic: str, msg: Any, t_ns: int) -> None:
        msgtype = msg.__msgtype__
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.ts)
        raw = (
            self.ts.serialize_ros1(msg, msgtype)
            if self.ros1
            else self.ts.serialize_cdr(msg, msgtype)
        )
        self.writer.write(self.conns[topic], t_ns, raw)

    def image(self, img: np.ndarray, encoding: str, t_ns: int) -> Any:
        img = np.ascontiguousarray(img)
        h, w = img.shape[:2]
        data = np.frombuffer(img.tobytes(), dtype=np.uint8)
        return self.ts.types["sensor_msgs/msg/Image"](
            header=self.header(t_ns), height=h, width=w, encoding=encoding, is_bigendian=0,
            step=data.size // h, data=data,
        )  # fmt: skip

    def compressed_depth(self, img: np.ndarray, codec: str, t_ns: int) -> Any:
        head = struct.pack("<iff", 0, 0.0, 0.0)
        if codec == "rvl":
            h, w = img.shape
            body = struct.pack("<II", w, h) + encode_rvl(img)
        else:
            ok, png = cv2.imencode(".png", img.astype(np.uint16))
            assert ok
            body = png.tobytes()
        return self.ts.types["sensor_msgs/msg/CompressedImage"](
            header=self.header(t_ns),
            format=f"16UC1; compressedDepth {codec}",
            data=np.frombuffer(head + body, dtype=np.uint8),
        )

    def camera_info(self, w: int, h: int, t_ns: int, k: Iterable[float] = K) -> Any:
        fx, fy, cx, cy = k
        mat = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64)
        cls = self.ts.types["sensor_msgs/msg/CameraInfo"]
        roi = self.ts.types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        names = ("D", "K", "R", "P") if self.ros1 else ("d", "k", "r", "p")
        arrays = (np.zeros(5), mat, np.eye(3).ravel(), np.zeros(12))
        return cls(
            header=self.header(t_ns), height=h, width=w, distortion_model="plumb_bob",
            binning_x=0, binning_y=0, roi=roi, **dict(zip(names, arrays, strict=True)),
        )  # fmt: skip


def depth_frames(t: int, h: int = 24, w: int = 32) -> np.ndarray:
    """uint16 depth in mm: 1000 + 10 k + column, with invalid (0) pixels in column 0."""
    d = 1000 + 10 * np.arange(t)[:, None, None] + np.arange(w)[None, None, :]
    d = np.broadcast_to(d, (t, h, w)).astype(np.uint16).copy()
    d[:, :, 0] = 0
    return d


def ir_frames(t: int, h: int = 24, w: int = 32) -> np.ndarray:
    """uint8 IR texture that moves one pixel per frame."""
    yy, xx = np.mgrid[0:h, 0:w]
    return np.stack(
        [(127 + 100 * np.sin((xx - k) / 2.0) * np.cos(yy / 3.0)).astype(np.uint8) for k in range(t)]
    )


def write_generic_bag(
    path: Path,
    kind: str = "ros2",
    *,
    frames: int = 4,
    encoding: str = "16UC1",
    compressed: str | None = None,
    with_ir: bool = True,
    with_info: bool = True,
    with_depth: bool = True,
    ir_size: tuple[int, int] | None = None,
    period_ns: int = 33_333_333,
    t0_ns: int = 1_700_000_000 * 10**9,
) -> Path:
    """A realsense-ros-like bag: depth (+ camera_info) and infra1 topics; returns the file."""
    d = depth_frames(frames)
    ir = ir_frames(frames, *(ir_size or d.shape[1:]))
    with BagWriter(path, kind) as bag:
        for k in range(frames):
            t = t0_ns + k * period_ns
            if with_depth:
                if compressed:
                    bag.write(DEPTH_TOPIC + "/compressedDepth",
                              bag.compressed_depth(d[k], compressed, t), t)  # fmt: skip
                elif encoding == "32FC1":
                    bag.write(DEPTH_TOPIC, bag.image(d[k].astype(np.float32) / 1000, "32FC1", t), t)
                else:
                    bag.write(DEPTH_TOPIC, bag.image(d[k], encoding, t), t)
            if with_info:
                bag.write(INFO_TOPIC, bag.camera_info(d.shape[2], d.shape[1], t), t)
            if with_ir:
                bag.write(IR_TOPIC, bag.image(ir[k], "mono8", t + 1000), t + 1000)
    return bag.file
