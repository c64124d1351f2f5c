"""The falling-ball noise sweep shared by E1 (σ_d levels) and E2 (σ_I levels).

One unit = one (method, noise level, seed): the ball of EVALUATION §3 at ``sigma_d`` /
``sigma_i``, the method run on it (Ours with the cached flow of that intensity sequence), its
frames scored (Eq. 7 roughness, Eq. 8 shape correctness), one tidy row per frame.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

from ._common import METHODS, Context, tidy
from ._config import Profile
from ._runner import Unit
from ._scenes import ball, flow_for, run_method
from ._scoring import flow_epe_frames, score_frames, support_frames

__all__ = ["ball_rows", "sweep_units"]


def ball_rows(
    name: str,
    profile: Profile,
    cache_dir: Path,
    method: str,
    seed: int,
    *,
    sigma_d: float,
    sigma_i: float,
    flow_stats: bool = False,
) -> list[dict]:
    """Tidy rows of ``method`` on the ball at depth noise ``sigma_d`` (mm), intensity noise
    ``sigma_i`` (fraction of the range); ``flow_stats`` adds Ours' ``flow_epe`` (px) and
    ``full_support`` (fraction of ROI pixels tracked in all window frames) to each row."""
    seq = ball(profile, seed, sigma_d, sigma_i)
    flow = flow_for(seq, profile.flow_method, cache_dir) if method == "ours" else None
    out = run_method(method, seq, flow=flow)
    scored = score_frames(out.points, seq)
    if flow_stats and out.result is not None:
        epe = flow_epe_frames(out.result.flow_forward, seq)
        full = support_frames(out.result.support, seq, out.result.params.num_frames)
        for s, e, f in zip(scored, epe, full, strict=True):
            s["flow_epe"] = e
            s["full_support"] = f
    return tidy(
        name,
        "ball",
        method,
        seed,
        scored,
        seq.num_frames,
        sigma_d=sigma_d,
        sigma_i=sigma_i,
        seconds_per_frame=out.seconds / seq.num_frames,
    )


def sweep_units(
    ctx: Context,
    unit_fn: Callable[..., list[dict]],
    level_name: str,
    tag: str,
    levels: Iterable[float],
) -> list[Unit]:
    """One unit per (seed, level, method), Ours first per seed so its flow is cached early;
    ``unit_fn(profile=, cache_dir=, method=, seed=, <level_name>=level)``, named
    ``<method>_<tag><level:.2f>_s<seed>``."""
    p = ctx.profile
    return [
        Unit(
            f"{m}_{tag}{lv:.2f}_s{seed}",
            unit_fn,
            {"profile": p, "cache_dir": ctx.cache_dir, "method": m, level_name: lv, "seed": seed},
        )
        for seed in p.seeds
        for lv in levels
        for m in sorted(METHODS, key=lambda m: m != "ours")
    ]
