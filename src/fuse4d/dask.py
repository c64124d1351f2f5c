"""``fuse4d.dask``: chunked 4D fusion on dask, bit-identical to :func:`fuse4d.fuse_sequence`.

>>> import fuse4d.dask as fd                                      # doctest: +SKIP
>>> res = fd.fuse(depth, intensity, intrinsics, chunk_frames=32)  # doctest: +SKIP
>>> depth_fused, support = dask.compute(res.depth, res.support)   # doctest: +SKIP
>>> fd.release_engines()  # the idle chunk engine's memory back  # doctest: +SKIP

Needs the ``scale`` extra (``pip install 'fuse4d[scale]'``). The implementation lives in
:mod:`fuse4d.scale`; see ``docs/scaling.md``.
"""

from __future__ import annotations

# the public names of fuse4d.scale, listed once (there)
from .scale import *
from .scale import __all__  # noqa: F401
