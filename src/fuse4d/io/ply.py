"""PLY point-cloud export (binary little-endian) of one back-projected frame."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputFileError, ShapeError
from ..sequence import as_storable_intensity
from ._atomic import atomic_file

__all__ = ["read_ply", "write_ply"]

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


def write_ply(
    points: ArrayLike,
    path: str | PathLike[str],
    *,
    colors: ArrayLike | None = None,
    overwrite: bool = False,
) -> int:
    """Write the valid points of a point map as a binary little-endian PLY file, atomically.

    Parameters
    ----------
    points : (H, W, 3) or (N, 3) ndarray
        X, Y, Z in mm (e.g. :func:`fuse4d.depth_to_points` of one frame); points with any
        non-finite coordinate are skipped.
    path : str or PathLike
        Output ``.ply`` file.
    colors : (H, W) or (N,) ndarray, optional
        Intensity in [0, 1] for each point (uint8/uint16 divided by 255/65535),
        stored as gray ``red = green = blue`` (uchar).
    overwrite : bool, optional
        Replace an existing file. Default False.

    Returns
    -------
    int
        Number of points written.

    Raises
    ------
    ShapeError
        If the shapes do not fit.
    ParameterError
        If float ``colors`` lie far outside [0, 1] (0-255).
    OutputExistsError
        If ``path`` exists and ``overwrite`` is False.
    """
    p = np.asarray(points, dtype=np.float32)
    if p.ndim < 2 or p.shape[-1] != 3:
        raise ShapeError("points", ("H", "W", 3), p.shape, "Or (N, 3): X, Y, Z in mm")
    flat = p.reshape(-1, 3)
    keep = np.isfinite(flat).all(axis=1)
    n = int(keep.sum())
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        c = as_storable_intensity(colors, name="colors")
        if c.shape != p.shape[:-1]:
            raise ShapeError("colors", p.shape[:-1], c.shape, "One intensity per point")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vertices = np.empty(n, dtype=fields)
    for axis, name in enumerate("xyz"):
        vertices[name] = flat[keep, axis]
    if colors is not None:
        gray = np.clip(np.round(np.nan_to_num(c.reshape(-1)[keep]) * 255.0), 0, 255)
        for name in ("red", "green", "blue"):
            vertices[name] = gray.astype(np.uint8)
    header = ["ply", "format binary_little_endian 1.0", "comment fuse4d point cloud, units mm",
              f"element vertex {n}", "property float x", "property float y", "property float z"]  # fmt: skip
    if colors is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header.append("end_header")
    with atomic_file(path, overwrite=overwrite) as tmp, tmp.open("wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vertices.tobytes())
    return n


def read_ply(
    path: str | PathLike[str],
) -> tuple[NDArray[np.float32], NDArray[np.uint8] | None]:
    """Read the vertices of a binary little-endian PLY file (minimal; for tests and checks).

    Returns
    -------
    points : (N, 3) ndarray of float32
        X, Y, Z.
    colors : (N, 3) ndarray of uint8 or None
        ``red, green, blue`` if the file has them.

    Raises
    ------
    InputFileError
        If the file is missing, not binary little-endian PLY, or truncated.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputFileError(p, "file not found") from None
    except OSError as exc:
        raise InputFileError(p, f"cannot read file ({exc.strerror or exc})") from None
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        raise InputFileError(p, "not a PLY file (no 'ply' magic or no end_header)")
    lines = data[:end].decode("ascii", errors="replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise InputFileError(p, "only binary_little_endian PLY is supported")
    count, fields = _parse_header(lines, p)
    dtype = np.dtype(fields)
    body = data[end + len(b"end_header\n") :]
    if len(body) < count * dtype.itemsize:
        raise InputFileError(
            p, f"truncated: {count} vertices need {count * dtype.itemsize} bytes, got {len(body)}"
        )
    vertices = np.frombuffer(body, dtype=dtype, count=count)
    points = np.stack([vertices[a] for a in "xyz"], axis=1).astype(np.float32)
    names = dtype.names or ()
    colors = None
    if all(c in names for c in ("red", "green", "blue")):
        colors = np.stack([vertices[c] for c in ("red", "green", "blue")], axis=1).astype(np.uint8)
    return points, colors


def _parse_header(lines: list[str], p: Path) -> tuple[int, list[tuple[str, str]]]:
    """Vertex count and fields from the header lines (before ``end_header``)."""
    count: int | None = None
    fields: list[tuple[str, str]] = []
    in_vertex = False
    for line in lines:
        parts = line.split()
        if parts[:1] == ["element"]:
            if len(parts) != 3:
                raise InputFileError(p, f"bad header line {line!r} (expected 'element NAME N')")
            in_vertex = parts[1] == "vertex"
            if in_vertex:
                if count is not None:
                    raise InputFileError(p, "more than one vertex element")
                if not parts[2].isdigit():
                    raise InputFileError(p, f"bad vertex count {parts[2]!r}")
                count = int(parts[2])
            elif count is not None:
                break
            else:  # another element before the vertices: its data would come first
                raise InputFileError(p, f"element {parts[1]!r} before the vertices: unsupported")
        elif parts[:1] == ["property"] and in_vertex:
            if len(parts) < 3 or parts[1] == "list" or parts[1] not in _PLY_TYPES:
                raise InputFileError(p, f"unsupported vertex property {line!r}")
            if any(name == parts[2] for name, _ in fields):
                raise InputFileError(p, f"vertex property {parts[2]!r} appears twice")
            fields.append((parts[2], "<" + _PLY_TYPES[parts[1]]))
    if count is None:
        raise InputFileError(p, "no vertex element")
    missing = [a for a in "xyz" if a not in {name for name, _ in fields}]
    if missing:
        raise InputFileError(p, f"vertex properties {', '.join(missing)} missing")
    return count, fields
