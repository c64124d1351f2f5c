"""A contiguous part of a recording, read as a recording of its own (``frames="A:B"``).

``fuse4d run REC --frames 200:300`` fuses frames 200-299 of REC as if they were the whole
recording: every code path that opens the recording with the same reader options (the
streaming run, the dask engine's tasks, the report of the run) sees the same 100 frames,
numbered 0-99. Decoders that stream forward (video, message logs) seek to the first frame
once (:meth:`~fuse4d.io._base.FrameReader.iter_frames`), they do not decode the part before it
again for every frame.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..sequence import GroundTruth, Sequence
from ._base import Frame, FrameReader, FrameSelection, ProgressCallback, resolve_frames

__all__ = ["FrameRange"]


class FrameRange(FrameReader):
    """Frames ``frames`` of ``reader``, renumbered from 0.

    Parameters
    ----------
    reader : FrameReader
        The whole recording (closed with this reader).
    frames : slice, range, (start, stop) or "A:B"
        The contiguous part (Python slice semantics, as :func:`fuse4d.io.resolve_frames`).

    Attributes
    ----------
    first_frame : int
        Index in the recording of this reader's frame 0.

    Examples
    --------
    >>> from fuse4d.io import open_frames  # doctest: +SKIP
    >>> part = open_frames("rec.bag", frames="200:300")  # doctest: +SKIP
    >>> len(part), part.first_frame  # doctest: +SKIP
    (100, 200)
    """

    def __init__(self, reader: FrameReader, frames: FrameSelection) -> None:
        self._reader = reader
        self._range = resolve_frames(frames, len(reader))
        self.first_frame = self._range.start
        self.format = reader.format  # type: ignore[misc]
        self.path = reader.path
        self.intrinsics = reader.intrinsics
        ts = reader.timestamps
        self.timestamps = None if ts is None else ts[self._range.start : self._range.stop]
        self.fps = reader.fps
        self.depth_unit_mm = reader.depth_unit_mm
        self.ground_truth_keys = reader.ground_truth_keys
        self.notes = reader.notes
        self.sensor = reader.sensor

    def __len__(self) -> int:
        return len(self._range)

    def __getattr__(self, name: str) -> Any:
        # the public layout-specific attributes of the recording (a bag's streams); never its
        # private state (an npz's members, a decoder's pass), which covers the whole file
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._reader, name)

    def _shift(self, frame: Frame, index: int) -> Frame:
        return replace(frame, index=index)

    def read_frame(self, index: int) -> Frame:
        k = self._index(index)
        return self._shift(self._reader.read_frame(self._range[k]), k)

    def read_intensity(self, index: int) -> NDArray[np.float32]:
        return self._reader.read_intensity(self._range[self._index(index)])

    def read_source(self, start: int, stop: int) -> NDArray[np.uint8] | None:
        a = self.first_frame
        return self._reader.read_source(a + start, a + stop)

    def iter_frames(self, frames: FrameSelection = None) -> Iterator[Frame]:
        sel = resolve_frames(frames, len(self))
        a = self.first_frame
        inner = self._reader.iter_frames((a + sel.start, a + sel.stop))
        for k, frame in zip(sel, inner, strict=True):
            yield self._shift(frame, k)

    def __iter__(self) -> Iterator[Frame]:
        return self.iter_frames(None)

    def _ground_truth(self, selection: range) -> GroundTruth | None:
        a = self.first_frame
        return self._reader._ground_truth(range(a + selection.start, a + selection.stop))

    def read_sequence(
        self, frames: FrameSelection = None, *, progress: ProgressCallback | None = None
    ) -> Sequence:
        sel = resolve_frames(frames, len(self))
        a = self.first_frame
        return self._reader.read_sequence((a + sel.start, a + sel.stop), progress=progress)

    def close(self) -> None:
        self._reader.close()
