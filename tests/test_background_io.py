"""``benchmarks/background_io.py``: the lowered and normal I/O threads of ``fuse4d run``
timed in alternating rounds."""

from __future__ import annotations

import argparse
import sys
import threading

import pytest

from conftest import load_benchmark, write_ball_folder
from fuse4d import _background


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("background_io")


def _lowered_by_lower_priority() -> bool:
    """Whether lower_priority lowers a live BackgroundLoop thread."""
    gate = threading.Event()

    def work(worker: _background.BackgroundLoop) -> None:
        gate.wait()
        worker.done = True

    worker = _background.BackgroundLoop(work, "test")
    worker.lower_priority()
    lowered = worker.lowered
    gate.set()
    worker.join()
    return lowered


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice is Linux's")
def test_normal_mode_never_lowers_and_restores_the_methods(bench):
    loop = _background.BackgroundLoop
    lower, promote_one = loop.lower_priority, loop._promote_one
    with bench.io_priority(False, []):
        assert not _lowered_by_lower_priority()
    assert loop.lower_priority is lower
    assert loop._promote_one is promote_one
    assert _lowered_by_lower_priority()  # as fuse4d runs


def test_compare_times_both_modes_in_each_round(bench, tmp_path):
    rec = write_ball_folder(tmp_path / "rec")
    args = argparse.Namespace(frames=4, window=3, causal=False, rounds=2, load=1)
    result = bench.compare(rec, args, echo=False)
    assert [len(result["ms_per_frame"][m]) for m in bench.MODES] == [2, 2]
    assert result["lowered_over_normal"]["pairs"] == 2
    assert "flow" in result["median_stage_ms"]["lowered"]
    assert result["handovers"]["normal"] == 0  # never lowered: never handed over
