"""The ``.npz`` sequence format (NumPy zip archive), fuse4d's lossless native format.

Keys
----
``depth``        (T, H, W) float32, mm, NaN = invalid                          (required)
``intensity``    (T, H, W) float32 in [0, 1]                                    (required)
``intrinsics``   (4,) float64 ``[fx, fy, cx, cy]`` in px                         (required)
``timestamps``   (T,) float64 seconds; ``fps`` scalar; ``name`` string          (optional)
``sensor``       string: the kind of depth camera (``Sequence.sensor``)           (optional)
``depth_gt``     (T, H, W) float32 mm; ``mask_gt`` (T, H, W) bool;
``flow_gt``      (T-1, H, W, 2) float32 px ([..., 0] = du, [..., 1] = dv)       (optional GT)
``gt_<key>``     ``GroundTruth.extra[key]``; ``gt_scene`` (``ball``/``plane``/``sheet``)
                 with one ``gt_<field>`` per field of ``GroundTruth.scene`` (e.g.
                 ``gt_center_row``), converted to/from the typed geometry here     (optional GT)
anything else    caller's arrays (e.g. fusion's ``support``): kept by :func:`write_npz`'s
                 ``extra=`` and returned by :func:`read_npz_extra`; ignored by :func:`read_npz`.
                 ``fuse4d run`` adds ``support``, ``filled``, ``source``, ``confidence`` and
                 ``fuse4d_params`` (JSON text: the run's fusion and flow parameters,
                 :data:`fuse4d.run.NPZ_PARAMS_KEY`).

Archives are written uncompressed by default: float depth noise hardly compresses, and
uncompressed members can be memory-mapped, so :class:`NpzReader` streams frames without
loading the whole array.
"""

from __future__ import annotations

import math
import mmap
import struct
import tokenize
import zipfile
import zlib
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..camera import Intrinsics
from ..errors import InputFileError
from ..sequence import GroundTruth, Sequence, check_sequence, split_scene_extra
from ._atomic import atomic_file
from ._base import (
    Frame,
    FrameReader,
    FrameSelection,
    ProgressCallback,
    check_sensor_kind,
    file_sequence,
    resolve_frames,
    stored_unit_intensity,
)

__all__ = ["RESERVED_NPZ_KEYS", "NpzReader", "read_npz", "read_npz_extra", "write_npz"]

#: Keys with a meaning in the fuse4d npz format (``gt_*`` keys are reserved as well).
RESERVED_NPZ_KEYS = frozenset(
    {"depth", "intensity", "intrinsics", "timestamps", "fps", "name", "sensor", "depth_gt", "mask_gt",
     "flow_gt"}
)  # fmt: skip
_REQUIRED = ("depth", "intensity", "intrinsics")
#: Bytes released before each memory-mapped frame besides its own pages: more than the pages
#: a fault maps around the faulting one (Linux fault-around: 64 KiB by default).
_FAULT_AROUND_MARGIN = 1 << 20


class NpzReader(FrameReader):
    """Frame reader for a fuse4d ``.npz`` file.

    Uncompressed archive members are memory-mapped (constant memory per frame); compressed
    ones are decompressed once, on first access.

    Raises
    ------
    InputFileError
        If the file is missing, not a valid npz, lacks a required key, or holds arrays of
        inconsistent shapes.
    """

    format = "npz"

    def __init__(self, path: str | PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            what = "is a folder, not an .npz file" if self.path.is_dir() else "file not found"
            raise InputFileError(self.path, what)
        try:
            self._zip = zipfile.ZipFile(self.path)
            names = {Path(n).stem: n for n in self._zip.namelist() if n.endswith(".npy")}
        except (zipfile.BadZipFile, OSError, EOFError) as exc:
            raise InputFileError(
                self.path, f"not a valid .npz file (truncated or corrupt: {exc})"
            ) from None
        self._members = names
        self._cache: dict[str, np.ndarray] = {}
        try:
            self._open(names)
        except BaseException:
            self.close()
            raise

    def _open(self, names: dict[str, str]) -> None:
        for key in _REQUIRED:
            if key not in names:
                raise InputFileError(
                    self.path,
                    f"missing key '{key}' (a fuse4d .npz needs depth, intensity, intrinsics)",
                )
        depth = self._array("depth")
        intensity = self._array("intensity")
        for key, arr in (("depth", depth), ("intensity", intensity)):
            if arr.dtype.kind not in "fiub" or arr.dtype.names is not None:
                raise InputFileError(
                    self.path, f"key '{key}' must hold real numbers, got dtype {arr.dtype}"
                )
        if depth.ndim != 3:
            raise InputFileError(
                self.path, f"key 'depth' must have shape (T, H, W), got {depth.shape}"
            )
        if intensity.shape != depth.shape:
            raise InputFileError(
                self.path,
                f"key 'intensity' has shape {intensity.shape} but 'depth' has {depth.shape}",
            )
        if depth.shape[0] < 1:
            raise InputFileError(self.path, "key 'depth' holds no frame (T = 0)")
        k = self._array("intrinsics")
        if k.size != 4 or k.dtype.kind not in "fiu":
            raise InputFileError(
                self.path,
                f"key 'intrinsics' must hold [fx, fy, cx, cy], got {k.dtype} of shape {k.shape}",
            )
        try:
            self.intrinsics = Intrinsics.from_array(k, width=depth.shape[2], height=depth.shape[1])
        except (TypeError, ValueError) as exc:
            raise InputFileError(self.path, f"key 'intrinsics': {exc}") from None
        self._t = int(depth.shape[0])
        if "timestamps" in names:
            self.timestamps = self._timestamps()
        if "fps" in names:
            fps = self._number("fps")
            if not (math.isfinite(fps) and fps > 0):
                raise InputFileError(self.path, f"key 'fps' must be a number > 0, got {fps!r}")
            self.fps = fps
        if "name" in names:
            name = self._array("name")
            if name.ndim != 0 or name.dtype.kind not in "US":
                raise InputFileError(self.path, "key 'name' must hold one string")
            self._name = str(name)
        else:
            self._name = self.path.name
        if "sensor" in names:
            sensor = self._array("sensor")
            if sensor.ndim != 0 or sensor.dtype.kind not in "US":
                raise InputFileError(self.path, "key 'sensor' must hold one string")
            self.sensor = check_sensor_kind(str(sensor), self.path, "key 'sensor'")
        gt = [k[:-3] for k in ("depth_gt", "mask_gt", "flow_gt") if k in names]
        gt += [k for k in names if k.startswith("gt_")]
        self.ground_truth_keys = tuple(gt)
        for key, shape in (
            ("depth_gt", depth.shape),
            ("mask_gt", depth.shape),
            ("flow_gt", (self._t - 1, *depth.shape[1:], 2)),
        ):
            if key in names and self._array(key).shape != shape:
                raise InputFileError(
                    self.path, f"key '{key}' has shape {self._array(key).shape}, expected {shape}"
                )

    def _number(self, key: str) -> float:
        value = self._array(key)
        if value.size != 1 or value.dtype.kind not in "fiu":
            raise InputFileError(
                self.path, f"key '{key}' must hold one number, got {value.dtype} {value.shape}"
            )
        return float(value.reshape(()))

    def _timestamps(self) -> np.ndarray:
        raw = self._array("timestamps")
        if raw.dtype.kind not in "fiu":
            raise InputFileError(self.path, f"key 'timestamps' must hold numbers, got {raw.dtype}")
        ts = np.asarray(raw, dtype=np.float64).ravel()
        if ts.shape != (self._t,):
            raise InputFileError(
                self.path, f"key 'timestamps' has {ts.size} values for {self._t} frames"
            )
        if not np.isfinite(ts).all():
            raise InputFileError(self.path, "key 'timestamps' holds NaN or inf")
        if self._t > 1 and not np.all(np.diff(ts) > 0):
            raise InputFileError(self.path, "key 'timestamps' must be strictly increasing")
        return ts

    # -------------------------------------------------------------- member access
    def _array(self, key: str) -> np.ndarray:
        if key not in self._cache:
            try:
                self._cache[key] = self._load_member(self._members[key])
            except KeyError:
                raise InputFileError(self.path, f"missing key '{key}'") from None
            except MEMBER_ERRORS as exc:
                raise InputFileError(
                    self.path, f"key '{key}': cannot read array (truncated or corrupt: {exc})"
                ) from None
        return self._cache[key]

    def _load_member(self, member: str) -> np.ndarray:
        info = self._zip.getinfo(member)
        if info.compress_type == zipfile.ZIP_STORED:
            mapped = self._memmap(info)
            if mapped is not None:
                return mapped
        return read_member(self._zip, member)

    def _memmap(self, info: zipfile.ZipInfo) -> np.ndarray | None:
        with self.path.open("rb") as f:
            f.seek(info.header_offset)
            header = f.read(30)
            if len(header) < 30 or header[:4] != b"PK\x03\x04":
                raise ValueError("bad local file header")
            name_len, extra_len = struct.unpack("<HH", header[26:30])
            start = info.header_offset + 30 + name_len + extra_len
            f.seek(start)
            header = _read_npy_header(f)
            if header is None:
                return None
            shape, fortran, dtype = header
            offset = f.tell()
        if dtype.hasobject:
            raise ValueError("object arrays are not allowed")
        nbytes = math.prod(shape) * dtype.itemsize
        if offset + nbytes > self.path.stat().st_size or offset - start + nbytes > info.file_size:
            raise ValueError(f"member {info.filename} is truncated")
        if nbytes == 0:
            return np.zeros(shape, dtype=dtype)
        order = "F" if fortran else "C"
        return np.memmap(self.path, dtype=dtype, mode="r", offset=offset, shape=shape, order=order)

    def _release(self, key: str, k: int) -> None:
        """Drop frame ``k`` of a memory-mapped member from this process's resident set.

        The pages stay in the OS page cache; without this, every frame read through the map
        stays counted in the reader's RSS, which then grows with the recording's length
        (a 1200-frame 600 x 600 recording maps 3.5 GB) although each frame is copied out once.
        The range starts ``_FAULT_AROUND_MARGIN`` bytes before the frame: a page fault maps
        the pages around it too (Linux "fault-around", 64 KiB by default), and those lying
        before the frame would otherwise stay mapped after their own frame was released
        (≈ 55 KiB per frame kept at 300 x 300: +55 MB of RSS over 1200 frames).
        """
        arr = self._cache.get(key)
        handle = getattr(arr, "_mmap", None)
        if handle is None or not arr.flags.c_contiguous or arr.ndim < 1:
            return
        frame_bytes = arr[0].nbytes
        start = arr.offset % mmap.ALLOCATIONGRANULARITY + k * frame_bytes
        page = max(0, start - start % mmap.PAGESIZE - _FAULT_AROUND_MARGIN)
        try:
            handle.madvise(mmap.MADV_DONTNEED, page, start + frame_bytes - page)
        except (AttributeError, OSError, ValueError):  # not Linux, or a closed map
            return

    def close(self) -> None:
        """Close the archive (memory-mapped arrays already handed out stay valid)."""
        zf = getattr(self, "_zip", None)
        if zf is not None:
            zf.close()

    # -------------------------------------------------------------- FrameReader
    def __len__(self) -> int:
        return self._t

    def read_frame(self, index: int) -> Frame:
        """Frame ``index``: depth (H, W) mm float32 (NaN invalid), intensity (H, W) [0, 1]."""
        k = self._index(index)
        depth = np.array(self._array("depth")[k], dtype=np.float32)
        depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
        self._release("depth", k)
        intensity = self._checked_intensity(k)
        mask = None
        if "mask_gt" in self._members:
            raw_mask = self._array("mask_gt")
            if raw_mask.dtype.kind not in "fiub" or raw_mask.dtype.names is not None:
                raise InputFileError(
                    self.path, f"key 'mask_gt' must hold booleans, got dtype {raw_mask.dtype}"
                )
            mask = np.array(raw_mask[k], dtype=bool)
            self._release("mask_gt", k)
        ts = None if self.timestamps is None else float(self.timestamps[k])
        return Frame(k, depth, intensity, ts, mask)

    def read_intensity(self, index: int) -> NDArray[np.float32]:
        """Frame ``index``'s intensity, (H, W) float32 in [0, 1], without reading its depth."""
        return self._checked_intensity(self._index(index))

    def read_source(self, start: int, stop: int) -> NDArray[np.uint8] | None:
        """The ``source`` key's frames ``start:stop`` (see :meth:`FrameReader.read_source`)."""
        if "source" not in self._members:
            return None
        return np.array(self._array("source")[start:stop], dtype=np.uint8)

    def _checked_intensity(self, k: int) -> NDArray[np.float32]:
        """Frame ``k``'s intensity as float32, released from the map, checked to lie in [0, 1]
        (uint8 and uint16 divided by 255 and 65535; other integer types refused, as
        :func:`fuse4d.sequence.normalize_intensity` refuses them)."""
        intensity = stored_unit_intensity(
            self._array("intensity")[k], self.path, k, what="key 'intensity'"
        )
        self._release("intensity", k)
        return intensity

    def read_sequence(
        self, frames: FrameSelection = None, *, progress: ProgressCallback | None = None
    ) -> Sequence:
        """Read the selected frames (with ground truth) into a :class:`~fuse4d.Sequence`."""
        sel = resolve_frames(frames, self._t)
        a, b = sel.start, sel.stop
        depth = np.array(self._array("depth")[a:b], dtype=np.float32)
        intensity = np.array(self._array("intensity")[a:b])
        if progress is not None:
            progress(len(sel), len(sel))
        return file_sequence(
            self.path,
            depth,
            intensity,
            self.intrinsics,
            timestamps=None if self.timestamps is None else self.timestamps[a:b],
            fps=self.fps,
            ground_truth=self._ground_truth(sel),
            name=self._name,
            sensor=self.sensor,
        )

    def _ground_truth(self, selection: range) -> GroundTruth | None:
        if not self.ground_truth_keys:
            return None
        a, b = selection.start, selection.stop

        def get(key: str, stop: int = b) -> np.ndarray | None:
            return np.array(self._array(key)[a:stop]) if key in self._members else None

        values: dict[str, Any] = {}
        for key in self._members:
            if key.startswith("gt_"):
                value = np.array(self._array(key))
                values[key[3:]] = value.item() if value.ndim == 0 else value
        try:  # the typed scene geometry (gt_scene + its fields), sliced by its own rules
            scene, rest = split_scene_extra(values)
        except KeyError as exc:
            raise InputFileError(
                self.path,
                f"ground truth of scene {values.get('scene')!r} lacks gt_ keys {exc.args[0]}",
            ) from None
        extra = {
            k: (
                v[a:b] if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == self._t else v
            )
            for k, v in rest.items()
        }
        return GroundTruth(
            depth=get("depth_gt"),
            mask=get("mask_gt"),
            flow=get("flow_gt", max(a, b - 1)),
            extra=extra,
            scene=None if scene is None else scene.select(slice(a, b)),
        )

    def read_extra(self, frames: FrameSelection = None) -> dict[str, np.ndarray]:
        """The non-reserved arrays: a leading axis of length T (per frame) sliced to
        ``frames``, one of length T - 1 (per pair of consecutive frames, as ``flow_gt``) to the
        pairs between them; other arrays whole."""
        sel = resolve_frames(frames, self._t)
        out = {}
        for key in self._members:
            if key in RESERVED_NPZ_KEYS or key.startswith("gt_"):
                continue
            value = np.array(self._array(key))
            if value.ndim >= 1 and value.shape[0] == self._t:
                value = value[sel.start : sel.stop]
            elif value.ndim >= 1 and self._t > 1 and value.shape[0] == self._t - 1:
                value = value[sel.start : sel.stop - 1]
            out[key] = value
        return out


def read_member(zf: zipfile.ZipFile, member: str) -> np.ndarray:
    """Read one ``.npy`` member of an open archive without pickles, checking the declared
    size against the member's before numpy allocates it (a corrupt header must not make it
    allocate terabytes).

    Raises
    ------
    ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, struct.error
        If the member is corrupt (callers turn these into :class:`~fuse4d.InputFileError`).
    """
    info = zf.getinfo(member)
    with zf.open(member) as f:
        header = _read_npy_header(f)
        if header is not None:
            shape, _, dtype = header
            if dtype.hasobject:
                raise ValueError("object arrays are not allowed")
            if f.tell() + math.prod(shape) * dtype.itemsize > info.file_size:
                raise ValueError(f"member {info.filename} is truncated")
    with zf.open(member) as f:
        return np.lib.format.read_array(f, allow_pickle=False)


#: What a corrupt archive member raises while being read.
#: (numpy's header parser can raise tokenize.TokenError/SyntaxError on a corrupt header)
MEMBER_ERRORS = (zipfile.BadZipFile, OSError, EOFError, ValueError, struct.error, zlib.error,
                 tokenize.TokenError, SyntaxError)  # fmt: skip


def _read_npy_header(f: Any) -> Any:
    """(shape, fortran_order, dtype) of the ``.npy`` stream at ``f``; None for versions other
    than 1.0/2.0 (numpy then reads the member itself)."""
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(f)
    if version == (2, 0):
        return np.lib.format.read_array_header_2_0(f)
    return None


def read_npz(
    path: str | PathLike[str],
    *,
    frames: FrameSelection = None,
    progress: ProgressCallback | None = None,
) -> Sequence:
    """Read a fuse4d ``.npz`` sequence (see the module docstring for the keys).

    Parameters
    ----------
    path : str or PathLike
        The ``.npz`` file.
    frames : slice, range, (start, stop), "A:B" or None, optional
        Contiguous frame range to read (ground truth is sliced to match).
    progress : callable, optional
        ``callback(done, total)``.

    Returns
    -------
    Sequence
        Depth in mm (NaN invalid), intensity in [0, 1], with ``ground_truth`` when the file
        has ``depth_gt``/``mask_gt``/``flow_gt``/``gt_*`` keys.

    Raises
    ------
    InputFileError
        If the file is missing, corrupt, lacks a required key, or its arrays disagree.
    """
    with NpzReader(path) as reader:
        return reader.read_sequence(frames, progress=progress)


def read_npz_extra(
    path: str | PathLike[str], *, frames: FrameSelection = None
) -> dict[str, np.ndarray]:
    """Arrays of a fuse4d ``.npz`` other than the sequence and ground-truth keys.

    Use it to carry extra outputs (e.g. fusion's ``support``) through a read/write round
    trip: ``write_npz(seq, out, extra=read_npz_extra(inp))``.
    """
    with NpzReader(path) as reader:
        return reader.read_extra(frames)


def write_npz(
    seq: Sequence,
    path: str | PathLike[str],
    *,
    extra: dict[str, Any] | None = None,
    overwrite: bool = False,
    compress: bool = False,
) -> Path:
    """Write a sequence (with its ground truth) as a fuse4d ``.npz``, atomically.

    Parameters
    ----------
    seq : Sequence
        The sequence; ``ground_truth`` is stored as ``depth_gt``, ``mask_gt``, ``flow_gt``
        and ``gt_<key>`` for each ``ground_truth.extra`` entry and each field of
        ``ground_truth.scene`` (plus ``gt_scene``).
    path : str or PathLike
        Output file (``.npz`` is not appended automatically).
    extra : dict of str to array, optional
        Additional arrays to store under their own names (must not be a reserved key).
    overwrite : bool, optional
        Replace an existing file. Default False.
    compress : bool, optional
        Deflate the members (smaller, slower, no memory-mapped streaming). Default False.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    OutputExistsError
        If ``path`` exists and ``overwrite`` is False.
    ValueError
        If an ``extra`` key is reserved or a value cannot be stored without pickling.
    """
    check_sequence(seq, "write_npz")
    arrays: dict[str, Any] = {
        "depth": seq.depth,
        "intensity": seq.intensity,
        "intrinsics": seq.intrinsics.as_array(),
    }
    if seq.timestamps is not None:
        arrays["timestamps"] = seq.timestamps
    if seq.fps is not None:
        arrays["fps"] = np.float64(seq.fps)
    if seq.name:
        arrays["name"] = np.str_(seq.name)
    if seq.sensor:
        arrays["sensor"] = np.str_(seq.sensor)
    gt = seq.ground_truth
    if gt is not None:
        for key, value in (("depth_gt", gt.depth), ("mask_gt", gt.mask), ("flow_gt", gt.flow)):
            if value is not None:
                arrays[key] = np.asarray(value)
        scene = {} if gt.scene is None else gt.scene.to_extra()
        clash = sorted(set(scene) & set(gt.extra))
        if clash:
            raise ValueError(f"ground_truth.extra keys {clash} clash with the scene geometry")
        for key, value in {**scene, **gt.extra}.items():
            arrays[f"gt_{key}"] = _storable(value, f"ground_truth.extra[{key!r}]")
    for key, value in (extra or {}).items():
        if key in RESERVED_NPZ_KEYS or key.startswith("gt_") or not key.isidentifier():
            raise ValueError(
                f"extra key {key!r} is reserved or not a valid name; reserved: "
                f"{', '.join(sorted(RESERVED_NPZ_KEYS))} and gt_*"
            )
        arrays[key] = _storable(value, f"extra[{key!r}]")
    save = np.savez_compressed if compress else np.savez
    with atomic_file(path, overwrite=overwrite) as tmp, tmp.open("wb") as f:
        save(f, allow_pickle=False, **arrays)
    return Path(path)


def _storable(value: Any, name: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.hasobject:
        raise ValueError(f"{name} cannot be stored in .npz (not a numeric/string array)")
    return arr
