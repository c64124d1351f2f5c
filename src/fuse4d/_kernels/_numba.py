"""The single numba policy of fuse4d: every kernel is compiled through these decorators.

``cache=True`` everywhere (CI and the CLI reuse compiled code across processes).
fastmath is limited to flags that keep NaN/inf semantics intact, because NaN marks invalid
depth throughout fuse4d; ``nnan``/``ninf`` would silently break ``np.isnan`` tests.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

# OpenMP threads that spin after each parallel region steal the CPU from the main thread's
# numpy/OpenCV work in between (measured at 600x600 on 2 busy cores: the motion-reference stage
# took 70 ms instead of 18 ms). Sleep instead; a user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba

__all__ = ["FASTMATH", "kernel_threads", "literal_unroll", "njit", "njit_parallel", "prange"]

#: fastmath flags allowed in kernels (no 'nnan', 'ninf': NaN = invalid depth).
FASTMATH = frozenset({"contract", "arcp", "nsz"})

#: Set FUSE4D_NUMBA_PARALLEL=0 to compile "parallel" kernels serially (debugging, profiling).
PARALLEL = os.environ.get("FUSE4D_NUMBA_PARALLEL", "1") != "0"

prange = numba.prange
#: unrolls a loop over a tuple at compile time (numba.literal_unroll)
literal_unroll = numba.literal_unroll


def njit(func=None, **kwargs):
    """``numba.njit`` with the project policy (cache, fastmath). Serial kernels."""
    opts = {"cache": True, "fastmath": set(FASTMATH), "nogil": True}
    opts.update(kwargs)
    if func is None:
        return numba.njit(**opts)
    return numba.njit(**opts)(func)


def njit_parallel(func=None, **kwargs):
    """``numba.njit(parallel=True)`` with the project policy; ``prange`` over rows or frames."""
    opts = {"cache": True, "fastmath": set(FASTMATH), "nogil": True, "parallel": PARALLEL}
    opts.update(kwargs)
    if func is None:
        return numba.njit(**opts)
    return numba.njit(**opts)(func)


@contextmanager
def kernel_threads(n: int | None) -> Iterator[None]:
    """Run the parallel kernels that the calling thread launches inside the block on at most
    ``n`` threads (numba's thread count is per calling thread: other threads, e.g. dask
    workers, keep theirs); ``None``: unchanged. The results do not depend on it (no kernel
    reduces across threads)."""
    prev = numba.get_num_threads()
    if n is None or n >= prev:
        yield
        return
    numba.set_num_threads(n)
    try:
        yield
    finally:
        numba.set_num_threads(prev)
