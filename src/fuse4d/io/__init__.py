"""Reading and writing 3D videos: fuse4d's npz and frame-folder formats, real RGB-D layouts
(TUM, cv2-xml, frames-json), camera recordings (ROS 1/ROS 2/MCAP bags and RealSense
``.bag``/``.db3``, Azure Kinect/Orbbec ``.mkv``; the ``sensors`` extra), FFV1 depth video and
zarr v3 stores, PLY point clouds (Middlebury ``.flo`` flow files: :mod:`fuse4d.flow.flo`).

In memory: depth (T, H, W) float32 mm with NaN = invalid, intensity (T, H, W) float32 in
[0, 1]. On disk, 16-bit depth stores ``value * depth_unit_mm`` mm with 0 = invalid. Every
writer is atomic (temporary name + rename) and refuses to replace an existing output unless
``overwrite=True``; every reader reports a bad file with one :class:`~fuse4d.InputFileError`
naming the file and the frame. See ``docs/formats.md``.
"""

from __future__ import annotations

from ._atomic import check_output
from ._base import CAMERA_PRESETS, Frame, FrameReader, read_camera_json, resolve_frames
from ._images import read_depth_png, read_intensity_image, read_mask_image
from .api import (
    READ_FORMATS,
    WRITE_FORMATS,
    convert_recording,
    count_frames,
    detect_format,
    iter_frames,
    load_sequence,
    open_frames,
    read_intrinsics,
    save_sequence,
)
from .cv2xml import Cv2XmlReader
from .folder import FolderReader, FrameFolderWriter, read_frame_folder, write_frame_folder
from .framesjson import FramesJsonReader
from .mask import read_mask
from .mkv import MkvReader
from .npz import NpzReader, read_npz, read_npz_extra, write_npz
from .ply import read_ply, write_ply
from .rosbag import RosbagReader
from .tum import TumReader, associate_timestamps, read_tum
from .video import DepthVideoWriter, write_depth_video
from .zarrstore import ZarrReader, ZarrWriter, write_zarr

__all__ = [
    "CAMERA_PRESETS",
    "READ_FORMATS",
    "WRITE_FORMATS",
    "Cv2XmlReader",
    "DepthVideoWriter",
    "FolderReader",
    "Frame",
    "FrameFolderWriter",
    "FrameReader",
    "FramesJsonReader",
    "MkvReader",
    "NpzReader",
    "RosbagReader",
    "TumReader",
    "ZarrReader",
    "ZarrWriter",
    "associate_timestamps",
    "check_output",
    "convert_recording",
    "count_frames",
    "detect_format",
    "iter_frames",
    "load_sequence",
    "open_frames",
    "read_camera_json",
    "read_depth_png",
    "read_frame_folder",
    "read_intensity_image",
    "read_intrinsics",
    "read_mask",
    "read_mask_image",
    "read_npz",
    "read_npz_extra",
    "read_ply",
    "read_tum",
    "resolve_frames",
    "save_sequence",
    "write_depth_video",
    "write_frame_folder",
    "write_npz",
    "write_ply",
    "write_zarr",
]
