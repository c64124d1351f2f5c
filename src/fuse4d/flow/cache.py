"""On-disk cache of optical-flow fields (METHOD §2.5 item 6).

Flow is the bottleneck of the pipeline and depends only on the intensity frames and the flow
parameters, so every fusion or evaluation sweep that changes only depth-side settings can reuse
it. :class:`FlowCache` stores one ``.npy`` file per entry, named by a SHA-256 key that the caller
builds from everything the result depends on (see :func:`fuse4d.flow.estimate_flow_pair`).
Writes are atomic (temporary file in the same folder + ``os.replace``), so a crash or a parallel
writer never leaves a half-written entry; an unreadable entry counts as a miss and is rewritten.
"""

from __future__ import annotations

import hashlib
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..io._atomic import atomic_file

__all__ = ["FlowCache", "hash_parts"]


def hash_parts(*parts: bytes | str | np.ndarray | None) -> str:
    """SHA-256 hex digest of a sequence of parts (strings, bytes, arrays, ``None``).

    Arrays contribute their dtype, shape and C-order bytes; every part is length-prefixed, so
    different splits of the same bytes give different keys.
    """
    digest = hashlib.sha256()
    for part in parts:
        if part is None:
            chunk = b"<none>"
        elif isinstance(part, np.ndarray):
            arr = np.ascontiguousarray(part)
            chunk = f"<array {arr.dtype.str} {arr.shape}>".encode() + arr.tobytes()
        elif isinstance(part, str):
            chunk = part.encode()
        else:
            chunk = bytes(part)
        digest.update(len(chunk).to_bytes(8, "little"))
        digest.update(chunk)
    return digest.hexdigest()


class FlowCache:
    """A folder of cached flow arrays, keyed by hex strings.

    Parameters
    ----------
    directory : str or PathLike
        Cache folder (a leading ``~`` is the home folder); created on the first write.

    Attributes
    ----------
    hits, misses : int
        Number of :meth:`load` calls that found / did not find a usable entry.

    Examples
    --------
    >>> import tempfile
    >>> cache = FlowCache(tempfile.mkdtemp())
    >>> cache.load("abc") is None
    True
    >>> cache.store("abc", np.zeros((2, 4, 5, 2), np.float32))
    >>> cache.load("abc").shape, cache.hits, cache.misses
    ((2, 4, 5, 2), 1, 1)
    """

    def __init__(self, directory: str | PathLike[str]) -> None:
        self.directory = Path(directory).expanduser()  # ("~/x" made a folder named "~")
        self.hits = 0
        self.misses = 0

    def __repr__(self) -> str:
        return f"FlowCache({str(self.directory)!r}, hits={self.hits}, misses={self.misses})"

    def path(self, key: str) -> Path:
        """File that holds entry ``key`` (two-level fan-out: ``ab/abcdef....npy``)."""
        if not key or any(c not in "0123456789abcdef" for c in key):
            raise ValueError(f"cache key must be a lower-case hex string, got {key!r}")
        return self.directory / key[:2] / f"{key}.npy"

    def load(self, key: str) -> NDArray[np.float32] | None:
        """The stored array, or ``None`` (a miss) if absent or unreadable."""
        path = self.path(key)
        try:
            array = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError):
            self.misses += 1
            return None
        self.hits += 1
        return array

    def store(self, key: str, array: np.ndarray) -> None:
        """Write ``array`` under ``key`` atomically (replacing an existing entry)."""
        path = self.path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(path, overwrite=True) as tmp, tmp.open("wb") as handle:
            np.save(handle, np.ascontiguousarray(array), allow_pickle=False)

    def clear(self) -> int:
        """Delete every entry; returns the number of files removed."""
        removed = 0
        if self.directory.is_dir():
            for file in self.directory.glob("??/*.npy"):
                file.unlink(missing_ok=True)
                removed += 1
        return removed
