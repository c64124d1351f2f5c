"""Background I/O threads (fuse4d._background): lowered to nice 19 once the fusion runs, and
handed back to a normal-priority thread, in order and without losing or repeating an item,
when their consumer finds them starved."""

from __future__ import annotations

import os
import sys
import threading
import time

import numpy as np
import pytest

from conftest import write_ball_folder
from fuse4d import FusionParams, load_sequence
from fuse4d import _background as background
from fuse4d import run as run_module
from fuse4d.io.resume import ResumableFolderWriter
from fuse4d.synthetic import make_falling_ball

linux_only = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="per-thread nice values are Linux's"
)


def _nice() -> int:
    """The calling thread's nice value (Linux: per thread)."""
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


def _timings() -> dict[str, float]:
    return {"read": 0.0, "write": 0.0, "io_wait": 0.0}


@linux_only
def test_starved_writer_hands_over_in_order(monkeypatch):
    """The first jobs are slow (the consumer's wait for room times out): the rest run in a
    new thread of the consumer's priority, every job once, in order."""
    monkeypatch.setattr(background, "STARVED_S", 0.01)
    ran = []
    started = threading.Event()

    def write(i):
        ran.append((i, threading.get_native_id(), _nice()))
        started.set()
        if i < 2:
            time.sleep(0.1)

    sink = run_module._WriteBehind(write, 1, _timings())
    sink.lower_priority()
    assert sink._worker.lowered
    sink.submit(0)
    started.wait(10)  # job 0 runs in the lowered thread before anything can starve
    for i in range(1, 8):
        sink.submit(i)
    sink.close()
    assert [i for i, _, _ in ran] == list(range(8))
    assert sink._worker.promoted
    threads = [tid for _, tid, _ in ran]
    first = threads[0]
    switch = threads.index(next(t for t in threads if t != first))
    assert set(threads[:switch]) == {first}
    assert first not in threads[switch:]
    assert len(set(threads[switch:])) == 1  # one successor
    assert ran[0][2] == background.BACKGROUND_NICE
    assert all(nice == _nice() for _, _, nice in ran[switch:])


@linux_only
def test_starved_read_ahead_hands_over_in_order_and_promotes_its_group(monkeypatch):
    monkeypatch.setattr(background, "STARVED_S", 0.01)
    producers = []

    def frames():
        for i in range(10):
            producers.append(threading.get_native_id())
            if i in (2, 3):
                time.sleep(0.1)
            yield i

    group: list[background.BackgroundLoop] = []
    reader = run_module._ReadAhead(frames(), 2, _timings(), group)
    sink = run_module._WriteBehind(lambda i: None, 2, _timings(), group)
    got = []
    for i in reader:
        got.append(i)
        if i == 1:  # as fuse_file does once the fusion has run
            reader.lower_priority()
            sink.lower_priority()
    reader.close()
    sink.close()
    assert got == list(range(10))  # none lost, none repeated, END once
    assert reader._worker.promoted
    assert sink._worker.promoted  # with the reader: one group
    assert len(set(producers)) == 2


def test_threads_never_lowered_are_never_handed_over(monkeypatch):
    """A slow reader that was not lowered is just slow: one thread throughout."""
    monkeypatch.setattr(background, "STARVED_S", 0.01)
    producers = []

    def frames():
        for i in range(4):
            producers.append(threading.get_native_id())
            time.sleep(0.03)
            yield i

    reader = run_module._ReadAhead(frames(), 1, _timings())
    assert list(reader) == [0, 1, 2, 3]
    reader.close()
    assert not reader._worker.promoted
    assert len(set(producers)) == 1


def test_no_per_thread_nice_outside_linux(monkeypatch):
    """Elsewhere setpriority with a thread id would name a process: nothing is lowered."""
    monkeypatch.setattr(background.sys, "platform", "darwin")
    sink = run_module._WriteBehind(lambda: None, 1, _timings())
    sink.lower_priority()
    assert not sink._worker.lowered
    sink.close()


@linux_only
def test_run_with_every_wait_starved_writes_what_the_inline_run_does(tmp_path, monkeypatch):
    """fuse_file with the I/O lowered after the first frame, a slow writer and every consumer
    wait taken for starvation (the hand-over in the middle of a real run): the same output as
    without threads."""
    src = write_ball_folder(tmp_path / "rec", frames=6)
    params = FusionParams(num_frames=3)
    run_module.fuse_file(src, tmp_path / "inline", fusion=params, io_queue=0)
    promoted = []
    promote = background.BackgroundLoop._promote_one

    def counted(self):
        promoted.append(self.lowered)
        promote(self)

    monkeypatch.setattr(background.BackgroundLoop, "_promote_one", counted)
    write = ResumableFolderWriter.write

    def slow_write(self, *args, **kwargs):  # the fusion waits for room in the queue
        time.sleep(0.02)
        write(self, *args, **kwargs)

    monkeypatch.setattr(ResumableFolderWriter, "write", slow_write)
    monkeypatch.setattr(run_module, "LOWER_AFTER_FRAMES", 1)
    monkeypatch.setattr(background, "STARVED_S", 1e-6)
    run_module.fuse_file(src, tmp_path / "starved", fusion=params, io_queue=1)
    assert True in promoted  # a lowered thread was handed over
    np.testing.assert_array_equal(
        load_sequence(tmp_path / "inline").depth, load_sequence(tmp_path / "starved").depth
    )


@linux_only
def test_writer_promoted_while_waiting_for_a_job_loses_none():
    """Promoted while its queue is empty: the lowered thread hands the job it then takes to
    its successor instead of running it."""
    ran = []
    sink = run_module._WriteBehind(lambda i: ran.append((i, _nice())), 2, _timings())
    sink.lower_priority()
    time.sleep(0.05)  # the writer thread now waits in queue.get()
    sink._worker.promote()
    for i in range(4):
        sink.submit(i)
    sink.close()
    assert ran == [(i, _nice()) for i in range(4)]  # all by the successor, in order


@linux_only
def test_live_writer_lowers_its_thread_once_two_frames_are_fused(tmp_path, monkeypatch):
    from fuse4d import _background
    from fuse4d.fusion import FusedFrame
    from fuse4d.live import CapturedFrame, LiveWriter

    # on a loaded machine (CI beside other work) a wait of STARVED_S promoted the lowered
    # thread again, as it should: not what this test is about
    monkeypatch.setattr(_background, "STARVED_S", 60.0)

    seq = make_falling_ball(small=True, num_frames=3)
    h, w = seq.depth.shape[1:]
    lowered = []
    with LiveWriter(tmp_path / "out", seq.intrinsics, depth_unit_mm=0.05) as writer:
        for t in range(3):
            points = np.zeros((h, w, 3), np.float32)
            points[..., 2] = seq.depth[t]
            no = np.zeros((h, w), bool)
            fused = FusedFrame(t, points, np.zeros((h, w), np.uint8), no, no)
            writer(CapturedFrame(t, seq.depth[t], seq.intensity[t], None, 0.0), fused)
            lowered.append(writer._sink._worker.lowered)
    assert lowered == [False, True, True]
    assert load_sequence(tmp_path / "out").num_frames == 3


def test_ctrl_c_in_the_final_wait_comes_after_the_writes_end():
    """A KeyboardInterrupt in the join of the write-behind thread marked it as ended while a
    write still ran (CPython 3.11), and the caller's abort deleted the staged output under
    it; the signal is now held until the writes are done, then raised."""
    import signal

    done = []

    def write(i):
        time.sleep(0.3)
        done.append(i)

    sink = run_module._WriteBehind(write, 2, _timings())
    sink.submit(0)
    sink.submit(1)
    timer = threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        sink.close()
    assert done == [0, 1]  # both writes had ended when the interrupt was raised


def test_an_interrupt_as_the_signals_are_held_still_waits_and_unblocks(monkeypatch):
    """pthread_sigmask runs the handlers of signals that came just before it: a Ctrl-C there
    raised out of held() with the signals left blocked for good and the wait skipped."""
    import signal

    from fuse4d import _signals

    real = signal.pthread_sigmask
    before = real(signal.SIG_BLOCK, ())

    def sigmask(how, sigs):
        previous = real(how, sigs)
        if how == signal.SIG_BLOCK and sigs:  # the blocking call, after it blocked
            raise KeyboardInterrupt
        return previous

    monkeypatch.setattr(signal, "pthread_sigmask", sigmask)
    ran = []
    with pytest.raises(KeyboardInterrupt), _signals.held():
        ran.append(True)
    monkeypatch.setattr(signal, "pthread_sigmask", real)
    assert ran == [True]  # the wait it protects was done
    assert real(signal.SIG_BLOCK, ()) == before  # nothing left blocked
