"""RVL codec kernels (numba; serial by nature, every value depends on the previous one).

Kept apart from :mod:`fuse4d.io.rvl` so that importing the I/O package (``fuse4d info``) does
not load numba: the kernels are imported when the first RVL image is decoded or encoded.
"""

from __future__ import annotations

import numpy as np

from ._numba import njit

__all__ = ["decode", "encode"]


@njit
def decode(words: np.ndarray, out: np.ndarray) -> int:  # pragma: no cover - numba
    """Decode ``words`` into ``out`` (uint16 pixels): 0, -1 if ``words`` ends first, -2 if a
    run passes the end of ``out``.

    The stream is a sequence of variable-length values (3-bit nibbles, low first, bit 3 = more
    follow): a zero-run length, a nonzero-run length, then that many zigzag deltas of the
    nonzero pixels, repeated. One loop reads them all, ``phase`` says what the next one is.
    """
    n = out.size
    pos = 0  # next word
    word = np.uint32(0)
    nibbles = 0
    k = 0
    previous = 0
    phase = 0  # 0: zero-run length next, 1: nonzero-run length next, 2: a nonzero pixel next
    remaining = 0  # nonzero pixels left in the run (phase 2)
    while k < n:
        value = 0
        shift = 0
        while True:
            if nibbles == 0:
                if pos >= words.size:
                    return -1
                word = words[pos]
                pos += 1
                nibbles = 8
            nibble = (word >> np.uint32(28)) & np.uint32(0xF)
            value |= int(nibble & np.uint32(7)) << shift
            word = (word << np.uint32(4)) & np.uint32(0xFFFFFFFF)
            nibbles -= 1
            shift += 3
            if (nibble & np.uint32(8)) == 0:
                break
        if phase == 2:
            delta = (value >> 1) ^ -(value & 1)
            current = (previous + delta) & 0xFFFF
            out[k] = current
            previous = current
            k += 1
            remaining -= 1
            if remaining == 0:
                phase = 0
        else:
            if k + value > n:
                return -2
            if phase == 0:
                for _ in range(value):
                    out[k] = 0
                    k += 1
                phase = 1
            else:
                remaining = value
                phase = 2 if value > 0 else 0
    return 0


@njit
def encode(values: np.ndarray, words: np.ndarray) -> int:  # pragma: no cover - numba
    n = values.size
    pos = 0
    word = np.uint32(0)
    nibbles = 0
    i = 0
    previous = 0
    while i < n:
        zeros = 0
        while i < n and values[i] == 0:
            zeros += 1
            i += 1
        nonzeros = 0
        j = i
        while j < n and values[j] != 0:
            nonzeros += 1
            j += 1
        for item in range(nonzeros + 2):
            if item == 0:
                value = zeros
            elif item == 1:
                value = nonzeros
            else:
                current = int(values[i])
                i += 1
                delta = current - previous
                if delta > 32767:  # 16-bit wrap, as the C++ codec's short arithmetic
                    delta -= 65536
                elif delta < -32768:
                    delta += 65536
                value = (delta << 1) ^ (delta >> 31)
                value &= 0xFFFFFFFF
                previous = current
            while True:
                nibble = value & 7
                value >>= 3
                if value:
                    nibble |= 8
                word = ((word << np.uint32(4)) | np.uint32(nibble)) & np.uint32(0xFFFFFFFF)
                nibbles += 1
                if nibbles == 8:
                    words[pos] = word
                    pos += 1
                    nibbles = 0
                    word = np.uint32(0)
                if not value:
                    break
    if nibbles:
        words[pos] = (word << np.uint32(4 * (8 - nibbles))) & np.uint32(0xFFFFFFFF)
        pos += 1
    return pos
