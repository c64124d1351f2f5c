"""Kernels of the 4D fusion (METHOD.md §3–§6). Private: arrays and scalars in, buffers filled.

Ring-buffer convention shared by the tracking and fusion kernels: frame T lives in slot
``T % S`` of the ``*_ring`` arrays (S = ring size), and the flows of the pair (T-1, T) live in
slot ``T % S`` of ``fwd_ring`` (s^{T-1,T}, on frame T-1's grid) and ``bwd_ring`` (s^{T,T-1}, on
frame T's grid).
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit, njit_parallel, prange

#: exp(-x) lookup table: x in [0, LUT_RANGE), LUT_STEPS entries per unit, linear interpolation.
LUT_RANGE = 16.0
LUT_STEPS = 256


def make_exp_lut() -> np.ndarray:
    """Table of exp(-x) for the bilateral weights (relative error ~2e-6 with interpolation)."""
    x = np.arange(int(LUT_RANGE * LUT_STEPS) + 2, dtype=np.float64) / LUT_STEPS
    return np.exp(-x).astype(np.float32)


@njit(inline="always")
def _exp_neg(x, lut):
    """exp(-x) for x >= 0 from the table; 0 beyond LUT_RANGE."""
    s = x * LUT_STEPS
    if s >= LUT_RANGE * LUT_STEPS:
        return np.float32(0.0)
    i = int(s)
    frac = np.float32(s - i)
    return lut[i] + frac * (lut[i + 1] - lut[i])


@njit(inline="always")
def _bilinear(field, x, y, comp):
    """Bilinear sample of ``field[:, :, comp]`` at continuous (x = column, y = row).

    The 2x2 stencil is clamped at the last row/column (METHOD §4.1); callers ensure
    0 <= x <= W-1 and 0 <= y <= H-1.
    """
    h = field.shape[0]
    w = field.shape[1]
    x0 = int(math.floor(x))
    y0 = int(math.floor(y))
    x0 = min(x0, w - 2)
    y0 = min(y0, h - 2)
    x0 = max(x0, 0)
    y0 = max(y0, 0)
    fx = x - x0
    fy = y - y0
    if w == 1:
        fx = 0.0
        x1 = x0
    else:
        x1 = x0 + 1
    if h == 1:
        fy = 0.0
        y1 = y0
    else:
        y1 = y0 + 1
    top = field[y0, x0, comp] * (1.0 - fx) + field[y0, x1, comp] * fx
    bottom = field[y1, x0, comp] * (1.0 - fx) + field[y1, x1, comp] * fx
    return top * (1.0 - fy) + bottom * fy


@njit(inline="always")
def _round_half_up(x):
    """floor(x + 0.5): METHOD §4.1 rounding (not round-half-to-even)."""
    return np.int64(math.floor(x + 0.5))


@njit(inline="always")
def _track_step(flow_step, flow_check, x, y, theta, per_step):
    """One tracking step with the forward-backward check (Eq. 4, in px, A4).

    Parameters: ``flow_step`` is sampled at (x, y) to move; ``flow_check`` (the reverse flow,
    on the landing frame's grid) is sampled at the landing point. Returns
    ``(ok, new_x, new_y)``; ok is False when the landing point leaves the image or the FB
    error is not < theta.
    """
    h = flow_step.shape[0]
    w = flow_step.shape[1]
    if per_step:
        iu = _round_half_up(x)
        iv = _round_half_up(y)
        su = float(flow_step[iv, iu, 0])
        sv = float(flow_step[iv, iu, 1])
    else:
        su = _bilinear(flow_step, x, y, 0)
        sv = _bilinear(flow_step, x, y, 1)
    nx = x + su
    ny = y + sv
    if not (nx >= 0.0 and nx <= w - 1.0 and ny >= 0.0 and ny <= h - 1.0):
        return False, nx, ny
    if per_step:
        ix = _round_half_up(nx)
        iy = _round_half_up(ny)
        cu = float(flow_check[iy, ix, 0])
        cv = float(flow_check[iy, ix, 1])
    else:
        cu = _bilinear(flow_check, nx, ny, 0)
        cv = _bilinear(flow_check, nx, ny, 1)
    e2 = (su + cu) * (su + cu) + (sv + cv) * (sv + cv)
    if not (e2 < theta * theta):
        return False, nx, ny
    if per_step:
        nx = float(_round_half_up(nx))
        ny = float(_round_half_up(ny))
    return True, nx, ny


# --------------------------------------------------------------------------- per-frame stages
@njit_parallel
def _bilateral3d_kernel(points, ref, intensity, radius, inv_2sd2, inv_2sg2, lut, residual, out):
    """Intensity-guided 3D bilateral of one frame (inner sum of Eq. 5, METHOD §5.1).

    Weights d(P_c, P_n) g(I_c, I_n) over the (2r+1)^2 window, NaN neighbours skipped.
    residual=False: out = sum w P_n / sum w (the literal inner sum).
    residual=True (A18): out = P~_c + sum w (P_n - P~_n) / sum w, i.e. every neighbour is first
    moved onto the centre's smooth reference surface (ref = P~), so that averaging removes
    noise without flattening curvature or shifting the point off its ray.
    points, ref (H,W,3) mm; intensity (H,W); out (H,W,3) (NaN where points is NaN).
    """
    h, w = intensity.shape
    for v in prange(h):
        for u in range(w):
            pz = points[v, u, 2]
            if np.isnan(pz):
                out[v, u, 0] = np.nan
                out[v, u, 1] = np.nan
                out[v, u, 2] = np.nan
                continue
            px = points[v, u, 0]
            py = points[v, u, 1]
            ic = intensity[v, u]
            # accumulate offsets (float64): no cancellation at ~1e3 mm
            ax = 0.0
            ay = 0.0
            az = 0.0
            wsum = 0.0
            v0 = max(v - radius, 0)
            v1 = min(v + radius + 1, h)
            u0 = max(u - radius, 0)
            u1 = min(u + radius + 1, w)
            for nv in range(v0, v1):
                for nu in range(u0, u1):
                    qz = points[nv, nu, 2]
                    if np.isnan(qz):
                        continue
                    dx = points[nv, nu, 0] - px
                    dy = points[nv, nu, 1] - py
                    dz = qz - pz
                    di = intensity[nv, nu] - ic
                    arg = (dx * dx + dy * dy + dz * dz) * inv_2sd2 + di * di * inv_2sg2
                    wgt = _exp_neg(arg, lut)
                    if residual:
                        ax += wgt * (points[nv, nu, 0] - ref[nv, nu, 0])
                        ay += wgt * (points[nv, nu, 1] - ref[nv, nu, 1])
                        az += wgt * (qz - ref[nv, nu, 2])
                    else:
                        ax += wgt * dx
                        ay += wgt * dy
                        az += wgt * dz
                    wsum += wgt
            if residual:
                out[v, u, 0] = ref[v, u, 0] + ax / wsum
                out[v, u, 1] = ref[v, u, 1] + ay / wsum
                out[v, u, 2] = ref[v, u, 2] + az / wsum
            else:
                out[v, u, 0] = px + ax / wsum
                out[v, u, 1] = py + ay / wsum
                out[v, u, 2] = pz + az / wsum


@njit_parallel
def _pair_diagnostics_kernel(
    fwd, bwd, ref_t, ref_t1, depth_t, depth_t1, theta, max_step, per_step, fb_error, motion
):
    """Per pair (t, t+1): FB error map on frame t's grid and the one-step 3D motion m^{t,t+1}.

    fb_error (H,W): |s_fwd(x) + s_bwd(x + s_fwd(x))| px, NaN if the landing leaves the image.
    motion (H,W,3): P~^{t+1}[round(x')] - P~^t[x] in mm where the step is valid (Eq. 3, 4), NaN
    elsewhere.
    """
    h, w = depth_t.shape
    for v in prange(h):
        for u in range(w):
            su = fwd[v, u, 0]
            sv = fwd[v, u, 1]
            nx = u + su
            ny = v + sv
            motion[v, u, 0] = np.nan
            motion[v, u, 1] = np.nan
            motion[v, u, 2] = np.nan
            if not (nx >= 0.0 and nx <= w - 1.0 and ny >= 0.0 and ny <= h - 1.0):
                fb_error[v, u] = np.nan
                continue
            cu = _bilinear(bwd, nx, ny, 0)
            cv = _bilinear(bwd, nx, ny, 1)
            fb_error[v, u] = math.sqrt((su + cu) ** 2 + (sv + cv) ** 2)
            if np.isnan(depth_t[v, u]):
                continue
            ok, lx, ly = _track_step(fwd, bwd, float(u), float(v), theta, per_step)
            if not ok:
                continue
            iu = _round_half_up(lx)
            iv = _round_half_up(ly)
            d1 = depth_t1[iv, iu]
            if np.isnan(d1) or not (abs(d1 - depth_t[v, u]) < max_step):
                continue
            for c in range(3):
                motion[v, u, c] = ref_t1[iv, iu, c] - ref_t[v, u, c]


# --------------------------------------------------------------------------- tracking
@njit_parallel
def _track_kernel(
    fwd_ring,
    bwd_ring,
    depth_ring,
    t,
    first,
    last,
    theta,
    max_step,
    per_step,
    land_row,
    land_col,
    land_ok,
):
    """Chain tracks from every valid pixel of frame t through the window [first, last].

    Output index k runs over offsets first-t .. last-t without 0, in increasing order
    (k = T - first for T < t, k = T - first - 1 for T > t). ``land_row/col`` (K,H,W) int32
    hold the rounded landing pixel x^_i^T; ``land_ok`` (K,H,W) bool the validity nu^{t,T}
    (AND of per-step checks: in image, FB < theta, valid depth, depth step < max_step).
    """
    ring = depth_ring.shape[0]
    h = depth_ring.shape[1]
    w = depth_ring.shape[2]
    st = t % ring
    for v in prange(h):
        for u in range(w):
            valid0 = not np.isnan(depth_ring[st, v, u])
            # forward
            x = float(u)
            y = float(v)
            pr = np.int64(v)
            pc = np.int64(u)
            alive = valid0
            for T in range(t + 1, last + 1):
                k = T - first - 1
                if alive:
                    ps = T % ring
                    ok, nx, ny = _track_step(fwd_ring[ps], bwd_ring[ps], x, y, theta, per_step)
                    if ok:
                        r = _round_half_up(ny)
                        c = _round_half_up(nx)
                        d1 = depth_ring[T % ring, r, c]
                        d0 = depth_ring[(T - 1) % ring, pr, pc]
                        if np.isnan(d1) or not (abs(d1 - d0) < max_step):
                            ok = False
                    if ok:
                        x = nx
                        y = ny
                        pr = r
                        pc = c
                    else:
                        alive = False
                land_ok[k, v, u] = alive
                land_row[k, v, u] = pr
                land_col[k, v, u] = pc
            # backward
            x = float(u)
            y = float(v)
            pr = np.int64(v)
            pc = np.int64(u)
            alive = valid0
            for T in range(t - 1, first - 1, -1):
                k = T - first
                if alive:
                    ps = (T + 1) % ring
                    ok, nx, ny = _track_step(bwd_ring[ps], fwd_ring[ps], x, y, theta, per_step)
                    if ok:
                        r = _round_half_up(ny)
                        c = _round_half_up(nx)
                        d1 = depth_ring[T % ring, r, c]
                        d0 = depth_ring[(T + 1) % ring, pr, pc]
                        if np.isnan(d1) or not (abs(d1 - d0) < max_step):
                            ok = False
                    if ok:
                        x = nx
                        y = ny
                        pr = r
                        pc = c
                    else:
                        alive = False
                land_ok[k, v, u] = alive
                land_row[k, v, u] = pr
                land_col[k, v, u] = pc


# --------------------------------------------------------------------------- fusion (Eq. 5)
@njit_parallel
def _fuse_kernel(
    bil_ring,
    ref_ring,
    t,
    first,
    land_row,
    land_col,
    land_ok,
    temporal_weight,
    min_support,
    gate,
    out_points,
    support,
    hole,
):
    """Outer sum of Eq. 5 along the tracks (METHOD §5.2, motion vectors per §4.2/§4.3).

    p^_i^t = P~^t[x_i] + sum_T nu f(t,T) (B^T[x^_i^T] - P~^T[x^_i^T]) / sum_T nu f(t,T),
    which equals (1/kappa) sum_T nu f (B^T[x^] - m^{t,T}) with m = P~^T[x^] - P~^t[x].
    temporal_weight[|T - t|] = f(t, T). A sample whose mapped-back point
    B^T[x^] - m^{t,T} lies ``gate`` mm or more from frame t's own B^t[x] is rejected like a
    failed track (temporal range gate, A19; gate = inf disables it). Pixels with support <
    min_support are holes and get the bilateral-only value B^t[x_i] (filled later by Eq. 6).
    """
    ring = bil_ring.shape[0]
    h = bil_ring.shape[1]
    w = bil_ring.shape[2]
    st = t % ring
    kmax = land_ok.shape[0]
    gate2 = gate * gate
    for v in prange(h):
        for u in range(w):
            if np.isnan(ref_ring[st, v, u, 2]):
                for c in range(3):
                    out_points[v, u, c] = np.nan
                support[v, u] = 0
                hole[v, u] = False
                continue
            # detail of frame t itself: B^t - P~^t
            ex = bil_ring[st, v, u, 0] - ref_ring[st, v, u, 0]
            ey = bil_ring[st, v, u, 1] - ref_ring[st, v, u, 1]
            ez = bil_ring[st, v, u, 2] - ref_ring[st, v, u, 2]
            w0 = temporal_weight[0]
            ax = w0 * ex
            ay = w0 * ey
            az = w0 * ez
            wsum = w0
            count = 0
            for k in range(kmax):
                if not land_ok[k, v, u]:
                    continue
                T = first + k if first + k < t else first + k + 1
                sT = T % ring
                r = land_row[k, v, u]
                c = land_col[k, v, u]
                dx = bil_ring[sT, r, c, 0] - ref_ring[sT, r, c, 0]
                dy = bil_ring[sT, r, c, 1] - ref_ring[sT, r, c, 1]
                dz = bil_ring[sT, r, c, 2] - ref_ring[sT, r, c, 2]
                if not ((dx - ex) ** 2 + (dy - ey) ** 2 + (dz - ez) ** 2 < gate2):
                    continue
                wt = temporal_weight[abs(T - t)]
                ax += wt * dx
                ay += wt * dy
                az += wt * dz
                wsum += wt
                count += 1
            support[v, u] = min(count, 255)
            if count < min_support:
                hole[v, u] = True
                for c in range(3):
                    out_points[v, u, c] = bil_ring[st, v, u, c]
            else:
                hole[v, u] = False
                out_points[v, u, 0] = ref_ring[st, v, u, 0] + ax / wsum
                out_points[v, u, 1] = ref_ring[st, v, u, 1] + ay / wsum
                out_points[v, u, 2] = ref_ring[st, v, u, 2] + az / wsum


# --------------------------------------------------------------------------- hole filling (Eq. 6)
@njit(inline="always")
def _jacobian_column(points, in_set, v, u, dv, du):
    """One column of J_n (d p / d u or d p / d v) by central / one-sided differences over F."""
    h, w = in_set.shape
    vp, up = v + dv, u + du
    vm, um = v - dv, u - du
    plus = 0 <= vp < h and 0 <= up < w and in_set[vp, up]
    minus = 0 <= vm < h and 0 <= um < w and in_set[vm, um]
    gx = 0.0
    gy = 0.0
    gz = 0.0
    if plus and minus:
        gx = 0.5 * (points[vp, up, 0] - points[vm, um, 0])
        gy = 0.5 * (points[vp, up, 1] - points[vm, um, 1])
        gz = 0.5 * (points[vp, up, 2] - points[vm, um, 2])
    elif plus:
        gx = points[vp, up, 0] - points[v, u, 0]
        gy = points[vp, up, 1] - points[v, u, 1]
        gz = points[vp, up, 2] - points[v, u, 2]
    elif minus:
        gx = points[v, u, 0] - points[vm, um, 0]
        gy = points[v, u, 1] - points[vm, um, 1]
        gz = points[v, u, 2] - points[vm, um, 2]
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
    """
    h, w = hole.shape
    in_set = np.zeros((h, w), dtype=np.bool_)
    for v in range(h):
        for u in range(w):
            in_set[v, u] = (not hole[v, u]) and not np.isnan(points[v, u, 2])
    hv = np.empty(h * w, dtype=np.int64)
    hu = np.empty(h * w, dtype=np.int64)
    nh = 0
    for v in range(h):
        for u in range(w):
            if hole[v, u]:
                hv[nh] = v
                hu[nh] = u
                nh += 1
    new_vals = np.empty((nh, 3), dtype=np.float64)
    take = np.zeros(nh, dtype=np.bool_)
    for _ in range(passes):
        any_filled = False
        for k in range(nh):
            take[k] = False
            v = hv[k]
            u = hu[k]
            if not hole[v, u]:
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
                    jux, juy, juz = _jacobian_column(points, in_set, nv, nu, 0, 1)
                    jvx, jvy, jvz = _jacobian_column(points, in_set, nv, nu, 1, 0)
                    du = u - nu
                    dv = v - nv
                    ax += wgt * (qx + jux * du + jvx * dv)
                    ay += wgt * (qy + juy * du + jvy * dv)
                    az += wgt * (qz + juz * du + jvz * dv)
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
        if not any_filled:
            break


# --------------------------------------------------------------------------- output on pixel rays
@njit(inline="always")
def _ref_difference(ref, v, u, dv, du, max_step):
    """Derivative of the reference surface along (dv, du), gated by depth jumps (None = 0s)."""
    h = ref.shape[0]
    w = ref.shape[1]
    zc = ref[v, u, 2]
    vp, up = v + dv, u + du
    vm, um = v - dv, u - du
    plus = 0 <= vp < h and 0 <= up < w and abs(ref[vp, up, 2] - zc) < max_step
    minus = 0 <= vm < h and 0 <= um < w and abs(ref[vm, um, 2] - zc) < max_step
    if plus and minus:
        return (
            True,
            0.5 * (ref[vp, up, 0] - ref[vm, um, 0]),
            0.5 * (ref[vp, up, 1] - ref[vm, um, 1]),
            0.5 * (ref[vp, up, 2] - ref[vm, um, 2]),
        )
    if plus:
        return (
            True,
            ref[vp, up, 0] - ref[v, u, 0],
            ref[vp, up, 1] - ref[v, u, 1],
            ref[vp, up, 2] - ref[v, u, 2],
        )
    if minus:
        return (
            True,
            ref[v, u, 0] - ref[vm, um, 0],
            ref[v, u, 1] - ref[vm, um, 1],
            ref[v, u, 2] - ref[vm, um, 2],
        )
    return False, 0.0, 0.0, 0.0


@njit_parallel
def _project_to_rays_kernel(points, ref, fx, fy, cx, cy, max_step, out):
    """Move each fused point along the local tangent plane onto its own pixel's ray (A17).

    The plane passes through the fused point p^ with the normal of the (smooth) reference
    surface P~ at the pixel; the output is ray_i * d with d = (n . p^) / (n . ray_i). Where the
    normal is undefined (isolated pixel, depth edge on both sides) or the ray grazes the plane
    (|cos| < 0.05), or the correction exceeds max_step, the point keeps its Z: ray_i * p^_z.
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
                ok_u, ax, ay, az = _ref_difference(ref, v, u, 0, 1, max_step)
                ok_v, bx, by, bz = _ref_difference(ref, v, u, 1, 0, max_step)
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


# --------------------------------------------------------------------------- segment-limited smoothing
@njit_parallel
def _segment_box_rows_kernel(values, depth, radius, max_step, out):
    """One local-linear box pass along rows, limited to depth-continuous segments.

    A segment is a run of valid pixels (finite ``depth``) whose consecutive raw depths differ
    by less than ``max_step`` mm; the window of each pixel is truncated to its segment, so
    values never mix across depth discontinuities or holes. Within the window a straight line
    is fitted (least squares over the column index) and evaluated at the pixel: on a symmetric
    window this is the plain box mean; on a truncated one (image border, depth edge) it has no
    slope bias. O(1) per pixel (prefix sums). values, depth, out: (H, W) float32; out is NaN
    where depth is NaN.
    """
    h, w = depth.shape
    for v in prange(h):
        s_val = np.empty(w + 1, dtype=np.float64)
        s_kv = np.empty(w + 1, dtype=np.float64)
        u = 0
        while u < w:
            if np.isnan(depth[v, u]):
                out[v, u] = np.nan
                u += 1
                continue
            a = u
            b = u + 1
            while (
                b < w
                and not np.isnan(depth[v, b])
                and abs(depth[v, b] - depth[v, b - 1]) < max_step
            ):
                b += 1
            s_val[0] = 0.0
            s_kv[0] = 0.0
            for k in range(a, b):
                j = k - a
                s_val[j + 1] = s_val[j] + values[v, k]
                s_kv[j + 1] = s_kv[j] + j * values[v, k]
            for k in range(a, b):
                lo = max(k - radius, a) - a
                hi = min(k + radius, b - 1) - a
                n = hi - lo + 1
                mean_val = (s_val[hi + 1] - s_val[lo]) / n
                # column indices lo..hi: mean and variance in closed form
                mean_j = 0.5 * (lo + hi)
                var_j = (n * n - 1) / 12.0
                if var_j > 0.0:
                    cov = (s_kv[hi + 1] - s_kv[lo]) / n - mean_j * mean_val
                    out[v, k] = mean_val + cov / var_j * ((k - a) - mean_j)
                else:
                    out[v, k] = mean_val
            u = b
