"""Kernels that fill *sensor* holes (pixels without raw depth) — issue 10, our A26/A27.

Two stages, both private (arrays in, buffers filled; the wrappers in :mod:`fuse4d.holes`
validate):

* :func:`_temporal_fill_kernel` (A26): a pixel with no depth at t is still tracked through
  the intensity video (the flow is defined everywhere); where its track lands on valid depth
  in other frames of the window, those frames' motion-reference points are collected and the
  weighted least-squares line through them (the A21 trajectory) is evaluated at t.
* :func:`_spatial_fill_kernel` (A27, A37): small remaining holes get the intensity-weighted
  plane through the valid neighbours on one side of any depth discontinuity in the window
  (the side whose intensity resembles the hole's), so a fill never bridges a discontinuity.
"""

from __future__ import annotations

import math

import numpy as np

from ._common import ROW_CHUNKS, _balanced_row_bounds, _round_half_up, _step_limit
from ._numba import njit, njit_parallel, prange
from .fusion import _add_trajectory_sample, _fill_landing, _put_trajectory_value, _track_step

#: a row's own cost (scanning it for targets, copying its other pixels) in target pixels, for
#: the chunks of :func:`_balanced_row_bounds`
ROW_SCAN_WORK = 2.0


@njit_parallel
def _target_row_bounds(target, n_chunks):
    """Row chunks (:func:`._common._balanced_row_bounds`) of about equal work for a kernel
    over the ``target`` pixels of an (H, W) bool mask: a row's work is its targets plus
    :data:`ROW_SCAN_WORK`."""
    h, w = target.shape
    work = np.empty(h, np.float64)
    for v in prange(h):
        m = 0
        for u in range(w):
            if target[v, u]:
                m += 1
        work[v] = m + ROW_SCAN_WORK
    return _balanced_row_bounds(work, n_chunks)


@njit_parallel
def _temporal_fill_kernel(
    fwd_ring,
    bwd_ring,
    depth_ring,
    ref_ring,
    frame_slot,
    t,
    first,
    last,
    theta,
    max_step,
    quad,
    temporal_weight,
    min_samples,
    target,
    out_points,
    out_count,
    per_step=False,
):
    """Fill ``target`` pixels of frame t from the other frames along their tracks.

    For each target pixel (no raw depth at t) both directions are chained as in the tracking
    kernel (sub-pixel accumulation, forward-backward check Eq. 4 per step, stop at the image
    border); the depth checks start at the first landing with valid depth, after which each
    valid landing must stay within the depth-step limit of the previous one (A22) or the track
    ends. Each valid landing x^T contributes the reference point P~^T[x^T] with the temporal
    weight f(t, T). With at least ``min_samples`` samples the output point is the weighted
    least-squares line through them evaluated at t (their weighted mean when they do not
    determine a line); ``out_count`` gets the number of samples (0 = not filled, point NaN).
    ``frame_slot[T - first]`` is the ring slot of frame T (see :mod:`._kernels.fusion`).

    ``per_step``: the literal per-step rounding of the tracks (``quantize="per_step"``, A6).

    Step-major, like the tracking kernel: the target pixels of a row are gathered and advance
    one step at a time, so their independent chains overlap in the CPU (one chain is a series
    of dependent flow gathers, latency-bound). Each pixel sees the same arithmetic in the same
    order as :func:`_temporal_fill_reference` (the per-pixel loop), so the output is
    bit-identical to it (tested). The streaming engine has the tracking kernel
    (:func:`._kernels.fusion._track_kernel`) chain the holes in the same pass instead; this
    kernel serves the composed tracks (A31), which chain no pixel per output frame, and
    ``quantize="per_step"``, whose fill chains the engine runs here without the per-step
    rounding (as before stop 38; ``per_step`` True is the tracking kernel's oracle).
    """
    h = depth_ring.shape[1]
    w = depth_ring.shape[2]
    n_chunks = min(h, ROW_CHUNKS)
    bounds = _target_row_bounds(target, n_chunks)  # the holes cluster in a few rows
    for ci in prange(n_chunks):  # scratch allocated once per chunk, not per row
        cols = np.empty(w, np.int64)
        xs = np.empty(w, np.float64)
        ys = np.empty(w, np.float64)
        prev = np.empty(w, np.float64)  # float64 like the reference's scalar
        alive = np.empty(w, np.bool_)
        acc = np.empty((9, w), np.float64)  # s0, s1, s2, ax, ay, az, bx, by, bz
        count = np.empty(w, np.int64)
        for v in range(bounds[ci], bounds[ci + 1]):
            m = 0
            for u in range(w):
                out_count[v, u] = 0
                if target[v, u]:
                    cols[m] = u
                    m += 1
            if m == 0:
                continue
            for j in range(m):
                count[j] = 0
                for q in range(9):
                    acc[q, j] = 0.0
            for direction in (1, -1):
                for j in range(m):
                    xs[j] = float(cols[j])
                    ys[j] = float(v)
                    prev[j] = np.nan
                    alive[j] = True
                n_steps = last - t if direction == 1 else t - first
                for step in range(1, n_steps + 1):
                    T = t + direction * step
                    slot = frame_slot[T - first]
                    flow_slot = slot if direction == 1 else frame_slot[T + 1 - first]
                    step_ring = fwd_ring if direction == 1 else bwd_ring
                    check_ring = bwd_ring if direction == 1 else fwd_ring
                    wt = temporal_weight[abs(T - t)]
                    tau = float(T - t)
                    any_alive = False
                    for j in range(m):
                        if not alive[j]:
                            continue
                        ok, nx, ny = _track_step(
                            step_ring, check_ring, flow_slot, xs[j], ys[j], theta, per_step
                        )
                        if not ok:
                            alive[j] = False
                            continue
                        any_alive = True
                        xs[j] = nx
                        ys[j] = ny
                        r = _round_half_up(ny)
                        c = _round_half_up(nx)
                        state, d1 = _fill_landing(
                            depth_ring[slot], ref_ring[slot], r, c, prev[j], max_step, quad
                        )
                        if state <= 0:
                            alive[j] = state == 0  # (no depth here: follow the intensity on)
                            continue
                        prev[j] = d1
                        _add_trajectory_sample(
                            acc,
                            j,
                            wt,
                            tau,
                            ref_ring[slot, r, c, 0],
                            ref_ring[slot, r, c, 1],
                            ref_ring[slot, r, c, 2],
                        )
                        count[j] += 1
                    if not any_alive:
                        break
            for j in range(m):
                _put_trajectory_value(
                    acc, j, count[j], min_samples, out_points, out_count, v, cols[j]
                )


@njit
def _temporal_fill_reference(
    fwd_ring,
    bwd_ring,
    depth_ring,
    ref_ring,
    frame_slot,
    t,
    first,
    last,
    theta,
    max_step,
    quad,
    temporal_weight,
    min_samples,
    target,
    out_points,
    out_count,
    per_step=False,
):
    """:func:`_temporal_fill_kernel` pixel by pixel (each chain to its end before the next
    pixel's): the oracle of the step-major kernel, same arguments and outputs."""
    h = depth_ring.shape[1]
    w = depth_ring.shape[2]
    for v in range(h):
        for u in range(w):
            out_count[v, u] = 0
            if not target[v, u]:
                continue
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            # weighted sums of the samples' x, y, z and of tau times them
            ax = 0.0
            ay = 0.0
            az = 0.0
            bx = 0.0
            by = 0.0
            bz = 0.0
            count = 0
            for direction in (1, -1):
                x = float(u)
                y = float(v)
                prev = np.nan
                n_steps = last - t if direction == 1 else t - first
                for step in range(1, n_steps + 1):
                    T = t + direction * step
                    slot = frame_slot[T - first]
                    flow_slot = slot if direction == 1 else frame_slot[T + 1 - first]
                    step_ring = fwd_ring if direction == 1 else bwd_ring
                    check_ring = bwd_ring if direction == 1 else fwd_ring
                    ok, nx, ny = _track_step(
                        step_ring, check_ring, flow_slot, x, y, theta, per_step
                    )
                    if not ok:
                        break
                    x = nx
                    y = ny
                    r = _round_half_up(ny)
                    c = _round_half_up(nx)
                    d1 = depth_ring[slot, r, c]
                    if np.isnan(d1) or np.isnan(ref_ring[slot, r, c, 2]):
                        continue  # still no depth here: keep following the intensity
                    if not np.isnan(prev) and not (
                        abs(d1 - prev) < _step_limit(prev, max_step, quad)
                    ):
                        break
                    prev = d1
                    wt = temporal_weight[abs(T - t)]
                    tau = float(T - t)
                    s0 += wt
                    s1 += wt * tau
                    s2 += wt * tau * tau
                    px = ref_ring[slot, r, c, 0]
                    py = ref_ring[slot, r, c, 1]
                    pz = ref_ring[slot, r, c, 2]
                    ax += wt * px
                    ay += wt * py
                    az += wt * pz
                    bx += wt * tau * px
                    by += wt * tau * py
                    bz += wt * tau * pz
                    count += 1
            if count < min_samples or count == 0:
                for q in range(3):
                    out_points[v, u, q] = np.nan
                continue
            out_count[v, u] = min(count, 255)
            det = s0 * s2 - s1 * s1
            if det > 1e-9 * s0 * s0:  # line through the samples, evaluated at tau = 0
                out_points[v, u, 0] = (ax * s2 - bx * s1) / det
                out_points[v, u, 1] = (ay * s2 - by * s1) / det
                out_points[v, u, 2] = (az * s2 - bz * s1) / det
            else:  # one frame only (or all at one tau): their mean
                out_points[v, u, 0] = ax / s0
                out_points[v, u, 1] = ay / s0
                out_points[v, u, 2] = az / s0


@njit
def _side_plane_value(zs, ws, dus, dvs, n, z_min, z_max):  # pragma: no cover - compiled
    """Value at the hole (offset 0, 0) of the weighted least-squares plane z = a + b du + c dv
    through the neighbours ``i < n`` with ``z_min <= zs[i] <= z_max`` (depth ``zs``, weight
    ``ws``, offsets ``dus``, ``dvs`` px), clamped to their depth range (no extrapolation
    beyond what was measured); their weighted mean where the offsets are (nearly) collinear."""
    s = sx = sy = sxx = sxy = syy = sz = sxz = syz = 0.0
    lo = np.inf
    hi = -np.inf
    for i in range(n):
        z = zs[i]
        if z < z_min or z > z_max:
            continue
        wt = ws[i]
        x = dus[i]
        y = dvs[i]
        s += wt
        sx += wt * x
        sy += wt * y
        sxx += wt * x * x
        sxy += wt * x * y
        syy += wt * y * y
        sz += wt * z
        sxz += wt * x * z
        syz += wt * y * z
        lo = min(lo, z)
        hi = max(hi, z)
    mean = sz / s
    mx = sx / s
    my = sy / s
    cxx = sxx - s * mx * mx
    cxy = sxy - s * mx * my
    cyy = syy - s * my * my
    cxz = sxz - s * mx * mean
    cyz = syz - s * my * mean
    det = cxx * cyy - cxy * cxy
    if det <= 1e-6 * s * s:
        return mean
    b = (cxz * cyy - cyz * cxy) / det
    c = (cyz * cxx - cxz * cxy) / det
    return min(max(mean - b * mx - c * my, lo), hi)


@njit
def _side_weight(zs, ws, n, z_min, z_max):  # pragma: no cover - compiled
    """Total weight of the neighbours ``i < n`` with ``z_min <= zs[i] <= z_max``."""
    total = 0.0
    for i in range(n):
        if z_min <= zs[i] <= z_max:
            total += ws[i]
    return total


@njit
def _largest_gap(zs, n, z_min, z_max, max_step, quad, bucket_lo, bucket_hi, srt):
    """The largest gap between consecutive values of ``zs[i]`` (i < n) within ``[z_min,
    z_max]`` that exceeds the depth-step limit at its lower end: ``(below, above)``, the
    values either side of it, or ``(nan, nan)`` when no gap qualifies (A37).

    Bucketed in O(n): with buckets of the limit at ``z_min`` (the smallest limit in the
    range), two values in one bucket are closer than any qualifying gap, so the candidates
    are the gaps between consecutive non-empty buckets (from one's maximum to the next's
    minimum). Ranges needing more buckets than ``bucket_lo`` holds are sorted instead
    (``srt``). The same gap as sorting all values and scanning them.
    """
    width = _step_limit(z_min, max_step, quad)
    nb = int((z_max - z_min) / width) + 1
    best = 0.0
    below = np.nan
    above = np.nan
    if nb <= bucket_lo.size:
        for b in range(nb):
            bucket_lo[b] = np.inf
            bucket_hi[b] = -np.inf
        for i in range(n):
            z = zs[i]
            if z_min <= z <= z_max:
                b = min(int((z - z_min) / width), nb - 1)
                bucket_lo[b] = min(bucket_lo[b], z)
                bucket_hi[b] = max(bucket_hi[b], z)
        prev = -1.0
        for b in range(nb):
            if bucket_lo[b] == np.inf:
                continue
            if prev >= 0.0:
                gap = bucket_lo[b] - prev
                if gap > _step_limit(prev, max_step, quad) and gap > best:
                    best = gap
                    below = prev
                    above = bucket_lo[b]
            prev = bucket_hi[b]
        return below, above
    m = 0
    for i in range(n):
        if z_min <= zs[i] <= z_max:
            srt[m] = zs[i]
            m += 1
    srt[:m].sort()
    for j in range(m - 1):
        gap = srt[j + 1] - srt[j]
        if gap > _step_limit(srt[j], max_step, quad) and gap > best:
            best = gap
            below = srt[j]
            above = srt[j + 1]
    return below, above


@njit_parallel
def _spatial_fill_kernel(
    depth, intensity, target, radius, inv_2si2, inv_2ss2, max_step, quad, out_depth
):  # pragma: no cover - compiled
    """Fill ``target`` pixels from the valid neighbours of one side of the hole (A27, A37).

    For each target pixel, the valid pixels of ``depth`` within ``radius`` px are sorted by
    depth and split at the largest gap between consecutive depths that exceeds the
    depth-step limit (A22) at the nearer of the two: a depth discontinuity. Each neighbour
    weighs exp(-dI^2 / 2 sigma_I^2 - r^2 / 2 sigma_s^2); the side with the larger total weight
    — the one whose intensity resembles the hole's — is kept, and split again while it spans
    another discontinuity (no side is forced: where the hole's geometry rules one out, the
    caller refuses the fill, :class:`fuse4d.holes._HoleSides`). A slanted surface
    has no such gap however much its depth changes across the window, so it stays one side
    (our A37; A27 took the neighbours within one step limit of the farthest / nearest, which
    on a floor or a wall seen at an angle kept one edge of the hole's neighbourhood). The fill
    is the weighted least-squares plane through the kept side, evaluated at the hole and
    clamped to the side's depth range (:func:`_side_plane_value`). The gap is found without
    sorting (:func:`_largest_gap`), and not looked for where the window's depth range is within
    the step limit. ``out_depth`` gets the result,
    NaN where no neighbour is valid; non-target pixels are copied from ``depth``.
    """
    h, w = depth.shape
    n_max = (2 * radius + 1) ** 2
    n_chunks = min(h, ROW_CHUNKS)
    bounds = _target_row_bounds(target, n_chunks)  # the holes cluster in a few rows
    for ci in prange(n_chunks):  # scratch allocated once per chunk, not per pixel
        zs = np.empty(n_max, np.float64)
        ws = np.empty(n_max, np.float64)
        dus = np.empty(n_max, np.float64)
        dvs = np.empty(n_max, np.float64)
        srt = np.empty(n_max, np.float64)
        bucket_lo = np.empty(4 * n_max, np.float64)
        bucket_hi = np.empty(4 * n_max, np.float64)
        for v in range(bounds[ci], bounds[ci + 1]):
            for u in range(w):
                if not target[v, u]:
                    out_depth[v, u] = depth[v, u]
                    continue
                n = 0
                i0 = intensity[v, u]
                z_lo = np.inf
                z_hi = -np.inf
                for dv in range(-radius, radius + 1):
                    for du in range(-radius, radius + 1):
                        vv = v + dv
                        uu = u + du
                        if 0 <= vv < h and 0 <= uu < w:
                            d = depth[vv, uu]
                            if np.isnan(d):
                                continue
                            di = intensity[vv, uu] - i0
                            zs[n] = d
                            ws[n] = math.exp(-di * di * inv_2si2 - (dv * dv + du * du) * inv_2ss2)
                            dus[n] = du
                            dvs[n] = dv
                            z_lo = min(z_lo, zs[n])
                            z_hi = max(z_hi, zs[n])
                            n += 1
                if n == 0:
                    out_depth[v, u] = np.nan
                    continue
                while z_hi - z_lo > _step_limit(z_lo, max_step, quad):  # a gap is possible
                    below, above = _largest_gap(
                        zs, n, z_lo, z_hi, max_step, quad, bucket_lo, bucket_hi, srt
                    )
                    if np.isnan(below):
                        break
                    w_near = _side_weight(zs, ws, n, z_lo, below)
                    w_far = _side_weight(zs, ws, n, above, z_hi)
                    if w_near > w_far:
                        z_hi = below
                    else:
                        z_lo = above
                out_depth[v, u] = _side_plane_value(zs, ws, dus, dvs, n, z_lo, z_hi)


@njit_parallel(fastmath=False)
def _source_confidence_kernel(depth, points, support, n, source, confidence, holes):
    """Per-pixel source codes and confidence before the sensor-hole fills, in one pass.

    ``source`` (H, W) uint8: 2 (fused) where ``depth`` (the frame's input depth) is valid and
    ``support`` > 0, 1 (measured) where valid, 0 where NaN or where the z of ``points`` (H, W, 3,
    the fused points so far; a (0, 0, 3) array: not read, as where no output can be NaN) is NaN
    (``fill_fallback="nan"``: no depth is output there);
    ``confidence`` (H, W) float32: (1 + support) / n where source is 1 or 2 (computed in
    float64, then rounded), else 0; ``holes`` (H, W) bool: NaN input depth.
    Returns whether any hole exists. The same values as the numpy expressions it replaces in
    :meth:`fuse4d.FusionEngine._fill_sensor_holes` (issue 13: 6 ms per 640x480 frame there).
    """
    h, w = depth.shape
    check_output = points.shape[0] > 0
    row_hole = np.zeros(h, np.bool_)  # per row: no reduction across threads
    for v in prange(h):
        for u in range(w):
            if np.isnan(depth[v, u]):
                source[v, u] = 0
                confidence[v, u] = 0.0
                holes[v, u] = True
                row_hole[v] = True
            elif check_output and np.isnan(points[v, u, 2]):
                source[v, u] = 0
                confidence[v, u] = 0.0
                holes[v, u] = False
            else:
                s = support[v, u]
                source[v, u] = 2 if s > 0 else 1
                confidence[v, u] = np.float32((1.0 + np.float64(s)) / n)
                holes[v, u] = False
    return row_hole.any()


@njit
def _hole_runs_kernel(
    depth, max_step, quad, row, start, length, orient, z_near, z_far
):  # pragma: no cover - compiled
    """Every horizontal run of holes between two surfaces at a depth discontinuity (A27, A39).

    For each maximal run of NaN pixels in a row with valid depth at both ends whose depths
    differ by at least the depth-step limit (A22) of the nearer: its ``row``, first column
    ``start`` and ``length`` (px); ``orient`` (int8) +1 where the right end is the nearer
    (the foreground is to the run's right), -1 where the left end is; ``z_near`` / ``z_far``
    (mm) the two ends' depths. The buffers hold at least H * W // 2 + 1 runs; returns the
    number of runs.
    """
    h, w = depth.shape
    n = 0
    for v in range(h):
        u = 0
        while u < w:
            if not np.isnan(depth[v, u]):
                u += 1
                continue
            first = u
            while u < w and np.isnan(depth[v, u]):
                u += 1
            if first > 0 and u < w:
                left = depth[v, first - 1]
                right = depth[v, u]
                zn = min(left, right)
                zf = max(left, right)
                if zf - zn >= _step_limit(zn, max_step, quad):
                    row[n] = v
                    start[n] = first
                    length[n] = u - first
                    orient[n] = 1 if right < left else -1
                    z_near[n] = zn
                    z_far[n] = zf
                    n += 1
    return n


@njit
def _side_bounds_kernel(
    row, start, length, orient, z_near, z_far, n, shadow_orient, shadow_scale, rim_max, kind, bound
):  # pragma: no cover - compiled
    """Which surface the holes of the runs of :func:`_hole_runs_kernel` must take (A27, A39).

    ``shadow_orient`` (+1 / -1) is the orientation of the frame's shadow side. A run of the
    other orientation of at most ``rim_max`` px is a rim dropout of the foreground: ``kind``
    1. In a run of the shadow orientation, the projector's shadow covers
    ns = round(``shadow_scale`` (1/z_near - 1/z_far)) px next to the far end
    (``shadow_scale`` = f b, px mm; 0 = unknown): where the rest of the run (the rim next to
    the near end) is -1 to ``rim_max`` px, those ns pixels get ``kind`` 2. Both get
    ``bound`` = (z_near + z_far) / 2 mm, the depth that separates the two surfaces. ``kind``
    (H, W) int8 and ``bound`` (H, W) float32 are written at those pixels only.
    """
    for r in range(n):
        v, u0, run, o = row[r], start[r], length[r], orient[r]
        zn, zf = z_near[r], z_far[r]
        mid = np.float32(0.5 * (zn + zf))
        if o != shadow_orient:
            if run <= rim_max:
                for uu in range(u0, u0 + run):
                    kind[v, uu] = 1
                    bound[v, uu] = mid
        elif shadow_scale > 0.0:
            ns = int(shadow_scale * (1.0 / zn - 1.0 / zf) + 0.5)
            if -1 <= run - ns <= rim_max:
                for i in range(min(ns, run)):  # counted from the far end
                    uu = u0 + i if o == 1 else u0 + run - 1 - i
                    kind[v, uu] = 2
                    bound[v, uu] = mid


@njit
def _grazing_rims_kernel(
    depth, row, start, length, orient, z_near, z_far, n, focal_px, min_slope, rim_max, kind, bound
):  # pragma: no cover - compiled
    """Thin holes beside a foreground surface that turns away from the camera (A40).

    For each run of :func:`_hole_runs_kernel` of at most ``rim_max`` px whose near end's
    surface recedes toward the hole, seen along the row, by more than ``min_slope`` mm of
    depth per mm across (the last two valid pixels: (z_end - z_inner) / (z_end / f), f =
    ``focal_px``): ``kind`` 3 and ``bound`` = (z_near + z_far) / 2 mm where ``kind`` is still 0.
    """
    w = depth.shape[1]
    for r in range(n):
        run = length[r]
        if run > rim_max:
            continue
        v, u0 = row[r], start[r]
        end = u0 + run if orient[r] == 1 else u0 - 1  # the near end
        inner = end + 1 if orient[r] == 1 else end - 1
        if inner < 0 or inner >= w or np.isnan(depth[v, inner]):
            continue
        z0 = depth[v, end]
        if (z0 - depth[v, inner]) * focal_px / z0 <= min_slope:
            continue
        mid = np.float32(0.5 * (z_near[r] + z_far[r]))
        for uu in range(u0, u0 + run):
            if kind[v, uu] == 0:
                kind[v, uu] = 3
                bound[v, uu] = mid


# --------------------------------------------------------------------------- one-pass masks
# The fill stage's masks and scatters, each one pass over the image instead of a chain of
# numpy temporaries (issue 13: they took about 4 of the stage's 10 ms per 640x480 frame).
@njit(inline="always")
def _on_wrong_side(kind, bound, z):
    """A fill at depth ``z`` (mm) on the surface that the hole's ``kind`` rules out
    (:class:`fuse4d.holes._HoleSides`): a rim (1, 3) farther than ``bound``, a shadow (2)
    nearer; False where ``z`` or ``bound`` is NaN."""
    if kind == 1 or kind == 3:
        return z > bound
    if kind == 2:
        return z < bound
    return False


@njit_parallel
def _side_agrees_kernel(kind, bound, filled, out):  # pragma: no cover - compiled
    """``out`` (H, W) bool: not :func:`_on_wrong_side` at every pixel."""
    h, w = kind.shape
    for v in prange(h):
        for u in range(w):
            out[v, u] = not _on_wrong_side(kind[v, u], bound[v, u], filled[v, u])


@njit_parallel
def _time_fill_agrees_kernel(
    filled, side, holes, max_step, quad, kind, bound, out
):  # pragma: no cover - compiled
    """Which time fills keep their side (A26 against A27's side rule, then A39-A41).

    ``out`` (H, W) bool: at the ``holes`` pixels, True where ``side`` (the spatial-fill value
    of the side the intensity picks, mm) is NaN or within the depth-step limit (A22) of the
    fill ``filled`` (mm), and the fill is not on the wrong side of a rim or shadow; False
    elsewhere.
    """
    h, w = holes.shape
    for v in prange(h):
        for u in range(w):
            if not holes[v, u]:
                out[v, u] = False
                continue
            s = side[v, u]
            z = filled[v, u]
            near = np.isnan(s) or abs(z - s) < _step_limit(s, max_step, quad)
            out[v, u] = near and not _on_wrong_side(kind[v, u], bound[v, u], z)


@njit
def _small_components_kernel(labels, n_labels, max_area, out):  # pragma: no cover - compiled
    """``out`` (H, W) bool: pixels of the components of ``labels`` (int32, 0 = background,
    1 .. n_labels - 1 = components, e.g. ``cv2.connectedComponents``) with at most
    ``max_area`` pixels that do not touch the image border. Two passes (areas, then the
    mask); OpenCV's per-component statistics took 0.9 ms per 640x480 frame, this 0.1-0.2."""
    h, w = labels.shape
    area = np.zeros(n_labels, np.int64)
    border = np.zeros(n_labels, np.bool_)
    for v in range(h):
        edge_row = v == 0 or v == h - 1
        for u in range(w):
            lab = labels[v, u]
            if lab > 0:
                area[lab] += 1
                if edge_row or u == 0 or u == w - 1:
                    border[lab] = True
    for v in range(h):
        for u in range(w):
            lab = labels[v, u]
            out[v, u] = lab > 0 and area[lab] <= max_area and not border[lab]


@njit_parallel
def _put_on_rays_kernel(got, z, rays, points, source, code):  # pragma: no cover - compiled
    """Where ``got``: ``points`` (H, W, 3) = ``rays`` (H, W, 3) times the fill's depth ``z``
    (H, W) mm, and ``source`` = ``code``."""
    h, w = got.shape
    for v in prange(h):
        for u in range(w):
            if got[v, u]:
                zz = z[v, u]
                points[v, u, 0] = rays[v, u, 0] * zz
                points[v, u, 1] = rays[v, u, 1] * zz
                points[v, u, 2] = rays[v, u, 2] * zz
                source[v, u] = code
