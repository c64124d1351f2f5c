"""Middlebury ``.flo`` optical-flow files.

Format: float32 tag 202021.25 (bytes ``PIEH``), int32 width, int32 height, then
``height * width * 2`` float32 values, row-major, ``(u, v)`` interleaved, little-endian.
Components with magnitude > 1e9 mean "unknown" (Middlebury ``UNKNOWN_FLOW_THRESH``).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputFileError, ParameterError
from ..io._atomic import atomic_file

__all__ = ["FLO_TAG", "FLO_UNKNOWN", "read_flo", "write_flo"]

#: The float32 magic number at the start of every .flo file.
FLO_TAG = 202021.25
#: The value written for unknown flow (anything with magnitude > 1e9 reads as unknown).
FLO_UNKNOWN = 1e10
_UNKNOWN_THRESH = 1e9


def read_flo(path: str | PathLike[str]) -> NDArray[np.float32]:
    """Read a Middlebury ``.flo`` file.

    Returns
    -------
    flow : (H, W, 2) ndarray of float32
        ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row), in px; NaN (both components)
        where the file marks the flow as unknown (|value| > 1e9) or non-finite.

    Raises
    ------
    InputFileError
        Missing file, wrong tag, implausible size, or truncated data.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputFileError(p, "file not found") from None
    except OSError as exc:
        raise InputFileError(p, f"cannot read file ({exc.strerror or exc})") from None
    if len(data) < 12:
        raise InputFileError(p, f"too short for a .flo header ({len(data)} bytes)")
    tag = float(np.frombuffer(data, "<f4", 1, 0)[0])
    if tag != FLO_TAG:
        raise InputFileError(p, f"not a Middlebury .flo file (tag {tag!r}, expected {FLO_TAG})")
    width, height = (int(v) for v in np.frombuffer(data, "<i4", 2, 4))
    if not (0 < width < 100_000 and 0 < height < 100_000):
        raise InputFileError(p, f"implausible flow size {width}x{height}")
    need = width * height * 2 * 4
    if len(data) - 12 < need:
        raise InputFileError(
            p, f"truncated: {width}x{height} flow needs {need} bytes, got {len(data) - 12}"
        )
    flow = np.frombuffer(data, "<f4", width * height * 2, 12).reshape(height, width, 2)
    flow = flow.astype(np.float32)
    unknown = ~np.isfinite(flow).all(axis=2) | (np.abs(flow) > _UNKNOWN_THRESH).any(axis=2)
    flow[unknown] = np.nan
    return flow


def write_flo(flow: ArrayLike, path: str | PathLike[str], *, overwrite: bool = False) -> Path:
    """Write an ``(H, W, 2)`` flow field (px) as a Middlebury ``.flo`` file, atomically.

    NaN/inf components are written as unknown (1e10, both components).

    Raises
    ------
    ValueError
        If ``flow`` is not ``(H, W, 2)``.
    OutputExistsError
        If ``path`` exists and ``overwrite`` is False.
    """
    f = np.asarray(flow, dtype=np.float32)
    if f.ndim != 3 or f.shape[2] != 2 or f.shape[0] < 1 or f.shape[1] < 1:
        raise ParameterError(f"flow must have shape (H, W, 2), got {f.shape}")
    out = f.astype("<f4", copy=True)
    out[~np.isfinite(out).all(axis=2)] = FLO_UNKNOWN
    header = np.array([FLO_TAG], "<f4").tobytes() + np.array(f.shape[1::-1], "<i4").tobytes()
    with atomic_file(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(header + out.tobytes())
    return Path(path)
