"""Tests of Intrinsics and the Eq. 2 back-projection / projection."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d import Intrinsics, ShapeError, depth_to_points, project_points
from fuse4d.camera import points_to_depth
from fuse4d.errors import ParameterError, ParameterTypeError


def test_intrinsics_matrix_and_array():
    k = Intrinsics(fx=500, fy=510, cx=319.5, cy=239.5, width=640, height=480)
    np.testing.assert_array_equal(k.matrix, [[500, 0, 319.5], [0, 510, 239.5], [0, 0, 1]])
    assert Intrinsics.from_array(k.as_array(), width=640, height=480) == k
    assert Intrinsics.from_matrix(k.matrix, width=640, height=480) == k
    assert k.shape == (480, 640)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"fx": float("nan")}, "Intrinsics.fx must be finite, got nan"),
        ({"fy": 0.0}, "Intrinsics.fy must be > 0 pixels, got 0.0"),
        ({"cx": float("inf")}, "Intrinsics.cx must be finite, got inf"),
        ({"width": 0}, "Intrinsics.width must be a positive integer, got 0"),
        ({"height": 2.5}, "Intrinsics.height must be a positive integer, got 2.5"),
    ],
)
def test_intrinsics_rejects_bad_values(kwargs, message):
    base = {"fx": 100.0, "fy": 100.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 3}
    base.update(kwargs)
    with pytest.raises(ValueError, match="^" + message.replace(".", r"\.") + "$"):
        Intrinsics(**base)


def test_intrinsics_from_array_wrong_size():
    with pytest.raises(
        ValueError, match=r"intrinsics must be \[fx, fy, cx, cy\] \(4 numbers\), got 3"
    ):
        Intrinsics.from_array([1.0, 2.0, 3.0], width=4, height=4)


def test_scaled_keeps_pixel_centre_convention():
    k = Intrinsics(fx=100, fy=100, cx=1.5, cy=1.5, width=4, height=4)
    s = k.scaled(0.5)
    assert (s.fx, s.cx, s.width) == (50.0, 0.5, 2)


def test_backprojection_eq2_and_roundtrip(rng):
    k = Intrinsics(fx=300.0, fy=310.0, cx=9.7, cy=6.2, width=20, height=12)
    depth = rng.uniform(400, 900, (3, 12, 20)).astype(np.float32)
    depth[0, 2, 3] = np.nan
    depth[1, 0, 0] = 0.0
    p = depth_to_points(depth, k)
    assert p.shape == (3, 12, 20, 3)
    assert p.dtype == np.float32
    v, u = 5, 17
    expected = depth[2, v, u] * np.array([(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0])
    np.testing.assert_allclose(p[2, v, u], expected, rtol=1e-6)
    assert np.isnan(p[0, 2, 3]).all()
    assert np.isnan(p[1, 0, 0]).all()
    uu, vv = project_points(p, k)
    grid_v, grid_u = np.mgrid[0:12, 0:20]
    ok = np.isfinite(uu)
    np.testing.assert_allclose(uu[ok], np.broadcast_to(grid_u, uu.shape)[ok], atol=1e-3)
    np.testing.assert_allclose(vv[ok], np.broadcast_to(grid_v, vv.shape)[ok], atol=1e-3)
    z = points_to_depth(p)
    np.testing.assert_array_equal(np.isnan(z), ~(np.isfinite(depth) & (depth > 0)))


def test_backprojection_kernel_equals_the_formula_everywhere(rng):
    """Every pixel, invalid values (NaN, 0, negative, +-inf) and a strided input included."""
    k = Intrinsics(fx=300.0, fy=310.0, cx=9.7, cy=6.2, width=20, height=12)
    depth = rng.uniform(400, 900, (2, 12, 40)).astype(np.float32)[:, :, ::2]  # not contiguous
    depth[0, 1, :5] = [np.nan, 0.0, -3.0, np.inf, -np.inf]
    d = np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(np.nan))
    u = (np.arange(20, dtype=np.float32) - np.float32(k.cx)) / np.float32(k.fx)
    v = (np.arange(12, dtype=np.float32) - np.float32(k.cy)) / np.float32(k.fy)
    expected = np.stack([d * u[None, :], d * v[:, None], d], axis=-1)
    np.testing.assert_array_equal(depth_to_points(depth, k), expected)  # the same float32 bits
    np.testing.assert_array_equal(depth_to_points(depth[1], k), expected[1])


def test_backprojection_shape_mismatch_message():
    k = Intrinsics(fx=300.0, fy=300.0, cx=1, cy=1, width=5, height=4)
    with pytest.raises(ShapeError, match=r"depth must have shape \(\*, 4, 5\), got \(4, 6\)"):
        depth_to_points(np.ones((4, 6)), k)


def test_valid_depth_kernel_is_numpys_invalid_depth_rule():
    """FusionEngine.push's one-pass kernel: depth where finite and > 0, NaN elsewhere, the
    values of ``np.where(np.isfinite(d) & (d > 0), d, nan)`` (signed zeros, infinities,
    negative and subnormal depths included)."""
    from fuse4d._kernels.camera import _valid_depth_kernel

    rng = np.random.default_rng(5)
    d = rng.uniform(-100, 5000, (13, 37)).astype(np.float32)
    d.flat[:8] = [np.nan, np.inf, -np.inf, 0.0, -0.0, 1e-45, -1e-45, np.float32(65535)]
    out = np.empty_like(d)
    _valid_depth_kernel(d, out)
    expected = np.where(np.isfinite(d) & (d > 0), d, np.float32(np.nan))
    np.testing.assert_array_equal(out, expected)
    assert out.flat[5] == np.float32(1e-45)
    assert np.isnan(out.flat[6])


def test_scaled_refuses_what_is_not_a_finite_positive_number():
    """``scaled(inf)`` raised an OverflowError, ``scaled("a")`` a TypeError."""
    k = Intrinsics(fx=500, fy=510, cx=319.5, cy=239.5, width=640, height=480)
    assert k.scaled(np.float32(0.5)) == k.scaled(0.5)
    for bad in ("a", None, True):
        with pytest.raises(ParameterTypeError, match="factor must be a number"):
            k.scaled(bad)
    for bad in (float("inf"), float("nan"), 0.0, -1.0):
        with pytest.raises(ParameterError, match="factor must be a finite number > 0"):
            k.scaled(bad)
    with pytest.raises(ParameterError, match="too large for a 480x640 image"):
        k.scaled(1e307)


@pytest.mark.parametrize(
    ("row", "col", "value"), [(0, 1, 0.5), (1, 0, 1e-3), (2, 0, 1.0), (2, 1, 2.0), (2, 2, 2.0)]
)
def test_from_matrix_refuses_what_the_pinhole_model_ignores(row, col, value):
    """A skew K[0,1] or a K[2,2] other than 1 was silently ignored (wrong points)."""
    mat = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    mat[row, col] = value
    want = 1 if (row, col) == (2, 2) else 0
    with pytest.raises(ParameterError, match=rf"K\[{row},{col}\] must be {want}, got {value:g}"):
        Intrinsics.from_matrix(mat, width=640, height=480)


def test_camera_inputs_that_are_not_numbers_are_named():
    """A word in the values raised numpy's ValueError."""
    k = Intrinsics(fx=500, fy=510, cx=319.5, cy=239.5, width=640, height=480)
    with pytest.raises(ParameterTypeError, match="intrinsics must hold numbers"):
        Intrinsics.from_array(["a", 2, 3, 4], width=2, height=2)
    with pytest.raises(ParameterTypeError, match="camera matrix must hold numbers"):
        Intrinsics.from_matrix([["a"] * 3] * 3, width=2, height=2)
    with pytest.raises(ParameterTypeError, match="points must hold numbers"):
        project_points(np.array([["a", "b", "c"]]), k)
