"""ST-MF: non-causal motion-compensated spatio-temporal median (Matyunin et al. 2011, BASELINES §7)."""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import median_filter

from .._kernels.baselines import _block_match_kernel, _stmf_median_kernel
from .._params import check_int, check_number
from ..camera import Intrinsics
from ._common import MAX_WINDOW_RADIUS, check_inputs, iterate

__all__ = ["block_match", "sorting_network", "spatio_temporal_median"]


@functools.lru_cache(maxsize=16)
def sorting_network(size: int) -> NDArray[np.int32]:
    """Batcher's odd-even merge sorting network for ``size`` inputs, as (P, 2) index pairs.

    Built for the next power of two and pruned to pairs with both indices < ``size``: the
    missing inputs act as +inf, which never move, so the pruned network sorts ``size`` values
    (ascending; pair (i, j) puts the smaller value at i).
    """
    n = 1
    while n < size:
        n *= 2
    pairs = []
    p = 1
    while p < n:
        k = p
        while k >= 1:
            pairs.extend(
                (i + j, i + j + k)
                for j in range(k % p, n - k, 2 * k)
                for i in range(min(k, n - j - k))
                if (i + j) // (2 * p) == (i + j + k) // (2 * p) and i + j + k < size
            )
            k //= 2
        p *= 2
    return np.array(pairs, dtype=np.int32).reshape(-1, 2)


def block_match(
    reference: ArrayLike, moving: ArrayLike, *, block: int = 8, search: int = 8
) -> NDArray[np.int32]:
    """Per-pixel motion of ``moving`` relative to ``reference`` by SAD block matching.

    Full search ±``search`` px over ``block``×``block`` blocks, then a 3×3 median filter on the
    block vector field; each pixel takes its block's vector.

    Parameters
    ----------
    reference, moving : (H, W) ndarray
        Intensity frames t and τ in [0, 1].
    block : int, default 8
        Block size (px).
    search : int, default 8
        Search range (px).

    Returns
    -------
    (H, W, 2) ndarray of int32
        ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row), with ``moving[x + v] ≈ reference[x]``.
    """
    ref = np.ascontiguousarray(reference, dtype=np.float32)
    mov = np.ascontiguousarray(moving, dtype=np.float32)
    h, w = ref.shape
    nb_r, nb_c = -(-h // block), -(-w // block)
    vec = np.empty((nb_r, nb_c, 2), np.int32)
    _block_match_kernel(ref, mov, int(block), int(search), vec)
    vec = np.stack([median_filter(vec[..., c], size=3, mode="nearest") for c in range(2)], -1)
    full = np.repeat(np.repeat(vec, block, axis=0), block, axis=1)[:h, :w]
    return np.ascontiguousarray(full, dtype=np.int32)


def spatio_temporal_median(
    depth: ArrayLike,
    intensity: ArrayLike,
    intrinsics: Intrinsics,
    *,
    size: int = 2,
    iterations: int = 1,
    half_window: int = 1,
    intensity_tol: float = 0.05,
    block: int = 8,
    search: int = 8,
) -> NDArray[np.float32]:
    """ST-MF: median over motion-compensated candidates from frames t−k … t+k.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray
        Intensity in [0, 1] (motion estimation and candidate check).
    intrinsics : Intrinsics
        Camera (shape check only).
    size : int, default 2
        ``temporal_radius`` k: frames t−k..t+k (2k+1 frames, truncated at the ends).
        Sweep 1–4.
    iterations : int, default 1
        Repeated application to its own output (the motion is estimated once). Sweep 1–3.
    half_window : int, default 1
        a, spatial half window ((2a+1)² offsets). Sweep 0, 1, 2.
    intensity_tol : float, default 0.05
        τ_I ([0, 1] units).
    block, search : int, default 8, 8
        Block size and full-search range (px) of the block matching.

    Returns
    -------
    (T, H, W) ndarray of float32
        Filtered depth (mm). Holes are filled where candidates exist (part of the method).

    Notes
    -----
    [R] (BASELINES §7): block matching of each neighbour τ directly against frame t (SAD on I),
    3×3 median on the block vectors; candidates D_τ(x + v_τ(x) + o) kept if valid and
    |I_τ(x + v_τ(x) + o) − I_t(x + o)| < τ_I; output = their median.
    """
    d, g = check_inputs(depth, intensity, intrinsics, guided_by="stmf")
    k = check_int("spatio_temporal_median", "size", size, minimum=0)
    a = check_int(
        "spatio_temporal_median", "half_window", half_window, minimum=0, maximum=MAX_WINDOW_RADIUS
    )
    check_number("spatio_temporal_median", "intensity_tol", intensity_tol, gt=0)
    check_int("spatio_temporal_median", "block", block, minimum=1, maximum=MAX_WINDOW_RADIUS)
    check_int("spatio_temporal_median", "search", search, minimum=0, maximum=MAX_WINDOW_RADIUS)
    n, h, w = d.shape
    # Motion from every neighbour to every frame: depends on intensity only, computed once.
    vectors: dict[tuple[int, int], NDArray[np.int32]] = {}
    for t in range(n):
        for tau in range(max(0, t - k), min(n, t + k + 1)):
            if tau == t:
                vectors[(t, tau)] = np.zeros((h, w, 2), np.int32)
            else:
                vectors[(t, tau)] = block_match(g[t], g[tau], block=block, search=search)

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        out = np.empty_like(cur)
        for t in range(n):
            t0, t1 = max(0, t - k), min(n, t + k + 1)
            vec = np.stack([vectors[(t, tau)] for tau in range(t0, t1)])
            buf = np.empty((h, w), np.float32)
            _stmf_median_kernel(
                np.ascontiguousarray(cur[t0:t1]),
                np.ascontiguousarray(g[t0:t1]),
                t - t0,
                vec,
                a,
                float(intensity_tol),
                sorting_network((t1 - t0) * (2 * a + 1) ** 2),  # windows truncate at the ends
                buf,
            )
            out[t] = buf
        return out

    return iterate(step, d, iterations, owner="spatio_temporal_median")
