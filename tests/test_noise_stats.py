"""The one-pass noise-model statistics (issue 13) equal the numpy expressions they replace,
bit for bit: ``estimate_noise_quad``'s samples and the median depth of a frame."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d._kernels.noise import _finite_median32, _median64
from fuse4d.motion import estimate_noise_quad


def _numpy_noise_quad(depth: np.ndarray) -> float:
    """estimate_noise_quad as numpy expressions (before issue 13)."""
    sub = depth[::2].astype(np.float64)
    second = np.abs(sub[:, :-2] - 2.0 * sub[:, 1:-1] + sub[:, 2:]).ravel()
    z = sub[:, 1:-1].ravel()
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(second) & (second > 0) & (second < 0.05 * z)
    return float(np.median(second[ok] / z[ok] ** 2) / 1.65) if ok.any() else 0.0


def _frames(rng):
    """Continuous, quantised (structured-light-like), holed, tiny and empty frames."""
    yy, xx = np.mgrid[0:61, 0:83].astype(np.float64)
    plane = 900.0 + 3.0 * xx + 1.5 * yy
    yield (plane + rng.normal(0, 0.2, plane.shape)).astype(np.float32)
    z = plane * 2.5
    yield (np.round(z**2 / 30000.0) * 30000.0 / z).astype(np.float32)  # z^2-quantised
    holed = (plane + rng.normal(0, 2.0, plane.shape)).astype(np.float32)
    holed[rng.random(holed.shape) < 0.3] = np.nan
    yield holed
    yield np.full((5, 3), 700.0, np.float32)  # no non-zero second difference
    yield np.full((4, 4), np.nan, np.float32)
    yield np.ones((1, 2), np.float32)


def test_noise_quad_equals_numpy(rng):
    frames = list(_frames(rng))
    for depth in frames:
        assert estimate_noise_quad(depth) == _numpy_noise_quad(depth)
    assert estimate_noise_quad(frames[1]) > 0.0  # the quantised frame has samples


@pytest.mark.parametrize("kind", ["normal", "quantised", "signed", "constant", "wide"])
def test_finite_median_equals_numpy(rng, kind):
    for n in (1, 2, 3, 10, 11, 1000, 1001):
        a = {
            "normal": rng.normal(1000, 50, n),
            "quantised": np.round(rng.normal(1000, 50, n) / 7) * 7,
            "signed": rng.normal(0, 1, n),
            "constant": np.full(n, 1234.5),
            "wide": rng.uniform(1e-3, 1e5, n),
        }[kind].astype(np.float32)
        holes = rng.random(n) < 0.2
        a[holes] = np.nan
        a[rng.random(n) < 0.02] = np.inf
        finite = a[np.isfinite(a)]
        got = _finite_median32(a.reshape(1, -1))
        if finite.size:
            assert got == float(np.median(finite))
        else:
            assert np.isnan(got)


@pytest.mark.parametrize(
    "kind", ["normal", "positive", "quantised", "signed", "constant", "close", "split", "wide"]
)
def test_median64_equals_numpy(rng, kind):
    """Odd and even counts; values that share their top 16, 32 or 48 key bits (every digit
    level), the two middle values in different top bins, infinities; values past ``n`` are
    not read."""
    for n in (1, 2, 3, 4, 10, 11, 1000, 1001, 4096):
        a = {
            "normal": rng.normal(0.0, 1.0, n),
            "positive": np.exp(rng.normal(-12.0, 2.0, n)),  # like the noise samples
            "quantised": np.round(rng.normal(5.0, 3.0, n)),
            "signed": rng.choice([-np.inf, -3.0, -1e-300, 2e-300, 7.0, np.inf], n),
            "constant": np.full(n, 0.125),
            "close": 1.0 + rng.integers(0, 40, n) * np.finfo(np.float64).eps,  # low digit only
            "split": np.where(np.arange(n) < n // 2, 1.0, 1e6),  # middle ranks in two top bins
            "wide": rng.uniform(-1e300, 1e300, n),
        }[kind]
        buffer = np.concatenate([a, rng.normal(0.0, 1.0, 5)])
        with np.errstate(invalid="ignore"):  # numpy's mean of -inf and inf
            expected = np.median(a)
        np.testing.assert_equal(_median64(buffer, n), expected)  # (NaN equals NaN)


def _numpy_depth_noise(depth: np.ndarray, reference: np.ndarray) -> float:
    """estimate_depth_noise's statistic as numpy expressions (before issue 13's kernel)."""
    r = np.abs(depth[::2, ::2] - reference[::2, ::2]).ravel()
    r = r[np.isfinite(r)]
    if r.size == 0:
        return 0.0
    keep = r[r <= np.quantile(r, 0.95)]
    return float(1.2533 * keep.mean()) if keep.size else 0.0


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (2, 2), (3, 5), (31, 47), (60, 80), (97, 41)])
def test_depth_noise_kernel_equals_numpy(rng, shape):
    """The one-kernel statistic (the engine's path, its reference a strided view of the
    smoothed points) equals the numpy expressions bit for bit: continuous, quantised (ties at
    the percentile), holed and constant residuals, references with NaN, every sample count's
    interpolation weight."""
    from fuse4d.motion import _depth_noise, estimate_depth_noise

    for trial in range(12):
        depth = rng.normal(1500.0, 40.0, shape).astype(np.float32)
        noise = rng.normal(0.0, rng.choice([0.01, 1.0, 30.0]), shape)
        if trial % 3 == 1:  # quantised: most residuals 0, many ties
            noise = np.round(noise / 4.0) * 4.0
        points = np.zeros((*shape, 3), np.float32)
        points[..., 2] = depth + noise.astype(np.float32)
        if trial % 4 == 2:
            depth[rng.random(shape) < 0.3] = np.nan
            points[..., 2][rng.random(shape) < 0.1] = np.nan
        if trial == 11:
            points[..., 2] = depth  # every residual 0
        expected = _numpy_depth_noise(depth, points[..., 2])
        assert _depth_noise(depth, points, 2) == expected
        assert estimate_depth_noise(depth, reference=points[..., 2]) == expected
        as64 = points[..., 2].astype(np.float64)  # the numpy path, unchanged
        assert estimate_depth_noise(depth, reference=as64) == _numpy_depth_noise(depth, as64)
