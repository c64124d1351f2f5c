"""Scale-out on dask: chunked 4D fusion that equals the in-memory result bit for bit.

Needs the ``scale`` extra (``pip install 'fuse4d[scale]'``: dask[array], distributed, zarr 3).
The public face is :mod:`fuse4d.dask` (``fuse4d.dask.fuse``, ``fuse4d.dask.flows``); the
modules here are:

==============  ==========================================================================
``_deps``       the optional-dependency check (one clear ImportError)
``graph``       stage 1 (pair flows, once per pair) and stage 2 (fusion with a ±h halo)
``inputs``      recordings on disk as lazy dask arrays (one delayed read per frame)
``zarr_out``    zarr v3 output: one shard per time chunk, per-chunk done markers, resume
``cluster``     the scheduler behind ``fuse4d run --engine dask`` (threads, processes, tcp://)
``cli``         ``fuse4d run --engine dask`` for one or many recordings
==============  ==========================================================================

See ``docs/scaling.md``.
"""

from __future__ import annotations

from ._deps import require_scale_extra

require_scale_extra()

from .graph import DaskFlows, DaskFusion, flows, fuse, release_engines
from .inputs import LazyRecording, open_lazy
from .zarr_out import ZarrOutput, write_zarr

__all__ = [
    "DaskFlows",
    "DaskFusion",
    "LazyRecording",
    "ZarrOutput",
    "flows",
    "fuse",
    "open_lazy",
    "release_engines",
    "write_zarr",
]
