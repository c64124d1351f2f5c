"""E4 — roughness vs number of fused frames (EVALUATION §4 E4; paper "static plane / falling ball").

Ours with n ∈ {1 … 9} fused frames on the static textured plane and on the falling ball, both with
a fixed-pattern (structural) noise σ_struct = 0.15 mm plus temporal noise σ = 0.15 mm, σ_I = 2 %.
For each n the sequence mean and std (over frames) of roughness; fit
mean(n) = √(δ_s² + δ_t²/n) (and the same form to std(n)) with ``scipy.optimize.curve_fit``.
Frames are scored where every n has its full window (frames 4 … N−5), so all n see the same
frames.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import curve_fit

from ._common import Context, tidy
from ._config import Profile
from ._plots import figure
from ._runner import Unit
from ._scenes import flow_for, ours_params, run_method, scene
from ._scoring import score_frames
from ._summary import group_stats, markdown_table

NAME = "E4"
TITLE = "E4 — roughness vs number of fused frames n (Ours; σ_struct = σ = 0.15 mm, σ_I = 2 %)"
SIGMA, SIGMA_STRUCT, SIGMA_I = 0.15, 0.15, 0.02
SCENES = ("plane", "ball")
SCENE_LABELS = {"plane": "static plane", "ball": "falling ball (dynamic)"}


def make(profile: Profile, scene_name: str, seed: int) -> Any:
    """The E4 scene (plane without texture-correlated noise: σ is uniform, as specified)."""
    kw: dict[str, Any] = {
        "depth_noise": SIGMA,
        "intensity_noise": SIGMA_I,
        "structural_noise": SIGMA_STRUCT,
    }
    if scene_name == "plane":
        kw["texture_correlated"] = False
    return scene(scene_name, profile.small, e4_frames(profile), seed, **kw)


def e4_frames(profile: Profile) -> int:
    """Sequence length of E4 (longer in the reduced profile: the std is over frames)."""
    return int(profile.extra.get("e4_num_frames", profile.num_frames))


def ours_label(n: int) -> str:
    """The label of Ours fusing ``n`` frames, e.g. ``"Ours (5 frames)"``."""
    return f"Ours ({n} frame{'' if n == 1 else 's'})"


def unit(profile: Profile, cache_dir: Path, scene_name: str, n: int, seed: int) -> list[dict]:
    """Rows of Ours with ``n`` fused frames on one scene."""
    seq = make(profile, scene_name, seed)
    flow = flow_for(seq, profile.flow_method, cache_dir)
    out = run_method("ours", seq, flow=flow, fusion=ours_params(num_frames=n))
    scored = score_frames(out.points, seq)
    return tidy(
        NAME,
        scene_name,
        "ours",
        seed,
        scored,
        seq.num_frames,
        label=ours_label(n),  # not LABELS' "Ours (9 frames)": n varies here
        n_frames=n,
        sigma_d=SIGMA,
        sigma_struct=SIGMA_STRUCT,
        sigma_i=SIGMA_I,
        seconds_per_frame=out.seconds / seq.num_frames,
    )


def units(ctx: Context) -> list[Unit]:
    """One unit per (seed, scene, n)."""
    p = ctx.profile
    return [
        Unit(
            f"{s}_n{n}_s{seed}",
            unit,
            {"profile": p, "cache_dir": ctx.cache_dir, "scene_name": s, "n": n, "seed": seed},
        )
        for seed in p.seeds
        for s in SCENES
        for n in p.e4_frames
    ]


def parameters(ctx: Context) -> dict[str, Any]:
    """Every setting of E4 (for the JSON)."""
    return {
        "scenes": {"plane": "make_static_plane(texture_correlated=False)", "ball": "§3 ball"},
        "sigma_temporal": SIGMA,
        "sigma_struct": SIGMA_STRUCT,
        "sigma_i": SIGMA_I,
        "num_frames_sequence": e4_frames(ctx.profile),
        "n_frames": list(ctx.profile.e4_frames),
        "scored_frames": "interior: 4 .. N-5 (full 9-frame window)",
        "model": "sqrt(delta_s^2 + delta_t^2 / n), curve_fit, bounds >= 0",
        "flow_method": ctx.profile.flow_method,
        "ours": vars(ours_params()),
    }


def _model(n: np.ndarray, ds: float, dt: float) -> np.ndarray:
    return np.sqrt(ds**2 + dt**2 / n)


def fit(ns: list[float], ys: list[float]) -> tuple[float, float, float]:
    """Least-squares fit of √(δ_s² + δ_t²/n): returns (δ_s, δ_t, R²)."""
    x, y = np.asarray(ns, float), np.asarray(ys, float)
    if len(x) < 3:
        return math.nan, math.nan, math.nan
    p0 = (float(y.min()), float(max(y.max() - y.min(), 1e-6)))
    (ds, dt), _ = curve_fit(_model, x, y, p0=p0, bounds=(0.0, np.inf), maxfev=10000)
    res = y - _model(x, ds, dt)
    tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum(res**2)) / tot if tot > 0 else math.nan
    return float(ds), float(dt), r2


def curves(rows: list[dict]) -> dict[str, dict[str, Any]]:
    """Per scene: n, mean(n), std(n) (interior frames) and both fits."""
    st = group_stats(rows, ("scene", "n_frames"), "roughness", where=lambda r: r["interior"] == 1)
    out = {}
    for s in SCENES:
        ns = sorted(k[1] for k in st if k[0] == s)
        if not ns:
            continue
        mean = [st[(s, n)].mean for n in ns]
        std = [st[(s, n)].std_frames for n in ns]
        out[s] = {
            "n": ns,
            "mean": mean,
            "std": std,
            "fit_mean": fit(ns, mean),
            "fit_std": fit(ns, std),
        }
    return out


def summarize(ctx: Context, rows: list[dict]) -> dict[str, Any]:
    """Write ``E4.md`` and ``E4_roughness_vs_frames.png``."""
    d = ctx.exp_dir(NAME)
    cv = curves(rows)
    colors = {"plane": "#1f77b4", "ball": "#d62728"}
    with figure(d / "E4_roughness_vs_frames.png", ncols=2, size=(13.0, 5.0)) as (_, ax):
        for j, (key, what) in enumerate((("mean", "mean"), ("std", "std over frames"))):
            a = ax[0, j]
            for s, c in cv.items():
                ds, dt, r2 = c[f"fit_{key}"]
                a.plot(c["n"], c[key], "o", color=colors[s], label=f"{SCENE_LABELS[s]}: measured")
                nn = np.linspace(1, max(c["n"]), 100)
                if math.isfinite(ds):
                    a.plot(
                        nn,
                        _model(nn, ds, dt),
                        "-",
                        color=colors[s],
                        label=f"fit √(δs²+δt²/n): δs={ds:.3g}, δt={dt:.3g} mm, R²={r2:.3f}",
                    )
            a.set_xlabel("number of fused frames n")
            a.set_ylabel(f"roughness Π, {what} (mm)")
            a.set_title(f"Roughness {what} vs n (Ours)")
            a.legend(fontsize=8)
    header = (
        [
            "scene",
            "statistic",
            *[f"n={n:g}" for n in next(iter(cv.values()))["n"]],
            "δ_s (mm)",
            "δ_t (mm)",
            "R²",
        ]
        if cv
        else ["scene"]
    )
    table = [
        [
            SCENE_LABELS[s],
            key,
            *[f"{v:.4f}" for v in (*c[key], *c[f"fit_{key}"][:2])],
            f"{c[f'fit_{key}'][2]:.3f}",
        ]
        for s, c in cv.items()
        for key in ("mean", "std")
    ]
    md = f"# {TITLE}\n\nInterior frames only (every n has its full window).\n\n"
    md += markdown_table(header, table) + "\n![E4](E4_roughness_vs_frames.png)\n"
    (d / "E4.md").write_text(md)
    return {s: {k: v for k, v in c.items()} for s, c in cv.items()}
