"""Decimation (fuse4d.decimate, ``fuse4d live --decimate``): the RealSense decimation filter's
block rule, checked against a numpy oracle and against ``rs.decimation_filter`` itself."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from fuse4d import FusionParams, Sequence, depth_to_points, fuse_sequence
from fuse4d.camera import Intrinsics
from fuse4d.cli import main
from fuse4d.decimate import (
    decimate_depth,
    decimate_intensity,
    decimate_intrinsics,
    decimate_mask,
)
from fuse4d.io import load_sequence, write_npz
from fuse4d.synthetic import make_scene

K = Intrinsics(fx=60.0, fy=61.0, cx=31.5, cy=23.0, width=64, height=47)


def _blocks(a: np.ndarray, f: int) -> np.ndarray:
    h, w = a.shape[0] // f, a.shape[1] // f
    return a[: h * f, : w * f].reshape(h, f, w, f).transpose(0, 2, 1, 3).reshape(h, w, f * f)


def _oracle(depth: np.ndarray, f: int) -> np.ndarray:
    """Lower median (f <= 3) or mean (f >= 4) of each block's finite values, NaN if none."""
    b = _blocks(depth.astype(np.float64), f)
    n = np.isfinite(b).sum(-1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        if f >= 4:
            return np.nanmean(b, -1)
    ordered = np.sort(b, -1)  # NaN last
    lower = np.take_along_axis(ordered, np.maximum((n - 1) // 2, 0)[..., None], -1)[..., 0]
    return np.where(n > 0, lower, np.nan)


@pytest.mark.parametrize("factor", [2, 3, 4, 5, 8])
def test_depth_is_the_blocks_lower_median_or_mean_of_valid_depths(factor):
    rng = np.random.default_rng(factor)
    depth = rng.uniform(500, 4000, (K.height, K.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.4] = np.nan
    depth[:factor, :factor] = np.nan  # one block without any valid depth
    out = decimate_depth(depth, factor)
    assert out.shape == (K.height // factor, K.width // factor)
    assert out.dtype == np.float32
    assert np.isnan(out[0, 0])
    np.testing.assert_allclose(out, _oracle(depth, factor), rtol=1e-6, equal_nan=True)
    if factor <= 3:  # a median is one of the block's own depths (no value across an edge)
        ok = np.isfinite(out)
        members = _blocks(depth, factor)[ok]
        assert (members == out[ok][:, None]).any(axis=1).all()


def test_factor_one_is_a_copy_and_bad_factors_are_refused():
    depth = np.full((4, 6), 1000.0, np.float32)
    out = decimate_depth(depth, 1)
    np.testing.assert_array_equal(out, depth)
    assert out is not depth
    for bad in (0, 9, 1.5, True):
        with pytest.raises(ValueError, match="decimation factor"):
            decimate_depth(depth, bad)
    with pytest.raises(ValueError, match="smaller than one 5 x 5 block"):
        decimate_depth(depth, 5)


def test_intensity_mean_and_mask_any():
    intensity = np.arange(20, dtype=np.float32).reshape(4, 5) / 20
    out = decimate_intensity(intensity, 2)
    assert out.shape == (2, 2)
    np.testing.assert_allclose(out, _blocks(intensity, 2).mean(-1), rtol=1e-6)
    mask = np.zeros((4, 5), bool)
    mask[3, 1] = True
    np.testing.assert_array_equal(decimate_mask(mask, 2), [[False, False], [True, False]])


@pytest.mark.parametrize("factor", [2, 3])
def test_intrinsics_keep_the_block_centres(factor):
    """On a plane facing the camera the decimated pixel's 3D point is the mean of its block's
    points: the principal point follows the pixel-centre convention."""
    depth = np.full((K.height, K.width), 1500.0, np.float32)
    k2 = decimate_intrinsics(K, factor)
    assert (k2.width, k2.height) == (K.width // factor, K.height // factor)
    assert k2.fx == pytest.approx(K.fx / factor)
    full = depth_to_points(depth, K)
    small = depth_to_points(decimate_depth(depth, factor), k2)
    for c in range(3):
        np.testing.assert_allclose(small[..., c], _blocks(full[..., c], factor).mean(-1), atol=1e-3)


def test_equals_the_realsense_sdk_filter():
    """``rs.decimation_filter`` on the same Z16 frame (whole mm): equal for f = 2, within its
    integer truncation of the mean for f = 4 (sizes that the SDK does not pad)."""
    pytest.importorskip("pyrealsense2", reason="pyrealsense2 (fuse4d[sensors]) not installed")
    import pyrealsense2 as rs

    from fuse4d.baselines.realsense import _push, _software_sensor

    k = Intrinsics(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
    rng = np.random.default_rng(0)
    z16 = rng.integers(500, 3000, (48, 64)).astype(np.uint16)
    z16[rng.random(z16.shape) < 0.3] = 0
    depth = np.where(z16 > 0, z16, np.nan).astype(np.float32)
    for factor, tolerance in ((2, 0.0), (4, 1.0)):
        handle = _software_sensor(rs, k, 0.001)
        sdk = rs.decimation_filter()
        sdk.set_option(rs.option.filter_magnitude, factor)
        frame = sdk.process(_push(rs, handle, z16, 0, 0.001))
        expected = np.asanyarray(frame.get_data()).astype(np.float64)
        ours = np.nan_to_num(decimate_depth(depth, factor), nan=0.0)
        assert ours.shape == expected.shape
        assert np.abs(ours - expected).max() <= tolerance


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    seq = make_scene("ball", small=True, num_frames=6, rng=0)
    path = tmp_path_factory.mktemp("decimate") / "ball.npz"
    write_npz(seq, path)
    return path, seq


def test_cli_live_decimate_fuses_the_decimated_frames(ball, tmp_path, capsys):
    """``fuse4d live --decimate 2`` = the causal fusion of the decimated recording."""
    path, seq = ball
    out = tmp_path / "fused.npz"
    args = ["live", str(path), "--window", "3", "--decimate", "2", "-o", str(out), "--json"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["decimate"] == 2
    assert summary["size"] == [seq.intrinsics.width // 2, seq.intrinsics.height // 2]
    assert summary["frames_fused"] == 6
    small = np.stack([decimate_depth(d, 2) for d in seq.depth])
    inten = np.stack([decimate_intensity(i, 2) for i in seq.intensity])
    k2 = decimate_intrinsics(seq.intrinsics, 2)
    expected = fuse_sequence(small, inten, k2, fusion=FusionParams(num_frames=3, causal=True))
    written = load_sequence(out)
    assert (written.intrinsics.width, written.intrinsics.height) == (k2.width, k2.height)
    assert written.intrinsics.fx == pytest.approx(k2.fx)
    assert written.intrinsics.cx == pytest.approx(k2.cx)
    np.testing.assert_array_equal(written.depth, expected.depth)
    assert main([*args[:-1], "--force", "--decimate", "9"]) == 2
    assert "--decimate must be 1..8" in capsys.readouterr().err


def test_cli_live_decimate_larger_than_the_image_is_one_error_line(tmp_path, capsys):
    path = tmp_path / "tiny.npz"
    k = Intrinsics(fx=6.0, fy=6.0, cx=2.5, cy=2.5, width=6, height=6)
    depth = np.full((2, 6, 6), 1000.0, np.float32)
    write_npz(Sequence(depth=depth, intensity=np.full_like(depth, 0.5), intrinsics=k), path)
    assert main(["live", str(path), "--decimate", "8"]) == 2
    err = capsys.readouterr().err
    assert err.count("fuse4d: error:") == 1
    assert f"{path}: --decimate 8" in err
    assert "smaller than one 8 x 8 block" in err


@pytest.mark.parametrize("factor", [1, 2, 4])
def test_depth_zero_negative_and_inf_are_invalid_like_nan(factor):
    """0 (a 16-bit file's invalid), negative and inf depths are no measurement: never the
    block's median nor part of its mean (they were: a half-empty uint16 block gave 0 mm)."""
    assert decimate_depth(np.array([[0, 0], [1000, 1002]], np.uint16), 2).tolist() == [[1000.0]]
    depth = np.full((4, 4), 1000.0, np.float32)
    depth[:2] = [[0, -5, np.inf, -np.inf], [0, 0, 0, 0]]
    expected = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    out = decimate_depth(depth, factor)
    np.testing.assert_array_equal(out, _oracle(expected, factor) if factor > 1 else expected)
    if factor == 4:
        assert out.tolist() == [[1000.0]]  # the mean of the valid half, not 500 mm or inf
    empty = decimate_depth(np.zeros((4, 4), np.uint16), factor)
    assert np.isnan(empty).all()


def test_integer_intensity_is_scaled_to_unit_range():
    """uint8 intensity is value / 255 here as everywhere (it came out as 0-255 floats)."""
    u8 = np.array([[0, 255], [255, 255]], np.uint8)
    assert decimate_intensity(u8, 2).tolist() == [[0.75]]
    u16 = np.array([[0, 65535], [65535, 65535]], np.uint16)
    assert decimate_intensity(u16, 2).tolist() == [[0.75]]
    floats = np.array([[0.0, 0.5], [0.5, 1.0]], np.float32)  # floats kept as they are
    assert decimate_intensity(floats, 2).tolist() == [[0.5]]
    with pytest.raises(TypeError, match="does not say its bit depth"):
        decimate_intensity(np.ones((2, 2), np.int32), 2)
