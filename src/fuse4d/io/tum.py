"""The TUM RGB-D benchmark layout: ``rgb.txt``/``depth.txt`` lists associated by timestamp.

Layout::

    SEQ/rgb.txt       "# comment" lines, then "timestamp filename" (seconds, path relative to SEQ)
    SEQ/depth.txt     same, for the 16-bit depth PNGs (value / 5000 = metres, 0 = invalid)
    SEQ/camera.json   optional: fx, fy, cx, cy (px) [, depth_unit_mm]

Association follows TUM's ``associate.py``: every (depth, rgb) pair whose timestamps differ by
at most ``max_difference`` seconds is a candidate, candidates are taken greedily in order of
increasing difference, each image used at most once; frames are ordered by depth timestamp (in
whatever order ``depth.txt`` lists them; a timestamp listed twice is refused) and carry the
depth timestamp. A UTF-8 byte-order mark at the start of a list is ignored. TUM folders carry
no intrinsics: give ``intrinsics=`` (a preset such as ``"freiburg1"``, see
:data:`~fuse4d.io.CAMERA_PRESETS`) or a ``camera.json`` holding them; fuse4d never guesses
them. With ``intrinsics=``, a ``camera.json`` may hold just ``depth_unit_mm``.
"""

from __future__ import annotations

import math
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .._params import check_number
from ..camera import Intrinsics
from ..errors import InputFileError, ParameterError
from ..sequence import Sequence
from ._base import (
    CAMERA_PRESETS,
    Frame,
    FrameReader,
    FrameSelection,
    IntrinsicsLike,
    ProgressCallback,
    _check_size,
    depth_unit,
    inside,
    read_camera_json,
    resolve_intrinsics,
)
from ._images import (
    check_frame_shape,
    decode_image,
    read_checked_intensity,
    read_depth_png,
    read_intensity_image,
)

__all__ = ["TUM_DEPTH_UNIT_MM", "TumReader", "associate_timestamps", "read_tum"]

#: TUM depth PNGs store 5000 units per metre: one unit = 0.2 mm.
TUM_DEPTH_UNIT_MM = 0.2


def _read_list(path: Path) -> tuple[np.ndarray, list[str], list[int]]:
    """Timestamps (s), file names and line numbers (1-based) of a TUM list, in file order."""
    if not path.is_file():
        raise InputFileError(path, "file not found (a TUM folder needs rgb.txt and depth.txt)")
    stamps: list[float] = []
    names: list[str] = []
    lines: list[int] = []
    try:
        text_lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read file ({exc})") from None
    for lineno, line in enumerate(text_lines, 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.replace(",", " ").split()
        try:
            if len(parts) < 2 or not math.isfinite(float(parts[0])):
                raise ValueError
            stamps.append(float(parts[0]))
        except ValueError:
            raise InputFileError(
                path, f"line {lineno}: expected 'timestamp filename', got {text!r}"
            ) from None
        names.append(parts[1])
        lines.append(lineno)
    if not names:
        raise InputFileError(path, "lists no image")
    return np.asarray(stamps, dtype=np.float64), names, lines


def _in_time_order(
    path: Path, stamps: np.ndarray, names: list[str], lines: list[int], notes: list[str]
) -> tuple[np.ndarray, list[str]]:
    """The list sorted by timestamp (a note says when it was not); a repeated timestamp is an
    InputFileError naming both lines."""
    order = np.argsort(stamps, kind="stable")
    ts = stamps[order]
    same = np.nonzero(np.diff(ts) == 0)[0]
    if same.size:
        a, b = sorted((lines[order[same[0]]], lines[order[same[0] + 1]]))
        raise InputFileError(
            path, f"lines {a} and {b}: timestamp {ts[same[0]]:.6f} is listed twice"
        )
    if np.any(np.diff(order) < 0):
        notes.append(f"{path.name} is not in time order: frames ordered by timestamp")
    return ts, [names[i] for i in order]


def associate_timestamps(
    first: np.ndarray, second: np.ndarray, *, max_difference: float = 0.02
) -> list[tuple[int, int]]:
    """Match two timestamp lists (seconds) like TUM's ``associate.py``.

    Returns
    -------
    list of (i, j)
        Index pairs with ``|first[i] - second[j]| <= max_difference``, each index used once,
        chosen greedily by increasing difference, sorted by ``i``.

    Raises
    ------
    ParameterError
        If ``max_difference`` is not a finite number >= 0 s (a negative one matched nothing).
    """
    check_number("associate_timestamps", "max_difference", max_difference, ge=0, finite=True)
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64)
    order = np.argsort(b, kind="stable")
    bs = b[order]
    lo = np.searchsorted(bs, a - max_difference, side="left")
    hi = np.searchsorted(bs, a + max_difference, side="right")
    candidates = [
        (abs(a[i] - bs[j]), i, int(order[j]))
        for i in range(a.size)
        for j in range(lo[i], hi[i])
        if abs(a[i] - bs[j]) <= max_difference
    ]
    candidates.sort()
    used_a: set[int] = set()
    used_b: set[int] = set()
    pairs = []
    for _, i, j in candidates:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    pairs.sort()
    return pairs


class TumReader(FrameReader):
    """Frame reader for a TUM RGB-D folder (see the module docstring).

    Parameters
    ----------
    path : str or PathLike
        The sequence folder (holding ``rgb.txt`` and ``depth.txt``).
    depth_unit_mm : float, optional
        Default: ``camera.json``'s ``depth_unit_mm`` if present, else 0.2 (factor 5000).
    intrinsics : IntrinsicsLike, optional
        Required unless the folder has a ``camera.json``.
    max_difference : float, optional
        Largest accepted depth/rgb time difference in seconds (default 0.02).

    Raises
    ------
    InputFileError
        Missing lists, unparsable lines, no associated pair, missing intrinsics.
    """

    format = "tum"

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        depth_unit_mm: float | None = None,
        intrinsics: IntrinsicsLike | None = None,
        max_difference: float = 0.02,
    ) -> None:
        self.path = root = Path(path)
        if not root.is_dir():
            raise InputFileError(root, "folder not found")
        if not max_difference >= 0:
            raise ParameterError(f"max_difference must be >= 0 seconds, got {max_difference!r}")
        notes: list[str] = []
        depth_ts, depth_names = _in_time_order(
            root / "depth.txt", *_read_list(root / "depth.txt"), notes
        )
        rgb_ts, rgb_names, _ = _read_list(root / "rgb.txt")
        pairs = associate_timestamps(depth_ts, rgb_ts, max_difference=max_difference)
        if not pairs:
            raise InputFileError(
                root,
                f"no depth/rgb pair within {max_difference:g} s "
                "(check rgb.txt and depth.txt, or raise max_difference)",
            )
        self._files = [
            (
                inside(root, depth_names[i], root / "depth.txt"),
                inside(root, rgb_names[j], root / "rgb.txt"),
            )
            for i, j in pairs
        ]
        self.timestamps = np.asarray([depth_ts[i] for i, _ in pairs], dtype=np.float64)
        if len(pairs) < len(depth_names):
            notes.append(
                f"{len(depth_names) - len(pairs)} of {len(depth_names)} depth frames had no rgb "
                f"frame within {max_difference:g} s and were skipped"
            )
        cam_path = root / "camera.json"
        cam = None
        if cam_path.exists():
            cam = read_camera_json(cam_path, require_unit=False, require_camera=intrinsics is None)
        unit = depth_unit_mm
        if unit is None:
            unit = cam["depth_unit_mm"] if cam and cam["depth_unit_mm"] else TUM_DEPTH_UNIT_MM
        self.depth_unit_mm = depth_unit(unit, None if depth_unit_mm is not None else cam_path)
        image = decode_image(self._files[0][0], frame=0)
        h, w = image.shape[:2]
        if cam is not None:  # its size and rate, also beside given intrinsics
            _check_size(cam, w, h, cam_path)
            if cam.get("fps"):
                self.fps = cam["fps"]
        if intrinsics is not None:
            self.intrinsics = resolve_intrinsics(intrinsics, width=w, height=h)
        elif cam is not None:
            self.intrinsics = Intrinsics(
                cam["fx"], cam["fy"], cam["cx"], cam["cy"], width=w, height=h
            )
        else:
            hint = next((f" (the folder name suggests '{n}')" for n in CAMERA_PRESETS
                         if n in root.resolve().name.lower()), "")  # fmt: skip
            raise InputFileError(
                root,
                "no intrinsics: TUM folders do not store them; add camera.json with fx, fy, "
                f"cx, cy or pass intrinsics= (one of {', '.join(CAMERA_PRESETS)}){hint}",
            )
        self.notes = tuple(notes)

    def __len__(self) -> int:
        return len(self._files)

    def read_frame(self, index: int) -> Frame:
        """Frame ``index``: depth (H, W) mm float32 (NaN invalid), intensity (H, W) [0, 1]."""
        k = self._index(index)
        depth_path, rgb_path = self._files[k]
        depth = read_depth_png(depth_path, frame=k, unit_mm=self.depth_unit_mm or 1.0)
        check_frame_shape(depth, self.shape, depth_path, k, against="frame 0")
        intensity = read_intensity_image(rgb_path, frame=k)
        check_frame_shape(intensity, self.shape, rgb_path, k, against="the depth frame")
        ts = float(self.timestamps[k]) if self.timestamps is not None else None
        return Frame(k, depth, intensity, ts, None)

    def read_intensity(self, index: int) -> NDArray[np.float32]:
        """Frame ``index``'s intensity alone (the depth PNG is not decoded)."""
        k = self._index(index)
        return read_checked_intensity(self._files[k][1], k, self.shape)


def read_tum(
    path: str | PathLike[str],
    *,
    intrinsics: IntrinsicsLike | None = None,
    frames: FrameSelection = None,
    depth_unit_mm: float | None = None,
    max_difference: float = 0.02,
    progress: ProgressCallback | None = None,
) -> Sequence:
    """Read a TUM RGB-D folder into a :class:`~fuse4d.Sequence` (depth mm, NaN = invalid).

    See :class:`TumReader` for the parameters; ``timestamps`` are the depth timestamps (s).
    """
    reader = TumReader(
        path, depth_unit_mm=depth_unit_mm, intrinsics=intrinsics, max_difference=max_difference
    )
    return reader.read_sequence(frames, progress=progress)
