"""The writers' one-pass conversions (issue 13) equal the numpy code they replace, bit for bit."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from fuse4d.io import read_depth_png
from fuse4d.io._images import QuantizationReport, depth_to_units, intensity_to_uint
from fuse4d.io._images import _depth_to_units_numpy as _units_numpy
from fuse4d.io.folder import intensity_image


def _intensity_numpy(intensity):
    i8 = intensity_to_uint(intensity, 8)
    exact = np.allclose(i8 / 255.0, np.nan_to_num(intensity), rtol=0, atol=1e-6)
    return i8 if exact else intensity_to_uint(intensity, 16)


def _depth(dtype, rng):
    d = (rng.random((24, 32)) * 3000).astype(dtype)
    d[rng.random(d.shape) < 0.2] = np.nan
    d[0, :6] = [0.0, -3.0, np.inf, 1e9, 0.2, -np.inf]
    d[1, :4] = [0.5, 1.5, 2.5, 65535.5]
    return d


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("unit_mm", [1.0, 0.25, 0.1, 3.0])
@pytest.mark.parametrize("kind", ["noisy", "on_grid", "empty"])
def test_depth_to_units_matches_numpy(dtype, unit_mm, kind):
    rng = np.random.default_rng(1)
    d = _depth(dtype, rng)
    if kind == "on_grid":
        d = np.round(d / unit_mm) * unit_mm
    elif kind == "empty":
        d = np.full((5, 7), np.nan, dtype)
    ref, new = QuantizationReport(unit_mm), QuantizationReport(unit_mm)
    for _ in range(2):  # the report accumulates over frames
        expected = _units_numpy(d, unit_mm, ref)
        got = depth_to_units(d, unit_mm, new)
        assert got.dtype == np.uint16
        np.testing.assert_array_equal(got, expected)
    assert vars(new) == vars(ref)
    np.testing.assert_array_equal(depth_to_units(d, unit_mm), expected)  # no report


def test_depth_to_units_other_inputs_use_numpy():
    d = np.array([[0, 5, 70000], [3, -1, 2]], dtype=np.int64)
    np.testing.assert_array_equal(depth_to_units(d, 1.0), _units_numpy(d, 1.0, None))
    d3 = np.ones((2, 2, 2), np.float32)
    np.testing.assert_array_equal(depth_to_units(d3, 1.0), _units_numpy(d3, 1.0, None))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_intensity_image_matches_numpy(dtype):
    rng = np.random.default_rng(2)
    eight = rng.integers(0, 256, (20, 30)) / 255.0
    cases = [
        rng.random((20, 30)),  # 16 bits needed
        eight,  # exactly 8-bit
        eight + 2e-6,  # just past the tolerance
        eight + 5e-7,  # within it
        np.array([[np.nan, 1.2, -0.1], [0.5, 2 / 255, 1.0]]),  # NaN, clipped values
        np.array([[np.inf, 0.5], [0.25, -np.inf]]),  # infinities: the numpy path
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # inf * 65535 in the numpy path
        for case in cases:
            case = case.astype(dtype)
            expected = _intensity_numpy(case)
            got = intensity_image(case, None)
            assert got.dtype == expected.dtype
            np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_flag_images_give_the_numpy_expressions_bytes(dtype):
    """The confidence image: the bytes of rint(clip(nan_to_num(c), 0, 1) * 255) in float32,
    at every level's rounding edges (±1 ulp), out of range, NaN, ±inf, a strided view."""
    from fuse4d.io._base import flag_images

    edges = (np.arange(256) + 0.5) / 255.0
    c = np.concatenate(
        [
            np.arange(256) / 255.0,
            edges,
            np.nextafter(edges.astype(np.float32), np.float32(0)),
            np.nextafter(edges.astype(np.float32), np.float32(2)),
            [np.nan, np.inf, -np.inf, -0.0, -1e-9, 1.5, 1.0 + 1e-7],
        ]
    )
    c = np.resize(c, (31, 40)).astype(dtype)
    source = np.arange(c.size, dtype=np.uint8).reshape(c.shape) % 5
    for conf in (c, c[::2, 1::3]):
        with np.errstate(invalid="ignore"):
            expected = np.rint(
                np.clip(np.nan_to_num(np.asarray(conf, np.float32)), 0.0, 1.0) * 255.0
            ).astype(np.uint8)
        images = dict(flag_images(source[: conf.shape[0], : conf.shape[1]], conf))
        assert images["confidence"].dtype == np.uint8
        np.testing.assert_array_equal(images["confidence"], expected)
        np.testing.assert_array_equal(images["source"], source[: conf.shape[0], : conf.shape[1]])


@pytest.mark.parametrize("unit_mm", [1.0, 0.5])
def test_read_depth_png_holes(tmp_path, unit_mm):
    image = np.array([[0, 1, 2905], [65535, 0, 7]], np.uint16)
    path = tmp_path / "d.png"
    cv2.imwrite(str(path), image)
    depth = read_depth_png(path, unit_mm=unit_mm)
    expected = image.astype(np.float32) * np.float32(unit_mm)
    expected[image == 0] = np.nan
    assert depth.dtype == np.float32
    np.testing.assert_array_equal(depth, expected)


def test_source_confidence_kernel_matches_numpy():
    from fuse4d._kernels.holes import _source_confidence_kernel
    from fuse4d.holes import SOURCE_FUSED, SOURCE_MEASURED, SOURCE_NONE

    assert (SOURCE_NONE, SOURCE_MEASURED, SOURCE_FUSED) == (0, 1, 2)  # hard-coded there
    rng = np.random.default_rng(3)
    depth = rng.random((17, 23)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = np.nan
    support = rng.integers(0, 9, depth.shape).astype(np.uint8)
    out = depth + 1.0
    out[rng.random(depth.shape) < 0.2] = np.nan  # fill_fallback="nan": no output depth
    for n in (9.0, 7.0, 1.0):
        measured = ~np.isnan(depth)
        output = measured & ~np.isnan(out)
        source = np.where(output, SOURCE_MEASURED, SOURCE_NONE).astype(np.uint8)
        source[output & (support > 0)] = SOURCE_FUSED
        confidence = np.where(output, (1.0 + support) / n, 0.0).astype(np.float32)
        got = (np.empty_like(source), np.empty_like(confidence), np.empty(depth.shape, bool))
        points = np.stack([depth, depth, out], axis=-1)  # only z is read
        assert _source_confidence_kernel(depth, points, support, n, *got)
        np.testing.assert_array_equal(got[0], source)
        np.testing.assert_array_equal(got[1], confidence)
        np.testing.assert_array_equal(got[2], ~measured)
    full = np.ones((3, 4), np.float32)
    bufs = (np.empty((3, 4), np.uint8), np.empty((3, 4), np.float32), np.empty((3, 4), bool))
    full_points = np.ones((3, 4, 3), np.float32)
    assert not _source_confidence_kernel(full, full_points, np.zeros((3, 4), np.uint8), 9.0, *bufs)


@pytest.mark.parametrize("step", ["report", "moved_pts"])
def test_mkv_close_interrupted_before_the_rename_leaves_no_file(tmp_path, monkeypatch, step):
    """A Ctrl-C in close's warnings (after ``_stack`` was cleared) left the staged .mkv."""
    pytest.importorskip("av")
    from fuse4d.camera import Intrinsics
    from fuse4d.io import DepthVideoWriter

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    if step == "report":
        monkeypatch.setattr(QuantizationReport, "warn", interrupt)
    else:
        monkeypatch.setattr(DepthVideoWriter, "_warn_moved_pts", interrupt)
    k = Intrinsics(20.0, 20.0, 7.5, 5.5, width=16, height=12)
    out = tmp_path / "v.mkv"
    with pytest.raises(KeyboardInterrupt) as caught, DepthVideoWriter(out, k) as writer:
        writer.write(np.full(k.shape, 500.0, np.float32), np.full(k.shape, 0.5, np.float32))
    # while the interrupt is still held (its traceback keeps close's frame alive, so garbage
    # collection has not yet closed the atomic context): neither the temporary nor the output
    assert caught.traceback
    assert list(tmp_path.iterdir()) == []
