"""The streaming reader interface shared by every sequence layout, and argument helpers.

A :class:`FrameReader` opens a recording, reads its metadata (intrinsics, frame count,
timestamps) eagerly and its frames lazily, one at a time, so that memory does not grow with
the length of the recording.
"""

from __future__ import annotations

import json
import math
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import Intrinsics
from ..errors import InputFileError, ParameterError, ParameterTypeError
from ..sequence import _SENSOR_KINDS, GroundTruth, Sequence

__all__ = [
    "CAMERA_PRESETS",
    "Frame",
    "FrameReader",
    "FrameSelection",
    "IntrinsicsLike",
    "ProgressCallback",
    "SequentialReader",
    "check_frame_shapes",
    "inside",
    "read_camera_json",
    "resolve_frames",
    "resolve_intrinsics",
]

#: Intrinsics ``(fx, fy, cx, cy)`` in px of well-known 640x480 RGB-D cameras, selectable by
#: name (``intrinsics="freiburg1"``). The TUM values are the ones published with the TUM RGB-D
#: benchmark; ``"kinect-v1"`` is the OpenNI/ROS default used when no calibration exists.
CAMERA_PRESETS: dict[str, tuple[float, float, float, float]] = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
    "kinect-v1": (525.0, 525.0, 319.5, 239.5),
}
#: The image size (W, H) of every preset; a 4:3 image of another size gets the preset scaled.
PRESET_SIZE = (640, 480)

#: ``Intrinsics``, ``[fx, fy, cx, cy]``, a preset name from :data:`CAMERA_PRESETS`, the path of
#: a ``camera.json``, or a string ``"fx,fy,cx,cy"``.
IntrinsicsLike = Intrinsics | ArrayLike | str | PathLike[str]

#: ``None`` (all), a ``slice``/``range`` with step 1, ``(start, stop)`` or ``"start:stop"``.
FrameSelection = slice | range | tuple[int | None, int | None] | str | None

#: ``callback(done, total)`` called after each frame read or written.
ProgressCallback = Callable[[int, int], None]


@dataclass(frozen=True)
class Frame:
    """One frame of a recording.

    Attributes
    ----------
    index : int
        0-based frame index in the recording.
    depth : (H, W) ndarray of float32
        Depth in mm, NaN = invalid.
    intensity : (H, W) ndarray of float32
        Gray intensity in [0, 1].
    timestamp : float or None
        Capture time in seconds, if the layout stores one.
    mask : (H, W) ndarray of bool or None
        Object mask (e.g. the person in a ``cv2-xml`` recording), if the layout stores one.
    """

    index: int
    depth: NDArray[np.float32]
    intensity: NDArray[np.float32]
    timestamp: float | None = None
    mask: NDArray[np.bool_] | None = None


def file_sequence(path: Path, *args: Any, **kwargs: Any) -> Sequence:
    r"""``Sequence(*args, **kwargs)`` read from the file ``path``: its warnings ("only 0.0 % of
    depth pixels are valid") name the file, and its errors are :class:`InputFileError`\ s
    naming it."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            seq = Sequence(*args, **kwargs)
        except (TypeError, ValueError) as exc:
            raise InputFileError(path, str(exc)) from None
    for w in caught:
        warnings.warn(f"{path}: {w.message}", w.category, stacklevel=3)
    return seq


class FrameReader(ABC):
    """Lazy, random-access reader of one recording (abstract base).

    Subclasses set :attr:`format`, :attr:`path`, :attr:`intrinsics`, :attr:`timestamps`,
    :attr:`fps`, :attr:`depth_unit_mm` and implement :meth:`__len__` and :meth:`read_frame`.
    ``len(reader)``, ``reader[k]`` and ``for frame in reader`` work on every layout.
    """

    #: Layout name (``"npz"``, ``"folder"``, ``"tum"``, ``"cv2-xml"``, ``"frames-json"``).
    format: ClassVar[str] = ""
    path: Path
    intrinsics: Intrinsics
    timestamps: NDArray[np.float64] | None = None
    fps: float | None = None
    #: Millimetres per stored depth unit (None for float formats such as npz).
    depth_unit_mm: float | None = None
    #: Names of the ground-truth arrays available (``"depth"``, ``"mask"``, ``"flow"``, ...).
    ground_truth_keys: tuple[str, ...] = ()
    #: Human-readable notes about how the input was interpreted (shown by ``fuse4d info``).
    notes: tuple[str, ...] = ()
    #: The kind of depth camera, where the file says so (``"tof"`` for an Azure Kinect
    #: recording; :attr:`fuse4d.Sequence.sensor`), else None.
    sensor: str | None = None
    #: Index in the file of the reader's frame 0 (nonzero for a part of a recording opened
    #: with ``open_frames(..., frames="A:B")``).
    first_frame: int = 0

    @abstractmethod
    def __len__(self) -> int:
        """Number of frames."""

    @abstractmethod
    def read_frame(self, index: int) -> Frame:
        """Read frame ``index`` (0-based; negative counts from the end)."""

    def read_intensity(self, index: int) -> NDArray[np.float32]:
        """The intensity of frame ``index`` alone ((H, W) float32 in [0, 1]), equal to
        ``read_frame(index).intensity``; layouts that store it apart override this to skip
        reading and checking the depth (the flow stage of the dask engine reads only this)."""
        return self.read_frame(index).intensity

    def read_source(self, start: int, stop: int) -> NDArray[np.uint8] | None:
        """The per-pixel source codes (:attr:`fuse4d.FusedFrame.source`) of frames
        ``start:stop`` ((C, H, W) uint8) where the recording is a fused output that stores
        them (a frame folder's ``source/``, a zarr array or npz key ``source``: what
        ``fuse4d run`` writes); None for layouts or recordings without them."""
        return None

    @property
    def num_frames(self) -> int:
        """Number of frames T."""
        return len(self)

    @property
    def shape(self) -> tuple[int, int]:
        """Frame shape ``(H, W)``."""
        return self.intrinsics.shape

    def __getitem__(self, index: int) -> Frame:
        return self.read_frame(index)

    def __iter__(self) -> Iterator[Frame]:
        for k in range(len(self)):
            yield self.read_frame(k)

    def iter_frames(self, frames: FrameSelection = None) -> Iterator[Frame]:
        """Yield the selected frames one at a time."""
        for k in resolve_frames(frames, len(self)):
            yield self.read_frame(k)

    def close(self) -> None:  # noqa: B027 - optional hook, no-op by default
        """Release open files (no-op for most layouts)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _index(self, index: int) -> int:
        n = len(self)
        k = int(index)
        if k < 0:
            k += n
        if not 0 <= k < n:
            raise IndexError(f"{self.path}: frame {index} out of range (the recording has {n})")
        return k

    def _ground_truth(self, selection: range) -> GroundTruth | None:
        """Ground truth for the selected frames (layouts with GT override this)."""
        return None

    def read_sequence(
        self, frames: FrameSelection = None, *, progress: ProgressCallback | None = None
    ) -> Sequence:
        """Read the selected frames into an in-memory :class:`~fuse4d.Sequence`.

        Arrays are preallocated and filled frame by frame (no list of frames is kept).
        """
        sel = resolve_frames(frames, len(self))
        h, w = self.shape
        depth = np.empty((len(sel), h, w), dtype=np.float32)
        intensity = np.empty((len(sel), h, w), dtype=np.float32)
        masks: NDArray[np.bool_] | None = None
        for j, k in enumerate(sel):
            frame = self.read_frame(k)
            depth[j] = frame.depth
            intensity[j] = frame.intensity
            if frame.mask is not None:
                if masks is None:
                    masks = np.zeros((len(sel), h, w), dtype=bool)
                masks[j] = frame.mask
            if progress is not None:
                progress(j + 1, len(sel))
        gt = self._ground_truth(sel)
        if masks is not None:
            gt = GroundTruth(mask=masks) if gt is None else _with_mask(gt, masks)
        ts = None if self.timestamps is None else self.timestamps[sel.start : sel.stop]
        return file_sequence(
            self.path,
            depth,
            intensity,
            self.intrinsics,
            timestamps=ts,
            fps=self.fps,
            ground_truth=gt,
            name=self.path.name,
            sensor=self.sensor,
        )


class SequentialReader(FrameReader):
    """A reader of a container that decodes forward (a video or a message log; abstract base).

    Seeking such a container is expensive, so reading frame ``k + 1`` right after frame ``k``
    resumes one decoding pass (:meth:`_stream`) instead of seeking again; any other index
    restarts the pass at that frame. Subclasses implement ``_stream(k0, stop)``, a generator
    of frames ``k0 .. stop - 1`` in one pass, set :attr:`_missing_frame` (why a frame can be
    absent, for the error) and call :meth:`_close_stream` from their ``close``.
    """

    #: What the error says when the pass ends before frame ``k`` (e.g. "DEPTH frame missing").
    _missing_frame: ClassVar[str] = "frame missing"

    @abstractmethod
    def _stream(self, k0: int, stop: int | None = None) -> Iterator[Frame]:
        """Decode frames ``k0, k0 + 1, ..., stop - 1`` (``stop`` None: to the end) in one pass."""

    def read_frame(self, index: int) -> Frame:
        k = self._index(index)
        gen: Iterator[Frame] | None = getattr(self, "_pass", None)
        if gen is None or k != getattr(self, "_pass_next", -1):
            self._close_stream()
            gen = self._pass = self._stream(k)
        self._pass_next = k + 1
        try:
            return next(gen)
        except StopIteration:
            self._pass = None
            raise InputFileError(self.path, self._missing_frame_text(), frame=k) from None
        except BaseException:
            self._pass = None  # a generator that raised is finished: the next read starts anew
            raise

    def iter_frames(self, frames: FrameSelection = None) -> Iterator[Frame]:
        sel = resolve_frames(frames, len(self))
        yield from self._stream(sel.start, sel.stop)

    def __iter__(self) -> Iterator[Frame]:
        return self.iter_frames(None)

    def _missing_frame_text(self) -> str:
        """The error text for a frame the pass did not reach (override to add context)."""
        return self._missing_frame

    def _close_stream(self) -> None:
        """Stop the open decoding pass of :meth:`read_frame`, if any."""
        gen, self._pass = getattr(self, "_pass", None), None
        if gen is not None:
            gen.close()


def _with_mask(gt: GroundTruth, mask: NDArray[np.bool_]) -> GroundTruth:
    return replace(gt, mask=mask)  # keeps every other field (scene, extra)


def resolve_frames(frames: FrameSelection, total: int) -> range:
    """Turn a frame selection into a ``range`` of valid indices (step 1).

    Parameters
    ----------
    frames : slice, range, (start, stop), "start:stop" or None
        Python slice semantics (negative indices count from the end; ``None`` = all).
    total : int
        Number of frames in the recording.

    Raises
    ------
    ParameterTypeError
        If a bound is not a whole number or None (``(1.5, 3)``).
    ValueError
        If the selection is malformed, has a step other than 1, or selects no frame.
    """
    if frames is None:
        sel = slice(None)
    elif isinstance(frames, slice):
        sel = frames
    elif isinstance(frames, range):
        sel = slice(frames.start, frames.stop, frames.step)
    elif isinstance(frames, str):
        sel = _parse_frame_string(frames)
    elif isinstance(frames, tuple) and len(frames) == 2:
        sel = slice(*frames)
    else:
        raise ParameterError(
            f"frames must be None, a slice, a range, (start, stop) or 'start:stop', got {frames!r}"
        )
    for bound in (sel.start, sel.stop, sel.step):
        if bound is not None and (isinstance(bound, bool) or not hasattr(bound, "__index__")):
            raise ParameterTypeError(
                f"frames: start, stop and step must be whole numbers or None, got {bound!r} "
                f"(in {frames!r})"
            )
    if sel.step not in (None, 1):
        raise ParameterError(f"frames must be a contiguous range (step 1), got step {sel.step}")
    idx = range(total)[sel]
    if len(idx) < 1:
        raise ParameterError(f"frames {_show(sel)} selects no frame of a {total}-frame sequence")
    return idx


def _show(sel: slice) -> str:
    a = "" if sel.start is None else sel.start
    b = "" if sel.stop is None else sel.stop
    return f"{a}:{b}"


def _parse_frame_string(text: str) -> slice:
    parts = text.strip().split(":")
    try:
        if len(parts) == 1:
            k = int(parts[0])
            return slice(k, k + 1 if k != -1 else None)
        if len(parts) == 2:
            return slice(*(int(p) if p.strip() else None for p in parts))
    except ValueError:
        pass
    raise ParameterError(f"frames must look like 'A:B', 'A:', ':B' or 'K', got {text!r}")


def flag_images(source: ArrayLike, confidence: ArrayLike) -> tuple[tuple[str, NDArray], ...]:
    """A fused frame's per-pixel flags (each (H, W), as :func:`check_flags` checks) as the
    images of a frame folder: ``("source", uint8 codes)`` (:attr:`fuse4d.FusedFrame.source`)
    and ``("confidence", uint8 round(255 c))``."""
    from .._kernels.io import _confidence_to_uint8_kernel  # on first use (start-up time)

    c = np.ascontiguousarray(confidence, np.float32)
    c8 = np.empty(c.shape, np.uint8)
    _confidence_to_uint8_kernel(c, c8)  # one pass (issue 13: numpy took 1.6 ms a frame)
    return (("source", np.asarray(source, np.uint8)), ("confidence", c8))


def check_increasing_times(
    times: NDArray[np.float64], path: Path, what: str, unit: str = "s"
) -> None:
    """InputFileError naming the first frame whose time (``times``, s) is not after the
    previous frame's: frames are paired and indexed by their times, so a repeated or
    backwards one leaves no order to trust (a broken clock, a merged recording). ``what``:
    which times, e.g. "DEPTH track: pts"."""
    bad = np.nonzero(~(np.diff(times) > 0))[0]
    if bad.size:
        k = int(bad[0]) + 1
        raise InputFileError(
            path,
            f"{what} {times[k]:.6f} {unit} is not after frame {k - 1}'s ({times[k - 1]:.6f} "
            f"{unit}); the frames' times must increase",
            frame=k,
        )


def float_or_nan(value: Any) -> float:
    """``float(value)``, or NaN where ``value`` is no number (for checks that then refuse
    anything not finite with one message)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def checked_timestamp(
    previous: list[float | None],
    timestamp: Any,
    index: int,
    path: Path,
    *,
    resolution: float = 0.0,
) -> float | None:
    """Frame ``index``'s ``timestamp`` (s) for the writer of ``path`` that has stored
    ``previous``: a finite number after the last one (at the file's ``resolution``, s: a
    frame folder writes microseconds), given for every frame or for none; ParameterError
    naming the file and frame otherwise (the file written would be refused by its own
    reader)."""
    where = f"{path} (frame {index})"
    if previous and (timestamp is None) != (previous[0] is None):
        raise ParameterError(f"{where}: give a timestamp for every frame or for none")
    if timestamp is None:
        return None
    t = float_or_nan(timestamp)
    if not math.isfinite(t):
        raise ParameterError(f"{where}: timestamp {timestamp!r} is not a finite number")
    last = previous[-1] if previous else None
    if last is not None and not (
        round(t / resolution) > round(last / resolution) if resolution else t > last
    ):
        raise ParameterError(
            f"{where}: timestamp {t:.6f} s is not after frame {index - 1}'s ({last:.6f} s)"
            + (f" at the file's {resolution:g} s resolution" if resolution else "")
        )
    return t


def stored_unit_intensity(
    raw: np.ndarray, path: Path, frame: int, *, what: str, nan_as_zero: bool = False
) -> NDArray[np.float32]:
    """A stored intensity frame as float32 in [0, 1], the rule of every array layout (.npz,
    .zarr): uint8 and uint16 divided by 255 and 65535, bool as 0 and 1, other integer types
    refused (their range says nothing of the white level, as
    :func:`fuse4d.sequence.normalize_intensity` refuses them), floats checked
    (:func:`check_stored_intensity`); ``nan_as_zero``: NaN is unknown intensity, read as 0.

    Raises
    ------
    InputFileError
        An integer type other than uint8/uint16, or float values outside [0, 1].
    """
    if raw.dtype.kind in "ui":
        if raw.dtype.kind == "i" or raw.dtype.itemsize > 2:
            raise InputFileError(
                path,
                f"{what} has integer dtype {raw.dtype}, which does not say its bit depth; "
                "store uint8 (0-255), uint16 (0-65535) or float in [0, 1]",
                frame=frame,
            )
        return raw.astype(np.float32) / np.float32(np.iinfo(raw.dtype).max)
    out = np.array(raw, dtype=np.float32)
    if nan_as_zero:
        out[np.isnan(out)] = 0.0
    check_stored_intensity(out, path, frame, what=what)
    return out


def check_stored_intensity(
    intensity: NDArray[np.float32], path: Path, frame: int, *, what: str
) -> None:
    """Refuse a stored float intensity frame outside [0, 1], naming what was found.

    Parameters
    ----------
    intensity : ndarray (H, W) float32
        The frame as read (NaN already replaced where the layout defines a meaning for it).
    path : Path
        The file, for the message.
    frame : int
        The frame index, for the message.
    what : str
        How the layout names the array (``"key 'intensity'"``, ``"'intensity'"``).

    Raises
    ------
    InputFileError
        NaN, inf, or values outside [0, 1].
    """
    finite = np.isfinite(intensity)
    if finite.all() and intensity.min() >= 0 and intensity.max() <= 1:
        return
    if np.isnan(intensity).any():
        found = "NaN found"
    elif not finite.all():
        found = "inf found"
    else:
        low, high = intensity < 0, intensity > 1
        parts = [
            f"{int(n.sum())} {side} {worst!r}"
            for n, side, worst in (
                (low, "below 0, down to", float(intensity.min())),
                (high, "above 1, up to", float(intensity.max())),
            )
            if n.any()
        ]
        found = f"{' and '.join(parts)} found"
    raise InputFileError(
        path,
        f"{what} must hold finite values in [0, 1] ({found}; rescale with "
        "fuse4d.sequence.normalize_intensity)",
        frame=frame,
    )


def check_flags(index: int, shape: tuple[int, int], source: Any, confidence: Any) -> None:
    """Both per-pixel fusion flags of frame ``index`` or neither, each of ``shape``."""
    if (source is None) != (confidence is None):
        raise ParameterError(f"frame {index}: give source and confidence together")
    for name, a in (("source", source), ("confidence", confidence)):
        if a is not None and np.shape(a) != shape:
            raise ParameterError(f"frame {index}: {name} has shape {np.shape(a)}, expected {shape}")


def check_frame_shapes(index: int, shape: tuple[int, int], **arrays: ArrayLike | None) -> None:
    """Raise ``ValueError`` unless every given array (None = absent) has ``shape`` ``(H, W)``.

    Used by the writers before they append frame ``index``; the message names the array, the
    frame and both shapes.
    """
    for name, arr in arrays.items():
        if arr is not None and np.shape(arr) != shape:
            raise ParameterError(
                f"{name} of frame {index} has shape {np.shape(arr)}, expected {shape} "
                "(the intrinsics' height x width)"
            )


def inside(root: Path, name: Any, listed_in: Path, entry: int | None = None) -> Path:
    """``root / name`` for a file name read from an index file, refusing names that leave
    ``root`` (absolute paths, ``..``): an index file must not make fuse4d read elsewhere.

    Raises
    ------
    InputFileError
        If ``name`` is not a non-empty relative path inside ``root``.
    """
    where = "" if entry is None else f"entry {entry}: "
    if not isinstance(name, str) or not name.strip() or "\x00" in name:
        raise InputFileError(
            listed_in, f"{where}file name must be a non-empty string, got {name!r}"
        )
    rel = Path(name)
    if rel.is_absolute() or ".." in rel.parts:
        raise InputFileError(
            listed_in,
            f"{where}file name {name!r} leaves the recording folder (absolute or '..'); "
            "index files may only name files inside it",
        )
    return root / rel


#: Depth units accepted (mm per stored unit): 1 nm to 10 m; others come from corrupt files.
MIN_DEPTH_UNIT_MM = 1e-6
MAX_DEPTH_UNIT_MM = 1e4


def depth_unit(value: Any, source: Path | None = None) -> float:
    """Validate a depth unit (mm per stored unit) from ``source`` (None: a parameter).

    Raises
    ------
    InputFileError
        If it came from ``source`` and is not in (0, :data:`MAX_DEPTH_UNIT_MM`].
    ParameterError
        The same for a value given by the caller.
    """
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and MIN_DEPTH_UNIT_MM <= value <= MAX_DEPTH_UNIT_MM
    if not ok:
        problem = (
            f"depth_unit_mm must be in [{MIN_DEPTH_UNIT_MM:g}, {MAX_DEPTH_UNIT_MM:g}] mm, "
            f"got {value!r}"
        )
        if source is not None:
            raise InputFileError(source, problem)
        raise ParameterError(problem)
    return float(value)


def _number(value: Any, key: str, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputFileError(path, f"key '{key}' must be a number, got {value!r}")
    if not math.isfinite(value):
        raise InputFileError(path, f"key '{key}' must be finite, got {value!r}")
    return float(value)


#: The camera kinds a recording may state (:attr:`FrameReader.sensor`; one home with
#: :attr:`Sequence.sensor`'s check).
SENSOR_KINDS = _SENSOR_KINDS


def check_sensor_kind(value: object, path: Path, where: str) -> str | None:
    """The camera kind ``value`` stored in ``where`` of file ``path`` (None: absent)."""
    if value is None or value == "":
        return None
    if value not in SENSOR_KINDS:
        raise InputFileError(
            path, f"{where} must be one of {', '.join(SENSOR_KINDS)}, got {value!r}"
        )
    return str(value)


def read_camera_json(
    path: str | PathLike[str], *, require_unit: bool = True, require_camera: bool = True
) -> dict[str, float | None]:
    """Read a ``camera.json``: ``fx, fy, cx, cy`` (px), ``depth_unit_mm``, optional ``fps``.

    Optional ``width``/``height`` (px) are returned too (and checked by the readers), and the
    camera kind ``sensor`` (one of :data:`SENSOR_KINDS`).

    Parameters
    ----------
    path : str or PathLike
        The ``camera.json``.
    require_unit : bool, optional
        Whether ``depth_unit_mm`` must be present (False where the caller was given the unit).
    require_camera : bool, optional
        Whether ``fx, fy, cx, cy`` must be present (False where the caller was given the
        intrinsics).

    Returns
    -------
    dict
        Keys ``fx, fy, cx, cy, depth_unit_mm, fps, width, height, sensor`` (absent optional
        values are None; ``depth_unit_mm`` is None when absent and ``require_unit`` is False,
        ``fx, fy, cx, cy`` likewise with ``require_camera``).

    Raises
    ------
    InputFileError
        If the file is missing, not valid JSON, or a required key is missing or not a number.
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputFileError(p, "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(p, f"cannot read file ({exc})") from None
    except json.JSONDecodeError as exc:
        raise InputFileError(p, f"not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise InputFileError(p, "must hold a JSON object with keys fx, fy, cx, cy, depth_unit_mm")
    required = (["fx", "fy", "cx", "cy"] if require_camera else []) + (
        ["depth_unit_mm"] if require_unit else []
    )
    for key in required:
        if data.get(key) is None:
            raise InputFileError(p, f"missing key '{key}'")
    out: dict[str, float | None] = {}
    for key in ("fx", "fy", "cx", "cy", "depth_unit_mm", "fps", "width", "height"):
        out[key] = _number(data[key], key, p) if data.get(key) is not None else None
    for key in ("fx", "fy", "depth_unit_mm", "fps", "width", "height"):
        value = out[key]
        if value is not None and value <= 0:
            raise InputFileError(p, f"key '{key}' must be > 0, got {value:g}")
    out["sensor"] = check_sensor_kind(data.get("sensor"), p, "key 'sensor'")  # type: ignore[assignment]
    return out


def resolve_intrinsics(
    spec: IntrinsicsLike, *, width: int, height: int, source: str = "intrinsics"
) -> Intrinsics:
    """Build :class:`~fuse4d.Intrinsics` for an image of ``width`` x ``height`` px.

    Parameters
    ----------
    spec : Intrinsics, [fx, fy, cx, cy], preset name, "fx,fy,cx,cy" or path of a camera.json
        See :data:`CAMERA_PRESETS` for the names.
    width, height : int
        Image size in px (from the depth images).
    source : str, optional
        Name used in error messages.

    Raises
    ------
    ValueError
        If ``spec`` cannot be interpreted or an :class:`Intrinsics` has another image size.
    """
    if isinstance(spec, Intrinsics):
        if spec.shape != (height, width):
            raise ParameterError(
                f"{source} are for a {spec.width}x{spec.height} image but the frames are "
                f"{width}x{height} (WxH)"
            )
        return spec
    if isinstance(spec, str) and spec.strip().lower() in CAMERA_PRESETS:
        full = Intrinsics(*CAMERA_PRESETS[spec.strip().lower()], *PRESET_SIZE)
        factor = width / PRESET_SIZE[0]
        if width * PRESET_SIZE[1] != height * PRESET_SIZE[0]:  # not 4:3: cropped, or another camera
            raise ParameterError(
                f"{source} preset {spec.strip()!r} is for a {PRESET_SIZE[0]}x{PRESET_SIZE[1]} "
                f"image (or one scaled from it) but the frames are {width}x{height} (WxH); give "
                "'fx,fy,cx,cy' or a camera.json"
            )
        # the camera's image scaled (a 320x240 stream): its cx, cy used to lie outside it
        return full if factor == 1 else full.scaled(factor)
    if isinstance(spec, str) and "," in spec and not Path(spec).exists():
        try:
            values = [float(v) for v in spec.split(",")]
        except ValueError:
            raise ParameterError(
                f"{source} string must be 'fx,fy,cx,cy' numbers, got {spec!r}"
            ) from None
        return _intrinsics_from_values(values, width, height, source)
    if isinstance(spec, str | PathLike):
        p = Path(spec)
        if p.suffix.lower() != ".json" and not p.exists():
            names = ", ".join(CAMERA_PRESETS)
            raise ParameterError(
                f"{source} {str(spec)!r} is neither a preset ({names}), 'fx,fy,cx,cy', "
                "nor an existing camera.json"
            )
        cam = read_camera_json(p, require_unit=False)
        _check_size(cam, width, height, p)
        return Intrinsics(cam["fx"], cam["fy"], cam["cx"], cam["cy"], width=width, height=height)
    return _intrinsics_from_values(spec, width, height, source)


def _intrinsics_from_values(values: Any, width: int, height: int, source: str) -> Intrinsics:
    try:
        return Intrinsics.from_array(values, width=width, height=height)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{source}: {exc}") from None


def _check_size(cam: dict[str, float | None], width: int, height: int, path: Path) -> None:
    w, h = cam.get("width"), cam.get("height")
    if (w is not None and int(w) != width) or (h is not None and int(h) != height):
        raise InputFileError(
            path,
            f"camera size {w and int(w)}x{h and int(h)} does not match the "
            f"{width}x{height} frames (WxH)",
        )
