"""``real`` — the same methods on the two real recordings of ``../shared/data``.

* ``static_room_rgbd`` (12 frames, 30 Hz, static office corner, near-still camera): roughness
  on the real planes (walls, floor; default ROI = windows without depth edges) and temporal
  flicker (per-pixel std over time, mean over the pixels; the median too, in the rows) of the
  static scene;
* ``uva_cv2_person_turning`` (Kinect-v1 class, a person turning): roughness on the person
  (GT mask eroded by 5 px), background flicker (pixels outside the dilated masks of every
  frame), and the silhouette-band trail check: the fraction of valid pixels in the 8-px band
  just *outside* the person whose output depth is more than 100 mm nearer than the raw depth
  (foreground dragged onto the background: trails).

Methods: Raw, the seven filters, Ours (9 frames), the RealSense post-processing chain (when
``pyrealsense2`` is installed) and the plain 9-frame mean. Pictures: one moving frame side by
side (raw / Ours / RealSense chain / 9-frame mean) and an x–t slice (one image row through the
person stacked over time).
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from matplotlib.ticker import MaxNLocator
from numpy.typing import NDArray

from ...io import load_sequence
from ...metrics import default_roi, roughness_stats, temporal_flicker
from ...sequence import Sequence
from ._common import Context
from ._config import Profile
from ._plots import figure, label
from ._runner import Unit
from ._scenes import FILTERS, flow_for, ours_params, run_method
from ._summary import group_stats, markdown_table

NAME = "real"
TITLE = "real — static room (flicker, plane roughness) and person turning (roughness, trails)"
DATA = Path(__file__).resolve().parents[5] / "shared" / "data"
RECORDINGS = {"room": "static_room_rgbd", "person": "uva_cv2_person_turning"}
#: Frames of the person shown in the side-by-side picture and the row of the x–t slice.
BAND_PX, TRAIL_MM, ERODE_PX = 8, 100.0, 5
PICTURE_METHODS = ("raw", "ours", "realsense", "temporal-mean")


def data_dir() -> Path:
    """``../shared/data`` (override with ``FUSE4D_DATA``)."""
    import os

    return Path(os.environ.get("FUSE4D_DATA", DATA))


def methods() -> tuple[str, ...]:
    """Methods run on the real data (the RealSense chain only when its package is present)."""
    from ...baselines import available_baselines

    extra = []
    try:
        import pyrealsense2  # noqa: F401

        extra.append("realsense")
    except ImportError:
        pass
    del available_baselines
    return ("raw", *FILTERS, "ours", *extra, "temporal-mean")


def load(profile: Profile, rec: str) -> Any:
    """The recording: its first ``real_frames`` frames, cropped to ``extra["real_crop"]``.

    Only those frames are read, and once per process (every method of a recording shares
    them). ``real_crop = (rows, cols)`` (the quick profile's) keeps a window of that size centred
    on the person's bounding box over the frames (the image centre for the room), so the
    silhouette, its band and some background stay inside; the intrinsics are shifted to match.
    """
    crop = profile.extra.get("real_crop")
    return _load(str(data_dir() / RECORDINGS[rec]), profile.real_frames, crop and tuple(crop))


@lru_cache(maxsize=2)
def _load(path: str, num_frames: int, crop: tuple[int, int] | None) -> Sequence:
    seq = load_sequence(path, frames=(0, num_frames))  # clipped to the recording's length
    return seq if crop is None else _crop(seq, *crop)


def _crop(seq: Sequence, rows: int, cols: int) -> Sequence:
    """``seq`` cut to a ``rows x cols`` window (centred on the GT mask's box when there is one)."""
    _, h, w = seq.depth.shape
    rows, cols = min(rows, h), min(cols, w)
    gt = seq.ground_truth
    cy, cx = h // 2, w // 2
    if gt is not None and gt.mask is not None and np.asarray(gt.mask).any():
        ys, xs = np.nonzero(np.asarray(gt.mask, bool).any(axis=0))
        cy, cx = (int(ys.min()) + int(ys.max())) // 2, (int(xs.min()) + int(xs.max())) // 2
    v0 = min(max(0, cy - rows // 2), h - rows)
    u0 = min(max(0, cx - cols // 2), w - cols)
    win = (slice(None), slice(v0, v0 + rows), slice(u0, u0 + cols))
    k = seq.intrinsics
    k = replace(k, cx=k.cx - u0, cy=k.cy - v0, width=cols, height=rows)
    if gt is not None:
        gt = replace(
            gt,
            depth=None if gt.depth is None else gt.depth[win],
            mask=None if gt.mask is None else np.asarray(gt.mask)[win],
            flow=None if gt.flow is None else gt.flow[win],
        )
    return replace(
        seq, depth=seq.depth[win], intensity=seq.intensity[win], intrinsics=k, ground_truth=gt
    )


def _masks(seq: Any) -> tuple[NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]:
    """Person mask eroded, outside band (8 px), and static background (all frames)."""
    gt = seq.ground_truth
    m = np.asarray(gt.mask, bool)
    k_e = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ERODE_PX + 1, 2 * ERODE_PX + 1))
    k_b = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * BAND_PX + 1, 2 * BAND_PX + 1))
    inner = np.stack([cv2.erode(f.astype(np.uint8), k_e) > 0 for f in m])
    dil = np.stack([cv2.dilate(f.astype(np.uint8), k_b) > 0 for f in m])
    band = dil & ~m
    k_far = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (41, 41))
    ever = cv2.dilate(m.any(axis=0).astype(np.uint8), k_far) > 0
    return inner, band, ~ever


def person_scores(
    seq: Any, z: NDArray[np.floating], points: NDArray[np.floating] | None = None
) -> dict[str, Any]:
    """The person measures of one output depth video ``z`` (T, H, W) mm of the person clip.

    Returns ``stats`` (:class:`~fuse4d.metrics.RoughnessStats` of Eq. 7 on the eroded person
    mask where raw has a full edge-free window: one ROI for every method, a method's pixels
    without a defined Eq. 7 drop out; of ``points`` (T, H, W, 3) mm when given, else of ``z``
    on the pixel rays), ``roughness`` (its per-frame means, mm), ``flicker``
    (:func:`temporal_flicker` on the static background), and ``trail`` (per frame: fraction
    of the 8-px silhouette band where the output is more than 100 mm nearer than raw). The
    one home of these measures (``benchmarks/real_person.py`` uses it too).
    """
    raw_z = seq.depth
    inner, band, background = _masks(seq)
    k = seq.intrinsics
    from ...camera import depth_to_points

    roi = inner & default_roi(raw_z)
    if points is None:
        points = depth_to_points(np.asarray(z, np.float32), k)
    stats = roughness_stats(points, roi=roi)
    trail = []
    for t in range(seq.num_frames):
        b = band[t] & np.isfinite(z[t]) & np.isfinite(raw_z[t])
        tr = (raw_z[t][b] - z[t][b]) > TRAIL_MM
        trail.append(float(tr.mean()) if b.any() else math.nan)
    return {
        "stats": stats,
        "roughness": stats.frame_means,
        "n_roi": stats.num_pixels,
        "flicker": temporal_flicker(z, static=background),
        "trail": np.asarray(trail),
    }


#: Columns :func:`summarize` reads that earlier versions' rows lack (flicker_mean: stop 56);
#: a resumed run computes such units again.
ROW_COLUMNS = ("flicker_mean",)


def unit(profile: Profile, cache_dir: Path, rec: str, method: str, out_dir: Path) -> list[dict]:
    """Rows of one (recording, method); per frame roughness, and the sequence flicker."""
    seq = load(profile, rec)
    flow = flow_for(seq, profile.flow_method, cache_dir) if method == "ours" else None
    out = run_method(method, seq, flow=flow)
    pts = out.points
    z = pts[..., 2]
    raw_z = seq.depth
    person = person_scores(seq, z, pts) if rec == "person" else None
    if person is not None:
        stats, flick = person["stats"], person["flicker"]
    else:
        stats = roughness_stats(pts, roi=default_roi(raw_z) & default_roi(z))
        flick = temporal_flicker(z)
    rows = []
    for t in range(seq.num_frames):
        row: dict[str, Any] = {
            "experiment": NAME,
            "scene": rec,
            "method": method,
            "label": label(method),
            "seed": 0,
            "frame": t,
            "roughness": float(stats.frame_means[t]),
            "roughness_rms": float(stats.frame_rms_means[t]),
            "n_roi": int(stats.num_pixels[t]),
            "flicker_mean": float(flick.mean),
            "flicker_median": float(flick.median),
            "valid_fraction": float(np.isfinite(z[t]).mean()),
            "seconds_per_frame": out.seconds / seq.num_frames,
        }
        if person is not None:
            row["trail_fraction"] = float(person["trail"][t])
        rows.append(row)
    if rec == "person" and method in PICTURE_METHODS:
        out_dir.mkdir(parents=True, exist_ok=True)
        np.save(out_dir / f"{method}_depth.npy", z.astype(np.float16))
    return rows


def units(ctx: Context) -> list[Unit]:
    """One unit per (recording, method); skipped with a note when the data are absent."""
    if not all((data_dir() / r).is_dir() for r in RECORDINGS.values()):
        return []
    pic = ctx.out / NAME / "pictures"
    return [
        Unit(
            f"{rec}_{m}",
            unit,
            {
                "profile": ctx.profile,
                "cache_dir": ctx.cache_dir,
                "rec": rec,
                "method": m,
                "out_dir": pic,
            },
        )
        for rec in RECORDINGS
        for m in sorted(methods(), key=lambda m: m != "ours")
    ]


def parameters(ctx: Context) -> dict[str, Any]:
    """Every setting of ``real`` (for the JSON)."""
    return {
        "data": {k: str(data_dir() / v) for k, v in RECORDINGS.items()},
        "frames": ctx.profile.real_frames,
        "crop": ctx.profile.extra.get("real_crop", "none (full frames)"),
        "methods": list(methods()),
        "person_roi": f"GT mask eroded by {ERODE_PX} px ∩ default_roi of raw "
        "(no depth edge in 5x5; one ROI for every method)",
        "trail_band": f"{BAND_PX} px outside the mask; trail = output > {TRAIL_MM} mm nearer "
        "than raw",
        "room_roi": "default_roi of raw and output (planar patches without depth edges)",
        "flow_method": ctx.profile.flow_method,
        "ours": vars(ours_params()),
    }


def summarize(ctx: Context, rows: list[dict]) -> dict[str, Any]:
    """Write ``real.md``, ``real_person_frame.png`` and ``real_person_xt.png``."""
    d = ctx.exp_dir(NAME)
    if not rows:
        (d / "real.md").write_text(f"# {TITLE}\n\nData not found in {data_dir()}: skipped.\n")
        return {}
    rough = group_stats(rows, ("scene", "method"), "roughness")
    # the mean per-pixel std, as fuse4d metrics: the median reads 0 mm for quantised depth
    # whose static pixels mostly never leave their level over a short clip
    flick = group_stats(rows, ("scene", "method"), "flicker_mean")
    trail = group_stats(rows, ("scene", "method"), "trail_fraction")
    ms = [m for m in methods() if ("room", m) in rough or ("person", m) in rough]
    body = []
    for m in ms:

        def g(st: dict, s: str, scale: float = 1.0, m: str = m) -> float:
            return scale * st[(s, m)].mean if (s, m) in st else math.nan

        body.append(
            [
                label(m),
                g(rough, "room"),
                g(flick, "room"),
                g(rough, "person"),
                g(flick, "person"),
                g(trail, "person", 100),
            ]
        )
    md = f"# {TITLE}\n\n" + markdown_table(
        [
            "method",
            "room: plane roughness Π (mm)",
            "room: flicker, mean std over time (mm)",
            "person: roughness Π (mm)",
            "person: background flicker, mean std over time (mm)",
            "person: trail pixels in the 8-px band (%)",
        ],
        body,
    )
    md += "\n![frame](real_person_frame.png)\n\n![x-t](real_person_xt.png)\n"
    (d / "real.md").write_text(md)
    _pictures(ctx, d)
    return {"roughness": {f"{s}@{m}": v.mean for (s, m), v in rough.items()}}


def _pictures(ctx: Context, d: Path) -> None:
    pic = d / "pictures"
    avail = [m for m in PICTURE_METHODS if (pic / f"{m}_depth.npy").exists()]
    if "raw" not in avail:
        return
    seq = load(ctx.profile, "person")
    depths = {m: np.load(pic / f"{m}_depth.npy").astype(np.float32) for m in avail}
    mask = np.asarray(seq.ground_truth.mask, bool)
    t = seq.num_frames // 2
    ys, xs = np.nonzero(mask[t])
    v0, v1, u0, u1 = ys.min(), ys.max(), xs.min(), xs.max()
    pad = 30
    v0, v1 = max(0, v0 - pad), min(mask.shape[1], v1 + pad)
    u0, u1 = max(0, u0 - pad), min(mask.shape[2], u1 + pad)
    zin = depths["raw"][t][mask[t]]
    lo, hi = np.nanpercentile(zin, 2), np.nanpercentile(zin, 98)
    n = len(avail)
    with figure(d / "real_person_frame.png", ncols=n, nrows=2, size=(3.6 * n + 1.2, 9.0)) as (
        fig,
        ax,
    ):
        for j, m in enumerate(avail):
            a, b = ax[0, j], ax[1, j]
            crop = depths[m][t, v0:v1, u0:u1]
            im = a.imshow(
                crop,
                cmap="turbo",
                vmin=lo,
                vmax=hi,
                extent=(u0, u1, v1, v0),
                interpolation="nearest",
            )
            a.set_title(f"{label(m)}, frame {t}")
            diff = crop - depths["raw"][t, v0:v1, u0:u1]
            im2 = b.imshow(
                diff,
                cmap="RdBu_r",
                vmin=-20,
                vmax=20,
                extent=(u0, u1, v1, v0),
                interpolation="nearest",
            )
            b.set_title(f"{label(m)} − Raw")
            for x in (a, b):
                x.set_xlabel("column u (px)")
                x.set_ylabel("row v (px)")
                x.grid(False)
        fig.colorbar(
            im, ax=list(ax[0]), label="depth Z (mm); white = no depth; wall saturated", shrink=0.9
        )
        fig.colorbar(
            im2, ax=list(ax[1]), label="change against Raw (mm); white = no depth", shrink=0.9
        )
    cy = int(np.median(ys))
    with figure(d / "real_person_xt.png", ncols=len(avail), size=(3.6 * len(avail), 5.0)) as (
        fig,
        ax,
    ):
        for j, m in enumerate(avail):
            a = ax[0, j]
            cols = np.nonzero(mask[:, cy, :].any(axis=0))[0]
            c0 = max(0, int(cols.min()) - 40) if cols.size else 0
            c1 = min(mask.shape[2], int(cols.max()) + 40) if cols.size else mask.shape[2]
            sl = depths[m][:, cy, c0:c1]
            im = a.imshow(
                sl,
                cmap="turbo",
                vmin=lo,
                vmax=hi,
                aspect="auto",
                interpolation="nearest",
                extent=(c0, c1, sl.shape[0] - 0.5, -0.5),
            )
            a.set_title(f"{label(m)}\nrow v = {cy} over time")
            a.set_xlabel("column u (px)")
            a.set_ylabel("frame t")
            a.yaxis.set_major_locator(MaxNLocator(integer=True))
            a.grid(False)
        fig.colorbar(im, ax=list(ax.ravel()), label="depth Z (mm); white = no depth", shrink=0.8)
        fig.suptitle(
            "x–t slice: one image row through the person, frames stacked downwards "
            "(trails = smeared edges, flicker = speckle along t)"
        )
