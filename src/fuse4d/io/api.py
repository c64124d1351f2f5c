"""Format detection and the format-independent entry points (``load_sequence`` & co.)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Intrinsics
from ..errors import InputFileError, ParameterError
from ..sequence import Sequence, check_sequence
from ._atomic import check_output, warn_unstored_ground_truth
from ._base import Frame, FrameReader, FrameSelection, IntrinsicsLike, ProgressCallback
from .cv2xml import Cv2XmlReader, is_cv2_xml_folder
from .folder import FolderReader, FrameFolderWriter, write_frame_folder
from .frame_range import FrameRange
from .framesjson import FramesJsonReader
from .mkv import MkvReader
from .npz import RESERVED_NPZ_KEYS, NpzReader, read_npz_extra, write_npz
from .rosbag import RosbagReader
from .sensors import check_sensor_options, detect_sensor_format
from .tum import TumReader
from .video import DepthVideoWriter, write_depth_video
from .zarrstore import ZarrReader, ZarrWriter, write_zarr

__all__ = [
    "READ_FORMATS",
    "WRITE_FORMATS",
    "count_frames",
    "detect_format",
    "iter_frames",
    "load_sequence",
    "open_frames",
    "read_intrinsics",
    "save_sequence",
]

#: Layouts :func:`load_sequence` reads, with their reader classes.
READ_FORMATS: dict[str, type[FrameReader]] = {
    "npz": NpzReader,
    "folder": FolderReader,
    "tum": TumReader,
    "cv2-xml": Cv2XmlReader,
    "frames-json": FramesJsonReader,
    "rosbag": RosbagReader,
    "mkv": MkvReader,
    "zarr": ZarrReader,
}
#: Formats :func:`save_sequence` writes.
WRITE_FORMATS = ("npz", "folder", "mkv", "zarr")


#: What a file with a camera recording's suffix must be (:func:`detect_format` goes by the
#: first bytes; a mismatch is named rather than called an unknown type).
_RECORDING_SUFFIXES = {
    ".bag": "a ROS 1 bag",
    ".db3": "a ROS 2 SQLite bag",
    ".mcap": "an MCAP bag",
    ".mkv": "a Matroska video (Azure Kinect, Orbbec or fuse4d)",
}


def detect_format(path: str | PathLike[str]) -> str:
    """Name the layout of ``path`` (one of :data:`READ_FORMATS`).

    Rules, in order: a ``*.npz`` file → ``npz``; a ``frames.json`` file or a folder holding
    one → ``frames-json``; a folder with ``rgb.txt`` and ``depth.txt`` → ``tum``; a folder
    with a ``depth/`` subfolder → ``folder``; a folder with ``NNNN_depth.png`` next to
    ``NNNN_camera.xml`` → ``cv2-xml``. Camera recordings first, by their magic bytes: ROS 1
    bag, ROS 2 SQLite/MCAP (or a rosbag2 folder) → ``rosbag``; Matroska → ``mkv``; a zarr v3
    (``zarr.json``) or v2 (``.zgroup``) store → ``zarr`` (see :mod:`fuse4d.io.sensors`).

    Raises
    ------
    InputFileError
        If ``path`` does not exist or matches no layout.
    """
    p = Path(path)
    sensor = detect_sensor_format(p)
    if sensor is not None:
        return sensor
    if p.is_file():
        if p.suffix.lower() == ".npz":
            return "npz"
        if p.name == "frames.json":
            return "frames-json"
        expected = _RECORDING_SUFFIXES.get(p.suffix.lower())
        if expected is not None:  # the name says a recording, its first bytes do not
            raise InputFileError(
                p,
                f"its name says {expected}, its first bytes do not (truncated, or another "
                "format renamed?)",
            )
        raise InputFileError(
            p,
            "unknown file type (expected .npz, a ROS .bag/.db3/.mcap, an .mkv, or a sequence "
            "folder)",
        )
    if not p.is_dir():
        raise InputFileError(p, "file or folder not found")
    if (p / "frames.json").is_file():
        return "frames-json"
    if (p / "rgb.txt").is_file() and (p / "depth.txt").is_file():
        return "tum"
    if (p / "depth").is_dir():
        return "folder"
    if is_cv2_xml_folder(p):
        return "cv2-xml"
    raise InputFileError(
        p,
        "no depth frames found (expected depth/000000.png ... with camera.json, a TUM "
        "rgb.txt/depth.txt, a frames.json, or NNNN_depth.png + NNNN_camera.xml)",
    )


def open_frames(
    path: str | PathLike[str],
    *,
    format: str | None = None,
    depth_unit_mm: float | None = None,
    intrinsics: IntrinsicsLike | None = None,
    depth_topic: str | None = None,
    intensity_topic: str | None = None,
    intensity: str | None = None,
    undistort: bool | None = None,
    frames: FrameSelection = None,
) -> FrameReader:
    """Open a recording for lazy, frame-by-frame reading (memory independent of its length).

    Parameters
    ----------
    path : str or PathLike
        A ``.npz`` file or a sequence folder.
    format : str, optional
        Force a layout (see :data:`READ_FORMATS`); default: :func:`detect_format`.
    depth_unit_mm : float, optional
        Millimetres per stored depth unit; overrides the layout's own value (``camera.json``,
        ``depth_scale``, TUM's 0.2 mm). Not allowed for ``npz`` (already mm).
    intrinsics : IntrinsicsLike, optional
        Overrides the stored camera; required for TUM folders without ``camera.json``.
    depth_topic, intensity_topic : str, optional
        ``rosbag`` only: topics to use instead of the automatic choice.
    intensity : {"auto", "ir", "color"}, optional
        ``rosbag`` only: guide stream (default ``"auto"``: infrared, else colour aligned to
        depth). See :class:`~fuse4d.io.RosbagReader`.
    undistort : bool, optional
        ``mkv`` (Azure Kinect) only: remove lens distortion (default True).
    frames : slice, range, (start, stop) or "A:B", optional
        Read only this contiguous part, as a recording of its own: frame A of the file is
        the reader's frame 0 (:class:`~fuse4d.io.frame_range.FrameRange`, whose
        ``first_frame`` is A). Default: all frames.

    Returns
    -------
    FrameReader
        ``len(reader)``, ``reader[k]``, ``for frame in reader``, ``reader.intrinsics``,
        ``reader.read_sequence(frames)``.

    Examples
    --------
    >>> with open_frames("recording/") as reader:  # doctest: +SKIP
    ...     for frame in reader:
    ...         process(frame.depth, frame.intensity)
    """
    fmt = format or detect_format(path)
    if fmt not in READ_FORMATS:
        raise ParameterError(f"format must be one of {', '.join(READ_FORMATS)}, got {fmt!r}")
    options = check_sensor_options(
        fmt,
        {"depth_topic": depth_topic, "intensity_topic": intensity_topic,
         "intensity": intensity, "undistort": undistort},
    )  # fmt: skip
    reader = _open_whole(fmt, path, depth_unit_mm, intrinsics, options)
    if frames is None:
        return reader
    try:
        return FrameRange(reader, frames)
    except BaseException:
        reader.close()
        raise


def _open_whole(fmt, path, depth_unit_mm, intrinsics, options) -> FrameReader:
    """The reader of the whole recording (:func:`open_frames` without ``frames``)."""
    if options or fmt in ("rosbag", "mkv"):
        cls = READ_FORMATS[fmt]
        return cls(path, depth_unit_mm=depth_unit_mm, intrinsics=intrinsics, **options)
    if fmt == "npz":
        if depth_unit_mm is not None:
            raise ParameterError(
                "depth_unit_mm does not apply to .npz files (depth is stored in mm)"
            )
        if intrinsics is not None:
            raise ParameterError(".npz files store their intrinsics; intrinsics= is not allowed")
        return NpzReader(path)
    cls = READ_FORMATS[fmt]
    return cls(path, depth_unit_mm=depth_unit_mm, intrinsics=intrinsics)  # type: ignore[call-arg]


def load_sequence(
    path: str | PathLike[str],
    *,
    frames: FrameSelection = None,
    depth_unit_mm: float | None = None,
    intrinsics: IntrinsicsLike | None = None,
    format: str | None = None,
    progress: ProgressCallback | None = None,
    **options: Any,
) -> Sequence:
    """Load a recording in any supported layout into a :class:`~fuse4d.Sequence`.

    Parameters
    ----------
    path : str or PathLike
        A ``.npz`` file or a sequence folder (``folder``, ``tum``, ``cv2-xml``,
        ``frames-json``; see ``docs/formats.md``).
    frames : slice, range, (start, stop), "A:B" or None, optional
        Contiguous frame range (default: all).
    depth_unit_mm, intrinsics, format
        See :func:`open_frames`.
    **options
        Recording options (``depth_topic``, ``intensity_topic``, ``intensity``,
        ``undistort``); see :func:`open_frames`.
    progress : callable, optional
        ``callback(done, total)`` after each frame.

    Returns
    -------
    Sequence
        Depth (T, H, W) float32 mm with NaN = invalid, intensity (T, H, W) float32 in [0, 1],
        intrinsics, timestamps (s) where the layout stores them, fps, and ground truth
        (``mask`` for layouts with object masks; depth/mask/flow GT from npz).

    Raises
    ------
    InputFileError
        Missing, corrupt or inconsistent input, naming the file and frame.
    """
    reader = open_frames(
        path, format=format, depth_unit_mm=depth_unit_mm, intrinsics=intrinsics, **options
    )
    with reader:
        return reader.read_sequence(frames, progress=progress)


def iter_frames(
    path: str | PathLike[str],
    *,
    frames: FrameSelection = None,
    depth_unit_mm: float | None = None,
    intrinsics: IntrinsicsLike | None = None,
    format: str | None = None,
    **options: Any,
) -> Iterator[Frame]:
    """Yield the frames of a recording one at a time (see :class:`~fuse4d.io.Frame`)."""
    with open_frames(
        path, format=format, depth_unit_mm=depth_unit_mm, intrinsics=intrinsics, **options
    ) as reader:
        yield from reader.iter_frames(frames)


def read_intrinsics(
    path: str | PathLike[str],
    *,
    intrinsics: IntrinsicsLike | None = None,
    format: str | None = None,
) -> Intrinsics:
    """The camera of a recording, without reading its frames (beyond the first's size)."""
    with open_frames(path, format=format, intrinsics=intrinsics) as reader:
        return reader.intrinsics


def count_frames(
    path: str | PathLike[str],
    *,
    intrinsics: IntrinsicsLike | None = None,
    format: str | None = None,
) -> int:
    """Number of frames of a recording, without reading them."""
    with open_frames(path, format=format, intrinsics=intrinsics) as reader:
        return len(reader)


def save_sequence(
    seq: Sequence,
    path: str | PathLike[str],
    *,
    format: str | None = None,
    overwrite: bool = False,
    depth_unit_mm: float = 1.0,
    progress: ProgressCallback | None = None,
    warn_coarse_unit: bool = True,
) -> Path:
    """Write a sequence atomically as ``.npz`` (lossless, keeps ground truth), a frame folder,
    an FFV1 ``.mkv`` (lossless 16-bit depth video) or a ``.zarr`` v3 store (float, lossless).

    Ground truth is kept by ``.npz`` only (a frame folder keeps the object masks); a
    ``UserWarning`` names what another layout drops.

    Parameters
    ----------
    seq : Sequence
        The sequence.
    path : str or PathLike
        Output; ``format`` follows the suffix (``.npz``, ``.mkv``, ``.zarr``), else ``folder``
        (a suffix of another file format, e.g. ``.mp4``, is a
        :class:`~fuse4d.ParameterError`; see :func:`output_layout`).
    format : {"npz", "folder", "mkv", "zarr"}, optional
        Override the suffix's layout.
    overwrite : bool, optional
        Replace an existing output. Default False (:class:`~fuse4d.OutputExistsError`).
    depth_unit_mm : float, optional
        Folder and mkv formats: millimetres per stored unit (default 1.0). Values are
        rounded and clipped to 16 bit with a ``UserWarning`` on clipping or coarse rounding.
    progress : callable, optional
        ``callback(done, total)`` (folder format).
    warn_coarse_unit : bool, optional
        Folder and mkv formats: warn when ``depth_unit_mm`` is coarse for the data (default
        True). False where it is the input recording's own unit (a filtered result of it).

    Returns
    -------
    Path
        The written file or folder.
    """
    check_sequence(seq, "save_sequence")
    fmt = format or output_layout(path)
    if fmt == "npz":
        return write_npz(seq, path, overwrite=overwrite)
    if fmt == "mkv":
        return write_depth_video(
            seq, path, depth_unit_mm=depth_unit_mm, overwrite=overwrite,
            warn_coarse_unit=warn_coarse_unit,
        )  # fmt: skip
    if fmt == "zarr":
        return write_zarr(seq, path, overwrite=overwrite)
    if fmt == "folder":
        return write_frame_folder(
            seq, path, depth_unit_mm=depth_unit_mm, overwrite=overwrite, progress=progress,
            warn_coarse_unit=warn_coarse_unit,
        )  # fmt: skip
    raise ParameterError(f"format must be one of {', '.join(WRITE_FORMATS)}, got {fmt!r}")


#: Suffixes of files that fuse4d reads or that other tools write, never a fuse4d output: a
#: path ending in one is refused rather than silently made a frame folder of that name.
FILE_SUFFIXES = frozenset(
    [
        ".mp4",
        ".avi",
        ".mov",
        ".webm",
        ".m4v",
        ".gif",
        ".png",
        ".jpg",
        ".jpeg",
        ".tif",
        ".tiff",
        ".exr",
        ".ply",
        ".pcd",
        ".bag",
        ".db3",
        ".mcap",
        ".h5",
        ".hdf5",
        ".npy",
        ".flo",
        ".json",
        ".csv",
        ".txt",
        ".html",
    ]
)


def output_layout(path: str | PathLike[str]) -> str:
    """The layout (one of :data:`WRITE_FORMATS`) an output ``path`` is written in, by its
    suffix: ``.npz``, ``.mkv`` (FFV1 depth video), ``.zarr``, else a frame folder.

    Raises
    ------
    ParameterError
        A suffix of :data:`FILE_SUFFIXES` (e.g. ``out.mp4``): a user who names a file of a
        format fuse4d does not write would otherwise get a folder called ``out.mp4``.
    """
    suffix = Path(path).suffix.lower()
    if suffix in FILE_SUFFIXES:
        raise ParameterError(
            f"{path}: fuse4d does not write {suffix} files; give a frame folder (a name without "
            "a suffix), an .mkv (FFV1 depth video), a .zarr or an .npz (fuse4d report writes a "
            "viewable compare.mp4)"
        )
    return {".npz": "npz", ".mkv": "mkv", ".zarr": "zarr"}.get(suffix, "folder")


def stream_writer(path: str | PathLike[str]) -> tuple[type, str]:
    """The frame-by-frame writer class of an output ``path`` and its layout (``fuse4d run``,
    :func:`convert_recording`); ``.npz`` is written from memory and has none."""
    fmt = output_layout(path)
    writers = {"folder": FrameFolderWriter, "mkv": DepthVideoWriter, "zarr": ZarrWriter}
    if fmt not in writers:
        raise ParameterError(f"{path}: an .npz is written from memory, not frame by frame")
    return writers[fmt], fmt


#: How a ground-truth warning names a streamed output layout.
_LAYOUT_NAMES = {"folder": "the frame-folder format", "mkv": "the .mkv format",
                 "zarr": "the .zarr format"}  # fmt: skip


def _unstored_keys(keys: tuple[str, ...], layout: str) -> list[str]:
    """The ground truth of a reader (its ``ground_truth_keys``) that a ``layout`` output
    drops: all of it, but the object mask for a frame folder; an npz's ``gt_*`` values (scene
    geometry and settings) are counted, not listed."""
    dropped = [k for k in keys if not k.startswith("gt_") and (k, layout) != ("mask", "folder")]
    extra = sum(k.startswith("gt_") for k in keys)
    if extra:
        dropped.append(f"{extra} gt_* value{'' if extra == 1 else 's'}")
    return dropped


def _other_arrays(src: Path, reader: FrameReader) -> list[str]:
    """The arrays of the recording ``src`` (read by ``reader``) that are neither its frames nor
    ground truth: an .npz's other keys (``fuse4d run``'s ``support``, ``source``,
    ``confidence``, ...), the ``source`` and ``confidence`` of a fused folder or .zarr."""
    if reader.format == "npz":
        with np.load(src) as archive:  # the member names only
            return [
                k for k in archive.files if k not in RESERVED_NPZ_KEYS and not k.startswith("gt_")
            ]
    if len(reader) and reader.read_source(0, 1) is not None:
        return ["source", "confidence"]
    return []


def convert_recording(
    input: str | PathLike[str],
    output: str | PathLike[str],
    *,
    frames: FrameSelection = None,
    out_depth_unit_mm: float | None = None,
    overwrite: bool = False,
    progress: ProgressCallback | None = None,
    **reader_options: Any,
) -> Path:
    """Write a recording, or a part of it, in another layout (``fuse4d convert``).

    Frames are read and written one at a time (memory independent of the length), except
    for an ``.npz`` output, which is written from memory. The output is written under a
    temporary name and renamed into place, so a failed or interrupted conversion leaves
    nothing; the input is never touched.

    Parameters
    ----------
    input : str or PathLike
        Any layout :func:`open_frames` reads (a camera recording included).
    output : str or PathLike
        ``.npz`` (lossless; keeps ground truth), ``.mkv`` (FFV1, 16-bit depth), ``.zarr``
        (float, lossless), else a frame folder (16-bit PNGs). Depth, intensity, timestamps,
        frame rate, the camera kind (``sensor``, which decides A36's flying-pixel removal)
        and the object masks of a layout that stores them (folder output) are carried over;
        other ground truth only to ``.npz`` (a ``UserWarning`` names what is dropped). The
        other arrays of an ``.npz`` (a fused output's ``support``, ``source``, ``confidence``
        ...) are kept, sliced like the frames, from ``.npz`` to ``.npz`` only; a
        ``UserWarning`` names those another output drops, and a fused folder's or ``.zarr``'s
        ``source`` and ``confidence``, which no conversion keeps.
    frames : slice, range, (start, stop) or "A:B", optional
        Only this contiguous part (numbered from 0 in the output). Default: all frames.
    out_depth_unit_mm : float, optional
        Folder and ``.mkv`` outputs: millimetres per stored unit. Default: the input's own
        unit (lossless from 16-bit depth), or 1 mm for float depth (``.npz``, ``.zarr``, a
        32-bit float depth topic; a warning says where that rounding is coarse). Refused
        for ``.npz`` and ``.zarr`` outputs, which store float depth in mm.
    overwrite : bool, optional
        Replace an existing ``output``.
    progress : callable, optional
        ``callback(done, total)`` after each frame.
    **reader_options
        :func:`open_frames` options for the input (``format``, ``depth_unit_mm``,
        ``intrinsics``, ``depth_topic``, ``intensity_topic``, ``intensity``, ``undistort``).

    Returns
    -------
    Path
        The written file or folder.

    Examples
    --------
    >>> convert_recording("rec.bag", "rec_part.zarr", frames="200:300")  # doctest: +SKIP
    PosixPath('rec_part.zarr')
    """
    src, dst = Path(input), Path(output)
    check_output(dst, overwrite=overwrite, inputs=[src])
    layout = output_layout(dst)  # refuses a file suffix fuse4d does not write, before reading
    if out_depth_unit_mm is not None and not (
        math.isfinite(out_depth_unit_mm) and out_depth_unit_mm > 0
    ):  # 0 used to mean "the input's unit" silently
        raise ParameterError(f"out_depth_unit_mm must be > 0 mm, got {out_depth_unit_mm}")
    if out_depth_unit_mm is not None and layout in ("npz", "zarr"):  # was silently ignored
        raise ParameterError(
            f"{dst}: out_depth_unit_mm applies to frame-folder and .mkv outputs (16-bit depth) "
            "only; .npz and .zarr outputs store float depth in mm"
        )
    with open_frames(src, frames=frames, **reader_options) as reader:
        others = _other_arrays(src, reader)
        keep = layout == "npz" and reader.format == "npz"
        if others and not keep:
            warnings.warn(
                f"{dst}: the arrays {', '.join(others)} of {src} are not carried over (only "
                "an .npz converted to an .npz keeps them)",
                UserWarning,
                stacklevel=2,
            )
        if layout == "npz":
            extra = read_npz_extra(src, frames=frames) if keep and others else None
            seq = reader.read_sequence(progress=progress)
            return write_npz(seq, dst, extra=extra, overwrite=overwrite)
        writer_cls, _ = stream_writer(dst)
        dropped = _unstored_keys(reader.ground_truth_keys, layout)
        warn_unstored_ground_truth(dst, _LAYOUT_NAMES[layout], dropped, stacklevel=2)
        unit = out_depth_unit_mm or reader.depth_unit_mm or 1.0
        total = len(reader)
        with writer_cls(
            dst,
            reader.intrinsics,
            depth_unit_mm=unit,
            fps=reader.fps,
            overwrite=overwrite,
            sensor=reader.sensor,  # a ToF recording stays one (A36)
        ) as writer:
            for k, frame in enumerate(reader):
                writer.write(
                    frame.depth, frame.intensity, mask=frame.mask, timestamp=frame.timestamp
                )
                if progress is not None:
                    progress(k + 1, total)
    return dst
