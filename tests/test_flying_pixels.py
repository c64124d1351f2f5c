"""ToF flying pixels (A36, issue 10): the test, its oracle, and fusion that leaves them out.

* the numba kernel equals the NumPy oracle (``tests/naive/flying_pixels.py``);
* on the ToF model it finds most pixels far off the truth and takes (almost) no good pixel;
  on structured-light depth (staircase steps) and the paper's ball (steep sphere rim) it
  finds (almost) nothing;
* the engine removes them before fusing, flags them ``SOURCE_REJECTED`` and never fills them;
  "auto" follows the input's sensor kind (a ToF scene, an Azure Kinect recording).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fuse4d import FusionParams, Intrinsics, fuse_sequence
from fuse4d.flying_pixels import (
    FLYING_ISOLATION,
    FLYING_MAX_ANGLE_DEG,
    FLYING_MIN_JUMP,
    flying_pixel_mask,
    resolve_flying_pixels,
)
from fuse4d.holes import SOURCE_REJECTED
from fuse4d.io import load_sequence, open_frames, read_npz_extra, write_npz
from fuse4d.motion import estimate_noise_quad
from fuse4d.range_scenes import make_range_scene
from fuse4d.synthetic import make_falling_ball
from naive.flying_pixels import flying_pixel_mask as naive_flying_pixel_mask


@pytest.fixture(scope="module")
def tof_body():
    return make_range_scene("body", sensor="tof", small=True, num_frames=6, rng=0)


def _errors(seq):
    return np.abs(seq.depth - seq.ground_truth.depth)


def test_kernel_equals_the_oracle(tof_body):
    seq = tof_body
    for depth in seq.depth[:3]:
        expected = naive_flying_pixel_mask(
            depth,
            seq.intrinsics,
            max_angle_deg=FLYING_MAX_ANGLE_DEG,
            jump_quad=FLYING_MIN_JUMP * estimate_noise_quad(depth),
            isolation=FLYING_ISOLATION,
        )
        got = flying_pixel_mask(depth, seq.intrinsics)
        assert expected.sum() > 50  # the scene has flying pixels to find
        np.testing.assert_array_equal(got, expected)


def test_kernel_equals_the_oracle_on_random_steps():
    rng = np.random.default_rng(3)
    k = Intrinsics(fx=200.0, fy=200.0, cx=20.0, cy=15.0, width=40, height=30)
    depth = rng.choice([1000.0, 1300.0, 2000.0], size=(30, 40)).astype(np.float32)
    depth += rng.normal(0, 40, depth.shape).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    got = flying_pixel_mask(depth, k, quad=1e-6)
    expected = naive_flying_pixel_mask(
        depth, k, max_angle_deg=FLYING_MAX_ANGLE_DEG, jump_quad=FLYING_MIN_JUMP * 1e-6,
        isolation=FLYING_ISOLATION,
    )  # fmt: skip
    assert expected.any()
    np.testing.assert_array_equal(got, expected)
    assert not got[np.isnan(depth)].any()


@pytest.mark.parametrize("scene", ["ball", "body"])
def test_finds_the_far_off_pixels_of_the_tof_model_and_few_good_ones(scene):
    seq = make_range_scene(scene, sensor="tof", small=True, num_frames=3, rng=0)
    found = np.stack([flying_pixel_mask(d, seq.intrinsics) for d in seq.depth])
    err = _errors(seq)
    far_off = err > 100
    good = err < 20
    assert far_off.sum() > 50
    # 160 x 120: limbs a few px wide, where flying pixels touch (640 x 480: 94-97 %, A36)
    assert (found & far_off).sum() >= 0.75 * far_off.sum()
    assert (found & good).sum() <= 1e-4 * good.sum()


@pytest.mark.parametrize(
    "seq",
    [
        pytest.param(lambda: make_range_scene("body", sensor="kinect", small=True,
                                              num_frames=2, rng=0), id="kinect-body"),
        pytest.param(lambda: make_range_scene("room", sensor="kinect", small=True,
                                              num_frames=2, rng=0), id="kinect-room"),
        pytest.param(lambda: make_falling_ball(small=True, num_frames=2, rng=0), id="paper-ball"),
    ],
)  # fmt: skip
def test_staircases_and_steep_rims_are_not_flying_pixels(seq):
    seq = seq()
    found = np.stack([flying_pixel_mask(d, seq.intrinsics) for d in seq.depth])
    assert found.sum() <= 2e-4 * np.isfinite(seq.depth).sum()


def test_mixed_pixel_between_two_planes_and_not_a_slanted_plane():
    k = Intrinsics(fx=500.0, fy=500.0, cx=3.5, cy=0.0, width=8, height=1)
    edge = np.array([[1000, 1000, 1000, 1000, 1600, 2000, 2000, 2000]], np.float32)
    assert np.flatnonzero(flying_pixel_mask(edge, k)).tolist() == [4]
    slanted = np.linspace(1000, 1100, 8, dtype=np.float32)[None]  # 14 mm / px at 2 mm / px
    assert not flying_pixel_mask(slanted, k).any()
    with pytest.raises(ValueError, match="max_angle_deg"):
        flying_pixel_mask(edge, k, max_angle_deg=90)


def test_resolve_follows_the_sensor_kind_unless_set():
    auto = FusionParams()
    assert auto.flying_pixels == "auto"
    assert resolve_flying_pixels(auto, "tof").flying_pixels == "on"
    assert resolve_flying_pixels(auto, "structured-light").flying_pixels == "off"
    assert resolve_flying_pixels(auto, None).flying_pixels == "off"
    off = FusionParams(flying_pixels="off")
    assert resolve_flying_pixels(off, "tof") is off


def test_fusion_leaves_flying_pixels_empty_and_flagged(tof_body):
    seq = tof_body
    fill_all = FusionParams(fill_holes=True, fill_from_time=True, fill_max_hole_px=1000)
    on = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics,
                       fusion=fill_all.replace(flying_pixels="on"))  # fmt: skip
    found = np.stack([flying_pixel_mask(d, seq.intrinsics) for d in seq.depth])
    rejected = on.source == SOURCE_REJECTED
    np.testing.assert_array_equal(rejected, found)
    assert np.isnan(on.depth[rejected]).all()
    assert (on.confidence[rejected] == 0).all()
    assert on.params.flying_pixels == "on"
    # the sensor kind decides "auto" the same way
    auto = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=fill_all,
                         sensor=seq.sensor)  # fmt: skip
    np.testing.assert_array_equal(auto.depth, on.depth)


def test_removing_them_brings_the_tof_object_closer_to_the_truth(tof_body):
    seq = tof_body
    truth, obj = seq.ground_truth.depth, seq.ground_truth.mask
    rmse = {}
    for mode in ("off", "on"):
        out = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics,
                            fusion=FusionParams(flying_pixels=mode)).depth  # fmt: skip
        scored = obj & np.isfinite(out)
        rmse[mode] = float(np.sqrt(np.mean((out[scored] - truth[scored]) ** 2)))
        if mode == "on":  # what is scored: all but the removed pixels
            assert scored.sum() >= 0.9 * (obj & np.isfinite(seq.depth)).sum()
    # 160 x 120 (a 20-px ball; flying pixels side by side escape test 4): 0.71x; the full
    # 640 x 480 scenes 0.28x / 0.33x (benchmarks/real_sensors.py, A36)
    assert rmse["on"] < 0.85 * rmse["off"]


def test_sensor_kind_travels_through_npz_and_scenes(tmp_path, tof_body):
    assert tof_body.sensor == "tof"
    assert make_range_scene("ball", sensor="kinect", small=True, num_frames=2).sensor == (
        "structured-light"
    )
    path = tmp_path / "tof.npz"
    write_npz(tof_body, path)
    assert load_sequence(path).sensor == "tof"
    with open_frames(path) as reader:
        assert reader.sensor == "tof"


@pytest.mark.realdata
def test_azure_kinect_recording_is_tof_and_has_a_few_flying_pixels(shared_data):
    path = shared_data / "sensor_recordings" / "azure_kinect_recording.mkv"
    if not path.is_file():
        pytest.skip(f"not found: {path}")
    with open_frames(path) as reader:
        assert reader.sensor == "tof"
        depth = reader[0].depth
        found = flying_pixel_mask(depth, reader.intrinsics)
    valid = np.isfinite(depth)
    # the Azure Kinect's depth engine drops most mixed pixels itself; some stay (the table's
    # back edge, the box on it): 199 of 323 k valid pixels when measured (A36)
    assert 0 < found.sum() < 1e-3 * valid.sum()


def test_cli_info_and_run_on_a_tof_scene(tmp_path, tof_body, capsys):
    from fuse4d.cli import main

    path = tmp_path / "tof.npz"
    write_npz(tof_body, path)
    assert main(["info", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["sensor"] == "tof"
    assert main(["run", str(path), "-o", str(tmp_path / "out.npz"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["params"]["flying_pixels"] == "on"
    assert 0.001 < summary["rejected_fraction"] < 0.02
    # the summary's sensor-hole row: the same counts as the written source codes
    source = read_npz_extra(tmp_path / "out.npz")["source"]
    holes = np.isnan(tof_body.depth)
    outside = source == 6  # A38: beyond the field of view, never filled
    assert summary["hole_fraction"] == pytest.approx(holes.mean())
    assert summary["hole_outside_fraction"] == pytest.approx(outside.sum() / holes.sum())
    inside = (holes & ~outside).sum()
    assert summary["hole_time_fraction"] == pytest.approx((source == 3).sum() / inside)
    assert summary["hole_space_fraction"] == pytest.approx((source == 4).sum() / inside)
    assert summary["hole_time_fraction"] + summary["hole_space_fraction"] > 0.5
    off = ["--set", "flying_pixels=off", "--json"]
    assert main(["run", str(path), "-o", str(tmp_path / "off.npz"), *off]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["params"]["flying_pixels"] == "off"
    assert summary["rejected_fraction"] == 0


def test_rejected_pixels_are_flagged_in_a_zarr_output(tmp_path, tof_body, capsys):
    """A frame folder says nothing about its camera: --set flying_pixels=on; the zarr output
    holds the per-pixel source codes (5 = rejected) and confidence beside the depth."""
    import zarr

    from fuse4d.cli import main
    from fuse4d.io import FrameFolderWriter

    src = tmp_path / "tof"
    with FrameFolderWriter(src, tof_body.intrinsics) as writer:
        for d, i in zip(tof_body.depth, tof_body.intensity, strict=True):
            writer.write(d, i)
    with open_frames(src) as reader:
        assert reader.sensor is None
    out = tmp_path / "out.zarr"
    args = ["run", str(src), "-o", str(out), "--set", "flying_pixels=on", "--json"]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["rejected_fraction"] > 0.001
    store = zarr.open_group(str(out), mode="r")
    source, confidence, depth = store["source"][:], store["confidence"][:], store["depth"][:]
    raw = load_sequence(src).depth
    found = np.stack([flying_pixel_mask(d, tof_body.intrinsics) for d in raw])
    np.testing.assert_array_equal(source == SOURCE_REJECTED, found)
    assert np.isnan(depth[found]).all()
    assert (confidence[found] == 0).all()


def test_dask_chunks_reject_the_same_pixels_as_one_engine(tof_body):
    """The dask graph's chunk engines (halo frames pushed with a neighbour's frame state)
    remove the same flying pixels and give the same output as one streaming engine."""
    pytest.importorskip("dask.array")
    import dask

    import fuse4d.dask as fd

    seq = tof_body
    params = FusionParams(flying_pixels="on", num_frames=5)
    ref = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=params)
    res = fd.fuse(seq.depth, seq.intensity, seq.intrinsics, fusion=params, chunk_frames=2)
    depth, source = dask.compute(res.depth, res.source, scheduler="synchronous")
    np.testing.assert_array_equal(source, ref.source)
    assert (source == SOURCE_REJECTED).sum() > 50
    np.testing.assert_array_equal(depth, ref.depth)  # NaN where NaN, bit for bit elsewhere
