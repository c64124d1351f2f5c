"""Tests of the 4D fusion pipeline (METHOD §3-§8; issue 3 acceptance list)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fuse4d import Intrinsics, ShapeError, depth_to_points
from fuse4d._kernels.fusion import (
    _fill_holes_kernel,
    _fuse_kernel,
    _project_to_rays_kernel,
    _segment_box_rows_kernel,
    _track_kernel,
)
from fuse4d.bilateral import bilateral_filter_points
from fuse4d.config import FusionParams
from fuse4d.flow import SequenceFlow
from fuse4d.fusion import FusionEngine, fuse_sequence, fuse_stream
from fuse4d.metrics import roughness_stats
from fuse4d.motion import (
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
def test_bilateral_kernel_matches_oracle(rng):
    pts = depth_to_points(_plane_depth(1)[0] + rng.normal(0, 0.3, (H, W)), K)[:12, :14]
    pts[3, 4] = np.nan
    inten = _texture(12, 14)
    ref = pts + np.float32(0.1)
    for reference in (None, ref):
        fast = bilateral_filter_points(
            pts, inten, radius=2, sigma_distance=2.0, sigma_intensity=0.1, reference=reference
        )
        slow = naive.bilateral3d(pts, inten, 2, 2.0, 0.1, reference=reference)
        np.testing.assert_allclose(fast, slow, rtol=0, atol=2e-4)
        assert np.isnan(fast[3, 4]).all()
        assert np.isfinite(fast[3, 5]).all()  # NaN does not spread


def test_weight_function_is_close_to_exp():
    x = np.linspace(0, 4, 41)
    approx = np.array([naive.approx_exp_neg(v) for v in x])
    np.testing.assert_allclose(approx, np.exp(-x), rtol=0.009)


def test_segment_box_kernel_matches_oracle(rng):
    depth = (500 + rng.normal(0, 1, (6, 30))).astype(np.float32)
    depth[:, 12:] += 50.0  # a depth edge
    depth[2, 5] = np.nan
    values = depth.copy()
    out = np.empty_like(depth)
    _segment_box_rows_kernel(values, depth, 3, 10.0, 0.0, out)
    np.testing.assert_allclose(out, naive.segment_box_rows(values, depth, 3, 10.0), atol=1e-4)


def test_motion_reference_never_crosses_edges():
    d = np.full((20, 30), 500.0, np.float32)
    d[:, 15:] = 800.0
    d[5, 5] = np.nan
    r = motion_reference_depth(d, sigma=5.0)
    np.testing.assert_array_equal(r[:, :15][np.isfinite(r[:, :15])], 500.0)
    np.testing.assert_array_equal(r[:, 15:], 800.0)
    assert np.isnan(r[5, 5])


def test_track_and_fuse_kernels_match_oracles(rng):
    n = 5
    depth = _plane_depth(n)[:, :14, :16] + rng.normal(0, 0.2, (n, 14, 16)).astype(np.float32)
    depth[2, 4, 4] = np.nan
    fwd = rng.uniform(-0.7, 0.9, (n - 1, 14, 16, 2)).astype(np.float32)
    bwd = (-fwd + rng.normal(0, 0.6, fwd.shape)).astype(np.float32)
    t, first, last = 2, 0, 4
    ring_f = np.concatenate([np.zeros_like(fwd[:1]), fwd])
    ring_b = np.concatenate([np.zeros_like(bwd[:1]), bwd])
    rows = np.empty((4, 14, 16), np.int32)
    cols = np.empty_like(rows)
    ok = np.empty(rows.shape, bool)
    slots = np.arange(first, last + 1)
    _track_kernel(
        ring_f, ring_b, depth, slots, t, first, last, 1.0, 0.6, 0.0, False, rows, cols, ok
    )
    oracle = naive.track(fwd, bwd, depth, t, first, last, 1.0, 0.6)
    others = [T for T in range(first, last + 1) if t != T]
    for k, T in enumerate(others):
        for v in range(14):
            for u in range(16):
                r, c, alive = oracle[(T, v, u)]
                assert ok[k, v, u] == alive, (T, v, u)
                if alive:
                    assert (rows[k, v, u], cols[k, v, u]) == (r, c)
    assert 0 < ok.mean() < 1  # the test exercises both outcomes
    bil = rng.normal(0, 0.3, (n, 14, 16, 3)).astype(np.float32) + 500
    ref = rng.normal(0, 0.3, (n, 14, 16, 3)).astype(np.float32) + 500
    ref[2, 4, 4] = np.nan
    weights = np.exp(-(np.arange(3.0) ** 2) / 18.0)
    out = np.empty((14, 16, 3), np.float32)
    support = np.empty((14, 16), np.uint8)
    hole = np.empty((14, 16), bool)
    for trajectory in (False, True):
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
            1.0,
            0.8,
            0.0,
            0.0,
            trajectory,
            out,
            support,
            hole,
        )
        expected, exp_support = naive.fuse(
            bil, ref, oracle, t, first, last, weights, 0.8, trajectory=trajectory
        )
        np.testing.assert_array_equal(support, exp_support)
        fused = support >= 1
        np.testing.assert_allclose(out[fused], expected[fused], atol=1e-4)
        np.testing.assert_array_equal(out[hole], bil[t][hole])  # holes keep B^t (fallback)


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
    _project_to_rays_kernel(shifted, pts.astype(np.float32), K.fx, K.fy, K.cx, K.cy, 10.0, out)
    np.testing.assert_allclose(out, pts, atol=2e-3)
    assert np.abs(shifted - pts).max() > 0.3


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
    res = fuse_sequence(depth, inten, K, flow=_zero_flow(n))
    assert np.isnan(res.depth[2, 10:13, 10:13]).all()
    assert np.isfinite(res.depth[2, 9, 9:14]).all()  # no spreading
    assert np.isfinite(res.depth[2, 20, 30])  # other frame's hole only lowers support:
    assert res.support[2, 20, 30] == 2  # frames 1 and 0 (behind it) are lost, 3 and 4 kept
    assert res.support[2, 20, 31] == 4
    assert np.isnan(res.points[2, 11, 11]).all()


def test_literal_motion_is_much_rougher_than_regularised(rng):
    n = 9
    depth = _plane_depth(n, slope=0.0) + rng.normal(0, 0.3, (n, H, W)).astype(np.float32)
    inten = np.broadcast_to(_texture(H, W), (n, H, W)).copy()
    default = fuse_sequence(depth, inten, K, flow=_zero_flow(n))
    literal = fuse_sequence(
        depth, inten, K, flow=_zero_flow(n), fusion=FusionParams(motion_depth="raw", base="frame")
    )
    roi = np.zeros((n, H, W), bool)
    roi[:, 6:-6, 6:-6] = True
    r_default = roughness_stats(default.points, roi=roi).mean
    r_literal = roughness_stats(literal.points, roi=roi).mean
    r_raw = roughness_stats(depth_to_points(depth, K), roi=roi).mean
    assert r_default < 0.3 * r_literal
    assert r_literal > 0.8 * r_raw  # the literal Eq. 5 keeps frame t's own noise


def test_moving_object_fused_without_ghosting(rng):
    n = 9
    depth, inten, fwd, bwd = _translating(n)
    depth = depth + rng.normal(0, 0.2, depth.shape).astype(np.float32)
    res = fuse_sequence(depth, inten, K, flow=SequenceFlow(fwd, bwd))
    inner = (slice(4, 5), slice(8, -8), slice(8, -8))
    assert np.std(res.depth[inner] - 600.0) < 0.35 * np.std(depth[inner] - 600.0)
    assert (res.support[4, 8:-8, 8:-8] >= 6).mean() > 0.9


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
    with pytest.raises(RuntimeError, match="engine was flushed"):
        engine.push(depth[0], inten)


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
    res = fuse_sequence(depth, inten, K, flow=_zero_flow(4))
    assert np.isnan(res.depth[1]).all()
    assert np.isfinite(res.depth[0]).all()
    # tracks are never re-acquired (METHOD §4.1): an empty frame 1 cuts frame 0 off the rest
    assert (res.support[0] == 0).all()
    assert (res.support[3, 5:-5, 5:-5] == 1).all()
    single = fuse_sequence(depth[:1], inten[:1], K)
    assert (single.support == 0).all()  # no other frame: bilateral-only result, documented
    np.testing.assert_allclose(single.depth[0], depth[0], atol=2e-3)
    assert single.flow_forward.shape == (0, H, W, 2)


@pytest.mark.parametrize("value", [math.inf, 2.0])
def test_temporal_gate_parameter(value):
    assert FusionParams(temporal_gate=value).temporal_gate == value


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
