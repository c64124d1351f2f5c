"""One evaluation report: the scoring policy of fuse4d in one place (issue 9 R3, issue 10 §4).

:func:`evaluate` scores a depth video (and, if given, the raw input it came from) and returns a
:class:`MetricsReport`. It decides, once for everything that scores a result (``fuse4d
metrics``, the ``fuse4d run`` summary, ``demo``, ``bench --quality``, the real-data
benchmark):

* **the ROI** (pixels to score): the one given; else the EVALUATION ROI of a synthetic scene
  (ball ROI, central 80 % of plane/sheet); else :func:`~fuse4d.metrics.default_roi` of the
  *raw* depth (the output's when no raw is given), whose depth-step rule follows the
  noise model (A22). One ROI, computed once, for raw and output; every metric but Eq. 8
  (which keeps its own region, EVALUATION §2) is scored on it;
* **the noise model's q** (the step limit of ``bad_steps``, the default ROI and the static
  rule): given; else estimated from the raw video. A single video's own q is not the
  sensor's (a smoothed output reads a far smaller one), so without raw and without a given q
  ``bad_steps`` is not scored;
* **the same pixels** for raw and output: roughness on ROI pixels where Eq. 7 is defined in
  both, RMSE on ROI pixels valid in both, flicker on static pixels valid in every frame of
  both;
* **the static pixels** of the flicker: given; else static in the ground truth (GT depth);
  else detected from the raw video (:func:`~fuse4d.metrics.static_pixels`); a given ROI
  restricts them too (pixels in the ROI in every frame);
* **shape correctness** (Eq. 8) only for the falling ball, only when asked (it is slow).

:class:`RunningEvaluation` is the same policy frame by frame, for streamed recordings whose
frames do not fit in memory (``fuse4d run``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from numbers import Real
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._kernels.flicker import _temporal_tally_kernel
from .._validation import as_float32, check_shape
from ..camera import Intrinsics, depth_to_points
from ..errors import ParameterError, ParameterTypeError, ShapeError
from ..sequence import BallTruth, GroundTruth, Sequence
from .accuracy import FlickerStats, bad_pixel_fraction, depth_rmse, temporal_flicker
from .roi import (
    STATIC_LEVELS,
    STATIC_NOISE_RANGE,
    _check_odd_window,
    _frame_quads,
    _median_noise_sigma,
    default_roi,
    depth_trend,
    is_static,
    noise_sigma_frames,
    scene_roi,
    static_mask_from_ground_truth,
    static_pixels,
)
from .roughness import (
    _POINTS_HINT,
    RoughnessStats,
    _mean_std,
    _roughness_maps_on,
    roughness_maps,
    stats_from_maps,
)
from .shape import ShapeCorrectness, shape_correctness

__all__ = ["MetricsReport", "RunningEvaluation", "Scores", "evaluate"]

#: Threshold of the bad-pixel fraction (mm).
BAD_PIXEL_MM = 1.0

#: Where Eq. 8 is scored: its own region, whatever the ROI (EVALUATION §2).
SHAPE_REGION = (
    "Eq. 8's own region (EVALUATION §2), not the ROI: the ground-truth ball mask eroded by "
    "3 px, in the fixed column band and the rows within 140 px (full size) of the ball centre"
)

#: Why ``bad_steps`` is not scored for one video without a given q.
NO_NOISE_QUAD = (
    "not scored: one video's own depth noise is not the sensor's (a smoothed output reads a "
    "far smaller q, so a far stricter limit); give the sensor's q (noise_quad=, fuse4d "
    "metrics --noise-quad) or score RAW FUSED"
)


@dataclass(frozen=True)
class Scores:
    """The scores of one depth video on a report's pixels (lengths in mm).

    Attributes
    ----------
    roughness : RoughnessStats
        Eq. 7 (and the RMS plane residual) on the report's ROI pixels where Eq. 7 is defined
        (in raw and output alike when the report has both).
    flicker : FlickerStats or None
        Per-pixel std over time and frame-to-frame |Δ| on the report's static pixels (None
        for a single frame).
    rmse_roi : float
        RMSE to GT depth on the ROI pixels valid in GT, output (and raw); NaN without GT.
    rmse : float
        RMSE to GT depth on all GT-valid pixels of the given ROI (of every pixel when no ROI
        was given) where the output (and raw) depth is valid: the same pixels for both (a
        method that deleted its worst pixels looked better); NaN without GT.
    bad_1mm : float
        Fraction of the GT-valid pixels of the given ROI (of every pixel) more than 1 mm off
        (missing depth counts as bad, so deleting pixels does not help).
    fill_rate : float
        Fraction of the pixels of the given ROI (of every pixel), over all frames, with depth.
    shape : ShapeCorrectness or None
        Eq. 8 on the falling ball, when asked for.
    bad_steps : float
        As ``bad_1mm``, with the threshold ``max(1 mm, 2.5 q z^2)`` at the true depth z: the
        depth-noise model's step limit (A22; q of the raw video or the given one; NaN when
        neither is there, see :attr:`MetricsReport.noise_quad`), 1.5 quantisation steps of
        structured-light depth. On sensor depth at metres a fixed 1 mm calls nearly every
        pixel bad, and any averaging that moves values by less than a step "better" (a
        trailing 9-frame mean had fewer pixels > 1 mm off than raw); on the paper's 0.2 mm
        noise at 1 m it equals ``bad_1mm``.
    """

    roughness: RoughnessStats
    flicker: FlickerStats | None = None
    rmse_roi: float = math.nan
    rmse: float = math.nan
    bad_1mm: float = math.nan
    shape: ShapeCorrectness | None = None
    fill_rate: float = math.nan
    bad_steps: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        """Scalars, JSON friendly (NaN kept as float NaN)."""
        out: dict[str, Any] = {
            **self.roughness.to_dict(),
            "roughness_frame_means": self.roughness.frame_means.tolist(),
            "roughness_pixels": int(self.roughness.num_pixels.sum()),
            "rmse_roi": self.rmse_roi,
            "rmse": self.rmse,
            "bad_1mm": self.bad_1mm,
            "bad_steps": self.bad_steps,
            "fill_rate": self.fill_rate,
        }
        f = self.flicker
        out.update(
            flicker_std_median=math.nan if f is None else f.median,
            flicker_std_mean=math.nan if f is None else f.mean,
            flicker_step_mean=math.nan if f is None else f.step_mean,
            flicker_pixels=0 if f is None else f.num_pixels,
        )
        if self.shape is not None:
            out["shape"] = {
                **self.shape.to_dict(),
                "radius_3d_mean": float(np.nanmean(self.shape.radius_3d))
                if np.isfinite(self.shape.radius_3d).any()
                else math.nan,
                "true_radius": self.shape.true_radius,
            }
        return out


#: What each headline number of a report means (used by the CLI tables): key -> (label, unit).
METRIC_MEANINGS: dict[str, tuple[str, str]] = {
    "roughness_mean": ("roughness (Eq. 7), mean over frames", "mm, on the ROI"),
    "roughness_std": ("roughness std over frames", "mm"),
    "rms_residual": ("RMS plane-fit residual (spatial precision)", "mm, on the ROI"),
    "flicker_step_mean": ("flicker: frame-to-frame |Δ|", "mm, static pixels"),
    "flicker_std_mean": (
        "flicker: per-pixel std over time (temporal precision), mean",
        "mm, static pixels",
    ),
    "flicker_std_median": (
        "flicker: per-pixel std over time, median",
        "mm, static pixels; 0 where most never leave their quantisation level",
    ),
    "rmse_roi": ("RMSE to ground truth", "mm, on the ROI"),
    "rmse": ("RMSE to ground truth, whole image", "mm, pixels with depth in every input"),
    "bad_1mm": (
        "pixels > 1 mm off ground truth",
        "fraction of the --roi (else all), missing = bad",
    ),
    "bad_steps": (
        "pixels off ground truth by > max(1 mm, 2.5 q z^2), the noise model's step limit",
        "fraction of the --roi (else all), missing = bad",
    ),
    "fill_rate": ("fill rate: pixels with depth", "fraction of the --roi (else all), all frames"),
}


@dataclass(frozen=True)
class MetricsReport:
    """What :func:`evaluate` measured: output (and raw) scores on one set of pixels.

    Attributes
    ----------
    output : Scores
        Scores of the evaluated video.
    raw : Scores or None
        Scores of the raw input on the same pixels (None when no raw was given).
    roi : (T, H, W) ndarray of bool
        The ROI (pixels to score) before the Eq. 7 validity.
    roi_description : str
        Where the ROI came from.
    static : (H, W) ndarray of bool or None
        The flicker's static pixels (None for one frame).
    static_description : str
        Where they came from.
    window : int
        Roughness window n (px).
    noise_quad : float
        Depth-noise coefficient q (mm^-1) of ``bad_steps``' step limit: the given one, else
        the median over the raw video's frames; NaN without ground truth, and for a single
        video without a given q (its own q is not the sensor's: a smoothed output reads a
        far smaller one and so a far stricter limit).
    noise_quad_description : str
        Where ``noise_quad`` came from, or why it is NaN.
    roi_given : bool
        Whether the ROI was given (then ``rmse`` is on it too, the same as ``rmse_roi``).
    """

    output: Scores
    raw: Scores | None
    roi: NDArray[np.bool_]
    roi_description: str
    static: NDArray[np.bool_] | None
    static_description: str
    window: int
    noise_quad: float = math.nan
    noise_quad_description: str = ""
    roi_given: bool = False

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form: regions, then the output's and the raw's scores."""
        t = self.roi.shape[0]
        out: dict[str, Any] = {
            "window": self.window,
            "num_frames": t,
            "roi": {
                "description": self.roi_description,
                "given": self.roi_given,
                "pixels": int(self.roi.sum()),
                "pixels_per_frame": float(self.roi.sum() / max(t, 1)),
                "pixels_scored": int(self.output.roughness.num_pixels.sum()),
            },
            "static": {
                "description": self.static_description,
                "pixels": 0 if self.static is None else int(self.static.sum()),
            },
            "noise_quad": self.noise_quad,
            "noise_quad_description": self.noise_quad_description,
            "output": self.output.to_dict(),
        }
        if self.output.shape is not None:
            out["shape_region"] = SHAPE_REGION
        if self.raw is not None:
            out["raw"] = self.raw.to_dict()
        return out


def _as_video(
    data: ArrayLike | Sequence, intrinsics: Intrinsics | None, name: str
) -> tuple[NDArray[np.float32], NDArray[np.float32], Intrinsics | None]:
    """(depth (T, H, W), points (T, H, W, 3), intrinsics) of a depth/points array or Sequence."""
    if isinstance(data, Sequence):
        return data.depth, data.points(), data.intrinsics
    arr = np.asarray(data, dtype=np.float32)
    if arr.ndim == 4 and arr.shape[-1] == 3:
        arr = _invalid_to_nan(arr, data)
        return arr[..., 2], arr, intrinsics
    if arr.ndim == 3:
        if intrinsics is None:
            raise ParameterError(f"{name}: depth maps need intrinsics= to give 3D points")
        arr = _invalid_to_nan(arr, data)
        return arr, depth_to_points(arr, intrinsics), intrinsics
    raise ShapeError(name, ("T", "H", "W"), arr.shape, "depth (T, H, W) or points (T, H, W, 3)")


def _invalid_to_nan(arr: NDArray[np.float32], data: object) -> NDArray[np.float32]:
    """Float32 depth ``(T, H, W)`` or points ``(T, H, W, 3)`` ``arr`` (of ``data``) with every
    pixel of invalid depth (0, negative, inf: a 16-bit file's hole is 0) NaN, as
    :func:`~fuse4d.sequence.sanitize_depth` does: ``data`` is never written to, and nothing is
    copied where every depth is valid."""
    z = arr if arr.ndim == 3 else arr[..., 2]
    bad = ~(np.isfinite(z) & (z > 0))
    if bad.any():
        if not isinstance(data, np.ndarray) or np.may_share_memory(arr, data):
            arr = arr.copy()
        arr[bad] = np.nan
    return arr


def _frame_selection(
    frames: slice | ArrayLike, num_frames: int, name: str
) -> slice | NDArray[np.int64]:
    """``frames`` (a slice or indices of a ``num_frames``-frame video) checked: a
    ParameterError naming ``name`` where it selects no frame or an index is out of range (an
    IndexError, or a silently all-NaN report for an empty slice)."""
    if isinstance(frames, slice):
        try:
            count = len(range(num_frames)[frames])
        except (TypeError, ValueError):  # slice("a"), slice(0, 3, 0)
            raise ParameterError(
                f"{name} must be a slice of whole numbers, got {frames!r}"
            ) from None
        if count == 0:
            raise ParameterError(
                f"{name} {frames!r} selects no frame of the {num_frames}-frame video"
            )
        return frames
    idx = np.asarray(frames)
    if idx.ndim != 1 or (idx.size and (idx.dtype == np.bool_ or idx.dtype.kind not in "iu")):
        raise ParameterTypeError(
            f"{name} must be a slice or a 1-D array of frame indices, got {idx.dtype} of "
            f"shape {idx.shape}"
        )
    if idx.size == 0:
        raise ParameterError(f"{name} selects no frame of the {num_frames}-frame video")
    outside = (idx < -num_frames) | (idx >= num_frames)
    if outside.any():
        raise ParameterError(
            f"{name} holds frame {int(idx[outside][0])}, outside the {num_frames}-frame video "
            f"(0 .. {num_frames - 1})"
        )
    return idx.astype(np.int64)


def _user_roi(roi: ArrayLike, shape: tuple[int, int, int]) -> NDArray[np.bool_]:
    m = np.asarray(roi)
    if m.dtype != np.bool_:
        raise ParameterTypeError(f"roi must be a boolean mask, got dtype {m.dtype}")
    if m.shape == shape[1:]:
        return np.broadcast_to(m, shape)
    if m.shape != shape:
        raise ShapeError("roi", shape, m.shape, "a (H, W) or (T, H, W) bool mask")
    return m


def evaluate(
    output: ArrayLike | Sequence,
    *,
    intrinsics: Intrinsics | None = None,
    raw: ArrayLike | Sequence | None = None,
    ground_truth: GroundTruth | None = None,
    roi: ArrayLike | None = None,
    static: ArrayLike | None = None,
    window: int = 5,
    max_step: float = 10.0,
    noise_quad: float | None = None,
    frames: slice | NDArray[np.integer] | None = None,
    shape: bool = False,
    shape_frames: ArrayLike | None = None,
    rng: int | np.random.Generator | None = 0,
    progress: Callable[[int, int], None] | None = None,
) -> MetricsReport:
    """Score a depth video, and the raw input it came from, on the same pixels.

    Parameters
    ----------
    output : (T, H, W) depth, (T, H, W, 3) points or Sequence
        The video to score (mm, NaN = invalid); a Sequence brings its intrinsics and ground
        truth.
    intrinsics : Intrinsics, optional
        Camera; needed to turn depth maps into points.
    raw : (T, H, W) depth, (T, H, W, 3) points or Sequence, optional
        The raw input (or any second output to compare with): scored on the same pixels, and
        the source of the default ROI and of the detected static pixels.
    ground_truth : GroundTruth, optional
        Ground truth (default: that of ``raw`` or ``output`` when a Sequence): RMSE and bad
        pixels against its depth, the scene ROI and static pixels of a synthetic scene, Eq. 8
        on the ball.
    roi : (H, W) or (T, H, W) bool, optional
        Pixels to score; applies to every metric (flicker: pixels in it in every frame) but
        the shape correctness, which Eq. 8 scores on its own region (:data:`SHAPE_REGION`).
        Default: the scene ROI of a synthetic scene, else :func:`default_roi` of the raw depth.
    static : (H, W) bool, optional
        Pixels known to be static, for the flicker. Default: static in the GT depth, else
        :func:`static_pixels` of the raw video.
    window : int, optional
        Roughness window n (odd, px).
    max_step : float, optional
        Floor (mm) of the depth-step limit of the default ROI (the static detection follows
        the noise alone).
    noise_quad : float, optional
        The sensor's depth-noise coefficient q (1/mm; σ(z) ≈ q z², e.g.
        :func:`~fuse4d.motion.estimate_noise_quad` of its raw depth): the step limit
        ``max(1 mm, 2.5 q z²)`` of ``bad_steps``, of the default ROI and of the static rule.
        Default: estimated from each raw frame; without ``raw``, the default ROI and static
        rule use the output's own estimate and ``bad_steps`` is NaN (:data:`NO_NOISE_QUAD`).
    frames : slice or index array, optional
        Frames to score (e.g. the interior frames whose fusion window is complete).
    shape : bool, optional
        Also compute the shape correctness (Eq. 8; falling ball only; ~1 s/frame full size).
    shape_frames : array of int, optional
        Frames (of the scored ones) for Eq. 8; default all.
    rng : int, Generator or None, optional
        Seed of the MLESAC fits (the same for raw and output).
    progress : callable, optional
        ``progress(done, total)`` during the shape fits.

    Returns
    -------
    MetricsReport

    Examples
    --------
    >>> from fuse4d.synthetic import make_falling_ball
    >>> seq = make_falling_ball(small=True, num_frames=3)
    >>> rep = evaluate(seq.ground_truth.depth, raw=seq, intrinsics=seq.intrinsics)
    >>> bool(rep.output.roughness.mean < rep.raw.roughness.mean)
    True
    >>> rep.roi_description.split(":")[0]
    'ball ROI'
    """
    if noise_quad is not None and (
        isinstance(noise_quad, bool)
        or not isinstance(noise_quad, Real)
        or not (math.isfinite(noise_quad) and noise_quad >= 0)
    ):
        raise ParameterError(f"noise_quad must be a finite number >= 0 (1/mm), got {noise_quad!r}")
    window = _check_odd_window(window, 3)
    k = intrinsics
    for src in (output, raw):
        if k is None and isinstance(src, Sequence):
            k = src.intrinsics
    out_d, out_p, _ = _as_video(output, k, "output")
    gt = ground_truth
    raw_d = raw_p = None
    if raw is not None:
        raw_d, raw_p, _ = _as_video(raw, k, "raw")
        if raw_d.shape != out_d.shape:
            raise ShapeError("raw", out_d.shape, raw_d.shape, "raw and output must match")
        if gt is None and isinstance(raw, Sequence):
            gt = raw.ground_truth
    if gt is None and isinstance(output, Sequence):
        gt = output.ground_truth
    num_t = out_d.shape[0]
    sel: slice | NDArray[np.integer] = slice(None)
    if frames is not None:
        sel = _frame_selection(frames, num_t, "frames")
        if roi is not None and np.ndim(roi) == 3 and np.shape(roi)[0] != num_t:
            raise ShapeError(
                "roi",
                (num_t, *out_d.shape[1:]),
                np.shape(roi),
                "a (T, H, W) roi has one mask per frame of the whole video",
            )
        out_d, out_p = out_d[sel], out_p[sel]
        if raw_d is not None and raw_p is not None:
            raw_d, raw_p = raw_d[sel], raw_p[sel]
        if gt is not None:
            gt = gt.select(sel, num_t)
        if roi is not None and np.ndim(roi) == 3:
            roi = np.asarray(roi)[sel]
    ref_d = out_d if raw_d is None else raw_d
    full = out_d.shape

    # the noise model's q of each raw frame (A22), given or estimated once: the default ROI's
    # step limit, the static rule (their median) and the step limit of bad_steps
    quads = _frame_quads(ref_d, noise_quad)

    # ---- the ROI: one, for raw and output
    if roi is not None:
        region = _user_roi(roi, full)
        roi_desc = "the given mask"
    elif gt is not None and gt.scene is not None:
        region, roi_desc = scene_roi(gt, intrinsics=k, window=window)
    else:
        region = default_roi(ref_d, window=window, max_step=max_step, noise_quad=quads)
        roi_desc = (
            f"{window}x{window} windows fully valid in the {'raw' if raw_d is not None else ''}"
            f"{' ' if raw_d is not None else ''}depth, no step between neighbours above "
            f"max({max_step:g} mm, 2.5 q z^2) (noise model A22)"
        )

    # ---- the static pixels of the flicker
    static_region, static_desc = None, "one frame: no flicker"
    if num_t >= 2 and out_d.shape[0] >= 2:
        if static is not None:
            static_region = np.asarray(static)
            if static_region.dtype != np.bool_:
                raise ParameterTypeError(
                    f"static must be a boolean mask, got dtype {static_region.dtype}"
                )
            if static_region.shape != full[1:]:
                raise ShapeError("static", full[1:], static_region.shape, "a (H, W) bool mask")
            static_desc = "the given static mask"
        elif gt is not None and gt.depth is not None:
            static_region = static_mask_from_ground_truth(gt)
            static_desc = "static in the ground truth"
        else:
            sigma = _median_noise_sigma(ref_d)
            static_region = static_pixels(
                ref_d, noise_quad=float(np.median(quads)), noise_sigma=sigma
            )
            static_desc = f"{_static_rule(sigma)} ({'raw' if raw_d is not None else 'input'})"
        if roi is not None:
            static_region = static_region & region.all(axis=0)
            static_desc += ", inside the given ROI"
        static_region = static_region & np.isfinite(out_d).all(axis=0)
        if raw_d is not None:
            static_region = static_region & np.isfinite(raw_d).all(axis=0)
        static_desc += "; valid in every frame of " + ("both" if raw_d is not None else "it")

    # ---- the same pixels for raw and output
    out_maps = roughness_maps(out_p, window=window)
    raw_maps = None if raw_p is None else roughness_maps(raw_p, window=window)
    scored = region & np.isfinite(out_maps[0])
    depth_ok = np.isfinite(out_d)
    if raw_maps is not None and raw_d is not None:
        scored = scored & np.isfinite(raw_maps[0])
        depth_ok = depth_ok & np.isfinite(raw_d)
    whole = None if roi is None else region
    shape_sel = (
        None
        if shape_frames is None
        else _frame_selection(np.asarray(shape_frames), full[0], "shape_frames")
    )

    # the step limit of bad_steps: one q for raw and output, given or from the raw video
    quad, quad_desc = math.nan, "no ground truth"
    if gt is not None and gt.depth is not None:
        if noise_quad is not None:
            quad, quad_desc = float(noise_quad), "given"
        elif raw_d is not None:
            quad, quad_desc = float(np.median(quads)), "median over the raw video's frames"
        else:
            quad_desc = NO_NOISE_QUAD

    def score(depth: NDArray, points: NDArray, maps: tuple[NDArray, NDArray]) -> Scores:
        flick = None
        if static_region is not None:
            flick = temporal_flicker(depth, static=static_region)
        rmse_roi = rmse = bad = bad_steps = math.nan
        if gt is not None and gt.depth is not None:
            rmse_roi = depth_rmse(gt.depth, depth, roi=region & depth_ok)
            rmse = depth_rmse(gt.depth, depth, roi=depth_ok if whole is None else whole & depth_ok)
            bad = bad_pixel_fraction(gt.depth, depth, threshold=BAD_PIXEL_MM, roi=whole)
            if math.isfinite(quad):
                bad_steps = bad_pixel_fraction(
                    gt.depth, depth, threshold=BAD_PIXEL_MM, roi=whole, noise_quad=quad
                )
        sc = None
        if shape and gt is not None and isinstance(gt.scene, BallTruth):
            g, p = gt, points
            if shape_sel is not None:
                g, p = gt.select(shape_sel, depth.shape[0]), points[shape_sel]
            sc = shape_correctness(g, p, rng=rng, progress=progress)
        has_depth = np.isfinite(depth) if whole is None else np.isfinite(depth)[whole]
        fill = float(has_depth.mean()) if has_depth.size else math.nan
        return Scores(
            stats_from_maps(*maps, scored), flick, rmse_roi, rmse, bad, sc, fill, bad_steps
        )

    return MetricsReport(
        output=score(out_d, out_p, out_maps),
        raw=None
        if raw_d is None or raw_p is None or raw_maps is None
        else score(raw_d, raw_p, raw_maps),
        roi=region,
        roi_description=roi_desc,
        static=static_region,
        static_description=static_desc,
        window=window,
        noise_quad=quad,
        noise_quad_description=quad_desc,
        roi_given=roi is not None,
    )


#: The float64 per-pixel state of :class:`RunningEvaluation`'s flicker tally.
_TALLY_ARRAYS = ("zmin", "zmax", "zsum", "ztsum", "raw_step", "out_step", "prev_raw", "prev_out")


class RunningEvaluation:
    """:func:`evaluate`'s raw-vs-output policy, fed one frame at a time (streamed recordings).

    Per frame: Eq. 7 on the default ROI of the raw frame (noise-model step rule), on pixels
    where it is defined in raw and output. Over the stream: frame-to-frame |Δ| of raw and
    output on the pixels that turn out static (:func:`~fuse4d.metrics.static_pixels`'s rule on
    running per-pixel min/max/mean of the raw depth, valid in every frame). Memory: a few
    ``(H, W)`` arrays, whatever the length.

    Parameters
    ----------
    window : int, optional
        Roughness window n (odd, px).
    max_step : float, optional
        Floor (mm) of the depth-step limit.
    every : int, optional
        Score the roughness (Eq. 7, the plane-fit residual) on every ``every``-th frame only
        (frames 0, every, 2 every, ...; raw and output on the same frames and pixels); the
        flicker always uses every frame. 1 = all frames. ``fuse4d run`` uses 4: the two
        roughness maps of a frame cost almost as much as its fusion stage (uva 640 x 480: 2 x
        6.5 ms against 16 ms, stop 40).
    total_frames : int, optional
        Frames the stream will have, where known: the noise σ₀ of the static rule is then
        estimated on the frames :func:`evaluate` uses (:func:`~fuse4d.metrics.roi.
        noise_sigma_frames`, at most 8), so that both find the same static pixels; else on
        the roughness frames.

    Notes
    -----
    Eq. 7 is evaluated on the ROI pixels only (:func:`~fuse4d.metrics.roughness._roughness_maps_on`,
    the same values as :func:`~fuse4d.metrics.roughness_maps` there), since no other pixel is
    scored.
    """

    def __init__(
        self,
        *,
        window: int = 5,
        max_step: float = 10.0,
        every: int = 1,
        total_frames: int | None = None,
    ) -> None:
        if isinstance(every, bool) or int(every) != every or every < 1:
            raise ParameterError(f"every must be an integer >= 1, got {every!r}")
        window = _check_odd_window(window, 3)
        self._sigma_frames = (
            None if total_frames is None else set(noise_sigma_frames(int(total_frames)))
        )
        self.window = window
        self.max_step = max_step
        self.every = int(every)
        self.roughness_frames = 0
        self.frames = 0
        self._raw_means: list[float] = []
        self._out_means: list[float] = []
        self._raw_rms: list[float] = []
        self._out_rms: list[float] = []
        self._pixels = 0
        self._quads: list[float] = []
        self._sigmas: list[float] = []
        self._state: dict[str, NDArray[Any]] | None = None

    def _noise_sigma(self) -> float:
        """The raw depth's noise σ₀ (mm): the median of the frames' estimates."""
        return float(np.median(self._sigmas)) if self._sigmas else 0.0

    def add(
        self,
        raw_points: ArrayLike,
        output_points: ArrayLike,
        *,
        noise_quad: float | None = None,
        noise_sigma: float | None = None,
    ) -> None:
        """Score one frame: raw and output ``(H, W, 3)`` point maps (mm). ``noise_quad`` and
        ``noise_sigma``: the raw depth's noise coefficient q (1/mm) and noise σ₀ (mm) where
        the caller has them (:meth:`~fuse4d.fusion.FusionEngine.input_noise_quad`); None:
        estimated here, q with the engine's estimator, σ₀ with
        :func:`~fuse4d.motion.estimate_depth_noise` as :func:`evaluate` does (on the roughness
        frames only; the engine's own σ₀ is measured against another reference and is not
        the same number)."""
        rp = as_float32(raw_points, name="raw_points")[None]
        op = as_float32(output_points, name="output_points")[None]
        check_shape(rp[0], ("H", "W", 3), name="raw_points", hint=_POINTS_HINT)
        if self._state is not None:
            size = (*self._state["valid"].shape, 3)
            check_shape(rp[0], size, name="raw_points", hint="the size of the earlier frames")
        check_shape(op[0], rp.shape[1:], name="output_points", hint="the size of raw_points")
        rd, od = rp[..., 2], op[..., 2]
        quad = float(_frame_quads(rd, noise_quad)[0])
        if noise_sigma is not None:
            self._sigmas.append(float(noise_sigma))
        elif (
            self.frames in self._sigma_frames
            if self._sigma_frames is not None
            else self.frames % self.every == 0
        ):
            from ..motion import estimate_depth_noise

            self._sigmas.append(estimate_depth_noise(rd[0]))
        if self.frames % self.every == 0:
            self.roughness_frames += 1
            region = default_roi(rd, window=self.window, max_step=self.max_step, noise_quad=quad)
            raw_maps = _roughness_maps_on(rp, region, window=self.window)
            out_maps = _roughness_maps_on(op, region, window=self.window)
            scored = region & np.isfinite(raw_maps[0]) & np.isfinite(out_maps[0])
            rs, os_ = stats_from_maps(*raw_maps, scored), stats_from_maps(*out_maps, scored)
            if scored.any():
                self._raw_means.append(float(rs.frame_means[0]))
                self._out_means.append(float(os_.frame_means[0]))
                self._raw_rms.append(float(rs.frame_rms_means[0]))
                self._out_rms.append(float(os_.frame_rms_means[0]))
                self._pixels += int(scored.sum())
        self._quads.append(quad)
        self._add_temporal(rd[0], od[0])
        self.frames += 1

    def _add_temporal(self, rd: NDArray[np.floating], od: NDArray[np.floating]) -> None:
        """Add one frame's raw and output depth (H, W) mm to the flicker state (float64)."""
        first = self._state is None
        if first:
            shape = rd.shape
            self._state = {"valid": np.empty(shape, np.bool_)} | {
                name: np.empty(shape, np.float64) for name in _TALLY_ARRAYS
            }
        st = self._state
        _temporal_tally_kernel(
            rd,
            od,
            first,
            float(self.frames),
            st["valid"],
            st["zmin"],
            st["zmax"],
            st["zsum"],
            st["ztsum"],
            st["raw_step"],
            st["out_step"],
            st["prev_raw"],
            st["prev_out"],
        )

    def result(self) -> dict[str, Any]:
        """The scores so far (mm): roughness raw/output on the same pixels, flicker |Δ|.

        Keys: ``raw_roughness``, ``output_roughness`` (mean over frames of the frame mean of
        Eq. 7), ``raw_rms_residual``, ``output_rms_residual``, ``roughness_pixels``,
        ``roughness_frames`` (frames scored for roughness), ``frames``, ``raw_flicker``, ``output_flicker`` (mean frame-to-frame |Δ| on static pixels, NaN for
        fewer than 2 frames), ``static_pixels``, ``roi_description``,
        ``static_description``.
        """
        res: dict[str, Any] = {
            "raw_roughness": _mean_std(np.asarray(self._raw_means, dtype=np.float64))[0],
            "output_roughness": _mean_std(np.asarray(self._out_means, dtype=np.float64))[0],
            "raw_rms_residual": _mean_std(np.asarray(self._raw_rms, dtype=np.float64))[0],
            "output_rms_residual": _mean_std(np.asarray(self._out_rms, dtype=np.float64))[0],
            "roughness_pixels": self._pixels,
            "roughness_frames": self.roughness_frames,
            "frames": self.frames,
            "raw_flicker": math.nan,
            "output_flicker": math.nan,
            "static_pixels": 0,
            "roi_description": (
                f"{self.window}x{self.window} windows fully valid in the raw frame, no step "
                f"between neighbours above max({self.max_step:g} mm, 2.5 q z^2); pixels where "
                "Eq. 7 is defined in raw and output"
                + (
                    ""
                    if self.every == 1
                    else f"; on {self.roughness_frames} of {self.frames} frames (one in "
                    f"{self.every}, from frame 0)"
                )
            ),
            "static_description": _static_rule(self._noise_sigma()) + " (raw)",
        }
        st = self._state
        if st is not None and self.frames >= 2:
            quad = float(np.median(self._quads))
            with np.errstate(invalid="ignore"):
                mean = st["zsum"] / self.frames
                trend = depth_trend(st["zsum"], st["ztsum"], self.frames)
                static = st["valid"] & is_static(
                    st["zmin"], st["zmax"], mean, quad, noise_sigma=self._noise_sigma(),
                    trend=trend, frames=self.frames,
                )  # fmt: skip
            if static.any():
                pairs = self.frames - 1
                res["raw_flicker"] = float(st["raw_step"][static].mean() / pairs)
                res["output_flicker"] = float(st["out_step"][static].mean() / pairs)
            res["static_pixels"] = int(static.sum())
        return res


def _static_rule(noise_sigma: float) -> str:
    """How :func:`~fuse4d.metrics.static_pixels` found the static pixels, in words."""
    return (
        "detected: valid in every frame, depth range over time within the noise (<= "
        f"{STATIC_LEVELS:g} quantisation steps or {STATIC_NOISE_RANGE:g} x the depth noise "
        f"{noise_sigma:.3g} mm)"
    )
