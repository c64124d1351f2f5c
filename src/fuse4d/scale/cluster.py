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
and ``--workers N`` uses N cores, and with glibc's default allocator settings (not
distributed's ``MALLOC_TRIM_THRESHOLD_``, see :data:`ALLOCATOR_ENV`). Workers of a cluster
given by address are checked for that setting, with a warning that says how to start them.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import dask

from ..errors import ParameterError
from ._deps import require_scale_extra

__all__ = [
    "ALLOCATOR_ENV",
    "QUIET_CONFIG",
    "SINGLE_THREAD_ENV",
    "local_cluster",
    "open_compute",
    "slow_allocator_workers",
    "warn_if_slow_allocator",
]

#: Environment of worker processes: one thread per library (dask provides the parallelism).
SINGLE_THREAD_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "OPENCV_FOR_THREADS_NUM": "1",
}

#: Environment overrides for glibc's allocator in worker processes (None = leave unset).
#: distributed's nanny sets ``MALLOC_TRIM_THRESHOLD_=65536`` by default, to hand freed memory
#: back to the OS; setting it at all also switches off glibc's adaptive mmap threshold, so
#: every array above 128 KiB is a fresh ``mmap`` whose pages fault in on first touch — the
#: engine's per-frame (H, W, 3) temporaries then cost ~2.8 M page faults per 96 frames at
#: 600 x 600 and make the same fusion ~1.4x slower in a worker than in a plain process.
ALLOCATOR_ENV: dict[str, str | None] = {"MALLOC_TRIM_THRESHOLD_": None}

_ALLOCATOR_HINT = (
    "{n} of {total} dask workers run with MALLOC_TRIM_THRESHOLD_ set (distributed's default), "
    "which makes fuse4d's tasks ~1.4x slower (every large array is a fresh mmap); start them "
    "with the dask config distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_ = null "
    "(a YAML file in ~/.config/dask; see docs/scaling.md, 'Worker environment')"
)


def _trim_threshold() -> str | None:
    """This process's ``MALLOC_TRIM_THRESHOLD_`` (run on each worker)."""
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def slow_allocator_workers(client: Any) -> list[str]:
    """Addresses of the client's workers that run with ``MALLOC_TRIM_THRESHOLD_`` set.

    Such workers (distributed's nanny sets it unless told not to, see :data:`ALLOCATOR_ENV`)
    fault in every large temporary array page by page.

    Parameters
    ----------
    client : distributed.Client

    Returns
    -------
    list of str
        Sorted worker addresses; empty when every worker uses glibc's adaptive default.
    """
    return _allocator_check(client)[0]


def _allocator_check(client: Any) -> tuple[list[str], list[str]]:
    """(slow, silent): the addresses of the workers that run with ``MALLOC_TRIM_THRESHOLD_``
    set, and of those that did not answer (died or left meanwhile: a dead worker made the
    whole run fail with "Stream is closed")."""
    found = client.run(_trim_threshold, on_error="return")
    silent = sorted(a for a, value in found.items() if isinstance(value, BaseException))
    slow = sorted(a for a, value in found.items() if value is not None and a not in silent)
    return slow, silent


def warn_if_slow_allocator(client: Any) -> None:
    """Warn (``RuntimeWarning``) when some of the client's workers run with
    ``MALLOC_TRIM_THRESHOLD_`` set, saying how to start them instead, and when some did not
    answer (a worker died: its log says why)."""
    slow, silent = _allocator_check(client)
    if silent:
        warnings.warn(
            f"{len(silent)} dask worker(s) did not answer ({', '.join(silent)}): a worker "
            "died or left; see the workers' logs (their tasks go to the others)",
            RuntimeWarning,
            stacklevel=3,
        )
    if slow:
        total = len(client.scheduler_info()["workers"])
        warnings.warn(
            _ALLOCATOR_HINT.format(n=len(slow), total=total), RuntimeWarning, stacklevel=3
        )


#: How often the scheduler of :func:`local_cluster` balances work (dask's default: 1 s). A
#: task that depends on another is queued on the worker that holds the dependency's result,
#: even a token of a few bytes, until work stealing moves it; the flow tasks of a chunk take
#: 0.3-0.5 s at 600 x 600, so with a 1 s interval an idle worker waited up to 2 s at the start
#: of a run (measured, 2 workers). Set the same on your own cluster's scheduler
#: (``distributed.scheduler.work-stealing-interval``).
STEALING_INTERVAL = "100ms"

#: dask settings of the processes of :func:`local_cluster` that cut distributed's own
#: background work, which on a machine with as many workers as cores takes CPU from the tasks:
#: the workers' statistical profiler (a stack sample every 10 ms, for the dashboard's profile
#: page), the event-loop tick (every 20 ms, for "event loop unresponsive" warnings), the system
#: monitor (every 0.5 s, for the dashboard's plots) and the memory monitor (every 0.1 s; it
#: spills and restarts a worker that exceeds its limit, now within 1 s). Measured on an idle
#: 2-worker LocalCluster (2 vCPUs, 20 s, ``/proc`` CPU times): 2.8 s of CPU with dask's
#: defaults (scheduler 1.2 s, each worker 0.8 s: 7 % of the machine), 0.4 s with these. The
#: fuse4d tasks do not need any of them; set them on your own cluster too (docs/scaling.md,
#: "Worker environment").
QUIET_CONFIG: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
}


@contextlib.contextmanager
def local_cluster(workers: int, **kwargs: Any) -> Iterator[Any]:
    """A ``distributed.LocalCluster`` of ``workers`` single-threaded processes and its client.

    The worker processes inherit this process's environment (``PYTHONPATH``,
    ``NUMBA_CACHE_DIR``) plus :data:`SINGLE_THREAD_ENV`, without distributed's
    ``MALLOC_TRIM_THRESHOLD_`` (:data:`ALLOCATOR_ENV`); the scheduler and workers run with
    :data:`STEALING_INTERVAL` and :data:`QUIET_CONFIG`. ``kwargs`` go to ``LocalCluster``.
    """
    require_scale_extra(distributed=True)
    from distributed import Client, LocalCluster

    spawn_env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    spawn_env.update(SINGLE_THREAD_ENV)
    spawn_env.update(ALLOCATOR_ENV)
    options = {"n_workers": workers, "threads_per_worker": 1, "processes": True}
    options.update(kwargs)
    options.setdefault("dashboard_address", ":0")  # no clash with a running dashboard
    # distributed's nanny writes pre-spawn-environ into *this* process's os.environ and leaves
    # it there; NUMBA_NUM_THREADS=1 in the caller's environment then breaks numba's next
    # compilation ("Cannot set NUMBA_NUM_THREADS ... once the threads have been launched").
    # The workers are spawned by the time LocalCluster returns: restore the caller's environment.
    saved = dict(os.environ)
    try:
        with (
            dask.config.set(
                {
                    "distributed.nanny.pre-spawn-environ": spawn_env,
                    "distributed.scheduler.work-stealing-interval": STEALING_INTERVAL,
                    **QUIET_CONFIG,
                }
            ),
            _workers_ignore_ctrl_c(),
        ):
            cluster = LocalCluster(**options)
    finally:
        _restore_environ(saved)
    nanny_log = logging.getLogger("distributed.nanny")
    nanny_level = nanny_log.level
    try:
        with cluster, Client(cluster) as client:
            # a task cancelled by Ctrl-C logged "Async instruction ... ended with
            # CancelledError" in each worker, between the progress bar and "interrupted"
            client.run(_quiet_cancellations)
            try:
                yield client
            except BaseException:
                # closing kills the workers still inside a kernel ("Worker process still
                # alive after 4.0 seconds, killing", once per worker): expected after Ctrl-C
                nanny_log.setLevel(logging.ERROR)
                raise
    finally:
        nanny_log.setLevel(nanny_level)
        _restore_environ(saved)


def _quiet_cancellations() -> None:
    """In a worker: log only errors of distributed's task state machine."""
    logging.getLogger("distributed.worker.state_machine").setLevel(logging.ERROR)


@contextlib.contextmanager
def _workers_ignore_ctrl_c() -> Iterator[None]:
    """Spawn the worker processes with SIGINT ignored (inherited through exec; Python then
    installs no KeyboardInterrupt handler). Ctrl-C reaches the whole process group: each
    worker printed a KeyboardInterrupt traceback, and the client's clean-up then met dead
    workers. This process stops the run and closes the cluster. SIGINT is ignored here only
    while the cluster starts (main thread only: elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


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
            try:
                with contextlib.redirect_stdout(sys.stderr):
                    progress(futures)
            except BaseException:  # Ctrl-C: end the bar's line before "fuse4d: interrupted"
                print(file=sys.stderr, flush=True)
                raise
        return tuple(client.gather(futures))

    return compute


#: Address schemes of a running dask scheduler (``distributed``).
SCHEDULER_ADDRESS_SCHEMES = ("tcp://", "tls://", "ucx://", "inproc://")


def check_scheduler(scheduler: str, workers: int | None = None) -> None:
    """Refuse a scheduler name or worker count that :func:`open_compute` cannot use, before a
    caller writes anything.

    Raises
    ------
    ParameterError
        ``scheduler`` is not threads, processes, sync or an address that distributed can
        parse (``tcp://HOST:PORT``); ``workers`` < 1.
    ImportError
        An address without ``distributed`` installed.
    """
    if not scheduler.startswith(SCHEDULER_ADDRESS_SCHEMES) and scheduler not in (
        "threads",
        "processes",
        "sync",
    ):
        raise ParameterError(
            f"scheduler must be threads, processes, sync or tcp://HOST:PORT, got {scheduler!r}"
        )
    if workers is not None and workers < 1:
        raise ParameterError(f"workers must be >= 1 (default: the CPU count), got {workers}")
    if scheduler.startswith(SCHEDULER_ADDRESS_SCHEMES):
        require_scale_extra(distributed=True)  # ImportError: before distributed is imported
        from distributed.comm.addressing import get_address_host

        try:
            with warnings.catch_warnings():  # ucx:// warns, then raises the same FutureWarning
                warnings.simplefilter("ignore")
                get_address_host(scheduler)  # the scheme's own parser: tcp:// needs HOST:PORT
        except (ValueError, TypeError, Warning) as exc:
            raise ParameterError(
                f"scheduler must be threads, processes, sync or tcp://HOST:PORT, got "
                f"{scheduler!r} ({' '.join(str(exc).split())})"
            ) from None


def _connect(scheduler: str) -> Any:
    """A ``distributed.Client`` of the scheduler at address ``scheduler``.

    Raises
    ------
    ImportError
        Without ``distributed``.
    ParameterError
        If the address is malformed or no scheduler answers there (``tls://`` without a
        TLS configuration, a scheme whose backend is not installed, no server, a timeout).
    """
    check_scheduler(scheduler)
    from distributed import Client

    try:
        return Client(scheduler)
    except (OSError, ValueError, TypeError) as exc:  # timeout, bad address, tls, ucx
        raise ParameterError(f"--scheduler {scheduler}: cannot connect: {exc}") from None


@contextlib.contextmanager
def _on_exit(on_exit: Callable[[Any], object] | None, client: Any) -> Iterator[None]:
    """Run ``on_exit(client)`` when the block ends. After an exception (Ctrl-C: the workers
    may be gone) its own failure is not raised: it replaced the KeyboardInterrupt with a
    "Stream is closed" error, exit 2 instead of 130."""
    try:
        yield
    except BaseException:
        if on_exit is not None:
            with contextlib.suppress(Exception):
                on_exit(client)
        raise
    if on_exit is not None:
        on_exit(client)


@contextlib.contextmanager
def open_compute(
    scheduler: str = "threads",
    workers: int | None = None,
    *,
    progress: bool = True,
    on_exit: Callable[[Any], object] | None = None,
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
    on_exit : callable, optional
        Called when the block ends (also after an exception) with the ``distributed.Client``
        of a ``tcp://`` scheduler or of the local cluster, else with None; e.g.
        :func:`fuse4d.scale.graph.release_engines`, so that long-lived workers (and this
        process, which runs the tasks of the threads and sync schedulers) do not keep an
        idle chunk engine.

    Yields
    ------
    callable
        ``compute(*delayed) -> tuple`` of results; all inputs of one call share the workers.
    """
    check_scheduler(scheduler, workers)
    n = workers or os.cpu_count() or 1
    if scheduler.startswith(SCHEDULER_ADDRESS_SCHEMES):
        with _connect(scheduler) as client:
            warn_if_slow_allocator(client)
            with _on_exit(on_exit, client):
                yield _compute_with(client, progress)
        return
    if scheduler == "processes" and importlib.util.find_spec("distributed") is not None:
        with local_cluster(n) as client, _on_exit(on_exit, client):
            yield _compute_with(client, progress)
        return
    # (no distributed: "processes" is dask's multiprocessing pool)
    from dask.diagnostics import ProgressBar

    def compute(*tasks: Any) -> tuple[Any, ...]:
        bar = ProgressBar(out=sys.stderr) if progress else contextlib.nullcontext()
        with bar:
            return dask.compute(*tasks, scheduler=scheduler, num_workers=n)

    try:
        yield compute
    finally:
        if on_exit is not None:
            on_exit(None)
