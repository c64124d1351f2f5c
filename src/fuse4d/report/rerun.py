"""Optional: log raw and fused depth with the pinhole camera to a Rerun ``.rrd`` recording.

Open it with ``rerun out.rrd`` to scrub the 4D result (the viewer back-projects each depth image
through its pinhole into a point cloud). Needs the ``fuse4d[viz]`` extra (``rerun-sdk``).
"""

from __future__ import annotations

from collections.abc import Callable
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..sequence import Sequence
from ._sources import open_fused, open_raw

__all__ = ["have_rerun", "write_rerun"]


def have_rerun() -> bool:
    """True when ``rerun-sdk`` is importable."""
    try:
        import rerun  # noqa: F401
    except ImportError:
        return False
    return True


def _set_frame(rec: Any, t: int) -> None:
    if hasattr(rec, "set_time"):  # rerun >= 0.23
        rec.set_time("frame", sequence=t)
    else:  # older releases
        rec.set_time_sequence("frame", t)


def write_rerun(
    input: str | PathLike[str] | Sequence,
    fused: Any,
    path: str | PathLike[str],
    *,
    chunk_frames: int = 16,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
    reader_options: dict[str, Any] | None = None,
) -> Path:
    """Write raw and fused depth (and the intensity) of every frame into a Rerun recording.

    Parameters
    ----------
    input, fused
        As for :func:`fuse4d.report.write_report`.
    path : str or PathLike
        Output ``.rrd`` file (written under a temporary name, renamed when complete).
    chunk_frames : int, optional
        Frames held in memory at a time.
    overwrite : bool, optional
        Replace an existing file.
    progress : callable, optional
        ``progress(done, total)`` per frame.

    Returns
    -------
    Path
        The recording.

    Raises
    ------
    ImportError
        When ``rerun-sdk`` is not installed (``pip install 'fuse4d[viz]'``).
    """
    from ..io._atomic import atomic_file

    try:
        import rerun as rr
    except ImportError:
        raise ImportError(
            "writing a Rerun recording needs rerun-sdk: pip install 'fuse4d[viz]'"
        ) from None
    raw = open_raw(input, reader_options)
    try:
        fres = open_fused(fused, raw, support=None, filled=None)
    except BaseException:
        raw.close()
        raise
    out = Path(path)
    try:
        with atomic_file(out, overwrite=overwrite) as tmp:
            rec = rr.RecordingStream("fuse4d")
            rec.save(str(tmp))
            k = raw.intrinsics
            for name in ("raw", "fused"):
                pinhole = rr.Pinhole(
                    focal_length=[k.fx, k.fy],
                    principal_point=[k.cx, k.cy],
                    width=k.width,
                    height=k.height,
                )
                rec.log(f"world/{name}", pinhole, static=True)
            total = raw.num_frames
            for a in range(0, total, chunk_frames):
                b = min(total, a + chunk_frames)
                rseq = raw.chunk(a, b)
                fch = fres.chunk(a, b)
                for j in range(b - a):
                    _set_frame(rec, a + j)
                    for name, depth in (("raw", rseq.depth[j]), ("fused", fch.depth[j])):
                        mm = np.nan_to_num(depth, nan=0.0).astype(np.float32)  # 0 = no depth
                        rec.log(f"world/{name}/depth", rr.DepthImage(mm, meter=1000.0))
                    gray = np.clip(np.rint(255.0 * rseq.intensity[j]), 0, 255).astype(np.uint8)
                    rec.log("world/raw/intensity", rr.Image(gray))
                    if progress is not None:
                        progress(a + j + 1, total)
            rec.flush()  # blocks until everything is written
            rec.disconnect()
    finally:
        raw.close()
        fres.close()
    return out
