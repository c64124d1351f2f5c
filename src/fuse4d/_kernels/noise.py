"""Per-frame statistics of the depth-noise model (A22) and the frame's median depth, each one
numba kernel over the frame instead of numpy temporaries (issue 13). Private.

* :func:`_noise_quad_ratios`: the samples of :func:`fuse4d.motion.estimate_noise_quad`.
* :func:`_median64`: ``np.median`` of those samples (float64).
* :func:`_finite_median32`: ``np.median`` of a float32 frame's finite values.

Both medians are radix selections, bit for bit numpy's result, without a sort or partition.
A value's key is an unsigned integer whose order is the float order (:func:`_sortable`).
One histogram of the keys' top 16 bits gives the bin of each middle rank; the keys in that
bin are gathered (one more pass), and the rank is found among them from histograms of their
lower 16-bit digits. The gathering writes every key and advances its index on a match: the
match follows no pattern (a third of the ball's depths share the median's top bits, spread
over the image), and a branch on it mispredicted often enough to cost twice the pass.
600 x 600 ball (stop 49, best of 15, old and new code in one process): the depth median
1.45-1.50 -> 0.69 ms (0.56 -> 0.52 on ``uva_cv2_person_turning`` frames), the samples' median
1.53 -> 0.21 ms (``np.median``; uva 0.58 -> 0.19).

Both reproduce numpy's results exactly (tested against numpy); the arithmetic is compiled
without ``contract`` and ``arcp`` so that it rounds as numpy does.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit
from ._segments import SEGMENT_FASTMATH

__all__ = ["_finite_median32", "_median64", "_noise_quad_ratios", "_trimmed_residuals"]

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
#: float64 bits: the sign, and the exponent bits that are all set for +-inf and NaN
_SIGN64 = np.uint64(0x8000000000000000)
#: one radix digit: 16 bits
_DIGIT = 16
_DIGIT_MASK = (1 << _DIGIT) - 1
#: the shift of the digit below the top one, as int64 (one overload of _key_of_rank: a
#: literal 0 would type as Literal[int](0), a second signature in the cache index)
_LOW_SHIFT32 = np.int64(0)
_LOW_SHIFT64 = np.int64(64 - 2 * _DIGIT)


@njit(inline="always")
def _sortable(b, sign):
    """The key of the float with bits ``b`` (uint32 or uint64; ``sign`` its sign bit) whose
    unsigned order is the float order."""
    if b & sign:
        return ~b
    return b | sign


@njit(inline="always")
def _float_bits(key, sign):
    """The bits of the float whose :func:`_sortable` key is ``key``."""
    return key & ~sign if key & sign else ~key


@njit(inline="always")
def _value(key):
    """The float32 whose :func:`_sortable` key is ``key`` (uint32)."""
    return np.array([_float_bits(key, _SIGN)], np.uint32).view(np.float32)[0]


@njit(inline="always")
def _value64(key):
    """The float64 whose :func:`_sortable` key is ``key`` (uint64)."""
    return np.array([_float_bits(key, _SIGN64)], np.uint64).view(np.float64)[0]


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
def _key_of_rank(keys, m, rank, shift):
    """The key of rank ``rank`` (0-based, increasing) among ``keys[:m]`` (uint64), which share
    every bit above ``shift`` + 16: digit by digit (16 bits from ``shift`` down to 0), each
    pass keeping in place the keys that have the rank's digit (``keys`` is reordered)."""
    mask = np.uint64(_DIGIT_MASK)
    s = np.uint64(shift)
    while True:
        counts = np.zeros(1 << _DIGIT, np.int64)
        for i in range(m):
            counts[(keys[i] >> s) & mask] += 1
        digit, rank = _bin_of(counts, rank)
        d = np.uint64(digit)
        if s == 0:  # the keys left share every other bit
            return ((keys[0] >> np.uint64(_DIGIT)) << np.uint64(_DIGIT)) | d
        kept = 0
        for i in range(m):  # kept <= i
            k = keys[i]
            keys[kept] = k
            kept += ((k >> s) & mask) == d
        m = kept
        s -= np.uint64(_DIGIT)


@njit
def _gather32(bits, high, count):
    """The keys (as uint64) of the ``count`` finite float32 bit patterns among ``bits`` whose
    key's top 16 bits are ``high`` (branch-free, module doc)."""
    out = np.empty(count + 1, np.uint64)
    j = 0
    for i in range(bits.size):
        b = bits[i]
        k = _sortable(b, _SIGN)
        out[j] = k
        j += ((b & _EXPONENT) != _EXPONENT) & ((k >> np.uint32(_DIGIT)) == high)
    return out


@njit
def _gather64(bits, n, high, count):
    """The keys of the ``count`` float64 bit patterns among ``bits[:n]`` whose key's top 16
    bits are ``high`` (branch-free, module doc)."""
    out = np.empty(count + 1, np.uint64)
    j = 0
    for i in range(n):
        k = _sortable(bits[i], _SIGN64)
        out[j] = k
        j += (k >> np.uint64(64 - _DIGIT)) == high
    return out


@njit
def _top_histogram32(bits):
    """Histogram of the top 16 key bits of the finite float32 bit patterns ``bits``, and their
    count."""
    top = np.zeros(1 << _DIGIT, np.int64)
    # np.int64: a plain ``n = 0`` can be typed Literal[int](0) and compile a second overload
    # of this cached kernel; two cold processes compiling different overloads race on the index
    n = np.int64(0)
    for i in range(bits.size):
        b = bits[i]
        if (b & _EXPONENT) != _EXPONENT:
            top[_sortable(b, _SIGN) >> np.uint32(_DIGIT)] += 1
            n += 1
    return top, n


@njit
def _ranked32(bits, top, rank_a, rank_b):
    """The float32 values of ranks ``rank_a`` <= ``rank_b`` (0-based, increasing) among the
    finite bit patterns ``bits`` whose top-digit histogram is ``top``."""
    high_a, in_a = _bin_of(top, rank_a)
    high_b, in_b = _bin_of(top, rank_b)
    keys_a = _gather32(bits, np.uint32(high_a), top[high_a])
    # (one digit below the top one: _key_of_rank leaves the keys in place, keys_a may be keys_b)
    keys_b = keys_a if high_b == high_a else _gather32(bits, np.uint32(high_b), top[high_b])
    a = _value(np.uint32(_key_of_rank(keys_a, top[high_a], in_a, _LOW_SHIFT32)))
    b = _value(np.uint32(_key_of_rank(keys_b, top[high_b], in_b, _LOW_SHIFT32)))
    return a, b


@njit(fastmath=_EXACT)
def _finite_median32(depth):
    """``np.median`` of the finite values of float32 ``depth`` (any shape), as float: the
    middle value, or float32(a + b) / 2 of the two middle ones (numpy's float32 mean); NaN
    when there is none."""
    bits = np.ascontiguousarray(depth).ravel().view(np.uint32)
    top, n = _top_histogram32(bits)
    if n == 0:
        return np.nan
    lo, hi = _ranked32(bits, top, (n - 1) // 2, n // 2)
    if n % 2 == 1:
        return np.float64(hi)
    return np.float64(np.float32(lo + hi) / np.float32(2.0))


@njit(fastmath=_EXACT)
def _trimmed_residuals(depth, points, channel, out):
    """The residuals of :func:`fuse4d.motion.estimate_depth_noise` at or below their 95th
    percentile, in ``out[:k]``; returns k (0: no finite residual).

    The residuals r = |depth - points[..., channel]| (float32) of every 2nd row and column,
    the finite ones in row-major order (``out``: at least ceil(H / 2) ceil(W / 2) float32),
    and ``np.quantile(r, 0.95)`` as numpy computes it (method "linear": the order statistics
    around the virtual index (n - 1) 0.95 by radix selection, interpolated in float32 like
    numpy's ``_lerp`` with a Python-float weight); the kept residuals stay in their order, so
    numpy's ``mean`` of ``out[:k]`` is that of ``r[r <= q]``.
    """
    h, w = depth.shape
    n = 0
    for v in range(0, h, 2):
        for u in range(0, w, 2):
            x = abs(depth[v, u] - points[v, u, channel])
            out[n] = x
            n += np.isfinite(x)
    if n == 0:
        return 0
    bits = out[:n].view(np.uint32)
    top, _ = _top_histogram32(bits)
    virtual = (n - 1) * 0.95
    below = math.floor(virtual)
    rank = int(below)
    # (n = 1: numpy takes the one value twice; b - a = 0 makes the weight irrelevant)
    a, b = _ranked32(bits, top, rank, min(rank + 1, n - 1))
    gamma = virtual - below
    diff = b - a  # numpy's _lerp: from the nearer end
    q = b - diff * np.float32(1.0 - gamma) if gamma >= 0.5 else a + diff * np.float32(gamma)
    k = 0
    for i in range(n):  # in place: k <= i
        x = out[i]
        out[k] = x
        k += x <= q
    return k


@njit(fastmath=_EXACT)
def _median64(values, n):
    """``np.median(values[:n])`` of float64 ``values``, none NaN, ``n`` >= 1: the middle value,
    or (a + b) / 2 of the two middle ones (numpy's mean of them). -0.0 ranks below 0.0 here
    and equal to it in numpy: a zero median's sign may differ (the noise samples are > 0)."""
    bits = values.view(np.uint64)
    top = np.zeros(1 << _DIGIT, np.int64)
    for i in range(n):
        top[_sortable(bits[i], _SIGN64) >> np.uint64(64 - _DIGIT)] += 1
    high_a, rank_a = _bin_of(top, (n - 1) // 2)
    high_b, rank_b = _bin_of(top, n // 2)
    keys_a = _gather64(bits, n, np.uint64(high_a), top[high_a])
    if high_b == high_a:  # (each rank's search reorders its keys)
        keys_b = keys_a.copy()
    else:
        keys_b = _gather64(bits, n, np.uint64(high_b), top[high_b])
    hi = _value64(_key_of_rank(keys_b, top[high_b], rank_b, _LOW_SHIFT64))
    if n % 2 == 1:
        return hi
    return (_value64(_key_of_rank(keys_a, top[high_a], rank_a, _LOW_SHIFT64)) + hi) / 2.0
