"""Fusion-pipeline speed benchmarks (pytest-benchmark) at 600x600 with a 9-frame window.

Run::

    python -m pytest benchmarks/test_bench_fusion.py --benchmark-enable -q

``fuse4d bench`` gives the same per-stage breakdown from the streaming engine, plus peak RSS.
"""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d import FusionEngine, FusionParams, depth_to_points, preset
from fuse4d.bilateral import bilateral_filter_points
from fuse4d.motion import motion_reference_depth
from fuse4d.synthetic import make_falling_ball


@pytest.fixture(scope="module")
def ball():
    return make_falling_ball(num_frames=18)


def test_bilateral_600(benchmark, ball):
    points = depth_to_points(ball.depth[0], ball.intrinsics)
    ref = depth_to_points(motion_reference_depth(ball.depth[0], sigma=3.0), ball.intrinsics)
    benchmark(bilateral_filter_points, points, ball.intensity[0], reference=ref)


def test_motion_reference_600(benchmark, ball):
    benchmark(motion_reference_depth, ball.depth[0], sigma=3.0)


@pytest.mark.parametrize("name", ["fast"])
def test_engine_per_frame_600(benchmark, ball, name):
    chosen = preset(name)
    frames = list(zip(ball.depth, ball.intensity, strict=True))
    engine = FusionEngine(ball.intrinsics, fusion=FusionParams(), flow=chosen.flow)
    for depth, intensity in frames[:9]:  # fill the window (and compile)
        engine.push(depth, intensity)
    state = {"k": 9}

    def one_frame():
        depth, intensity = frames[state["k"] % len(frames)]
        state["k"] += 1
        return engine.push(depth, intensity)

    out = benchmark.pedantic(one_frame, rounds=8, iterations=1)
    assert len(out) == 1
    assert np.isfinite(out[0].depth).mean() > 0.9
