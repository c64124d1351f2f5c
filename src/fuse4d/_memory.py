"""Buffers whose memory is written when they are made (issue 13). Private.

``np.zeros`` and ``np.empty`` only reserve address space: the kernel maps each page at its
first write. A streaming engine that makes its ring buffers that way pays for the mapping
during its first frames, inside the per-frame timings, instead of at construction. On this
project's 2-core machine a 4 KiB page fault costs about 1.6 us, and at times 30 us or more
(while the host reclaims the guest's memory): writing the flow ring buffers of a 600 x 600,
9-frame engine then added 15-30 ms to each of the first frames, so that whole
``fuse4d bench`` runs measured a flow stage of 22-38 ms instead of 8-11.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["committed"]


def committed(shape: int | tuple[int, ...], dtype: Any, value: Any = 0) -> np.ndarray:
    """A new array of ``shape`` and ``dtype`` filled with ``value``, every page written now."""
    return np.full(shape, value, dtype)
