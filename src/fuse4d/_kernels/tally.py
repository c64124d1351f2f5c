"""Kernel of the per-frame counts of the ``fuse4d run`` summary. Private.

:class:`fuse4d.run._QualityTally` counted a fused frame's raw-valid, supported and filled
pixels with boolean indexing and its source codes with ``np.bincount`` (which converts the
codes to int64 first): ≈ 1.2 ms per 640 x 480 frame in temporaries. One pass counts them all.
"""

from __future__ import annotations

import math

from ._numba import njit

#: layout of the counts: raw-valid, of them supported and filled, then one per source code
VALID, SUPPORTED, FILLED, SOURCES = 0, 1, 2, 3


@njit
def _frame_counts_kernel(raw_depth, support, filled, source, counts):  # pragma: no cover
    """Add one frame's counts to ``counts`` (int64, ``SOURCES`` + number of codes).

    ``raw_depth`` (H, W) float: finite where the raw frame has depth; ``support`` (H, W)
    uint8, ``filled`` (H, W) bool: the fused frame's; ``source`` (H, W) uint8 codes, or a
    (0, 0) array: none. Counts the raw-valid pixels, those of them with support > 0 and those
    of them filled, and the pixels per source code (codes beyond the array: not counted).
    """
    h, w = raw_depth.shape
    n_codes = counts.shape[0] - SOURCES
    has_source = source.shape[0] > 0
    valid = 0
    supported = 0
    n_filled = 0
    for v in range(h):
        for u in range(w):
            if math.isfinite(raw_depth[v, u]):
                valid += 1
                supported += 1 if support[v, u] > 0 else 0
                n_filled += 1 if filled[v, u] else 0
            if has_source:
                code = source[v, u]
                if code < n_codes:
                    counts[SOURCES + code] += 1
    counts[VALID] += valid
    counts[SUPPORTED] += supported
    counts[FILLED] += n_filled
