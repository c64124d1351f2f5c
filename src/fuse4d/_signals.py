"""Whether the user interrupted this command (Ctrl-C, SIGTERM, SIGHUP).

One flag for the CLI and the code that handles signals itself (``fuse4d live``): an
interrupt raised inside numba's compiler (a ctypes callback) surfaces as another error, and
the CLI tells it from a bug by this flag.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Iterator

__all__ = ["INTERRUPTED"]

#: Set by a signal handler; cleared by :func:`fuse4d.cli.main` at the start of each command.
INTERRUPTED = threading.Event()

#: Seconds within which the same signal again is taken for the first one delivered twice, not
#: a second Ctrl-C: GNU ``timeout -s INT`` sends it to the process and then to its process
#: group a few ms apart (which read as "abort at once"), and no person presses Ctrl-C twice
#: that fast to mean it.
ECHO_S = 0.2

_last: tuple[int, float] | None = None  # the last signal counted: number, time.monotonic()


def is_echo(signum: int) -> bool:
    """Note signal ``signum`` received now; True when it only repeats the last one counted
    (the same signal within :data:`ECHO_S` of it): the handler then ignores it.

    Shared by every handler of fuse4d (the CLI's, ``fuse4d live``'s), so an echo that arrives
    after one handler has handed over to another is still an echo. The time is when the
    handler runs: two presses made while the main thread was inside a long C call may read
    as one."""
    global _last
    now = time.monotonic()
    if _last is not None and _last[0] == signum and now - _last[1] < ECHO_S:
        return True
    _last = (signum, now)
    return False


def reset() -> None:
    """Forget earlier signals (:func:`fuse4d.cli.main`, at the start of each command)."""
    global _last
    _last = None
    INTERRUPTED.clear()


@contextlib.contextmanager
def held() -> Iterator[None]:
    """Hold Ctrl-C, SIGTERM and SIGHUP back while the main thread waits for a writer
    thread (``fuse4d live``'s, ``fuse4d run``'s write-behind); one that came is handled when
    the wait is over. A KeyboardInterrupt in ``Thread.join`` marks the thread as ended while
    it still runs (CPython 3.11): the staged output was then deleted under a write still in
    progress, which made its folders again (zarr), and a temporary was left. Main thread,
    POSIX only (elsewhere nothing is held)."""
    names = ("SIGINT", "SIGTERM", "SIGHUP")
    sigs = {getattr(signal, n) for n in names if hasattr(signal, n)}
    if threading.current_thread() is not threading.main_thread() or not hasattr(
        signal, "pthread_sigmask"
    ):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, ())  # the mask now, unchanged
    pending: KeyboardInterrupt | None = None
    try:
        try:
            # (the call runs the Python handlers of signals that came just before it: an
            # interrupt raised here would skip the wait; it is raised after it instead)
            signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
        except KeyboardInterrupt as exc:
            pending = exc
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
    if pending is not None:
        raise pending
