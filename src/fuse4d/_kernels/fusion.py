"""Kernels of the 4D fusion (METHOD.md §3–§6). Private: arrays and scalars in, buffers filled.

Ring-buffer convention shared by the tracking and fusion kernels (owned by ``fuse4d.motion``,
whose ``_track_window`` / ``_pair_motion`` are the only Python callers of the tracking
kernels): frame T lives in slot ``T % S`` of the ``*_ring`` arrays (S = ring size), and the
flows of the pair (T-1, T) live in slot ``T % S`` of ``fwd_ring`` (s^{T-1,T}, on frame T-1's
grid) and ``bwd_ring`` (s^{T,T-1}, on frame T's grid). Shared primitives (the depth-step rule
``_step_limit``, bilinear sampling, rounding, the weight function, the derivative helper) are
in ``_common.py``; ``docs/equations.md`` maps each kernel to its equation and oracle test.
"""

from __future__ import annotations

import math

import numpy as np

from ._common import (
    ROW_CHUNKS,
    _bilinear2,
    _bilinear2_plane,
    _difference,
    _exp_neg_fast,
    _round_half_up,
    _step_limit,
)
from ._numba import literal_unroll, njit, njit_parallel, prange
from ._segments import SEGMENT_FASTMATH, _box_line, _line_segments


@njit(inline="always")
def _track_step(step_ring, check_ring, slot, x, y, theta, per_step):
    """One tracking step with the forward-backward check (Eq. 4, in px, A4).

    ``step_ring[slot]`` (the flow that moves the point) is sampled at (x, y); ``check_ring[slot]``
    (the reverse flow, on the landing frame's grid) at the landing point. Returns
    ``(ok, new_x, new_y)``; ok is False when the landing point leaves the image or the FB
    error is not < theta.
    """
    h = step_ring.shape[1]
    w = step_ring.shape[2]
    if per_step:
        iu = _round_half_up(x)
        iv = _round_half_up(y)
        su = float(step_ring[slot, iv, iu, 0])
        sv = float(step_ring[slot, iv, iu, 1])
    else:
        su, sv = _bilinear2(step_ring, slot, x, y)
    nx = x + su
    ny = y + sv
    if not (nx >= 0.0 and nx <= w - 1.0 and ny >= 0.0 and ny <= h - 1.0):
        return False, nx, ny
    if per_step:
        ix = _round_half_up(nx)
        iy = _round_half_up(ny)
        cu = float(check_ring[slot, iy, ix, 0])
        cv = float(check_ring[slot, iy, ix, 1])
    else:
        cu, cv = _bilinear2(check_ring, slot, nx, ny)
    e2 = (su + cu) * (su + cu) + (sv + cv) * (sv + cv)
    if not (e2 < theta * theta):
        return False, nx, ny
    if per_step:
        nx = float(_round_half_up(nx))
        ny = float(_round_half_up(ny))
    return True, nx, ny


@njit(inline="always")
def _checked_landing(x, y, su, sv, cu, cv, w, h, theta2, per_step):
    """One tracking step from (x, y) by the flow sample (su, sv): ``(ok, nx, ny)``, ok when
    the landing lies in the W x H image and the forward-backward error with the reverse
    flow (cu, cv) sampled there is below theta (``theta2`` = theta^2; Eq. 4); with
    ``per_step`` the landing of an ok step is rounded to its pixel (``quantize="per_step"``).
    The arithmetic of :func:`_track_step`."""
    nx = x + su
    ny = y + sv
    ok = nx >= 0.0 and nx <= w - 1.0 and ny >= 0.0 and ny <= h - 1.0
    if ok:
        e2 = (su + cu) * (su + cu) + (sv + cv) * (sv + cv)
        ok = e2 < theta2
    if ok and per_step:
        nx = float(_round_half_up(nx))
        ny = float(_round_half_up(ny))
    return ok, nx, ny


@njit(inline="always")
def _fill_landing(depth_T, ref_T, r, c, prev, max_step, quad):
    """A26 at a fill chain's landing pixel (r, c) of frame T: ``(state, d)`` with d the depth
    there and state 0 (no depth or no reference point: the chain follows the intensity on),
    1 (a sample: within the depth-step limit of the previous sample ``prev``, NaN: none yet)
    or -1 (a depth step: the chain ends)."""
    d1 = depth_T[r, c]
    if np.isnan(d1) or np.isnan(ref_T[r, c, 2]):
        return 0, d1
    if not np.isnan(prev) and not (abs(d1 - prev) < _step_limit(prev, max_step, quad)):
        return -1, d1
    return 1, d1


@njit(inline="always")
def _add_trajectory_sample(acc, j, wt, tau, px, py, pz):
    """Add a tracked sample P~^T (mm) at tau = T - t with weight ``wt`` to column ``j`` of the
    weighted least-squares sums ``acc`` (9, n): s0, s1, s2, then x, y, z and tau times them."""
    acc[0, j] += wt
    acc[1, j] += wt * tau
    acc[2, j] += wt * tau * tau
    acc[3, j] += wt * px
    acc[4, j] += wt * py
    acc[5, j] += wt * pz
    acc[6, j] += wt * tau * px
    acc[7, j] += wt * tau * py
    acc[8, j] += wt * tau * pz


@njit(inline="always")
def _put_trajectory_value(acc, j, n, min_samples, out_points, out_count, v, u):
    """A26's output at pixel (v, u) from the sums of column ``j`` and its ``n`` samples: the
    weighted least-squares line through them at tau = 0 (their weighted mean when they do not
    determine a line), ``out_count`` = n (0 and NaN below ``min_samples``)."""
    if n < min_samples or n == 0:
        for q in range(3):
            out_points[v, u, q] = np.nan
        return
    out_count[v, u] = min(n, 255)
    s0 = acc[0, j]
    s1 = acc[1, j]
    s2 = acc[2, j]
    det = s0 * s2 - s1 * s1
    if det > 1e-9 * s0 * s0:  # line through the samples, evaluated at tau = 0
        out_points[v, u, 0] = (acc[3, j] * s2 - acc[6, j] * s1) / det
        out_points[v, u, 1] = (acc[4, j] * s2 - acc[7, j] * s1) / det
        out_points[v, u, 2] = (acc[5, j] * s2 - acc[8, j] * s1) / det
    else:  # one frame only (or all at one tau): their mean
        out_points[v, u, 0] = acc[3, j] / s0
        out_points[v, u, 1] = acc[4, j] / s0
        out_points[v, u, 2] = acc[5, j] / s0


# --------------------------------------------------------------------------- per-frame stages
#: column offsets (0..6, i.e. -3..3 about the centre) of a radius-3 bilateral window: a tuple so
#: that ``literal_unroll`` spells the seven terms out at compile time (see
#: :func:`_bilateral_row_r3_kernel`)
_R3_COLUMNS = (0, 1, 2, 3, 4, 5, 6)


@njit(inline="always")
def _bilateral_term(nx, ny, nz, ni, qx, qy, qz, cx, cy, cz, ci, a, b):
    """One neighbour's weighted values (w qx, w qy, w qz, w) in the 3D bilateral (Eq. 5 inner
    sum); a NaN neighbour (``nz``) weighs 0."""
    zero = np.float32(0.0)
    dx = nx - cx
    dy = ny - cy
    dz = nz - cz
    di = ni - ci
    arg = (dx * dx + dy * dy + dz * dz) * a + di * di * b
    valid = not math.isnan(nz)
    wgt = _exp_neg_fast(arg)
    wgt = wgt if valid else zero
    return (
        wgt * (qx if valid else zero),
        wgt * (qy if valid else zero),
        wgt * (qz if valid else zero),
        wgt,
    )


@njit
def _bilateral_row_kernel(cx, cy, cz, ci, nx, ny, nz, ni, qx, qy, qz, a, b, ax, ay, az, ws):
    """Accumulate one neighbour offset for one row (1D slices; this loop vectorises)."""
    for u in range(cx.shape[0]):
        tx, ty, tz, tw = _bilateral_term(
            nx[u], ny[u], nz[u], ni[u], qx[u], qy[u], qz[u], cx[u], cy[u], cz[u], ci[u], a, b
        )
        ax[u] += tx
        ay[u] += ty
        az[u] += tz
        ws[u] += tw


@njit
def _bilateral_row_r3_kernel(cx, cy, cz, ci, nx, ny, nz, ni, qx, qy, qz, a, b, ax, ay, az, ws):
    """Accumulate all seven column offsets of a radius-3 window from one neighbour row.

    ``c*`` and the accumulators are the row's columns 3 .. W-4 (centre column u at index
    u - 3), ``n*`` / ``q*`` the neighbour row's W columns, so column u's neighbours are at
    indices u - 3 .. u + 3 of those: never negative. Per pixel the same sums in the same
    order (offset -3 to 3) as seven :func:`_bilateral_row_kernel` calls, but the centre and the
    sums stay in registers across the seven terms: loads and stores were what bounded the
    per-offset loop (8.1 -> 4.4-5.3 ms per 640x480 frame, stop 35).
    """
    for u in range(cx.shape[0]):
        x = cx[u]
        y = cy[u]
        z = cz[u]
        c = ci[u]
        sx = ax[u]
        sy = ay[u]
        sz = az[u]
        sw = ws[u]
        for k in literal_unroll(_R3_COLUMNS):
            j = u + k
            tx, ty, tz, tw = _bilateral_term(
                nx[j], ny[j], nz[j], ni[j], qx[j], qy[j], qz[j], x, y, z, c, a, b
            )
            sx += tx
            sy += ty
            sz += tz
            sw += tw
        ax[u] = sx
        ay[u] = sy
        az[u] = sz
        ws[u] = sw


@njit
def _bilateral_row_offsets(px, py, pz, pi, qx, qy, qz, v, nv, radius, lo, hi, a, b, acc):
    """Accumulate neighbour row ``nv``'s offsets -radius..radius for row ``v``'s columns
    ``lo`` .. ``hi - 1`` (one :func:`_bilateral_row_kernel` call per offset)."""
    w = px.shape[1]
    # only the offsets that reach a column of the image (a radius past the image's width
    # would otherwise loop over millions of empty offsets: `--set spatial_radius=1000000`)
    for du in range(max(-radius, 1 - hi), min(radius, w - 1 - lo) + 1):
        u0 = max(lo, -du)
        u1 = min(hi, w - du)
        if u1 <= u0:
            continue
        _bilateral_row_kernel(
            px[v, u0:u1],
            py[v, u0:u1],
            pz[v, u0:u1],
            pi[v, u0:u1],
            px[nv, u0 + du : u1 + du],
            py[nv, u0 + du : u1 + du],
            pz[nv, u0 + du : u1 + du],
            pi[nv, u0 + du : u1 + du],
            qx[nv, u0 + du : u1 + du],
            qy[nv, u0 + du : u1 + du],
            qz[nv, u0 + du : u1 + du],
            a,
            b,
            acc[0, u0:u1],
            acc[1, u0:u1],
            acc[2, u0:u1],
            acc[3, u0:u1],
        )


@njit_parallel
def _bilateral_planes_kernel(points, reference, planes, values):
    """The planar inputs of :func:`_bilateral3d_kernel` in one pass: ``planes`` (3, H, W) the
    coordinates of ``points`` (H, W, 3) mm, ``values`` (3, H, W) ``points - reference``
    (float32, as numpy subtracts). Six strided numpy copies took 1 ms at 640x480."""
    h, w = points.shape[0], points.shape[1]
    for v in prange(h):
        for u in range(w):
            for c in range(3):
                p = points[v, u, c]
                planes[c, v, u] = p
                values[c, v, u] = p - reference[v, u, c]


@njit_parallel
def _bilateral3d_kernel(px, py, pz, intensity, qx, qy, qz, radius, inv_2sd2, inv_2sg2, out):
    """Intensity-guided 3D bilateral of one frame (inner sum of Eq. 5, METHOD §5.1).

    Planar (SoA) inputs so that the innermost loop over columns vectorises: px, py, pz (H,W)
    point coordinates (mm, NaN = invalid), intensity (H,W), and qx, qy, qz (H,W) the values
    averaged. Output ``out = (P_c - q_c) + sum_n w q_n / sum_n w`` with weights
    d(P_c, P_n) g(I_c, I_n), exp(-x) ~ (1 - x/1024)^1024, NaN neighbours unweighted.
    With q = P - P~ this is the residual bilateral (A18); with q = P - const it is the literal
    weighted mean of the points. out (H,W,3), NaN where pz is NaN. Radius 3 (every preset's)
    takes the columns away from the border seven offsets at a time
    (:func:`_bilateral_row_r3_kernel`); the sums are the same, term for term. Each row sums
    only over its span of valid centres (first to last non-NaN ``pz``).
    """
    h, w = intensity.shape
    a = np.float32(inv_2sd2)
    b = np.float32(inv_2sg2)
    r3 = radius == 3 and w > 6
    n_chunks = min(h, ROW_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk, not per row
        acc = np.empty((4, w), dtype=np.float32)
        for v in range(ci * h // n_chunks, (ci + 1) * h // n_chunks):
            acc[:] = 0.0
            # the row's span of valid centres: outside it every output is NaN (the band of
            # rows and columns a registered depth image leaves empty: 20 % of uva's pixels)
            lo = 0
            while lo < w and np.isnan(pz[v, lo]):
                lo += 1
            hi = w
            while hi > lo and np.isnan(pz[v, hi - 1]):
                hi -= 1
            nv_end = 0 if lo == hi else min(v + radius + 1, h)  # (no valid centre: no sum)
            # radius 3: columns 3 .. W-4 seven offsets at a time, the border columns one
            # offset at a time (each column takes the same path as without the span)
            mid_lo = max(lo, 3)
            mid_hi = min(hi, w - 3)
            for nv in range(max(v - radius, 0), nv_end):
                if not r3:
                    _bilateral_row_offsets(
                        px, py, pz, intensity, qx, qy, qz, v, nv, radius, lo, hi, a, b, acc
                    )
                    continue
                if lo < 3:
                    _bilateral_row_offsets(
                        px, py, pz, intensity, qx, qy, qz, v, nv, radius, lo, min(hi, 3), a, b, acc
                    )
                if hi > w - 3:
                    right = max(lo, w - 3)
                    _bilateral_row_offsets(
                        px, py, pz, intensity, qx, qy, qz, v, nv, radius, right, hi, a, b, acc
                    )
                if mid_lo >= mid_hi:
                    continue
                _bilateral_row_r3_kernel(
                    px[v, mid_lo:mid_hi],
                    py[v, mid_lo:mid_hi],
                    pz[v, mid_lo:mid_hi],
                    intensity[v, mid_lo:mid_hi],
                    px[nv, mid_lo - 3 : mid_hi + 3],
                    py[nv, mid_lo - 3 : mid_hi + 3],
                    pz[nv, mid_lo - 3 : mid_hi + 3],
                    intensity[nv, mid_lo - 3 : mid_hi + 3],
                    qx[nv, mid_lo - 3 : mid_hi + 3],
                    qy[nv, mid_lo - 3 : mid_hi + 3],
                    qz[nv, mid_lo - 3 : mid_hi + 3],
                    a,
                    b,
                    acc[0, mid_lo:mid_hi],
                    acc[1, mid_lo:mid_hi],
                    acc[2, mid_lo:mid_hi],
                    acc[3, mid_lo:mid_hi],
                )
            for u in range(w):
                if np.isnan(pz[v, u]):
                    out[v, u, 0] = np.nan
                    out[v, u, 1] = np.nan
                    out[v, u, 2] = np.nan
                else:
                    out[v, u, 0] = px[v, u] - qx[v, u] + acc[0, u] / acc[3, u]
                    out[v, u, 1] = py[v, u] - qy[v, u] + acc[1, u] / acc[3, u]
                    out[v, u, 2] = pz[v, u] - qz[v, u] + acc[2, u] / acc[3, u]


@njit_parallel
def _pair_diagnostics_kernel(
    fwd_ring,
    bwd_ring,
    slot,
    ref_t,
    ref_t1,
    depth_t,
    depth_t1,
    theta,
    max_step,
    quad,
    per_step,
    fb_error,
    motion,
):
    """Per pair (t, t+1) with flows in ``*_ring[slot]``: FB error map and one-step 3D motion.

    fb_error (H,W): |s_fwd(x) + s_bwd(x + s_fwd(x))| px, NaN if the landing leaves the image.
    motion (H,W,3): P~^{t+1}[round(x')] - P~^t[x] in mm where the step is valid (Eq. 3, 4), NaN
    elsewhere. Validity is exactly the first step of :func:`_track_kernel`: in image, FB error
    < theta, valid depth at both ends, depth step < ``_step_limit(depth_t, max_step, quad)``.
    """
    h, w = depth_t.shape
    for v in prange(h):
        for u in range(w):
            su = fwd_ring[slot, v, u, 0]
            sv = fwd_ring[slot, v, u, 1]
            nx = u + su
            ny = v + sv
            motion[v, u, 0] = np.nan
            motion[v, u, 1] = np.nan
            motion[v, u, 2] = np.nan
            if not (nx >= 0.0 and nx <= w - 1.0 and ny >= 0.0 and ny <= h - 1.0):
                fb_error[v, u] = np.nan
                continue
            cu, cv = _bilinear2(bwd_ring, slot, nx, ny)
            fb_error[v, u] = math.sqrt((su + cu) ** 2 + (sv + cv) ** 2)
            if np.isnan(depth_t[v, u]):
                continue
            ok, lx, ly = _track_step(fwd_ring, bwd_ring, slot, float(u), float(v), theta, per_step)
            if not ok:
                continue
            iu = _round_half_up(lx)
            iv = _round_half_up(ly)
            d1 = depth_t1[iv, iu]
            limit = _step_limit(depth_t[v, u], max_step, quad)
            if np.isnan(d1) or not (abs(d1 - depth_t[v, u]) < limit):
                continue
            for c in range(3):
                motion[v, u, c] = ref_t1[iv, iu, c] - ref_t[v, u, c]


# --------------------------------------------------------------------------- tracking
@njit_parallel
def _track_kernel(
    fwd_ring,
    bwd_ring,
    depth_ring,
    frame_slot,
    t,
    first,
    last,
    theta,
    max_step,
    quad,
    per_step,
    land_row,
    land_col,
    land_ok,
    fill_target,
    ref_ring,
    temporal_weight,
    min_samples,
    fill_points,
    fill_count,
):
    """Chain tracks from every valid pixel of frame t through the window [first, last].

    ``frame_slot[T - first]`` is the ring slot of frame T, which also holds the flows of the
    pair (T-1, T). Output index k runs over the frames first..last without t, increasing
    (k = T - first for T < t, T - first - 1 for T > t). ``land_row/col`` (K,H,W) int32 hold
    the rounded landing pixel x^_i^T; ``land_ok`` (K,H,W) bool the validity nu^{t,T} (AND of
    per-step checks: in image, FB < theta, valid depth, depth step < max_step).

    With a (H, W) ``fill_target`` (a (0, 0) array: none) the same pass also fills those
    pixels, holes of frame t, from the other frames along their tracks (A26; a target with
    depth at t is tracked, not filled: count 0, NaN); the
    chains of :func:`._kernels.holes._temporal_fill_kernel` (the same arithmetic, so the same
    ``fill_points`` (H, W, 3) and ``fill_count`` (H, W) uint8, written at the targets only;
    tested). The hole chains share the tracks' flow rows, which the step's passes have in
    cache: they cost 1-3 ms here, where the separate kernel paid 4.6 of 12 ms of the fill
    stage on ``uva_cv2_person_turning`` (issue 13).

    Each step's passes visit only the row's chains still going (alive, or a hole being
    followed; ``act``), in increasing column order: on ``uva_cv2_person_turning`` only
    54-68 % of a frame's pixels still have a track at each other frame of a 9-frame window
    (27 % have no depth; FB failures and depth steps end others), and the samples of the
    rest were never used (this kernel alone 18.9 -> 17.3 ms per frame, stop 39).
    """
    h = depth_ring.shape[1]
    w = depth_ring.shape[2]
    st = frame_slot[t - first]
    theta2 = theta * theta
    has_fill = fill_target.shape[0] > 0
    n_chunks = min(h, ROW_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk, not per row
        xs = np.empty(w, dtype=np.float64)
        ys = np.empty(w, dtype=np.float64)
        su = np.empty(w, dtype=np.float64)
        sv = np.empty(w, dtype=np.float64)
        cu_row = np.empty(w, dtype=np.float64)
        cv_row = np.empty(w, dtype=np.float64)
        pr = np.empty(w, dtype=np.int32)
        pc = np.empty(w, dtype=np.int32)
        prev_depth = np.empty(w, dtype=np.float32)
        alive = np.empty(w, dtype=np.bool_)
        # A26 fill chains: following the intensity, the last depth landed on, the sums
        follow = np.zeros(w, dtype=np.bool_)
        fill_prev = np.empty(w, dtype=np.float64)
        acc = np.empty((9, w), dtype=np.float64)
        count = np.empty(w, dtype=np.int64)
        # the row's chains still going (alive, or an A26 hole being followed): the passes
        # of a step visit only these (a dead chain's samples were never used)
        act = np.empty(w, dtype=np.int64)
        for v in range(ci * h // n_chunks, (ci + 1) * h // n_chunks):
            fill_row = False
            if has_fill:
                for u in range(w):
                    fill_count[v, u] = 0
                    if fill_target[v, u]:
                        fill_row = True
                        count[u] = 0
                        for q in range(9):
                            acc[q, u] = 0.0
            # step-major order: all pixels of the row advance one step at a time, so the
            # independent per-pixel chains overlap in the CPU (a per-pixel chain is latency-bound)
            for direction in (1, -1):
                n_steps = last - t if direction == 1 else t - first
                if n_steps == 0:  # (a causal window has no frame after t)
                    continue
                d0 = depth_ring[st, v]
                n_act = 0
                for u in range(w):
                    xs[u] = u
                    ys[u] = v
                    pr[u] = v
                    pc[u] = u
                    prev_depth[u] = d0[u]
                    alive[u] = not np.isnan(d0[u])
                    follow[u] = fill_row and fill_target[v, u]
                    fill_prev[u] = np.nan
                    act[n_act] = u
                    n_act += 1 if (alive[u] or follow[u]) else 0
                for step in range(1, n_steps + 1):
                    T = t + direction * step
                    k = T - first - 1 if direction == 1 else T - first
                    slot = frame_slot[T - first]
                    # pair (T-1, T) lives in the slot of T, pair (T, T+1) in the slot of T+1
                    flow_slot = slot if direction == 1 else frame_slot[T + 1 - first]
                    step_flow = fwd_ring[flow_slot] if direction == 1 else bwd_ring[flow_slot]
                    check_flow = bwd_ring[flow_slot] if direction == 1 else fwd_ring[flow_slot]
                    depth_T = depth_ring[slot]
                    ref_T = ref_ring[slot]
                    wt = temporal_weight[abs(T - t)]
                    tau = float(T - t)
                    # one step of _track_step in two passes over the row: first every flow
                    # sample (branch-free, short independent iterations), then the checks;
                    # the same arithmetic, so the same bits as chaining pixel by pixel.
                    if step == 1:
                        # every track starts on its pixel centre, where the bilinear stencil's
                        # weights are 1 and 0: the sample is the pixel's flow (the same value,
                        # up to the sign of a zero, which no later step can see)
                        flow_row = step_flow[v]
                        for u in range(w):
                            su[u] = float(flow_row[u, 0])
                            sv[u] = float(flow_row[u, 1])
                    for j in range(n_act if step > 1 else 0):
                        u = act[j]
                        if per_step:
                            iu = _round_half_up(xs[u])
                            iv = _round_half_up(ys[u])
                            su[u] = float(step_flow[iv, iu, 0])
                            sv[u] = float(step_flow[iv, iu, 1])
                        else:
                            su[u], sv[u] = _bilinear2_plane(step_flow, xs[u], ys[u])
                    # the reverse flow at the landing point, clamped into the image (a landing
                    # outside fails below, whatever the sample)
                    for j in range(n_act):
                        u = act[j]
                        nx = min(max(xs[u] + su[u], 0.0), w - 1.0)
                        ny = min(max(ys[u] + sv[u], 0.0), h - 1.0)
                        if per_step:
                            ix = _round_half_up(nx)
                            iy = _round_half_up(ny)
                            cu_row[u] = float(check_flow[iy, ix, 0])
                            cv_row[u] = float(check_flow[iy, ix, 1])
                        else:
                            cu_row[u], cv_row[u] = _bilinear2_plane(check_flow, nx, ny)
                    n_keep = 0
                    for j in range(n_act):
                        u = act[j]
                        if alive[u]:
                            ok, nx, ny = _checked_landing(
                                xs[u], ys[u], su[u], sv[u], cu_row[u], cv_row[u], w, h, theta2,
                                per_step,
                            )  # fmt: skip
                            if ok:
                                r = _round_half_up(ny)
                                c = _round_half_up(nx)
                                d1 = depth_T[r, c]
                                limit = _step_limit(prev_depth[u], max_step, quad)
                                if np.isnan(d1) or not (abs(d1 - prev_depth[u]) < limit):
                                    ok = False
                                else:
                                    xs[u] = nx
                                    ys[u] = ny
                                    pr[u] = r
                                    pc[u] = c
                                    prev_depth[u] = d1
                            if not ok:
                                alive[u] = False
                        else:  # A26: a hole's chain (follow[u]), through holes until depth
                            ok, nx, ny = _checked_landing(
                                xs[u], ys[u], su[u], sv[u], cu_row[u], cv_row[u], w, h, theta2,
                                per_step,
                            )  # fmt: skip
                            if ok:
                                xs[u] = nx
                                ys[u] = ny
                                r = _round_half_up(ny)
                                c = _round_half_up(nx)
                                state, d1 = _fill_landing(
                                    depth_T, ref_T, r, c, fill_prev[u], max_step, quad
                                )
                                ok = state >= 0  # (0: no depth here, follow on)
                                if state > 0:
                                    fill_prev[u] = d1
                                    _add_trajectory_sample(
                                        acc, u, wt, tau, ref_T[r, c, 0], ref_T[r, c, 1],
                                        ref_T[r, c, 2],
                                    )  # fmt: skip
                                    count[u] += 1
                            follow[u] = ok
                        act[n_keep] = u
                        n_keep += 1 if (alive[u] or follow[u]) else 0
                    n_act = n_keep
                    ok_row = land_ok[k, v]
                    row_row = land_row[k, v]
                    col_row = land_col[k, v]
                    for u in range(w):
                        ok_row[u] = alive[u]
                        row_row[u] = pr[u]
                        col_row[u] = pc[u]
            if fill_row:
                for u in range(w):
                    if fill_target[v, u]:
                        _put_trajectory_value(
                            acc, u, count[u], min_samples, fill_points, fill_count, v, u
                        )


# --------------------------------------------------------------------------- fusion (Eq. 5)
@njit(inline="always")
def _parabola_basis(wsum, s1, s2, s3, s4, det):
    """The part of the weighted least-squares parabola that all coordinates share (A28, A32).

    Sums over the samples (tau = T - t, weight w, frame t itself included): wsum = sum w,
    s_k = sum w tau^k. By Frisch-Waugh, with (g, h) the weighted line through (tau, tau^2)
    and d = s4 - g s2 - h s3 the weighted residual sum of squares of tau^2, a coordinate with
    motion sums y_k = sum w tau^k m has the curvature c = (y2 - g y0 - h y1) / d, the
    parabola's value at tau = 0 is the line's minus c g, and RSS_line - RSS_parabola = c^2 d.
    ``det`` = wsum s2 - s1^2, the line's determinant. Returns ``(ok, inv_det, g, h, inv_d)``;
    ok is False where the line or the parabola is undetermined (fewer than three distinct
    times).
    """
    if not det > 1e-9 * wsum * wsum:
        return False, 0.0, 0.0, 0.0, 0.0
    inv_det = 1.0 / det
    g = (s2 * s2 - s3 * s1) * inv_det
    h = (wsum * s3 - s1 * s2) * inv_det
    d = s4 - g * s2 - h * s3
    if not det * d > 1e-6 * wsum * wsum * wsum:  # the 3x3 normal matrix's determinant
        return False, 0.0, 0.0, 0.0, 0.0
    return True, inv_det, g, h, 1.0 / d


@njit(inline="always")
def _line_value(wsum, s1, s2, y0, y1, det):
    """Value at tau = 0 of the weighted least-squares line through one coordinate's motion
    samples (A21; sums and ``det`` as in :func:`_parabola_basis`, y_k = sum w tau^k m); the
    weighted mean where all samples share one time."""
    if det > 1e-9 * wsum * wsum:
        return (y0 * s2 - y1 * s1) / det
    return y0 / wsum


@njit_parallel
def _fuse_kernel(
    bil_ring,
    ref_ring,
    frame_slot,
    t,
    first,
    land_row,
    land_col,
    land_ok,
    temporal_weight,
    min_support,
    gate_factor,
    sigma0,
    quad,
    min_gate,
    trajectory,
    f_crit,
    min_bias,
    static,
    static_tol_quad,
    out_points,
    support,
    hole,
    base_out,
):
    """Outer sum of Eq. 5 along the tracks (METHOD §5.2, motion vectors per §4.2/§4.3).

    p^_i^t = P~^t[x_i] + sum_T nu f(t,T) (B^T[x^_i^T] - P~^T[x^_i^T]) / sum_T nu f(t,T),
    which equals (1/kappa) sum_T nu f (B^T[x^] - m^{t,T}) with m = P~^T[x^] - P~^t[x].
    temporal_weight[|T - t|] = f(t, T). A sample whose mapped-back point
    B^T[x^] - m^{t,T} lies ``gate`` mm or more from frame t's own B^t[x] is rejected like a
    failed track (temporal range gate, A19), with gate = max(gate_factor * sigma(z),
    min_gate) and the frame's noise model sigma(z) = max(sigma0, quad z^2) (A22);
    gate_factor = inf disables it. Pixels with support <
    min_support are holes and get the bilateral-only value B^t[x_i] (filled later by Eq. 6).
    ``frame_slot[T - first]`` is the ring slot of frame T.

    trajectory = 1 (or True, A21): the base P~^t[x] is replaced by the value at t of the
    weighted least-squares line through the tracked reference positions P~^T[x^] (T in the
    window, accepted samples and t itself), i.e. the motion vectors m^{t,T} are regularised to
    be linear in time, so frame t's own low-frequency noise is averaged too. trajectory = 2
    (A28): the same with a weighted least-squares parabola (curved trajectories of turning or
    accelerating surfaces; falls back to the line when fewer than 3 distinct times
    determine it). trajectory = 3 (A32): the line, or the parabola for all three coordinates
    where some coordinate's curvature is both significant and large: its F statistic exceeds
    ``f_crit[n - 3]`` (n = the samples, t included; ``f_crit`` (K,) float64, the last entry
    for larger n) and the parabola moves its value at t by more than ``min_bias`` times the
    pixel's noise sigma(z) (f_crit and min_bias are unused by the other codes). 0 (or
    False): the frame base.

    static (H,W) bool (A33, ``fuse4d.static_tracks``): a static pixel's samples are the pixel
    itself in each frame T whose reference depth there lies within ``static_tol_quad *
    z~_t^2`` mm of frame t's, instead of its tracks (``land_*`` unused for it); with a
    trajectory base (codes 1-3) its trajectory is constant (A34): the base is the weighted
    mean of its motion vectors, t's own zero included.

    base_out (H,W,3) receives the base offset (mm) added to P~^t[x_i]: the trajectory fit's
    value at t minus P~^t[x_i] (0 with the frame base and at holes, NaN where P~^t is NaN),
    for the spatial smoothing of the base (A29, ``fuse4d.fusion``).
    """
    h = bil_ring.shape[1]
    w = bil_ring.shape[2]
    st = frame_slot[t - first]
    kmax = land_ok.shape[0]
    w0 = temporal_weight[0]
    n_chunks = min(h, ROW_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk, not per row
        acc = np.empty((w, 25), dtype=np.float64)
        lines = np.empty(3)
        parabolas = np.empty(3)
        for v in range(ci * h // n_chunks, (ci + 1) * h // n_chunks):
            acc[:] = 0.0
            # sample-major order over the row (independent per-pixel work overlaps in the CPU);
            # a pixel's 25 sums are contiguous (acc[u]: 4 cache lines touched per sample, not
            # 25 rows of a (25, W) table that outgrows L1: the kernel took 21 % less, stop 44).
            # acc[u, i]: 0-2 own detail e, 3-5 detail sum, 6 weight sum, 7 count, 8 s1, 9 s2,
            # 10 s3, 11 s4, 12 gate^2, per coordinate q: 13+q y0 (sum w m), 16+q y1
            # (sum w tau m), 19+q y2 (sum w tau^2 m), 22+q sum w m^2 (A32 only)
            for u in range(w):
                zt = ref_ring[st, v, u, 2]
                if np.isnan(zt):
                    continue
                gate = max(gate_factor * max(sigma0, quad * zt * zt), min_gate)
                acc[u, 12] = gate * gate
                for c in range(3):
                    e = bil_ring[st, v, u, c] - ref_ring[st, v, u, c]  # detail of frame t
                    acc[u, c] = e
                    acc[u, 3 + c] = w0 * e
                acc[u, 6] = w0
            for k in range(kmax):
                T = first + k if first + k < t else first + k + 1
                sT = frame_slot[T - first]
                wt = temporal_weight[abs(T - t)]
                tau = float(T - t)
                for u in range(w):
                    if static[v, u]:  # A33: the pixel's own sample, if its depth agrees
                        zt = ref_ring[st, v, u, 2]
                        if not abs(ref_ring[sT, v, u, 2] - zt) <= static_tol_quad * zt * zt:
                            continue
                        r = v
                        c = u
                    elif land_ok[k, v, u]:
                        r = land_row[k, v, u]
                        c = land_col[k, v, u]
                    else:
                        continue
                    dx = bil_ring[sT, r, c, 0] - ref_ring[sT, r, c, 0]
                    dy = bil_ring[sT, r, c, 1] - ref_ring[sT, r, c, 1]
                    dz = bil_ring[sT, r, c, 2] - ref_ring[sT, r, c, 2]
                    dist2 = (dx - acc[u, 0]) ** 2 + (dy - acc[u, 1]) ** 2 + (dz - acc[u, 2]) ** 2
                    if not (dist2 < acc[u, 12]):
                        continue
                    acc[u, 3] += wt * dx
                    acc[u, 4] += wt * dy
                    acc[u, 5] += wt * dz
                    acc[u, 6] += wt
                    acc[u, 7] += 1.0
                    acc[u, 8] += wt * tau
                    acc[u, 9] += wt * tau * tau
                    if trajectory >= 2:
                        acc[u, 10] += wt * tau * tau * tau
                        acc[u, 11] += wt * tau * tau * tau * tau
                    if trajectory:  # the trajectory's sums (A21, A28, A32)
                        for q in range(3):
                            m = ref_ring[sT, r, c, q] - ref_ring[st, v, u, q]
                            acc[u, 13 + q] += wt * m
                            acc[u, 16 + q] += wt * tau * m
                            if trajectory >= 2:  # the parabola's sums, unused by the line
                                acc[u, 19 + q] += wt * tau * tau * m
                            if trajectory == 3:  # the F test's sum
                                acc[u, 22 + q] += wt * m * m
            for u in range(w):
                zt = ref_ring[st, v, u, 2]
                if np.isnan(zt):
                    for c in range(3):
                        out_points[v, u, c] = np.nan
                        base_out[v, u, c] = np.nan
                    support[v, u] = 0
                    hole[v, u] = False
                    continue
                count = int(acc[u, 7])
                support[v, u] = min(count, 255)
                if count < min_support:
                    hole[v, u] = True
                    for c in range(3):
                        out_points[v, u, c] = bil_ring[st, v, u, c]
                        base_out[v, u, c] = 0.0
                    continue
                hole[v, u] = False
                wsum = acc[u, 6]
                if trajectory and static[v, u]:
                    # A34: a static pixel's trajectory is constant, its base the weighted
                    # mean of the motion vectors (t's own 0 included); a line's slope would
                    # be fitted noise, extrapolated at the end of a causal window
                    for c in range(3):
                        base = acc[u, 13 + c] / wsum
                        out_points[v, u, c] = ref_ring[st, v, u, c] + base + acc[u, 3 + c] / wsum
                        base_out[v, u, c] = base
                    continue
                # A21 line, A28 parabola, A32 the parabola for all three coordinates where
                # some coordinate's curvature is significant (F test) and larger than
                # min_bias sigma(z): one model for the point, so that the lateral and depth
                # offsets of a sample landing beside x stay consistent
                n = count + 1
                s1 = acc[u, 8]
                s2 = acc[u, 9]
                det = wsum * s2 - s1 * s1  # the line's, shared by the coordinates
                basis = (False, 0.0, 0.0, 0.0, 0.0)
                if trajectory >= 2:
                    basis = _parabola_basis(wsum, s1, s2, acc[u, 10], acc[u, 11], det)
                curved = trajectory == 2 and basis[0]
                test = trajectory == 3 and basis[0] and n > 3
                crit = f_crit[min(max(n - 3, 0), f_crit.size - 1)]
                floor = min_bias * max(sigma0, quad * zt * zt)
                for c in range(3):
                    y0 = acc[u, 13 + c]
                    y1 = acc[u, 16 + c]
                    lines[c] = _line_value(wsum, s1, s2, y0, y1, det) if trajectory else 0.0
                    parabolas[c] = lines[c]
                    if basis[0]:
                        _, inv_det, lin_g, lin_h, inv_d = basis  # (h is the height)
                        num = acc[u, 19 + c] - lin_g * y0 - lin_h * y1
                        curvature = num * inv_d
                        parabolas[c] = lines[c] - curvature * lin_g
                        if test and not curved and abs(curvature * lin_g) > floor:
                            # F test: (RSS_line - RSS_par) (n - 3) / RSS_par > crit
                            gain = num * curvature
                            slope = (wsum * y1 - s1 * y0) * inv_det
                            syy = acc[u, 22 + c]
                            rss_line = syy - lines[c] * y0 - slope * y1
                            if rss_line > 1e-12 * syy and gain > 0.0:
                                curved = gain * (n - 3) > crit * (rss_line - gain)
                for c in range(3):
                    base = parabolas[c] if curved else lines[c]
                    out_points[v, u, c] = ref_ring[st, v, u, c] + base + acc[u, 3 + c] / wsum
                    base_out[v, u, c] = base


# --------------------------------------------------------------------------- hole filling (Eq. 6)
@njit(inline="always")
def _jacobian_column(points, in_set, v, u, dv, du):
    """One column of J_n (d p / d u or d p / d v) by central / one-sided differences over F."""
    h, w = in_set.shape
    vp, up = v + dv, u + du
    vm, um = v - dv, u - du
    plus = 0 <= vp < h and 0 <= up < w and in_set[vp, up]
    minus = 0 <= vm < h and 0 <= um < w and in_set[vm, um]
    _ok, gx, gy, gz = _difference(points, v, u, dv, du, plus, minus)
    return gx, gy, gz


@njit
def _fill_holes_kernel(
    points, raw_points, hole, radius, inv_2sh2, passes, min_neighbours, gate, filled
):
    """Gradient-directed hole filling, onion peeling (Eq. 6, METHOD §6.2). In place.

    points (H,W,3): fused points, holes hold their fallback value; raw_points (H,W,3): P^t.
    hole (H,W) bool: True = to fill (cleared when filled). filled (H,W) bool: set True when a
    hole was filled. Each pass uses F (fused or filled, not hole, finite) as it stood at the
    start of the pass. A fill is accepted only within ``gate`` mm of the hole's current
    (fallback, bilateral-only) value (A20): first-order extrapolation overshoots on steep,
    curved surfaces such as a sphere's rim.

    Cost linear in the number of holes (issue 13): a hole's candidate depends only on F and
    the points within ``radius + 1`` px (the window plus the Jacobians' one-pixel reach), so
    after the first pass only the holes near a pixel filled in the previous pass are
    evaluated again; the others would repeat their last (rejected) evaluation. The Jacobians
    of F are cached between holes and passes. The result is that of evaluating every
    remaining hole in every pass.
    """
    h, w = hole.shape
    in_set = np.zeros((h, w), dtype=np.bool_)
    nh = 0
    for v in range(h):
        for u in range(w):
            in_set[v, u] = (not hole[v, u]) and not np.isnan(points[v, u, 2])
            if hole[v, u]:
                nh += 1
    # the remaining holes, in raster order (compacted after every pass)
    hv = np.empty(nh, dtype=np.int64)
    hu = np.empty(nh, dtype=np.int64)
    k = 0
    for v in range(h):
        for u in range(w):
            if hole[v, u]:
                hv[k] = v
                hu[k] = u
                k += 1
    new_vals = np.empty((nh, 3), dtype=np.float64)
    take = np.zeros(nh, dtype=np.bool_)
    # dirty[v, u]: F or the points changed within radius + 1 of (v, u) in the last pass
    dirty = np.zeros((h, w), dtype=np.bool_)
    # J_n of the members of F, computed when first needed and kept until F changes next to n
    # (J_n reads F and the points at n and its 4-neighbours): (du, dv) columns, x y z each
    jac = np.empty((h, w, 6), dtype=np.float64)
    jac_ok = np.zeros((h, w), dtype=np.bool_)
    reach = radius + 1
    for p in range(passes):
        for k in range(nh):
            take[k] = False
            v = hv[k]
            u = hu[k]
            if p > 0 and not dirty[v, u]:
                continue
            px = raw_points[v, u, 0]
            py = raw_points[v, u, 1]
            pz = raw_points[v, u, 2]
            count = 0
            for nv in range(max(v - radius, 0), min(v + radius + 1, h)):
                for nu in range(max(u - radius, 0), min(u + radius + 1, w)):
                    if in_set[nv, nu]:
                        count += 1
            if count < min_neighbours:
                continue
            ax = 0.0
            ay = 0.0
            az = 0.0
            wsum = 0.0
            for nv in range(max(v - radius, 0), min(v + radius + 1, h)):
                for nu in range(max(u - radius, 0), min(u + radius + 1, w)):
                    if not in_set[nv, nu]:
                        continue
                    qx = points[nv, nu, 0]
                    qy = points[nv, nu, 1]
                    qz = points[nv, nu, 2]
                    d2 = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
                    wgt = math.exp(-d2 * inv_2sh2)
                    if not jac_ok[nv, nu]:
                        jux, juy, juz = _jacobian_column(points, in_set, nv, nu, 0, 1)
                        jvx, jvy, jvz = _jacobian_column(points, in_set, nv, nu, 1, 0)
                        jac[nv, nu, 0] = jux
                        jac[nv, nu, 1] = juy
                        jac[nv, nu, 2] = juz
                        jac[nv, nu, 3] = jvx
                        jac[nv, nu, 4] = jvy
                        jac[nv, nu, 5] = jvz
                        jac_ok[nv, nu] = True
                    du = u - nu
                    dv = v - nv
                    ax += wgt * (qx + jac[nv, nu, 0] * du + jac[nv, nu, 3] * dv)
                    ay += wgt * (qy + jac[nv, nu, 1] * du + jac[nv, nu, 4] * dv)
                    az += wgt * (qz + jac[nv, nu, 2] * du + jac[nv, nu, 5] * dv)
                    wsum += wgt
            if wsum > 1e-30:
                nx_ = ax / wsum
                ny_ = ay / wsum
                nz_ = az / wsum
                dist2 = (
                    (nx_ - points[v, u, 0]) ** 2
                    + (ny_ - points[v, u, 1]) ** 2
                    + (nz_ - points[v, u, 2]) ** 2
                )
                if dist2 < gate * gate:
                    new_vals[k, 0] = nx_
                    new_vals[k, 1] = ny_
                    new_vals[k, 2] = nz_
                    take[k] = True
        # clear the marks of this pass, apply its fills, mark their neighbourhoods
        for k in range(nh):
            dirty[hv[k], hu[k]] = False
        any_filled = False
        for k in range(nh):
            if take[k]:
                v = hv[k]
                u = hu[k]
                points[v, u, 0] = new_vals[k, 0]
                points[v, u, 1] = new_vals[k, 1]
                points[v, u, 2] = new_vals[k, 2]
                hole[v, u] = False
                in_set[v, u] = True
                filled[v, u] = True
                any_filled = True
                for nv in range(max(v - reach, 0), min(v + reach + 1, h)):
                    for nu in range(max(u - reach, 0), min(u + reach + 1, w)):
                        dirty[nv, nu] = True
                for nv in range(max(v - 1, 0), min(v + 2, h)):
                    for nu in range(max(u - 1, 0), min(u + 2, w)):
                        jac_ok[nv, nu] = False
        if not any_filled:
            break
        # drop the filled holes from the list (order kept)
        m = 0
        for k in range(nh):
            if not take[k]:
                hv[m] = hv[k]
                hu[m] = hu[k]
                m += 1
        nh = m


# --------------------------------------------------------------------------- output on pixel rays
@njit(inline="always")
def _ref_difference(ref, v, u, dv, du, max_step, quad):
    """Derivative of the reference surface along (dv, du) over depth-continuous neighbours
    (depth step < ``_step_limit``, A22); ``(ok, gx, gy, gz)`` as :func:`_difference`."""
    h = ref.shape[0]
    w = ref.shape[1]
    zc = ref[v, u, 2]
    limit = _step_limit(zc, max_step, quad)
    vp, up = v + dv, u + du
    vm, um = v - dv, u - du
    plus = 0 <= vp < h and 0 <= up < w and abs(ref[vp, up, 2] - zc) < limit
    minus = 0 <= vm < h and 0 <= um < w and abs(ref[vm, um, 2] - zc) < limit
    return _difference(ref, v, u, dv, du, plus, minus)


@njit_parallel
def _project_to_rays_kernel(points, ref, fx, fy, cx, cy, max_step, quad, out):
    """Move each fused point along the local tangent plane onto its own pixel's ray (A17).

    The plane passes through the fused point p^ with the normal of the (smooth) reference
    surface P~ at the pixel; the output is ray_i * d with d = (n . p^) / (n . ray_i). Where the
    normal is undefined (isolated pixel, depth edge on both sides: steps of
    ``_step_limit(z, max_step, quad)`` or more) or the ray grazes the plane (|cos| < 0.05), or
    the correction exceeds max_step, the point keeps its Z: ray_i * p^_z.
    """
    h = points.shape[0]
    w = points.shape[1]
    for v in prange(h):
        ry = (v - cy) / fy
        for u in range(w):
            pz = points[v, u, 2]
            if np.isnan(pz):
                out[v, u, 0] = np.nan
                out[v, u, 1] = np.nan
                out[v, u, 2] = np.nan
                continue
            rx = (u - cx) / fx
            d = pz
            if not np.isnan(ref[v, u, 2]):
                ok_u, ax, ay, az = _ref_difference(ref, v, u, 0, 1, max_step, quad)
                ok_v, bx, by, bz = _ref_difference(ref, v, u, 1, 0, max_step, quad)
                if ok_u and ok_v:
                    nx = ay * bz - az * by
                    ny = az * bx - ax * bz
                    nz = ax * by - ay * bx
                    nrm = math.sqrt(nx * nx + ny * ny + nz * nz)
                    rnorm = math.sqrt(rx * rx + ry * ry + 1.0)
                    denom = nx * rx + ny * ry + nz
                    if nrm > 0.0 and abs(denom) > 0.05 * nrm * rnorm:
                        cand = (nx * points[v, u, 0] + ny * points[v, u, 1] + nz * pz) / denom
                        if abs(cand - pz) < max_step:
                            d = cand
            out[v, u, 0] = rx * d
            out[v, u, 1] = ry * d
            out[v, u, 2] = d


@njit_parallel
def _static_smoothing_kernel(points, smooth_z, static, limit_quad):
    """A42: move each static pixel's fused point along its ray (scaled about the camera
    centre) so that its depth approaches ``smooth_z``, by at most ``limit_quad * z^2`` mm.

    points (H,W,3) float32, modified in place; smooth_z (H,W) the edge-limited smoothing of
    the points' depth (NaN = none); static (H,W) bool (A33). Other pixels, and pixels
    without a finite depth or smoothing, are left as they are.
    """
    h = points.shape[0]
    w = points.shape[1]
    for v in prange(h):
        for u in range(w):
            if not static[v, u]:
                continue
            z = points[v, u, 2]
            target = smooth_z[v, u]
            if not (z > 0.0 and np.isfinite(target)):
                continue
            limit = limit_quad * z * z
            dz = min(max(target - z, -limit), limit)
            scale = (z + dz) / z
            points[v, u, 0] *= scale
            points[v, u, 1] *= scale
            points[v, u, 2] *= scale


# --------------------------------------------------------------------------- segment-limited smoothing
@njit_parallel(fastmath=set(SEGMENT_FASTMATH))
def _segment_box_rows_kernel(values, depth, radius, max_step, quad, out):
    """One local-linear box pass along rows, limited to depth-continuous segments.

    A segment is a run of valid pixels (finite ``depth``) whose consecutive raw depths differ
    by less than ``max_step`` mm; the window of each pixel is truncated to its segment, so
    values never mix across depth discontinuities or holes. Within the window a straight line
    is fitted (least squares over the column index) and evaluated at the pixel: on a symmetric
    window this is the plain box mean; on a truncated one (image border, depth edge) it has no
    slope bias. O(1) per pixel (prefix sums; :func:`._segments._box_line`). values, depth,
    out: (H, W) float32; out is NaN where depth is NaN.

    The engine runs the two-sweep kernels (:mod:`._kernels.segment_smooth`,
    :mod:`._kernels.smooth_base`), which equal passes of this one bit for bit (tested).
    """
    h, w = depth.shape
    n_chunks = min(h, ROW_CHUNKS)
    for ci in prange(n_chunks):  # scratch allocated once per chunk, not per row
        s_val = np.empty(w + 1, dtype=np.float64)
        s_kv = np.empty(w + 1, dtype=np.float64)
        starts = np.empty(w, dtype=np.int64)
        ends = np.empty(w, dtype=np.int64)
        for v in range(ci * h // n_chunks, (ci + 1) * h // n_chunks):
            for u in range(w):
                if np.isnan(depth[v, u]):
                    out[v, u] = np.nan
            m = _line_segments(depth[v], max_step, quad, starts, ends)
            _box_line(values[v], out[v], starts, ends, m, radius, s_val, s_kv)
