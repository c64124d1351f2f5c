"""Does fusing 9 frames smooth the person more than fusing 1? (issue 10, stop 17)

For the real Kinect-class clip ``../shared/data/uva_cv2_person_turning`` (first ``--frames``
frames) and the synthetic Kinect ``body`` range scene (ground truth), fuse4d is run with one
flow (DIS, computed once per sequence) for ``num_frames`` 1 and 9 and every base of Eq. 5, plus
any ``--variant NAME=field:value,...`` given, and prints:

* ``rough``: Eq. 7 roughness (5×5, mm) on the person — the measure of the ``real`` experiment
  (:func:`fuse4d.experiments.paper.real.person_scores`: GT mask eroded by 5 px, pixels whose
  window is edge-free in raw and output); on the body scene the true mask eroded by 5 px;
* ``rough(all)``: the stop-17 measure (mask ∩ raw-valid ∩ finite Eq. 7 of raw and output,
  frames 4..T-5; includes the silhouette rim);
* ``flicker``: mean frame-to-frame |Δ| (mm) on the static background (uva: outside the dilated
  masks of every frame, ``person_scores``; body: true static pixels valid in every frame);
* ``trail %``: silhouette-band trail measure (uva only);
* ``rmse`` / ``rmse obj``: RMSE (mm) vs the true depth on raw-valid pixels / on the body (body).

Usage::

    python benchmarks/real_person.py [--frames 30] [--body-frames 16] [--skip-body]
        [--variant "slope=base:trajectory,slope_prior:1"]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import cv2
import numpy as np

from fuse4d import FusionParams, depth_to_points, fuse_sequence, load_sequence
from fuse4d.flow import estimate_sequence_flow
from fuse4d.metrics import roughness
from fuse4d.range_scenes import make_range_scene

BASES = ("adaptive", "trajectory", "quadratic", "frame")


def _variants(extra: list[str]) -> dict[str, FusionParams]:
    out = {"n=1": FusionParams(num_frames=1)}
    for b in BASES:
        out[f"n=9 {b}"] = FusionParams(base=b)
        if b != "frame":
            out[f"n=9 {b} A29-off"] = FusionParams(base=b, base_smoothing=0.0)
    for spec in extra:
        name, _, fields = spec.partition("=")
        kw: dict[str, Any] = {}
        for item in fields.split(","):
            k, _, v = item.partition(":")
            kw[k] = v
        from fuse4d._params import coerce_fields

        out[name] = FusionParams(**coerce_fields(FusionParams, kw, owner=name))
    return out


def _rough_all(z, raw, mask, k) -> float:
    """Stop-17 measure: mean Eq. 7 on mask ∩ raw-valid ∩ finite Eq. 7 (raw and output)."""
    n = z.shape[0]
    vals = []
    for t in range(4, n - 4) if n > 8 else range(n):
        pi = roughness(depth_to_points(z[t], k))
        pr = roughness(depth_to_points(raw[t], k))
        m = mask[t] & np.isfinite(raw[t]) & np.isfinite(pi) & np.isfinite(pr)
        if m.any():
            vals.append(float(pi[m].mean()))
    return float(np.mean(vals))


def person_table(frames: int, variants: dict[str, FusionParams]) -> list[dict]:
    """Rows for the uva clip."""
    from fuse4d.experiments.paper.real import data_dir, person_scores

    seq = load_sequence(data_dir() / "uva_cv2_person_turning")
    seq = seq.frames(0, min(seq.num_frames, frames))
    flow = estimate_sequence_flow(seq.intensity, method="dis")
    mask = np.asarray(seq.ground_truth.mask, bool)
    raw_valid = np.isfinite(seq.depth)
    rows = []
    outs = {"raw": seq.depth}
    for name, p in variants.items():
        t0 = time.perf_counter()
        z = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=p, flow=flow).depth
        outs[name] = (np.where(raw_valid, z, np.nan), time.perf_counter() - t0)
    for name, val in outs.items():
        z, sec = (val, 0.0) if name == "raw" else val
        sc = person_scores(seq, z)
        sl = slice(4, frames - 4) if frames > 8 else slice(None)
        rows.append(
            {
                "scene": "uva person",
                "method": name,
                "rough": float(np.nanmean(sc["roughness"][sl])),
                "rough(all)": _rough_all(z, seq.depth, mask, seq.intrinsics),
                "flicker": sc["flicker"].step_mean,
                "trail %": 100 * float(np.nanmean(sc["trail"])),
                "rmse": float("nan"),
                "rmse obj": float("nan"),
                "s": sec,
            }
        )
    return rows


def body_table(frames: int, variants: dict[str, FusionParams]) -> list[dict]:
    """Rows for the synthetic Kinect body scene (640×480)."""
    seq = make_range_scene("body", sensor="kinect", num_frames=frames, rng=0)
    gt = seq.ground_truth
    k = seq.intrinsics
    flow = estimate_sequence_flow(seq.intensity, method="dis")
    raw_valid = np.isfinite(seq.depth)
    mask = np.asarray(gt.mask, bool)
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (11, 11))
    inner = np.stack([cv2.erode(f.astype(np.uint8), ker) > 0 for f in mask])
    static = raw_valid.all(0) & ~mask.any(0)
    rows = []
    outs = {"raw": (seq.depth, 0.0)}
    for name, p in variants.items():
        t0 = time.perf_counter()
        z = fuse_sequence(seq.depth, seq.intensity, k, fusion=p, flow=flow).depth
        outs[name] = (np.where(raw_valid, z, np.nan), time.perf_counter() - t0)
    sl = slice(4, frames - 4) if frames > 8 else slice(None)
    for name, (z, sec) in outs.items():
        err = (z - gt.depth)[sl]
        ok = raw_valid[sl] & np.isfinite(err)
        rough = []
        for t in range(frames)[sl]:
            pi = roughness(depth_to_points(z[t], k))
            m = inner[t] & np.isfinite(pi)
            rough.append(float(pi[m].mean()))
        rows.append(
            {
                "scene": "kinect body",
                "method": name,
                "rough": float(np.mean(rough)),
                "rough(all)": _rough_all(z, seq.depth, mask, k),
                "flicker": float(np.nanmean(np.abs(np.diff(z[sl][:, static], axis=0)))),
                "trail %": float("nan"),
                "rmse": float(np.sqrt(np.mean(err[ok] ** 2))),
                "rmse obj": float(np.sqrt(np.mean(err[ok & mask[sl]] ** 2))),
                "s": sec,
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--body-frames", type=int, default=16)
    ap.add_argument("--skip-body", action="store_true")
    ap.add_argument("--skip-person", action="store_true")
    ap.add_argument("--only", default="", help="comma list of variant names to run")
    ap.add_argument("--variant", action="append", default=[])
    a = ap.parse_args(argv)
    variants = _variants(a.variant)
    if a.only:
        keep = set(a.only.split(","))
        variants = {k: v for k, v in variants.items() if k in keep}
    rows = []
    if not a.skip_person:
        rows += person_table(a.frames, variants)
    if not a.skip_body:
        rows += body_table(a.body_frames, variants)
    cols = ("rough", "rough(all)", "flicker", "trail %", "rmse", "rmse obj", "s")
    print("| scene | method | " + " | ".join(cols) + " |")
    print("|---|---|" + "---|" * len(cols))
    for r in rows:
        print(
            f"| {r['scene']} | {r['method']} | "
            + " | ".join(f"{r[c]:.3f}" if c != "trail %" else f"{r[c]:.4f}" for c in cols)
            + " |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
