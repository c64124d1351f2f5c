"""E5 — Table-1 analogue on synthetic scenes (EVALUATION §4 E5; the DI4D recordings are absent).

Scenes: (a) static textured plane, (b) falling ball (σ_d = 0.2 mm, σ_I = 2 %), (c) deforming
sheet ("face" proxy). Methods: Raw, the seven filters, Ours (9 frames), 6D rigid fusion
(KinectFusion) on the plane and 6D non-rigid ED fusion on the ball and the sheet. Table: mean and
std (over frames) of roughness per scene, and Ours/Raw ratios beside the paper's.

ED's cost grows with its node count (16 pairwise warps per evaluated frame), so it is evaluated
only at ``profile.ed_frames`` frames, each from its own window of ±``size`` frames (9 frames at
the default ``size = 4``), with the profile's ``ed_params`` (node spacing, stride); the table
compares it with Ours and Raw on the same frames.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ._common import HALF_WINDOW, Context, tidy
from ._config import Profile
from ._plots import figure, label, method_style
from ._runner import Unit
from ._scenes import FILTERS, ball, flow_for, ours_params, run_method, scene
from ._scoring import evenly_spaced, score_frames
from ._summary import fmt, group_stats, markdown_table

NAME = "E5"
TITLE = "E5 — Table-1 analogue: roughness on plane / ball / deforming sheet"
SCENES = ("plane", "ball", "sheet")
SCENE_LABELS = {"plane": "plane (static)", "ball": "ball (falling)", "sheet": "sheet (≈ face)"}
#: The paper's Table 1 (§5): Ours/Raw ratios of the mean and of the std, per object.
PAPER_RATIOS = {
    "plane": (0.355, 0.162),
    "ball": (0.480, 0.144),
    "sheet": (0.364, 0.404),
}
#: Paper Table 1 values (mean mm, std in the column's scale) of the DI4D objects.
PAPER_OBJECT = {"plane": "plane", "ball": "ball", "sheet": "face"}


def methods_for(scene_name: str) -> tuple[str, ...]:
    """Methods run on ``scene_name`` (6D rigid on the static plane, 6D ED on dynamic scenes)."""
    six = ("kinectfusion",) if scene_name == "plane" else ("ed",)
    return ("raw", *FILTERS, *six, "ours")


def make(profile: Profile, scene_name: str, seed: int) -> Any:
    """The E5 scene with its §4 default noise."""
    if scene_name == "ball":
        return ball(profile, seed, 0.2, 0.02)
    return scene(scene_name, profile.small, profile.num_frames, seed)


def ed_frames(profile: Profile) -> list[int]:
    """Frames at which ED is evaluated (interior frames, evenly spaced)."""
    return evenly_spaced(profile.num_frames, profile.ed_frames, margin=HALF_WINDOW)


def unit(profile: Profile, cache_dir: Path, scene_name: str, method: str, seed: int) -> list[dict]:
    """Rows of one (scene, method, seed)."""
    seq = make(profile, scene_name, seed)
    if method == "ed":
        scored, seconds = [], 0.0
        ed_kw = dict(profile.extra.get("ed_params", {}))
        half = int(ed_kw.get("size", HALF_WINDOW))  # ED fuses frames c-size..c+size into c
        for c in ed_frames(profile):
            a, b = max(0, c - half), min(seq.num_frames, c + half + 1)
            win = seq.frames(a, b)
            out = run_method("ed", win, **ed_kw)
            seconds += out.seconds
            scored += score_frames(out.points[c - a : c - a + 1], seq, frames=[c])
        per_frame = seconds / max(1, len(scored))
    else:
        flow = flow_for(seq, profile.flow_method, cache_dir) if method == "ours" else None
        kw = profile.extra.get(f"{method}_params", {}) if method == "kinectfusion" else {}
        out = run_method(method, seq, flow=flow, **kw)
        scored = score_frames(out.points, seq)
        per_frame = out.seconds / seq.num_frames
    return tidy(NAME, scene_name, method, seed, scored, seq.num_frames, seconds_per_frame=per_frame)


def units(ctx: Context) -> list[Unit]:
    """One unit per (seed, scene, method); ED last (the slowest)."""
    p = ctx.profile
    out = [
        Unit(
            f"{s}_{m}_s{seed}",
            unit,
            {"profile": p, "cache_dir": ctx.cache_dir, "scene_name": s, "method": m, "seed": seed},
        )
        for seed in p.seeds
        for s in SCENES
        for m in sorted(methods_for(s), key=lambda m: (m == "ed", m != "ours"))
        if m != "ed" or p.ed_frames > 0  # ed_frames = 0: ED not run (too slow for the machine)
    ]
    return sorted(out, key=lambda u: u.kwargs["method"] == "ed")


def parameters(ctx: Context) -> dict[str, Any]:
    """Every setting of E5 (for the JSON)."""
    return {
        "scenes": {
            "plane": "make_static_plane defaults (σ(x) = 0.05·(2 − A) mm, σ_struct 0.02 mm)",
            "ball": "make_falling_ball σ_d 0.2 mm, σ_I 2 %",
            "sheet": "make_deforming_sheet defaults (σ_d 0.1 mm, σ_I 2 %)",
        },
        "methods": {s: list(methods_for(s)) for s in SCENES},
        "ed_frames": ed_frames(ctx.profile),
        "ed_params": ctx.profile.extra.get("ed_params", "BASELINES §9 defaults"),
        "kinectfusion_params": ctx.profile.extra.get("kinectfusion_params", "defaults"),
        "roi": "central 80 % of plane / sheet, ball ROI of §3 (metrics.scene_roi)",
        "flow_method": ctx.profile.flow_method,
        "ours": vars(ours_params()),
        "paper_ratios_ours_over_raw": PAPER_RATIOS,
    }


def table(rows: list[dict]) -> dict[str, dict[str, Any]]:
    """Per scene and method: mean, std (over frames) and the frames used."""
    st = group_stats(rows, ("scene", "method"), "roughness")
    ed_rows = [r for r in rows if r["method"] == "ed"]
    ed_f = {(r["scene"], r["frame"]) for r in ed_rows}
    same = group_stats(
        rows, ("scene", "method"), "roughness", where=lambda r: (r["scene"], r["frame"]) in ed_f
    )
    inner = group_stats(rows, ("scene", "method"), "roughness", where=lambda r: r["interior"] == 1)
    out: dict[str, dict[str, Any]] = {}
    for (s, m), v in st.items():
        iv = inner.get((s, m))
        out.setdefault(s, {})[m] = {
            "mean": v.mean,
            "std": v.std_frames,
            "frames": v.n_frames,
            "mean_at_ed_frames": same[(s, m)].mean if (s, m) in same else math.nan,
            "mean_interior": iv.mean if iv else math.nan,
            "std_interior": iv.std_frames if iv and iv.n_frames >= 3 else math.nan,
        }
    return out


def summarize(ctx: Context, rows: list[dict]) -> dict[str, Any]:
    """Write ``E5.md`` and ``E5_table1.png``."""
    d = ctx.exp_dir(NAME)
    tab = table(rows)
    lines = [
        f"# {TITLE}\n",
        (
            "Roughness Π (mm): mean over frames and std over frames (ddof 0). "
            "ED is evaluated on few frames only (column *frames*); *at ED frames* compares "
            "every method on exactly those frames.\n"
        ),
    ]
    for s in SCENES:
        if s not in tab:
            continue
        t = tab[s]
        body = [
            [
                label(m),
                t[m]["mean"],
                f"{t[m]['std']:.4f}" if t[m]["frames"] >= 3 else "–",
                str(t[m]["frames"]),
                t[m]["mean_at_ed_frames"],
                t[m]["mean_interior"],
                f"{t[m]['std_interior']:.4f}" if math.isfinite(t[m]["std_interior"]) else "–",
            ]
            for m in methods_for(s)
            if m in t
        ]
        lines.append(f"\n## {SCENE_LABELS[s]}\n")
        lines.append(
            markdown_table(
                [
                    "method",
                    "mean Π",
                    "std Π",
                    "frames",
                    "mean Π at ED frames",
                    "mean Π, interior frames",
                    "std Π, interior frames",
                ],
                body,
            )
        )
        if "ours" in t and "raw" in t:
            rm = t["ours"]["mean"] / t["raw"]["mean"]
            rs = t["ours"]["std"] / t["raw"]["std"] if t["raw"]["std"] > 0 else math.nan
            pm, ps = PAPER_RATIOS[s]
            lines.append(
                f"\nOurs/Raw: mean **{fmt(rm)}** (paper, {PAPER_OBJECT[s]}: {pm:.3f}), "
                f"std **{fmt(rs)}** (paper: {ps:.3f}).\n"
            )
    lines.append("\n![E5](E5_table1.png)\n")
    (d / "E5.md").write_text("".join(lines))
    with figure(d / "E5_table1.png", ncols=3, size=(15.0, 5.0)) as (_, ax):
        for j, s in enumerate(SCENES):
            a = ax[0, j]
            if s not in tab:
                continue
            ms = [m for m in methods_for(s) if m in tab[s]]
            vals = [tab[s][m]["mean"] if m != "ed" else tab[s][m]["mean_at_ed_frames"] for m in ms]
            errs = [tab[s][m]["std"] if tab[s][m]["frames"] >= 3 else 0.0 for m in ms]
            a.bar(
                range(len(ms)),
                vals,
                yerr=errs,
                capsize=2,
                color=[method_style(m)["color"] for m in ms],
            )
            top = 1.5 * tab[s]["raw"]["mean"] if "raw" in tab[s] else max(vals)
            a.set_ylim(0, top)
            for k, v in enumerate(vals):
                if v > top:
                    a.text(
                        k,
                        0.97 * top,
                        f"{v:.2f}↑",
                        ha="center",
                        va="top",
                        fontsize=7,
                        color="white",
                        fontweight="bold",
                        rotation=90,
                    )
                else:
                    a.text(k, v * 1.01, f"{v:.2f}", ha="center", va="bottom", fontsize=7)
            a.set_xticks(
                range(len(ms)), [label(m) for m in ms], rotation=60, ha="right", fontsize=8
            )
            a.set_ylabel("mean roughness Π (mm) ± std over frames")
            ratio = tab[s]["ours"]["mean"] / tab[s]["raw"]["mean"] if "raw" in tab[s] else math.nan
            a.set_title(
                f"{SCENE_LABELS[s]}: Ours/Raw {ratio:.3f} (paper {PAPER_RATIOS[s][0]:.3f})\n"
                "6D bar: mean on its evaluated frame(s); ↑ = bar clipped"
            )
    return tab
