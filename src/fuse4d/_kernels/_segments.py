"""The segment-limited box pass (A3′ smoothing), shared by every kernel that runs it. Private.

* :func:`_line_segments`: the depth-continuous segments of one line.
* :func:`_box_line`: one local-linear box pass over them; :func:`_box_line3` of three
  channels at once.
* :data:`SEGMENT_FASTMATH`: the fastmath flags the calling kernels must be compiled with.
* :data:`BLOCK`, :data:`BLOCK_CHUNKS`: the blocking of the two-sweep kernels.

The rounding of :func:`_box_line` is written out in the source, so that it does not depend on
the kernel it is inlined into: every fused multiply-add is an explicit :func:`_fma`, and the
kernels are compiled without ``contract`` and ``arcp`` (with them LLVM fused, or turned
``x * (1 / n)`` into ``x / n``, differently in each caller: 1-ulp differences between kernels
computing the same pass). The arithmetic is the one the original single kernel
(``_segment_box_rows_kernel`` compiled with ``contract`` and ``arcp``, AVX-512) performed, so
the values did not change: its output loop ran 8 pixels at a time (vectorised) and the rest of
a segment one at a time, and the two paths rounded differently at a truncated window (one
reciprocal of n for both means in the vectorised path, two divisions in the other); both
paths are kept, chosen by the same rule (:data:`_VECTOR`).
"""

from __future__ import annotations

import numpy as np
from numba import types
from numba.core.extending import intrinsic

from ._common import _step_limit
from ._numba import FASTMATH, njit

__all__ = [
    "BLOCK",
    "BLOCK_CHUNKS",
    "SEGMENT_FASTMATH",
    "_box_line",
    "_box_line3",
    "_fma",
    "_line_segments",
]

#: fastmath flags of the kernels that inline :func:`_box_line` (no FMA contraction, no
#: reciprocal rewriting: the rounding is the source's)
SEGMENT_FASTMATH = frozenset(FASTMATH - {"contract", "arcp"})

#: lines per block of a two-sweep kernel (``smooth_base``, ``segment_smooth``): the
#: transposed writes are runs of this many float32
BLOCK = 16
#: parallel chunks of blocks of a sweep, each allocating its scratch once instead of per
#: block: A29's row sweep of a 640 x 480 frame (eight arrays, a 16 x 3 x 640 float32 tile of
#: 123 kB among them) went 2.9 -> 2.2 ms on two threads (stop 48; glibc's trim and mmap
#: thresholds raised did not give the per-block kernel that: not the memory being returned
#: to the system). Its column sweep, changed alike, did not move.
BLOCK_CHUNKS = 8

#: pixels per step of the original kernel's vectorised output loop: in a segment of L >= 8
#: pixels the first L - L % 8 ran vectorised, the others one by one
_VECTOR = 8


@intrinsic
def _fma(typingctx, a, b, c):
    """a * b + c (float64) rounded once (``llvm.fma``)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@njit(inline="always")
def _line_segments(z, max_step, quad, starts, ends):
    """Depth-continuous segments of one line ``z`` (float32 mm, NaN = excluded): runs of
    finite values whose consecutive differences are below ``_step_limit``. Writes the runs
    [starts[i], ends[i]) and returns their number."""
    n = z.shape[0]
    m = 0
    u = 0
    while u < n:
        if np.isnan(z[u]):
            u += 1
            continue
        a = u
        b = u + 1
        while (
            b < n
            and not np.isnan(z[b])
            and abs(z[b] - z[b - 1]) < _step_limit(z[b - 1], max_step, quad)
        ):
            b += 1
        starts[m] = a
        ends[m] = b
        m += 1
        u = b
    return m


@njit(inline="always")
def _truncated(s_val, s_kv, j, last, radius, n_vector):
    """The line fit of pixel ``j`` of a segment of ``last`` + 1 pixels whose window is cut by
    the segment's end (prefix sums ``s_val``, ``s_kv`` of the segment)."""
    lo = max(j - radius, 0)
    hi = min(j + radius, last)
    n = hi - lo + 1
    sum_val = s_val[hi + 1] - s_val[lo]
    sum_kv = s_kv[hi + 1] - s_kv[lo]
    if j < n_vector:
        inv_n = 1.0 / n
        mean_val = sum_val * inv_n
        mean_kv = sum_kv * inv_n
    else:
        mean_val = sum_val / n
        mean_kv = sum_kv / n
    # index mean and variance in closed form
    mean_j = 0.5 * (lo + hi)
    var_j = np.float64(n * n - 1) * (1.0 / 12.0)
    if var_j > 0.0:
        cov = _fma(-mean_j, mean_val, mean_kv)
        return _fma(cov / var_j, j - mean_j, mean_val)
    return mean_val


@njit(inline="always")
def _segment_out(s_val, s_kv, dst, a, b, radius, inv_full, interior=True):
    """Write the box pass of the segment [a, b) to ``dst`` from its prefix sums: the full
    windows (the plain mean, a branch-free loop; skipped when not ``interior``) and the ones
    cut by the segment's ends."""
    size = b - a
    last = size - 1
    n_vector = size - size % _VECTOR
    head = min(radius, size)
    for j in range(head):
        dst[a + j] = _truncated(s_val, s_kv, j, last, radius, n_vector)
    if interior:
        for j in range(radius, size - radius):
            # full symmetric window: the line fit reduces to the mean
            dst[a + j] = (s_val[j + radius + 1] - s_val[j - radius]) * inv_full
    for j in range(max(size - radius, head), size):
        dst[a + j] = _truncated(s_val, s_kv, j, last, radius, n_vector)


@njit(inline="always")
def _box_line(src, dst, starts, ends, m, radius, s_val, s_kv):
    """One local-linear box pass of radius ``radius`` px over the ``m`` segments of a line.

    ``src`` -> ``dst`` (float32; pixels outside the segments are not written); ``s_val``,
    ``s_kv``: float64 scratch of at least the longest segment + 1. Within a segment the window
    of each pixel is truncated to the segment and a straight line (least squares over the
    pixel index) is fitted and evaluated at the pixel: the plain box mean on a full window.
    Float64 prefix sums restarted at each segment.
    """
    inv_full = 1.0 / (2 * radius + 1)
    for i in range(m):
        a = starts[i]
        b = ends[i]
        sv = 0.0
        kv = 0.0
        s_val[0] = sv
        s_kv[0] = kv
        for k in range(a, b):
            j = k - a
            x = np.float64(src[k])
            sv = sv + x
            kv = _fma(np.float64(j), x, kv)
            s_val[j + 1] = sv
            s_kv[j + 1] = kv
        _segment_out(s_val, s_kv, dst, a, b, radius, inv_full)


@njit(inline="always")
def _box_line3(src, dst, starts, ends, m, radius, s_val, s_kv):
    """:func:`_box_line` of three channels at once (``src``, ``dst``: (3, n) float32;
    ``s_val``, ``s_kv``: (3, >= n + 1) float64): the same values per channel, the prefix
    sums of the channels interleaved (six independent chains instead of two)."""
    inv_full = 1.0 / (2 * radius + 1)
    for i in range(m):
        a = starts[i]
        b = ends[i]
        sv0 = 0.0
        sv1 = 0.0
        sv2 = 0.0
        kv0 = 0.0
        kv1 = 0.0
        kv2 = 0.0
        for c in range(3):
            s_val[c, 0] = 0.0
            s_kv[c, 0] = 0.0
        # s_kv is read only within 2 radius + 1 of the segment's ends (the cut windows)
        size = b - a
        keep_head = min(size, 2 * radius + 1)
        keep_tail = max(keep_head, size - 2 * radius - 2)
        # the full window of pixel p = j - radius ends at j: its mean is written as soon as
        # s_val[j + 1] is known (the same operands as in _segment_out, one pass fewer)
        width = 2 * radius
        for j in range(size):
            fj = np.float64(j)
            x0 = np.float64(src[0, a + j])
            x1 = np.float64(src[1, a + j])
            x2 = np.float64(src[2, a + j])
            sv0 = sv0 + x0
            sv1 = sv1 + x1
            sv2 = sv2 + x2
            kv0 = _fma(fj, x0, kv0)
            kv1 = _fma(fj, x1, kv1)
            kv2 = _fma(fj, x2, kv2)
            s_val[0, j + 1] = sv0
            s_val[1, j + 1] = sv1
            s_val[2, j + 1] = sv2
            if j < keep_head or j >= keep_tail:
                s_kv[0, j + 1] = kv0
                s_kv[1, j + 1] = kv1
                s_kv[2, j + 1] = kv2
            if j >= width:
                p = a + j - radius
                dst[0, p] = (sv0 - s_val[0, j - width]) * inv_full
                dst[1, p] = (sv1 - s_val[1, j - width]) * inv_full
                dst[2, p] = (sv2 - s_val[2, j - width]) * inv_full
        for c in range(3):
            _segment_out(s_val[c], s_kv[c], dst[c], a, b, radius, inv_full, False)
