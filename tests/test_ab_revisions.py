"""The summaries of ``benchmarks/ab_revisions.py`` (paired A/B of two revisions' engines)."""

from __future__ import annotations

import math

import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def ab():
    return load_benchmark("ab_revisions")


def test_paired_summary_takes_the_ratio_within_each_pair(ab):
    # the machine drifts by 2x between pairs; within each pair new is 10 % faster
    base = [40.0, 80.0, 41.0, 79.0, 60.0]
    new = [36.0, 72.0, 36.9, 71.1, 54.0]
    s = ab.paired_summary(base, new)
    assert s["ratio_median"] == pytest.approx(0.9)
    assert s["ratio_low"] == pytest.approx(0.9)
    assert s["ratio_high"] == pytest.approx(0.9)
    assert s["new_faster"] == 5
    assert s["pairs"] == 5
    assert s["base_median_ms"] == 60.0
    assert s["new_median_ms"] == 54.0


def test_stage_summary_shows_the_one_stage_that_changed(ab):
    base = [{"flow": 8.0 * k, "fill": 2.0 * k, "io": 0.0} for k in (1.0, 1.5, 1.2)]
    new = [{"flow": 8.0 * k, "fill": 1.0 * k, "io": 0.0} for k in (1.0, 1.5, 1.2)]
    s = ab.stage_summary(base, new)
    assert s["flow"]["ratio_median"] == pytest.approx(1.0)
    assert s["fill"]["ratio_median"] == pytest.approx(0.5)
    assert s["fill"]["base_median_ms"] == pytest.approx(2.4)
    assert math.isnan(s["io"]["ratio_median"])  # never timed: no ratio


def test_stage_summary_keeps_the_stages_both_sides_timed(ab):
    base = [{"flow": 1.0, "old_stage": 1.0}]
    new = [{"flow": 1.0, "new_stage": 1.0}]
    assert list(ab.stage_summary(base, new)) == ["flow"]
