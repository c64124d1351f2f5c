"""RVL depth codec (Wilson 2017, "Fast Lossless Depth Image Compression"), as used by ROS's
``compressed_depth_image_transport`` (``CompressedImage`` format ``"16UC1; compressedDepth rvl"``).

No Python package decodes RVL, and the codec is 40 lines of bit twiddling over 32-bit words,
so it is written here with numba (serial by nature: every value depends on the previous one).
A 640x480 frame (10 % holes, 2.5:1 compression) decodes in 6-9 ms on the shared 2-core CI
machine under load, i.e. > 100 frames/s.

Stream layout: little-endian 32-bit words holding 4-bit nibbles from the most significant end;
each value is a variable-length code of 3-bit groups (low group first, bit 3 = "more follows").
The image is a run of ``zeros`` count, ``nonzeros`` count, then ``nonzeros`` zig-zag deltas to
the previous non-zero pixel, repeated until every pixel is decoded.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .._kernels._numba import njit

__all__ = ["decode_rvl", "encode_rvl"]


@njit
def _decode(words: np.ndarray, out: np.ndarray) -> int:  # pragma: no cover - numba
    n = out.size
    pos = 0  # next word
    word = np.uint32(0)
    nibbles = 0
    k = 0
    previous = 0
    while k < n:
        for phase in range(2):  # 0: zeros, 1: nonzeros
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
            if k + value > n:
                return -2
            if phase == 0:
                for _ in range(value):
                    out[k] = 0
                    k += 1
            else:
                for _ in range(value):
                    positive = 0
                    shift = 0
                    while True:
                        if nibbles == 0:
                            if pos >= words.size:
                                return -1
                            word = words[pos]
                            pos += 1
                            nibbles = 8
                        nibble = (word >> np.uint32(28)) & np.uint32(0xF)
                        positive |= int(nibble & np.uint32(7)) << shift
                        word = (word << np.uint32(4)) & np.uint32(0xFFFFFFFF)
                        nibbles -= 1
                        shift += 3
                        if (nibble & np.uint32(8)) == 0:
                            break
                    delta = (positive >> 1) ^ -(positive & 1)
                    current = (previous + delta) & 0xFFFF
                    out[k] = current
                    previous = current
                    k += 1
            if k >= n:
                break
    return 0


@njit
def _encode(values: np.ndarray, words: np.ndarray) -> int:  # pragma: no cover - numba
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


def decode_rvl(data: bytes | np.ndarray, width: int, height: int) -> NDArray[np.uint16]:
    """Decode an RVL stream into a ``(height, width)`` uint16 image.

    Raises
    ------
    ValueError
        If the stream ends early or encodes more pixels than ``width * height``.
    """
    buf = np.frombuffer(bytes(data), dtype=np.uint8)
    usable = buf.size - buf.size % 4
    words = buf[:usable].view("<u4").astype(np.uint32)
    out = np.empty(int(width) * int(height), dtype=np.uint16)
    status = _decode(words, out)
    if status == -1:
        raise ValueError("RVL stream ends before all pixels are decoded (truncated)")
    if status == -2:
        raise ValueError("RVL stream encodes more pixels than the image holds (corrupt)")
    return out.reshape(int(height), int(width))


def encode_rvl(image: np.ndarray) -> bytes:
    """Encode a uint16 image as an RVL stream (inverse of :func:`decode_rvl`; for tests/writers)."""
    values = np.ascontiguousarray(image, dtype=np.uint16).ravel()
    words = np.zeros(3 * values.size + 8, dtype=np.uint32)  # worst case: 6 nibbles/pixel + runs
    count = _encode(values, words)
    return words[:count].astype("<u4").tobytes()
