"""Optical-flow benchmark: EPE / AAE / time of every registered method on real and synthetic GT.

Datasets
--------
``middlebury``
    The four real-camera Middlebury training pairs in ``<data>/middlebury_flow`` (frame 10 → 11,
    ground truth ``flow10.flo``; pixels with unknown GT, |value| > 1e9, are excluded). Colour
    frames are converted to gray (BT.601), as for every fuse4d input.
``ball``
    The synthetic falling ball (EVALUATION §3, :func:`fuse4d.synthetic.make_falling_ball`) at
    sigma_I = 2 % and 10 % (seed 0), pairs (10, 11) and (25, 26) (small variant: (4, 5) and
    (9, 10)); error over the ball interior = GT mask of frame t eroded by 6 px (scaled with the
    variant's pixel scale, at least 1 px). The reference flow is the exact image motion of the
    ball, (0, speed * Z_c / Z) px, computed from the GT depth (2.0-2.5 px), not the constant
    ``ground_truth.flow`` = (0, 2) px, which is off by up to 0.5 px on the ball's front.

Metrics: average end-point error (EPE, px) and average angular error (AAE, degrees, Baker et al.
2011); time = wall-clock ms of one forward :func:`fuse4d.flow.estimate_flow` call per pair
(input conversion included), after one untimed warm-up call per method on a tiny pair (numba
compilation, OpenCV initialisation). OpenCV runs with its default thread count.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import InputFileError
from ..flow import DISParams, available_flow_methods, estimate_flow, read_flo, resolve_flow_params
from ..io import read_intensity_image
from ..metrics import flow_angular_error, flow_endpoint_error
from ..sequence import BallTruth

__all__ = [
    "BenchEntry",
    "BenchResult",
    "FlowPair",
    "ball_interior_erosion",
    "ball_pairs",
    "default_bench_entries",
    "middlebury_pairs",
    "run_flow_benchmark",
    "summarize_flow_benchmark",
]

MIDDLEBURY_SEQUENCES = ("Dimetrodon", "Hydrangea", "RubberWhale", "Venus")

#: |flow| above this marks unknown ground truth in Middlebury ``.flo`` files.
UNKNOWN_FLOW = 1e9


@dataclass(frozen=True)
class BenchEntry:
    """One benchmarked configuration: a label, a registered method and its parameters."""

    label: str
    method: str
    params: Any


@dataclass(frozen=True)
class FlowPair:
    """A frame pair with ground-truth flow (px) and the mask of pixels that are scored."""

    dataset: str
    name: str
    image0: NDArray[np.float32]
    image1: NDArray[np.float32]
    flow_true: NDArray[np.float32]
    mask: NDArray[np.bool_]


@dataclass(frozen=True)
class BenchResult:
    """Scores of one entry on one pair."""

    label: str
    method: str
    paper_method: bool
    dataset: str
    pair: str
    epe: float
    aae: float
    ms: float
    size: tuple[int, int] = field(default=(0, 0))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return {
            "label": self.label,
            "method": self.method,
            "paper_method": self.paper_method,
            "dataset": self.dataset,
            "pair": self.pair,
            "epe_px": self.epe,
            "aae_deg": self.aae,
            "ms": self.ms,
            "height": self.size[0],
            "width": self.size[1],
        }


def default_bench_entries(methods: Iterable[str] | None = None) -> list[BenchEntry]:
    """One entry per registered method with default parameters; DIS as its three presets.

    ``methods`` filters by label (``dis-medium``) or method name (``dis`` = all DIS presets),
    in any case (``DIS``), as ``fuse4d flow -m`` takes them; an unknown name raises
    ``ValueError`` listing the valid ones.
    """
    entries: list[BenchEntry] = []
    for name in available_flow_methods():
        if name == "dis":
            entries.extend(
                BenchEntry(f"dis-{preset}", "dis", DISParams.from_preset(preset))
                for preset in ("ultrafast", "fast", "medium")
            )
        else:
            entries.append(BenchEntry(name, name, resolve_flow_params(name)))
    if methods is None:
        return entries
    wanted = [m.strip().lower() for m in methods if m.strip()]
    valid = {e.label for e in entries} | {e.method for e in entries}
    unknown = [m for m in wanted if m not in valid]
    if unknown:
        raise ValueError(
            f"unknown flow method(s) {', '.join(unknown)}; available: {', '.join(sorted(valid))}"
        )
    return [e for e in entries if e.label in wanted or e.method in wanted]


def middlebury_pairs(directory: str | Path) -> tuple[list[FlowPair], str]:
    """The Middlebury pairs in ``directory`` (``middlebury_flow``), and a reason if none.

    A sequence none of whose three files (``other-data/<seq>/frame10.png``, ``frame11.png``,
    ``other-gt-flow/<seq>/flow10.flo``) exists is left out.

    Raises
    ------
    InputFileError
        A sequence with only some of its files (naming the missing one), or whose frames and
        ground truth differ in size (naming the file that does not match ``frame10.png``), or
        whose ground truth holds no known flow vector (naming ``flow10.flo``: its EPE would be
        NaN, and the dataset mean with it).
    """
    root = Path(directory)
    if not root.is_dir():
        return [], f"{root} not found"
    pairs = []
    for seq in MIDDLEBURY_SEQUENCES:
        frames = root / "other-data" / seq
        paths = (frames / "frame10.png", frames / "frame11.png")
        gt_path = root / "other-gt-flow" / seq / "flow10.flo"
        present = [p.is_file() for p in (*paths, gt_path)]
        if not any(present):
            continue
        if not all(present):
            missing = [p for p, ok in zip((*paths, gt_path), present, strict=True) if not ok]
            raise InputFileError(
                missing[0], f"file not found (the Middlebury sequence {seq} is incomplete)"
            )
        image0, image1 = (read_intensity_image(p) for p in paths)
        gt = np.asarray(read_flo(gt_path), dtype=np.float32)
        for path, shape in ((paths[1], image1.shape), (gt_path, gt.shape[:2])):
            if shape != image0.shape:
                raise InputFileError(
                    path,
                    f"{shape[1]}x{shape[0]} px, but {paths[0].name} of the Middlebury sequence "
                    f"{seq} is {image0.shape[1]}x{image0.shape[0]} px: not from this sequence",
                )
        known = np.all(np.isfinite(gt) & (np.abs(gt) <= UNKNOWN_FLOW), axis=-1)
        if not known.any():
            raise InputFileError(
                gt_path,
                f"no known flow vector (every one is unknown, |flow| > {UNKNOWN_FLOW:g} px, or "
                f"not finite): no ground truth for the Middlebury sequence {seq}",
            )
        gt = np.where(known[..., None], gt, np.float32(0.0))
        pairs.append(FlowPair("middlebury", seq, image0, image1, gt, known))
    return pairs, "" if pairs else f"no Middlebury pairs found under {root}"


def ball_pairs(*, intensity_noise: float, small: bool = False) -> list[FlowPair]:
    """Two frame pairs of the synthetic falling ball with their GT flow and interior mask."""
    from ..synthetic import make_falling_ball

    pairs_t = (4, 9) if small else (10, 25)
    seq = make_falling_ball(
        intensity_noise=intensity_noise, num_frames=max(pairs_t) + 2, small=small, rng=0
    )
    gt = seq.ground_truth
    if gt is None or gt.flow is None or gt.mask is None:
        raise ValueError("make_falling_ball returned no ground-truth flow/mask")
    erosion = ball_interior_erosion(small=small)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erosion + 1, 2 * erosion + 1))
    label = f"ball {intensity_noise * 100:g}%"
    out = []
    for t in pairs_t:
        interior = cv2.erode(gt.mask[t].astype(np.uint8), kernel).astype(bool)
        out.append(
            FlowPair(
                label,
                f"{t}-{t + 1}",
                seq.intensity[t],
                seq.intensity[t + 1],
                _ball_true_flow(gt, t),
                interior,
            )
        )
    return out


def _ball_true_flow(gt: Any, t: int) -> NDArray[np.float32]:
    """Exact image motion of the translating ball: (0, speed_px * Z_c / Z) on ball pixels.

    The ball translates along +Y only, so a surface point keeps its depth Z and moves by
    dv = f * dY / Z px, where f * dY = speed_px * Z_c (speed_px is the centre's motion at the
    centre depth Z_c). This is 2.0-2.5 px on the full-size ball (front surface Z = 560 mm),
    whereas ``ground_truth.flow`` is the constant centre speed (0, 2) px: against that, even a
    perfect tracker scores ≈ 0.4 px EPE. Falls back to ``ground_truth.flow`` when the scene
    geometry is not recorded.
    """
    ball = gt.scene
    if gt.depth is None or not isinstance(ball, BallTruth):
        return np.asarray(gt.flow[t], np.float32)
    z_center = float(np.asarray(ball.center_mm)[t][2])
    speed = ball.speed_px
    flow = np.zeros((*gt.mask[t].shape, 2), np.float32)
    ball = gt.mask[t] & np.isfinite(gt.depth[t])
    flow[..., 1][ball] = speed * z_center / gt.depth[t][ball]
    return flow


def _warm_up(entry: BenchEntry) -> None:
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.random((64, 64)).astype(np.float32), (0, 0), 2.0)
    estimate_flow(image, np.roll(image, 1, axis=1), method=entry.method, params=entry.params)


def run_flow_benchmark(
    entries: Iterable[BenchEntry],
    pairs: Iterable[FlowPair],
    *,
    progress: Callable[[int, int], None] | None = None,
) -> list[BenchResult]:
    """Score every entry on every pair (one timed forward solve each)."""
    entries = list(entries)
    pairs = list(pairs)
    methods = available_flow_methods()
    results = []
    total = len(entries) * len(pairs)
    done = 0
    for entry in entries:
        _warm_up(entry)
        paper = methods[entry.method].paper_method
        for pair in pairs:
            start = time.perf_counter()
            flow = estimate_flow(pair.image0, pair.image1, method=entry.method, params=entry.params)
            ms = (time.perf_counter() - start) * 1e3
            epe = float(flow_endpoint_error(pair.flow_true, flow, roi=pair.mask))
            aae = float(flow_angular_error(pair.flow_true, flow, roi=pair.mask))
            results.append(
                BenchResult(
                    entry.label,
                    entry.method,
                    paper,
                    pair.dataset,
                    pair.name,
                    epe,
                    aae,
                    ms,
                    pair.image0.shape,
                )
            )
            done += 1
            if progress is not None:
                progress(done, total)
    return results


def ball_interior_erosion(*, small: bool = False) -> int:
    """Erosion (px) of the ball's GT mask that leaves the interior where flow errors are
    scored: 6 px at 600x600, scaled with the image (``pixel_scale = fx / 1000``)."""
    from ..synthetic import scene_intrinsics

    return max(1, round(6 * scene_intrinsics(small=small).fx / 1000.0))


def summarize_flow_benchmark(results: Iterable[BenchResult]) -> list[dict[str, Any]]:
    """Per (entry, dataset): mean EPE, mean AAE, mean ms over its pairs; entry order kept."""
    groups: dict[tuple[str, str], list[BenchResult]] = {}
    for r in results:
        groups.setdefault((r.label, r.dataset), []).append(r)
    rows = []
    for (label, dataset), rs in groups.items():
        rows.append(
            {
                "label": label,
                "method": rs[0].method,
                "paper_method": rs[0].paper_method,
                "dataset": dataset,
                "pairs": len(rs),
                "epe_px": float(np.mean([r.epe for r in rs])),
                "aae_deg": float(np.mean([r.aae for r in rs])),
                "ms": float(np.mean([r.ms for r in rs])),
                # every size of the group (Middlebury's pairs differ: 584x388, 420x380, ...)
                "size": ", ".join(dict.fromkeys(f"{r.size[1]}x{r.size[0]}" for r in rs)),
            }
        )
    return rows
