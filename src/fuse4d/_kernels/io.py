"""Kernels of the frame writers (issue 13: a real run's write-behind thread spent ~22 ms of
CPU per 640x480 frame in numpy boolean indexing, taken from the fusion on 2 cores), and the
conversion of the flow methods' input images to 8 bits.

Each computes, in one pass and without temporaries, the very values of the numpy code it
replaces in :mod:`fuse4d.io._images` (``fastmath`` off: divisions stay divisions, so the
results are the same bits).
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit


@njit(fastmath=False)
def _depth_to_units_kernel(depth, unit_mm, out):
    """Depth (H, W) mm → ``out`` (H, W) uint16: rint(depth / unit_mm) clipped to [1, 65535]
    where depth is finite and > 0, else 0.

    Returns (valid, above 65535, below 1, max |depth / unit_mm - rint(...)|) over the valid
    pixels (0.0 residual when none is valid), what :class:`QuantizationReport` records.
    """
    h, w = depth.shape
    n_valid = 0
    n_high = 0
    n_low = 0
    worst = 0.0
    for v in range(h):
        for u in range(w):
            d = np.float64(depth[v, u])
            if not (math.isfinite(d) and d > 0.0):
                out[v, u] = 0
                continue
            q = d / unit_mm
            s = np.rint(q)
            n_valid += 1
            if s > 65535.0:
                n_high += 1
                out[v, u] = 65535
            elif s < 1.0:
                n_low += 1
                out[v, u] = 1
            else:
                out[v, u] = np.uint16(s)
            r = abs(q - s)
            if r > worst:
                worst = r
    return n_valid, n_high, n_low, worst


@njit(fastmath=False)
def _intensity_to_uint8_kernel(intensity, tol, out):
    """Intensity (H, W) in [0, 1] → ``out`` (H, W) uint8 = clip(rint(i * 255), 0, 255), NaN
    as 0. Returns (exact, special): exact when every |out / 255 - i| <= ``tol`` (NaN read as
    0; ``np.allclose``'s test), special when the input holds an infinity (the caller then
    uses numpy; ``out`` is then not defined). The 256 quotients k / 255 come from a table
    (the same float64 values), not a division per pixel."""
    levels = np.arange(256).astype(np.float64) / 255.0
    h, w = intensity.shape
    exact = True
    for v in range(h):
        for u in range(w):
            x = np.float64(intensity[v, u])
            if math.isinf(x):
                return False, True
            if math.isnan(x):
                x = 0.0
            k = np.uint8(min(max(np.rint(x * 255.0), 0.0), 255.0))
            out[v, u] = k
            exact &= abs(levels[k] - x) <= tol
    return exact, False


@njit(fastmath=False)
def _confidence_to_uint8_kernel(confidence, out):
    """Confidence (H, W) float32 → ``out`` (H, W) uint8 = rint(clip(c, 0, 1) * 255) in
    float32, NaN as 0: the bytes of ``np.rint(np.clip(np.nan_to_num(c), 0, 1) * 255.0)
    .astype(np.uint8)`` (:func:`fuse4d.io._base.flag_images`; 1.6 ms there, one pass here)."""
    h, w = confidence.shape
    for v in range(h):
        for u in range(w):
            c = confidence[v, u]
            if math.isnan(c):
                c = np.float32(0.0)
            c = min(max(c, np.float32(0.0)), np.float32(1.0))
            out[v, u] = np.uint8(np.rint(c * np.float32(255.0)))


@njit(fastmath=False)
def _unit_to_uint8_kernel(image, out):
    """Intensity (H, W) float32 in [0, 1] -> ``out`` (H, W) uint8: ``image * 255 + 0.5`` in
    float32 (no fused multiply-add), clipped to [0, 255] and truncated: the bytes of the
    numpy expression in :func:`fuse4d.flow._checks.to_uint8`."""
    h, w = image.shape
    for v in range(h):
        for u in range(w):
            x = image[v, u] * np.float32(255.0) + np.float32(0.5)
            x = min(max(x, np.float32(0.0)), np.float32(255.0))
            out[v, u] = np.uint8(x)
