"""Pure-NumPy/Python oracles for the fusion kernels (slow, obviously correct, tiny inputs)."""

from __future__ import annotations

import math

import numpy as np


def approx_exp_neg(x):
    """The kernels' weight function: exp(-x) ~ (1 - x / 1024) ** 1024, 0 beyond x = 1024."""
    return max(1.0 - x / 1024.0, 0.0) ** 1024


def bilateral3d(points, intensity, radius, sigma_d, sigma_g, reference=None):
    """Inner sum of Eq. 5 with exact exp; residual form when ``reference`` is given."""
    h, w = intensity.shape
    out = np.full_like(points, np.nan, dtype=np.float64)
    for v in range(h):
        for u in range(w):
            if np.isnan(points[v, u, 2]):
                continue
            acc = np.zeros(3)
            wsum = 0.0
            for nv in range(max(v - radius, 0), min(v + radius + 1, h)):
                for nu in range(max(u - radius, 0), min(u + radius + 1, w)):
                    q = points[nv, nu].astype(np.float64)
                    if np.isnan(q[2]):
                        continue
                    d2 = np.sum((q - points[v, u]) ** 2)
                    di = float(intensity[nv, nu]) - float(intensity[v, u])
                    wgt = approx_exp_neg(d2 / (2 * sigma_d**2) + di * di / (2 * sigma_g**2))
                    acc += wgt * (q - reference[nv, nu] if reference is not None else q)
                    wsum += wgt
            out[v, u] = acc / wsum + (reference[v, u] if reference is not None else 0.0)
    return out


def step_limit(z, max_step, quad):
    """The depth-step rule (A22): max(tau_jump, 2.5 quad z^2), mm."""
    return max(max_step, 2.5 * quad * float(z) ** 2)


def segment_box_rows(values, depth, radius, max_step, quad=0.0):
    """One local-linear box pass along rows limited to depth-continuous segments."""
    h, w = depth.shape
    out = np.full((h, w), np.nan)
    for v in range(h):
        segment = np.full(w, -1)
        sid = -1
        for u in range(w):
            if np.isnan(depth[v, u]):
                continue
            if (
                u == 0
                or segment[u - 1] < 0
                or not abs(depth[v, u] - depth[v, u - 1])
                < step_limit(depth[v, u - 1], max_step, quad)
            ):
                sid += 1
            segment[u] = sid
        for u in range(w):
            if segment[u] < 0:
                continue
            idx = [
                k
                for k in range(u - radius, u + radius + 1)
                if 0 <= k < w and segment[k] == segment[u]
            ]
            vals = np.array([values[v, k] for k in idx], dtype=np.float64)
            if len(idx) > 1:
                slope, intercept = np.polyfit(np.array(idx, dtype=np.float64), vals, 1)
                out[v, u] = slope * u + intercept
            else:
                out[v, u] = vals[0]
    return out


def bilinear(field, x, y):
    """Bilinear sample with the 2x2 stencil clamped at the last row/column."""
    h, w = field.shape[:2]
    x0 = min(max(math.floor(x), 0), max(w - 2, 0))
    y0 = min(max(math.floor(y), 0), max(h - 2, 0))
    x1 = min(x0 + 1, w - 1)
    y1 = min(y0 + 1, h - 1)
    fx = x - x0 if w > 1 else 0.0
    fy = y - y0 if h > 1 else 0.0
    top = field[y0, x0] * (1 - fx) + field[y0, x1] * fx
    bottom = field[y1, x0] * (1 - fx) + field[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def _nearest(field, x, y):
    return field[math.floor(y + 0.5), math.floor(x + 0.5)].astype(np.float64)


def flow_step(step, check, x, y, theta, per_step):
    """One tracking step with the FB check (Eq. 4): (ok, new_x, new_y)."""
    h, w = step.shape[:2]
    sample = _nearest if per_step else bilinear
    s = sample(step, x, y)
    nx, ny = x + s[0], y + s[1]
    if not (0 <= nx <= w - 1 and 0 <= ny <= h - 1):
        return False, nx, ny
    c = sample(check, nx, ny)
    if not math.hypot(s[0] + c[0], s[1] + c[1]) < theta:
        return False, nx, ny
    if per_step:
        nx, ny = float(math.floor(nx + 0.5)), float(math.floor(ny + 0.5))
    return True, nx, ny


def track(fwd, bwd, depth, t, first, last, theta, max_step, quad=0.0, per_step=False):
    """Chained tracks (METHOD §4.1): {(T, v, u): (row, col, valid)} per pixel.

    ``per_step=False``: sub-pixel accumulation, rounding for lookup only (A6); ``True``: the
    literal rounding after every step. Depth steps are limited by :func:`step_limit`, evaluated
    at the depth the step starts from (A22).
    """
    _n, h, w = depth.shape
    result = {}
    for v in range(h):
        for u in range(w):
            valid0 = not np.isnan(depth[t, v, u])
            for direction in (1, -1):
                x, y = float(u), float(v)
                pr, pc = v, u
                alive = valid0
                rng = range(t + 1, last + 1) if direction == 1 else range(t - 1, first - 1, -1)
                for T in rng:
                    if alive:
                        if direction == 1:
                            step, check, prev = fwd[T - 1], bwd[T - 1], T - 1
                        else:
                            step, check, prev = bwd[T], fwd[T], T + 1
                        ok, nx, ny = flow_step(step, check, x, y, theta, per_step)
                        if ok:
                            r, cc = math.floor(ny + 0.5), math.floor(nx + 0.5)
                            d0 = depth[prev, pr, pc]
                            d1 = depth[T, r, cc]
                            ok = not np.isnan(d1) and abs(d1 - d0) < step_limit(d0, max_step, quad)
                        if ok:
                            x, y, pr, pc = nx, ny, r, cc
                        else:
                            alive = False
                    result[(T, v, u)] = (pr, pc, alive)
    return result


def _round(x):
    return math.floor(x + 0.5)


def composed_track(fwd, bwd, depth, t, first, last, theta, max_step, quads):
    """Composed tracks (A31, ``FusionParams(tracks="composed")``): {(T, v, u): (row, col,
    valid)} like :func:`track`. A chain s -> c takes its exact first step to s +- 1 (checked
    with frame s's ``quads[s]``) and then follows the chain of the rounded landing pixel,
    shifted by the landing's sub-pixel offset; where the shift leaves that chain's landing
    pixel, the new pixel needs valid depth within the step limit of it (``quads[c]``).
    Positions are stored as float32, as the kernels store them."""
    _n, h, w = depth.shape
    memo = {}

    def one_step(s, direction):
        out = {}
        T = s + direction
        step, check = (fwd[s], bwd[s]) if direction == 1 else (bwd[s - 1], fwd[s - 1])
        for v in range(h):
            for u in range(w):
                d0 = depth[s, v, u]
                ok, x, y = flow_step(step, check, float(u), float(v), theta, False)
                ok = ok and not np.isnan(d0)
                r, c = v, u
                if ok:
                    r, c = _round(y), _round(x)
                    d1 = depth[T, r, c]
                    ok = not np.isnan(d1) and abs(d1 - d0) < step_limit(d0, max_step, quads[s])
                    if not ok:
                        r, c = v, u
                out[(v, u)] = (float(np.float32(x)), float(np.float32(y)), ok, r, c)
        return out

    def chain(s, c_frame):
        if (s, c_frame) in memo:
            return memo[(s, c_frame)]
        direction = 1 if c_frame > s else -1
        first_step = one_step(s, direction)
        if abs(c_frame - s) == 1:
            memo[(s, c_frame)] = first_step
            return first_step
        nxt = chain(s + direction, c_frame)
        out = {}
        for v in range(h):
            for u in range(w):
                x1, y1, ok, _r, _c = first_step[(v, u)]
                x, y, r, c = x1, y1, v, u
                if ok:
                    r1, c1 = _round(y1), _round(x1)
                    nx, ny, ok, rn, cn = nxt[(r1, c1)]
                    if ok:
                        x, y = nx + (x1 - c1), ny + (y1 - r1)
                        ok = 0 <= x <= w - 1 and 0 <= y <= h - 1
                        if ok:
                            r, c = _round(y), _round(x)
                            rn, cn = _round(ny), _round(nx)
                            if (r, c) != (rn, cn):
                                d, dn = depth[c_frame, r, c], depth[c_frame, rn, cn]
                                ok = not np.isnan(d) and abs(d - dn) < step_limit(
                                    dn, max_step, quads[c_frame]
                                )
                if not ok:
                    r, c = v, u
                out[(v, u)] = (float(np.float32(x)), float(np.float32(y)), ok, r, c)
        memo[(s, c_frame)] = out
        return out

    result = {}
    for T in range(first, last + 1):
        if t == T:
            continue
        ch = chain(t, T)
        for (v, u), (_x, _y, ok, r, c) in ch.items():
            result[(T, v, u)] = (r, c, ok)
    return result


def static_tracks(tracks, reference_z, intensity, depth_t, t, first, last, quad):
    """A33 as a rewrite of the tracks: where the pixel is static, its "track" is the pixel
    itself in each frame whose reference depth there is within ``tol * q z~_t^2`` of frame t's
    (``tol``, ``ratio``, ``box``: the method's constants in :mod:`fuse4d.static_tracks`).

    Static: raw depth valid at t, the reference depth at the pixel within that tolerance in
    every frame where it is finite, and sum over a (2 box + 1)^2 box (mirrored at the border,
    edge not repeated) of sum_T (I_T(x) - I_t(x))^2 at most ``ratio`` times the same sum at
    the tracks' landings (the pixel's own term where a track is invalid). Returns the new
    tracks dict and the static mask.
    """
    import fuse4d.static_tracks as method  # its constants, not its code

    tol, ratio, box = (
        method.STATIC_DEPTH_TOLERANCE,
        method.STATIC_PHOTO_RATIO,
        method.STATIC_BOX_RADIUS,
    )

    _n, h, w = reference_z.shape
    still = np.zeros((h, w), bool)
    zero = np.zeros((h, w))
    moved = np.zeros((h, w))
    others = [T for T in range(first, last + 1) if t != T]
    for v in range(h):
        for u in range(w):
            zt = float(reference_z[t, v, u])
            limit = tol * quad * zt * zt
            still[v, u] = not (np.isnan(depth_t[v, u]) or np.isnan(zt)) and all(
                not abs(float(reference_z[T, v, u]) - zt) > limit for T in others
            )
            for T in others:
                own = (float(intensity[T, v, u]) - float(intensity[t, v, u])) ** 2
                r, c, ok = tracks[(T, v, u)]
                landed = (float(intensity[T, r, c]) - float(intensity[t, v, u])) ** 2
                zero[v, u] += own
                moved[v, u] += landed if ok else own

    def box_sum(a):
        padded = np.pad(a, box, mode="reflect")
        return sum(
            padded[box + dv : box + dv + h, box + du : box + du + w]
            for dv in range(-box, box + 1)
            for du in range(-box, box + 1)
        )

    static = still & (box_sum(zero) <= ratio * box_sum(moved))
    out = dict(tracks)
    for v, u in zip(*np.nonzero(static), strict=True):
        zt = float(reference_z[t, v, u])
        for T in others:
            near = abs(float(reference_z[T, v, u]) - zt) <= tol * quad * zt * zt
            out[(T, v, u)] = (v, u, bool(near))
    return out, static


def pair_motion(fwd, bwd, ref_t, ref_t1, depth_t, depth_t1, theta, max_step, quad, per_step):
    """FB error map (bilinear at the unrounded landing, px) and one-step motion (Eq. 3, mm)."""
    h, w = depth_t.shape
    fb = np.full((h, w), np.nan)
    motion = np.full((h, w, 3), np.nan)
    for v in range(h):
        for u in range(w):
            s = fwd[v, u].astype(np.float64)
            nx, ny = u + s[0], v + s[1]
            if not (0 <= nx <= w - 1 and 0 <= ny <= h - 1):
                continue
            c = bilinear(bwd, nx, ny)
            fb[v, u] = math.hypot(s[0] + c[0], s[1] + c[1])
            if np.isnan(depth_t[v, u]):
                continue
            ok, lx, ly = flow_step(fwd, bwd, float(u), float(v), theta, per_step)
            if not ok:
                continue
            r, cc = math.floor(ly + 0.5), math.floor(lx + 0.5)
            d0, d1 = depth_t[v, u], depth_t1[r, cc]
            if np.isnan(d1) or not abs(d1 - d0) < step_limit(d0, max_step, quad):
                continue
            motion[v, u] = ref_t1[r, cc].astype(np.float64) - ref_t[v, u]
    return fb, motion


def _trajectory_fit(taus, wts, motions, trajectory, bias_floor):
    """(3,) value at tau = 0 of the weighted least-squares line (1) or parabola (2) through
    (taus, motions), or (3) the parabola for all coordinates where a coordinate's F test
    (scipy.stats, level ``CURVATURE_TEST_LEVEL`` / 3) rejects the line and its parabola
    differs from its line at tau = 0 by more than ``bias_floor`` mm."""
    from scipy.stats import f as f_dist

    from fuse4d.fusion import CURVATURE_TEST_LEVEL

    def fit(degree, m):
        design = np.stack([taus**k for k in range(degree + 1)], axis=1)
        sw = np.sqrt(wts)
        coef = np.linalg.lstsq(design * sw[:, None], m * sw, rcond=None)[0]
        return float(coef[0]), float(np.sum(wts * (m - design @ coef) ** 2))

    distinct = len(set(taus.tolist()))
    if distinct == 1:
        return np.average(motions, axis=0, weights=wts)
    lines = np.array([fit(1, motions[:, c])[0] for c in range(3)])
    if trajectory == 1 or distinct == 2:
        return lines
    parabolas = np.array([fit(2, motions[:, c])[0] for c in range(3)])
    if trajectory == 2:
        return parabolas
    n = len(taus)
    if n <= 3:
        return lines
    crit = f_dist.ppf(1.0 - CURVATURE_TEST_LEVEL / 3.0, 1, n - 3)
    for c in range(3):
        m = motions[:, c]
        rss_line, rss_par = fit(1, m)[1], fit(2, m)[1]
        if rss_line > 1e-12 * float(np.sum(wts * m * m)) and rss_line - rss_par > 0:
            significant = rss_par <= 0 or (rss_line - rss_par) * (n - 3) / rss_par > crit
            if significant and abs(parabolas[c] - lines[c]) > bias_floor:
                return parabolas
    return lines


def fuse(
    bilateral,
    reference,
    tracks,
    t,
    first,
    last,
    weights,
    gate,
    *,
    trajectory=False,
    base_out=None,
    noise=None,
    min_bias=0.0,
    constant=None,
):
    """Outer sum of Eq. 5 along given tracks, with the temporal range gate (A19) and,
    optionally, the trajectory base (A21: least-squares line through the motion vectors;
    ``trajectory=2``: a parabola, A28; ``trajectory=3``: the parabola where the F test of a
    coordinate rejects the line, A32). ``base_out`` (H, W, 3), if given, receives each pixel's base
    offset (A29; NaN where the reference is NaN).

    ``gate``: mm, or a function of frame t's reference depth z (mm) giving the gate in mm;
    ``noise``: a function of z giving the depth noise sigma(z) in mm (A32's bias floor is
    ``min_bias`` sigma(z); None: 0). ``constant`` (H, W) bool: with a trajectory base, these
    pixels' trajectory is constant (A34, the static pixels of A33): the weighted mean of
    their motion vectors, t's own zero included.
    """
    _n, h, w, _ = bilateral.shape
    out = np.full((h, w, 3), np.nan)
    support = np.zeros((h, w), int)
    for v in range(h):
        for u in range(w):
            if np.isnan(reference[t, v, u, 2]):
                continue
            own = bilateral[t, v, u] - reference[t, v, u]
            g = gate(float(reference[t, v, u, 2])) if callable(gate) else gate
            taus, wts, details, motions = [0.0], [weights[0]], [own], [np.zeros(3)]
            for T in range(first, last + 1):
                if t == T:
                    continue
                r, c, ok = tracks[(T, v, u)]
                if not ok:
                    continue
                detail = bilateral[T, r, c] - reference[T, r, c]
                if not np.linalg.norm(detail - own) < g:
                    continue
                taus.append(float(T - t))
                wts.append(weights[abs(T - t)])
                details.append(detail)
                motions.append(reference[T, r, c] - reference[t, v, u])
                support[v, u] += 1
            wts_a = np.array(wts)
            base = np.zeros(3)
            if trajectory and constant is not None and constant[v, u]:
                base = np.average(np.array(motions), axis=0, weights=wts_a)
            elif trajectory:
                z = float(reference[t, v, u, 2])
                floor = min_bias * (noise(z) if noise is not None else 0.0)
                base = _trajectory_fit(np.array(taus), wts_a, np.array(motions), trajectory, floor)
            out[v, u] = (
                reference[t, v, u] + base + np.average(np.array(details), axis=0, weights=wts_a)
            )
            if base_out is not None:
                base_out[v, u] = base
    return out, support


def smooth_base(out, base, depth, hole, sigma, max_step, quad, limit):
    """A29: keep the edge-limited spatial mean S of the base offset and its fine-scale part
    clipped to +-limit q z^2 (S from fuse4d's oracle-tested segment smoothing). In place."""
    from fuse4d.motion import _segment_smooth

    d = np.where(hole, np.nan, depth).astype(np.float32)
    bound = limit * quad * np.nan_to_num(depth).astype(np.float64) ** 2
    for c in range(3):
        own = np.nan_to_num(base[..., c]).astype(np.float32)
        sm = _segment_smooth(own, d, sigma=sigma, max_step=max_step, noise_quad=quad)
        for v, u in zip(*np.nonzero(np.isfinite(sm)), strict=True):
            fine = min(max(own[v, u] - sm[v, u], -bound[v, u]), bound[v, u])
            out[v, u, c] += sm[v, u] + fine - own[v, u]


def noise_gate(gate_factor, sigma0, quad, min_gate):
    """The temporal gate of a frame as a function of depth z (A19, A22), mm."""
    return lambda z: max(gate_factor * max(sigma0, quad * z * z), min_gate)


def _diff(points, v, u, dv, du, plus, minus):
    if plus and minus:
        return True, 0.5 * (points[v + dv, u + du] - points[v - dv, u - du])
    if plus:
        return True, points[v + dv, u + du] - points[v, u]
    if minus:
        return True, points[v, u] - points[v - dv, u - du]
    return False, np.zeros(3)


def fill_holes(points, raw_points, hole, radius, sigma, passes, min_neighbours, gate):
    """Eq. 6 with onion peeling and the A20 acceptance gate: (points, hole, filled), copies.

    Each pass fills, from the fused set F as it stood at the start of the pass, every hole
    with at least ``min_neighbours`` members of F in its window, accepting a fill only within
    ``gate`` mm of the hole's current value.
    """
    pts = points.astype(np.float64)
    hole = hole.copy()
    h, w = hole.shape
    filled = np.zeros_like(hole)
    in_f = ~hole & np.isfinite(points[..., 2])
    for _ in range(passes):
        f_now = in_f.copy()
        new = {}
        for v, u in zip(*np.nonzero(hole), strict=True):
            window = [
                (nv, nu)
                for nv in range(max(v - radius, 0), min(v + radius + 1, h))
                for nu in range(max(u - radius, 0), min(u + radius + 1, w))
                if f_now[nv, nu]
            ]
            if len(window) < min_neighbours:
                continue
            acc = np.zeros(3)
            wsum = 0.0
            for nv, nu in window:
                q = pts[nv, nu]
                wgt = math.exp(-np.sum((q - raw_points[v, u]) ** 2) / (2 * sigma**2))
                inside = [
                    (a, b) for a, b in ((nv, nu + 1), (nv, nu - 1), (nv + 1, nu), (nv - 1, nu))
                ]
                ok = [0 <= a < h and 0 <= b < w and f_now[a, b] for a, b in inside]
                _, ju = _diff(pts, nv, nu, 0, 1, ok[0], ok[1])
                _, jv = _diff(pts, nv, nu, 1, 0, ok[2], ok[3])
                acc += wgt * (q + ju * (u - nu) + jv * (v - nv))
                wsum += wgt
            if wsum > 1e-30 and np.linalg.norm(acc / wsum - pts[v, u]) < gate:
                new[(v, u)] = acc / wsum
        if not new:
            break
        for (v, u), value in new.items():
            pts[v, u] = value
            hole[v, u] = False
            filled[v, u] = True
            in_f[v, u] = True
    return pts, hole, filled


def project_to_rays(points, ref, fx, fy, cx, cy, max_step, quad):
    """A17: each point moved along the reference surface's tangent plane onto its pixel ray."""
    h, w = points.shape[:2]
    out = np.full(points.shape, np.nan)
    for v in range(h):
        for u in range(w):
            p = points[v, u].astype(np.float64)
            if np.isnan(p[2]):
                continue
            ray = np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
            d = p[2]
            zc = ref[v, u, 2]
            if not np.isnan(zc):
                limit = step_limit(zc, max_step, quad)

                def near(a, b, zc=zc, limit=limit):
                    return 0 <= a < h and 0 <= b < w and abs(ref[a, b, 2] - zc) < limit

                ok_u, ju = _diff(ref, v, u, 0, 1, near(v, u + 1), near(v, u - 1))
                ok_v, jv = _diff(ref, v, u, 1, 0, near(v + 1, u), near(v - 1, u))
                if ok_u and ok_v:
                    n = np.cross(ju.astype(np.float64), jv.astype(np.float64))
                    denom = n @ ray
                    if np.linalg.norm(n) > 0 and abs(denom) > 0.05 * np.linalg.norm(
                        n
                    ) * np.linalg.norm(ray):
                        cand = (n @ p) / denom
                        if abs(cand - p[2]) < max_step:
                            d = cand
            out[v, u] = ray * d
    return out


def engine_frame(depth, intensity, fwd, bwd, intrinsics, params, t):
    """Frame ``t`` of :func:`fuse4d.fuse_sequence` (one iteration) composed from the oracles.

    The per-frame stages that have their own oracle tests (the segment-limited smoothing D~,
    the 3D bilateral, the noise estimates) are taken from fuse4d; tracking (Eq. 4), the outer
    sum of Eq. 5 with the temporal gate, hole filling (Eq. 6) and the ray output (A17) are the
    NumPy oracles above. Returns (points (H, W, 3) mm, support (H, W)).
    """
    from fuse4d import depth_to_points
    from fuse4d.bilateral import bilateral_filter_points
    from fuse4d.motion import estimate_depth_noise, estimate_noise_quad, motion_reference_depth

    p = params
    d_all = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    n = d_all.shape[0]

    def smoothed(d, sigma, quad):
        ref = motion_reference_depth(d, sigma=sigma, max_step=p.max_depth_step, noise_quad=quad)
        return depth_to_points(ref, intrinsics)

    frames = []
    for d, inten in zip(d_all, intensity, strict=True):
        pts = depth_to_points(d, intrinsics)
        quad = estimate_noise_quad(d)
        z_med = float(np.median(d[np.isfinite(d)]))
        smooth = smoothed(d, p.reference_sigma, quad)
        motion_ref = pts if p.motion_depth == "raw" else smoothed(d, p.motion_sigma, quad)
        sigma_d = max(p.sigma_distance, p.distance_noise_scale * quad * z_med**2)
        bil = bilateral_filter_points(
            pts,
            inten,
            radius=p.spatial_radius,
            sigma_distance=sigma_d,
            sigma_intensity=p.sigma_intensity,
            reference=smooth if p.bilateral == "residual" else None,
        )
        sigma0 = estimate_depth_noise(d, reference=smooth[..., 2])
        frames.append((pts, smooth, motion_ref, bil, quad, sigma0, z_med))
    first = max(0, t - p.past_frames)
    last = min(n - 1, t + p.future_frames)
    pts, smooth, _ref, bil_t, quad, sigma0, z_med = frames[t]
    if p.tracks == "composed" and p.quantize == "final":
        quads = [f[4] for f in frames]
        tracks = composed_track(
            fwd, bwd, d_all, t, first, last, p.fb_threshold, p.max_depth_step, quads
        )
    else:
        tracks = track(
            fwd,
            bwd,
            d_all,
            t,
            first,
            last,
            p.fb_threshold,
            p.max_depth_step,
            quad,
            p.quantize == "per_step",
        )
    if p.static_tracks and last > first:  # A33
        ref_z = np.stack([f[2][..., 2] for f in frames])
        tracks, static = static_tracks(tracks, ref_z, intensity, d_all[t], t, first, last, quad)
    else:
        static = None
    tw = np.arange(max(p.past_frames, p.future_frames) + 1, dtype=np.float64)
    weights = (
        np.ones_like(tw)
        if math.isinf(p.sigma_temporal)
        else np.exp(-(tw**2) / (2 * p.sigma_temporal**2))
    )
    bil_all = np.stack([f[3] for f in frames])
    ref_all = np.stack([f[2] for f in frames])
    gate = noise_gate(p.temporal_gate, sigma0, quad, p.min_gate_mm)
    base = np.full(bil_all.shape[1:], np.nan)
    from fuse4d.fusion import CURVATURE_MIN_BIAS  # a constant of the method, not the code

    out, support = fuse(
        bil_all,
        ref_all,
        tracks,
        t,
        first,
        last,
        weights,
        gate,
        trajectory={"frame": 0, "trajectory": 1, "quadratic": 2, "adaptive": 3}[p.base],
        base_out=base,
        noise=lambda z: max(sigma0, quad * z * z),
        min_bias=CURVATURE_MIN_BIAS,
        constant=static,
    )
    hole = np.isfinite(ref_all[t, ..., 2]) & (support < p.min_temporal_support)
    support = np.where(hole, 0, support)  # frames fused into the pixel: none below the minimum
    if p.base_smoothing > 0 and p.base != "frame" and not math.isinf(p.base_fine_limit):
        smooth_base(
            out,
            base,
            d_all[t],
            hole,
            p.base_smoothing,
            p.max_depth_step,
            quad,
            p.base_fine_limit,
        )
    out[hole] = bil_t[hole]
    if p.fill_holes and hole.any():
        frame_gate = max(p.temporal_gate * max(sigma0, quad * z_med**2), p.min_gate_mm)
        out, hole, _filled = fill_holes(
            out, pts, hole, p.fill_radius, p.sigma_fill, p.fill_passes, 3, frame_gate
        )
    if p.fill_fallback == "nan":
        out[hole] = np.nan
    if p.output == "ray":
        k = intrinsics
        out = project_to_rays(out, smooth, k.fx, k.fy, k.cx, k.cy, p.max_depth_step, quad)
    if p.static_smoothing > 0 and static is not None:  # A42
        target = motion_reference_depth(
            out[..., 2], sigma=p.static_smoothing, max_step=p.max_depth_step, noise_quad=quad
        )
        out = smooth_static(out, static, target, p.static_smoothing_limit * quad)
    return out, support


def smooth_static(points, static, target, limit_quad):
    """A42 oracle: each static pixel's point scaled along its ray so that its depth moves
    toward ``target`` by at most ``limit_quad * z^2`` mm; the others unchanged."""
    z = points[..., 2].astype(np.float64)
    ok = static & np.isfinite(z) & (z > 0) & np.isfinite(target)
    safe = np.where(ok, z, 1.0)
    limit = limit_quad * safe * safe
    moved = safe + np.clip(np.where(ok, target, safe) - safe, -limit, limit)
    scale = np.where(ok, moved / safe, 1.0)
    return (points * scale[..., None]).astype(points.dtype)
