"""Tests of fuse4d.metrics: kernels vs naive oracles, analytic cases, errors, CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fuse4d import Intrinsics, Sequence, ShapeError, depth_to_points, fuse_sequence
from fuse4d._kernels.roughness import _smallest_eigvec_newton
from fuse4d._kernels.sphere_fit import _mlesac_score_kernel
from fuse4d.cli import main
from fuse4d.errors import InputFileError, ParameterError, ParameterTypeError
from fuse4d.io import read_mask
from fuse4d.metrics import (
    bad_pixel_fraction,
    ball_roi,
    central_roi,
    circle_fit_mlesac,
    default_roi,
    depth_rmse,
    evaluate,
    flow_angular_error,
    flow_endpoint_error,
    roughness,
    roughness_maps,
    roughness_rms,
    roughness_stats,
    scene_roi,
    shape_correctness,
    sphere_fit_mlesac,
    static_mask_from_ground_truth,
    static_pixels,
    temporal_flicker,
)
from fuse4d.metrics.evaluate import _as_video
from fuse4d.synthetic import make_deforming_sheet, make_falling_ball, make_static_plane
from naive.metrics import naive_default_roi, naive_mlesac_score, naive_roughness

K = Intrinsics(fx=500.0, fy=500.0, cx=15.5, cy=11.5, width=32, height=24)


def _bumpy_points(rng, nan_fraction=0.1):
    yy, xx = np.mgrid[0:24, 0:32]
    depth = (
        600.0 + 0.3 * xx + 5 * np.sin(xx / 4.0) * np.cos(yy / 5.0) + rng.normal(0, 0.3, xx.shape)
    )
    depth[rng.random(depth.shape) < nan_fraction] = np.nan
    return depth_to_points(depth, K)


# ---------------------------------------------------------------------------- roughness
@pytest.mark.parametrize("window", [3, 5, 7])
def test_roughness_matches_naive_oracle(rng, window):
    pts = _bumpy_points(rng)
    pi, rms = roughness_maps(pts, window=window)
    pi_ref, rms_ref = naive_roughness(pts, window=window)
    np.testing.assert_array_equal(np.isnan(pi), np.isnan(pi_ref))
    assert np.isfinite(pi).sum() > 300
    np.testing.assert_allclose(pi, pi_ref, rtol=1e-3, atol=2e-4, equal_nan=True)
    np.testing.assert_allclose(rms, rms_ref, rtol=1e-3, atol=2e-5, equal_nan=True)


def test_plane_normal_by_newton_matches_eigh_and_falls_back_for_lines(rng):
    """The roughness maps' smallest eigenvector (Newton's cosine, A = q I and line-like
    scatters included) against numpy's eigh; line-like scatters ask for the closed form."""
    cases = []
    for scales, exact in (((9.0, 7.0, 0.01), True), ((1e4, 2.0, 1.0), False), ((5.0,) * 3, True)):
        basis, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        cases.append((basis @ np.diag(scales) @ basis.T, exact))
    cases.append((np.diag([4.0, 4.0, 4.0]), True))  # A = q I: any normal, Z by convention
    for a, exact in cases:
        nx, ny, nz, lam, ok = _smallest_eigvec_newton(
            a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2]
        )
        assert ok == exact
        if not ok:
            continue
        values, vectors = np.linalg.eigh(a)
        assert lam == pytest.approx(values[0], abs=1e-9 * values[-1])
        if values[1] - values[0] > 1e-6 * values[-1]:  # a unique normal (up to sign)
            assert abs(np.dot([nx, ny, nz], vectors[:, 0])) == pytest.approx(1.0, abs=1e-9)
        else:
            assert [nx, ny, nz] == [0.0, 0.0, 1.0] or abs(np.linalg.norm([nx, ny, nz]) - 1) < 1e-9


def test_roughness_of_a_steep_ramp_matches_the_oracle(rng):
    """Windows on a surface seen nearly edge-on are line-like (the closed-form fallback)."""
    _, xx = np.mgrid[0:24, 0:32]
    depth = 600.0 + 300.0 * xx + rng.normal(0, 0.3, xx.shape)
    pts = depth_to_points(depth, K)
    window = pts[8:13, 8:13].reshape(-1, 3).astype(np.float64)
    d = window - window.mean(axis=0)
    a = d.T @ d
    *_, exact = _smallest_eigvec_newton(a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2])
    assert not exact  # the fallback is what this case tests
    pi, rms = roughness_maps(pts)
    pi_ref, rms_ref = naive_roughness(pts)
    assert np.isfinite(pi).sum() > 50
    np.testing.assert_allclose(pi, pi_ref, rtol=1e-3, atol=2e-4, equal_nan=True)
    np.testing.assert_allclose(rms, rms_ref, rtol=1e-3, atol=2e-5, equal_nan=True)


def test_roughness_sequence_axis_and_wrappers(rng):
    pts = np.stack([_bumpy_points(rng), _bumpy_points(rng)])
    pi = roughness(pts)
    assert pi.shape == (2, 24, 32)
    assert pi.dtype == np.float32
    np.testing.assert_array_equal(pi[1], roughness(pts[1]))
    np.testing.assert_array_equal(roughness_rms(pts), roughness_maps(pts)[1])


def test_exact_tilted_plane_has_zero_roughness():
    yy, xx = np.mgrid[0:24, 0:32]
    # a plane Z = a + b X + c Y in camera space is 1/Z linear in (u, v)
    inv = (1.0 / 500.0) * (1.0 - 0.3 * (xx - K.cx) / K.fx + 0.2 * (yy - K.cy) / K.fy)
    pi, rms = roughness_maps(depth_to_points(1.0 / inv, K))
    assert np.isfinite(pi[2:-2, 2:-2]).all()
    assert np.nanmax(pi) < 2e-3  # float32 points at ~500 mm
    assert np.nanmax(rms) < 1e-4


def test_noisy_plane_expectation():
    """E|Pi| = N sigma sqrt(1 - 1/N) sqrt(2/pi) for a fronto-parallel plane, N = n^2."""
    rng = np.random.default_rng(1)
    big = Intrinsics(fx=1000.0, fy=1000.0, cx=99.5, cy=99.5, width=200, height=200)
    sigma = 0.2
    depth = 700.0 + rng.normal(0.0, sigma, (3, 200, 200))
    pi, rms = roughness_maps(depth_to_points(depth, big), window=5)
    n = 25
    expected = n * sigma * math.sqrt(1 - 1 / n) * math.sqrt(2 / math.pi)
    assert np.nanmean(pi) == pytest.approx(expected, rel=0.02)
    # RMS residual: E R^2 = sigma^2 (N - 3) / N
    assert np.nanmean(rms**2) == pytest.approx(sigma**2 * (n - 3) / n, rel=0.03)


def test_roughness_validity_rules():
    depth = np.full((24, 32), 500.0)
    depth[10, 10] = np.nan  # invalid centre
    depth[3:6, 20:25] = np.nan  # 15 missing points around (4, 22)
    pi = roughness(depth_to_points(depth, K))
    assert np.isnan(pi[10, 10])
    assert np.isfinite(pi[10, 11])  # 24/25 valid
    assert np.isnan(pi[6, 22])  # 25 - 10 = 15 valid < 20
    assert np.isnan(pi[0, 0])
    assert np.isnan(pi[0, 15])
    assert np.isfinite(pi[1, 15])  # 20/25 at the border: exactly 80 %


@pytest.mark.parametrize("window", [4, 1, 2.5, "5", None, math.nan, math.inf])
def test_roughness_rejects_bad_window(window):
    with pytest.raises(ParameterError, match="window must be an odd integer >= 3"):
        roughness(np.zeros((8, 8, 3)), window=window)


@pytest.mark.parametrize("window", [4, 0, 2.5, "5", None, math.nan, math.inf])
def test_default_roi_rejects_bad_window(window):
    with pytest.raises(ParameterError, match="window must be an odd positive integer"):
        default_roi(np.full((8, 8), 500.0), window=window)


def test_a_whole_float_window_is_the_integer_window(rng):
    """window=5.0 crashed in numba (a float radius) in default_roi and roughness_stats."""
    depth = 900 + rng.normal(0, 1, (2, 21, 31))
    pts = depth_to_points(depth, Intrinsics(200.0, 200.0, 15.0, 10.0, 31, 21))
    for window in (5.0, np.float64(5), np.int64(5)):
        np.testing.assert_array_equal(default_roi(depth, window=window), default_roi(depth))
        stats = roughness_stats(pts, window=window)
        np.testing.assert_array_equal(stats.frame_means, roughness_stats(pts).frame_means)


def test_roughness_rejects_bad_shape():
    with pytest.raises(ShapeError, match=r"points must have shape \(T, H, W, 3\)"):
        roughness(np.zeros((2, 8, 8, 2)))


def test_roughness_stats_over_frames(rng):
    pts = np.stack([_bumpy_points(rng, 0.0) for _ in range(4)])
    roi = np.zeros((24, 32), dtype=bool)
    roi[5:15, 5:20] = True
    stats = roughness_stats(pts, roi=roi)
    pi = roughness(pts)
    expect = np.array([pi[t][roi].mean() for t in range(4)])
    np.testing.assert_allclose(stats.frame_means, expect, rtol=1e-6)
    assert stats.mean == pytest.approx(expect.mean())
    assert stats.std == pytest.approx(expect.std(ddof=0))
    assert stats.num_pixels.tolist() == [150] * 4
    assert stats.interior(1) == pytest.approx((expect[1:3].mean(), expect[1:3].std()))
    with pytest.raises(ValueError, match="margin must be in"):
        stats.interior(2)


def test_roughness_stats_empty_frame_is_nan_and_skipped(rng):
    pts = np.stack([_bumpy_points(rng, 0.0), np.full((24, 32, 3), np.nan, np.float32)])
    stats = roughness_stats(pts)
    assert np.isnan(stats.frame_means[1])
    assert stats.num_pixels[1] == 0
    assert stats.mean == pytest.approx(stats.frame_means[0])


def test_roughness_stats_rejects_bad_roi(rng):
    with pytest.raises(ShapeError, match="roi must have shape"):
        roughness_stats(_bumpy_points(rng), roi=np.ones((3, 3), bool))
    with pytest.raises(TypeError, match="roi must be a boolean mask"):
        roughness_stats(_bumpy_points(rng), roi=np.ones((24, 32)))


# ---------------------------------------------------------------------------- ROIs
def test_default_roi_excludes_edges_borders_and_holes():
    d = np.full((12, 12), 500.0)
    d[:, 7:] = 520.0  # a 20 mm step between columns 6 and 7
    d[2, 2] = np.nan
    roi = default_roi(d, window=3, max_step=10.0, noise_quad=0.0)
    assert not roi[0].any()
    assert not roi[:, 0].any()
    assert not roi[5, 6]
    assert not roi[5, 7]
    assert roi[5, 5]
    assert roi[5, 8]
    assert not roi[1:4, 1:4].any()
    assert roi[5, 4]
    assert default_roi(d, window=3, max_step=30.0, noise_quad=0.0)[5, 6]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_default_roi_kernel_equals_the_scipy_filters(seed):
    """Random quantised slopes, steps, holes and infinities; windows 1-7, one frame and a
    stack with a noise coefficient per frame; images narrower than the window."""
    rng = np.random.default_rng(seed)
    for shape in ((31, 43), (3, 29, 17), (4, 3), (2, 9)):
        d = 2000.0 + 8.0 * np.floor(rng.uniform(0, 40, shape)).astype(np.float32)
        d += np.where(rng.random(shape) < 0.05, 300.0, 0.0)
        d[rng.random(shape) < 0.08] = np.nan
        d[rng.random(shape) < 0.01] = np.inf
        quads = rng.uniform(0.0, 3e-6, shape[:-2])
        for window in (1, 3, 5, 7):
            for max_step in (0.0, 10.0):
                got = default_roi(d, window=window, max_step=max_step, noise_quad=quads)
                want = naive_default_roi(d, window, max_step, quads)
                assert got.any() or not want.any()
                np.testing.assert_array_equal(got, want)


def test_default_roi_follows_the_noise_model_on_quantised_slopes():
    """A staircase of 30 mm quantisation steps at 3 m is one surface, not a field of edges."""
    from fuse4d._kernels.fusion import _step_limit
    from fuse4d.metrics import step_limit

    z = 3000.0 + 30.0 * np.floor(np.arange(40) / 4.0)  # a slanted floor, quantised
    d = np.broadcast_to(z[:, None], (40, 20)).copy()
    q = 30.0 / 1.65 / 3000.0**2  # one quantisation level per 1.65 noise levels (A22)
    assert default_roi(d, window=5, noise_quad=0.0)[2:-2, 2:-2].mean() < 0.1  # plateaus only
    assert default_roi(d, window=5, noise_quad=q)[2:-2, 2:-2].all()
    d[20:, :] += 400.0  # a real depth edge stays an edge
    assert not default_roi(d, window=5, noise_quad=q)[18:22].any()
    for zz, step, quad in ((500.0, 10.0, 0.0), (3000.0, 10.0, q), (1000.0, 2.0, 1e-6)):
        assert step_limit(zz, max_step=step, noise_quad=quad) == pytest.approx(
            _step_limit(zz, step, quad)
        )


def test_depth_0_and_negative_are_invalid_for_the_roi_static_pixels_and_noise(rng):
    """A hole of 0 (a 16-bit file's) was a flat surface: in the ROI, static, and it pulled
    the noise estimate down (0.29 against 0.40 mm with NaN)."""
    from fuse4d.motion import estimate_depth_noise

    nan_hole = 800 + rng.normal(0, 0.5, (4, 40, 40))
    nan_hole[:, 10:30, 10:30] = np.nan
    for fill in (0.0, -5.0):
        hole = np.where(np.isnan(nan_hole), fill, nan_hole)
        roi = default_roi(hole, noise_quad=0.0)
        assert not roi[:, 8:32, 8:32].any()
        np.testing.assert_array_equal(roi, default_roi(nan_hole, noise_quad=0.0))
        static = static_pixels(hole)
        assert not static[10:30, 10:30].any()
        np.testing.assert_array_equal(static, static_pixels(nan_hole))
        assert estimate_depth_noise(hole[0]) == estimate_depth_noise(nan_hole[0])
    assert (hole == -5.0).sum() == 4 * 400  # the input is not written to


def test_static_pixels_excludes_a_passing_object_not_sensor_noise(rng):
    from fuse4d.metrics import static_pixels

    d = 2500.0 + 30.0 * rng.integers(-1, 2, size=(10, 16, 16)).astype(np.float64)
    d[3:6, 4:8, 4:8] = 1500.0  # someone walks through
    d[:, 0, 0] = np.nan
    static = static_pixels(d, noise_quad=30.0 / 1.65 / 2500.0**2)
    assert not static[4:8, 4:8].any()
    assert not static[0, 0]
    assert static.sum() == 16 * 16 - 16 - 1


def test_static_pixels_exclude_a_surface_moving_by_more_than_the_noise(rng):
    """A surface approaching at 0.9 mm a frame under 0.2 mm noise (the synthetic ball) is not
    static: a fixed 30 mm tolerance called it static, and the flicker then rewarded lag."""
    from fuse4d.metrics import static_pixels

    t = np.arange(8, dtype=np.float64)[:, None, None]
    d = 1000.0 + rng.normal(0.0, 0.2, (8, 16, 16))
    d[:, :, 8:] -= 0.9 * t  # the right half moves
    static = static_pixels(d, noise_quad=0.0)
    assert static[:, :8].mean() > 0.99
    assert not static[:, 8:].any()


def test_flicker_without_ground_truth_does_not_reward_lag():
    """On the ball without its ground truth, fuse4d is steadier than a 9-frame mean on the
    detected static pixels, as the ground truth says; the mean used to look twice as steady
    because the moving ball counted as static."""
    from fuse4d.baselines import run_baseline
    from fuse4d.metrics import evaluate

    seq = make_falling_ball(small=True, num_frames=8)
    fused = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics).depth
    mean = run_baseline("temporal-mean", seq.depth, None, seq.intrinsics)
    bare = Sequence(seq.depth, seq.intensity, seq.intrinsics)
    ours = evaluate(bare.with_depth(fused), raw=bare)
    theirs = evaluate(bare.with_depth(mean), raw=bare)
    assert ours.output.flicker.num_pixels == theirs.output.flicker.num_pixels
    assert ours.output.flicker.step_mean < 0.5 * theirs.output.flicker.step_mean


def test_ball_roi_small():
    seq = make_falling_ball(small=True, num_frames=3, depth_noise=0.0)
    roi = ball_roi(seq)
    gt = seq.ground_truth
    assert roi.shape == (3, 150, 150)
    assert not (roi & ~gt.mask).any()
    vv, uu = np.nonzero(roi[2])
    dist = np.hypot(uu - gt.scene.center_col, vv - gt.scene.center_row[2])
    assert dist.max() <= 25.0
    assert dist.max() > 24.0
    assert roi[0].sum() == roi[2].sum()  # pure translation, same ROI size


def test_central_roi_plane_and_sheet():
    plane = make_static_plane(small=True, num_frames=2)
    roi, desc = scene_roi(plane)
    assert "central 80 %" in desc
    frac = roi[0].sum() / plane.ground_truth.mask[0].sum()
    assert 0.5 < frac < 0.7  # 0.8 x 0.8 of the area, minus the window margin
    sheet = make_deforming_sheet(small=True, num_frames=3)
    roi_s = central_roi(sheet)
    assert roi_s.any()
    assert not (roi_s & ~sheet.ground_truth.mask).any()


def test_static_mask_from_ground_truth():
    seq = make_falling_ball(small=True, num_frames=4)
    static = static_mask_from_ground_truth(seq.ground_truth)
    assert not (static & seq.ground_truth.mask.any(axis=0)).any()
    assert static.mean() > 0.5


# ---------------------------------------------------------------------------- shape
def _sphere_points(rng, n=2000, radius=140.0, centre=(0.0, 20.0, 700.0)):
    d = rng.normal(size=(n, 3))
    return radius * d / np.linalg.norm(d, axis=1, keepdims=True) + np.asarray(centre)


def test_sphere_fit_exact_sphere(rng):
    fit = sphere_fit_mlesac(_sphere_points(rng))
    assert fit.radius == pytest.approx(140.0, abs=1e-6)
    assert fit.minimal_radius == pytest.approx(140.0, abs=1e-6)
    np.testing.assert_allclose(fit.center, [0.0, 20.0, 700.0], atol=1e-6)
    assert fit.num_inliers == 2000


def test_sphere_fit_robust_to_outliers(rng):
    pts = _sphere_points(rng) + rng.normal(0, 0.2, (2000, 3))
    pts[:600] = rng.uniform(-150, 150, (600, 3)) + np.array([0.0, 0.0, 700.0])
    fit = sphere_fit_mlesac(pts, rng=3)
    assert fit.radius == pytest.approx(140.0, abs=0.1)
    assert 0.6 < fit.inlier_fraction < 0.8


def test_circle_fit(rng):
    a = rng.uniform(0, np.pi, 300)
    pts = np.stack([50 * np.cos(a) + 3, 50 * np.sin(a) - 7], 1)
    assert circle_fit_mlesac(pts).radius == pytest.approx(50.0, abs=1e-6)


def test_mlesac_kernel_matches_oracle(rng):
    pts = _sphere_points(rng, 500) + rng.normal(0, 0.5, (500, 3))
    centres = np.array([[0.0, 20.0, 700.0], [1.0, 18.0, 702.0], [0.0, 0.0, 0.0]])
    radii = np.array([140.0, 139.0, 5.0])
    nll, gamma = np.empty(3), np.empty(3)
    usable = np.array([True, True, False])
    _mlesac_score_kernel(pts, centres, radii, usable, 0.5, 50.0, 5, nll, gamma)
    for m in range(2):
        ref_nll, ref_gamma = naive_mlesac_score(pts, centres[m], radii[m])
        assert nll[m] == pytest.approx(ref_nll, rel=1e-9)
        assert gamma[m] == pytest.approx(ref_gamma, rel=1e-9)
    assert nll[2] == np.inf


def test_sphere_fit_errors():
    with pytest.raises(ValueError, match="needs at least 4 finite points, got 3"):
        sphere_fit_mlesac(np.ones((3, 3)))
    with pytest.raises(ShapeError, match=r"points must have shape \(N, 3\)"):
        sphere_fit_mlesac(np.ones((10, 2)))
    with pytest.raises(ValueError, match="sigma must be > 0"):
        sphere_fit_mlesac(np.ones((10, 3)), sigma=0)


def test_shape_correctness_noise_free_ball_is_one():
    seq = make_falling_ball(small=True, num_frames=2, depth_noise=0.0)
    sc = shape_correctness(seq, seq.points())
    np.testing.assert_allclose(sc.c_3d, 1.0, atol=1e-4)
    np.testing.assert_allclose(sc.c_profile, 1.0, atol=2e-3)
    assert (sc.num_points > 3000).all()
    # a scaled ball (radius 140 * 1.01) gives C = 0.99
    sc2 = shape_correctness(seq, seq.points() * 1.01)
    np.testing.assert_allclose(sc2.c_3d, 0.99, atol=2e-4)


def test_shape_correctness_needs_ball_ground_truth():
    plane = make_static_plane(small=True, num_frames=2)
    with pytest.raises(ValueError, match="needs the falling-ball ground truth"):
        shape_correctness(plane, plane.points())


# ---------------------------------------------------------------------------- accuracy
def test_depth_rmse_and_bad_pixels():
    truth = np.array([[500.0, 500.0], [500.0, np.nan]])
    test = np.array([[500.0, 503.0], [np.nan, 1.0]])
    assert depth_rmse(truth, test) == pytest.approx(math.sqrt(9 / 2))
    assert bad_pixel_fraction(truth, test) == pytest.approx(2 / 3)  # NaN counts as bad
    assert bad_pixel_fraction(truth, test, threshold=5.0) == pytest.approx(1 / 3)
    assert bad_pixel_fraction(truth, test, noise_quad=0.0) == pytest.approx(2 / 3)
    mask = np.array([[True, False], [True, True]])
    assert depth_rmse(truth, test, roi=mask) == 0.0
    assert math.isnan(depth_rmse(truth, test, roi=np.zeros((2, 2), bool)))
    with pytest.warns(DeprecationWarning, match="called roi="):
        assert depth_rmse(truth, test, mask=mask) == 0.0
    with pytest.raises(TypeError, match="give roi= only"):
        depth_rmse(truth, test, roi=mask, mask=mask)
    with pytest.raises(ShapeError, match="depth_test must have shape"):
        depth_rmse(truth, np.zeros((3, 2)))


@pytest.mark.parametrize("scale", [1e-2, 1.0, 1e5])
def test_roughness_of_collinear_points_is_zero(scale):
    """Every plane through a line fits points on it: with a double smallest eigenvalue the
    normal came from rounding noise and two points scored 1-2 % of their distance."""
    p = np.full((3, 3, 3), np.nan, np.float32)
    p[1, 1] = np.array([545.16522, -2862.5295, 98489.13]) * scale / 1e5
    p[1, 2] = np.array([0.0, -2308.7449, 99294.3]) * scale / 1e5
    p[0, 0] = 2 * p[1, 1] - p[1, 2]  # a third point on the line
    pi, rms = roughness_maps(p, window=3, min_valid_fraction=2 / 9)
    length = float(np.linalg.norm(p[1, 2] - p[1, 1]))
    assert pi[1, 1] <= 1e-6 * length
    assert rms[1, 1] <= 1e-6 * length


def test_bad_pixels_with_the_noise_models_step_limit():
    """``noise_quad`` q: the threshold at true depth z is max(threshold, 2.5 q z^2)."""
    truth = np.array([[1000.0, 1000.0], [3000.0, 3000.0]])
    test = truth + np.array([[2.0, 3.0], [22.0, 23.0]])  # limits at q = 1e-6: 2.5, 22.5 mm
    assert bad_pixel_fraction(truth, test) == 1.0
    assert bad_pixel_fraction(truth, test, noise_quad=1e-6) == pytest.approx(0.5)
    assert bad_pixel_fraction(truth, test, threshold=2.0, noise_quad=1e-7) == pytest.approx(0.75)
    for bad in (-1e-6, math.nan, math.inf):
        with pytest.raises(ParameterError, match="noise_quad must be"):
            bad_pixel_fraction(truth, test, noise_quad=bad)


@pytest.mark.parametrize("name", ["threshold", "noise_quad"])
@pytest.mark.parametrize("value", ["1", None, True])
def test_bad_pixels_name_a_threshold_that_is_not_a_number(name, value):
    """``threshold="1"`` raised math.isfinite's TypeError."""
    with pytest.raises(ParameterTypeError, match=rf"^{name} must be a number"):
        bad_pixel_fraction(np.ones(3), np.ones(3), **{name: value})
    assert bad_pixel_fraction(np.ones(3), np.ones(3), **{name: np.float32(1)}) == 0.0


def test_temporal_flicker_matches_std(rng):
    depth = 500.0 + rng.normal(0, 0.3, (20, 6, 7))
    depth[3, 0, 0] = np.nan
    static = np.ones((6, 7), bool)
    static[5] = False
    f = temporal_flicker(depth, static=static)
    ref = depth[:, :5].std(axis=0).ravel()[1:]
    assert f.num_pixels == 34
    assert f.median == pytest.approx(np.median(ref), rel=1e-5)
    assert f.mean == pytest.approx(ref.mean(), rel=1e-5)
    assert np.isnan(f.std_map[0, 0])
    assert np.isnan(f.std_map[5, 3])
    with pytest.raises(ValueError, match="at least 2 frames"):
        temporal_flicker(depth[:1])


def test_flow_errors():
    truth = np.zeros((1, 2, 3, 2))
    test = np.zeros((1, 2, 3, 2))
    test[..., 0] = 3.0
    test[..., 1] = 4.0
    truth[0, 0, 0] = np.nan  # unknown GT excluded
    assert flow_endpoint_error(truth, test) == pytest.approx(5.0)
    assert flow_angular_error(truth, truth) == pytest.approx(0.0, abs=1e-5)
    # (1, 0) vs (0, 0): angle between (1, 0, 1) and (0, 0, 1) = 45 degrees
    one = np.zeros((1, 1, 1, 2))
    one[..., 0] = 1.0
    assert flow_angular_error(np.zeros((1, 1, 1, 2)), one) == pytest.approx(45.0)
    mask = np.zeros((1, 2, 3), bool)
    assert math.isnan(flow_endpoint_error(truth, test, roi=mask))


# ---------------------------------------------------------------------------- acceptance
def test_small_ball_roughness_grows_with_noise():
    means = []
    for sd in (0.0, 0.1, 0.2):
        seq = make_falling_ball(small=True, num_frames=3, depth_noise=sd)
        means.append(roughness_stats(seq.points(), roi=ball_roi(seq)).mean)
    # curvature floor: 4x coarser sampling than full size -> 16 x 0.12 mm (EVALUATION §1)
    assert means[0] == pytest.approx(16 * 0.1226, rel=0.05)
    assert means[0] < means[1] < means[2]


@pytest.mark.slow
def test_full_ball_matches_spec_simulation():
    """EVALUATION §1: raw Pi = 3.62 mm at sigma_d = 0.2 mm (tolerance 5 %), paper 3.75."""
    seq = make_falling_ball(num_frames=10)
    stats = roughness_stats(seq.points(), roi=ball_roi(seq))
    assert stats.mean == pytest.approx(3.62, rel=0.05)
    assert stats.rms_mean == pytest.approx(0.17, rel=0.05)


# ---------------------------------------------------------------------------- CLI
@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--window", "999"], "--window 999: larger than the 150x150 image"),  # was n/a
        (["--max-step", "-1"], "--max-step must be a depth step > 0 mm"),  # was ignored
        (["--max-step", "nan"], "--max-step must be a depth step > 0 mm"),
    ],
)
def test_cli_metrics_options_it_cannot_use_are_one_line(tmp_path, capsys, args, says):
    out = tmp_path / "ball.npz"
    assert main(["synth", "ball", "-o", str(out), "--small", "--frames", "2"]) == 0
    capsys.readouterr()
    assert main(["metrics", str(out), "--no-shape", *args]) == 2
    assert says in capsys.readouterr().err


def test_cli_metrics_json_on_synthetic_ball(tmp_path, capsys):
    out = tmp_path / "ball.npz"
    assert main(["synth", "ball", "-o", str(out), "--small", "--frames", "4"]) == 0
    capsys.readouterr()
    assert main(["metrics", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["roi"]["description"].startswith("ball ROI")
    assert res["roi"]["pixels"] > 4000
    out = res["output"]
    assert "raw" not in res
    assert 3.0 < out["roughness_mean"] < 5.0
    assert 0.15 < out["rms_residual"] < 0.21
    assert out["rmse"] == pytest.approx(0.2, rel=0.05)
    assert out["bad_1mm"] < 1e-3
    assert 0.1 < out["flicker_std_median"] < 0.25
    assert res["static"]["description"].startswith("static in the ground truth")
    assert out["shape"]["c_3d_mean"] > 0.999


def test_cli_metrics_default_and_file_roi(tmp_path, capsys):
    seq = make_static_plane(small=True, num_frames=3)
    from fuse4d.io import write_npz

    path = tmp_path / "plain.npz"
    write_npz(seq.with_depth(seq.depth).__class__(seq.depth, seq.intensity, seq.intrinsics), path)
    assert main(["metrics", str(path), "--json", "--frames", "1:3"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["roi"]["description"].startswith("5x5 windows fully valid")
    assert res["frames"] == [1, 3]
    assert res["output"]["rmse"] is None
    roi = np.zeros((150, 150), bool)
    roi[70:80, 70:80] = True
    np.savez(tmp_path / "roi.npz", mask=roi)
    assert main(["metrics", str(path), "--json", "--roi", str(tmp_path / "roi.npz")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["roi"]["pixels"] == 300
    # the same pixels as a box, the form `fuse4d report --roi` takes: the same scores
    assert main(["metrics", str(path), "--json", "--roi", "70:80,70:80"]) == 0
    box = json.loads(capsys.readouterr().out)
    assert box["roi"]["description"] == "box rows 70:80, columns 70:80"
    assert box["output"] == res["output"]
    assert box["roi"]["pixels"] == 300
    assert main(["metrics", str(path), "--gt", str(path), "--json", "--window", "3"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["output"]["rmse"] == 0.0
    assert res["output"]["bad_1mm"] == 0.0


def test_cli_metrics_bad_input(tmp_path, capsys):
    assert main(["metrics", str(tmp_path / "missing.npz"), "--json"]) == 2
    assert "fuse4d: error:" in capsys.readouterr().err
    np.savez(tmp_path / "roi.npz", other=np.ones(3))
    out = tmp_path / "b.npz"
    main(["synth", "ball", "-o", str(out), "--small", "--frames", "2"])
    capsys.readouterr()
    assert main(["metrics", str(out), "--roi", str(tmp_path / "roi.npz")]) == 2
    assert "no mask key: needs a key 'mask' or 'roi'" in capsys.readouterr().err
    for box, message in (("0:5,7", "must look like R0:R1,C0:C1"), ("0:5,0:999", "not a non-empty")):
        assert main(["metrics", str(out), "--roi", box]) == 2
        assert message in capsys.readouterr().err
        assert main(["metrics", str(out), "--static-mask", box]) == 2
        assert message in capsys.readouterr().err
    assert main(["metrics", str(out), "--window", "4"]) == 2
    assert "--window must be an odd integer" in capsys.readouterr().err


def test_plot_roughness_map_and_save_figure(tmp_path):
    from fuse4d.errors import OutputExistsError
    from fuse4d.plot import plot_roughness_map, save_figure

    seq = make_falling_ball(small=True, num_frames=2)
    fig = plot_roughness_map(roughness(seq.points()[0]), vmax=8.0, title="raw")
    out = save_figure(fig, tmp_path / "map.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["map.png"]  # no temporary left
    with pytest.raises(OutputExistsError, match="output exists"):
        save_figure(fig, out)
    with pytest.raises(ValueError, match="vmax must exceed vmin"):
        plot_roughness_map(np.zeros((4, 4)), vmax=0.0)


def test_roughness_of_a_depth_map_says_how_to_make_points():
    """A (T, H, W) depth passed to the roughness (which takes 3D points) got "must have shape
    (H, W, 3)"; the message now names the conversion."""
    depth = np.full((2, 16, 20), 500.0, np.float32)
    for wrong in (depth, depth[0]):
        with pytest.raises(ShapeError, match=r"3D points in mm \(from depth: fuse4d.depth_to_"):
            roughness_stats(wrong)


# ------------------------------------------------------- invalid depth, mask types and files
def test_zero_and_negative_depth_are_invalid_in_the_metrics():
    """A 16-bit file's hole (0) scored as a depth of 0 mm: a 1000 mm error in the RMSE."""
    truth = np.array([[1000, 1000], [1000, 1000]], np.uint16)
    test = np.array([[1002, 0], [1000, 1000]], np.uint16)
    before = test.copy()
    assert depth_rmse(truth, test) == pytest.approx(math.sqrt(4 / 3))
    np.testing.assert_array_equal(test, before)  # never written to
    truth[1, 1] = 0  # a hole in the truth is not scored; one in the test counts as bad
    assert bad_pixel_fraction(truth, test) == pytest.approx(2 / 3)
    assert math.isnan(bad_pixel_fraction(-1.0 * truth.astype(np.float32), test))  # no truth
    video = np.full((3, 8, 8), 1000.0, np.float32)
    video[1, 0, 0] = 0.0
    video[2, 1, 1] = -5.0
    kept = video.copy()
    f = temporal_flicker(video)
    assert f.num_pixels == 62
    assert f.mean == 0.0
    np.testing.assert_array_equal(video, kept)
    rep = evaluate(video, intrinsics=Intrinsics(100.0, 100.0, 3.5, 3.5, 8, 8))
    assert rep.output.fill_rate == pytest.approx(1 - 2 / 192)
    np.testing.assert_array_equal(video, kept)


def test_as_video_copies_only_where_depth_is_invalid():
    k = Intrinsics(100.0, 100.0, 1.5, 1.5, 4, 4)
    depth = np.full((2, 4, 4), 800.0, np.float32)
    d, p, _ = _as_video(depth, k, "output")
    assert d is depth  # all valid: no copy
    points = depth_to_points(depth, k)
    d, p, _ = _as_video(points, k, "output")
    assert np.shares_memory(p, points)
    points[0, 1, 1] = 0.0
    d, p, _ = _as_video(points, k, "output")
    assert not np.shares_memory(p, points)
    assert np.isnan(p[0, 1, 1]).all()
    assert (points[0, 1, 1] == 0.0).all()
    assert np.isnan(d[0, 1, 1])


def test_masks_of_the_wrong_type_are_parameter_type_errors():
    seq = make_falling_ball(small=True, num_frames=2)
    ints = np.ones(seq.shape, np.int64)
    with pytest.raises(ParameterTypeError, match="static must be a boolean mask, got dtype int64"):
        evaluate(seq, static=ints)
    with pytest.raises(ShapeError, match=r"static must have shape \(150, 150\), got \(3, 3\)"):
        evaluate(seq, static=np.ones((3, 3), bool))
    with pytest.raises(ParameterTypeError, match="roi must be a boolean"):
        evaluate(seq, roi=ints)
    with pytest.raises(ParameterTypeError, match="roi must be a boolean"):
        depth_rmse(seq.depth, seq.depth, roi=ints)
    with pytest.raises(ParameterTypeError, match="static must be a boolean"):
        temporal_flicker(seq.depth, static=ints)
    flow = np.zeros((1, 150, 150, 2))
    with pytest.raises(ParameterTypeError, match="roi must be a boolean"):
        flow_endpoint_error(flow, flow, roi=ints)
    with pytest.raises(ParameterTypeError, match="roi must be a boolean"):
        roughness_stats(seq.points(), roi=ints)


def test_read_mask_npy_nan_and_unknown_files(tmp_path):
    mask = np.zeros((2, 6, 5), np.uint8)
    mask[:, 1:3, 2:4] = 7
    np.save(tmp_path / "m.npy", mask)
    np.testing.assert_array_equal(read_mask(tmp_path / "m.npy"), mask != 0)
    np.testing.assert_array_equal(read_mask(tmp_path / "m.npy", frames="1:2"), mask[1:2] != 0)
    (tmp_path / "bad.npy").write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(InputFileError, match=r"not a valid \.npy file"):
        read_mask(tmp_path / "bad.npy")
    np.save(tmp_path / "obj.npy", np.array([None, 1], dtype=object), allow_pickle=True)
    with pytest.raises(InputFileError, match=r"not a valid \.npy file"):
        read_mask(tmp_path / "obj.npy")
    floats = np.ones((6, 5), np.float32)
    floats[0, 0] = np.nan
    np.savez(tmp_path / "nan.npz", mask=floats)
    with pytest.raises(InputFileError, match="mask holds 1 NaN values"):
        read_mask(tmp_path / "nan.npz")
    (tmp_path / "m.txt").write_text("not a mask")
    with pytest.raises(InputFileError, match=r"an image \(PNG, JPEG, TIFF\), an \.npz, an \.npy"):
        read_mask(tmp_path / "m.txt")


def test_cli_metrics_checks_a_static_mask_per_frame(tmp_path, capsys):
    out = tmp_path / "ball.npz"
    assert main(["synth", "ball", "-o", str(out), "--small", "--frames", "3"]) == 0
    capsys.readouterr()
    static = np.zeros((10, 150, 150), bool)
    static[:, :20, :20] = True
    np.savez(tmp_path / "s.npz", mask=static)
    assert main(["metrics", str(out), "--no-shape", "--static-mask", str(tmp_path / "s.npz")]) == 2
    assert "--static-mask: mask has 10 frames, the input 3" in capsys.readouterr().err
    np.save(tmp_path / "s.npy", static[0])
    args = ["metrics", str(out), "--no-shape", "--json", "--static-mask", str(tmp_path / "s.npy")]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["output"]["flicker_pixels"] == 400
