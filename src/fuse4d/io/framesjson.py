"""The ``frames-json`` layout: a ``frames.json`` index with per-frame camera, scale and files.

``frames.json`` (as written by the fusion-toolbox project) holds ``{"root": [entry, ...]}``,
each entry::

    {"info": {"kcam": {"matrix": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                       "image_size": [W, H]},
              "depth_scale": 0.001,      # metres per stored unit -> depth_unit_mm = 1000 * it
              "depth_bias": 0.0,         # must be 0
              "timestamp": 33432},       # microseconds
     "depth_image": "frame_00001_depth.png",   # uint16 PNG, 0 = invalid
     "rgb_image": "frame_00001_rgb.png"}

Paths are relative to the json's folder. Entries whose two image files are both absent at the
*end* of the list (a recording copied only in part) are skipped and reported in
:attr:`FramesJsonReader.notes`; a missing file anywhere else is an error. ``rt_cam`` poses and
``depth_max`` are ignored.
"""

from __future__ import annotations

import json
import math
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..camera import Intrinsics
from ..errors import InputFileError
from ._base import Frame, FrameReader, IntrinsicsLike, depth_unit, inside, resolve_intrinsics
from ._images import check_frame_shape, read_checked_intensity, read_depth_png, read_intensity_image

__all__ = ["FramesJsonReader"]


def _get(entry: Any, keys: tuple[str, ...], path: Path, k: int) -> Any:
    value = entry
    for key in keys:
        if not isinstance(value, dict) or key not in value:
            raise InputFileError(path, f"entry {k}: missing key '{'.'.join(keys)}'")
        value = value[key]
    return value


def _real(value: Any, key: str, path: Path, k: int) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputFileError(path, f"entry {k}: {key} must be a finite number, got {value!r}")
    return float(value)


def _matrix(value: Any, path: Path, k: int) -> np.ndarray:
    rows = value if isinstance(value, list) else []
    if len(rows) != 3 or any(not isinstance(r, list) or len(r) != 3 for r in rows):
        raise InputFileError(path, f"entry {k}: kcam.matrix must be 3x3 numbers")
    return np.array([[_real(v, "kcam.matrix", path, k) for v in r] for r in rows], float)


def _image_size(value: Any, path: Path, k: int) -> tuple[int, ...]:
    if value is None or value == []:
        return ()
    if not isinstance(value, list) or len(value) != 2:
        raise InputFileError(path, f"entry {k}: kcam.image_size must be [W, H], got {value!r}")
    w, h = (_real(v, "kcam.image_size", path, k) for v in value)
    return (int(w), int(h))


class FramesJsonReader(FrameReader):
    """Frame reader for the ``frames-json`` layout (see the module docstring).

    Parameters
    ----------
    path : str or PathLike
        The folder holding ``frames.json`` (or the json file itself).
    depth_unit_mm : float, optional
        Overrides ``1000 * depth_scale``.
    intrinsics : IntrinsicsLike, optional
        Overrides ``kcam``.

    Raises
    ------
    InputFileError
        Bad JSON, a missing key, cameras or depth scales that differ between frames, a missing
        file that is not part of a missing tail, non-increasing timestamps.
    """

    format = "frames-json"

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        depth_unit_mm: float | None = None,
        intrinsics: IntrinsicsLike | None = None,
    ) -> None:
        p = Path(path)
        json_path = p / "frames.json" if p.is_dir() else p
        self.path = json_path.parent
        try:
            data = json.loads(json_path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputFileError(json_path, "file not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise InputFileError(json_path, f"cannot read file ({exc})") from None
        except json.JSONDecodeError as exc:
            raise InputFileError(
                json_path, f"not valid JSON ({exc.msg} at line {exc.lineno})"
            ) from None
        entries = data.get("root") if isinstance(data, dict) else None
        if not isinstance(entries, list) or not entries:
            raise InputFileError(json_path, 'expected {"root": [frame entries]} with >= 1 entry')
        present = []
        for k, entry in enumerate(entries):
            d = inside(self.path, _get(entry, ("depth_image",), json_path, k), json_path, k)
            c = inside(self.path, _get(entry, ("rgb_image",), json_path, k), json_path, k)
            present.append((d, c, d.is_file(), c.is_file()))
        n = len(present)
        while n > 0 and not present[n - 1][2] and not present[n - 1][3]:
            n -= 1
        if n == 0:
            raise InputFileError(
                self.path, f"no depth frames found (expected {present[0][0].name}, ...)"
            )
        for k in range(n):
            d, c, d_ok, c_ok = present[k]
            if not d_ok or not c_ok:
                raise InputFileError(d if not d_ok else c, "file not found", frame=k)
        notes = []
        if n < len(entries):
            notes.append(
                f"frames.json lists {len(entries)} frames; the last {len(entries) - n} "
                f"(files absent) were skipped"
            )
        self._files = [(d, c) for d, c, _, _ in present[:n]]
        mats, scales, stamps, sizes = [], [], [], []
        for k in range(n):
            e = entries[k]
            mats.append(_matrix(_get(e, ("info", "kcam", "matrix"), json_path, k), json_path, k))
            scales.append(_real(_get(e, ("info", "depth_scale"), json_path, k), "depth_scale",
                                json_path, k))  # fmt: skip
            stamps.append(
                _real(_get(e, ("info", "timestamp"), json_path, k), "timestamp", json_path, k)
            )
            sizes.append(_image_size(e["info"]["kcam"].get("image_size"), json_path, k))
            bias = e["info"].get("depth_bias")
            bias = 0.0 if bias is None else _real(bias, "depth_bias", json_path, k)
            if bias != 0.0:
                raise InputFileError(json_path, f"entry {k}: depth_bias {bias} is not supported")
            if k and not np.allclose(mats[-1], mats[0], rtol=1e-6, atol=1e-6):
                raise InputFileError(
                    json_path,
                    f"entry {k}: camera differs from frame 0's; fuse4d needs one fixed camera",
                )
            if k and scales[-1] != scales[0]:
                raise InputFileError(json_path, f"entry {k}: depth_scale differs from frame 0's")
        if depth_unit_mm is not None:
            unit = float(depth_unit_mm)
        else:
            if not scales[0] > 0:
                raise InputFileError(json_path, f"depth_scale must be > 0, got {scales[0]}")
            unit = 1000.0 * scales[0]
            notes.append(f"depth_scale {scales[0]:g} m/unit -> {unit:g} mm/unit")
        self.depth_unit_mm = depth_unit(unit, json_path if depth_unit_mm is None else None)
        first = read_depth_png(self._files[0][0], frame=0)
        h, w = first.shape
        if sizes[0] and tuple(int(s) for s in sizes[0]) != (w, h):
            raise InputFileError(
                json_path,
                f"kcam.image_size {list(sizes[0])} does not match the {w}x{h} depth images",
            )
        if intrinsics is not None:
            self.intrinsics = resolve_intrinsics(intrinsics, width=w, height=h)
        else:
            try:
                self.intrinsics = Intrinsics.from_matrix(mats[0], width=w, height=h)
            except ValueError as exc:
                raise InputFileError(json_path, f"kcam.matrix: {exc}") from None
        ts = np.asarray(stamps, dtype=np.float64) * 1e-6
        if n > 1 and not np.all(np.diff(ts) > 0):
            raise InputFileError(json_path, "timestamps must be strictly increasing")
        self.timestamps = ts
        self.notes = tuple(notes)

    def __len__(self) -> int:
        return len(self._files)

    def read_frame(self, index: int) -> Frame:
        """Frame ``index``: depth (H, W) mm float32 (NaN invalid), intensity (H, W) [0, 1]."""
        k = self._index(index)
        depth_path, colour_path = self._files[k]
        depth = read_depth_png(depth_path, frame=k, unit_mm=self.depth_unit_mm or 1.0)
        check_frame_shape(depth, self.shape, depth_path, k, against="frame 0")
        intensity = read_intensity_image(colour_path, frame=k)
        check_frame_shape(intensity, self.shape, colour_path, k, against="the depth frame")
        ts = None if self.timestamps is None else float(self.timestamps[k])
        return Frame(k, depth, intensity, ts, None)

    def read_intensity(self, index: int) -> NDArray[np.float32]:
        """Frame ``index``'s intensity alone (the depth PNG is not decoded)."""
        k = self._index(index)
        return read_checked_intensity(self._files[k][1], k, self.shape)
