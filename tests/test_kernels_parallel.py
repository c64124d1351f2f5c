"""The row-parallel tracking kernel equals its serial, pixel-by-pixel reference bit for bit
(issue 13: the kernel was restructured for speed, its results must not move; the fusion
kernel's oracle test is in test_fusion.py)."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d._kernels._common import (
    _bilinear2,
    _bilinear2_plane,
    _bilinear_stencil,
    _round_half_up,
    _step_limit,
)
from fuse4d._kernels._numba import njit
from fuse4d._kernels.fusion import _track_kernel, _track_step
from fuse4d.motion import _NO_FILL, _TimeFill, _track_window


@njit
def _serial_track(fwd_ring, bwd_ring, depth_ring, frame_slot, t, first, last, theta, max_step,
                  quad, per_step, land_row, land_col, land_ok):  # fmt: skip
    """The tracking kernel as it was before issue 13: one pixel's chain after the other."""
    h = depth_ring.shape[1]
    w = depth_ring.shape[2]
    st = frame_slot[t - first]
    for v in range(h):
        for u in range(w):
            for direction in (1, -1):
                x = float(u)
                y = float(v)
                r = v
                c = u
                prev = depth_ring[st, v, u]
                alive = not np.isnan(prev)
                n_steps = last - t if direction == 1 else t - first
                for step in range(1, n_steps + 1):
                    T = t + direction * step
                    k = T - first - 1 if direction == 1 else T - first
                    slot = frame_slot[T - first]
                    flow_slot = slot if direction == 1 else frame_slot[T + 1 - first]
                    step_ring = fwd_ring if direction == 1 else bwd_ring
                    check_ring = bwd_ring if direction == 1 else fwd_ring
                    if alive:
                        ok, nx, ny = _track_step(
                            step_ring, check_ring, flow_slot, x, y, theta, per_step
                        )
                        if ok:
                            nr = _round_half_up(ny)
                            nc = _round_half_up(nx)
                            d1 = depth_ring[slot, nr, nc]
                            if np.isnan(d1) or not (
                                abs(d1 - prev) < _step_limit(prev, max_step, quad)
                            ):
                                ok = False
                            else:
                                x, y, r, c, prev = nx, ny, nr, nc, d1
                        alive = ok
                    land_ok[k, v, u] = alive
                    land_row[k, v, u] = r
                    land_col[k, v, u] = c


def _window_case(rng, s=9, h=37, w=53):
    """A ring of s noisy frames with random sub-pixel flows, holes and depth steps."""
    depth = (600.0 + rng.normal(0, 0.5, (s, h, w))).astype(np.float32)
    depth[:, :, w // 2 :] += 40.0  # a depth edge
    depth[rng.random((s, h, w)) < 0.03] = np.nan
    fwd = rng.uniform(-1.5, 1.8, (s, h, w, 2)).astype(np.float32)
    bwd = (-fwd + rng.normal(0, 0.7, fwd.shape)).astype(np.float32)
    return fwd, bwd, depth


@pytest.mark.parametrize("per_step", [False, True])
@pytest.mark.parametrize(("t", "first", "last"), [(13, 9, 17), (4, 0, 8), (2, 0, 5), (8, 8, 8)])
def test_track_kernel_equals_serial_reference(rng, per_step, t, first, last):
    fwd, bwd, depth = _window_case(rng)
    s = depth.shape[0]
    slots = np.arange(first, last + 1, dtype=np.int64) % s  # ring wrap-around for t = 13
    k = max(last - first, 1)
    got = [np.zeros((k, 37, 53), dt) for dt in (np.int32, np.int32, np.bool_)]
    exp = [np.zeros((k, 37, 53), dt) for dt in (np.int32, np.int32, np.bool_)]
    args = (fwd, bwd, depth, slots, t, first, last, 1.0, 5.0, 1e-5, per_step)
    _track_kernel(*args, *got, *_NO_FILL)
    _serial_track(*args, *exp)
    for a, b in zip(got, exp, strict=True):
        np.testing.assert_array_equal(a, b)
    if last > first:
        assert 0.05 < got[2].mean() < 0.95  # both outcomes exercised


@pytest.mark.parametrize("per_step", [False, True])
@pytest.mark.parametrize(("t", "first", "last"), [(13, 9, 17), (4, 0, 8), (5, 0, 5), (0, 0, 3)])
def test_holes_chained_beside_the_tracks_equal_the_time_fill_kernel(rng, per_step, t, first, last):
    """The A26 fill that the tracking pass does beside the tracks (the engine's) gives the
    points and counts of the separate kernel and of its per-pixel reference, bit for bit, and
    leaves the tracks as they are without it."""
    from fuse4d._kernels.holes import _temporal_fill_kernel, _temporal_fill_reference

    fwd, bwd, depth = _window_case(rng)
    s, h, w = depth.shape
    depth[rng.random((s, h, w)) < 0.2] = np.nan  # more holes: some tracks run through several
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    noisy = depth + rng.normal(0, 1, depth.shape)
    ref = np.stack([np.broadcast_to(u, depth.shape), np.broadcast_to(v, depth.shape), noisy], -1)
    ref = ref.astype(np.float32)
    ref[rng.random((s, h, w)) < 0.02] = np.nan  # depth without a reference point
    slots = np.arange(first, last + 1, dtype=np.int64) % s
    target = np.isnan(depth[t % s]) & (rng.random((h, w)) < 0.9)  # holes, as the engine's
    weight = rng.uniform(0.2, 1.0, s)
    k = last - first
    args = (fwd, bwd, depth, slots, t, first, last, 1.0, 5.0, 1e-5, per_step)
    plain = [np.zeros((k, h, w), dt) for dt in (np.int32, np.int32, np.bool_)]
    _track_kernel(*args, *plain, *_NO_FILL)
    got = [np.zeros((k, h, w), dt) for dt in (np.int32, np.int32, np.bool_)]
    pts, cnt = np.full((h, w, 3), -1.0, np.float32), np.full((h, w), 99, np.uint8)
    _track_kernel(*args, *got, *_TimeFill(target, ref, weight, 1, pts, cnt))
    for a, b in zip(got, plain, strict=True):
        np.testing.assert_array_equal(a, b)
    for fill in (_temporal_fill_kernel, _temporal_fill_reference):
        want_pts = np.full((h, w, 3), -1.0, np.float32)
        want_cnt = np.full((h, w), 99, np.uint8)
        fill(fwd, bwd, depth, ref, slots, t, first, last, 1.0, 5.0, 1e-5, weight, 1, target,
             want_pts, want_cnt, per_step)  # fmt: skip
        np.testing.assert_array_equal(cnt, want_cnt)
        np.testing.assert_array_equal(pts.view(np.uint32), want_pts.view(np.uint32))
    assert (cnt[target] > 1).any()  # multi-frame fills ...
    assert (cnt[target] == 0).any()  # ... and targets left unfilled
    assert (pts[~target] == -1.0).all()  # only the targets are written


def test_track_window_reuses_buffers(rng):
    fwd, bwd, depth = _window_case(rng)
    kw = {"fb_threshold": 1.0, "max_step": 5.0, "quad": 0.0, "per_step": False}
    _s, rows, cols, ok = _track_window(fwd, bwd, depth, 4, 0, 8, **kw)
    bufs = (np.empty((8, 37, 53), np.int32), np.empty((8, 37, 53), np.int32))
    bufs += (np.empty((8, 37, 53), np.bool_),)
    _s, r2, _c2, _ok2 = _track_window(fwd, bwd, depth, 2, 0, 5, **kw, out=bufs)
    assert r2.base is bufs[0]
    assert r2.shape == (5, 37, 53)
    _s, r3, c3, ok3 = _track_window(fwd, bwd, depth, 4, 0, 8, **kw, out=bufs)
    for a, b in ((rows, r3), (cols, c3), (ok, ok3)):
        np.testing.assert_array_equal(a, b)


def test_bilinear_stencil_clamps_and_both_samplers_agree(rng):
    """_bilinear2 (ring slot) and _bilinear2_plane share _bilinear_stencil: same bits, equal
    to the bilinear formula inside, clamped at the last row/column, exact on 1-px grids."""
    ring = rng.standard_normal((2, 5, 7, 2)).astype(np.float32)
    for x, y in ((0.0, 0.0), (2.25, 1.5), (6.0, 4.0), (5.999, 3.2)):
        x0, y0, x1, y1, w00, w01, w10, w11 = _bilinear_stencil(5, 7, x, y)
        assert 0 <= x0 <= 5
        assert 0 <= y0 <= 3
        assert (x1, y1) == (x0 + 1, y0 + 1)
        assert np.isclose(w00 + w01 + w10 + w11, 1.0)
        f = ring[1].astype(np.float64)
        fx, fy = x - x0, y - y0
        ref = (
            (1 - fx) * (1 - fy) * f[y0, x0] + fx * (1 - fy) * f[y0, x1]
            + (1 - fx) * fy * f[y1, x0] + fx * fy * f[y1, x1]
        )  # fmt: skip
        a = _bilinear2(ring, 1, x, y)
        assert a == _bilinear2_plane(ring[1], x, y)
        np.testing.assert_allclose(a, ref, rtol=1e-6, atol=1e-6)
    assert _bilinear_stencil(1, 1, 0.0, 0.0) == (0, 0, 0, 0, 1.0, 0.0, 0.0, 0.0)


# ----------------------------------------------------------------------------- composed tracks (A31)
def test_one_step_kernel_is_the_first_tracking_step(rng):
    """_one_step_kernel's landing pixel and validity equal the first step of _track_kernel,
    both directions, and its positions are the flow added to the pixel."""
    from fuse4d._kernels.tracks import _one_step_kernel

    fwd, bwd, depth = _window_case(rng)
    _s, h, w = depth.shape
    slots = np.arange(3, 6, dtype=np.int64)  # frames 3..5 in slots 3..5
    exp = [np.zeros((2, h, w), dt) for dt in (np.int32, np.int32, np.bool_)]
    _track_kernel(fwd, bwd, depth, slots, 4, 3, 5, 1.0, 5.0, 1e-5, False, *exp, *_NO_FILL)
    x, y = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    ok, r, c = np.empty((h, w), bool), np.empty((h, w), np.int32), np.empty((h, w), np.int32)
    # pair (4, 5) lives in slot 5: forward from frame 4, backward from frame 5 to 4
    for k, (step, check, frm, to) in enumerate(
        [(bwd[4], fwd[4], depth[4], depth[3]), (fwd[5], bwd[5], depth[4], depth[5])]
    ):
        _one_step_kernel(step, check, frm, to, 1.0, 5.0, 1e-5, x, y, ok, r, c)
        np.testing.assert_array_equal(ok, exp[2][k])
        np.testing.assert_array_equal(r[ok], exp[0][k][ok])
        np.testing.assert_array_equal(c[ok], exp[1][k][ok])
        vv, uu = np.mgrid[0:h, 0:w]
        np.testing.assert_allclose(x, uu + step[..., 0], atol=1e-4)
        np.testing.assert_allclose(y, vv + step[..., 1], atol=1e-4)
        assert 0.05 < ok.mean() < 0.95
