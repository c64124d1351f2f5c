"""Lossless 16-bit depth video: FFV1 (``gray16le``) in Matroska through PyAV.

Layout (read back by :class:`~fuse4d.io.mkv.MkvReader`)
------
track ``DEPTH``       FFV1 gray16le, depth in units of ``FUSE4D_DEPTH_UNIT_MM`` mm, 0 = invalid
track ``INTENSITY``   FFV1 gray16le, intensity ``round(65535 i)``
tags                  ``FUSE4D_INTRINSICS`` (``fx,fy,cx,cy`` px), ``FUSE4D_DEPTH_UNIT_MM``,
                      ``FUSE4D_FPS``, ``FUSE4D_T0`` (first timestamp, s)
pts                   milliseconds after ``FUSE4D_T0`` (Matroska's time base is 1 ms)

FFV1 is lossless, so the stored 16-bit values round-trip bit-exactly; depth itself is rounded
to the unit (as for PNG folders; use ``.npz`` or ``.zarr`` for float depth). The file appears
under its name only when complete (written under a temporary name, then renamed).
"""

from __future__ import annotations

import contextlib
import math
import warnings
from contextlib import ExitStack
from fractions import Fraction
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Intrinsics, check_intrinsics
from ..errors import ParameterError
from ..sequence import Sequence, as_storable_intensity
from ._atomic import (
    StagedWriter,
    atomic_file,
    check_output,
    checked_for_layout,
    reports_write_errors,
)
from ._base import check_frame_shapes
from ._extras import require
from ._images import QuantizationReport, depth_to_units, intensity_to_uint

__all__ = ["DepthVideoWriter", "write_depth_video"]

_MS = Fraction(1, 1000)


class DepthVideoWriter(StagedWriter):
    """Write depth + intensity frame by frame to an FFV1 ``.mkv`` (atomic).

    Parameters
    ----------
    path : str or PathLike
        Output ``.mkv``.
    intrinsics : Intrinsics
        Camera; frames must be ``(intrinsics.height, intrinsics.width)``.
    depth_unit_mm : float, optional
        Millimetres per stored unit (default 1.0; range up to 65535 units). Rounding and
        clipping are reported by one ``UserWarning``, as for frame folders.
    fps : float, optional
        Frame rate used for pts when frames have no timestamps (default 30).
    overwrite : bool, optional
        Replace an existing output.
    sensor : str, optional
        The camera kind (``"tof"``, ``"structured-light"``, ``"active-stereo"``), stored so
        that the output is fused as its camera's recording was (A36).
    warn_coarse_unit : bool, optional
        Warn at close when ``depth_unit_mm`` is coarse against the data's pixel noise
        (default True); False where it is the input recording's own unit (``fuse4d run``).
    """

    #: A depth video holds depth and intensity only (no per-pixel fusion flags).
    stores_flags = False

    def __init__(
        self,
        path: str | PathLike[str],
        intrinsics: Intrinsics,
        *,
        depth_unit_mm: float = 1.0,
        fps: float | None = None,
        overwrite: bool = False,
        sensor: str | None = None,
        warn_coarse_unit: bool = True,
    ) -> None:
        check_intrinsics(intrinsics)
        if intrinsics.width == 1 and intrinsics.height > 1:
            # FFmpeg's FFV1 encoder will not open for a one-column gray16 frame
            raise ParameterError(
                f"{path}: frames 1 px wide cannot be stored as FFV1 .mkv (FFmpeg refuses the "
                f"size 1x{intrinsics.height}); write .npz, .zarr or a frame folder"
            )
        if not (math.isfinite(depth_unit_mm) and depth_unit_mm > 0):
            raise ParameterError(f"depth_unit_mm must be > 0, got {depth_unit_mm!r}")
        if fps is not None and not (math.isfinite(fps) and fps > 0):
            raise ParameterError(f"fps must be > 0, got {fps!r}")
        self._av = require("av", what="writing .mkv depth video")
        self.path = check_output(path, overwrite=overwrite)
        self.intrinsics = intrinsics
        self.depth_unit_mm = float(depth_unit_mm)
        self.fps = fps
        self.sensor = sensor
        self.overwrite = overwrite
        self.num_written = 0
        self._report = QuantizationReport(self.depth_unit_mm, warn_coarse_unit=warn_coarse_unit)
        self._stack: ExitStack | None = None
        self._container: Any = None
        self._streams: tuple[Any, Any] | None = None
        self._t0: float | None = None
        self._last_pts = -1
        self._moved: list[tuple[int, float]] = []  # (frame, ms) of the pts moved > 1 ms

    @reports_write_errors
    def open(self) -> None:
        """Create the temporary file and the two FFV1 tracks (called by ``with``)."""
        if self._stack is not None:
            raise RuntimeError("DepthVideoWriter is already open")
        stack = ExitStack()
        tmp = stack.enter_context(atomic_file(self.path, overwrite=self.overwrite))
        self._stack = stack
        self._tmp = Path(tmp)
        self._container = self._av.open(str(tmp), mode="w", format="matroska")
        k = self.intrinsics
        streams = []
        for title in ("DEPTH", "INTENSITY"):
            s = self._container.add_stream("ffv1", rate=Fraction(round(self.fps or 30)))
            s.width, s.height, s.pix_fmt = k.width, k.height, "gray16le"
            s.time_base = _MS
            # the encoder's own time base too: it was 1/round(fps), onto which PyAV rescales
            # each frame's ms pts (29.97 fps timestamps collided, frames went missing)
            s.codec_context.time_base = _MS
            s.codec_context.gop_size = 1  # every frame a key frame: exact seeks, no carried state
            s.metadata["title"] = title
            streams.append(s)
        self._streams = (streams[0], streams[1])
        # tags go into the header, which is written with the first packet: set them now
        meta = self._container.metadata
        meta["FUSE4D_INTRINSICS"] = ",".join(repr(float(v)) for v in k.as_array())
        meta["FUSE4D_DEPTH_UNIT_MM"] = repr(self.depth_unit_mm)
        if self.fps:
            meta["FUSE4D_FPS"] = repr(float(self.fps))
        if self.sensor:
            meta["FUSE4D_SENSOR"] = self.sensor

    @reports_write_errors
    def write(
        self,
        depth: np.ndarray,
        intensity: np.ndarray,
        *,
        mask: np.ndarray | None = None,
        timestamp: float | None = None,
    ) -> None:
        """Append one frame (depth mm, NaN/<=0 invalid; intensity [0, 1], uint8/uint16 divided
        by 255/65535; mask ignored).

        The pts (ms) must increase strictly: a frame whose rounded pts is not after the
        previous frame's is stored 1 ms after it; where that moves frames by more than the
        1 ms rounding, one ``UserWarning`` at :meth:`close` names them."""
        if self._streams is None:
            raise RuntimeError("DepthVideoWriter is not open; use it in a `with` block")
        shape = self.intrinsics.shape
        check_frame_shapes(self.num_written, shape, depth=depth, intensity=intensity)
        intensity = as_storable_intensity(intensity, name=f"intensity of frame {self.num_written}")
        if self.num_written and (timestamp is None) != (self._t0 is None):
            # the times start at frame 0 or not at all (as the frame-folder writer's)
            raise ParameterError(
                f"{self.path} (frame {self.num_written}): give a timestamp for every frame or "
                "for none"
            )
        if timestamp is not None and not math.isfinite(float(timestamp)):
            raise ParameterError(
                f"{self.path} (frame {self.num_written}): timestamp {timestamp!r} is not finite"
            )
        if timestamp is not None and self.num_written == 0:
            self._t0 = float(timestamp)
            self._container.metadata["FUSE4D_T0"] = repr(self._t0)
        if self._t0 is not None and timestamp is not None:
            exact_ms = (float(timestamp) - self._t0) * 1000.0
        else:
            exact_ms = self.num_written * 1000.0 / (self.fps or 30.0)
        pts = max(round(exact_ms), self._last_pts + 1)  # strictly increasing (1 ms resolution)
        if pts - exact_ms > 1.0:
            self._moved.append((self.num_written, pts - exact_ms))
        self._last_pts = pts
        planes = (
            depth_to_units(depth, self.depth_unit_mm, self._report),
            intensity_to_uint(intensity, 16),
        )
        for stream, plane in zip(self._streams, planes, strict=True):
            frame = self._av.VideoFrame.from_ndarray(
                np.ascontiguousarray(plane, dtype=np.uint16), format="gray16le"
            )
            frame.pts, frame.time_base = pts, _MS
            for packet in stream.encode(frame):
                self._container.mux(packet)
        self.num_written += 1

    def _warn_moved_pts(self) -> None:
        """One warning for the frames whose time :meth:`write` moved (they did not come
        after the previous frame at the 1 ms resolution of the pts)."""
        if not self._moved:
            return
        frame, ms = max(self._moved, key=lambda m: m[1])
        n = len(self._moved)
        which, moved = f"frame {frame}", f"was stored {ms:.1f} ms later"
        if n > 1:
            which = f"{n} frames (first: frame {self._moved[0][0]})"
            moved = f"were stored later, by up to {ms:.1f} ms (frame {frame})"
        warnings.warn(
            f"{self.path}: {which} did not come after the previous frame at the .mkv's 1 ms "
            f"time resolution and {moved}",
            UserWarning,
            stacklevel=5,  # the caller's `with` (through close, its decorator, __exit__)
        )

    @reports_write_errors
    def close(self) -> None:
        """Flush the encoders, write the tags and move the file into place."""
        if self._stack is None:
            return
        if self.num_written == 0:
            self.abort()
            raise ParameterError(f"{self.path}: no frame was written")
        try:  # _stack stays set until the rename, so that anything before it discards the stage
            for stream in self._streams or ():
                for packet in stream.encode():
                    self._container.mux(packet)
            self._container.close()
            self._report.warn(str(self.path), stacklevel=5)  # (through @reports_write_errors)
            self._warn_moved_pts()
        except BaseException:  # a Ctrl-C or an error-promoted warning too
            self.abort()
            raise
        stack, self._stack = self._stack, None
        stack.close()  # moves the file into place (or deletes the temporary if that fails)

    def abort(self) -> None:
        """Discard the partial output."""
        if self._stack is None:
            return
        if self._container is not None:
            with contextlib.suppress(self._av.FFmpegError, OSError, ValueError):
                self._container.close()  # a half-written container may fail to finalise
        self._discard_stage()


def write_depth_video(
    seq: Sequence,
    path: str | PathLike[str],
    *,
    depth_unit_mm: float = 1.0,
    overwrite: bool = False,
    warn_coarse_unit: bool = True,
) -> Path:
    """Write a :class:`~fuse4d.Sequence` as FFV1 ``.mkv`` (see :class:`DepthVideoWriter`, whose
    ``warn_coarse_unit`` this passes on).

    Ground truth (masks included) cannot be stored in this format (a ``UserWarning`` says
    so; use :func:`~fuse4d.io.write_npz` to keep it)."""
    checked_for_layout(
        seq, path, owner="write_depth_video", layout="the .mkv format", keeps_mask=False,
        overwrite=overwrite,
    )  # fmt: skip
    with DepthVideoWriter(
        path,
        seq.intrinsics,
        depth_unit_mm=depth_unit_mm,
        fps=seq.fps,
        overwrite=overwrite,
        sensor=seq.sensor,
        warn_coarse_unit=warn_coarse_unit,
    ) as writer:
        ts = seq.timestamps
        for t in range(seq.num_frames):
            writer.write(
                seq.depth[t], seq.intensity[t], timestamp=None if ts is None else float(ts[t])
            )
    return Path(path)
