"""The frame-folder sequence format: one 16-bit depth PNG and one intensity image per frame.

Layout::

    SEQ/
      camera.json          {"fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5,
                            "depth_unit_mm": 1.0, "fps": 30.0}      (fps optional)
      depth/000000.png     uint16; value * depth_unit_mm = depth in mm; 0 = invalid
      intensity/000000.png 8- or 16-bit, gray or colour (converted to gray); .jpg allowed
      mask/000000.png      optional object mask (>= 50 % of max = True) -> GroundTruth.mask
      timestamps.txt       optional, one time in seconds per line

Frames are numbered 0, 1, 2, ... without gaps (any number of digits; the writer uses 6).
"""

from __future__ import annotations

import json
import re
from contextlib import ExitStack
from os import PathLike
from pathlib import Path
from types import TracebackType
from typing import Self

import numpy as np
from numpy.typing import NDArray

from ..camera import Intrinsics, check_intrinsics
from ..errors import InputFileError, ParameterError
from ..sequence import Sequence, as_storable_intensity
from ._atomic import (
    atomic_dir,
    check_output,
    checked_for_layout,
    reports_write_errors,
)
from ._base import (
    Frame,
    FrameReader,
    IntrinsicsLike,
    ProgressCallback,
    _check_size,
    check_flags,
    check_frame_shapes,
    checked_timestamp,
    depth_unit,
    flag_images,
    read_camera_json,
    resolve_intrinsics,
)
from ._images import (
    QuantizationReport,
    check_frame_shape,
    decode_image,
    depth_to_units,
    encode_png,
    intensity_to_uint,
    read_checked_intensity,
    read_depth_png,
    read_intensity_image,
    read_mask_image,
)

__all__ = ["FolderReader", "FrameFolderWriter", "read_frame_folder", "write_frame_folder"]

_NUMBERED = re.compile(r"^(\d+)$")
_INTENSITY_EXT = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


def _numbered_files(folder: Path, extensions: tuple[str, ...]) -> dict[int, Path]:
    if not folder.is_dir():
        return {}
    found: dict[int, Path] = {}
    for p in sorted(folder.iterdir()):
        m = _NUMBERED.match(p.stem)
        if m and p.suffix.lower() in extensions and p.is_file():
            k = int(m.group(1))
            if k in found:
                raise InputFileError(
                    p, f"frame number {k} appears twice (also {found[k].name}); keep one", frame=k
                )
            found[k] = p
    return found


def _check_contiguous(files: dict[int, Path], folder: Path, ext: str) -> None:
    for k in range(len(files)):
        if k not in files:
            width = len(next(iter(files.values())).stem)
            raise InputFileError(
                folder / f"{k:0{width}d}{ext}",
                "file not found (frames must be numbered 0, 1, 2, ... without gaps)",
                frame=k,
            )


class FolderReader(FrameReader):
    """Frame reader for a frame folder (see the module docstring for the layout).

    Parameters
    ----------
    path : str or PathLike
        The sequence folder.
    depth_unit_mm : float, optional
        Overrides ``depth_unit_mm`` of ``camera.json``.
    intrinsics : IntrinsicsLike, optional
        Overrides ``fx, fy, cx, cy`` of ``camera.json`` (which may then be absent, if
        ``depth_unit_mm`` is given as well).

    Raises
    ------
    InputFileError
        Empty/missing ``depth/``, gaps in the numbering, intensity/mask counts differing from
        depth, missing or incomplete ``camera.json``, unreadable first frame.
    """

    format = "folder"

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        depth_unit_mm: float | None = None,
        intrinsics: IntrinsicsLike | None = None,
    ) -> None:
        self.path = root = Path(path)
        if not root.is_dir():
            raise InputFileError(root, "folder not found")
        _refuse_unfinished_run(root)
        self._depth = _numbered_files(root / "depth", (".png",))
        if not self._depth:
            _refuse_half_tum(root)
            raise InputFileError(
                root, "no depth frames found (expected depth/000000.png, depth/000001.png, ...)"
            )
        _check_contiguous(self._depth, root / "depth", ".png")
        n = len(self._depth)
        self._intensity = _numbered_files(root / "intensity", _INTENSITY_EXT)
        if not self._intensity:
            _refuse_half_tum(root)
            raise InputFileError(
                root, "no intensity frames found (expected intensity/000000.png, ...)"
            )
        _check_contiguous(self._intensity, root / "intensity", ".png")
        if len(self._intensity) != n:
            raise InputFileError(
                root / "intensity",
                f"{len(self._intensity)} intensity frames but {n} depth frames; "
                "every depth frame needs an intensity frame",
            )
        self._mask = _numbered_files(root / "mask", _INTENSITY_EXT)
        if self._mask:
            _check_contiguous(self._mask, root / "mask", ".png")
            if len(self._mask) != n:
                raise InputFileError(
                    root / "mask", f"{len(self._mask)} mask frames but {n} depth frames"
                )
            self.ground_truth_keys = ("mask",)
        # a fused output's per-pixel source codes (FrameFolderWriter's flags), when complete
        self._source = _numbered_files(root / "source", (".png",))
        if len(self._source) != n:
            self._source = []
        first = decode_image(self._depth[0], frame=0)
        h, w = first.shape[:2]
        cam_path = root / "camera.json"
        cam: dict[str, float | None] = {}
        if intrinsics is None or depth_unit_mm is None or cam_path.exists():
            if not cam_path.exists():
                raise InputFileError(
                    cam_path,
                    "file not found (a frame folder needs camera.json with fx, fy, cx, cy, "
                    "depth_unit_mm)",
                )
            cam = read_camera_json(
                cam_path, require_unit=depth_unit_mm is None, require_camera=intrinsics is None
            )
            _check_size(cam, w, h, cam_path)
        unit = depth_unit_mm if depth_unit_mm is not None else cam["depth_unit_mm"]
        self.depth_unit_mm = depth_unit(unit, None if depth_unit_mm is not None else cam_path)
        if intrinsics is not None:
            self.intrinsics = resolve_intrinsics(intrinsics, width=w, height=h)
        else:
            self.intrinsics = Intrinsics(
                cam["fx"], cam["fy"], cam["cx"], cam["cy"], width=w, height=h
            )
        self.fps = cam.get("fps")
        self.sensor = cam.get("sensor")  # type: ignore[assignment]
        ts_path = root / "timestamps.txt"
        if ts_path.exists():
            self.timestamps = _read_timestamps(ts_path, n)

    def __len__(self) -> int:
        return len(self._depth)

    def read_frame(self, index: int) -> Frame:
        """Frame ``index``: depth (H, W) mm float32 (NaN invalid), intensity (H, W) [0, 1]."""
        k = self._index(index)
        depth = read_depth_png(self._depth[k], frame=k, unit_mm=self.depth_unit_mm or 1.0)
        check_frame_shape(depth, self.shape, self._depth[k], k, against="frame 0")
        intensity = read_intensity_image(self._intensity[k], frame=k)
        check_frame_shape(intensity, self.shape, self._intensity[k], k, against="the depth frame")
        mask = None
        if self._mask:
            mask = read_mask_image(self._mask[k], frame=k)
            check_frame_shape(mask, self.shape, self._mask[k], k, against="the depth frame")
        ts = None if self.timestamps is None else float(self.timestamps[k])
        return Frame(k, depth, intensity, ts, mask)

    def read_intensity(self, index: int) -> NDArray[np.float32]:
        """Frame ``index``'s intensity alone (the depth PNG is not decoded)."""
        k = self._index(index)
        return read_checked_intensity(self._intensity[k], k, self.shape)

    def read_source(self, start: int, stop: int) -> NDArray[np.uint8] | None:
        """The ``source/`` PNGs of frames ``start:stop`` (see :meth:`FrameReader.read_source`)."""
        if not self._source:
            return None
        frames = []
        for k in range(start, stop):
            codes = decode_image(self._source[k], frame=k)
            if codes.dtype != np.uint8:
                raise InputFileError(self._source[k], "source codes must be 8-bit", frame=k)
            check_frame_shape(codes, self.shape, self._source[k], k, against="the depth frame")
            frames.append(codes)
        return np.stack(frames)


def _refuse_unfinished_run(root: Path) -> None:
    """A folder that ``fuse4d run`` is still writing (or was killed while writing)."""
    from .resume import unfinished_run_message  # local import: resume imports this module

    message = unfinished_run_message(root)
    if message:
        raise InputFileError(root, message)


def _refuse_half_tum(root: Path) -> None:
    """A TUM folder with one of its two lists, found lacking as a frame folder: say so."""
    lists = [(root / name).is_file() for name in ("depth.txt", "rgb.txt")]
    if any(lists) and not all(lists):
        missing = "rgb.txt" if lists[0] else "depth.txt"
        raise InputFileError(
            root, f"TUM folder: {missing} not found (a TUM folder needs rgb.txt and depth.txt)"
        )


def _read_timestamps(path: Path, n: int) -> np.ndarray:
    try:
        values = [
            float(line.split()[0])
            for line in path.read_text(encoding="utf-8").splitlines()
            if line.strip() and not line.lstrip().startswith("#")
        ]
    except ValueError as exc:
        raise InputFileError(path, f"cannot parse timestamps ({exc})") from None
    if len(values) != n:
        raise InputFileError(path, f"{len(values)} timestamps for {n} frames")
    ts = np.asarray(values, dtype=np.float64)
    if not np.isfinite(ts).all():
        raise InputFileError(path, "timestamps must be finite numbers (found NaN or inf)")
    if n > 1 and not np.all(np.diff(ts) > 0):
        raise InputFileError(path, "timestamps must be strictly increasing")
    return ts


def read_frame_folder(
    path: str | PathLike[str],
    *,
    frames: slice | range | tuple[int | None, int | None] | str | None = None,
    depth_unit_mm: float | None = None,
    intrinsics: IntrinsicsLike | None = None,
    progress: ProgressCallback | None = None,
) -> Sequence:
    """Read a frame folder into a :class:`~fuse4d.Sequence` (depth mm, NaN = invalid).

    See :class:`FolderReader` for the parameters and errors; ``frames`` selects a contiguous
    range. A ``mask/`` folder becomes ``ground_truth.mask``.
    """
    reader = FolderReader(path, depth_unit_mm=depth_unit_mm, intrinsics=intrinsics)
    return reader.read_sequence(frames, progress=progress)


class FrameFolderWriter:
    """Write a frame folder frame by frame; the folder appears at ``path`` only when complete.

    Frames are written into a hidden temporary folder next to ``path``; :meth:`close` (or
    leaving the ``with`` block without error) writes ``camera.json`` and renames the folder
    into place. If an exception escapes the ``with`` block, the temporary folder is deleted
    and ``path`` is left as it was.

    Parameters
    ----------
    path : str or PathLike
        Destination folder.
    intrinsics : Intrinsics
        Camera; frames must be ``(intrinsics.height, intrinsics.width)``.
    depth_unit_mm : float, optional
        Millimetres per stored unit (default 1.0: 1 mm steps, range up to 65.535 m). Depth is
        rounded to the unit and clipped to [1, 65535] units; one ``UserWarning`` at close
        reports clipped values and a unit that is coarse compared with the data's noise.
    fps : float, optional
        Stored in ``camera.json``.
    intensity_bits : {8, 16} or None, optional
        Bit depth of the intensity PNGs; None (default) picks 8 when a frame is exactly
        representable in 8 bits and 16 otherwise.
    overwrite : bool, optional
        Replace an existing ``path``. Default False (raises :class:`OutputExistsError`).
    sensor : str, optional
        The camera kind (``"tof"``, ``"structured-light"``, ``"active-stereo"``), stored in
        ``camera.json`` so that the folder is fused as its camera's recording was (A36).
    warn_coarse_unit : bool, optional
        Warn at close when ``depth_unit_mm`` is coarse against the data's pixel noise
        (default True); False where it is the input recording's own unit (``fuse4d run``).

    Examples
    --------
    >>> with FrameFolderWriter(out, seq.intrinsics) as writer:  # doctest: +SKIP
    ...     for depth, intensity in zip(seq.depth, seq.intensity):
    ...         writer.write(depth, intensity)
    """

    #: :meth:`write` stores a fused frame's per-pixel ``source`` and ``confidence``.
    stores_flags = True

    def __init__(
        self,
        path: str | PathLike[str],
        intrinsics: Intrinsics,
        *,
        depth_unit_mm: float = 1.0,
        fps: float | None = None,
        intensity_bits: int | None = None,
        overwrite: bool = False,
        sensor: str | None = None,
        warn_coarse_unit: bool = True,
    ) -> None:
        check_intrinsics(intrinsics)
        if not (np.isfinite(depth_unit_mm) and depth_unit_mm > 0):
            raise ParameterError(f"depth_unit_mm must be > 0, got {depth_unit_mm!r}")
        if intensity_bits not in (None, 8, 16):
            raise ParameterError(f"intensity_bits must be 8, 16 or None, got {intensity_bits!r}")
        if fps is not None and not (np.isfinite(fps) and fps > 0):
            raise ParameterError(f"fps must be > 0, got {fps!r}")
        self.path = check_output(path, overwrite=overwrite)
        self.intrinsics = intrinsics
        self.depth_unit_mm = float(depth_unit_mm)
        self.fps = fps
        self.intensity_bits = intensity_bits
        self.overwrite = overwrite
        self.sensor = sensor
        self.num_written = 0
        self._timestamps: list[float | None] = []
        self._has_mask: bool | None = None
        self._has_flags: bool | None = None
        self._report = QuantizationReport(self.depth_unit_mm, warn_coarse_unit=warn_coarse_unit)
        self._stack: ExitStack | None = None
        self._tmp: Path | None = None

    def __enter__(self) -> Self:
        try:
            self.open()
        except BaseException:
            self.abort()  # ``with`` does not call __exit__ when __enter__ fails
            raise
        return self

    @reports_write_errors
    def open(self) -> None:
        """Create the temporary folder (called by ``with``)."""
        if self._stack is not None:
            raise RuntimeError("FrameFolderWriter is already open")
        stack = ExitStack()
        self._tmp = stack.enter_context(atomic_dir(self.path, overwrite=self.overwrite))
        self._stack = stack
        (self._tmp / "depth").mkdir()
        (self._tmp / "intensity").mkdir()

    @reports_write_errors
    def write(
        self,
        depth: np.ndarray,
        intensity: np.ndarray,
        *,
        mask: np.ndarray | None = None,
        timestamp: float | None = None,
        source: np.ndarray | None = None,
        confidence: np.ndarray | None = None,
    ) -> None:
        """Append one frame.

        Parameters
        ----------
        depth : (H, W) ndarray
            Depth in mm; NaN, inf and values <= 0 are stored as 0 (invalid).
        intensity : (H, W) ndarray of float
            Intensity in [0, 1] (values slightly outside are clipped; uint8/uint16 are divided
            by 255/65535).
        mask : (H, W) ndarray of bool, optional
            Object mask (all frames or none).
        timestamp : float, optional
            Capture time in seconds (all frames or none).
        source, confidence : (H, W) ndarray, optional
            A fused frame's per-pixel flags (:attr:`fuse4d.FusedFrame.source` codes,
            ``confidence`` in [0, 1]), stored as ``source/`` (uint8 codes) and ``confidence/``
            (uint8, round(255 c)) PNGs; both or neither, for all frames or none.
        """
        if self._tmp is None:
            raise RuntimeError("FrameFolderWriter is not open; use it in a `with` block")
        shape = self.intrinsics.shape
        check_frame_shapes(self.num_written, shape, depth=depth, intensity=intensity, mask=mask)
        stamp = checked_timestamp(  # (timestamps.txt holds microseconds)
            self._timestamps, timestamp, self.num_written, self.path, resolution=1e-6
        )
        intensity = as_storable_intensity(intensity, name=f"intensity of frame {self.num_written}")
        if self._has_mask is None:
            self._has_mask = mask is not None
            if self._has_mask:
                (self._tmp / "mask").mkdir()
        elif self._has_mask != (mask is not None):
            raise ParameterError(
                f"frame {self.num_written}: give a mask for every frame or for none"
            )
        check_flags(self.num_written, shape, source, confidence)
        if self._has_flags is None:
            self._has_flags = source is not None
        elif self._has_flags != (source is not None):
            raise ParameterError(
                f"frame {self.num_written}: give source and confidence for every frame or none"
            )
        k = self.num_written
        name = f"{k:06d}.png"
        encode_png(
            depth_to_units(depth, self.depth_unit_mm, self._report), self._tmp / "depth" / name
        )
        encode_png(self._intensity_image(intensity), self._tmp / "intensity" / name)
        if mask is not None:
            encode_png(np.where(np.asarray(mask, bool), 255, 0).astype(np.uint8),
                       self._tmp / "mask" / name)  # fmt: skip
        if source is not None:
            for sub, image in flag_images(source, confidence):
                (self._tmp / sub).mkdir(exist_ok=True)
                encode_png(image, self._tmp / sub / name)
        self._timestamps.append(stamp)
        self.num_written += 1

    def _intensity_image(self, intensity: np.ndarray) -> np.ndarray:
        return intensity_image(intensity, self.intensity_bits)

    @reports_write_errors
    def close(self) -> None:
        """Finish: write ``camera.json`` (+ ``timestamps.txt``) and move the folder into place."""
        if self._stack is None or self._tmp is None:
            return
        stack, self._stack = self._stack, None
        try:
            if self.num_written == 0:
                raise ParameterError(f"{self.path}: no frame was written")
            text = camera_json_text(self.intrinsics, self.depth_unit_mm, self.fps, self.sensor)
            (self._tmp / "camera.json").write_text(text)
            stamps = self._timestamps
            if any(t is not None for t in stamps):
                if any(t is None for t in stamps):
                    raise ParameterError("give a timestamp for every frame or for none")
                text = "".join(f"{t:.6f}\n" for t in stamps)
                (self._tmp / "timestamps.txt").write_text(text)
        except BaseException as exc:
            stack.__exit__(type(exc), exc, exc.__traceback__)
            raise
        stack.close()
        self._tmp = None
        self._report.warn(str(self.path), stacklevel=5)  # (through @reports_write_errors)

    def abort(self) -> None:
        """Discard everything written so far; ``path`` is left untouched."""
        if self._stack is None:
            return
        stack, self._stack, self._tmp = self._stack, None, None
        err = RuntimeError("aborted")
        stack.__exit__(RuntimeError, err, None)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def intensity_image(intensity: np.ndarray, bits: int | None) -> np.ndarray:
    """Intensity in [0, 1] as the uint8/uint16 image stored in a frame folder.

    ``bits=None`` picks 8 when the frame is exactly representable in 8 bits, else 16.
    """
    if bits is None:
        arr = np.asarray(intensity)
        if arr.ndim == 2 and arr.dtype in (np.float32, np.float64):
            # one pass, the same values and test as the numpy code below (issue 13: ~10 ms
            # per 640x480 frame in the write-behind thread)
            from .._kernels.io import _intensity_to_uint8_kernel

            # np.allclose's tolerance as numpy computes it for this dtype (1e-6 rounded to
            # the input's precision)
            tol = float((1e-6 + 0.0 * np.abs(np.zeros(1, arr.dtype)))[0])
            i8 = np.empty(arr.shape, np.uint8)
            exact, special = _intensity_to_uint8_kernel(arr, tol, i8)
            if not special:
                return i8 if exact else intensity_to_uint(intensity, 16)
        i8 = intensity_to_uint(intensity, 8)
        exact = np.allclose(i8 / 255.0, np.nan_to_num(intensity), rtol=0, atol=1e-6)
        return i8 if exact else intensity_to_uint(intensity, 16)
    return intensity_to_uint(intensity, bits)


def camera_json_text(
    intrinsics: Intrinsics, depth_unit_mm: float, fps: float | None, sensor: str | None = None
) -> str:
    """The ``camera.json`` of a frame folder (``sensor``: the camera kind, where known)."""
    cam: dict[str, float | int | str] = {
        "fx": intrinsics.fx,
        "fy": intrinsics.fy,
        "cx": intrinsics.cx,
        "cy": intrinsics.cy,
        "width": intrinsics.width,
        "height": intrinsics.height,
        "depth_unit_mm": depth_unit_mm,
    }
    if fps is not None:
        cam["fps"] = float(fps)
    if sensor:
        cam["sensor"] = sensor
    return json.dumps(cam, indent=2) + "\n"


def write_frame_folder(
    seq: Sequence,
    path: str | PathLike[str],
    *,
    depth_unit_mm: float = 1.0,
    intensity_bits: int | None = None,
    overwrite: bool = False,
    progress: ProgressCallback | None = None,
    warn_coarse_unit: bool = True,
) -> Path:
    """Write a sequence as a frame folder, atomically (see :class:`FrameFolderWriter`, whose
    ``warn_coarse_unit`` this passes on).

    ``ground_truth.mask`` is written to ``mask/``; ground-truth depth, flow and extras cannot
    be stored in this format (a ``UserWarning`` says so; use :func:`write_npz` to keep them).

    Returns
    -------
    Path
        The written folder.
    """
    gt = checked_for_layout(
        seq, path, owner="write_frame_folder", layout="the frame-folder format",
        keeps_mask=True, overwrite=overwrite,
    )  # fmt: skip
    masks = None if gt is None else gt.mask
    stamps = seq.timestamps
    writer = FrameFolderWriter(
        path,
        seq.intrinsics,
        depth_unit_mm=depth_unit_mm,
        fps=seq.fps,
        intensity_bits=intensity_bits,
        overwrite=overwrite,
        sensor=seq.sensor,
        warn_coarse_unit=warn_coarse_unit,
    )
    with writer:
        for t in range(seq.num_frames):
            writer.write(
                seq.depth[t],
                seq.intensity[t],
                mask=None if masks is None else masks[t],
                timestamp=None if stamps is None else float(stamps[t]),
            )
            if progress is not None:
                progress(t + 1, seq.num_frames)
    return Path(path)
