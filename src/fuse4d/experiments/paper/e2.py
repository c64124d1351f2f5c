"""E2 — mean roughness vs intensity noise (EVALUATION §4 E2; paper Fig. "(b) intensity noise").

Falling ball, σ_d = 0.2 mm, σ_I ∈ {2 … 10} %. For Ours also the flow end-point error on the
ball ROI and the fraction of ball ROI pixels with full temporal support (all 8 window frames
tracked), which show why Ours is robust to intensity noise.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ._ball_sweep import ball_rows, sweep_units
from ._common import METHODS, Context
from ._config import Profile
from ._plots import figure, label, method_style
from ._runner import Unit
from ._scenes import ours_params
from ._summary import group_stats, markdown_table

NAME = "E2"
TITLE = "E2 — mean roughness vs intensity noise (falling ball, σ_d = 0.2 mm)"
SIGMA_D = 0.2


def unit(profile: Profile, cache_dir: Path, method: str, sigma_i: float, seed: int) -> list[dict]:
    """Rows of one (method, σ_I, seed); Ours' rows carry ``flow_epe`` and ``full_support``."""
    return ball_rows(
        NAME, profile, cache_dir, method, seed, sigma_d=SIGMA_D, sigma_i=sigma_i, flow_stats=True
    )


def units(ctx: Context) -> list[Unit]:
    """One unit per (seed, σ_I, method)."""
    return sweep_units(ctx, unit, "sigma_i", "si", ctx.profile.sigma_i_levels)


def parameters(ctx: Context) -> dict[str, Any]:
    """Every setting of E2 (for the JSON)."""
    return {
        "scene": "falling ball (EVALUATION §3)",
        "sigma_d": SIGMA_D,
        "sigma_i_levels": list(ctx.profile.sigma_i_levels),
        "methods": list(METHODS),
        "baseline_params": "defaults of fuse4d.baselines (BASELINES.md)",
        "ours": vars(ours_params()),
        "flow_method": ctx.profile.flow_method,
        "flow_epe_region": "ball roughness ROI of frame t (EVALUATION §3), forward flow t→t+1",
        "full_support": "support == (truncated) window length − 1 on the ball ROI",
    }


def summarize(ctx: Context, rows: list[dict]) -> dict[str, Any]:
    """Write ``E2.md`` and ``E2_roughness_vs_intensity_noise.png``."""
    d = ctx.exp_dir(NAME)
    stats = group_stats(rows, ("method", "sigma_i"), "roughness")
    epe = group_stats(rows, ("method", "sigma_i"), "flow_epe")
    sup = group_stats(rows, ("method", "sigma_i"), "full_support")
    levels = sorted({k[1] for k in stats})
    pct = [100 * s for s in levels]
    with figure(d / "E2_roughness_vs_intensity_noise.png", ncols=2, size=(13.0, 5.8)) as (_, ax):
        a, b = ax[0, 0], ax[0, 1]
        for m in METHODS:
            xs = [s for s in levels if (m, s) in stats]
            a.errorbar(
                [100 * s for s in xs],
                [stats[(m, s)].mean for s in xs],
                yerr=[stats[(m, s)].std_seeds for s in xs],
                label=label(m),
                capsize=2,
                **method_style(m),
            )
        a.set_xlabel("intensity noise σ_I (% of max. intensity)")
        a.set_ylabel("mean roughness Π, Eq. 7 (mm)")
        a.set_title(TITLE)
        a.legend(ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.14))
        xs = [s for s in levels if ("ours", s) in epe]
        b.plot(
            [100 * s for s in xs],
            [epe[("ours", s)].mean for s in xs],
            color="#d62728",
            marker="o",
            label="flow EPE on the ball ROI (left axis)",
        )
        b.set_xlabel("intensity noise σ_I (% of max. intensity)")
        b.set_ylabel("flow end-point error (px)", color="#d62728")
        b.set_title("Why Ours is robust: flow error and temporal support (Ours)")
        b.set_ylim(bottom=0)
        b2 = b.twinx()
        xs = [s for s in levels if ("ours", s) in sup]
        b2.plot(
            [100 * s for s in xs],
            [100 * sup[("ours", s)].mean for s in xs],
            color="#1f77b4",
            marker="s",
            linestyle="--",
            label="ball pixels with full support (right axis)",
        )
        b2.set_ylabel("pixels tracked into all 8 window frames (%)", color="#1f77b4")
        b2.set_ylim(0, 105)
        b2.grid(False)
        h1, l1 = b.get_legend_handles_labels()
        h2, l2 = b2.get_legend_handles_labels()
        b.legend(h1 + h2, l1 + l2, loc="lower left")
    table = [
        [label(m), *[stats[(m, s)].mean if (m, s) in stats else float("nan") for s in levels]]
        for m in METHODS
    ]
    table.append(
        ["Ours: flow EPE (px)", *[epe.get(("ours", s)) and epe[("ours", s)].mean for s in levels]]
    )
    table.append(
        [
            "Ours: full support (%)",
            *[sup.get(("ours", s)) and 100 * sup[("ours", s)].mean for s in levels],
        ]
    )
    md = f"# {TITLE}\n\nMean roughness Π (mm) over all frames, mean over seeds.\n\n"
    md += markdown_table(["method", *[f"σ_I = {p:.0f} %" for p in pct]], table)
    md += "\n![E2](E2_roughness_vs_intensity_noise.png)\n"
    (d / "E2.md").write_text(md)
    return {"roughness": {f"{m}@{s:.2f}": st.mean for (m, s), st in stats.items()}}
