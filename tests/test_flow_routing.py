"""The fusion reaches flows through the public estimator: cache and ROI from every entry point,
and one way to hand precomputed flows in (REVIEW §1.4.2-1.4.4)."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d import FlowConfig, FusionEngine, FusionParams, fuse_sequence, load_sequence
from fuse4d.cli import main
from fuse4d.flow import FlowCache, SequenceFlow, estimate_sequence_flow
from fuse4d.synthetic import make_falling_ball

PARAMS = FusionParams(num_frames=3)


@pytest.fixture(scope="module")
def ball():
    return make_falling_ball(small=True, num_frames=4)


def _cache_files(folder):
    return sorted(folder.glob("??/*.npy"))


def test_fuse_sequence_fills_and_reuses_the_flow_cache(ball, tmp_path):
    flow = FlowConfig("dis", cache_dir=str(tmp_path / "cache"))
    first = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=PARAMS, flow=flow)
    files = _cache_files(tmp_path / "cache")
    assert len(files) == ball.num_frames - 1  # one entry per pair (forward + backward)
    # a second run reads the cache: poison nothing, but check the flows come back identical
    mtimes = [f.stat().st_mtime_ns for f in files]
    second = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=PARAMS, flow=flow)
    assert [f.stat().st_mtime_ns for f in _cache_files(tmp_path / "cache")] == mtimes
    np.testing.assert_array_equal(first.depth, second.depth)
    np.testing.assert_array_equal(first.flow_forward, second.flow_forward)


def test_engine_uses_the_cache_entries(ball, tmp_path):
    """A cached (here: doctored) entry is what the engine tracks with: proof it is read."""
    flow = FlowConfig("dis", cache_dir=str(tmp_path / "c"))
    fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=PARAMS, flow=flow)
    cache = FlowCache(tmp_path / "c")
    for path in _cache_files(tmp_path / "c"):
        cache.store(path.stem, np.full_like(np.load(path), 0.25))
    engine = FusionEngine(ball.intrinsics, fusion=PARAMS, flow=flow)
    pairs = []
    engine.on_pair = lambda pair: pairs.append(pair.forward)
    for t in range(ball.num_frames):
        engine.push(ball.depth[t], ball.intensity[t])
    engine.flush()
    assert len(pairs) == ball.num_frames - 1
    assert np.all(pairs[0] == 0.25)  # read from the cache
    # the key covers the warm start (the doctored flow), so later pairs are solved afresh
    assert not np.all(pairs[1] == 0.25)


def test_flow_roi_reaches_the_tracker(ball):
    roi = (10, 60, 20, 90)
    res = fuse_sequence(
        ball.depth, ball.intensity, ball.intrinsics, fusion=PARAMS, flow=FlowConfig("dis", roi=roi)
    )
    outside = np.ones(ball.depth.shape[1:], bool)
    outside[roi[0] : roi[1], roi[2] : roi[3]] = False
    assert np.all(res.flow_forward[:, outside] == 0)
    assert np.any(res.flow_forward[:, ~outside] != 0)


@pytest.mark.parametrize("form", ["sequence_flow", "estimated", "tuple", "list"])
def test_every_form_of_precomputed_flow_works(ball, form):
    est = estimate_sequence_flow(ball.intensity, method="dis")
    flow = {
        "sequence_flow": SequenceFlow(est.forward, est.backward),
        "estimated": est,
        "tuple": (est.forward, est.backward),
        "list": [est.forward, est.backward],
    }[form]
    res = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=PARAMS, flow=flow)
    ref = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=PARAMS)
    np.testing.assert_array_equal(res.flow_forward, est.forward)
    # the estimator's warm starts are the engine's: same flows, same fused depth
    np.testing.assert_array_equal(res.depth, ref.depth)
    assert res.flow_method == ("dis" if form == "estimated" else "precomputed")


def test_engine_accepts_precomputed_flows(ball):
    est = estimate_sequence_flow(ball.intensity, method="dis")
    engine = FusionEngine(ball.intrinsics, fusion=PARAMS, flow=est)
    out = []
    for t in range(ball.num_frames):
        out += engine.push(ball.depth[t], ball.intensity[t])
    out += engine.flush()
    ref = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=PARAMS, flow=est)
    np.testing.assert_array_equal(np.stack([f.depth for f in out]), ref.depth)


def test_bad_flow_objects_give_clear_errors(ball):
    with pytest.raises(TypeError, match="precomputed flows must be a SequenceFlow"):
        fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, flow=42)
    with pytest.raises(TypeError, match="precomputed flows must be a SequenceFlow"):
        FusionEngine(ball.intrinsics, flow=np.zeros(3))


def test_forward_flows_alone_are_a_fuse4d_error(ball):
    """flow=<the forward array only> was a bare TypeError (reported by the CLI as an internal
    error); now a ParameterTypeError naming the argument and the pair it wants."""
    from fuse4d.errors import ParameterTypeError

    forward = estimate_sequence_flow(ball.intensity, method="dis").forward
    with pytest.raises(ParameterTypeError, match=r"^flow: .*\(forward, backward\) pair") as info:
        fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, flow=forward)
    assert f"one array of shape {forward.shape} (pass the backward flows too)" in str(info.value)


def test_cli_flow_cache_and_roi(ball, tmp_path, capsys):
    src = tmp_path / "ball.npz"
    assert main(["synth", "ball", "--small", "--frames", "4", "-o", str(src)]) == 0
    cache = tmp_path / "cache"
    args = ["run", str(src), "--window", "3", "--flow-cache", str(cache), "--json"]
    assert main([*args, "-o", str(tmp_path / "a.npz")]) == 0
    assert len(_cache_files(cache)) == 3
    assert main([*args, "-o", str(tmp_path / "b.npz")]) == 0
    a = load_sequence(tmp_path / "a.npz").depth
    b = load_sequence(tmp_path / "b.npz").depth
    np.testing.assert_array_equal(a, b)
    capsys.readouterr()
    bad = ["run", str(src), "-o", str(tmp_path / "c.npz"), "--flow-roi", "1,2,3"]
    assert main(bad) == 2
    assert "--flow-roi must be R0:R1,C0:C1 or ROW0,ROW1,COL0,COL1" in capsys.readouterr().err


def test_cli_flow_roi_takes_the_roi_syntax_of_report_and_metrics():
    """``--flow-roi 10:60,20:90`` (the ``--roi`` syntax of report and metrics) was refused;
    the config's R0,R1,C0,C1 still works."""
    from fuse4d.cli.cmd_fuse import _resolve

    for roi in ("10:60,20:90", "10,60,20,90", "10, 60, 20, 90"):
        _, flow, _ = _resolve("fast", None, None, False, None, None, None, flow_roi=roi)
        assert flow.roi == (10, 60, 20, 90)


def test_cli_flow_param_on_optional_field(tmp_path, capsys):
    """``--flow pmbp --flow-param coarse_num_iter=3`` used to fail ("must be an integer")."""
    src = tmp_path / "ball.npz"
    assert main(["synth", "ball", "--small", "--frames", "2", "-o", str(src)]) == 0
    args = ["run", str(src), "-o", str(tmp_path / "o.npz"), "--window", "2", "--json"]
    flow_args = ["--flow", "pmbp-fast", "--flow-param", "coarse_num_iter=1"]
    assert main([*args, *flow_args, "--flow-param", "num_iter=1"]) == 0
