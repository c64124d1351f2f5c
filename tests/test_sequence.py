"""Tests of the Sequence data model and its validation messages."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d import Intrinsics, Sequence, ShapeError
from fuse4d.errors import ParameterError, ParameterTypeError
from fuse4d.sequence import GroundTruth, normalize_intensity


@pytest.fixture
def k():
    return Intrinsics(fx=100.0, fy=100.0, cx=2.0, cy=1.5, width=5, height=4)


def test_sequence_converts_and_marks_invalid(k):
    depth = np.full((2, 4, 5), 500, dtype=np.uint16)
    depth[0, 0, 0] = 0
    inten = np.full((2, 4, 5), 255, dtype=np.uint8)
    seq = Sequence(depth, inten, k)
    assert seq.depth.dtype == np.float32
    assert seq.intensity.dtype == np.float32
    assert np.isnan(seq.depth[0, 0, 0])
    assert seq.intensity.max() == 1.0
    assert seq.num_frames == 2
    assert seq.shape == (4, 5)
    assert seq.points().shape == (2, 4, 5, 3)


def test_sequence_rejects_shape_mismatch(k):
    with pytest.raises(ShapeError, match=r"intensity must have shape \(2, 4, 5\), got \(3, 4, 5\)"):
        Sequence(np.ones((2, 4, 5)), np.zeros((3, 4, 5)), k)


def test_sequence_rejects_intrinsics_mismatch(k):
    with pytest.raises(ShapeError, match=r"the intrinsics give an image of 4x5"):
        Sequence(np.ones((1, 5, 5)), np.zeros((1, 5, 5)), k)


def test_sequence_rejects_empty_and_2d(k):
    with pytest.raises(ValueError, match=r"at least one frame \(T >= 1\), got T = 0"):
        Sequence(np.ones((0, 4, 5)), np.zeros((0, 4, 5)), k)
    with pytest.raises(ShapeError, match=r"For a single frame use depth\[None\]"):
        Sequence(np.ones((4, 5)), np.zeros((4, 5)), k)


def test_sequence_rejects_intensity_out_of_range(k):
    with pytest.raises(ValueError, match=r"intensity must lie in \[0, 1\], got range \[0, 2\]"):
        Sequence(np.ones((1, 4, 5)), np.linspace(0, 2, 20).reshape(1, 4, 5), k)


def test_sequence_rejects_wrong_intrinsics_type():
    with pytest.raises(TypeError, match=r"intrinsics must be a fuse4d\.Intrinsics, got list"):
        Sequence(np.ones((1, 4, 5)), np.zeros((1, 4, 5)), [1, 2, 3, 4])


def test_sequence_warns_mostly_invalid(k):
    depth = np.full((1, 4, 5), np.nan)
    with pytest.warns(UserWarning, match=r"only 0.0 % of depth pixels are valid"):
        Sequence(depth, np.zeros((1, 4, 5)), k)


def test_sequence_timestamps_and_fps(k):
    with pytest.raises(ValueError, match="timestamps must be strictly increasing"):
        Sequence(np.ones((2, 4, 5)), np.zeros((2, 4, 5)), k, timestamps=[1.0, 1.0])
    with pytest.raises(ValueError, match="fps must be a positive number, got -3"):
        Sequence(np.ones((2, 4, 5)), np.zeros((2, 4, 5)), k, fps=-3)
    with pytest.raises(ParameterTypeError, match="fps must be a number, got 'abc'"):
        Sequence(np.ones((2, 4, 5)), np.zeros((2, 4, 5)), k, fps="abc")


def test_frames_slices_ground_truth(k):
    gt = GroundTruth(
        depth=np.ones((3, 4, 5), np.float32),
        flow=np.zeros((2, 4, 5, 2), np.float32),
        extra={"center_row": np.arange(3.0), "radius_mm": 140.0},
    )
    seq = Sequence(np.ones((3, 4, 5)), np.zeros((3, 4, 5)), k, ground_truth=gt)
    sub = seq.frames(1, 3)
    assert sub.num_frames == 2
    assert sub.ground_truth.flow.shape == (1, 4, 5, 2)
    np.testing.assert_array_equal(sub.ground_truth.extra["center_row"], [1.0, 2.0])
    with pytest.raises(ValueError, match="selects no frame"):
        seq.frames(5, 9)


def test_normalize_intensity():
    np.testing.assert_allclose(normalize_intensity(np.array([0, 65535], np.uint16)), [0, 1])
    np.testing.assert_allclose(normalize_intensity(np.array([0.0, 50.0, 200.0])), [0, 0.25, 1])


@pytest.mark.parametrize("stamps", [[0.0, np.inf], [-np.inf, 0.0], [np.nan, 1.0]])
def test_timestamps_must_be_finite(k, stamps):
    """Non-finite times were accepted, and save_sequence then wrote an .npz that
    load_sequence refused."""
    bad = int(np.flatnonzero(~np.isfinite(stamps))[0])
    with pytest.raises(ParameterError, match=rf"timestamps must be finite .*frame {bad} has"):
        Sequence(np.full((2, 4, 5), 500.0), np.zeros((2, 4, 5)), k, timestamps=stamps)


def test_timestamps_that_are_not_numbers_are_named(k):
    """A word raised numpy's ValueError."""
    with pytest.raises(ParameterTypeError, match="timestamps must be numbers"):
        Sequence(np.full((2, 4, 5), 500.0), np.zeros((2, 4, 5)), k, timestamps=["a", "b"])


@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.int16, np.int8, np.uint32])
def test_integer_intensity_wider_than_uint16_is_refused(k, dtype):
    """Divided by its dtype's maximum (9.2e18 for the int64 of a list of ints), 0-255 values
    all became black."""
    levels = np.arange(40, dtype=dtype).reshape(2, 4, 5)
    with pytest.raises(ParameterTypeError, match=r"integer dtype .*\.astype\(np\.uint8\)"):
        Sequence(np.full((2, 4, 5), 500.0), levels, k)
    with pytest.raises(ParameterTypeError, match="intensity has integer dtype"):
        Sequence(np.full((2, 4, 5), 500.0), levels.tolist(), k)
    seq = Sequence(np.full((2, 4, 5), 500.0), levels.astype(np.uint8), k)
    assert seq.intensity.max() == pytest.approx(39 / 255)


def test_intensity_of_either_byte_order_and_bool(k):
    big = np.array([0, 13107, 65535], dtype=">u2")
    np.testing.assert_allclose(normalize_intensity(big), [0, 0.2, 1])
    np.testing.assert_array_equal(normalize_intensity(np.array([True, False])), [1, 0])


def test_normalize_intensity_brings_negative_floats_into_0_1(k):
    """Values below 0 stayed below 0, so Sequence's advice to call normalize_intensity failed
    again."""
    raw = np.linspace(-0.2, 0.8, 40).reshape(2, 4, 5)
    with pytest.raises(ParameterError, match="normalize_intensity"):
        Sequence(np.full((2, 4, 5), 500.0), raw, k)
    unit = normalize_intensity(raw)
    assert unit.min() == 0.0
    assert unit.max() == 1.0
    np.testing.assert_allclose(unit, raw + 0.2, atol=1e-6)  # linear: [min, max] -> [0, 1]
    seq = Sequence(np.full((2, 4, 5), 500.0), unit, k)
    assert seq.intensity.min() == 0.0
    np.testing.assert_array_equal(normalize_intensity(np.full(3, -2.0)), [0, 0, 0])
    with_nan = normalize_intensity(np.array([np.nan, -1.0, 3.0]))
    np.testing.assert_array_equal(with_nan[1:], [0, 1])


def test_ground_truth_select_keeps_the_flow_of_step_1_slices_only(k):
    """A stepped slice kept the flow of every pair (5 for 3 frames); a reversed one none."""
    flow = np.arange(5, dtype=np.float32)[:, None, None, None] * np.ones((5, 4, 5, 2))
    gt = GroundTruth(depth=np.ones((6, 4, 5), np.float32), flow=flow)
    assert gt.select(slice(1, 4), 6).flow[:, 0, 0, 0].tolist() == [1, 2]
    for index in (slice(0, 6, 2), slice(None, None, -1), np.array([0, 1, 2])):
        sub = gt.select(index, 6)
        assert sub.flow is None
        Sequence(np.ones(sub.depth.shape), np.zeros(sub.depth.shape), k, ground_truth=sub)
