"""Block decimation of depth (``fuse4d.decimate``). Private.

Serial (``njit``, no GIL): ``fuse4d live`` runs it in its capture thread, beside the fusion's
parallel kernels, where a parallel kernel would only compete for the same cores.
"""

from __future__ import annotations

import numpy as np

from ._numba import njit

__all__ = ["_decimate_depth_kernel"]


@njit
def _decimate_depth_kernel(depth, factor, use_median, out):  # pragma: no cover - compiled
    """``out[v, u]`` from the valid (finite, > 0) depths of block ``depth[f v : f v + f, f u :
    f u + f]`` (f = ``factor``): their lower median (``use_median``; the ((n - 1) // 2)-th of
    the n sorted values, a measured depth) or their mean; NaN when the block has none.

    ``depth`` (H, W) float32 mm; ``out`` (H // f, W // f) float32.
    """
    ho, wo = out.shape
    values = np.empty(factor * factor, np.float32)
    for v in range(ho):
        for u in range(wo):
            n = 0
            total = 0.0
            for dv in range(factor):
                row = v * factor + dv
                for du in range(factor):
                    d = depth[row, u * factor + du]
                    if d > 0.0 and d < np.inf:  # False for NaN, 0, negative, inf
                        if use_median:  # insertion into the sorted prefix
                            j = n
                            while j > 0 and values[j - 1] > d:
                                values[j] = values[j - 1]
                                j -= 1
                            values[j] = d
                        else:
                            total += d
                        n += 1
            if n == 0:
                out[v, u] = np.nan
            elif use_median:
                out[v, u] = values[(n - 1) // 2]
            else:
                out[v, u] = np.float32(total / n)
