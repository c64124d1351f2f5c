"""Chunked access to the report's inputs: files of any layout, or arrays already in memory."""

from __future__ import annotations

import json
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import Intrinsics
from ..errors import InputFileError, ParameterError, ShapeError
from ..fusion import STAGES, FusionResult
from ..io.resume import run_parameters, run_seconds, run_steady_ms
from ..sequence import Sequence

__all__ = ["FusedChunk", "FusedSource", "RawSource", "open_fused", "open_raw"]

PathOrSequence = str | PathLike[str] | Sequence


@contextmanager
def _quiet_chunks():
    """Chunks are re-read pieces of an input already accepted: repeat no warning per chunk."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="only .* of depth pixels are valid")
        yield


class RawSource:
    """The raw recording, read in chunks of frames (with ground truth where stored)."""

    def __init__(self, data: PathOrSequence, reader_options: dict[str, Any] | None = None) -> None:
        self._seq: Sequence | None = None
        self._reader: Any = None
        #: the frames of the file that are read where only a part is (``frames`` option)
        self.part: range | None = None
        if isinstance(data, Sequence):
            if reader_options:
                raise ParameterError(
                    "reader options (frames, topics, camera) apply to a recording on disk, "
                    "not to an in-memory Sequence: slice the Sequence instead"
                )
            self._seq = data
            self.intrinsics: Intrinsics = data.intrinsics
            self.num_frames = data.num_frames
            self.fps = data.fps
            self.name = data.name or "in-memory sequence"
            self.has_ground_truth = (
                data.ground_truth is not None and data.ground_truth.depth is not None
            )
        else:
            from ..io import open_frames

            self._reader = open_frames(data, **(reader_options or {}))
            if "frames" in (reader_options or {}):  # also read from a ground-truth recording
                first = self._reader.first_frame
                self.part = range(first, first + len(self._reader))
            self.intrinsics = self._reader.intrinsics
            self.num_frames = len(self._reader)
            self.fps = self._reader.fps
            self.name = str(data)
            self.has_ground_truth = "depth" in self._reader.ground_truth_keys

    @property
    def shape(self) -> tuple[int, int]:
        """Frame shape (H, W)."""
        return self.intrinsics.shape

    def chunk(self, start: int, stop: int) -> Sequence:
        """Frames ``start:stop`` as a :class:`~fuse4d.Sequence` (ground truth included)."""
        with _quiet_chunks():
            if self._seq is not None:
                return self._seq.frames(start, stop)
            return self._reader.read_sequence((start, stop))

    def close(self) -> None:
        """Close the file reader (if any)."""
        if self._reader is not None:
            self._reader.close()


@dataclass
class FusedChunk:
    """Fused frames ``start:stop``.

    Attributes
    ----------
    depth : (C, H, W) ndarray of float32
        Fused depth in mm, NaN = invalid.
    support : (C, H, W) ndarray of uint8 or None
        Frames fused per pixel (temporal support), when the result stores it.
    filled : (C, H, W) ndarray of bool or None
        Pixels filled by hole filling (Eq. 6), when stored.
    source : (C, H, W) ndarray of uint8 or None
        Where each value comes from (:attr:`fuse4d.FusedFrame.source` codes), when stored.
    """

    depth: NDArray[np.float32]
    support: NDArray[np.uint8] | None
    filled: NDArray[np.bool_] | None
    source: NDArray[np.uint8] | None = None


class FusedSource:
    """The fused result, in chunks: a file (``.npz`` or any readable layout) or arrays."""

    def __init__(
        self,
        data: str | PathLike[str] | Sequence | FusionResult | ArrayLike,
        *,
        support: ArrayLike | None = None,
        filled: ArrayLike | None = None,
    ) -> None:
        self._reader: Any = None
        self._depth: NDArray[np.float32] | None = None
        self._support = None if support is None else np.asarray(support)
        self._filled = None if filled is None else np.asarray(filled, dtype=bool)
        self._source: NDArray[np.uint8] | None = None
        self.params: dict[str, Any] | None = None
        #: mm per stored depth step of a fused frame folder (None: float depth)
        self.depth_unit_mm: float | None = None
        self.seconds: float | None = None
        #: wall ms per frame once running, of a `fuse4d run` output folder (its manifest)
        self.steady_ms: float | None = None
        self.name = "in-memory result"
        if isinstance(data, FusionResult):
            self._depth = data.depth
            self._support = data.support if self._support is None else self._support
            self._filled = data.filled if self._filled is None else self._filled
            self._source = data.source
            self.params = {**data.params.to_dict(), "flow_method": data.flow_method}
            # the pipeline stages' seconds (not flow_worker: the overlapped flow, beside them)
            stages = [data.timings[k] for k in STAGES if k in data.timings]
            self.seconds = float(sum(stages)) if stages else None
        elif isinstance(data, Sequence):
            self._depth = data.depth
            self.name = data.name or self.name
        elif isinstance(data, str | PathLike) and (store := _dask_output(Path(data))) is not None:
            # `fuse4d run --engine dask` output: fused depth and flags, no intensity; the
            # arrays are read chunk by chunk (zarr slices), like the other layouts
            self.name = str(data)
            self._depth = store["depth"]
            self._support = store.get("support", None)
            self._filled = store.get("filled", None)
            self._source = store.get("source", None)
            meta = dict(store.attrs).get("fuse4d") or {}
            if isinstance(meta.get("params"), dict):
                flow = meta.get("flow") or {}
                self.params = {**meta["params"], "flow_method": flow.get("method", "")}
        elif isinstance(data, str | PathLike):
            from ..io import open_frames

            self._reader = open_frames(data)
            self.name = str(data)
            self.depth_unit_mm = self._reader.depth_unit_mm
            self._keys: set[str] = set()
            if Path(data).is_dir():  # a `fuse4d run` output folder records its parameters
                self.params = run_parameters(data)
                self.seconds = run_seconds(data)
                self.steady_ms = run_steady_ms(data)
            members = getattr(self._reader, "_members", None)
            if isinstance(members, dict):  # NpzReader: support/filled are memory-mapped members
                self._keys = {k for k in ("support", "filled") if k in members}
                self.params = _npz_parameters(self._reader)
        else:
            depth = np.asarray(data, dtype=np.float32)
            if depth.ndim != 3:
                raise ShapeError("fused", ("T", "H", "W"), depth.shape, "fused depth in mm")
            self._depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(np.nan))
        if self._reader is not None:
            self.num_frames = len(self._reader)
            self.shape = self._reader.intrinsics.shape
        else:
            assert self._depth is not None
            self.num_frames = int(self._depth.shape[0])
            self.shape = (int(self._depth.shape[1]), int(self._depth.shape[2]))
        for name, arr in (("support", self._support), ("filled", self._filled)):
            if arr is not None and arr.shape != (self.num_frames, *self.shape):
                raise ShapeError(name, (self.num_frames, *self.shape), arr.shape, "one per frame")

    @property
    def has_support(self) -> bool:
        """Whether support and filled maps are available."""
        if self._reader is not None:
            return "support" in self._keys
        return self._support is not None

    def _member(self, key: str, start: int, stop: int) -> np.ndarray | None:
        if key not in self._keys:
            return None
        return np.array(self._reader._array(key)[start:stop])  # memory-mapped npz member

    def first_intensity(self) -> NDArray[np.float32] | None:
        """Frame 0's intensity where the result stores one (``fuse4d run`` copies its
        input's), else None."""
        if self._reader is None:
            return None
        with _quiet_chunks():
            return np.asarray(self._reader.read_frame(0).intensity, dtype=np.float32)

    def chunk(self, start: int, stop: int) -> FusedChunk:
        """Fused frames ``start:stop``."""
        if self._reader is not None:
            with _quiet_chunks():
                seq = self._reader.read_sequence((start, stop))
            support = self._member("support", start, stop)
            filled = self._member("filled", start, stop)
            return FusedChunk(
                seq.depth,
                None if support is None else support.astype(np.uint8),
                None if filled is None else filled.astype(bool),
                self._reader.read_source(start, stop),  # what `fuse4d run` stores, any layout
            )
        assert self._depth is not None
        s = None if self._support is None else self._support[start:stop].astype(np.uint8)
        f = None if self._filled is None else self._filled[start:stop]
        o = None if self._source is None else self._source[start:stop]
        return FusedChunk(np.asarray(self._depth[start:stop], dtype=np.float32), s, f, o)

    def close(self) -> None:
        """Close the file reader (if any)."""
        if self._reader is not None:
            self._reader.close()


def _npz_parameters(reader: Any) -> dict[str, Any] | None:
    """The fusion parameters (and ``flow_method``) that ``fuse4d run`` stores in an ``.npz``
    output (:data:`fuse4d.run.NPZ_PARAMS_KEY`, the record of a folder output's manifest), in
    the form :func:`~fuse4d.io.resume.run_parameters` gives a folder's; None where the file
    holds no readable record (another program's result, or an older fuse4d's)."""
    from ..run import NPZ_PARAMS_KEY

    if NPZ_PARAMS_KEY not in reader._members:
        return None
    try:
        record = json.loads(str(np.asarray(reader._array(NPZ_PARAMS_KEY)).item()))
    except (InputFileError, ValueError, TypeError):
        return None
    fusion = record.get("fusion") if isinstance(record, dict) else None
    if not isinstance(fusion, dict):
        return None
    flow = record.get("flow")
    return {**fusion, "flow_method": flow.get("method", "") if isinstance(flow, dict) else ""}


def recorded_reader_options(fused: str | PathLike[str]) -> dict[str, Any]:
    """How the run that wrote ``fused`` read its input: a ``fuse4d run`` folder's manifest
    (streams, camera, frame range), or the frame range an ``--engine dask`` store records
    (its other options are stored as text); ``{}`` for anything else."""
    from ..io.resume import run_reader_options

    path = Path(fused)
    if not path.is_dir():
        return {}
    store = _dask_output(path)
    if store is None:
        return run_reader_options(path)
    meta = dict(store.attrs).get("fuse4d") or {}
    recorded = meta.get("reader_options") if isinstance(meta, dict) else None
    frames = recorded.get("frames") if isinstance(recorded, dict) else None
    return {"frames": str(frames)} if frames else {}


def _dask_output(path: Path) -> Any:
    """The zarr group of a ``fuse4d run --engine dask`` output (fused ``depth`` and the
    per-pixel flags, no ``intensity``), else None."""
    if not (path / "zarr.json").is_file():
        return None
    try:
        import zarr

        group = zarr.open_group(str(path), mode="r")
    except (ImportError, OSError, ValueError, TypeError, LookupError):
        return None
    if "depth" not in group or "intensity" in group:
        return None
    meta = dict(group.attrs).get("fuse4d")
    if isinstance(meta, dict) and meta.get("complete") is False:
        # an interrupted run's OUT.zarr.partial: its unwritten chunks read as all-NaN frames,
        # and the report scored them as fuse4d's result
        from ..errors import InputFileError

        raise InputFileError(
            path,
            "unfinished fuse4d run --engine dask (its missing chunks read as empty frames); "
            "finish it with the same command and --resume",
        )
    return group


def open_raw(data: PathOrSequence, reader_options: dict[str, Any] | None = None) -> RawSource:
    """Open the raw input (see :class:`RawSource`), a recording with the
    :func:`fuse4d.io.open_frames` options ``reader_options``."""
    if not isinstance(data, Sequence | str | PathLike):
        raise TypeError(
            f"input must be a path or a fuse4d.Sequence, got {type(data).__name__}; wrap arrays "
            "as Sequence(depth, intensity, intrinsics)"
        )
    return RawSource(data, reader_options)


def open_fused(
    data: Any, raw: RawSource, *, support: ArrayLike | None, filled: ArrayLike | None
) -> FusedSource:
    """Open the fused result and check it matches the raw input frame for frame."""
    fused = FusedSource(data, support=support, filled=filled)
    if fused.num_frames != raw.num_frames or tuple(fused.shape) != raw.shape:
        name = fused.name
        problem = (
            f"fused result has {fused.num_frames} frames of {fused.shape[0]}x{fused.shape[1]} "
            f"but the input {raw.name} has {raw.num_frames} of {raw.shape[0]}x{raw.shape[1]}; "
            "give the output of fusing exactly this input (for a run of part of it, the same "
            "--frames)"
        )
        fused.close()
        if isinstance(data, str | PathLike):
            raise InputFileError(Path(data), problem)
        raise ParameterError(f"{name}: {problem}")
    mine = fused.first_intensity()
    if mine is not None:
        theirs = np.asarray(raw.chunk(0, 1).intensity[0], dtype=np.float32)
        differ = float(np.mean(np.abs(mine - theirs)))
        # a result of another recording (or of other frames) was scored against this one:
        # the stored copy of the input's intensity equals it up to 8-bit rounding. A warning,
        # not an error: an .mkv or .zarr output does not record how its input was read
        # (--no-undistort, --intensity, topics), so a true result can differ too
        if differ > SAME_INTENSITY_TOLERANCE:
            warnings.warn(
                f"{data}: its intensity (frame 0) is not that of {raw.name}'s first frame "
                f"(mean |difference| {differ:.3f}): a result of another recording or other "
                "frames, or of this input read otherwise (--no-undistort, --intensity, "
                "topics)? The report compares different frames if so",
                stacklevel=2,
            )
    return fused


#: Mean |difference| of frame 0's intensity (in [0, 1]) between a fused result's stored copy
#: and its input, above which they are different frames: 8-bit storage rounds by <= 0.002,
#: the intensity noise of two frames of one scene differs by ~0.01.
SAME_INTENSITY_TOLERANCE = 0.004
