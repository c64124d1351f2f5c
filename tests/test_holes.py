"""Sensor-hole filling (issue 10, A26/A27): from time along tracks, then small holes in space."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fuse4d._kernels._common import _balanced_row_bounds
from fuse4d._kernels.holes import (
    _hole_runs_kernel,
    _spatial_fill_kernel,
    _temporal_fill_kernel,
    _temporal_fill_reference,
)
from fuse4d.holes import _hole_sides, _side_consistent, fill_small_holes, small_hole_mask


def _ring(depth, flow_u):
    """Ring buffers for T frames moving right by ``flow_u`` px/frame (exact, uniform flow)."""
    t, h, w = depth.shape
    fwd = np.zeros((t, h, w, 2), np.float32)
    bwd = np.zeros((t, h, w, 2), np.float32)
    fwd[1:, ..., 0] = flow_u  # slot T holds pair (T-1, T)
    bwd[1:, ..., 0] = -flow_u
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    ref = np.stack([u[None].repeat(t, 0), v[None].repeat(t, 0), depth], axis=-1)
    return fwd, bwd, ref.astype(np.float32)


def _fill(
    depth,
    ref,
    fwd,
    bwd,
    t,
    target,
    *,
    min_samples=1,
    max_step=10.0,
    quad=0.0,
    first=0,
    last=None,
    weight=None,
    kernel=_temporal_fill_kernel,
):
    n, h, w = depth.shape
    last = n - 1 if last is None else last
    out = np.full((h, w, 3), -1.0, np.float32)
    count = np.full((h, w), 99, np.uint8)
    kernel(
        fwd,
        bwd,
        depth,
        ref,
        np.arange(first, last + 1, dtype=np.int64) % n,
        t,
        first,
        last,
        2.0,
        max_step,
        quad,
        np.ones(n) if weight is None else weight,
        min_samples,
        target,
        out,
        count,
    )
    return out, count


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_step_major_kernel_equals_the_per_pixel_reference_bit_for_bit(seed):
    """Random flows (FB failures, border exits), holes at t and elsewhere, a ring whose slots
    wrap, depth steps that end tracks: same points and counts as chaining pixel by pixel."""
    rng = np.random.default_rng(seed)
    n, h, w = 9, 23, 37
    depth = rng.uniform(900.0, 1100.0, (n, h, w)).astype(np.float32)
    depth[rng.random((n, h, w)) < 0.3] = np.nan
    depth[:, :, 25:] += 400.0  # a depth edge: tracks crossing it stop
    fwd = rng.normal(0.0, 1.5, (n, h, w, 2)).astype(np.float32)
    bwd = (-fwd + rng.normal(0.0, 0.7, (n, h, w, 2))).astype(np.float32)
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    ref = np.stack(
        [u[None].repeat(n, 0), v[None].repeat(n, 0), depth + rng.normal(0, 1, depth.shape)],
        axis=-1,
    ).astype(np.float32)
    weight = rng.uniform(0.2, 1.0, n)
    for t, first, last in ((4, 0, 8), (11, 7, 15), (0, 0, 4), (8, 4, 8)):
        target = np.isnan(depth[t % n]) | (rng.random((h, w)) < 0.1)
        args = (depth, ref, fwd, bwd, t, target)
        opts = {"quad": 2e-6, "max_step": 30.0, "first": first, "last": last, "weight": weight}
        got = _fill(*args, **opts)
        want = _fill(*args, **opts, kernel=_temporal_fill_reference)
        assert (want[1] > 1).any()  # the case has multi-frame fills ...
        assert (want[1][target] == 0).any()  # ... and targets left unfilled
        np.testing.assert_array_equal(got[1], want[1])
        np.testing.assert_array_equal(got[0].view(np.uint32), want[0].view(np.uint32))


def test_static_hole_is_filled_from_the_frames_where_it_has_depth():
    depth = np.full((5, 8, 10), 1000.0, np.float32)
    depth[:, :, 5:] = 1500.0
    depth[2, 3, 2] = np.nan  # a dropout in frame 2 only
    fwd, bwd, ref = _ring(depth, 0.0)
    target = np.isnan(depth[2])
    out, count = _fill(depth, ref, fwd, bwd, 2, target)
    assert count[3, 2] == 4
    assert out[3, 2, 2] == pytest.approx(1000.0)
    assert np.all(count[~target] == 0)  # only the targets are touched


def test_moving_surface_is_interpolated_along_its_trajectory():
    """A surface receding 5 mm/frame while moving 1 px/frame: the line through the tracked
    samples gives the depth at t, not a blend of the other frames' values at the pixel."""
    n, h, w = 5, 6, 20
    depth = np.empty((n, h, w), np.float32)
    for k in range(n):
        depth[k] = 1000.0 + 5.0 * k
    fwd, bwd, ref = _ring(depth, 1.0)
    depth[2, 2, 8] = np.nan
    target = np.isnan(depth[2])
    out, count = _fill(depth, ref, fwd, bwd, 2, target)
    assert count[2, 8] == 4
    assert out[2, 8, 2] == pytest.approx(1010.0, abs=1e-3)
    assert out[2, 8, 0] == pytest.approx(8.0, abs=1e-3)  # the tracked column at t


def test_track_stops_at_a_depth_jump_and_needs_samples():
    depth = np.full((3, 4, 4), 1000.0, np.float32)
    depth[2] = 1500.0  # next frame jumps far away: not the same surface
    depth[0] = 1000.0
    depth[1, 1, 1] = np.nan
    fwd, bwd, ref = _ring(depth, 0.0)
    target = np.isnan(depth[1])
    out, count = _fill(depth, ref, fwd, bwd, 1, target, min_samples=2)
    # forward lands on 1500 (first sample of that direction), backward on 1000: both count,
    # the line through them is their mean at tau = 0 (the gate applies within one direction)
    assert count[1, 1] == 2
    depth[0, 1, 1] = np.nan
    out, count = _fill(depth, ref, fwd, bwd, 1, target, min_samples=2)
    assert count[1, 1] == 0
    assert np.isnan(out[1, 1]).all()


def test_small_hole_mask_keeps_small_inner_components_only():
    holes = np.zeros((10, 10), bool)
    holes[2:4, 2:4] = True  # 4 px, inside
    holes[5:9, 5:9] = True  # 16 px, inside
    holes[0, 0] = True  # touches the border
    assert small_hole_mask(holes, 4).sum() == 4
    assert small_hole_mask(holes, 16).sum() == 20
    assert small_hole_mask(holes, 0).sum() == 0


def test_small_hole_mask_matches_opencv_component_statistics(rng):
    """The one-pass area/border kernel against OpenCV's own component statistics."""
    for density in (0.2, 0.45, 0.6):
        holes = rng.random((40, 57)) < density
        _, labels, stats, _ = cv2.connectedComponentsWithStats(holes.astype(np.uint8), 8)
        x, y, w, h, area = stats.T
        keep = (x > 0) & (y > 0) & (x + w < 57) & (y + h < 40) & (area <= 6)
        keep[0] = False
        np.testing.assert_array_equal(small_hole_mask(holes, 6), keep[labels] & holes)


def test_spatial_fill_takes_one_side_and_never_blends_across_an_edge():
    """A shadow band on the wall (it looks like the wall in the intensity image) takes the
    wall's depth; a dropout on the foreground's rim (it looks like the foreground) takes the
    foreground's. Never a blend of the two."""
    d = np.full((12, 12), 3000.0, np.float32)
    d[:, 7:] = 1500.0  # foreground to the right
    inten = np.where(np.arange(12) < 7, 0.3, 0.8)[None, :].repeat(12, 0).astype(np.float32)
    d[4:8, 5:7] = np.nan  # shadow band left of the foreground edge, on the wall
    out, filled = fill_small_holes(d, inten, radius=3)
    assert filled.sum() == 8
    np.testing.assert_allclose(out[filled], 3000.0)
    d2 = np.full((12, 12), 3000.0, np.float32)
    d2[:, 7:] = 1500.0
    d2[4:8, 7:9] = np.nan  # a dropout on the foreground's rim
    out2, filled2 = fill_small_holes(d2, inten, radius=3)
    assert filled2.sum() == 8
    np.testing.assert_allclose(out2[filled2], 1500.0)


def test_hole_runs_are_oriented_by_the_nearer_end():
    d = np.array([[3000, np.nan, np.nan, 1500, 1500, np.nan, 3000, np.nan, 3004, np.nan]])
    row, start, length = (np.zeros(6, np.int32) for _ in range(3))
    orient = np.zeros(6, np.int8)
    z_near, z_far = np.zeros(6), np.zeros(6)
    n = _hole_runs_kernel(
        d.astype(np.float32), 10.0, 0.0, row, start, length, orient, z_near, z_far
    )
    # foreground right of the first run, left of the second; no edge at the third; the
    # fourth touches the border
    assert n == 2
    assert start[:2].tolist() == [1, 5]
    assert length[:2].tolist() == [2, 1]
    assert orient[:2].tolist() == [1, -1]
    assert z_near[:2].tolist() == [1500.0, 1500.0]
    assert z_far[:2].tolist() == [3000.0, 3000.0]


def _edge_scene(rim_cols):
    """A wall at 3 m with a foreground block at 1.5 m (cols 10-19) in a textureless scene (the
    intensity cannot tell a shadow from a rim); shadow bands of 3 px left of the block in
    rows 0-29; a 2-px rim dropout at ``rim_cols`` in rows 12-15."""
    d = np.full((30, 30), 3000.0, np.float32)
    d[:, 10:20] = 1500.0
    d[:, 7:10] = np.nan  # the projector's shadow: left of the foreground
    d[12:16, rim_cols] = np.nan
    return d, np.full(d.shape, 0.5, np.float32)


def test_rim_dropouts_away_from_the_shadow_side_never_take_the_background():
    """Every shadow lies left of the foreground, so a thin hole right of it is no shadow: a
    rim of the foreground, or background that block matching lost beside the edge. It never
    takes the wall's depth by the intensity rule's say-so (measured on the Kinect-model ball:
    the ball's far rim got the wall, 1 m off), nor is it forced onto the foreground (A41:
    on the Kinect-model body most such forced fills were > 100 mm off): it is filled where it
    looks like the foreground and left empty where it looks like the wall."""
    d, inten = _edge_scene(slice(18, 20))
    kind = _hole_sides(d, focal_px=None, max_step=10.0, quad=0.0).kind
    assert (kind[12:16, 18:20] == 1).all()
    assert np.count_nonzero(kind == 1) == 8  # the shadow bands are not rims
    like_rim = inten.copy()
    like_rim[:, 10:20] = 0.8  # the block and the hole bright, the wall 0.5
    out, filled = fill_small_holes(d, like_rim, max_area_px=64)
    assert filled[12:16, 18:20].all()
    np.testing.assert_allclose(out[12:16, 18:20], 1500.0)
    like_wall = inten.copy()
    like_wall[:, 10:18] = 0.8  # the hole looks like the wall: refused, not forced
    out, filled = fill_small_holes(d, like_wall, max_area_px=64)
    assert not filled[12:16, 18:20].any()
    # without a shadow side (the same hole, no shadow bands) the intensity rule decides alone
    d2, _ = _edge_scene(slice(18, 20))
    d2[:, 7:10] = 3000.0
    assert not _hole_sides(d2, focal_px=None, max_step=10.0, quad=0.0).kind.any()
    out, filled = fill_small_holes(d2, like_wall, max_area_px=64)
    assert filled[12:16, 18:20].all()
    np.testing.assert_allclose(out[12:16, 18:20], 3000.0)
    # a wide band on that side is no rim (a registration gap): the intensity rule decides
    d3, _ = _edge_scene(slice(18, 20))
    d3[12:16, 20:26] = np.nan
    assert not _hole_sides(d3, focal_px=None, max_step=10.0, quad=0.0).kind[12:16, 18:26].any()


def _shadow_scene():
    """A wall at 3 m, a foreground block at 1.5 m (cols 30-44) and, left of it in rows 2-37,
    the projector's shadow of a camera with f = 100 px, b = 90 mm: f b (1/1.5 m - 1/3 m) =
    3 px (cols 27-29). The shadow looks like the foreground in the intensity image (0.8; the
    wall is 0.2), so the intensity rule alone gives it the foreground's depth."""
    d = np.full((40, 60), 3000.0, np.float32)
    d[:, 30:45] = 1500.0
    d[2:38, 27:30] = np.nan
    inten = np.full(d.shape, 0.2, np.float32)
    inten[:, 27:45] = 0.8
    return d, inten


def test_projector_shadow_never_takes_the_foreground():
    """A39: within the shadow's width a fill on the foreground's surface is refused, whatever
    the intensity says; one on the wall is kept."""
    d, inten = _shadow_scene()
    sides = _hole_sides(d, focal_px=100.0, max_step=10.0, quad=0.0)
    np.testing.assert_array_equal(sides.kind == 2, np.isnan(d))
    np.testing.assert_allclose(sides.bound[np.isnan(d)], 2250.0)
    assert not sides.agrees(np.full(d.shape, 1510.0, np.float32))[2:38, 27:30].any()
    assert sides.agrees(np.full(d.shape, 2990.0, np.float32)).all()
    out, filled = fill_small_holes(d, inten, max_area_px=128, focal_px=100.0)
    band = np.s_[2:38, 27:30]
    assert not (filled & (out < 2250.0))[band].any()  # never the foreground
    assert not filled[10:30, 27:30].any()  # where the intensity chose it: refused, left empty
    wall_like = inten.copy()
    wall_like[2:38, 27:30] = 0.2  # the shadow looks like the wall: filled from it
    out, filled = fill_small_holes(d, wall_like, max_area_px=128, focal_px=100.0)
    assert filled[2:38, 27:30].all()
    np.testing.assert_allclose(out[2:38, 27:30], 3000.0)
    # without the focal length the intensity rule decides: the foreground, 1.5 m off
    out, filled = fill_small_holes(d, inten, max_area_px=128)
    np.testing.assert_allclose(out[10:30, 27:30], 1500.0)
    # a run wider than its shadow by more than a rim (a hole of another cause) is not split
    d2, _ = _shadow_scene()
    d2[2:38, 18:27] = np.nan
    kind = _hole_sides(d2, focal_px=100.0, max_step=10.0, quad=0.0).kind
    assert not kind[2:38, 18:30].any()


def test_time_fill_side_check_matches_its_definition(rng):
    """_side_consistent's one pass: at the hole pixels, the fill is within the step limit (A22)
    of the side's spatial value (or there is none), and not on a rim's or shadow's wrong side."""
    d, inten = _shadow_scene()
    d[20:23, 5:8] = np.nan  # a hole in the wall too
    sides = _hole_sides(d, focal_px=100.0, max_step=10.0, quad=2e-6)
    holes = np.isnan(d)
    filled = rng.choice([1500.0, 1508.0, 2990.0, 3000.0, 3030.0], d.shape).astype(np.float32)
    filled[0, 28] = np.nan
    got = _side_consistent(
        filled, d, inten, holes, sides, radius=4, sigma_intensity=0.1, max_step=10.0, quad=2e-6
    )
    side = np.empty_like(d)
    _spatial_fill_kernel(d, inten, holes, 4, 1.0 / (2 * 0.1**2), 1.0 / 8.0, 10.0, 2e-6, side)
    z = side.astype(np.float64)
    limit = np.maximum(10.0, 2.5 * 2e-6 * z * z)
    with np.errstate(invalid="ignore"):
        near = np.isnan(z) | (np.abs(filled - z) < limit)
    expected = holes & near & sides.agrees(filled)
    np.testing.assert_array_equal(got, expected)
    assert got.any()
    assert (holes & ~got).any()  # both outcomes occur


def test_balanced_row_bounds_give_each_chunk_an_equal_share(rng):
    """The hole kernels' row chunks: in order, covering every row, each within one row's
    work of its share (most of the work in a few rows, as a recording's holes are)."""
    work = np.full(480, 2.0)
    work[300:340] += rng.integers(100, 600, 40)
    work[100:110] += 900.0
    for n in (1, 2, 7, 64):
        b = _balanced_row_bounds(work, n)
        assert b[0] == 0
        assert b[-1] == work.size
        assert (np.diff(b) >= 0).all()
        share = work.sum() / n
        cum = np.concatenate([[0.0], np.cumsum(work)])
        for i in range(1, n):  # each boundary within one row of its share
            assert cum[b[i]] <= share * i + 1e-9 < cum[b[i]] + work[b[i]]
    # the two threads' halves of 64 chunks: equal rows would give them 10 % / 90 % here
    b = _balanced_row_bounds(work, 64)
    assert abs(work[: b[32]].sum() - work.sum() / 2) <= work.max()


def test_spatial_fill_of_a_pixel_does_not_depend_on_the_other_targets():
    """Row chunks follow the targets; a target's value and every other pixel's copy do not
    depend on where the chunks fall (holes in the bottom rows only, then also at the top)."""
    d, inten = _shadow_scene()
    d, inten = np.tile(d, (4, 1)), np.tile(inten, (4, 1))  # 160 rows: 64 chunks of 2-3
    holes = np.isnan(d)
    bottom = holes.copy()
    bottom[: d.shape[0] - 20] = False
    few = np.full_like(d, -1.0)
    _spatial_fill_kernel(d, inten, bottom, 4, 50.0, 1.0 / 8.0, 10.0, 2e-6, few)
    all_ = np.full_like(d, -1.0)
    _spatial_fill_kernel(d, inten, holes, 4, 50.0, 1.0 / 8.0, 10.0, 2e-6, all_)
    np.testing.assert_array_equal(few[bottom], all_[bottom])
    np.testing.assert_array_equal(few[~bottom], d[~bottom])  # every other row copied
    assert np.isfinite(few[bottom]).any()


def test_thin_hole_beside_a_receding_foreground_never_takes_the_background():
    """A40: no shadow side (a ToF camera). A 2 px hole between a foreground block and the
    wall; where the block's surface recedes toward the hole (a grazing rim) a fill with the
    wall's depth is refused, beside a face turned to the camera it is kept."""
    d = np.full((30, 40), 3000.0, np.float32)
    d[:, 10:20] = 1500.0
    d[:, 18:20] = [1530.0, 1560.0]  # rows 0-14: receding 30 mm/px = 2 mm per mm across at f 100
    d[15:, 18:20] = 1500.0  # rows 15-29: facing the camera
    d[5:25, 20:22] = np.nan
    inten = np.full(d.shape, 0.5, np.float32)  # the intensity cannot tell
    sides = _hole_sides(d, focal_px=100.0, max_step=10.0, quad=0.0)
    assert (sides.kind[5:15, 20:22] == 3).all()
    assert not sides.kind[15:25].any()
    assert not (sides.kind == 1).any()  # refused, not forced: the intensity rule chooses
    wall = np.full(d.shape, 3000.0, np.float32)
    assert not sides.agrees(wall)[5:15, 20:22].any()
    assert sides.agrees(wall)[15:25].all()
    assert not _hole_sides(d, focal_px=None, max_step=10.0, quad=0.0).kind.any()
    out, filled = fill_small_holes(d, inten, max_area_px=64, focal_px=100.0)
    assert not (filled & (out > 2250.0))[5:15, 20:22].any()


def test_spatial_fill_prefers_similar_intensity():
    d = np.full((9, 9), 2000.0, np.float32)
    d[:, 5:] = 2004.0  # same surface (2 levels apart), two materials
    inten = np.where(np.arange(9) < 5, 0.2, 0.8)[None, :].repeat(9, 0).astype(np.float32)
    d[4, 4] = np.nan
    out, _ = fill_small_holes(d, inten, radius=2, sigma_intensity=0.05)
    assert out[4, 4] == pytest.approx(2000.0, abs=0.1)


def test_large_or_border_holes_stay_holes():
    d = np.full((20, 20), 2000.0, np.float32)
    d[5:15, 5:15] = np.nan  # 100 px
    d[0:3, 0:3] = np.nan
    out, filled = fill_small_holes(d, np.full_like(d, 0.5), max_area_px=64)
    assert not filled.any()
    assert np.isnan(out[5:15, 5:15]).all()


def test_spatial_fill_follows_a_slanted_surface():
    """A37: a floor seen at an angle changes depth by 8 mm per row (within the 10 mm step
    limit between neighbours) and by 64 mm across the window, yet it is one surface: the fill
    lies on its plane (A27's "within one step of the farthest neighbour" kept only the hole's
    far edge: 20-30 mm off)."""
    rows = np.arange(20, dtype=np.float32)[:, None]
    d = np.repeat(3000.0 + 8.0 * rows, 20, axis=1).astype(np.float32)
    truth = d.copy()
    d[8:11, 6:9] = np.nan
    d[14, 15] = np.nan
    out, filled = fill_small_holes(d, np.full_like(d, 0.5), max_area_px=64, radius=4)
    assert filled.sum() == 10
    np.testing.assert_allclose(out[filled], truth[filled], atol=0.5)


def test_spatial_fill_on_a_slanted_surface_still_stops_at_an_edge():
    """The slanted wall left of a foreground block at 1.5 m: a hole on the wall beside the
    block takes the wall's plane, never the block's depth or a blend."""
    cols = np.arange(24, dtype=np.float32)[None, :]
    wall = np.repeat(3000.0 + 7.0 * cols, 16, axis=0).astype(np.float32)
    d = wall.copy()
    d[:, 14:] = 1500.0
    inten = np.where(np.arange(24) < 14, 0.3, 0.8)[None, :].repeat(16, 0).astype(np.float32)
    d[6:9, 12:14] = np.nan  # on the wall, touching the block
    out, filled = fill_small_holes(d, inten, max_area_px=64, radius=4)
    assert filled[6:9, 12:14].all()
    np.testing.assert_allclose(out[6:9, 12:14], wall[6:9, 12:14], atol=0.5)


# ------------------------------------------------------ flags and fills of the whole engine
@pytest.fixture(scope="module")
def kinect_body():
    """A small Kinect-model body: shadow holes, rim dropouts, a moving foreground."""
    from fuse4d.range_scenes import make_range_scene

    return make_range_scene("body", sensor="kinect", small=True, num_frames=6)


def _fused(seq, **params):
    from fuse4d import FusionParams, fuse_sequence

    return fuse_sequence(
        seq.depth, seq.intensity, seq.intrinsics, fusion=FusionParams(**params), flow="dis"
    )


def _assert_flags_describe_the_output(seq, res):
    """Codes 1 and 2 only where the sensor measured depth and the output has some; codes
    0, 5 and 6 only where the output has none; confidence 0 where there is no depth."""
    from fuse4d.holes import SOURCE_FUSED, SOURCE_MEASURED, SOURCE_SPACE, SOURCE_TIME

    raw = np.isfinite(seq.depth)
    out = np.isfinite(res.depth)
    raw_codes = np.isin(res.source, [SOURCE_MEASURED, SOURCE_FUSED])
    assert not (raw_codes & ~raw).any(), "a sensor hole flagged measured or fused"
    assert not (raw_codes & ~out).any(), "a pixel without output depth flagged measured/fused"
    fills = np.isin(res.source, [SOURCE_TIME, SOURCE_SPACE])
    assert not (fills & raw).any()
    assert out[fills].all()
    assert not out[~raw_codes & ~fills].any()
    assert (res.confidence[~out] == 0).all()
    assert ((res.source == SOURCE_FUSED) == (raw_codes & (res.support > 0))).all()


def test_a_second_iteration_flags_the_recordings_holes_as_the_first(kinect_body):
    """iterations=2 used to fuse the first pass's filled holes as measured depth: thousands of
    sensor holes flagged measured/fused, the field of view taken from filled depth."""
    from fuse4d.holes import SOURCE_OUTSIDE

    one = _fused(kinect_body)
    two = _fused(kinect_body, iterations=2)
    _assert_flags_describe_the_output(kinect_body, two)
    np.testing.assert_array_equal(two.source == SOURCE_OUTSIDE, one.source == SOURCE_OUTSIDE)
    raw_holes = ~np.isfinite(kinect_body.depth)
    filled_one = np.isfinite(one.depth) & raw_holes
    filled_two = np.isfinite(two.depth) & raw_holes
    assert abs(int(filled_two.sum()) - int(filled_one.sum())) < 0.1 * filled_one.sum()


@pytest.mark.parametrize(
    "params",
    [
        {"fill_fallback": "nan"},
        {"fill_fallback": "nan", "min_temporal_support": 3},
        {"fill_fallback": "nan", "fill_holes": True},
        {"min_temporal_support": 3},
        {"fill_fallback": "nan", "min_temporal_support": 3, "iterations": 2},
    ],
)
def test_flags_follow_the_output_under_fallback_and_minimum_support(kinect_body, params):
    """fill_fallback="nan" used to leave empty pixels flagged measured (confidence 1/n), and
    pixels below min_temporal_support (not fused: B^t) were flagged fused."""
    from fuse4d.holes import SOURCE_MEASURED, SOURCE_NONE

    res = _fused(kinect_body, **params)
    _assert_flags_describe_the_output(kinect_body, res)
    if params.get("min_temporal_support", 1) > 1 and params.get("iterations", 1) == 1:
        assert not ((res.support > 0) & (res.support < 3)).any()
        plain = _fused(kinect_body)
        below = (plain.support > 0) & (plain.support < 3) & np.isfinite(kinect_body.depth)
        assert below.any()
        if params.get("fill_fallback") == "nan":
            assert np.isnan(res.depth[below]).all()
            assert (res.source[below] == SOURCE_NONE).all()
        else:
            assert (res.source[below] == SOURCE_MEASURED).all()


def test_space_fill_size_limit_is_measured_on_the_sensor_holes(kinect_body):
    """The fill from time breaks a large hole into pieces; A27's size and border limits are
    the sensor hole's, so none of those pieces is filled in space."""
    from fuse4d.holes import SOURCE_SPACE

    res = _fused(kinect_body)
    limit = 64
    space = res.source == SOURCE_SPACE
    assert space.any()
    for t in range(kinect_body.num_frames):
        small = small_hole_mask(~np.isfinite(kinect_body.depth[t]), limit)
        assert not (space[t] & ~small).any(), f"frame {t}: space fill in a large sensor hole"
