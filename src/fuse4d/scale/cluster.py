"""The scheduler behind ``fuse4d run --engine dask``: threads, local processes, or a cluster.

============================  ==================================================================
``threads``                   dask's threaded scheduler in this process (``--workers`` threads)
``processes``                 a ``distributed.LocalCluster`` of ``--workers`` single-threaded
                              worker processes (dask's multiprocessing pool without distributed)
``tcp://HOST:PORT``           an existing ``dask.distributed`` scheduler (e.g. dask-jobqueue)
``sync``                      one thread, no parallelism (debugging)
============================  ==================================================================

Worker processes are started with one thread each for numba, OpenMP and OpenCV
(``NUMBA_NUM_THREADS=1`` before the interpreter starts), so that parallelism comes from dask
and ``--workers N`` uses N cores.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
from collections.abc import Callable, Iterator
from typing import Any

import dask

from ._deps import require_scale_extra

__all__ = ["SINGLE_THREAD_ENV", "local_cluster", "open_compute"]

#: Environment of worker processes: one thread per library (dask provides the parallelism).
SINGLE_THREAD_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "OPENCV_FOR_THREADS_NUM": "1",
}


@contextlib.contextmanager
def local_cluster(workers: int, **kwargs: Any) -> Iterator[Any]:
    """A ``distributed.LocalCluster`` of ``workers`` single-threaded processes and its client.

    The worker processes inherit this process's environment (``PYTHONPATH``,
    ``NUMBA_CACHE_DIR``) plus :data:`SINGLE_THREAD_ENV`. ``kwargs`` go to ``LocalCluster``.
    """
    require_scale_extra(distributed=True)
    from distributed import Client, LocalCluster

    spawn_env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    spawn_env.update(SINGLE_THREAD_ENV)
    options = {"n_workers": workers, "threads_per_worker": 1, "processes": True}
    options.update(kwargs)
    options.setdefault("dashboard_address", ":0")  # no clash with a running dashboard
    # distributed's nanny writes pre-spawn-environ into *this* process's os.environ and leaves
    # it there; NUMBA_NUM_THREADS=1 in the caller's environment then breaks numba's next
    # compilation ("Cannot set NUMBA_NUM_THREADS ... once the threads have been launched").
    # The workers are spawned by the time LocalCluster returns: restore the caller's environment.
    saved = dict(os.environ)
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": spawn_env}):
            cluster = LocalCluster(**options)
    finally:
        _restore_environ(saved)
    try:
        with cluster, Client(cluster) as client:
            yield client
    finally:
        _restore_environ(saved)


def _restore_environ(saved: dict[str, str]) -> None:
    """Put ``os.environ`` back to ``saved`` (keys added since are removed)."""
    for key in set(os.environ) - set(saved):
        del os.environ[key]
    os.environ.update(saved)


def _compute_with(client: Any, show: bool) -> Callable[..., tuple[Any, ...]]:
    def compute(*tasks: Any) -> tuple[Any, ...]:
        from distributed import progress

        futures = client.compute(list(tasks))
        if show:
            with contextlib.redirect_stdout(sys.stderr):
                progress(futures)
        return tuple(client.gather(futures))

    return compute


@contextlib.contextmanager
def open_compute(
    scheduler: str = "threads", workers: int | None = None, *, progress: bool = True
) -> Iterator[Callable[..., tuple[Any, ...]]]:
    """A ``compute(*delayed)`` function for the chosen scheduler, with dask's progress bar.

    Parameters
    ----------
    scheduler : str
        ``"threads"``, ``"processes"``, ``"sync"`` or a ``tcp://HOST:PORT`` address.
    workers : int, optional
        Threads or worker processes of a local scheduler (default: the CPU count).
    progress : bool
        Show dask's progress bar on stderr.

    Yields
    ------
    callable
        ``compute(*delayed) -> tuple`` of results; all inputs of one call share the workers.
    """
    n = workers or os.cpu_count() or 1
    if scheduler.startswith(("tcp://", "tls://", "ucx://", "inproc://")):
        require_scale_extra(distributed=True)
        from distributed import Client

        with Client(scheduler) as client:
            yield _compute_with(client, progress)
        return
    if scheduler == "processes" and importlib.util.find_spec("distributed") is not None:
        with local_cluster(n) as client:
            yield _compute_with(client, progress)
        return
    # (no distributed: "processes" is dask's multiprocessing pool)
    if scheduler not in ("threads", "processes", "sync"):
        raise ValueError(
            f"scheduler must be threads, processes, sync or tcp://HOST:PORT, got {scheduler!r}"
        )
    from dask.diagnostics import ProgressBar

    def compute(*tasks: Any) -> tuple[Any, ...]:
        bar = ProgressBar(out=sys.stderr) if progress else contextlib.nullcontext()
        with bar:
            return dask.compute(*tasks, scheduler=scheduler, num_workers=n)

    yield compute
