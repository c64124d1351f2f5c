"""PMBP flow: kernels vs the NumPy oracle, known motions, determinism, schedules, params."""

from __future__ import annotations

import dataclasses

import cv2
import numba
import numpy as np
import pytest

from fuse4d import ShapeError
from fuse4d._kernels import pmbp as K
from fuse4d.experiments.flow_accuracy import ball_pairs
from fuse4d.flow import estimate_flow
from fuse4d.flow.pmbp import (
    PMBP_FAST,
    PMBPFastParams,
    PMBPParams,
    _asw_weights,
    _config,
    _consistent,
    _fill_inconsistent,
    pmbp_flow,
    pmbp_flow_fast,
    pmbp_flow_pair,
    register,
)
from naive import pmbp as naive


def _texture(h, w, shift=(0.0, 0.0), seed=0):
    """Analytic sum-of-sinusoids texture in [0, 1], sampled at (col − du, row − dv).

    ``_texture(..., shift=d)`` is image1 of a pair whose true flow is ``d`` everywhere:
    image0(p) = image1(p + d).
    """
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = cols - shift[0], rows - shift[1]
    img = np.zeros((h, w))
    for _ in range(12):
        ang = rng.uniform(0, np.pi)
        lam = rng.uniform(8.0, 24.0)  # smooth enough for bilinear sampling
        k = 2 * np.pi / lam
        img += np.sin(k * (np.cos(ang) * x + np.sin(ang) * y) + rng.uniform(0, 2 * np.pi))
    img = 0.5 + 0.15 * img / img.std()
    return np.clip(img, 0, 1).astype(np.float32)


def _pair(h, w, d, noise=0.0, seed=0):
    a, b = _texture(h, w, seed=seed), _texture(h, w, shift=d, seed=seed)
    if noise:
        rng = np.random.default_rng(seed + 100)
        a = np.clip(a + rng.normal(0, noise, a.shape), 0, 1).astype(np.float32)
        b = np.clip(b + rng.normal(0, noise, b.shape), 0, 1).astype(np.float32)
    return a, b


def _interleave(image, gu=None, gv=None):
    """(H, W, 4) float32 kernel layout: intensity, ∂u, ∂v, unused."""
    out = np.zeros((*image.shape, 4), np.float32)
    out[..., 0] = image
    if gu is not None:
        out[..., 1] = gu
        out[..., 2] = gv
    return out


def _epe(flow, d, margin):
    e = np.hypot(flow[..., 0] - d[0], flow[..., 1] - d[1])
    return float(e[margin:-margin, margin:-margin].mean())


SMALL = PMBPParams(num_particles=2, num_iter=3, pyramid_levels=2)
#: no forward-backward fill, no variational refinement: the PMBP solve alone
RAW = {"consistency_check": False, "variational_refinement_iterations": 0}


# ------------------------------------------------------------------------------------------
# kernels vs the naive oracle


@pytest.fixture
def tiny():
    """A 9x11 random grid with random particles, foundations and weights."""
    rng = np.random.default_rng(3)
    h, w, k = 9, 11, 3
    src = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.0)
    tgt = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.0)
    lab = rng.uniform(-2, 2, (h, w, k, 2)).astype(np.float32)
    found = rng.uniform(0, 1, (h, w, 4, k)).astype(np.float32)
    dis = rng.uniform(0, 3, (h, w, k)).astype(np.float32)
    return src, tgt, lab, found, dis


def test_asw_weights_match_oracle(tiny):
    src = tiny[0]
    p = PMBPParams(patch_radius=2, asw_gamma=0.1)
    roi = np.array([0, src.shape[0], 0, src.shape[1]], np.int64)
    got = _asw_weights(src, p, roi)
    guide = cv2.medianBlur(src, 3)
    np.testing.assert_allclose(got, naive.asw_weights(guide, 2, 0.1), rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("alpha", [0.0, 0.4])
@pytest.mark.parametrize(
    ("r", "c", "s"),
    [(4, 5, (0.3, -0.7)), (1, 1, (1.5, 0.25)), (8, 10, (-0.5, -2.0)), (4, 5, (4.6, 0.0))],
)
def test_patch_cost_matches_oracle(tiny, alpha, r, c, s):
    src, tgt = tiny[0], tiny[1]
    p = PMBPParams(gradient_weight=alpha, trunc_intensity=0.1, trunc_gradient=0.05)
    roi = np.array([0, src.shape[0], 0, src.shape[1]], np.int64)
    asw = _asw_weights(src, p, roi)
    cfg = _config(p, 1.0, True)
    gv0, gu0 = np.gradient(src)
    gv1, gu1 = np.gradient(tgt)
    grads = [np.ascontiguousarray(g, np.float32) for g in (gu0, gv0, gu1, gv1)]
    src4, tgt4 = _interleave(src, *grads[:2]), _interleave(tgt, *grads[2:])
    got = K._patch_cost(src4, tgt4, asw, r, c, *s, 2, cfg, np.inf)
    border = cfg[K._CFG_BORDER]
    want = naive.patch_cost(
        src, tgt, asw, r, c, s, rho=2, tau1=0.1, tau2=0.05, border=border, alpha=alpha, grads=grads
    )
    assert got == pytest.approx(want, rel=1e-5, abs=1e-6)
    # early termination returns a value above the bound, never below the true cost
    bounded = K._patch_cost(src4, tgt4, asw, r, c, *s, 2, cfg, want / 3)
    assert want / 3 < bounded <= want + 1e-5


def test_message_and_disbelief_match_oracle(tiny):
    _, _, lab, found, _ = tiny
    h, w = lab.shape[:2]
    roi = np.array([0, h, 0, w], np.int64)
    lam, trunc = 0.7, 2.5
    rng = np.random.default_rng(5)
    for r, c in [(0, 0), (4, 5), (8, 10), (0, 6), (5, 0)]:
        s = rng.uniform(-2, 2, 2)
        got = K._message_sum(lab, found, r, c, s[0], s[1], lam, trunc, roi)
        assert got == pytest.approx(naive.message_sum(lab, found, r, c, s, lam, trunc), rel=1e-6)
        una = np.zeros(lab.shape[:3], np.float32) + 0.25
        dis = np.zeros(lab.shape[:3], np.float32)
        K._refresh(lab, una, dis, found, r, c, lam, trunc, roi)
        for k in range(lab.shape[2]):
            want = naive.disbelief(0.25, lab, found, r, c, lab[r, c, k], lam, trunc)
            assert dis[r, c, k] == pytest.approx(want, rel=1e-5)


def test_foundation_update_matches_oracle(tiny):
    _, _, lab, found, dis = tiny
    h, w = lab.shape[:2]
    roi = np.array([0, h, 0, w], np.int64)
    lam, trunc = 0.7, 2.5
    for r, c in [(0, 0), (4, 5), (8, 10), (3, 10)]:
        want = naive.foundations(lab, dis, found, r, c, lam, trunc)
        got = found.copy()
        K._cache_foundations(lab, dis, got, r, c, lam, trunc, roi)
        np.testing.assert_allclose(got[r, c], want, rtol=1e-5, atol=1e-6)
        present = [d for d, *_ in naive.neighbours(r, c, (h, w))]
        assert np.all(got[r, c, present].min(axis=1) == 0.0)
        # only p's own foundations change
        mask = np.ones((h, w), bool)
        mask[r, c] = False
        np.testing.assert_array_equal(got[mask], found[mask])


@pytest.mark.parametrize("worst_value", [20.0, 2.0])
@pytest.mark.parametrize("cand", [(0.2, -0.3), (1.7, 0.9), (-1.1, 1.4)])
def test_candidate_acceptance_matches_oracle(tiny, cand, worst_value):
    """A candidate replaces the worst particle iff ψ1(s') + Σ m(s') < max_k B^k (METHOD §2.3)."""
    src, tgt, lab, found, dis = (x.copy() for x in tiny)
    h, w = src.shape
    r, c = 4, 5
    dis[r, c] = [1.0, worst_value, 0.5]  # B(s') is 5-10 here: accepted against 20, not 2
    p = PMBPParams(pairwise_weight=0.7, pairwise_trunc=2.5, gradient_weight=0.0)
    roi = np.array([0, h, 0, w], np.int64)
    asw = _asw_weights(src, p, roi)
    cfg = _config(p, 1.0, True)
    una = np.zeros((h, w, lab.shape[2]), np.float32)
    before = (lab.copy(), dis.copy())
    unary = naive.patch_cost(src, tgt, asw, r, c, cand, rho=2, tau1=0.3, border=cfg[3])
    b_new = naive.disbelief(unary, lab, found, r, c, cand, 0.7, 2.5)
    worst = int(np.argmax(dis[r, c]))
    accepted = K._try_candidate(
        _interleave(src), _interleave(tgt), asw, lab, una, dis, found, r, c, *cand, 2, cfg, roi
    )
    assert accepted == (b_new < before[1][r, c, worst])
    assert accepted == (worst_value == 20.0)
    if accepted:
        np.testing.assert_allclose(lab[r, c, worst], cand, rtol=1e-6)
        assert dis[r, c, worst] == pytest.approx(b_new, rel=1e-5)
        assert una[r, c, worst] == pytest.approx(unary, rel=1e-5, abs=1e-6)
        others = [k for k in range(lab.shape[2]) if k != worst]
        np.testing.assert_array_equal(lab[r, c, others], before[0][r, c, others])
    else:
        np.testing.assert_array_equal(lab, before[0])
        np.testing.assert_array_equal(dis, before[1])


def test_roi_removes_neighbours(tiny):
    _, _, lab, found, _ = tiny
    roi = np.array([4, 9, 5, 11], np.int64)  # (4, 5) is the roi's top-left corner
    full = naive.message_sum(lab, found, 4, 5, (0.1, 0.2), 1.0, 3.0)
    up = naive.message(lab, found, 3, 5, 1, (0.1, 0.2), 1.0, 3.0)
    left = naive.message(lab, found, 4, 4, 3, (0.1, 0.2), 1.0, 3.0)
    got = K._message_sum(lab, found, 4, 5, 0.1, 0.2, 1.0, 3.0, roi)
    assert got == pytest.approx(full - up - left, rel=1e-5)


def test_solution_lowers_the_energy():
    """The PMBP field has lower MRF energy (naive oracle) than zero flow and the true shift."""
    a, b = _pair(20, 22, (0.6, -0.4), noise=0.03, seed=2)
    p = PMBPParams(
        num_particles=3,
        num_iter=4,
        pairwise_weight=0.5,
        gradient_weight=0.0,
        presmooth_sigma=0.0,
        pyramid_levels=1,
        **RAW,  # the MRF solve itself: the post-steps do not minimise this energy
    )
    flow = pmbp_flow(a, b, p)
    roi = np.array([0, 20, 0, 22], np.int64)
    asw = _asw_weights(a, p, roi)
    border = _config(p, 1.0, True)[K._CFG_BORDER]

    def unary(r, c, s):
        return naive.patch_cost(a, b, asw, r, c, s, rho=2, tau1=0.3, border=border)

    e_pmbp = naive.energy(flow, unary, 0.5, 4.0)
    truth = np.broadcast_to(np.float32([0.6, -0.4]), flow.shape).copy()
    assert e_pmbp < naive.energy(np.zeros_like(flow), unary, 0.5, 4.0)
    assert e_pmbp < naive.energy(truth, unary, 0.5, 4.0) * 1.02


# ------------------------------------------------------------------------------------------
# known motions


@pytest.mark.parametrize("schedule", ["lines", "parallel", "sequential"])
def test_zero_motion_gives_zero_flow(schedule):
    a = _texture(48, 56)
    flow = pmbp_flow(a, a, dataclasses.replace(SMALL, schedule=schedule))
    assert flow.shape == (48, 56, 2)
    assert flow.dtype == np.float32
    np.testing.assert_array_equal(flow, 0.0)


@pytest.mark.parametrize("d", [(0.4, -0.7), (1.25, 0.5), (-2.3, 1.6)])
def test_subpixel_translation_recovered(d):
    a, b = _pair(80, 80, d)
    flow = pmbp_flow(a, b)
    assert _epe(flow, d, 10) < 0.1
    assert np.median(np.abs(flow[10:-10, 10:-10] - np.float32(d))) < 0.05


def test_fast_preset_translation():
    a, b = _pair(80, 80, (1.4, -0.9), noise=0.02)
    flow = pmbp_flow_fast(a, b)
    assert _epe(flow, (1.4, -0.9), 10) < 0.2
    assert PMBP_FAST.num_particles == 1
    assert isinstance(PMBP_FAST, PMBPParams)


@pytest.mark.parametrize("post", [True, False])
@pytest.mark.parametrize("schedule", ["lines", "parallel"])
@pytest.mark.parametrize("levels", [1, 2])
def test_parallel_agrees_with_sequential_schedule(schedule, levels, post):
    d = (1.1, -0.6)
    a, b = _pair(64, 72, d, noise=0.01, seed=4)
    base = PMBPParams(num_particles=2, num_iter=4, pyramid_levels=levels, coarse_num_iter=3)
    if not post:  # the solver alone, without the post-steps that could hide a difference
        base = dataclasses.replace(base, **RAW)
    e_par = _epe(pmbp_flow(a, b, dataclasses.replace(base, schedule=schedule)), d, 8)
    e_seq = _epe(pmbp_flow(a, b, dataclasses.replace(base, schedule="sequential")), d, 8)
    assert e_par < 0.15
    assert e_seq < 0.15
    assert abs(e_par - e_seq) < 0.05


# ------------------------------------------------------------------------------------------
# determinism, warm start, roi


@pytest.mark.parametrize("schedule", ["lines", "parallel", "sequential"])
def test_deterministic_for_a_fixed_seed(schedule):
    a, b = _pair(40, 44, (0.7, 0.3), noise=0.05, seed=1)
    p = dataclasses.replace(SMALL, schedule=schedule, seed=7)
    first = pmbp_flow(a, b, p)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        second = pmbp_flow(a, b, p)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(first, second)
    other = pmbp_flow(a, b, dataclasses.replace(p, seed=8))
    assert not np.array_equal(first, other)


def test_seed_beyond_int64_is_a_parameter_error():
    """seed=2**63 was an OverflowError and 2**64 a numba TypingError inside the solve, both
    reported as internal errors; the largest int64 seed runs."""
    from fuse4d.errors import ParameterError

    for seed in (2**63, 2**64):
        with pytest.raises(ParameterError, match=r"PMBPParams\.seed must be an integer in"):
            PMBPParams(seed=seed)
    a, b = _pair(12, 14, (0.5, 0.0))
    flow = pmbp_flow(a, b, dataclasses.replace(SMALL, seed=2**63 - 1, pyramid_levels=1))
    assert np.isfinite(flow).all()


def test_warm_start_is_used():
    d = (2.6, -1.3)
    a, b = _pair(40, 40, d)
    init = np.broadcast_to(np.float32(d), (40, 40, 2)).copy()
    p = PMBPParams(num_particles=1, num_iter=0, pyramid_levels=1, **RAW)
    np.testing.assert_array_equal(pmbp_flow(a, b, p, init)[6:-6, 6:-6], init[6:-6, 6:-6])
    # without it, zero-iteration K=1 is the zero seed
    assert np.abs(pmbp_flow(a, b, p)[6:-6, 6:-6]).max() == 0.0


def test_roi_restricts_the_solve():
    d = (0.8, 0.5)
    a, b = _pair(48, 60, d)
    p = dataclasses.replace(SMALL, roi=(10, 40, 12, 50))
    flow = pmbp_flow(a, b, p)
    outside = np.ones((48, 60), bool)
    outside[10:40, 12:50] = False
    assert np.all(flow[outside] == 0.0)
    assert _epe(flow[10:40, 12:50], d, 4) < 0.1


# ------------------------------------------------------------------------------------------
# parameters and input errors


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("num_particles", 0, "num_particles"),
        ("num_particles", 2.0, "num_particles"),
        ("patch_radius", -1, "patch_radius"),
        ("gradient_weight", 1.5, "gradient_weight"),
        ("asw_gamma", 0.0, "asw_gamma"),
        ("pairwise_weight", -1.0, "pairwise_weight"),
        ("max_motion", float("nan"), "max_motion"),
        ("num_iter", -1, "num_iter"),
        ("pyramid_levels", 0, "pyramid_levels"),
        ("schedule", "random", "schedule"),
        ("roi", (5, 2, 0, 4), "roi"),
        ("roi", (0, 4, 0), "roi"),
        ("seed", -3, "seed"),
        ("consistency_threshold", 0.0, "consistency_threshold"),
        ("fill_radius", 0, "fill_radius"),
        ("fill_sigma_intensity", -1.0, "fill_sigma_intensity"),
        ("variational_refinement_iterations", -1, "variational_refinement_iterations"),
        ("variational_refinement_sor_iterations", 0, "variational_refinement_sor_iterations"),
        ("variational_refinement_alpha", float("inf"), "variational_refinement_alpha"),
    ],
)
def test_params_validation(field, value, match):
    with pytest.raises(ValueError, match=match):
        PMBPParams(**{field: value})


@pytest.mark.parametrize("field", ["early_termination", "inside_target", "consistency_check"])
def test_params_bool_type(field):
    with pytest.raises(TypeError, match=field):
        PMBPParams(**{field: 1})


def test_fast_params_defaults():
    p = PMBPFastParams(num_iter=1)
    assert p.num_particles == 1
    assert p.num_iter == 1
    assert PMBPParams().num_particles == 3


def test_input_errors():
    a = _texture(20, 20)
    with pytest.raises(ShapeError, match="image1"):
        pmbp_flow(a, a[:10])
    with pytest.raises(ShapeError, match="image0"):
        pmbp_flow(np.stack([a, a]), a)
    with pytest.raises(ShapeError, match="init"):
        pmbp_flow(a, a, init=np.zeros((20, 20, 3), np.float32))
    with pytest.raises(ValueError, match="NaN"):
        pmbp_flow(np.full((20, 20), np.nan, np.float32), a)
    with pytest.raises(ValueError, match="roi"):
        pmbp_flow(a, a, PMBPParams(roi=(0, 30, 0, 10)))
    with pytest.raises(TypeError, match="PMBPParams"):
        pmbp_flow(a, a, {"num_particles": 1})


def test_registered_with_flow_module():
    register()
    d = (0.5, -0.5)
    a, b = _pair(64, 64, d)
    flow = estimate_flow(a, b, method="pmbp-fast")  # solved at half resolution
    assert _epe(flow, d, 8) < 0.15
    flow = estimate_flow(a, b, method="pmbp", params=SMALL)
    assert _epe(flow, d, 8) < 0.1


# ------------------------------------------------------------------------------------------
# post-steps: forward-backward check + edge-aware fill, variational refinement


def _occlusion_pair(h=96, w=96, d_bg=(0.5, 0.3), d_fg=(5.0, 0.0), box=(32, 64, 30, 62)):
    """A textured square moving by ``d_fg`` over a background moving by ``d_bg``: the square
    covers background pixels of image0 (occlusions). Returns image0, image1, true flow."""
    bg0, bg1 = _texture(h, w, seed=1), _texture(h, w, shift=d_bg, seed=1)
    fg0, fg1 = _texture(h, w, seed=2), _texture(h, w, shift=d_fg, seed=2)
    rows, cols = np.mgrid[0:h, 0:w]
    r0, r1, c0, c1 = box
    in0 = (rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)
    in1 = (
        (rows >= r0 + d_fg[1])
        & (rows < r1 + d_fg[1])
        & (cols >= c0 + d_fg[0])
        & (cols < c1 + d_fg[0])
    )
    truth = np.empty((h, w, 2), np.float32)
    truth[...] = d_bg
    truth[in0] = d_fg
    a = np.where(in0, fg0, bg0).astype(np.float32)
    b = np.where(in1, fg1, bg1).astype(np.float32)
    return a, b, truth


def _field_epe(flow, truth, margin=8):
    err = np.hypot(*(flow - truth).transpose(2, 0, 1))
    return float(err[margin:-margin, margin:-margin].mean())


def _naive_fill(flow, valid, guide, radius, sigma_i, sigma_s):
    """Pure-NumPy oracle of the fill: per-component weighted median of consistent pixels."""
    h, w = valid.shape
    out = flow.copy()
    for r, c in zip(*np.nonzero(~valid), strict=True):
        r0, r1 = max(r - radius, 0), min(r + radius + 1, h)
        c0, c1 = max(c - radius, 0), min(c + radius + 1, w)
        rows, cols = np.mgrid[r0:r1, c0:c1]
        ok = valid[r0:r1, c0:c1]
        if not ok.any():
            continue
        wts = np.exp(
            -np.abs(guide[r, c] - guide[r0:r1, c0:c1]) / sigma_i
            - ((rows - r) ** 2 + (cols - c) ** 2) / (2 * sigma_s**2)
        )[ok]
        for ch in range(2):
            vals = flow[r0:r1, c0:c1, ch][ok]
            order = np.argsort(vals, kind="stable")
            cum = np.cumsum(wts[order])
            out[r, c, ch] = vals[order][np.searchsorted(cum, 0.5 * cum[-1])]
    return out


def test_fill_kernel_matches_oracle():
    rng = np.random.default_rng(11)
    h, w = 17, 23
    flow = rng.normal(0, 2, (h, w, 2)).astype(np.float32)
    valid = rng.random((h, w)) > 0.3
    valid[:5, :5] = False  # a hole wider than the window: those pixels keep their value
    guide = rng.random((h, w)).astype(np.float32)
    p = PMBPParams(fill_radius=2, fill_sigma_intensity=0.2, fill_sigma_space=1.5)
    got = _fill_inconsistent(flow, valid, guide, p)
    want = _naive_fill(flow, valid, guide, 2, 0.2, 1.5)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    np.testing.assert_array_equal(got[valid], flow[valid])
    np.testing.assert_array_equal(got[:2, :2], flow[:2, :2])
    assert not np.array_equal(got[~valid][10:], flow[~valid][10:])


def test_consistency_mask():
    h, w = 20, 30
    fw = np.zeros((h, w, 2), np.float32)
    fw[..., 0] = 2.0
    bw = -fw.copy()
    bw[5, 12] = (3.0, 0.0)  # breaks the cycle of p = (5, 10)
    valid = _consistent(fw, bw, 1.0)
    assert not valid[5, 10]
    assert not valid[:, -2:].any()  # p + s leaves the image
    assert valid[:, :-2].sum() == h * (w - 2) - 1


def test_consistency_fill_fixes_occlusions():
    """The FB check + fill lowers the EPE around an occluding square and changes only the
    pixels that fail the check; disabled, the solve is untouched."""
    a, b, truth = _occlusion_pair()
    raw = pmbp_flow(a, b, PMBPParams(**RAW))
    filled = pmbp_flow(a, b, PMBPParams(variational_refinement_iterations=0))
    backward = pmbp_flow(b, a, PMBPParams(**RAW), -raw)
    valid = _consistent(raw, backward, PMBPParams().consistency_threshold)
    assert 0.01 < (~valid).mean() < 0.2
    np.testing.assert_array_equal(filled[valid], raw[valid])
    assert np.any(filled[~valid] != raw[~valid])
    assert _field_epe(filled, truth) < 0.9 * _field_epe(raw, truth)


def test_pair_function_shares_the_solves(monkeypatch):
    """pmbp_flow_pair: forward bit-identical to pmbp_flow, backward as good as a separate
    solve, and estimate_flow_pair runs 2 PMBP solves per pair instead of 4."""
    import fuse4d.flow.pmbp as pmbp_module
    from fuse4d.flow import estimate_flow_pair

    a, b, truth = _occlusion_pair()
    p = PMBPParams(num_particles=2, num_iter=3)
    forward, backward = pmbp_flow_pair(a, b, p)
    np.testing.assert_array_equal(forward, pmbp_flow(a, b, p))
    separate = pmbp_flow(b, a, p, -forward)
    back_truth = -truth  # background and (shifted) square move back by the same amounts
    mask = np.ones(truth.shape[:2], bool)
    mask[20:76, 20:80] = False  # compare on the background (away from the square's track)
    err_pair = np.hypot(*(backward - back_truth).transpose(2, 0, 1))[mask].mean()
    err_sep = np.hypot(*(separate - back_truth).transpose(2, 0, 1))[mask].mean()
    assert err_pair < 0.1
    assert err_pair < 1.2 * err_sep + 0.01
    calls = []
    real_solve = pmbp_module._solve
    monkeypatch.setattr(pmbp_module, "_solve", lambda *args: calls.append(1) or real_solve(*args))
    fw2, bw2 = estimate_flow_pair(a, b, method="pmbp", params=p)
    assert len(calls) == 2
    np.testing.assert_array_equal(fw2, forward)
    np.testing.assert_array_equal(bw2, backward)


def test_variational_refinement_reduces_error():
    a, b, truth = _occlusion_pair()
    off = pmbp_flow(a, b, PMBPParams(variational_refinement_iterations=0))
    on = pmbp_flow(a, b, PMBPParams())
    assert _field_epe(on, truth) < 0.85 * _field_epe(off, truth)
    # on a noisy sub-pixel translation as well
    d = (0.6, -1.2)
    a, b = _pair(64, 64, d, noise=0.03, seed=5)
    off = pmbp_flow(a, b, PMBPParams(**RAW))
    on = pmbp_flow(a, b, PMBPParams(consistency_check=False))
    assert _epe(on, d, 8) < 0.7 * _epe(off, d, 8)


def test_post_steps_respect_roi():
    a, b, _ = _occlusion_pair()
    p = PMBPParams(roi=(10, 80, 12, 90))
    flow = pmbp_flow(a, b, p)
    outside = np.ones(a.shape, bool)
    outside[10:80, 12:90] = False
    assert np.all(flow[outside] == 0.0)
    assert np.abs(flow[~outside]).max() > 0.2
    fast = pmbp_flow(a, b, PMBPFastParams(roi=(10, 80, 12, 90)))
    assert np.all(fast[outside] == 0.0)


# ------------------------------------------------------------------------------------------
# METHOD §2.6 acceptance on the falling ball


def _fb_pass_rate(fw, bw, mask):
    h, w = mask.shape
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    back = cv2.remap(bw, cols + fw[..., 0], rows + fw[..., 1], cv2.INTER_LINEAR)
    return float((np.hypot(*(fw + back).transpose(2, 0, 1))[mask] < 1.0).mean())


def _ball_acceptance(small):
    for noise, limit in ((0.02, 0.25), (0.10, 0.6)):
        pair = ball_pairs(intensity_noise=noise, small=small)[0]
        fw = pmbp_flow(pair.image0, pair.image1)
        epe = np.hypot(*(fw - pair.flow_true).transpose(2, 0, 1))[pair.mask].mean()
        assert epe < limit, (noise, epe)
        if noise == 0.02:
            bw = pmbp_flow(pair.image1, pair.image0, None, -fw)
            assert _fb_pass_rate(fw, bw, pair.mask) > 0.95


def test_ball_acceptance_small():
    """METHOD §2.6 targets on the 150x150 CI ball (exact image motion as reference)."""
    _ball_acceptance(small=True)


@pytest.mark.slow
def test_ball_acceptance_full_size():
    """METHOD §2.6 targets on the 600x600 ball: EPE < 0.25 / 0.6 px, FB pass > 95 %."""
    _ball_acceptance(small=False)
