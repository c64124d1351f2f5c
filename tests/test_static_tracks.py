"""A33: static pixels keep still (fuse4d.static_tracks, FusionParams.static_tracks)."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d import Intrinsics, fuse_sequence
from fuse4d.config import FusionParams
from fuse4d.flow import SequenceFlow
from fuse4d.motion import _pair_ring, _track_window
from fuse4d.static_tracks import static_pixels
from naive import fusion as naive


def _scene(rng, n=9, h=40, w=56, jitter=1.0):
    """A quantised, textureless static wall at 2.5 m with DIS-like spurious flow (smooth,
    forward-backward consistent, up to ~``jitter`` px, new in every pair), and a textured
    foreground square at 1.5 m moving 2 px per frame to the right with its exact flow."""
    k = Intrinsics(fx=580.0, fy=580.0, cx=w / 2, cy=h / 2, width=w, height=h)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    step = 2500.0**2 / (580.0 * 75.0 * 8.0)  # one disparity level of a Kinect v1 at 2.5 m
    wall = 2500.0 + 0.8 * xx + rng.normal(0, 0.35 * step, (n, h, w))
    depth = (np.round(wall / step) * step).astype(np.float32)
    inten = np.full((n, h, w), 0.5, np.float32) + rng.normal(0, 0.01, (n, h, w)).astype(np.float32)
    r0, r1, side = int(0.3 * h), int(0.7 * h), w // 4
    texture = rng.uniform(0.1, 0.9, (r1 - r0, side)).astype(np.float32)
    fwd = np.empty((n - 1, h, w, 2), np.float32)
    square = np.zeros((n, h, w), bool)
    for t in range(n):
        c0 = w // 8 + 2 * t
        square[t, r0:r1, c0 : c0 + side] = True
        depth[t, r0:r1, c0 : c0 + side] = 1500.0
        inten[t, r0:r1, c0 : c0 + side] = texture  # the texture moves with the square
    for t in range(n - 1):
        phase = rng.uniform(0, 2 * np.pi, 2)
        fwd[t, ..., 0] = jitter * np.sin(xx / 9.0 + phase[0]) * np.cos(yy / 7.0)
        fwd[t, ..., 1] = jitter * np.cos(xx / 8.0) * np.sin(yy / 11.0 + phase[1])
        fwd[t][square[t]] = (2.0, 0.0)
    bwd = -fwd  # consistent enough for the FB check (the flow is smooth)
    for t in range(n - 1):
        bwd[t][square[t + 1]] = (-2.0, 0.0)
    return depth, inten, fwd, bwd, k, square


def test_static_pixels_match_the_oracle(rng):
    depth, inten, fwd, bwd, _k, _square = _scene(rng, n=5, h=14, w=18, jitter=0.8)
    ref = depth.copy()  # any reference: a slightly smoothed copy keeps some pixels apart
    ref[:, :, 1:] = 0.5 * (depth[:, :, 1:] + depth[:, :, :-1])
    ref_points = np.zeros((*ref.shape, 3), np.float32)
    ref_points[..., 2] = ref
    quad = 4.0e-6
    t, first, last = 2, 0, 4
    slots, rows, cols, ok = _track_window(
        _pair_ring(fwd),
        _pair_ring(bwd),
        depth,
        t,
        first,
        last,
        fb_threshold=2.0,
        max_step=10.0,
        quad=quad,
        per_step=False,
    )
    got = static_pixels(ref_points, inten, depth[t], slots, t, first, (rows, cols, ok), quad)
    tracks = naive.track(fwd, bwd, depth, t, first, last, 2.0, 10.0, quad)
    _tracks, expected = naive.static_tracks(tracks, ref, inten, depth[t], t, first, last, quad)
    np.testing.assert_array_equal(got, expected)
    assert 0 < got.mean() < 1  # both kinds of pixel occur


def _static_mask(depth, inten, shift=2.0):
    """static_pixels on a scene whose every pixel moves ``shift`` px per frame to the right
    (exact flows, valid tracks), t = 2 of 5 frames, reference = the raw depth."""
    n, h, w = depth.shape
    fwd = np.zeros((n - 1, h, w, 2), np.float32)
    fwd[..., 0] = shift
    ref = np.zeros((*depth.shape, 3), np.float32)
    ref[..., 2] = depth
    quad = 2.0e-6  # 2 q z^2 = 9 mm at 1.5 m
    slots, rows, cols, ok = _track_window(
        _pair_ring(fwd),
        _pair_ring(-fwd),
        depth,
        2,
        0,
        n - 1,
        fb_threshold=1.0,
        max_step=10.0,
        quad=quad,
        per_step=False,
    )
    return static_pixels(ref, inten, depth[2], slots, 2, 0, (rows, cols, ok), quad)


def test_static_needs_still_depth_and_no_better_flow(rng):
    n, h, w = 5, 20, 40
    depth = np.full((n, h, w), 1500.0, np.float32)
    inside = (slice(None), slice(4, -4))  # tracks from the middle columns stay in the image
    texture = rng.uniform(0.1, 0.9, (h, w + 2 * n)).astype(np.float32)
    moving = np.stack([texture[:, 2 * (n - t) : 2 * (n - t) + w] for t in range(n)])
    # a textured surface sliding sideways at constant depth: the flow explains the intensity
    assert not _static_mask(depth, moving)[inside].any()
    # the same without texture (intensity noise only): standing still is as good
    flat = 0.5 + rng.normal(0, 0.01, (n, h, w)).astype(np.float32)
    assert _static_mask(depth, flat)[inside].all()
    # ... unless the depth at the pixel moves by more than 2 q z^2 in some frame
    stepped = depth.copy()
    stepped[4, :, : w // 2] += 10.0
    mask = _static_mask(stepped, flat)
    assert not mask[:, 4 : w // 2].any()
    assert mask[:, w // 2 : -4].all()
    # frame t's own holes are never static
    holed = depth.copy()
    holed[2, 5:8, 10:14] = np.nan
    assert not _static_mask(holed, flat)[5:8, 10:14].any()


def _flicker(depth, mask):
    """Mean |frame-to-frame change| (mm) over the (H, W) ``mask``'s pixels, where valid."""
    step = np.abs(np.diff(depth, axis=0))
    both = mask[None] & np.isfinite(step)
    return float(step[both].mean())


@pytest.mark.parametrize("tracks", ["exact", "composed"])
def test_static_background_stops_flickering_without_trails(rng, tracks):
    depth, inten, fwd, bwd, k, square = _scene(rng)
    flows = SequenceFlow(fwd, bwd)
    on = FusionParams(tracks=tracks)
    off = on.replace(static_tracks=False)
    fused_on = fuse_sequence(depth, inten, k, fusion=on, flow=flows).depth
    fused_off = fuse_sequence(depth, inten, k, fusion=off, flow=flows).depth
    # the wall never covered by the square, in the frames with a full window (2..6)
    wall = ~np.any(square, axis=0)
    wall[:, :3] = wall[:, -3:] = False  # away from the border, where tracks leave
    raw, f_on, f_off = (_flicker(d[2:7], wall) for d in (depth, fused_on, fused_off))
    assert f_on < 0.6 * f_off < 0.6 * raw
    # no trail: near the square's edges the output keeps the raw depth's side of the edge
    edge = np.zeros_like(square)
    for t in range(depth.shape[0]):
        grown = np.roll(square[t], 3, axis=1) | np.roll(square[t], -3, axis=1)
        grown |= np.roll(square[t], 3, axis=0) | np.roll(square[t], -3, axis=0)
        edge[t] = grown & ~square[t]  # wall pixels within 3 px of the square
        edge[t] |= square[t] & ~np.roll(square[t], 3, axis=1)  # square pixels near its edge
    valid = edge & np.isfinite(depth) & np.isfinite(fused_on)
    assert np.abs(fused_on - depth)[valid].max() < 100.0
    # the moving textured square follows its tracks: the same result as without A33
    inner = square & np.roll(square, 2, axis=2) & np.roll(square, -2, axis=2)
    np.testing.assert_allclose(fused_on[inner], fused_off[inner], atol=1e-3)


@pytest.mark.parametrize("trajectory", [1, 3])
def test_static_pixels_have_a_constant_trajectory(rng, trajectory):
    """A34: with a trajectory base, a static pixel's base is the weighted mean of its motion
    vectors (t's own zero included), not a line through them: at the end of a causal window a
    line extrapolates its fitted noise. Kernel against the oracle, static pixels fused from
    their own samples (A33) and the others along their tracks."""
    from fuse4d._kernels.fusion import _fuse_kernel
    from fuse4d.fusion import CURVATURE_MIN_BIAS, curvature_f_critical

    n, h, w = 5, 10, 12
    first, last = 0, n - 1
    t = last  # causal: the window ends at t
    slots = np.arange(n, dtype=np.int64)
    bil = (rng.normal(0, 0.3, (n, h, w, 3)) + 2000).astype(np.float32)
    ref = (rng.normal(0, 0.3, (n, h, w, 3)) + 2000).astype(np.float32)
    ref[..., 2] += np.arange(n, dtype=np.float32)[:, None, None] * 0.2  # a drift to fit
    rows = rng.integers(0, h, (n - 1, h, w)).astype(np.int32)
    cols = rng.integers(0, w, (n - 1, h, w)).astype(np.int32)
    ok = rng.random((n - 1, h, w)) < 0.8
    static = rng.random((h, w)) < 0.5
    tol_quad = 1.5 / 2000.0**2  # 1.5 mm at 2 m: some of the own samples fail it
    tracks = {}
    for k, T in enumerate(range(first, last)):
        for v in range(h):
            for u in range(w):
                if static[v, u]:
                    zt = float(ref[t, v, u, 2])
                    agree = abs(float(ref[T, v, u, 2]) - zt) <= tol_quad * zt * zt
                    tracks[(T, v, u)] = (v, u, agree)
                else:
                    tracks[(T, v, u)] = (int(rows[k, v, u]), int(cols[k, v, u]), bool(ok[k, v, u]))
    weights = np.exp(-(np.arange(n, dtype=np.float64) ** 2) / 18.0)
    out = np.empty((h, w, 3), np.float32)
    support = np.empty((h, w), np.uint8)
    hole = np.empty((h, w), bool)
    base = np.empty((h, w, 3), np.float32)
    gate = 1e9
    _fuse_kernel(
        bil, ref, slots, t, first, rows, cols, ok, weights, 1, np.inf, 0.3, 0.0, gate,
        trajectory, curvature_f_critical(n), CURVATURE_MIN_BIAS, static, tol_quad,
        out, support, hole, base,
    )  # fmt: skip
    expected, exp_support = naive.fuse(
        bil, ref, tracks, t, first, last, weights, gate, trajectory=trajectory,
        noise=lambda z: 0.3, min_bias=CURVATURE_MIN_BIAS, constant=static,
    )  # fmt: skip
    np.testing.assert_array_equal(support, exp_support)
    fused = support >= 1
    assert (fused & static).sum() > 10
    assert (fused & ~static).sum() > 10
    np.testing.assert_allclose(out[fused], expected[fused], atol=1e-3)
    # the line would have extrapolated the drift: different at the static pixels
    line, _ = naive.fuse(
        bil, ref, tracks, t, first, last, weights, gate, trajectory=trajectory,
        noise=lambda z: 0.3, min_bias=CURVATURE_MIN_BIAS,
    )  # fmt: skip
    assert np.abs(line - expected)[fused & static].max() > 0.1
    np.testing.assert_allclose(line[fused & ~static], expected[fused & ~static])


def test_static_smoothing_takes_the_staircase_off_a_static_wall(rng):
    """A42: after fusion the static pixels move along their rays toward the edge-limited
    spatial mean of the fused depth, by at most ``static_smoothing_limit`` q z^2; the
    quantised wall comes closer to its true plane and the moving square is untouched."""
    from fuse4d.motion import estimate_noise_quad

    depth, inten, fwd, bwd, k, square = _scene(rng)
    flows = SequenceFlow(fwd, bwd)
    on_params = FusionParams()
    assert on_params.static_smoothing == 4.0  # A42 is on by default (stop 42)
    on = fuse_sequence(depth, inten, k, fusion=on_params, flow=flows).points
    off = fuse_sequence(depth, inten, k, fusion=on_params.replace(static_smoothing=0), flow=flows)
    off = off.points
    h, w = depth.shape[1:]
    truth = 2500.0 + 0.8 * np.mgrid[0:h, 0:w][1]
    wall = ~np.any(square, axis=0)
    wall[:, :3] = wall[:, -3:] = False

    def rmse(points):
        return float(np.sqrt(np.mean((points[2:7, ..., 2][:, wall] - truth[wall]) ** 2)))

    assert rmse(on) < 0.8 * rmse(off) < 0.2 * rmse(depth[..., None] * np.ones(3))
    inner = square & np.roll(square, 2, axis=2) & np.roll(square, -2, axis=2)
    np.testing.assert_array_equal(on[inner], off[inner])
    for t in range(depth.shape[0]):
        z_on, z_off = on[t, ..., 2], off[t, ..., 2]
        both = np.isfinite(z_on) & np.isfinite(z_off)
        limit = on_params.static_smoothing_limit * estimate_noise_quad(depth[t]) * z_off**2
        assert (np.abs(z_on - z_off)[both] <= limit[both] + 1e-3).all()  # float32 at 2.5 m
        # along the ray: the lateral position scales with the depth
        ratio = z_on[both] / z_off[both]
        np.testing.assert_allclose(
            on[t][both][:, :2], off[t][both][:, :2] * ratio[:, None], rtol=1e-5, atol=1e-3
        )


def test_static_smoothing_kernel_moves_static_points_within_the_limit(rng):
    from fuse4d._kernels.fusion import _static_smoothing_kernel

    h, w = 9, 11
    points = np.empty((h, w, 3), np.float32)
    z = rng.uniform(1000.0, 3000.0, (h, w)).astype(np.float32)
    points[..., 0] = rng.uniform(-500, 500, (h, w)) * z / 1000.0
    points[..., 1] = rng.uniform(-400, 400, (h, w)) * z / 1000.0
    points[..., 2] = z
    points[0, 0] = np.nan
    target = (z + rng.normal(0, 30.0, (h, w))).astype(np.float32)
    target[1, 1] = np.nan
    static = rng.random((h, w)) < 0.6
    static[0, 0] = static[1, 1] = True
    limit_quad = 2.0e-6
    out = points.copy()
    _static_smoothing_kernel(out, target, static, limit_quad)
    for v in range(h):
        for u in range(w):
            p, q = points[v, u], out[v, u]
            if not static[v, u] or not np.isfinite(target[v, u]) or not np.isfinite(p[2]):
                np.testing.assert_array_equal(q, p)
                continue
            lim = limit_quad * float(p[2]) ** 2
            expected = float(p[2]) + min(max(float(target[v, u]) - float(p[2]), -lim), lim)
            np.testing.assert_allclose(q[2], expected, rtol=1e-6)
            np.testing.assert_allclose(q, p * (expected / float(p[2])), rtol=1e-5)
