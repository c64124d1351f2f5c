"""Background I/O threads that leave the cores to the fusion (issue 13). Private.

``fuse4d run`` decodes frames ahead of the fusion and encodes them behind it, in two threads
(:class:`fuse4d.run._ReadAhead`, :class:`fuse4d.run._WriteBehind`); ``fuse4d live`` writes
behind it the same way. That work (about 12 ms of CPU per 640x480 frame of
``uva_cv2_person_turning`` on the 2-core dev machine) can happen at any moment. The fusion's
numba kernels split each image between all cores and wait for the slowest share, so an I/O
thread that takes a core in the middle of a kernel stalls the whole kernel; yet the fusion
leaves a core idle a third of the time (its serial steps, the gaps in OpenCV's flow: CPU time
1.65x the wall time on uva).

So once the fusion runs, each I/O thread is moved to nice 19 (:meth:`BackgroundLoop.
lower_priority`; Linux, where nice is a per-thread value; elsewhere nothing changes): the
scheduler then runs it when a core is free and gives the core back when a kernel's threads
wake. Not at start: a thread inherits its creator's nice value, and the pools that the
fusion shares (OpenCV's workers, started by its first parallel call) must be started by the
fusion's own threads, not by a lowered one.

The catch is other programs: a nice-19 thread gets about 1.5 % of a core that a
normal-priority process wants, so on a machine kept busy by other work the I/O would starve
and the run with it (measured beside two busy loops on the 2 cores: 213 -> 464 ms a frame;
SCHED_IDLE, 0.3 %, is worse: 3.1 s). An unprivileged thread cannot raise its priority again
(``RLIMIT_NICE``), so a consumer that has waited :data:`STARVED_S` for an item
(:meth:`BackgroundLoop.wait`) calls :meth:`BackgroundLoop.promote`: the rest of the loop (and of the run's other I/O loop) moves
to a new thread, created by the consumer and so of its priority, which takes over once the
lowered thread has finished its current item. From then on the run behaves as if this module
did not exist.

Measured (stop 50; ``fuse4d run``'s streaming path on ``uva_cv2_person_turning``, the I/O
lowered or not in alternating rounds of one process, 2-core machine). With the flow in the
fusion thread: centred window 9, 30 frames, median per-round ratios 0.988 and 0.970 in two
sittings; causal window 3, 40 frames, 0.955; SCHED_IDLE instead of nice 19 the same (0.967).
With the flow overlapped, as ``fuse4d run`` computes it since (``python
benchmarks/background_io.py``): centred 9 94.1 -> 91.4 ms a frame (0.971, lowered faster in
6 of 6 rounds), causal 3 0.990; beside two busy loops on the two cores (``--load 2``, 40
frames) 199.9 -> 204.9 (1.025, every run handed over: the price of the lowered threads' last
items under load).
"""

from __future__ import annotations

import os
import queue
import sys
import threading
from collections.abc import Callable
from typing import TypeVar

__all__ = ["BACKGROUND_NICE", "LOWER_AFTER_FRAMES", "STARVED_S", "BackgroundLoop"]

T = TypeVar("T")

#: Nice value of a lowered background thread (the lowest priority of the normal policy).
BACKGROUND_NICE = 19
#: The I/O threads of a run are lowered once the fusion has taken this many frames: by then it
#: has run every stage, its flow included, so the thread pools it shares (OpenCV's workers)
#: were started by its own threads (fusion or flow worker), not by a lowered one.
LOWER_AFTER_FRAMES = 2
#: A consumer that waited this long (s) for a lowered thread hands its loop to a normal one
#: (about half a frame of the fast preset at 640 x 480; the waits of a run that is not starved
#: are under 2 ms a frame).
STARVED_S = 0.05


def _set_thread_nice(native_id: int, nice: int) -> bool:
    """Set the nice value of one thread (Linux only: ``setpriority`` with a thread id sets that
    thread's; elsewhere it would name a process). True if it was set."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        os.setpriority(os.PRIO_PROCESS, native_id, nice)
    except OSError:
        return False
    return True


class BackgroundLoop:
    """``loop(self)`` in a daemon thread that can be lowered to nice 19 and, if it starves,
    handed to a thread of normal priority.

    ``loop`` does its work one item at a time. Between items it returns as soon as
    :meth:`handing_over` is True, leaving its state where a new call resumes; before it
    returns for good (work done, stopped or failed) it sets :attr:`done`. After a
    :meth:`promote`, ``loop`` is called again in the new thread once the first has ended, so
    at most one thread runs it at any time and items keep their order.

    Parameters
    ----------
    loop : callable
        The work, called with this object.
    name : str
        Name of the thread(s).
    group : list of BackgroundLoop, optional
        The loops of one run (this one is added): a starved one promotes them all, since what
        starves one (other programs' load) will starve the others.
    """

    def __init__(
        self,
        loop: Callable[[BackgroundLoop], None],
        name: str,
        group: list[BackgroundLoop] | None = None,
    ) -> None:
        self._loop = loop
        self._name = name
        self._group = [self] if group is None else group
        if group is not None:
            group.append(self)
        #: set by ``loop`` when it has returned for good
        self.done = False
        self._lowered: threading.Thread | None = None
        self._promoted = False
        self._thread = threading.Thread(target=loop, args=(self,), name=name, daemon=True)
        self._thread.start()

    @property
    def lowered(self) -> bool:
        """Whether the thread was lowered to :data:`BACKGROUND_NICE` (and not yet promoted)."""
        return self._lowered is not None and not self._promoted

    @property
    def promoted(self) -> bool:
        """Whether a starved loop was handed to a normal-priority thread."""
        return self._promoted

    def lower_priority(self) -> None:
        """Move the thread to nice :data:`BACKGROUND_NICE` (once; Linux only).

        Call it from the consumer once the compute's shared thread pools exist (threads
        inherit their creator's nice value)."""
        if self._lowered is not None or self.done:
            return
        native = self._thread.native_id
        if native is not None and _set_thread_nice(native, BACKGROUND_NICE):
            self._lowered = self._thread

    def handing_over(self) -> bool:
        """True in the lowered thread once :meth:`promote` was called: ``loop`` must return."""
        return self._promoted and threading.current_thread() is self._lowered

    def promote(self) -> None:
        """Hand the rest of this loop and of its group to new threads of the caller's
        priority (loops never lowered, already promoted or done are left). Call it from the
        consumer."""
        for loop in self._group:
            loop._promote_one()

    def _promote_one(self) -> None:
        if self._lowered is None or self._promoted or self.done:
            return
        self._promoted = True
        first = self._thread

        def take_over() -> None:
            first.join()
            if not self.done:
                self._loop(self)

        self._thread = threading.Thread(target=take_over, name=self._name, daemon=True)
        self._thread.start()

    def wait(self, queue_op: Callable[[float | None], T]) -> T:
        """``queue_op(timeout)``: a consumer's get from or put to this loop's queue (raising
        ``queue.Empty`` / ``queue.Full`` when the timeout passes); one that waits more than
        :data:`STARVED_S` promotes the loop (:meth:`promote`) and then waits on."""
        try:
            return queue_op(STARVED_S)
        except (queue.Empty, queue.Full):
            self.promote()  # starved by other programs (if lowered)
            return queue_op(None)

    def join(self) -> None:
        """Wait until the loop has returned for good (call it from the consumer)."""
        self._thread.join()
