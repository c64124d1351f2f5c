"""Whether the user interrupted this command (Ctrl-C, SIGTERM, SIGHUP).

One flag for the CLI and the code that handles signals itself (``fuse4d live``): an
interrupt raised inside numba's compiler (a ctypes callback) surfaces as another error, and
the CLI tells it from a bug by this flag.
"""

from __future__ import annotations

import threading
import time

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
