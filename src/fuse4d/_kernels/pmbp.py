"""numba kernels of PatchMatch Belief Propagation (METHOD.md §2).

State of one solve (all float32, C-contiguous, allocated by ``fuse4d.flow.pmbp``):

- ``lab``   (H, W, K, 2): particles s_p^k = (du, dv) in px;
- ``una``   (H, W, K):    cached unary ψ1_p(s_p^k) (a particle's unary never changes);
- ``dis``   (H, W, K):    disbelief B_p^k = ψ1 + Σ incoming messages, as of p's last visit;
- ``found`` (H, W, 4, K): foundations F_{p\\q}^k of p toward its neighbour q in direction d
  (d = 0 up (r-1), 1 down (r+1), 2 left (c-1), 3 right (c+1); the opposite of d is d ^ 1).

The message from q = nbr_d(p) into p at label s is
``min_k λ·min(|s - s_q^k|², T) + found[q, d ^ 1, k]``.

Images: ``src4`` = I^t (the grid the flow lives on) and ``tgt4`` = I^{t+1} (sampled
bilinearly), each (H, W, 4) float32 with channels (I, ∂u I, ∂v I, unused) -- interleaved so
that one bilinear tap reads one cache line (the gradient channels are read only when α > 0);
``asw`` (H, W, (2ρ+1)²) the adaptive-support weights of each pixel's patch (0 off the image).

``cfg`` (float64 array) packs the scalar knobs, see ``_CFG_*``; ``roi`` (int64[4]) =
(row0, row1, col0, col1), half-open: only pixels inside are solved, and neighbours outside it do
not exist for the MRF.

One pixel update (refresh, propagation, random search, foundations) is ``_visit_pixel``,
shared by the sequential and the red-black sweep; the energy terms are inlined into it (numba
``inline="always"``), which removed ~2/3 of the run time (array-argument call overhead).

Randomness: a counter-based generator (splitmix64) keyed by (seed, level, iteration, phase,
pixel index), so every pixel draws the same numbers whatever the thread schedule.

Post-step: ``_fill_inconsistent_kernel`` replaces the pixels that fail the forward-backward
check by an edge-aware weighted median of the consistent ones (decision A23).
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit, njit_parallel, prange

# indices into the packed ``cfg`` vector
_CFG_ALPHA = 0  # gradient weight α
_CFG_TAU1 = 1  # intensity truncation τ1
_CFG_TAU2 = 2  # gradient truncation τ2
_CFG_BORDER = 3  # border cost β((1-α)τ1 + ατ2)
_CFG_LAMBDA = 4  # pairwise weight λ (per px²)
_CFG_TRUNC = 5  # pairwise truncation T_pw (px²)
_CFG_MAXMOT = 6  # max motion M (px)
_CFG_R0 = 7  # initial random-search radius (px)
_CFG_RMIN = 8  # minimal random-search radius (px)
_CFG_EARLY = 9  # 1.0: early termination of the patch cost
_CFG_INIT_RADIUS = 10  # random initial particles: uniform within this radius (px) ...
_CFG_INIT_CENTRED = 11  # ... of seeds[0] if 1.0, else of zero
_CFG_INSIDE = 12  # 1.0: labels must keep p + s inside the target image
_CFG_SEARCH_BEST = 13  # 1.0: random search around the best particle only
_CFG_SIZE = 14

_INF = np.inf
_DUP2 = 1e-6  # two labels closer than 1e-3 px are duplicates

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_TO_UNIT = 1.0 / 9007199254740992.0  # 2**-53


# --------------------------------------------------------------------------------------------
# random numbers


@njit(inline="always")
def _mix64(z):
    """splitmix64 finaliser (uint64 -> uint64)."""
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@njit
def _rng_key(seed, level, it, phase, pixel):
    """Per-pixel stream key from (seed, pyramid level, iteration, phase, pixel index)."""
    z = _mix64(np.uint64(seed) + _GOLDEN)
    z = _mix64(z ^ (np.uint64(level) * np.uint64(0x100000001B3) + np.uint64(it)))
    z = _mix64(z ^ (np.uint64(phase) * _GOLDEN))
    return _mix64(z ^ np.uint64(pixel))


@njit(inline="always")
def _uniform(state):
    """Next (state, u) with u uniform in [-1, 1)."""
    state = state + _GOLDEN
    z = _mix64(state)
    u = float(z >> _S11) * _TO_UNIT
    return state, 2.0 * u - 1.0


# --------------------------------------------------------------------------------------------
# energy terms


@njit(inline="always")
def _patch_cost(src4, tgt4, asw, r, c, su, sv, rho, cfg, bound):
    """ψ1_p(s): ASW-weighted truncated patch dissimilarity (METHOD §2.1), float32 arithmetic.

    ``src4`` / ``tgt4`` (H, W, 4): channels (I, ∂u I, ∂v I, unused) of I^t and I^{t+1}.
    Accumulated row by row; returns as soon as the partial sum exceeds ``bound`` (early
    termination, METHOD §2.5.3; pass ``inf`` for the full value). ``s`` is constant over the
    patch, so the bilinear weights are computed once; in the image interior the interpolation
    is separable (vertical blend of 2ρ+2 columns, then horizontal).
    """
    h = src4.shape[0]
    w = src4.shape[1]
    alpha = np.float32(cfg[_CFG_ALPHA])
    tau1 = np.float32(cfg[_CFG_TAU1])
    tau2 = np.float32(cfg[_CFG_TAU2])
    border = np.float32(cfg[_CFG_BORDER])
    bnd = np.float32(bound)
    one = np.float32(1.0)
    a_int = one - alpha
    x = c + su
    y = r + sv
    fx = math.floor(x)
    fy = math.floor(y)
    ix = int(fx)
    iy = int(fy)
    ax = np.float32(x - fx)
    ay = np.float32(y - fy)
    bx = one - ax
    by = one - ay
    acc = np.float32(0.0)
    j = 0
    if (
        r - rho >= 0
        and r + rho < h
        and c - rho >= 0
        and c + rho < w
        and iy - rho >= 0
        and iy + rho + 1 < h
        and ix - rho >= 0
        and ix + rho + 1 < w
    ):
        # fast path: patch and its bilinear footprint inside both images, no bounds checks
        if alpha > 0.0:
            for dy in range(-rho, rho + 1):
                ty = iy + dy
                qr = r + dy
                tx = ix - rho
                p0 = by * tgt4[ty, tx, 0] + ay * tgt4[ty + 1, tx, 0]
                p1 = by * tgt4[ty, tx, 1] + ay * tgt4[ty + 1, tx, 1]
                p2 = by * tgt4[ty, tx, 2] + ay * tgt4[ty + 1, tx, 2]
                for dx in range(-rho, rho + 1):
                    tx = ix + dx + 1
                    qc = c + dx
                    c0 = by * tgt4[ty, tx, 0] + ay * tgt4[ty + 1, tx, 0]
                    c1 = by * tgt4[ty, tx, 1] + ay * tgt4[ty + 1, tx, 1]
                    c2 = by * tgt4[ty, tx, 2] + ay * tgt4[ty + 1, tx, 2]
                    di = abs(src4[qr, qc, 0] - (bx * p0 + ax * c0))
                    gd = abs(src4[qr, qc, 1] - (bx * p1 + ax * c1))
                    gd += abs(src4[qr, qc, 2] - (bx * p2 + ax * c2))
                    acc += asw[r, c, j] * (a_int * min(di, tau1) + alpha * min(gd, tau2))
                    p0 = c0
                    p1 = c1
                    p2 = c2
                    j += 1
                if acc > bnd:
                    return acc
            return acc
        for dy in range(-rho, rho + 1):
            ty = iy + dy
            qr = r + dy
            p0 = by * tgt4[ty, ix - rho, 0] + ay * tgt4[ty + 1, ix - rho, 0]
            for dx in range(-rho, rho + 1):
                tx = ix + dx + 1
                c0 = by * tgt4[ty, tx, 0] + ay * tgt4[ty + 1, tx, 0]
                acc += asw[r, c, j] * min(abs(src4[qr, c + dx, 0] - (bx * p0 + ax * c0)), tau1)
                p0 = c0
                j += 1
            if acc > bnd:
                return acc
        return acc * a_int
    # general path: clipped patch, samples off the target image cost ``border``
    w00 = bx * by
    w01 = ax * by
    w10 = bx * ay
    w11 = ax * ay
    side = 2 * rho + 1
    for dy in range(-rho, rho + 1):
        qr = r + dy
        if qr < 0 or qr >= h:
            continue
        ty = iy + dy
        row_out = ty < 0 or ty > h - 1 or (ty == h - 1 and ay > 0.0)
        ty1 = min(ty + 1, h - 1)
        base = (dy + rho) * side + rho
        for dx in range(-rho, rho + 1):
            qc = c + dx
            if qc < 0 or qc >= w:
                continue
            wq = asw[r, c, base + dx]
            tx = ix + dx
            if row_out or tx < 0 or tx > w - 1 or (tx == w - 1 and ax > 0.0):
                acc += wq * border
                continue
            tx1 = min(tx + 1, w - 1)
            val = w00 * tgt4[ty, tx, 0] + w01 * tgt4[ty, tx1, 0]
            val += w10 * tgt4[ty1, tx, 0] + w11 * tgt4[ty1, tx1, 0]
            cost = a_int * min(abs(src4[qr, qc, 0] - val), tau1)
            if alpha > 0.0:
                gu = w00 * tgt4[ty, tx, 1] + w01 * tgt4[ty, tx1, 1]
                gu += w10 * tgt4[ty1, tx, 1] + w11 * tgt4[ty1, tx1, 1]
                gv = w00 * tgt4[ty, tx, 2] + w01 * tgt4[ty, tx1, 2]
                gv += w10 * tgt4[ty1, tx, 2] + w11 * tgt4[ty1, tx1, 2]
                gd = abs(src4[qr, qc, 1] - gu) + abs(src4[qr, qc, 2] - gv)
                cost += alpha * min(gd, tau2)
            acc += wq * cost
        if acc > bnd:
            return acc
    return acc


@njit(inline="always")
def _message(lab, found, qr, qc, dq, su, sv, lam, trunc):
    """m_{q→p}(s) = min_k λ·min(|s - s_q^k|², T) + F_{q\\p}^k, p = nbr_dq(q)."""
    best = _INF
    for k in range(lab.shape[2]):
        du = su - lab[qr, qc, k, 0]
        dv = sv - lab[qr, qc, k, 1]
        v = lam * min(du * du + dv * dv, trunc) + found[qr, qc, dq, k]
        if v < best:
            best = v
    return best


@njit(inline="always")
def _message_sum(lab, found, r, c, su, sv, lam, trunc, roi):
    """Σ_{q ∈ N4(p) ∩ roi} m_{q→p}(s)."""
    acc = 0.0
    if r > roi[0]:
        acc += _message(lab, found, r - 1, c, 1, su, sv, lam, trunc)
    if r < roi[1] - 1:
        acc += _message(lab, found, r + 1, c, 0, su, sv, lam, trunc)
    if c > roi[2]:
        acc += _message(lab, found, r, c - 1, 3, su, sv, lam, trunc)
    if c < roi[3] - 1:
        acc += _message(lab, found, r, c + 1, 2, su, sv, lam, trunc)
    return acc


@njit(inline="always")
def _neighbour(r, c, d, roi):
    """(exists, row, col) of the neighbour of (r, c) in direction d inside ``roi``."""
    if d == 0:
        return r > roi[0], r - 1, c
    if d == 1:
        return r < roi[1] - 1, r + 1, c
    if d == 2:
        return c > roi[2], r, c - 1
    return c < roi[3] - 1, r, c + 1


@njit(inline="always")
def _refresh(lab, una, dis, found, r, c, lam, trunc, roi):
    """Step 1: B_p^k = ψ1 (cached) + current messages, for every particle."""
    for k in range(lab.shape[2]):
        dis[r, c, k] = una[r, c, k] + _message_sum(
            lab, found, r, c, lab[r, c, k, 0], lab[r, c, k, 1], lam, trunc, roi
        )


@njit(inline="always")
def _cache_foundations(lab, dis, found, r, c, lam, trunc, roi):
    """Step 4: F_{p\\q}^k = B_p^k − m_{q→p}(s_p^k), shifted to min 0, for every neighbour q."""
    nk = lab.shape[2]
    for d in range(4):
        ok, qr, qc = _neighbour(r, c, d, roi)
        if not ok:
            continue
        lo = _INF
        for k in range(nk):
            f = dis[r, c, k] - _message(
                lab, found, qr, qc, d ^ 1, lab[r, c, k, 0], lab[r, c, k, 1], lam, trunc
            )
            found[r, c, d, k] = f
            if found[r, c, d, k] < lo:
                lo = found[r, c, d, k]  # the stored float32 value: the minimum becomes exactly 0
        for k in range(nk):
            found[r, c, d, k] -= lo


@njit(inline="always")
def _label_valid(r, c, su, sv, h, w, maxmot, inside):
    """|s| <= M and, if ``inside``, p + s within the target image."""
    if su * su + sv * sv > maxmot * maxmot:
        return False
    if not inside:
        return True
    x = c + su
    y = r + sv
    return 0.0 <= x <= w - 1.0 and 0.0 <= y <= h - 1.0


@njit(inline="always")
def _try_candidate(src4, tgt4, asw, lab, una, dis, found, r, c, su, sv, rho, cfg, roi):
    """Evaluate candidate label s' at p; replace the worst particle if B_p(s') is lower."""
    h = src4.shape[0]
    w = src4.shape[1]
    if not _label_valid(r, c, su, sv, h, w, cfg[_CFG_MAXMOT], cfg[_CFG_INSIDE] != 0.0):
        return False
    nk = lab.shape[2]
    worst_k = 0
    worst = -_INF
    for k in range(nk):
        du = lab[r, c, k, 0] - su
        dv = lab[r, c, k, 1] - sv
        if du * du + dv * dv < _DUP2:
            return False
        if dis[r, c, k] > worst:
            worst = dis[r, c, k]
            worst_k = k
    lam = cfg[_CFG_LAMBDA]
    trunc = cfg[_CFG_TRUNC]
    ms = _message_sum(lab, found, r, c, su, sv, lam, trunc, roi)
    bound = worst - ms
    if bound <= 0.0:
        return False
    if cfg[_CFG_EARLY] == 0.0:
        bound = _INF
    u = _patch_cost(src4, tgt4, asw, r, c, su, sv, rho, cfg, bound)
    if u + ms < worst:
        lab[r, c, worst_k, 0] = su
        lab[r, c, worst_k, 1] = sv
        una[r, c, worst_k] = u
        dis[r, c, worst_k] = u + ms
        return True
    return False


@njit(inline="always")
def _best_particle(dis, r, c):
    best_k = 0
    for k in range(1, dis.shape[2]):
        if dis[r, c, k] < dis[r, c, best_k]:
            best_k = k
    return best_k


@njit(inline="always")
def _propagate_from(src4, tgt4, asw, lab, una, dis, found, r, c, qr, qc, rho, cfg, roi):
    """Step 2 for one neighbour q: its min-disbelief particle is a candidate at p."""
    kq = _best_particle(dis, qr, qc)
    _try_candidate(
        src4, tgt4, asw, lab, una, dis, found, r, c,
        lab[qr, qc, kq, 0], lab[qr, qc, kq, 1], rho, cfg, roi,
    )  # fmt: skip


@njit
def _visit_pixel(
    src4, tgt4, asw, lab, una, dis, found, r, c, rho, cfg, roi, prop_mask,
    state, centres,
):  # fmt: skip
    """One PMBP update of pixel p = (r, c) (METHOD §2.3 steps 1-4).

    ``prop_mask`` bit d set: propagate from the neighbour in direction d (if it exists).
    ``state``: the pixel's random stream; ``centres`` (K, 2) scratch for the frozen centres.
    Shared by both schedules (compiled once; the energy terms are inlined into it).
    """
    lam = cfg[_CFG_LAMBDA]
    trunc = cfg[_CFG_TRUNC]
    nk = lab.shape[2]
    _refresh(lab, una, dis, found, r, c, lam, trunc, roi)  # 1.
    # 2. propagation
    for d in range(4):
        if (prop_mask >> d) & 1:
            ok, qr, qc = _neighbour(r, c, d, roi)
            if ok:
                _propagate_from(
                    src4, tgt4, asw, lab, una, dis, found, r, c, qr, qc, rho,
                    cfg, roi,
                )  # fmt: skip
    # 3. random search around frozen centres (every particle, or the best one only)
    for k in range(nk):
        centres[k, 0] = lab[r, c, k, 0]
        centres[k, 1] = lab[r, c, k, 1]
    k_lo = 0
    k_hi = nk
    if cfg[_CFG_SEARCH_BEST] != 0.0:
        k_lo = _best_particle(dis, r, c)
        k_hi = k_lo + 1
    rmin = cfg[_CFG_RMIN]
    for k in range(k_lo, k_hi):
        rad = cfg[_CFG_R0]
        while rad >= rmin:
            state, u1 = _uniform(state)
            state, u2 = _uniform(state)
            _try_candidate(
                src4, tgt4, asw, lab, una, dis, found, r, c,
                centres[k, 0] + rad * u1, centres[k, 1] + rad * u2, rho, cfg, roi,
            )  # fmt: skip
            rad *= 0.5
    # 4. foundations
    _cache_foundations(lab, dis, found, r, c, lam, trunc, roi)


# --------------------------------------------------------------------------------------------
# sweeps


@njit
def _sweep_sequential_kernel(src4, tgt4, asw, lab, una, dis, found, rho, cfg, roi, seed, level, it):
    """One reference sweep (METHOD §2.3): raster order by ``it % 4``, neighbours visited earlier
    in this sweep propagate."""
    w = src4.shape[1]
    direction = it % 4
    rows_up = direction == 0 or direction == 3  # rows increasing
    cols_up = direction == 0 or direction == 2  # cols increasing
    d_row = 0 if rows_up else 1  # direction of the previous row in scan order (up / down)
    d_col = 2 if cols_up else 3  # direction of the previous column (left / right)
    nr = roi[1] - roi[0]
    nc = roi[3] - roi[2]
    centres = np.empty((lab.shape[2], 2), dtype=np.float64)
    for ii in range(nr):
        r = roi[0] + ii if rows_up else roi[1] - 1 - ii
        for jj in range(nc):
            c = roi[2] + jj if cols_up else roi[3] - 1 - jj
            mask = 0
            if ii > 0:
                mask |= 1 << d_row
            if jj > 0:
                mask |= 1 << d_col
            state = _rng_key(seed, level, it, 0, r * w + c)
            _visit_pixel(
                src4, tgt4, asw, lab, una, dis, found, r, c, rho, cfg, roi,
                mask, state, centres,
            )  # fmt: skip


@njit_parallel
def _sweep_checkerboard_kernel(
    src4, tgt4, asw, lab, una, dis, found, rho, cfg, roi, seed, level, it,
    colour,
):  # fmt: skip
    """Half a parallel sweep: every pixel with (r + c) % 2 == colour, rows in parallel.

    Pixels of one colour read only the other colour's particles and foundations, so the result
    does not depend on the thread schedule. Each pixel propagates from all four neighbours.
    """
    w = src4.shape[1]
    nk = lab.shape[2]
    for ii in prange(roi[1] - roi[0]):
        r = roi[0] + ii
        centres = np.empty((nk, 2), dtype=np.float64)
        c = roi[2] if (r + roi[2]) % 2 == colour else roi[2] + 1
        while c < roi[3]:
            state = _rng_key(seed, level, it, 1 + colour, r * w + c)
            _visit_pixel(
                src4, tgt4, asw, lab, una, dis, found, r, c, rho, cfg, roi,
                15, state, centres,
            )  # fmt: skip
            c += 2


@njit_parallel
def _sweep_lines_kernel(
    src4, tgt4, asw, lab, una, dis, found, rho, cfg, roi, seed, level, it, parity
):  # fmt: skip
    """Half a line-parallel sweep: every row (``it`` even) or column (``it`` odd) whose index
    has the given ``parity`` is scanned sequentially, lines in parallel.

    Along a line the scan runs forward for ``it % 4`` in (0, 1), backward otherwise, and each
    pixel propagates from the pixel it just left (same thread) and from its two neighbours on
    the adjacent lines, which have the other parity and are not written during this phase:
    the result does not depend on the thread schedule, and labels travel a whole line per
    sweep as in the sequential reference (GPU PatchMatch style alternating passes).
    """
    w = src4.shape[1]
    nk = lab.shape[2]
    horizontal = it % 2 == 0
    forward = it % 4 < 2
    if horizontal:
        lo, hi = roi[0], roi[1]
        length = roi[3] - roi[2]
        d_prev = 2 if forward else 3  # left / right neighbour was visited just before
        perp = (1 << 0) | (1 << 1)
    else:
        lo, hi = roi[2], roi[3]
        length = roi[1] - roi[0]
        d_prev = 0 if forward else 1  # up / down
        perp = (1 << 2) | (1 << 3)
    first = lo if (lo % 2) == parity else lo + 1
    n_lines = max(0, (hi - first + 1) // 2)
    for li in prange(n_lines):
        line = first + 2 * li
        centres = np.empty((nk, 2), dtype=np.float64)
        for jj in range(length):
            pos = jj if forward else length - 1 - jj
            if horizontal:
                r = line
                c = roi[2] + pos
            else:
                r = roi[0] + pos
                c = line
            mask = perp
            if jj > 0:
                mask |= 1 << d_prev
            state = _rng_key(seed, level, it, 4 + parity, r * w + c)
            _visit_pixel(
                src4, tgt4, asw, lab, una, dis, found, r, c, rho, cfg, roi, mask, state,
                centres,
            )  # fmt: skip


# --------------------------------------------------------------------------------------------
# set-up and read-out


@njit
def _exp_tables(guide, inv):
    """(ok, e_pos, e_neg): e_pos = exp((Ī − min Ī)·inv), e_neg = 1 / e_pos per pixel (float64),
    so that exp(−|Ī(p) − Ī(q)|·inv) = e_neg[p]·e_pos[q] if Ī(q) <= Ī(p), else e_pos[p]·e_neg[q]
    -- two exp per pixel instead of one per pair. ``ok`` is False (tables not filled) when the
    intensity range would overflow them; callers then evaluate exp directly."""
    h, w = guide.shape
    g_lo = np.inf
    g_hi = -np.inf
    for r in range(h):
        for c in range(w):
            g_lo = min(g_lo, guide[r, c])
            g_hi = max(g_hi, guide[r, c])
    ok = h * w > 0 and (g_hi - g_lo) * inv < 300.0
    e_pos = np.ones((h, w), dtype=np.float64)
    e_neg = np.ones((h, w), dtype=np.float64)
    if ok:
        for r in range(h):
            for c in range(w):
                t = (guide[r, c] - g_lo) * inv
                e_pos[r, c] = math.exp(t)
                e_neg[r, c] = math.exp(-t)
    return ok, e_pos, e_neg


@njit_parallel
def _asw_kernel(guide, rho, gamma, roi, out):
    """out[p, j] = exp(−|Ī(p) − Ī(q_j)| / γ) for the (2ρ+1)² patch offsets q_j; 0 off-image
    (products of :func:`_exp_tables`, not one exp per weight)."""
    h, w = guide.shape
    side = 2 * rho + 1
    inv = 1.0 / gamma
    tables, e_pos, e_neg = _exp_tables(guide, inv)
    for r in prange(roi[0], roi[1]):
        for c in range(roi[2], roi[3]):
            g = guide[r, c]
            for dy in range(-rho, rho + 1):
                qr = r + dy
                for dx in range(-rho, rho + 1):
                    qc = c + dx
                    j = (dy + rho) * side + dx + rho
                    if qr < 0 or qr >= h or qc < 0 or qc >= w:
                        out[r, c, j] = 0.0
                    elif not tables:
                        out[r, c, j] = math.exp(-abs(g - guide[qr, qc]) * inv)
                    elif guide[qr, qc] <= g:
                        out[r, c, j] = e_neg[r, c] * e_pos[qr, qc]
                    else:
                        out[r, c, j] = e_pos[r, c] * e_neg[qr, qc]


@njit_parallel
def _init_kernel(src4, tgt4, asw, seeds, lab, una, dis, found, rho, cfg, roi, seed, level):
    """Initial particles: the seed labels ``seeds`` (S, H, W, 2) first (invalid and duplicate ones
    dropped; if more than K remain, the K with the lowest unary are kept), then uniform random
    labels in the box ±``cfg[_CFG_INIT_RADIUS]`` around zero (or around ``seeds[0]``),
    redrawn until valid. B = ψ1, foundations 0."""
    h = src4.shape[0]
    w = src4.shape[1]
    nk = lab.shape[2]
    maxmot = cfg[_CFG_MAXMOT]
    inside = cfg[_CFG_INSIDE] != 0.0
    for r in prange(roi[0], roi[1]):
        for c in range(roi[2], roi[3]):
            for d in range(4):
                for k in range(nk):
                    found[r, c, d, k] = 0.0
            n = 0
            for s in range(seeds.shape[0]):
                su = seeds[s, r, c, 0]
                sv = seeds[s, r, c, 1]
                if not _label_valid(r, c, su, sv, h, w, maxmot, inside):
                    continue
                dup = False
                for k in range(n):
                    du = lab[r, c, k, 0] - su
                    dv = lab[r, c, k, 1] - sv
                    if du * du + dv * dv < _DUP2:
                        dup = True
                if dup:
                    continue
                u = _patch_cost(src4, tgt4, asw, r, c, su, sv, rho, cfg, _INF)
                slot = n
                if n == nk:
                    slot = 0
                    for k in range(1, nk):
                        if una[r, c, k] > una[r, c, slot]:
                            slot = k
                    if u >= una[r, c, slot]:
                        continue
                else:
                    n += 1
                lab[r, c, slot, 0] = su
                lab[r, c, slot, 1] = sv
                una[r, c, slot] = u
            state = _rng_key(seed, level, 0, 3, r * w + c)
            rad = cfg[_CFG_INIT_RADIUS]
            cu = 0.0
            cv = 0.0
            if cfg[_CFG_INIT_CENTRED] != 0.0:
                cu = seeds[0, r, c, 0]
                cv = seeds[0, r, c, 1]
            lo_u = max(max(-maxmot, cu - rad), -float(c))
            hi_u = max(min(min(maxmot, cu + rad), w - 1.0 - c), lo_u)
            lo_v = max(max(-maxmot, cv - rad), -float(r))
            hi_v = max(min(min(maxmot, cv + rad), h - 1.0 - r), lo_v)
            tries = 0
            while n < nk:
                state, a = _uniform(state)
                state, b = _uniform(state)
                su = lo_u + 0.5 * (a + 1.0) * (hi_u - lo_u)
                sv = lo_v + 0.5 * (b + 1.0) * (hi_v - lo_v)
                tries += 1
                if not _label_valid(r, c, su, sv, h, w, maxmot, inside) and tries < 1000:
                    continue
                if tries >= 1000:
                    su = 0.0
                    sv = 0.0
                lab[r, c, n, 0] = su
                lab[r, c, n, 1] = sv
                una[r, c, n] = _patch_cost(src4, tgt4, asw, r, c, su, sv, rho, cfg, _INF)
                n += 1
            for k in range(nk):
                dis[r, c, k] = una[r, c, k]


@njit_parallel
def _best_label_kernel(lab, dis, roi, out):
    """out[p] = the min-disbelief particle inside ``roi``; ``out`` is pre-filled outside."""
    for r in prange(roi[0], roi[1]):
        for c in range(roi[2], roi[3]):
            k = _best_particle(dis, r, c)
            out[r, c, 0] = lab[r, c, k, 0]
            out[r, c, 1] = lab[r, c, k, 1]


# --------------------------------------------------------------------------------------------
# post-step: edge-aware fill of forward-backward inconsistent pixels


@njit(inline="always")
def _partition_below(vals, wts, lo, hi, pivot, strict):
    """Move the elements of ``[lo, hi]`` below ``pivot`` (``strict``: < pivot, else <= pivot)
    to the front; returns (first index not moved, their total weight). Branch-free body (the
    comparisons are data-dependent, so branches would mispredict half the time)."""
    st = lo
    acc = 0.0
    for i in range(lo, hi + 1):
        v = vals[i]
        wv = wts[i]
        take = (v < pivot) if strict else (v <= pivot)
        vals[i] = vals[st]
        wts[i] = wts[st]
        vals[st] = v
        wts[st] = wv
        st += take
        acc += wv * take
    return st, acc


@njit(inline="always")
def _weighted_median(vals, wts, m, target):
    """Value of the first element, in ascending value order, at which the cumulative weight of
    ``vals[:m]`` reaches ``target`` (the weighted median for ``target`` = half the total).

    Weighted quickselect (median-of-three pivot; one pass for < pivot, one for == pivot),
    expected O(m) instead of a sort; ``vals`` and ``wts`` are permuted in place. Requires
    0 < target <= Σ wts[:m].
    """
    lo = 0
    hi = m - 1
    cum = 0.0  # weight of the elements already known to lie below [lo, hi]
    while lo < hi:
        a = vals[lo]
        b = vals[(lo + hi) >> 1]
        c = vals[hi]
        if a > b:
            a, b = b, a
        if b > c:
            b = c
        pivot = max(a, b)  # median of the three, one of the values in [lo, hi]
        st, w_lt = _partition_below(vals, wts, lo, hi, pivot, True)
        if cum + w_lt >= target:
            hi = st - 1
            continue
        cum += w_lt
        st, w_eq = _partition_below(vals, wts, st, hi, pivot, False)
        if cum + w_eq >= target:
            return pivot
        cum += w_eq
        lo = st
    return vals[lo]


@njit_parallel
def _fill_inconsistent_kernel(flow, valid, guide, radius, inv_sigma_i, inv_2sigma_s2, out):
    """Replace every pixel with ``valid[p] == False`` by the weighted median of the consistent
    pixels q within the (2·radius+1)² window, weights
    exp(−|Ī(p) − Ī(q)| · inv_sigma_i − |p − q|² · inv_2sigma_s2), per component (du, dv).

    ``flow`` / ``out`` (H, W, 2) float32 (``out`` pre-filled with ``flow``); ``valid`` (H, W)
    bool; ``guide`` (H, W) float32 intensity. Reads only ``flow`` (never ``out``), so the result
    does not depend on the thread schedule. A pixel with no consistent pixel in its window keeps
    its value. The median is found by weighted quickselect (:func:`_weighted_median`) instead
    of two sorts, and the weights are products of :func:`_exp_tables` entries and a table of
    the spatial factor instead of one exp each (issue 13: 1.75 → 0.40 CPU s for the two fills
    of a real 640x480 pair with 18 % of its pixels inconsistent).
    """
    h, w = valid.shape
    side = 2 * radius + 1
    spatial = np.empty(side * side, dtype=np.float64)
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            spatial[(dy + radius) * side + dx + radius] = math.exp(
                -(dx * dx + dy * dy) * inv_2sigma_s2
            )
    tables, e_pos, e_neg = _exp_tables(guide, inv_sigma_i)
    for r in prange(h):
        vals0 = np.empty(side * side, dtype=np.float32)
        vals1 = np.empty(side * side, dtype=np.float32)
        wts0 = np.empty(side * side, dtype=np.float64)
        wts1 = np.empty(side * side, dtype=np.float64)
        for c in range(w):
            if valid[r, c]:
                continue
            g = guide[r, c]
            m = 0
            total = 0.0
            for dy in range(-radius, radius + 1):
                qr = r + dy
                if qr < 0 or qr >= h:
                    continue
                base = (dy + radius) * side + radius
                for dx in range(-radius, radius + 1):
                    qc = c + dx
                    if qc < 0 or qc >= w or not valid[qr, qc]:
                        continue
                    gq = guide[qr, qc]
                    if not tables:
                        wt = math.exp(-abs(g - gq) * inv_sigma_i)
                    elif gq <= g:
                        wt = e_neg[r, c] * e_pos[qr, qc]
                    else:
                        wt = e_pos[r, c] * e_neg[qr, qc]
                    wt *= spatial[base + dx]
                    vals0[m] = flow[qr, qc, 0]
                    vals1[m] = flow[qr, qc, 1]
                    wts0[m] = wt
                    wts1[m] = wt
                    total += wt
                    m += 1
            if m == 0 or total <= 0.0:
                continue
            out[r, c, 0] = _weighted_median(vals0, wts0, m, 0.5 * total)
            out[r, c, 1] = _weighted_median(vals1, wts1, m, 0.5 * total)
