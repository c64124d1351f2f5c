"""Tests of the 4D fusion pipeline (METHOD §3-§8; issue 3 acceptance list)."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest

from fuse4d import Intrinsics, ShapeError, depth_to_points
from fuse4d._kernels.fusion import (
    _fill_holes_kernel,
    _fuse_kernel,
    _project_to_rays_kernel,
    _segment_box_rows_kernel,
)
from fuse4d.bilateral import bilateral_filter_points
from fuse4d.config import LITERAL_PAPER, FusionParams, preset
from fuse4d.flow import SequenceFlow
from fuse4d.fusion import (
    CURVATURE_MIN_BIAS,
    CURVATURE_TEST_LEVEL,
    FusionEngine,
    curvature_f_critical,
    fuse_sequence,
    fuse_stream,
)
from fuse4d.holes import SOURCE_NONE, SOURCE_OUTSIDE, SOURCE_TIME, _fill_holes, fill_holes
from fuse4d.metrics import roughness_stats
from fuse4d.motion import (
    _pair_motion,
    _pair_ring,
    _track_window,
    _window,
    compute_motion_field,
    estimate_noise_quad,
    motion_reference_depth,
    track_frame,
)
from naive import fusion as naive

H, W = 40, 48
K = Intrinsics(fx=120.0, fy=120.0, cx=23.5, cy=19.5, width=W, height=H)


def _texture(h, w, seed=0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.zeros((h, w))
    for _ in range(12):
        fx, fy = rng.uniform(0.05, 0.5, 2)
        img += np.sin(fx * xx + fy * yy + rng.uniform(0, 6.28))
    img = (img - img.min()) / (img.max() - img.min())
    return (0.15 + 0.7 * img).astype(np.float32)


def _plane_depth(n, *, slope=0.5, base=500.0):
    """Depth of the 3D plane Z = base + s_x X + s_y Y (s_x = slope * fx / base mm/mm)."""
    yy, xx = np.mgrid[0:H, 0:W]
    sx = slope * K.fx / base
    sy = 0.2 * K.fy / base
    z = base / (1.0 - sx * (xx - K.cx) / K.fx - sy * (yy - K.cy) / K.fy)
    return np.broadcast_to(z, (n, H, W)).astype(np.float32).copy()


def _translating(n, speed=2):
    """A textured plane moving down by ``speed`` px/frame (integer): exact flows known."""
    big = _texture(H + speed * n, W, seed=3)
    inten = np.stack([big[speed * (n - 1 - t) : speed * (n - 1 - t) + H] for t in range(n)])
    depth = np.full((n, H, W), 600.0, np.float32)
    fwd = np.zeros((n - 1, H, W, 2), np.float32)
    fwd[..., 1] = speed
    bwd = -fwd
    return depth, inten, fwd, bwd


def _zero_flow(n):
    z = np.zeros((n - 1, H, W, 2), np.float32)
    return SequenceFlow(z, z.copy())


# ----------------------------------------------------------------------------- kernels vs oracles
@pytest.mark.parametrize("radius", [2, 3])  # 3: the seven-column unrolled path away from borders
def test_bilateral_kernel_matches_oracle(rng, radius):
    pts = depth_to_points(_plane_depth(1)[0] + rng.normal(0, 0.3, (H, W)), K)[:12, :14]
    pts[3, 4] = np.nan
    pts[6, 1] = np.nan  # a NaN among the border columns
    inten = _texture(12, 14)
    ref = pts + np.float32(0.1)
    for reference in (None, ref):
        fast = bilateral_filter_points(
            pts, inten, radius=radius, sigma_distance=2.0, sigma_intensity=0.1, reference=reference
        )
        slow = naive.bilateral3d(pts, inten, radius, 2.0, 0.1, reference=reference)
        np.testing.assert_allclose(fast, slow, rtol=0, atol=2e-4)
        assert np.isnan(fast[3, 4]).all()
        assert np.isfinite(fast[3, 5]).all()  # NaN does not spread


@pytest.mark.parametrize("radius", [2, 3])
def test_bilateral_kernel_sums_each_row_over_its_valid_span(rng, radius):
    """issue 13: each row is summed only between its first and last valid centre (the band
    a registered depth image leaves empty); rows that start or end inside the border columns
    of the radius-3 path, rows without or with one valid pixel, still match the oracle."""
    full = depth_to_points(_plane_depth(1)[0] + rng.normal(0, 0.3, (H, W)), K)[:14, :20]
    pts = full.copy()
    pts[:2] = np.nan  # rows without depth
    pts[2:, :5] = np.nan  # a left band wider than the border columns
    pts[2:, 17:] = np.nan  # a right band ending inside them
    pts[6, :] = np.nan
    pts[6:8, 19] = full[6:8, 19]  # one valid pixel in the last column (and below it)
    pts[8, :] = np.nan
    pts[8, 1] = full[8, 1]  # one in the second column
    pts[10, :] = np.nan
    pts[10, 5:14] = full[10, 5:14]  # a row within the seven-column middle only
    pts[11, :3] = full[11, :3]  # a row reaching into the left border columns again
    inten = _texture(14, 20)
    fast = bilateral_filter_points(
        pts, inten, radius=radius, sigma_distance=2.0, sigma_intensity=0.1, reference=pts + 0.1
    )
    slow = naive.bilateral3d(pts, inten, radius, 2.0, 0.1, reference=pts + 0.1)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=2e-4)
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(pts))


def test_bilateral_radius_past_the_image_is_the_whole_image_and_quick(rng):
    """A radius larger than the image (``--set spatial_radius=1000000``) looped over a
    million empty column offsets per row pair (a hang); it equals the image-wide window."""
    pts = depth_to_points(_plane_depth(1)[0] + rng.normal(0, 0.3, (H, W)), K)[:10, :12]
    inten = _texture(10, 12)
    whole = bilateral_filter_points(pts, inten, radius=12, reference=pts + 0.1)
    huge = bilateral_filter_points(pts, inten, radius=10**9, reference=pts + 0.1)
    np.testing.assert_array_equal(huge, whole)
    np.testing.assert_allclose(
        whole, naive.bilateral3d(pts, inten, 12, 2.0, 0.1, pts + 0.1), atol=2e-4
    )


def test_vanishing_sigmas_weigh_the_centre_not_nan(rng):
    """A sigma so small that 1 / (2 sigma^2) overflows float32 gave the centre 0 x inf = NaN
    weight: every output NaN. Now only equal values weigh: the residual bilateral returns
    each point itself; the temporal weights of a tiny sigma_temporal are (1, 0, 0, ...)."""
    from fuse4d._kernels._common import MAX_GAUSS_FACTOR, gauss_factor

    pts = depth_to_points(_plane_depth(1)[0] + rng.normal(0, 0.3, (H, W)), K)[:10, :12]
    out = bilateral_filter_points(
        pts, _texture(10, 12), sigma_distance=1e-30, sigma_intensity=1e-30, reference=pts
    )
    np.testing.assert_array_equal(out, pts)
    assert gauss_factor(1e-200) == MAX_GAUSS_FACTOR  # 2 sigma^2 == 0.0: no ZeroDivisionError
    assert gauss_factor(2.0) == 1.0 / 8.0
    engine = FusionEngine(K, fusion=FusionParams(sigma_temporal=1e-200))
    np.testing.assert_array_equal(engine._temporal_weight[:2], [1.0, 0.0])


def test_bilateral_planes_kernel_equals_numpys_planes_and_residuals(rng):
    """issue 13: the planar inputs of the residual bilateral in one pass are the numpy
    values, bit for bit (NaN points included)."""
    from fuse4d._kernels.fusion import _bilateral_planes_kernel

    pts = depth_to_points(_plane_depth(1)[0] + rng.normal(0, 0.3, (H, W)), K)
    pts[2, 3] = np.nan
    ref = (pts + rng.normal(0, 0.5, pts.shape)).astype(np.float32)
    planes = np.empty((3, H, W), np.float32)
    values = np.empty_like(planes)
    _bilateral_planes_kernel(pts, ref, planes, values)
    np.testing.assert_array_equal(planes, np.moveaxis(pts, -1, 0))
    np.testing.assert_array_equal(values, np.moveaxis(pts - ref, -1, 0))


def test_weight_function_is_close_to_exp():
    x = np.linspace(0, 4, 41)
    approx = np.array([naive.approx_exp_neg(v) for v in x])
    np.testing.assert_allclose(approx, np.exp(-x), rtol=0.009)


@pytest.mark.parametrize("quad", [0.0, 2e-5])
def test_segment_box_kernel_matches_oracle(rng, quad):
    depth = (500 + rng.normal(0, 1, (6, 30))).astype(np.float32)
    depth[:, 12:] += 50.0  # a depth edge
    depth[:, 20:] += 9.0 + 4.0 * rng.random((6, 1)).astype(np.float32)  # cut only if quad = 0
    depth[2, 5] = np.nan
    values = depth.copy()
    out = np.empty_like(depth)
    _segment_box_rows_kernel(values, depth, 3, 10.0, quad, out)
    expected = naive.segment_box_rows(values, depth, 3, 10.0, quad)
    np.testing.assert_allclose(out, expected, atol=1e-4)
    # quad = 2e-5 mm^-1: limit 2.5 q z^2 = 15 mm at 550 mm joins the 9-13 mm step, not the 50 mm
    cut = naive.segment_box_rows(values, depth, 3, 10.0, 0.0)
    assert (np.abs(expected - cut)[:, 17:23].max() > 1.0) == (quad > 0)


def test_segment_box_pass_rounds_as_before():
    """The box pass's rounding is written out (``_kernels/_segments.py``) as the original
    kernel's compiled code did it: a cut window in the first L - L % 8 pixels of a segment of
    L >= 8 takes one reciprocal of n for both means, elsewhere two divisions (here the same
    window, pixel 0, rounds to -0.5799999237 in segments of 16 and 13 but -0.5799999833 in
    one of 5). Pinned values, so that the fused output cannot move by an ulp."""
    x = [-1.65, 2.68, 0.59, 1.51, -4.51, 2.85, -4.71, 0.57, 4.08, 5.64, 1.53, 2.64, -1.82, -1.44]
    x = np.array([*x, 3.51, 0.0], np.float32)
    pinned = {
        16: [-0.5799999237060547, 0.4130000174045563, 0.5830000042915344, 1.409999966621399],
        13: [-0.5799999237060547, 0.4130000174045563, 0.9340000152587891, -0.8916666507720947],
        5: [-0.5799999833106995, 0.4130000174045563, -0.9650000929832458, -3.3533334732055664],
    }
    for n, want in pinned.items():
        out = np.empty((1, n), np.float32)
        _segment_box_rows_kernel(
            x[None, :n].copy(), np.full((1, n), 1e3, np.float32), 2, 10.0, 0.0, out
        )
        np.testing.assert_array_equal(out[0, [0, 1, n - 2, n - 1]], np.float32(want))


def test_motion_reference_never_crosses_edges():
    d = np.full((20, 30), 500.0, np.float32)
    d[:, 15:] = 800.0
    d[5, 5] = np.nan
    r = motion_reference_depth(d, sigma=5.0)
    np.testing.assert_array_equal(r[:, :15][np.isfinite(r[:, :15])], 500.0)
    np.testing.assert_array_equal(r[:, 15:], 800.0)
    assert np.isnan(r[5, 5])


def _random_window(rng, n=5, h=14, w=16):
    """A noisy plane crop with random sub-pixel flows whose FB errors straddle theta = 1 px."""
    depth = _plane_depth(n)[:, :h, :w] + rng.normal(0, 0.2, (n, h, w)).astype(np.float32)
    depth[n // 2, 4, 4] = np.nan
    fwd = rng.uniform(-0.7, 0.9, (n - 1, h, w, 2)).astype(np.float32)
    bwd = (-fwd + rng.normal(0, 0.6, fwd.shape)).astype(np.float32)
    return depth, fwd, bwd


# quad = 1.2e-6 mm^-1 gives a step limit 2.5 q z^2 ~ 0.75-0.8 mm > max_step = 0.6 mm on this
# ~500-mm plane: the A22 branch of the depth-step rule decides part of the steps
NOISE_CASES = [
    pytest.param(0.0, False, 0.0, 0.0, id="no-noise-model"),
    pytest.param(1.2e-6, False, 0.2, 0.5, id="noise-model"),
    pytest.param(1.2e-6, True, 0.2, 0.5, id="noise-model-per-step"),
]


@pytest.mark.parametrize(("quad", "per_step", "sigma0", "min_gate"), NOISE_CASES)
def test_track_and_fuse_kernels_match_oracles(rng, quad, per_step, sigma0, min_gate):
    n = 5
    depth, fwd, bwd = _random_window(rng, n)
    t, first, last = 2, 0, 4
    slots, rows, cols, ok = _track_window(
        _pair_ring(fwd),
        _pair_ring(bwd),
        depth,
        t,
        first,
        last,
        fb_threshold=1.0,
        max_step=0.6,
        quad=quad,
        per_step=per_step,
    )
    oracle = naive.track(fwd, bwd, depth, t, first, last, 1.0, 0.6, quad, per_step)
    others = [T for T in range(first, last + 1) if t != T]
    for k, T in enumerate(others):
        for v in range(14):
            for u in range(16):
                r, c, alive = oracle[(T, v, u)]
                assert ok[k, v, u] == alive, (T, v, u)
                if alive:
                    assert (rows[k, v, u], cols[k, v, u]) == (r, c)
    assert 0 < ok.mean() < 1  # the test exercises both outcomes
    if quad > 0:  # ... and the noise-model branch of the step rule changed some of them
        fixed = naive.track(fwd, bwd, depth, t, first, last, 1.0, 0.6, 0.0, per_step)
        assert any(fixed[key][2] != oracle[key][2] for key in oracle)
    bil = rng.normal(0, 0.3, (n, 14, 16, 3)).astype(np.float32) + 500
    ref = rng.normal(0, 0.3, (n, 14, 16, 3)).astype(np.float32) + 500
    ref[2, 4, 4] = np.nan
    weights = np.exp(-(np.arange(3.0) ** 2) / 18.0)
    out = np.empty((14, 16, 3), np.float32)
    support = np.empty((14, 16), np.uint8)
    hole = np.empty((14, 16), bool)
    base = np.empty((14, 16, 3), np.float32)
    gate_factor = 1.0 if quad == 0 else 3.0
    sigma0 = 0.8 if quad == 0 else sigma0  # quad = 0: a plain 0.8 mm gate
    gate = naive.noise_gate(gate_factor, sigma0, quad, min_gate)
    f_crit = curvature_f_critical(4)
    # frame base, line (A21), parabola (A28), the F-test choice (A32)
    for trajectory in (0, 1, 2, 3):
        _fuse_kernel(
            bil,
            ref,
            slots,
            t,
            first,
            rows,
            cols,
            ok,
            weights,
            1,
            gate_factor,
            sigma0,
            quad,
            min_gate,
            trajectory,
            f_crit,
            CURVATURE_MIN_BIAS,
            np.zeros((14, 16), bool),  # no static pixels (A33 has its own tests)
            0.0,
            out,
            support,
            hole,
            base,
        )
        expected, exp_support = naive.fuse(
            bil,
            ref,
            oracle,
            t,
            first,
            last,
            weights,
            gate,
            trajectory=trajectory,
            noise=lambda z: max(sigma0, quad * z * z),
            min_bias=CURVATURE_MIN_BIAS,
        )
        np.testing.assert_array_equal(support, exp_support)
        fused = support >= 1
        np.testing.assert_allclose(out[fused], expected[fused], atol=1e-4)
        np.testing.assert_array_equal(out[hole], bil[t][hole])  # holes keep B^t (fallback)
        # base_out (A29) is the trajectory fit's offset: output minus it = the frame-base output
        valid = np.isfinite(ref[t, ..., 2])
        assert np.isnan(base[~valid]).all()
        if trajectory == 0:
            frame_out = out.copy()
            np.testing.assert_array_equal(base[valid], 0.0)
        np.testing.assert_allclose((out - base)[fused], frame_out[fused], atol=1e-4)
        # the gate rejected some tracked samples, and not all
        assert 0 < support.sum() < ok[:, np.isfinite(ref[t, ..., 2])].sum()


def _fuse_static_tracks(ref, trajectory, f_crit, sigma0):
    """_fuse_kernel on a 9-frame window whose tracks all stay on their pixel, B = P~
    (no detail), depth noise sigma0 mm: the output is P~^4 + the trajectory base."""
    n, h, w, _ = ref.shape
    rows = np.broadcast_to(np.arange(h)[None, :, None], (n - 1, h, w)).astype(np.int32)
    cols = np.broadcast_to(np.arange(w)[None, None, :], (n - 1, h, w)).astype(np.int32)
    ok = np.ones((n - 1, h, w), bool)
    out = np.empty((h, w, 3), np.float32)
    base = np.empty((h, w, 3), np.float32)
    support = np.empty((h, w), np.uint8)
    hole = np.empty((h, w), bool)
    weights = np.exp(-(np.arange(5.0) ** 2) / 18.0)
    slots = np.arange(n, dtype=np.int64)
    args = (ref, ref, slots, 4, 0, rows, cols, ok, weights, 1, math.inf, sigma0, 0.0, 0.05)
    no_static = np.zeros((h, w), bool)
    _fuse_kernel(
        *args, trajectory, f_crit, CURVATURE_MIN_BIAS, no_static, 0.0, out, support, hole, base
    )
    return out


def test_adaptive_base_takes_the_parabola_only_where_the_line_is_rejected(rng):
    # A32: pixel (0, 0) moves linearly in depth, pixel (0, 1) on a parabola (1 mm/frame^2,
    # a bounce), pixel (0, 2) only laterally on a parabola (a lateral bounce at constant
    # depth), pixel (0, 3) on a parabola too flat to matter (0.02 mm/frame^2: the line's
    # chord bias ~0.1 mm, a fifth of the 1 mm noise sigma; significant against the 0.01 mm
    # scatter of this test's samples, but it keeps the line)
    tau = np.arange(-4.0, 5.0)
    ref = np.zeros((9, 1, 4, 3), np.float32)
    ref[..., 0] = 10.0
    ref[..., 1] = -20.0
    ref[..., 2] = 1000.0
    ref[:, 0, 0, 2] += 2.0 * tau
    ref[:, 0, 1, 2] += 2.0 * tau + tau**2
    ref[:, 0, 2, 1] += 3.0 * tau + tau**2
    ref[:, 0, 3, 2] += 2.0 * tau + 0.02 * tau**2
    ref += rng.normal(0, 0.01, ref.shape).astype(np.float32)
    f_crit = curvature_f_critical(6)
    line, parabola, adaptive = (_fuse_static_tracks(ref, k, f_crit, 1.0) for k in (1, 2, 3))
    np.testing.assert_array_equal(adaptive[0, 0], line[0, 0])
    np.testing.assert_array_equal(adaptive[0, 1], parabola[0, 1])
    np.testing.assert_array_equal(adaptive[0, 2], parabola[0, 2])  # one model for the point
    np.testing.assert_array_equal(adaptive[0, 3], line[0, 3])
    assert abs(parabola[0, 3, 2] - line[0, 3, 2]) > 0.05  # the flat curve was detectable
    # the line's chord bias is what the parabola removes: the true value at tau = 0
    assert abs(line[0, 1, 2] - 1000.0) > 3.0
    assert abs(adaptive[0, 1, 2] - 1000.0) < 0.1
    assert abs(adaptive[0, 2, 1] - -20.0) < 0.1
    # with a tiny noise sigma the flat curve takes the parabola too
    tiny = _fuse_static_tracks(ref, 3, f_crit, 0.01)
    np.testing.assert_array_equal(tiny[0, 3], parabola[0, 3])
    # and the same choices as the scipy.stats oracle
    for sigma0, fused in ((1.0, adaptive), (0.01, tiny)):
        expected, _ = naive.fuse(
            ref,
            ref,
            {(T, 0, u): (0, u, True) for T in range(9) for u in range(4)},
            4,
            0,
            8,
            np.exp(-(np.arange(5.0) ** 2) / 18.0),
            math.inf,
            trajectory=3,
            noise=lambda z, s=sigma0: s,
            min_bias=CURVATURE_MIN_BIAS,
        )
        np.testing.assert_allclose(fused, expected, atol=1e-3)


def test_curvature_critical_values_are_the_f_quantiles():
    from scipy.stats import f as f_dist

    crit = curvature_f_critical(12)
    assert crit[0] == math.inf
    k = np.arange(1, 13)
    np.testing.assert_allclose(crit[1:], f_dist.ppf(1 - CURVATURE_TEST_LEVEL / 3, 1, k), rtol=1e-9)


def test_curvature_critical_table_is_scipys_and_covers_the_long_windows():
    """The engine's critical values come from a table (scipy.special's import cost 0.23 s of
    every start-up): scipy's own values up to 62 degrees of freedom, computed beyond it, and
    for another level."""
    from scipy.special import stdtrit

    for max_df, level in ((62, CURVATURE_TEST_LEVEL), (80, CURVATURE_TEST_LEVEL), (6, 0.01)):
        crit = curvature_f_critical(max_df, level)
        k = np.arange(1, max_df + 1)
        np.testing.assert_allclose(crit[1:], stdtrit(k, 1.0 - level / 6.0) ** 2, rtol=1e-13)
        assert crit.size == max_df + 1
    assert curvature_f_critical(0).tolist() == [math.inf, pytest.approx(1458.358423480592)]


@pytest.mark.parametrize("per_step", [False, True])
def test_pair_diagnostics_kernel_matches_oracle(rng, per_step):
    depth, fwd, bwd = _random_window(rng, 2)
    depth[1, 7:9, 3:6] = np.nan
    small = Intrinsics(fx=120.0, fy=120.0, cx=7.5, cy=6.5, width=16, height=14)
    ref = depth_to_points(depth, small) + rng.normal(0, 0.1, (2, 14, 16, 3)).astype(np.float32)
    quad = 1.2e-6
    motion, fb = _pair_motion(
        _pair_ring(fwd),
        _pair_ring(bwd),
        ref,
        depth,
        0,
        fb_threshold=1.0,
        max_step=0.6,
        quad=quad,
        per_step=per_step,
    )
    exp_fb, exp_motion = naive.pair_motion(
        fwd[0], bwd[0], ref[0], ref[1], depth[0], depth[1], 1.0, 0.6, quad, per_step
    )
    np.testing.assert_array_equal(np.isnan(fb), np.isnan(exp_fb))
    np.testing.assert_allclose(fb, exp_fb, atol=1e-5)
    valid = np.isfinite(motion[..., 0])
    np.testing.assert_array_equal(valid, np.isfinite(exp_motion[..., 0]))
    np.testing.assert_allclose(motion[valid], exp_motion[valid], atol=1e-4)
    assert 0 < valid.mean() < 1
    # validity is exactly the first tracking step of frame 0 (one rule, A22)
    tracks = naive.track(fwd, bwd, depth, 0, 0, 1, 1.0, 0.6, quad, per_step)
    first_step = np.array([[tracks[(1, v, u)][2] for u in range(16)] for v in range(14)])
    np.testing.assert_array_equal(valid, first_step)


def _bumpy_surface(rng, h=16, w=18):
    yy, xx = np.mgrid[0:h, 0:w]
    depth = 500 + 0.8 * xx + 0.3 * yy + 0.05 * (xx - 8.0) ** 2 + rng.normal(0, 0.05, (h, w))
    depth[:, 13:] += 30.0  # a depth edge
    return depth.astype(np.float32), Intrinsics(100, 100, 8.5, 7.5, w, h)


def test_fill_holes_kernel_matches_oracle(rng):
    """Eq. 6 weights, Jacobians, onion order (a 5x5 hole needs 3 passes) and the A20 gate."""
    depth, k = _bumpy_surface(rng)
    raw = depth_to_points(depth, k)
    raw[0, 0] = np.nan
    hole = np.zeros(depth.shape, bool)
    hole[4:9, 3:8] = True  # onion: 3 passes
    hole[12, 10:12] = True
    hole[2, 12:14] = True  # at the depth edge: extrapolation from the far side is gated out
    hole[14, 0] = True
    points = raw + rng.normal(0, 0.05, raw.shape).astype(np.float32)
    points[hole] += np.float32(0.4)  # fallback values, off the surface
    for gate in (math.inf, 1.0):
        fast_points = points.copy()
        fast_hole = hole.copy()
        filled = _fill_holes(
            fast_points,
            raw,
            fast_hole,
            radius=2,
            sigma=2.0,
            passes=10,
            min_neighbours=3,
            gate=gate,
        )
        exp_points, exp_hole, exp_filled = naive.fill_holes(points, raw, hole, 2, 2.0, 10, 3, gate)
        np.testing.assert_array_equal(filled, exp_filled)
        np.testing.assert_array_equal(fast_hole, exp_hole)
        np.testing.assert_allclose(fast_points, exp_points, atol=1e-3)
        if gate == math.inf:  # literal Eq. 6: every hole with enough neighbours is filled
            np.testing.assert_array_equal(filled, hole)
        else:  # A20: the gate refuses part of the fills
            assert 0 < filled.sum() < hole.sum()
    # one pass reaches only the outer ring of the 5x5 hole (onion order)
    one = naive.fill_holes(points, raw, hole, 2, 2.0, 1, 3, math.inf)[2]
    assert one[4, 3:8].all()
    assert not one[6, 5]
    public, public_filled = fill_holes(points, raw, hole, gate=1.0)  # validated face, copy
    np.testing.assert_array_equal(public_filled, exp_filled)
    np.testing.assert_allclose(public, exp_points, atol=1e-3)
    with pytest.raises(ValueError, match="sigma must be > 0"):
        fill_holes(points, raw, hole, sigma=0.0)


def test_fill_holes_kernel_revisits_only_changed_holes_like_the_oracle(rng):
    """Issue 13: the kernel re-evaluates only holes near a fill of the last pass; masks must
    equal the oracle's, which evaluates every hole in every pass (many passes, scattered
    holes, a wide hole that peels for several passes, gate rejections near a depth edge)."""
    depth, k = _bumpy_surface(rng, h=30, w=34)
    raw = depth_to_points(depth, k)
    hole = rng.random(depth.shape) < 0.35
    hole[8:20, 4:16] = True  # peels over 6 passes
    points = raw + rng.normal(0, 0.05, raw.shape).astype(np.float32)
    points[hole] += np.float32(0.4)
    for gate, passes in ((math.inf, 10), (1.0, 10), (1.0, 3)):
        fast_points = points.copy()
        fast_hole = hole.copy()
        filled = _fill_holes(
            fast_points,
            raw,
            fast_hole,
            radius=2,
            sigma=2.0,
            passes=passes,
            min_neighbours=3,
            gate=gate,
        )
        exp_points, exp_hole, exp_filled = naive.fill_holes(
            points, raw, hole, 2, 2.0, passes, 3, gate
        )
        np.testing.assert_array_equal(filled, exp_filled)
        np.testing.assert_array_equal(fast_hole, exp_hole)
        np.testing.assert_allclose(fast_points, exp_points, atol=1e-3)
        assert 0 < filled.sum() <= hole.sum()


def test_one_frame_window_computes_no_flow():
    """Issue 13: num_frames=1 uses no pair, so the tracker is never built."""
    depth = _plane_depth(4)
    intensity = np.full(depth.shape, 0.5, np.float32)
    timings = {}
    engine = FusionEngine(K, fusion=FusionParams(num_frames=1), timings=timings)
    out = [fr for d, i in zip(depth, intensity, strict=True) for fr in engine.push(d, i)]
    out += engine.flush()
    assert [fr.index for fr in out] == [0, 1, 2, 3]
    assert engine._flow_estimator is None
    assert timings["flow"] == 0.0
    assert timings["tracking"] < 1.0
    assert (out[0].support == 0).all()


def test_project_to_rays_kernel_matches_oracle(rng):
    depth, k = _bumpy_surface(rng)
    depth[:, 9:] += 12.0  # a 12 mm step: an edge for quad = 0, continuous for quad = 2e-5
    depth[5, 5] = np.nan
    ref = depth_to_points(depth, k)
    points = ref + rng.normal(0, 0.3, ref.shape).astype(np.float32)
    for quad in (0.0, 2e-5):
        out = np.empty_like(points)
        _project_to_rays_kernel(points, ref, k.fx, k.fy, k.cx, k.cy, 10.0, quad, out)
        expected = naive.project_to_rays(points, ref, k.fx, k.fy, k.cx, k.cy, 10.0, quad)
        np.testing.assert_array_equal(np.isnan(out), np.isnan(expected))
        np.testing.assert_allclose(out, expected, atol=1e-3)
        cols = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]][1]
        on_ray = out[..., 0] / out[..., 2] * k.fx + k.cx
        np.testing.assert_allclose(
            on_ray[np.isfinite(on_ray)], cols[np.isfinite(on_ray)], atol=1e-3
        )
    step = naive.project_to_rays(points, ref, k.fx, k.fy, k.cx, k.cy, 10.0, 0.0)
    assert np.abs(step - expected)[:, 8:10].max() > 1e-3  # the step rule decides the normals


def test_fill_kernel_extrapolates_a_plane():
    yy, xx = np.mgrid[0:12, 0:12]
    depth = (500 + 0.5 * xx + 0.3 * yy).astype(np.float32)
    pts = depth_to_points(depth, Intrinsics(100, 100, 5.5, 5.5, 12, 12))
    truth = pts.copy()
    hole = np.zeros((12, 12), bool)
    hole[5:7, 5:7] = True
    work = pts.copy()
    work[hole] += 0.3  # fallback value, off the plane
    filled = np.zeros_like(hole)
    _fill_holes_kernel(work, truth, hole, 2, 1 / 8.0, 10, 3, 5.0, filled)
    assert filled[5:7, 5:7].all()
    assert not hole.any()
    # Z is linear in the pixel coordinates on this plane (exact); X, Y are quadratic
    np.testing.assert_allclose(work[5:7, 5:7, 2], truth[5:7, 5:7, 2], atol=1e-3)
    np.testing.assert_allclose(work[5:7, 5:7], truth[5:7, 5:7], atol=1e-2)
    # a gate tighter than the disagreement keeps the fallback
    work2 = pts.copy()
    work2[5:7, 5:7] += 0.3
    hole2 = np.zeros_like(hole)
    hole2[5:7, 5:7] = True
    filled2 = np.zeros_like(hole)
    _fill_holes_kernel(work2, truth, hole2, 2, 1 / 8.0, 10, 3, 0.1, filled2)
    assert not filled2.any()


def test_project_to_rays_puts_points_on_their_pixel_ray():
    depth = _plane_depth(1, slope=2.0)[0]
    pts = depth_to_points(depth, K).astype(np.float64)
    tangent_u = pts[20, 25] - pts[20, 24]
    tangent_u /= np.linalg.norm(tangent_u)
    shifted = (pts + 0.4 * tangent_u).astype(np.float32)  # slid within the plane, off its ray
    out = np.empty_like(shifted)
    _project_to_rays_kernel(shifted, pts.astype(np.float32), K.fx, K.fy, K.cx, K.cy, 10.0, 0.0, out)
    np.testing.assert_allclose(out, pts, atol=2e-3)
    assert np.abs(shifted - pts).max() > 0.3


# ----------------------------------------------------------------------------- switches vs oracle
LITERAL = dict(LITERAL_PAPER)
SWITCHES = {
    "default": {},
    "quantize-per-step": {"quantize": "per_step"},
    "output-points": {"output": "points"},
    "bilateral-points": {"bilateral": "points"},
    "fill-fallback-nan": {"fill_fallback": "nan"},
    "no-fill": {"fill_holes": False},  # the default since A35
    "reference-sigma": {"reference_sigma": 1.5},
    "motion-raw": {"motion_depth": "raw"},
    "base-frame": {"base": "frame"},
    "base-quadratic": {"base": "quadratic"},
    # A21 (the default is A32's adaptive base); on this scene the adaptive base takes the
    # parabola somewhere only along the exact tracks, so both sides of this case use them
    "base-line": {"base": "trajectory", "tracks": "exact"},
    "base-smoothing-off": {"base_smoothing": 0.0},  # A29
    "base-fine-limit-0": {"base_fine_limit": 0.0},  # A29: the plain spatial mean
    "temporal-gate-off": {"temporal_gate": math.inf},
    "tracks-exact": {"tracks": "exact"},  # A31 off (METHOD)
    "static-off": {"static_tracks": False},  # A33
    "static-smoothing-off": {"static_smoothing": 0.0},  # A42
    "literal": {**LITERAL, "quantize": "per_step", "fill_fallback": "nan"},
}
#: what a switch is compared with where it is not the plain defaults of ``SWITCH_BASE``
SWITCH_AGAINST = {"base-line": {"tracks": "exact"}}


def _switch_scene(rng, n=5, h=16, w=20):
    """Noisy curved slanted surface with a 30 mm step and holes, sub-pixel flows with FB errors
    around theta: tracks fail, samples are gated, holes appear and get filled (or not)."""
    k = Intrinsics(fx=600.0, fy=600.0, cx=9.5, cy=7.5, width=w, height=h)  # 0.8 mm/px
    yy, xx = np.mgrid[0:h, 0:w]
    depth = 500.0 + 1.0 * xx + 0.5 * yy + 0.1 * (xx - 10.0) ** 2 - 30.0 * (xx >= 13)
    depth = depth + rng.normal(0, 0.3, (n, h, w))
    depth = depth.astype(np.float32)
    depth[1, 3, 4] = depth[2, 9:11, 6:8] = np.nan
    inten = rng.uniform(0.2, 0.8, (n, h, w)).astype(np.float32)
    fwd = (np.array([0.4, 0.3]) + rng.normal(0, 0.2, (n - 1, h, w, 2))).astype(np.float32)
    bwd = (-fwd + rng.normal(0, 0.45, fwd.shape)).astype(np.float32)
    return depth, inten, fwd, bwd, k


# small enough that the noise model (2.5 q z^2 ~ 0.8 mm) decides part of the depth steps
SWITCH_BASE = FusionParams(
    fill_from_time=False,  # the sensor-hole fill (A26/A27) has its own tests (test_holes.py)
    fill_max_hole_px=0,
    num_frames=5,
    spatial_radius=2,
    fb_threshold=1.0,
    max_depth_step=0.6,
    min_temporal_support=3,
    min_gate_mm=0.3,
    fill_holes=True,  # the paper's Eq. 6 (off by default since A35) is composed in too
)


@pytest.mark.parametrize("switch", list(SWITCHES), ids=list(SWITCHES))
def test_switch_matches_engine_oracle(rng, switch):
    """Each literal-paper switch (and the defaults) against the NumPy composition of the
    tracking, Eq. 5, Eq. 6 and ray-output oracles (tests/naive/fusion.py:engine_frame)."""
    depth, inten, fwd, bwd, k = _switch_scene(rng)
    t = 2
    params = SWITCH_BASE.replace(**SWITCHES[switch])
    res = fuse_sequence(depth, inten, k, fusion=params, flow=SequenceFlow(fwd, bwd))
    expected, support = naive.engine_frame(depth, inten, fwd, bwd, k, params, t)
    np.testing.assert_array_equal(res.support[t], support)
    np.testing.assert_array_equal(np.isnan(res.points[t]), np.isnan(expected))
    np.testing.assert_allclose(res.points[t], expected, atol=2e-3)
    valid = np.isfinite(depth[t])
    assert 0 < (support[valid] >= 3).mean() < 1  # fused pixels and holes
    if switch != "default":  # the switch changes the result on this scene
        against = SWITCH_BASE.replace(**SWITCH_AGAINST.get(switch, {}))
        default, _ = naive.engine_frame(depth, inten, fwd, bwd, k, against, t)
        same = np.isnan(default) == np.isnan(expected)
        assert not (same.all() and np.allclose(default, expected, atol=2e-3, equal_nan=True))


# ----------------------------------------------------------------------------- METHOD §8 tests
def test_eq2_eq3_round_trip():
    n = 4
    depth, _inten, fwd, bwd = _translating(n)
    depth = _plane_depth(n, slope=0.3)
    params = FusionParams(max_depth_step=50.0)
    motion, fb = compute_motion_field(fwd, bwd, depth, K, params=params)
    ref_depth = np.stack(
        [
            motion_reference_depth(
                d,
                sigma=params.motion_sigma,
                max_step=params.max_depth_step,
                noise_quad=estimate_noise_quad(d),
            )
            for d in depth
        ]
    )
    ref = depth_to_points(ref_depth, K)
    v, u = 10, 20
    p = ref[0, v, u] + motion[0, v, u]  # P~^t[x] + m^{t,t+1} lands on pixel x^ = (v + 2, u)
    assert p[0] / p[2] * K.fx + K.cx == pytest.approx(u, abs=1e-3)
    assert p[1] / p[2] * K.fy + K.cy == pytest.approx(v + 2, abs=1e-3)
    assert p[2] == pytest.approx(ref_depth[1, v + 2, u], abs=1e-3)
    np.testing.assert_allclose(fb[:, :-2], 0.0, atol=1e-6)


def test_integer_translation_tracks_and_telescoping():
    n = 7
    depth, _inten, fwd, bwd = _translating(n)
    depth = _plane_depth(n, slope=0.3)
    tracks = track_frame(fwd, bwd, depth, 3, params=FusionParams(max_depth_step=50.0))
    rows, cols = np.mgrid[0:H, 0:W]
    for k, T in enumerate(tracks.frames):
        inside = (rows + 2 * (T - 3) >= 0) & (rows + 2 * (T - 3) <= H - 1)
        np.testing.assert_array_equal(tracks.valid[k], inside)
        np.testing.assert_array_equal(tracks.rows[k][inside], (rows + 2 * (T - 3))[inside])
        np.testing.assert_array_equal(tracks.cols[k][inside], cols[inside])
    motion, _ = compute_motion_field(fwd, bwd, depth, K, params=FusionParams(max_depth_step=50.0))
    ref = depth_to_points(
        np.stack(
            [
                motion_reference_depth(
                    d, sigma=3.0, max_step=50.0, noise_quad=estimate_noise_quad(d)
                )
                for d in depth
            ]
        ),
        K,
    )
    v, u = 8, 20
    m02 = ref[2, v + 4, u] - ref[0, v, u]  # endpoint form of m^{0,2}
    np.testing.assert_allclose(motion[0, v, u] + motion[1, v + 2, u], m02, atol=1e-4)


def test_static_noise_free_scene_is_identity():
    n = 5
    depth = _plane_depth(n, slope=0.4)
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    res = fuse_sequence(depth, inten, K, flow=_zero_flow(n))
    # exact on a plane away from the border; truncated windows at the border are asymmetric
    np.testing.assert_allclose(res.depth[:, 3:-3, 3:-3], depth[:, 3:-3, 3:-3], atol=2e-3)
    np.testing.assert_allclose(res.depth, depth, atol=0.05)
    assert (res.support[:, 5:-5, 5:-5] == 4).all()  # 5 frames inside a 9-frame window


def test_static_scene_with_real_flow_has_near_zero_flow():
    n = 3
    depth = _plane_depth(n)
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    res = fuse_sequence(depth, inten, K, flow="dis")
    assert np.abs(res.flow_forward).max() < 1e-3
    assert res.flow_method == "dis"


def test_window_truncation_at_both_ends():
    n = 12
    depth = _plane_depth(n)
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    res = fuse_sequence(depth, inten, K, flow=_zero_flow(n), fusion=FusionParams(num_frames=9))
    inner = res.support[:, 5:-5, 5:-5]
    assert (inner[0] == 4).all()  # t = 0: 4 future frames only
    assert (inner[1] == 5).all()
    assert (inner[5] == 8).all()
    assert (inner[-1] == 4).all()  # t = N-1: 4 past frames only
    causal = fuse_sequence(
        depth, inten, K, flow=_zero_flow(n), fusion=FusionParams(num_frames=9, causal=True)
    )
    assert (causal.support[0, 5:-5, 5:-5] == 0).all()
    assert (causal.support[-1, 5:-5, 5:-5] == 8).all()


def test_nan_propagation(rng):
    n = 5
    depth = _plane_depth(n) + rng.normal(0, 0.2, (n, H, W)).astype(np.float32)
    depth[2, 10:13, 10:13] = np.nan  # a hole in the centre frame
    depth[1, 20, 30] = np.nan  # a hole in another frame
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    no_fill = FusionParams(fill_from_time=False, fill_max_hole_px=0)
    res = fuse_sequence(depth, inten, K, flow=_zero_flow(n), fusion=no_fill)
    assert np.isnan(res.depth[2, 10:13, 10:13]).all()
    assert np.isfinite(res.depth[2, 9, 9:14]).all()  # no spreading
    assert np.isfinite(res.depth[2, 20, 30])  # other frame's hole only lowers support:
    assert res.support[2, 20, 31] == 4
    # a chain (METHOD §4.1) loses frames 1 and 0 (behind it) and keeps 3 and 4 ...
    chained = fuse_sequence(
        depth, inten, K, flow=_zero_flow(n), fusion=no_fill.replace(static_tracks=False)
    )
    assert chained.support[2, 20, 30] == 2
    # ... a static pixel (A33) samples itself in every frame: only frame 1 is lost
    assert res.support[2, 20, 30] == 3
    assert np.isnan(res.points[2, 11, 11]).all()
    assert (res.source[2, 10:13, 10:13] == SOURCE_NONE).all()
    # default: the sensor hole of frame 2 is filled from frames 0, 1, 3, 4 along its track (A26)
    filled = fuse_sequence(depth, inten, K, flow=_zero_flow(n))
    assert (filled.source[2, 10:13, 10:13] == SOURCE_TIME).all()
    truth = _plane_depth(n)[2, 10:13, 10:13]
    assert np.abs(filled.depth[2, 10:13, 10:13] - truth).max() < 0.5  # 0.2 mm noise, 4 frames
    np.testing.assert_allclose(filled.confidence[2, 10:13, 10:13], 4 / 9)
    # measured pixels are untouched by the sensor-hole fill
    np.testing.assert_array_equal(filled.depth[2, 9, 9:14], res.depth[2, 9, 9:14])


def test_no_sensor_hole_is_filled_outside_the_field_of_view():
    """A38: the bottom rows have no depth in any frame (the band a registered depth image
    leaves around the colour image); the scene moves down 2 px/frame, so their tracks land on
    valid depth in the earlier frames, but they stay empty, flagged SOURCE_OUTSIDE."""
    n = 5
    depth, inten, fwd, bwd = _translating(n)
    depth[:, -4:] = np.nan  # beyond the sensor's field of view, in every frame
    depth[2, 10:13, 10:13] = np.nan  # a dropout inside it
    res = fuse_sequence(depth, inten, K, flow=SequenceFlow(fwd, bwd))
    assert (res.source[:, -4:] == SOURCE_OUTSIDE).all()
    assert np.isnan(res.depth[:, -4:]).all()
    assert (res.confidence[:, -4:] == 0).all()
    assert (res.source[2, 10:13, 10:13] == SOURCE_TIME).all()
    # the same rows without depth in frame 2 only lie inside the field of view: the time
    # fill reaches them along the same tracks
    depth[:, -4:] = 600.0
    depth[2, -4:] = np.nan
    res = fuse_sequence(depth, inten, K, flow=SequenceFlow(fwd, bwd))
    assert (res.source[2, -4:] == SOURCE_TIME).all()
    np.testing.assert_allclose(res.depth[2, -4:], 600.0, atol=0.01)


def test_literal_motion_is_much_rougher_than_regularised(rng):
    n = 9
    depth = _plane_depth(n, slope=0.0) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    default = fuse_sequence(depth, inten, K, flow=_zero_flow(n))
    literal = fuse_sequence(
        depth,
        inten,
        K,
        flow=_zero_flow(n),
        # (without A42, which would smooth this static plane after any Eq. 5)
        fusion=FusionParams(motion_depth="raw", base="frame", static_smoothing=0.0),
    )
    roi = np.zeros((n, H, W), bool)
    roi[:, 6:-6, 6:-6] = True
    r_default = roughness_stats(default.points, roi=roi).mean
    r_literal = roughness_stats(literal.points, roi=roi).mean
    r_raw = roughness_stats(depth_to_points(depth, K), roi=roi).mean
    assert r_default < 0.3 * r_literal
    assert r_literal > 0.8 * r_raw  # the literal Eq. 5 keeps frame t's own noise


def _moving_box(rng, n=9, speed=2, noise=0.2):
    """A slanted textured box face (~600 mm) moving down ``speed`` px/frame over a slanted
    static background (~800 mm). Returns noisy depth, intensity, exact flows, true depth."""
    yy, xx = np.mgrid[0:H, 0:W]
    background = 800.0 + 1.5 * xx + 0.8 * yy
    bg_texture = _texture(H, W, seed=5)
    big = _texture(H + speed * n, W, seed=3)
    truth = np.empty((n, H, W), np.float32)
    inten = np.empty((n, H, W), np.float32)
    inside = np.empty((n, H, W), bool)
    for t in range(n):
        top = 6 + speed * t
        rows = yy - top  # row in the box's own frame
        inside[t] = (rows >= 0) & (rows < 14) & (xx >= 14) & (xx < 34)
        truth[t] = np.where(inside[t], 600.0 + 1.2 * xx + 2.0 * rows, background)
        inten[t] = np.where(inside[t], big[np.clip(rows, 0, None) + speed, xx], bg_texture)
    fwd = np.zeros((n - 1, H, W, 2), np.float32)
    bwd = np.zeros_like(fwd)
    fwd[..., 1] = np.where(inside[:-1], speed, 0.0)
    bwd[..., 1] = np.where(inside[1:], -speed, 0.0)
    depth = truth + rng.normal(0, noise, truth.shape).astype(np.float32)
    return depth, inten, SequenceFlow(fwd, bwd), truth, inside


def test_moving_object_fused_without_ghosting(rng):
    """A 9-frame temporal mean smears a moving edge by ~100 mm; the fusion keeps the edge
    (max error ~ noise) and still averages over ~8 frames (noise ~ 1/sqrt(8) of the
    bilateral-only result). Measured: fusion 0.31 mm at the edges, noise ratio 0.39; without
    the gates and motion compensation 97 mm; literal frame base or a temporal kernel that only
    weighs frame t: ratio 1.0; averaging the points B^T instead of the details: ratio 0.68."""
    n, t = 9, 4
    depth, inten, flow, truth, inside = _moving_box(rng, n)
    res = fuse_sequence(depth, inten, K, flow=flow)
    err = res.depth[t] - truth[t]
    # band of 3 px on both sides of the box's top and bottom edges (where a mean would ghost)
    edges = np.zeros((H, W), bool)
    rows = np.nonzero(inside[t].any(axis=1))[0]
    for r in (rows[0], rows[-1] + 1):
        edges[r - 3 : r + 3, 16:32] = True
    assert np.abs(err[edges]).max() < 1.0  # mm; the 9-frame mean is off by up to ~100 mm here
    mean = depth.mean(axis=0)
    assert np.abs(mean - truth[t])[edges].max() > 50.0  # the scene really tests ghosting
    # temporal averaging really happens: against the bilateral-only result (window of 1)
    spatial = fuse_sequence(depth[t : t + 1], inten[t : t + 1], K).depth[0] - truth[t]
    interior = np.zeros((H, W), bool)
    interior[rows[0] + 3 : rows[-1] - 2, 17:31] = True  # box face, away from its edges
    interior[3:6, 8:-8] = interior[-4:-1, 8:-8] = True  # background, never covered
    ratio = np.std(err[interior]) / np.std(spatial[interior])
    assert ratio < 0.5  # 1/sqrt(8.3 effective frames) = 0.35; spatial-only = 1
    # tracked with the box: 7.8 of 8 frames on its face (without motion compensation: 5.6)
    assert res.support[t][interior & inside[t]].mean() > 7.5


def test_temporal_gate_rejects_an_outlier_sample():
    """A19/A22: a +3 mm bump in frame 3 only is tracked (3 mm < 10 mm depth step) but the
    temporal gate rejects the sample; with temporal_gate = inf or a 5 mm gate floor it is
    averaged in and pulls the fused surface up."""
    n, t = 9, 4
    depth = _plane_depth(n, slope=0.2)
    depth[3, 18:23, 22:27] += 3.0
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    runs = {
        name: fuse_sequence(depth, inten, K, flow=_zero_flow(n), fusion=params)
        for name, params in (
            ("gate", FusionParams()),
            ("off", FusionParams(temporal_gate=math.inf)),
            ("floor", FusionParams(min_gate_mm=5.0)),
        )
    }
    centre = (t, 20, 24)
    assert runs["gate"].support[centre] == 7  # frame 3 rejected, 7 other frames kept
    assert runs["off"].support[centre] == 8
    assert runs["floor"].support[centre] == 8
    assert runs["gate"].support[t, 5, 5] == 8
    assert abs(runs["gate"].depth[centre] - depth[centre]) < 0.05
    for name in ("off", "floor"):
        assert runs[name].depth[centre] - depth[centre] > 0.1  # mm: the bump leaked in


def test_motion_field_validity_is_the_fused_tracks_validity_on_kinect_depth(rng):
    """Regression (A22): on Kinect-range depth (1.5-3 m, quantised in ~z^2 steps of 4-18 mm)
    FusionResult.motion and compute_motion_field are valid exactly where the fusion's one-step
    tracks are, although many accepted steps exceed the fixed 10 mm gate."""
    n = 5
    kinect = Intrinsics(fx=544.0, fy=544.0, cx=23.5, cy=19.5, width=W, height=H)
    xx = np.mgrid[0:H, 0:W][1]
    depth = np.broadcast_to(1500.0 + 30.0 * xx, (n, H, W))
    step = 2e-6 * depth**2  # one disparity level, mm
    noisy = np.round((depth + rng.normal(0, 0.4, (n, H, W)) * step) / step) * step
    noisy = noisy.astype(np.float32)
    noisy[2, 10:14, 10:14] = np.nan
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    fwd = np.zeros((n - 1, H, W, 2), np.float32)
    fwd[..., 1] = 1.0  # one row down per frame (consistent pair flows)
    bwd = -fwd
    flow = SequenceFlow(fwd, bwd)
    res = fuse_sequence(noisy, inten, kinect, flow=flow)
    motion, _ = compute_motion_field(fwd, bwd, noisy, kinect)
    for t in range(n - 1):
        tracks = track_frame(fwd, bwd, noisy, t)
        k = int(np.nonzero(tracks.frames == t + 1)[0][0])
        used = tracks.valid[k]
        np.testing.assert_array_equal(np.isfinite(res.motion[t, ..., 0]), used)
        np.testing.assert_array_equal(np.isfinite(motion[t, ..., 0]), used)
        jump = np.abs(noisy[t + 1, 1:, :] - noisy[t, :-1, :])
        assert (jump[used[:-1]] >= 10.0).mean() > 0.1  # the old 10 mm gate cut these


def test_streaming_equals_in_memory_bit_for_bit(rng):
    n = 11
    depth = _plane_depth(n) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    depth[4, 5:9, 5:9] = np.nan
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    for params in (FusionParams(num_frames=5), FusionParams(num_frames=4, causal=True)):
        memory = fuse_sequence(depth, inten, K, fusion=params, flow="dis")
        streamed = list(fuse_stream(zip(depth, inten, strict=True), K, fusion=params, flow="dis"))
        assert [f.index for f in streamed] == list(range(n))
        np.testing.assert_array_equal(np.stack([f.points for f in streamed]), memory.points)
        np.testing.assert_array_equal(np.stack([f.support for f in streamed]), memory.support)
        # a ring that never evicts (other slot mapping) gives the same bits
        engine = FusionEngine(K, fusion=params, flow="dis", ring_size=n)
        big = [fr for d, i in zip(depth, inten, strict=True) for fr in engine.push(d, i)]
        big += engine.flush()
        np.testing.assert_array_equal(np.stack([f.points for f in big]), memory.points)


def test_in_memory_and_stream_apis_stop_their_flow_worker():
    """fuse_sequence and fuse_stream compute the flows in a worker thread (overlap_flow):
    gone when they return, when a stream is abandoned and when the caller fails."""
    import threading

    def workers():
        return [t for t in threading.enumerate() if t.name.startswith("fuse4d-flow")]

    n = 6
    depth = _plane_depth(n)
    inten = _moving_texture(n)
    params = FusionParams(num_frames=3)
    fuse_sequence(depth, inten, K, fusion=params, flow="dis")
    assert not workers()
    stream = fuse_stream(zip(depth, inten, strict=True), K, fusion=params, flow="dis")
    next(stream)
    next(stream)
    assert workers()  # the stream's engine is running its worker
    stream.close()  # abandoned half way
    assert not workers()

    def failing(done, total):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        fuse_sequence(depth, inten, K, fusion=params, flow="dis", progress=failing)
    assert not workers()


def test_engine_emits_with_latency_and_bounded_ring():
    n = 8
    engine = FusionEngine(K, fusion=FusionParams(num_frames=5), flow="dis")
    assert engine.latency == 2
    depth = _plane_depth(n)
    inten = _texture(H, W)
    counts = [len(engine.push(d, inten)) for d in depth]
    assert counts == [0, 0, 1, 1, 1, 1, 1, 1]
    assert len(engine.flush()) == 2
    assert engine._depth.shape[0] == 5  # memory does not grow with the stream
    with pytest.raises(RuntimeError, match=r"engine was flushed; call reset\(\)"):
        engine.push(depth[0], inten)


def test_input_noise_quad_is_the_estimate_on_the_pushed_depth(rng):
    """The q that ``fuse4d run``'s summary reuses is estimate_noise_quad of the depth as
    pushed, while the frame is in the ring: with A36 the one taken before the flying pixels
    were removed (the noise model's is estimated without them); None for pushed points."""
    from fuse4d.range_scenes import make_range_scene

    plane = _plane_depth(4) + rng.normal(0, 0.5, (4, H, W)).astype(np.float32)
    plane[:, 3:6, 4:9] = np.nan
    tof = make_range_scene("body", sensor="tof", small=True, num_frames=4, rng=0)
    cases = [
        (K, plane, np.broadcast_to(_texture(H, W), plane.shape), "off"),
        (tof.intrinsics, tof.depth, tof.intensity, "on"),
    ]
    for k, depth, inten, flying in cases:
        engine = FusionEngine(k, fusion=FusionParams(num_frames=3, flying_pixels=flying))
        for t, d in enumerate(depth):
            for fr in engine.push(d, inten[t]):
                assert engine.input_noise_quad(fr.index) == estimate_noise_quad(depth[fr.index])
            assert engine.input_noise_quad(t) == estimate_noise_quad(d) > 0
        with pytest.raises(IndexError, match="frame 0 is not in the ring buffer"):
            engine.input_noise_quad(0)
    assert engine._rejected.any()  # the ToF body has flying pixels: A36 was exercised
    pushed_points = FusionEngine(K, fusion=FusionParams(num_frames=3), flow="dis")
    pushed_points.push(plane[0], _texture(H, W), points=depth_to_points(plane[0], K))
    assert pushed_points.input_noise_quad(0) is None


def test_iterations_reduce_roughness_further(rng):
    n = 5
    depth = _plane_depth(n) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    one = fuse_sequence(depth, inten, K, flow=_zero_flow(n))
    two = fuse_sequence(depth, inten, K, flow=_zero_flow(n), fusion=FusionParams(iterations=2))
    roi = np.zeros((n, H, W), bool)
    roi[:, 6:-6, 6:-6] = True
    assert roughness_stats(two.points, roi=roi).mean < roughness_stats(one.points, roi=roi).mean


# ----------------------------------------------------------------------------- bad input
def test_bad_input_messages():
    depth = _plane_depth(3)
    inten = np.broadcast_to(_texture(H, W), (3, H, W)).copy()
    with pytest.raises(
        ShapeError, match=r"intensity must have shape \(3, 40, 48\), got \(2, 40, 48\)"
    ):
        fuse_sequence(depth, inten[:2], K)
    wrong = Intrinsics(120.0, 120.0, 23.5, 19.5, width=50, height=40)
    with pytest.raises(ShapeError, match="the intrinsics describe another image size"):
        fuse_sequence(depth, inten, wrong)
    with pytest.raises(ShapeError, match=r"flow.forward must have shape \(2, 40, 48, 2\)"):
        fuse_sequence(
            depth, inten, K, flow=SequenceFlow(np.zeros((1, H, W, 2)), np.zeros((1, H, W, 2)))
        )
    with pytest.raises(ValueError, match="unknown flow method 'nope'; available methods: "):
        fuse_sequence(depth, inten, K, flow="nope")
    with pytest.raises(
        ValueError, match=r"FusionParams.num_frames must be an integer in \[1, 256\], got 0"
    ):
        FusionParams(num_frames=0)
    with pytest.raises(ValueError, match=r"FusionParams\.motion_depth must be one of"):
        FusionParams(motion_depth="smooth")
    with pytest.raises(ValueError, match=r"fuse_sequence needs at least one frame, got T = 0"):
        fuse_sequence(np.zeros((0, H, W)), np.zeros((0, H, W)), K)


def test_all_nan_frame_and_single_frame_are_graceful():
    depth = _plane_depth(4)
    depth[1] = np.nan
    inten = np.broadcast_to(_texture(H, W), (4, H, W)).copy()
    no_fill = FusionParams(fill_from_time=False, fill_max_hole_px=0)
    res = fuse_sequence(depth, inten, K, flow=_zero_flow(4), fusion=no_fill)
    assert np.isnan(res.depth[1]).all()
    assert np.isfinite(res.depth[0]).all()
    # with the sensor-hole fill, the empty frame takes its depth from frames 0, 2 and 3
    filled = fuse_sequence(depth, inten, K, flow=_zero_flow(4))
    assert (filled.source[1] == SOURCE_TIME).all()
    np.testing.assert_allclose(filled.depth[1], depth[0], atol=0.05)  # the smoothed reference
    # tracks are never re-acquired (METHOD §4.1): an empty frame 1 cuts frame 0 off the rest
    chained = fuse_sequence(
        depth, inten, K, flow=_zero_flow(4), fusion=no_fill.replace(static_tracks=False)
    )
    assert (chained.support[0] == 0).all()
    assert (chained.support[3, 5:-5, 5:-5] == 1).all()
    # static pixels (A33, the default) sample themselves in each frame: only frame 1 is lost
    assert (res.support[0, 5:-5, 5:-5] == 2).all()
    assert (res.support[3, 5:-5, 5:-5] == 2).all()
    single = fuse_sequence(depth[:1], inten[:1], K)
    assert (single.support == 0).all()  # no other frame: bilateral-only result, documented
    np.testing.assert_allclose(single.depth[0], depth[0], atol=2e-3)
    assert single.flow_forward.shape == (0, H, W, 2)


def test_distance_kernel_widens_with_quantised_far_depth(rng):
    """A25: on Kinect-like depth (z^2 quantisation steps of ~5 mm at 1.6 m) delta_d follows the
    noise model and the fused plane is smoother than with the literal fixed 2 mm kernel."""
    n = 5
    kinect = Intrinsics(fx=544.0, fy=544.0, cx=23.5, cy=19.5, width=W, height=H)  # 3 mm/px
    yy, xx = np.mgrid[0:H, 0:W]
    depth = np.broadcast_to(1600.0 + 2.0 * xx + 1.0 * yy, (n, H, W))
    step = 2e-6 * depth**2  # one disparity level, mm
    noisy = (np.round((depth + rng.normal(0, 2.0, depth.shape)) / step) * step).astype(np.float32)
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    quad = estimate_noise_quad(noisy[0])
    z_med = float(np.median(noisy[0]))
    wide = FusionEngine(kinect, fusion=FusionParams())._frame_sigma_distance(z_med, quad)
    fixed = FusionEngine(kinect, fusion=FusionParams(distance_noise_scale=0))
    assert wide > 1.5 * 2.0  # ~ 1.5 * 5 mm
    assert fixed._frame_sigma_distance(z_med, quad) == pytest.approx(2.0)
    rough = {}
    for scale in (0.0, 1.5):
        res = fuse_sequence(
            noisy,
            inten,
            kinect,
            fusion=FusionParams(distance_noise_scale=scale),
            flow=_zero_flow(n),
        )
        rough[scale] = roughness_stats(res.points, roi=np.isfinite(res.depth)).mean
    assert rough[1.5] < 0.8 * rough[0.0]
    with pytest.raises(ValueError, match="distance_noise_scale"):
        FusionParams(distance_noise_scale=-1.0)


def test_distance_scale_4_lowers_kinect_error_and_keeps_continuous_depth():
    """A30: the default delta_d scale (4 q z_med^2, was 1.5) averages more of the static
    quantisation staircase on the Kinect-model room (RMSE vs ground truth drops), and leaves
    continuous depth (the paper's ball: 4 q z^2 < 2 mm) bit for bit unchanged."""
    from fuse4d.range_scenes import make_range_scene
    from fuse4d.synthetic import make_falling_ball

    assert FusionParams().distance_noise_scale == 4.0
    fast = preset("fast")

    def fused(seq, scale: float):
        # A30 alone: A42 takes part of the same staircase off the room's static pixels
        fusion = fast.fusion.replace(distance_noise_scale=scale, static_smoothing=0.0)
        return fuse_sequence(
            seq.depth, seq.intensity, seq.intrinsics, fusion=fusion, flow=fast.flow
        )

    seq = make_range_scene("room", sensor="kinect", small=True, num_frames=6, rng=0)
    truth = seq.ground_truth.depth
    rmse = {}
    for scale in (1.5, 4.0):
        out = fused(seq, scale).depth
        m = np.isfinite(seq.depth) & np.isfinite(out)
        rmse[scale] = float(np.sqrt(np.mean((out - truth)[m] ** 2)))
    assert rmse[4.0] < 0.97 * rmse[1.5]  # measured 60.7 vs 63.5 mm
    ball = make_falling_ball(small=True, num_frames=4)
    pts = [fused(ball, scale).points for scale in (1.5, 4.0)]
    np.testing.assert_array_equal(pts[0], pts[1])


# ------------------------------------------------------------------ A29: base offset smoothing
def test_smooth_base_removes_offset_steps_and_keeps_small_fine_detail():
    """A29: a 1 mm step in the trajectory base offset (chord bias that changes with the
    support) is reduced to +-limit q z^2; a fine-scale offset within the bound is kept."""
    from fuse4d.fusion import _smooth_base

    h, w = 20, 30
    depth = np.full((h, w), 1000.0, np.float32)
    quad = 1e-6  # q z^2 = 1 mm at 1 m
    base = np.zeros((h, w, 3), np.float32)
    base[:, 15:, 2] = 1.0  # a step of the offset along a support boundary
    points = np.zeros((h, w, 3), np.float32) + base  # output = 0 + offset
    hole = np.zeros((h, w), bool)
    hole[0, 0] = True
    _smooth_base(
        points, base, depth, hole, sigma=2.0, max_step=10.0, quad=quad, limit_quad=0.1 * quad
    )
    jump = np.abs(np.diff(points[5, :, 2]))
    assert jump.max() < 0.45  # the 1 mm step became a ramp (+- the fine part, clipped to 0.1)
    assert np.all(np.abs(points[..., 2] - base[..., 2]) <= 0.5 + 1e-6)
    assert points[0, 0, 2] == base[0, 0, 2]  # holes untouched
    # small fine-scale offsets (|.| << 0.1 q z^2) are kept exactly
    fine = (0.01 * (-1.0) ** np.arange(w))[None, :].repeat(h, 0).astype(np.float32)
    base2 = np.zeros((h, w, 3), np.float32)
    base2[..., 2] = fine
    pts2 = base2.copy()
    _smooth_base(
        pts2, base2, depth, hole, sigma=2.0, max_step=10.0, quad=quad, limit_quad=0.1 * quad
    )
    np.testing.assert_allclose(pts2, base2, atol=1e-6)


def test_smooth_base_is_bit_identical_to_three_segment_smooths():
    """The stacked A29 kernels give, bit for bit, the NumPy form of A29: three
    ``_segment_smooth`` calls (X, Y, Z) and the clipped fine part in float32 (far, quantised
    depth with holes, edges and clipped pixels; fused output must not move by an ulp)."""
    from fuse4d.fusion import _smooth_base
    from fuse4d.motion import _segment_smooth

    rng = np.random.default_rng(7)
    h, w = 37, 53
    quad = 2e-6
    depth = (2500.0 + 300.0 * (np.arange(w)[None, :] > 30) + rng.normal(0, 8, (h, w))).astype(
        np.float32
    )
    depth[rng.random((h, w)) < 0.05] = np.nan
    hole = rng.random((h, w)) < 0.05
    base = rng.normal(0, 3.0, (h, w, 3)).astype(np.float32)
    base[rng.random((h, w)) < 0.05] = np.nan
    points = rng.normal(0, 1000.0, (h, w, 3)).astype(np.float32)
    kw = {"sigma": 2.0, "max_step": 10.0, "quad": quad, "limit_quad": 0.075 * quad}
    expected = points.copy()
    d = np.where(hole, np.float32(np.nan), depth).astype(np.float32)
    z = np.nan_to_num(depth)
    bound = np.float32(kw["limit_quad"]) * z * z
    for c in range(3):
        own = np.nan_to_num(base[..., c])
        smooth = _segment_smooth(own, d, sigma=2.0, max_step=10.0, noise_quad=quad)
        ok = np.isfinite(smooth)
        fine = np.clip(own - smooth, -bound, bound)
        expected[..., c][ok] += (smooth + fine - own)[ok]
    got = points.copy()
    _smooth_base(got, base, depth, hole, **kw)
    assert np.mean(got != points) > 0.5  # it did change most points
    np.testing.assert_array_equal(got, expected)


def _kinect_like(rng, h=41, w=67):
    """Quantised far depth (2-4 m, 1 mm steps) with holes, a depth edge and short segments;
    base offsets with NaN and inf."""
    depth = np.round(2500.0 + 900.0 * (np.arange(w)[None, :] > 40) + rng.normal(0, 6, (h, w)))
    depth = depth.astype(np.float32)
    depth[rng.random((h, w)) < 0.08] = np.nan
    depth[:, 20:23][rng.random((h, 3)) < 0.5] += 40.0  # 1-3 px segments at a step
    hole = rng.random((h, w)) < 0.04
    base = rng.normal(0, 2.0, (h, w, 3)).astype(np.float32)
    base[rng.random((h, w, 3)) < 0.05] = np.nan
    base[3, 4, 1] = np.inf
    return depth, hole, base


@pytest.mark.parametrize("sigma", [2.0, 3.5])
def test_smooth_base_row_sweep_is_two_box_passes_per_channel(rng, sigma):
    """A29's row sweep (segments found once per row, three channels at once, both passes)
    gives, bit for bit, two ``_segment_box_rows_kernel`` passes of each channel, transposed,
    and frame t's segments and clip bound transposed."""
    from fuse4d._kernels.smooth_base import _smooth_base_rows_kernel
    from fuse4d.motion import _box_radius

    depth, hole, base = _kinect_like(rng)
    h, w = depth.shape
    quad, radius = 1.7e-6, _box_radius(sigma)
    rows_t = np.full((w, 3, h), np.nan, np.float32)
    seg_t = np.empty((w, h), np.float32)
    bound_t = np.empty((w, h), np.float32)
    _smooth_base_rows_kernel(
        base, depth, hole, radius, 10.0, quad, 0.075 * quad, rows_t, seg_t, bound_t
    )
    seg = np.where(hole, np.float32(np.nan), depth)
    np.testing.assert_array_equal(seg_t, seg.T)
    np.testing.assert_array_equal(bound_t, np.float32(0.075 * quad) * seg.T * seg.T)
    ok = np.isfinite(seg)
    for c in range(3):
        a = np.nan_to_num(base[..., c])
        b = np.empty_like(a)
        _segment_box_rows_kernel(a, seg, radius, 10.0, quad, b)
        _segment_box_rows_kernel(b, seg, radius, 10.0, quad, a)
        np.testing.assert_array_equal(rows_t[:, c, :].T[ok], a[ok])


def _four_box_passes(values, depth, radius, quad):
    """The edge-limited smoothing as four ``_segment_box_rows_kernel`` passes (two along the
    rows, two along the rows of the transposed maps): what ``_segment_smooth`` computed
    before stop 48, its oracle."""
    a, b = values.copy(), np.empty_like(values)
    for _ in range(2):
        _segment_box_rows_kernel(a, depth, radius, 10.0, quad, b)
        a, b = b, a
    at, dt = np.ascontiguousarray(a.T), np.ascontiguousarray(depth.T)
    bt = np.empty_like(at)
    for _ in range(2):
        _segment_box_rows_kernel(at, dt, radius, 10.0, quad, bt)
        at, bt = bt, at
    return at.T


@pytest.mark.parametrize("sigma", [1.0, 3.0, 4.0])
@pytest.mark.parametrize("shape", [(41, 67), (1, 40), (40, 1), (17, 16)])
def test_segment_smooth_sweeps_are_four_box_passes(rng, sigma, shape):
    """``_segment_smooth`` (two sweeps, segments found once per line) gives, bit for bit, the
    four single passes; on quantised far depth with holes, for the depth itself (the motion
    reference) and for another map, on sizes that are not whole blocks."""
    from fuse4d.motion import _box_radius, _segment_smooth

    depth, hole, _ = _kinect_like(rng)
    d = np.where(hole, np.float32(np.nan), depth)[: shape[0], : shape[1]].copy()
    other = rng.normal(0, 3.0, d.shape).astype(np.float32)
    quad, radius = 1.7e-6, _box_radius(sigma)
    for values in (d, other):
        got = _segment_smooth(values, d, sigma=sigma, max_step=10.0, noise_quad=quad)
        np.testing.assert_array_equal(got, _four_box_passes(values, d, radius, quad))
    assert np.isnan(got[np.isnan(d)]).all()


@pytest.mark.parametrize("sigma", [1.0, 2.0, 3.5])
def test_smooth_base_matches_three_segment_smooths_on_kinect_like_depth(rng, sigma):
    """As above on quantised far depth with short segments and an inf offset; a frame whose
    every pixel is a hole is left unchanged."""
    from fuse4d.fusion import _smooth_base
    from fuse4d.motion import _segment_smooth

    depth, hole, base = _kinect_like(rng)
    quad = 1.7e-6
    points = rng.normal(0, 1000.0, (*depth.shape, 3)).astype(np.float32)
    for lq in (0.075 * quad, 10.0 * quad):
        kw = {"sigma": sigma, "max_step": 10.0, "quad": quad, "limit_quad": lq}
        expected = points.copy()
        d = np.where(hole, np.float32(np.nan), depth)
        z = np.nan_to_num(depth)
        bound = np.float32(lq) * z * z
        for c in range(3):
            own = np.nan_to_num(base[..., c])
            smooth = _segment_smooth(own, d, sigma=sigma, max_step=10.0, noise_quad=quad)
            ok = np.isfinite(smooth)
            fine = np.clip(own - smooth, -bound, bound)
            expected[..., c][ok] += (smooth + fine - own)[ok]
        got = points.copy()
        _smooth_base(got, base, depth, hole, **kw)
        np.testing.assert_array_equal(got, expected)
    got = points.copy()
    _smooth_base(got, base, depth, np.ones_like(hole), **kw)
    np.testing.assert_array_equal(got, points)


def test_base_smoothing_off_is_the_a21_line():
    """base_smoothing=0 and base_fine_limit=inf both leave the per-pixel line base (A21)."""
    depth, inten, fwd, bwd, k = _switch_scene(np.random.default_rng(3))
    flows = SequenceFlow(fwd, bwd)
    off = fuse_sequence(depth, inten, k, fusion=SWITCH_BASE.replace(base_smoothing=0.0), flow=flows)
    inf = fuse_sequence(
        depth, inten, k, fusion=SWITCH_BASE.replace(base_fine_limit=math.inf), flow=flows
    )
    np.testing.assert_array_equal(off.points, inf.points)


def _moving_texture(n, shift=1.0):
    base = _texture(H, W + int(n * shift) + 2)
    return np.stack(
        [np.ascontiguousarray(base[:, int(t * shift) : int(t * shift) + W]) for t in range(n)]
    )


@pytest.mark.parametrize(
    "params", [FusionParams(num_frames=5), FusionParams(num_frames=3, causal=True)]
)
def test_overlap_flow_equals_the_serial_engine_bit_for_bit(rng, params):
    """issue 13: the flow computed in a worker thread while push filters the frame."""
    import threading

    n = 9
    depth = _plane_depth(n) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    depth[3, 5:9, 5:9] = np.nan
    inten = _moving_texture(n)
    serial = FusionEngine(K, fusion=params, flow="dis")
    want = [f for d, i in zip(depth, inten, strict=True) for f in serial.push(d, i)]
    want += serial.flush()
    timings: dict[str, float] = {}
    with FusionEngine(K, fusion=params, flow="dis", overlap_flow=True, timings=timings) as eng:
        got = [f for d, i in zip(depth, inten, strict=True) for f in eng.push(d, i)]
        got += eng.flush()
        assert any(t.name.startswith("fuse4d-flow") for t in threading.enumerate())
        assert eng._flow_estimator.warm_starts == n - 2  # warm starts as in the serial engine
    assert not any(t.name.startswith("fuse4d-flow") for t in threading.enumerate())
    eng.close()  # idempotent
    assert timings["flow"] >= 0.0
    assert [f.index for f in got] == [f.index for f in want]
    for a, b in zip(got, want, strict=True):
        for field in ("points", "support", "filled", "unfilled", "source", "confidence"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


def test_kernels_beside_a_running_flow_use_one_thread_and_the_same_values(rng, monkeypatch):
    """issue 13: while the flow worker computes the new pair, push's motion reference and
    bilateral run on one numba thread (the worker holds a core); the output is the serial
    engine's, bit for bit, and numba's thread count is restored afterwards."""
    import time

    import numba

    from fuse4d._kernels._numba import kernel_threads

    params = FusionParams(num_frames=3, causal=True)
    n = 5
    depth = _plane_depth(n) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    inten = _moving_texture(n)
    serial = FusionEngine(K, fusion=params, flow="dis")
    want = [f for d, i in zip(depth, inten, strict=True) for f in serial.push(d, i)]
    flow_pair = FusionEngine._flow_pair

    def slow_flow_pair(self, *args, **kwargs):  # a flow that is still running during push
        time.sleep(0.05)
        return flow_pair(self, *args, **kwargs)

    seen = []
    smoothed = FusionEngine._smoothed_points

    def smoothed_points(self, *args, **kwargs):
        seen.append(numba.get_num_threads())
        return smoothed(self, *args, **kwargs)

    monkeypatch.setattr(FusionEngine, "_flow_pair", slow_flow_pair)
    monkeypatch.setattr(FusionEngine, "_smoothed_points", smoothed_points)
    before = numba.get_num_threads()
    with FusionEngine(K, fusion=params, flow="dis", overlap_flow=True) as eng:
        got = [f for d, i in zip(depth, inten, strict=True) for f in eng.push(d, i)]
    assert seen == [before] + [1] * (n - 1)  # frame 0 has no pair, so no flow beside it
    assert numba.get_num_threads() == before
    for a, b in zip(got, want, strict=True):
        for field in ("points", "support", "filled", "unfilled", "source", "confidence"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    inside = []

    def fail_on_one_thread():
        with kernel_threads(1):
            inside.append(numba.get_num_threads())
            raise RuntimeError

    with pytest.raises(RuntimeError):
        fail_on_one_thread()
    assert inside == [1]
    assert numba.get_num_threads() == before  # restored when the block raises
    with kernel_threads(None), kernel_threads(before + 1):  # no change asked for
        assert numba.get_num_threads() == before


def test_overlap_flow_failed_push_is_retried_as_by_the_serial_engine(rng):
    n = 5
    depth = _plane_depth(n) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    inten = _moving_texture(n)
    params = FusionParams(num_frames=3, causal=True)
    serial = FusionEngine(K, fusion=params, flow="dis")
    want = [serial.push(d, i)[0].points for d, i in zip(depth, inten, strict=True)]
    with FusionEngine(K, fusion=params, flow="dis", overlap_flow=True) as eng:
        got = []
        for t, (d, i) in enumerate(zip(depth, inten, strict=True)):
            if t in (1, 3):  # a push that fails after the worker started the pair's flow
                with pytest.raises(ShapeError):
                    eng.push(d, i, points=np.zeros((H, W, 2), np.float32))
                assert eng._pending_flow is None
            got.append(eng.push(d, i)[0].points)
    np.testing.assert_array_equal(np.stack(got), np.stack(want))


@pytest.mark.parametrize(
    ("params", "overlap_flow"),
    [
        (FusionParams(num_frames=3, causal=True), True),
        (FusionParams(num_frames=5), False),
        (FusionParams(num_frames=4, flying_pixels="on", tracks="composed"), False),
    ],
)
def test_reset_engine_equals_a_new_engine_bit_for_bit(rng, params, overlap_flow):
    """issue 13: ``reset`` starts a new stream on the same buffers (``fuse4d live`` restarts
    at every gap); what the buffers held from the previous stream must not matter."""
    n = 7
    depth = _plane_depth(n) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    depth[2, 5:9, 5:9] = np.nan
    inten = _moving_texture(n)
    other = _plane_depth(9, base=800.0) + rng.normal(0, 2.0, (9, H, W)).astype(np.float32)
    other[:, :, :6] = np.nan  # holes where the new stream has depth
    other[4, 10:30, 10:30] = np.nan
    fresh = FusionEngine(K, fusion=params, flow="dis", overlap_flow=overlap_flow)
    want = [f for d, i in zip(depth, inten, strict=True) for f in fresh.push(d, i)]
    want += fresh.flush()
    fresh.close()
    with FusionEngine(K, fusion=params, flow="dis", overlap_flow=overlap_flow) as engine:
        # a previous stream, stopped without a flush, that ends on the new stream's first
        # image (a tracker still warm would start the first pair from its last flow)
        other_inten = _moving_texture(9, shift=2.0)[::-1].copy()
        other_inten[-1] = inten[0]
        for d, i in zip(other, other_inten, strict=True):
            engine.push(d, i)
        rings = [id(b) for b in (engine._fwd, engine._depth, engine._bilateral)]
        engine.reset()
        got = [f for d, i in zip(depth, inten, strict=True) for f in engine.push(d, i)]
        got += engine.flush()
        if params.num_frames > 1:  # the tracker began again: warm starts as in a new engine
            assert engine._flow_estimator.warm_starts == n - 2
        assert rings == [id(b) for b in (engine._fwd, engine._depth, engine._bilateral)]
        engine.reset()  # after a flush too
        again = [f for d, i in zip(depth[:3], inten[:3], strict=True) for f in engine.push(d, i)]
    assert [f.index for f in got] == [f.index for f in want] == list(range(n))
    for a, b in zip(got, want, strict=True):
        for field in ("points", "support", "filled", "unfilled", "source", "confidence"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert [f.index for f in again] == [f.index for f in want if f.index + engine.latency < 3]


@pytest.mark.parametrize(
    "params", [FusionParams(num_frames=5), FusionParams(num_frames=3, causal=True)]
)
def test_output_range_emits_only_its_frames_with_the_same_bits(rng, params):
    """``set_output_range`` (a time chunk with its halo): only the frames of the range come out,
    each equal to the frame an engine that emits everything gives; misuse is refused."""
    n = 9
    depth = _plane_depth(n) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    depth[4, 5:9, 5:9] = np.nan
    inten = _moving_texture(n)
    full = FusionEngine(K, fusion=params, flow="dis")
    want = [f for d, i in zip(depth, inten, strict=True) for f in full.push(d, i)]
    want += full.flush()
    engine = FusionEngine(K, fusion=params, flow="dis")
    for first, stop in ((2, 6), (3, None)):
        engine.reset()
        engine.set_output_range(first, stop)
        got = [f for d, i in zip(depth, inten, strict=True) for f in engine.push(d, i)]
        got += engine.flush()
        assert [f.index for f in got] == list(range(first, n if stop is None else stop))
        for f in got:
            ref = want[f.index]
            for field in ("points", "support", "filled", "unfilled", "source", "confidence"):
                np.testing.assert_array_equal(getattr(f, field), getattr(ref, field))
    engine.reset()
    engine.push(depth[0], inten[0])
    with pytest.raises(RuntimeError, match="before the first push"):
        engine.set_output_range(1, 4)
    engine.reset()
    with pytest.raises(ValueError, match="first < stop"):
        engine.set_output_range(4, 4)


def test_shortcuts_without_fused_pixels_change_nothing(rng):
    """issue 13: the first frame of a causal window has no fused pixel (every valid pixel is
    an Eq. 6 hole); the Eq. 6 fill and the A29 base smoothing are skipped there, with the
    values the full computations give."""
    from fuse4d.fusion import _smooth_base

    depth = _plane_depth(1)[0] + rng.normal(0, 0.3, (H, W)).astype(np.float32)
    depth[5:9, 5:9] = np.nan
    points = depth_to_points(depth, K)
    hole = np.isfinite(depth)  # every valid pixel is a hole: F is empty
    raw = points + np.float32(0.5)
    kernel_points, kernel_hole = points.copy(), hole.copy()
    kernel_filled = np.zeros((H, W), np.bool_)
    _fill_holes_kernel(kernel_points, raw, kernel_hole, 2, 0.5, 10, 3, 5.0, kernel_filled)
    got_points, got_hole = points.copy(), hole.copy()
    filled = _fill_holes(
        got_points, raw, got_hole, radius=2, sigma=1.0, passes=10, min_neighbours=3, gate=5.0
    )
    np.testing.assert_array_equal(filled, kernel_filled)
    np.testing.assert_array_equal(got_points, kernel_points)
    np.testing.assert_array_equal(got_hole, kernel_hole)
    base = rng.normal(0, 0.1, (H, W, 3)).astype(np.float32)
    out = points.copy()
    _smooth_base(out, base, depth, hole, sigma=2.0, max_step=10.0, quad=1e-6, limit_quad=0.5)
    np.testing.assert_array_equal(out, points)
    partial = hole.copy()
    partial[20:30, 20:30] = False  # some fused pixels: the smoothing runs and changes them
    out = points.copy()
    _smooth_base(out, base, depth, partial, sigma=2.0, max_step=10.0, quad=1e-6, limit_quad=0.5)
    assert not np.array_equal(out, points)


@pytest.mark.parametrize(
    "params",
    [
        FusionParams(num_frames=5),
        FusionParams(num_frames=3, causal=True),
        FusionParams(num_frames=5, motion_sigma=1.5),  # a motion reference of its own
        FusionParams(num_frames=5, motion_depth="raw"),
    ],
)
def test_frame_states_from_another_engine_give_the_same_bits(rng, params):
    """The dask graph's halo frames: FrameState computed by one engine, pushed into another."""
    n = 8
    depth = _plane_depth(n) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    depth[3, 5:9, 5:9] = np.nan
    inten = _moving_texture(n)
    first = FusionEngine(K, fusion=params, flow="dis")
    want, states = [], []
    for d, i in zip(depth, inten, strict=True):
        want += first.push(d, i)
        states.append(first.frame_state(first._pushed - 1))
    want += first.flush()
    separate = params.motion_depth != "raw" and params.motion_sigma != params.reference_sigma
    assert (states[0].reference is not None) == separate
    timings: dict[str, float] = {}
    second = FusionEngine(K, fusion=params, flow="dis", timings=timings)
    got = []
    for t, (d, i) in enumerate(zip(depth, inten, strict=True)):
        got += second.push(d, i, state=states[t] if t % 2 else None)  # half given, half computed
    got += second.flush()
    assert [f.index for f in got] == [f.index for f in want]
    for a, b in zip(got, want, strict=True):
        for name in ("points", "support", "filled", "source", "confidence"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_frame_state_errors(rng):
    engine = FusionEngine(K, fusion=FusionParams(num_frames=3))
    depth = _plane_depth(1)[0]
    inten = _moving_texture(1)[0]
    with pytest.raises(IndexError, match="frame 0"):
        engine.frame_state(0)
    engine.push(depth, inten)
    state = engine.frame_state(0)
    with pytest.raises(ValueError, match="points or a frame state"):
        engine.push(depth, inten, points=np.zeros((H, W, 3), np.float32), state=state)
    with pytest.raises(ShapeError, match=r"state\.bilateral"):
        engine.push(depth, inten, state=dataclasses.replace(state, bilateral=state.bilateral[1:]))
    other = FusionEngine(K, fusion=FusionParams(num_frames=3, motion_sigma=1.5))
    with pytest.raises(ValueError, match="motion reference"):
        other.push(depth, inten, state=state)


# ----------------------------------------------------------------------------- composed tracks (A31)
def _composed_engine_tracks(depth, inten, fwd, bwd, k, params):
    """{t: (first, last, rows, cols, ok)} of every frame the engine emits (tracks="composed")."""
    engine = FusionEngine(k, fusion=params, flow=SequenceFlow(fwd, bwd))
    seen = {}
    emit = engine._emit

    def spy(t):
        first, last = _window(t, engine.past, engine.future, engine._pushed)
        rows, cols, ok = engine._composed.window(t, first, last)
        seen[t] = (first, last, rows.copy(), cols.copy(), ok.copy())
        return emit(t)

    engine._emit = spy
    for d, i in zip(depth, inten, strict=True):
        engine.push(d, i)
    engine.flush()
    return engine, seen


@pytest.mark.parametrize("causal", [False, True])
def test_composed_tracks_match_oracle(rng, causal):
    """The engine's composed tracks (A31) equal the NumPy composition (naive.composed_track)
    for every frame, truncated windows included, and differ from the exact chains somewhere."""
    depth, inten, fwd, bwd, k = _switch_scene(rng, n=7)
    params = SWITCH_BASE.replace(num_frames=5, causal=causal, tracks="composed")
    _engine, seen = _composed_engine_tracks(depth, inten, fwd, bwd, k, params)
    quads = [estimate_noise_quad(d) for d in depth]
    differs = 0
    for t, (first, last, rows, cols, ok) in seen.items():
        expected = naive.composed_track(fwd, bwd, depth, t, first, last, 1.0, 0.6, quads)
        exact = naive.track(fwd, bwd, depth, t, first, last, 1.0, 0.6, quads[t], False)
        others = [T for T in range(first, last + 1) if t != T]
        for j, T in enumerate(others):
            for v, u in np.ndindex(depth.shape[1:]):
                r, c, valid = expected[(T, v, u)]
                assert ok[j, v, u] == valid, (t, T, v, u)
                if valid:
                    assert (rows[j, v, u], cols[j, v, u]) == (r, c), (t, T, v, u)
                differs += exact[(T, v, u)] != (r, c, valid) and (valid or exact[(T, v, u)][2])
    assert differs > 0  # the scene's noisy flows tell composed from exact chains


def test_composed_tracks_equal_exact_on_a_translation(rng):
    """On a rigid sub-pixel translation (the same flow everywhere) composition is exact: the
    composed and the exact tracks fuse to the same output, bit for bit."""
    n, h, w = 9, 24, 30
    k = Intrinsics(fx=600.0, fy=600.0, cx=14.5, cy=11.5, width=w, height=h)
    depth = (800.0 + rng.normal(0, 0.2, (n, h, w))).astype(np.float32)
    inten = rng.uniform(0.2, 0.8, (n, h, w)).astype(np.float32)
    fwd = np.broadcast_to(np.array([0.35, -0.2], np.float32), (n - 1, h, w, 2)).copy()
    bwd = -fwd
    out = {}
    for tracks in ("exact", "composed"):
        res = fuse_sequence(
            depth, inten, k, fusion=FusionParams(tracks=tracks), flow=SequenceFlow(fwd, bwd)
        )
        out[tracks] = res
    np.testing.assert_array_equal(out["exact"].support, out["composed"].support)
    np.testing.assert_array_equal(out["exact"].points, out["composed"].points)
    assert (out["exact"].support[4] == 8).mean() > 0.5


def test_composed_tracks_do_not_depend_on_where_the_engine_started(rng):
    """A frame's composed tracks use only the pairs inside its window: an engine that starts
    later (a dask chunk with its halo) emits the same frames bit for bit."""
    depth, inten, fwd, bwd, k = _switch_scene(rng, n=9)
    params = SWITCH_BASE.replace(num_frames=5, tracks="composed")
    full = fuse_sequence(depth, inten, k, fusion=params, flow=SequenceFlow(fwd, bwd))
    start = 3
    late = fuse_sequence(
        depth[start:], inten[start:], k, fusion=params,
        flow=SequenceFlow(fwd[start:], bwd[start:]),
    )  # fmt: skip
    for t in range(start + params.past_frames, 9 - params.future_frames):
        np.testing.assert_array_equal(late.points[t - start], full.points[t])
        np.testing.assert_array_equal(late.support[t - start], full.support[t])


def test_engine_buffer_estimate_is_what_the_engine_allocates():
    """The memory check's estimate (``_engine_buffer_bytes``) follows the buffers the
    engine allocates, composed tracks (A31) or exact."""
    import tracemalloc

    from fuse4d.fusion import _engine_buffer_bytes

    FusionEngine(K).close()  # imports and caches outside the measurement
    for params in (FusionParams(), FusionParams(num_frames=16, tracks="exact", causal=True)):
        tracemalloc.start()
        try:
            engine = FusionEngine(K, fusion=params)
            held = tracemalloc.get_traced_memory()[0]
        finally:
            tracemalloc.stop()
        estimate = _engine_buffer_bytes(params, H, W, engine.ring)
        assert estimate <= held < 1.05 * estimate


def test_engine_refuses_a_window_whose_buffers_do_not_fit(monkeypatch):
    """--window 64 at 640x480 under a 4 GB address-space limit was an internal MemoryError
    (33 x 63 composed-track tables); without a limit n = 256 needed ~50 GB (the OOM killer).
    The engine refuses it up front, naming the window, the frame size, the memory and the
    ways out, and turns a MemoryError of its allocations into the same error."""
    import fuse4d.fusion as fusion_module
    import fuse4d.motion as motion_module
    from fuse4d.errors import ParameterError
    from fuse4d.fusion import _engine_buffer_bytes

    params = FusionParams(num_frames=64)
    need = _engine_buffer_bytes(params, H, W, 64)
    exact = _engine_buffer_bytes(params.replace(tracks="exact"), H, W, 64)
    assert exact < need / 3  # the composed tables grow with the square of the window
    monkeypatch.setattr(fusion_module, "available_memory", lambda: exact + 1)
    message = (
        r"num_frames=64 frames at 48x40 px needs about [\d.]+ MiB of fusion buffers, {}: "
        r"use a smaller window"
    )
    fits = message.format(r"[\d.]+ MiB is available")
    with pytest.raises(ParameterError, match=fits + r".*tracks='exact'"):
        FusionEngine(K, fusion=params)
    frames = [(np.full((H, W), 500.0), np.full((H, W), 0.5))] * 2
    with pytest.raises(ParameterError, match=fits):  # the streaming face, at its start
        next(fuse_stream(frames, K, fusion=params))
    FusionEngine(K, fusion=params.replace(tracks="exact")).close()  # fits
    monkeypatch.setattr(fusion_module, "available_memory", lambda: None)  # unknown: not checked

    def failing(shape, dtype, value=0):
        raise MemoryError(f"Unable to allocate an array with shape {shape}")

    monkeypatch.setattr(motion_module, "committed", failing)
    with pytest.raises(ParameterError, match=message.format("the allocation failed")):
        FusionEngine(K, fusion=params)
    # the estimate fit, the allocation failed: not "needs 1 MiB, 20 GiB is available"
    monkeypatch.setattr(fusion_module, "available_memory", lambda: 100 * need)
    failed = message.format(r"the allocation failed although about [\d.]+ .iB appeared available")
    with pytest.raises(ParameterError, match=failed):
        FusionEngine(K, fusion=params)


@pytest.mark.parametrize("iterations", [2, 3])
def test_filled_flags_are_the_last_passs_with_iterations(iterations):
    """``filled`` (Eq. 6) was ORed over the passes while support and source were the last
    pass's: on a ToF ball 256 of 410 pixels flagged filled had support > 0 and were fused."""
    from fuse4d.holes import SOURCE_MEASURED
    from fuse4d.range_scenes import make_range_scene

    seq = make_range_scene("ball", sensor="tof", small=True, num_frames=6, rng=0)
    params = FusionParams(num_frames=3, fill_holes=True, iterations=iterations)
    res = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=params, sensor="tof")
    assert res.filled.any()
    assert (res.support[res.filled] == 0).all()  # filled: no temporal support (Eq. 6)
    assert (res.source[res.filled] == SOURCE_MEASURED).all()


def test_fuse_stream_applies_flying_pixels_auto_for_the_sensor():
    """fuse_stream had no sensor=: a ToF recording's frames were fused with flying-pixel
    removal off ("auto" read as "off") where fuse4d run removed them."""
    from fuse4d.holes import SOURCE_REJECTED
    from fuse4d.range_scenes import make_range_scene

    seq = make_range_scene("body", sensor="tof", small=True, num_frames=3, rng=0)
    params = FusionParams(num_frames=3)
    frames = list(zip(seq.depth, seq.intensity, strict=True))
    streamed = list(fuse_stream(frames, seq.intrinsics, fusion=params, sensor="tof"))
    ref = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=params, sensor="tof")
    assert (ref.source == SOURCE_REJECTED).any()
    for f in streamed:
        np.testing.assert_array_equal(f.source, ref.source[f.index])
        np.testing.assert_array_equal(f.points, ref.points[f.index])
    plain = list(fuse_stream(frames, seq.intrinsics, fusion=params))  # unknown sensor: off
    assert not any((f.source == SOURCE_REJECTED).any() for f in plain)


def test_overlapped_flow_is_timed_in_its_worker(monkeypatch):
    """With overlap_flow the ``flow`` stage is only the wait for the worker; the flow's own
    seconds (2-19 ms/frame waited for 40-48 ms/frame of DIS in ``fuse4d bench --input``)
    are ``timings["flow_worker"]``."""
    from fuse4d.fusion import FLOW_WORKER, STAGES

    pause = 0.03
    flow_pair = FusionEngine._flow_pair

    def slow_flow_pair(self, index, intensity=None):
        time.sleep(pause)
        return flow_pair(self, index, intensity)

    monkeypatch.setattr(FusionEngine, "_flow_pair", slow_flow_pair)
    depth, inten, _fwd, _bwd = _translating(4)
    timings = dict.fromkeys(STAGES, 0.0)
    with FusionEngine(
        K, fusion=FusionParams(num_frames=3), timings=timings, overlap_flow=True
    ) as e:
        for t in range(4):
            e.push(depth[t], inten[t])
        e.flush()
    assert timings[FLOW_WORKER] >= 3 * pause  # three pairs, each timed in the worker
    serial = dict.fromkeys(STAGES, 0.0)
    with FusionEngine(K, fusion=FusionParams(num_frames=3), timings=serial) as e:
        e.push(depth[0], inten[0])
    assert FLOW_WORKER not in serial  # no worker, no key (bench rows, summed stages)
