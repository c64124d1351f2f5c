"""E1 — mean roughness vs depth noise (EVALUATION §4 E1; paper Fig. "Mean roughness vs (a)").

Falling ball, σ_I = 2 %, σ_d ∈ {0.10 … 0.40} mm; Raw, the seven filters and Ours (9 frames).
One flow set per seed (σ_I fixed) serves every depth-noise level.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ._ball_sweep import ball_rows, sweep_units
from ._common import METHODS, Context
from ._config import Profile
from ._plots import figure, label, method_style
from ._runner import Unit
from ._summary import group_stats, markdown_table

NAME = "E1"
TITLE = "E1 — mean roughness vs depth noise (falling ball, σ_I = 2 %)"
SIGMA_I = 0.02


def unit(profile: Profile, cache_dir: Path, method: str, sigma_d: float, seed: int) -> list[dict]:
    """Rows of one (method, σ_d, seed)."""
    return ball_rows(NAME, profile, cache_dir, method, seed, sigma_d=sigma_d, sigma_i=SIGMA_I)


def units(ctx: Context) -> list[Unit]:
    """One unit per (seed, σ_d, method); Ours first per seed so its flow is cached early."""
    return sweep_units(ctx, unit, "sigma_d", "sd", ctx.profile.sigma_d_levels)


def summarize(ctx: Context, rows: list[dict]) -> dict[str, Any]:
    """Write ``E1.md`` and ``E1_roughness_vs_depth_noise.png``; return the summary numbers."""
    d = ctx.exp_dir(NAME)
    stats = group_stats(rows, ("method", "sigma_d"), "roughness")
    levels = sorted({k[1] for k in stats})
    with figure(d / "E1_roughness_vs_depth_noise.png", size=(8.0, 5.0)) as (_, ax):
        for m in METHODS:
            xs = [s for s in levels if (m, s) in stats]
            ys = [stats[(m, s)].mean for s in xs]
            es = [stats[(m, s)].std_seeds for s in xs]
            ax.errorbar(xs, ys, yerr=es, label=label(m), capsize=2, **method_style(m))
        ax.set_xlabel("depth noise σ_d (mm)")
        ax.set_ylabel("mean roughness Π, Eq. 7 (mm)")
        seeds = max(st.n_seeds for st in stats.values())
        bars = "error bars: std over seeds" if seeds > 1 else "one seed, so no error bars"
        ax.set_title(f"{TITLE}\n(mean over all frames; {bars})")
        ax.legend(ncol=2)
    table = [
        [label(m), *[stats[(m, s)].mean if (m, s) in stats else float("nan") for s in levels]]
        for m in METHODS
    ]
    md = f"# {TITLE}\n\nMean roughness Π (mm) over all frames, mean over seeds.\n\n"
    md += markdown_table(["method", *[f"σ_d = {s:.2f} mm" for s in levels]], table)
    md += "\n![E1](E1_roughness_vs_depth_noise.png)\n"
    (d / "E1.md").write_text(md)
    return {
        "roughness": {f"{m}@{s:.2f}": st.mean for (m, s), st in stats.items()},
    }


def parameters(ctx: Context) -> dict[str, Any]:
    """Every setting of E1 (for the JSON)."""
    from ._scenes import ours_params

    return {
        "scene": "falling ball (EVALUATION §3)",
        "sigma_i": SIGMA_I,
        "sigma_d_levels": list(ctx.profile.sigma_d_levels),
        "methods": list(METHODS),
        "baseline_params": "defaults of fuse4d.baselines (BASELINES.md)",
        "ours": ours_params().__dict__
        if hasattr(ours_params(), "__dict__")
        else str(ours_params()),
        "flow_method": ctx.profile.flow_method,
    }
