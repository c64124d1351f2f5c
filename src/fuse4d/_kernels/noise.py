"""Per-frame statistics of the depth-noise model (A22) and the frame's median depth, each one
numba kernel over the frame instead of numpy temporaries (issue 13). Private.

* :func:`_noise_quad_ratios`: the samples of :func:`fuse4d.motion.estimate_noise_quad`.
* :func:`_finite_median32`: ``np.median`` of a float32 frame's finite values, bit for bit,
  by a two-level radix selection (two passes, no sort, no partition: 2.3 ms on the 600 x 600
  ball, where ``d[np.isfinite(d)]`` + ``np.median`` took 5 ms).

Both reproduce numpy's results exactly (tested against numpy); the arithmetic is compiled
without ``contract`` and ``arcp`` so that it rounds as numpy does.
"""

from __future__ import annotations

import numpy as np

from ._numba import njit
from ._segments import SEGMENT_FASTMATH

__all__ = ["_finite_median32", "_noise_quad_ratios"]

#: no FMA contraction, no reciprocal rewriting: numpy's rounding
_EXACT = set(SEGMENT_FASTMATH)


@njit(fastmath=_EXACT)
def _noise_quad_ratios(depth, out):
    """|second difference along the row| / z^2 of every 2nd row of ``depth`` (H, W) float32
    mm, over the non-zero differences below 5 % of z (z the middle pixel, float64 like
    numpy's): written to ``out`` (at least ceil(H / 2) (W - 2) float64); returns their count.
    The samples of :func:`fuse4d.motion.estimate_noise_quad` in numpy's order."""
    h, w = depth.shape
    n = 0
    for v in range(0, h, 2):
        row = depth[v]
        for u in range(1, w - 1):
            z = np.float64(row[u])
            second = abs(np.float64(row[u - 1]) - 2.0 * z + np.float64(row[u + 1]))
            if np.isfinite(second) and second > 0.0 and second < 0.05 * z:
                out[n] = second / z**2
                n += 1
    return n


#: float32 bits of +-inf and NaN: all exponent bits set
_EXPONENT = np.uint32(0x7F800000)
_SIGN = np.uint32(0x80000000)


@njit(inline="always")
def _sortable(b):
    """The uint32 key of the float32 with bits ``b`` whose unsigned order is the float order."""
    if b & _SIGN:
        return ~b
    return b | _SIGN


@njit(inline="always")
def _bin_of(counts, rank):
    """(bin, rank within the bin) of the value of ``rank`` (0-based) in histogram ``counts``."""
    b = 0
    seen = 0
    while seen + counts[b] <= rank:
        seen += counts[b]
        b += 1
    return b, rank - seen


@njit
def _median_keys(bits, n):
    """Keys (:func:`_sortable`) of the finite values of rank (n - 1) // 2 and n // 2
    (0-based, increasing order) among the ``n`` finite float32 bit patterns ``bits``: the top
    16 bits from one histogram, the low 16 from a histogram of the values that share them."""
    top = np.zeros(1 << 16, np.int64)
    for i in range(bits.size):
        b = bits[i]
        if (b & _EXPONENT) != _EXPONENT:
            top[_sortable(b) >> np.uint32(16)] += 1
    high_a, rank_a = _bin_of(top, (n - 1) // 2)
    high_b, rank_b = _bin_of(top, n // 2)
    low_a = np.zeros(1 << 16, np.int64)
    low_b = np.zeros(1 << 16, np.int64)
    ha = np.uint32(high_a)
    hb = np.uint32(high_b)
    for i in range(bits.size):
        b = bits[i]
        if (b & _EXPONENT) != _EXPONENT:
            k = _sortable(b)
            h = k >> np.uint32(16)
            if h == ha:
                low_a[k & np.uint32(0xFFFF)] += 1
            if h == hb:
                low_b[k & np.uint32(0xFFFF)] += 1
    a = _bin_of(low_a, rank_a)[0]
    b = _bin_of(low_b, rank_b)[0]
    return (ha << np.uint32(16)) | np.uint32(a), (hb << np.uint32(16)) | np.uint32(b)


@njit(inline="always")
def _value(key):
    """The float32 whose :func:`_sortable` key is ``key``."""
    b = key & ~_SIGN if key & _SIGN else ~key
    return np.array([b], np.uint32).view(np.float32)[0]


@njit(fastmath=_EXACT)
def _finite_median32(depth):
    """``np.median`` of the finite values of float32 ``depth`` (any shape), as float: the
    middle value, or float32(a + b) / 2 of the two middle ones (numpy's float32 mean); NaN
    when there is none."""
    bits = np.ascontiguousarray(depth).ravel().view(np.uint32)
    n = 0
    for i in range(bits.size):
        if (bits[i] & _EXPONENT) != _EXPONENT:
            n += 1
    if n == 0:
        return np.nan
    # np.int64: a plain ``n`` can be typed Literal[int](0) and compile a second overload of
    # this cached kernel; two cold processes compiling different overloads race on the index
    key_lo, key_hi = _median_keys(bits, np.int64(n))
    hi = _value(key_hi)
    if n % 2 == 1:
        return np.float64(hi)
    return np.float64(np.float32(_value(key_lo) + hi) / np.float32(2.0))
