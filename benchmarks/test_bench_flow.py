"""Flow-stage speed benchmarks (pytest-benchmark): one 600x600 synthetic-ball pair per method.

Run::

    python -m pytest benchmarks/test_bench_flow.py --benchmark-enable -q

Accuracy on real and synthetic ground truth is ``fuse4d bench-flow`` (EPE / AAE / ms table).
The slow methods (TV-L1, PMBP) run one round only. ``extra_info`` records the ball-interior EPE.
"""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d.experiments.flow_accuracy import ball_pairs
from fuse4d.flow import DISParams, available_flow_methods, estimate_flow, estimate_flow_pair

CASES = [
    ("dis-ultrafast", "dis", DISParams.from_preset("ultrafast")),
    ("dis-fast", "dis", DISParams.from_preset("fast")),
    ("dis-medium", "dis", DISParams.from_preset("medium")),
    ("farneback", "farneback", None),
    ("deepflow", "deepflow", None),
    ("tvl1", "tvl1", None),
    ("pmbp-fast", "pmbp-fast", None),
    ("pmbp", "pmbp", None),
]
SLOW = {"tvl1", "pmbp", "pmbp-fast"}


@pytest.fixture(scope="module")
def ball_pair():
    return ball_pairs(intensity_noise=0.02)[1]  # frames (25, 26), 600x600


@pytest.mark.parametrize(("label", "method", "params"), CASES, ids=[c[0] for c in CASES])
def test_flow_600(benchmark, ball_pair, label, method, params):
    if method not in available_flow_methods():
        pytest.skip(f"{method} not registered")
    pair = ball_pair
    estimate_flow(pair.image0[:64, :64], pair.image1[:64, :64], method=method, params=params)

    def run():
        return estimate_flow(pair.image0, pair.image1, method=method, params=params)

    flow = benchmark.pedantic(run, rounds=1, iterations=1) if label in SLOW else benchmark(run)
    err = np.hypot(*(flow - pair.flow_true)[pair.mask].T).mean()
    benchmark.extra_info["epe_ball_interior_px"] = float(err)


def test_dis_pair_forward_backward_600(benchmark, ball_pair):
    """What the fusion engine pays per frame with the ``fast`` preset (both directions)."""
    pair = ball_pair
    benchmark(lambda: estimate_flow_pair(pair.image0, pair.image1, method="dis"))
