"""``fuse4d report``: a self-contained HTML page that shows whether fusion helped, in time.

:func:`write_report` reads the raw recording and the fused result (files of any layout
:mod:`fuse4d.io` reads, or arrays), streams them in chunks of frames, and writes ``DIR/``::

    report.html    the page (inline CSS, figures as data URIs, no network access)
    compare.mp4    raw | fused | |raw - fused| over normal-shaded raw | fused | support
    metrics.json   every number of the page, with what it means
    cloud_raw.ply, cloud_fused.ply   the point cloud of the rendered frame

Memory does not grow with the sequence length: frames are read ``chunk_frames`` at a time,
the video is encoded frame by frame and the x–t slices keep one line per frame.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Iterable, Mapping
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._json import dumps
from ..camera import depth_to_points
from ..errors import ParameterError, ShapeError
from ..holes import _SourceTally
from ..metrics.evaluate import _static_rule
from ..metrics.roi import box_mask, depth_trend, is_static, noise_sigma_frames
from ..metrics.roi import parse_box as parse_roi
from ..motion import estimate_depth_noise, estimate_noise_quad
from ..sequence import Sequence
from ._sources import RawSource, open_fused, open_raw
from .planes import MIN_FIT_PIXELS, Plane, detect_planes, given_plane
from .render import colorize, normal_map, shade_points, splat_points
from .video import Mp4Writer, choose_codec, count_video_frames, video_rate
from .xt import MotionProfile, XtSlice, choose_line

if TYPE_CHECKING:
    from .layout import VideoLayout

__all__ = ["DEFINITIONS", "choose_codec", "count_video_frames", "parse_roi", "write_report"]

#: Frame rate (frames/s) of the video where neither --fps nor the input gives a usable one.
DEFAULT_VIDEO_FPS = 10.0

#: Meaning of each metric, as written into the page and ``metrics.json``.
DEFINITIONS = {
    "fill_rate": "fraction of all pixels of all frames with valid depth",
    "roughness_mean": (
        "paper Eq. 7, 5x5 window: mean over frames of the frame-mean roughness Pi on the "
        "default ROI of the raw frame (window fully valid, no neighbour step beyond the noise "
        "model's limit max(10 mm, 2.5 q z^2)) where Pi is defined for every method (the same "
        "pixels for all)"
    ),
    "roughness_std": "std over frames of the frame-mean roughness (temporal fluctuation)",
    "rms_residual": "RMS residual of the 5x5 local plane fit, same pixels as the roughness",
    "spatial_precision": (
        "vendor 'plane-fit RMS': RMS distance to the least-squares plane of each detected "
        "(or --roi given) planar region, same pixels for all methods, mean over frames"
    ),
    "flicker_mean": (
        "flicker: per-pixel std over time (temporal precision), mean over static pixels "
        "(pixels valid in every frame of every method; fuse4d metrics' flicker_std_mean)"
    ),
    "flicker_median": (
        "flicker: per-pixel std over time, median over the same pixels (flicker_std_median); "
        "0 where most never leave their quantisation level"
    ),
    "rmse": "RMSE to the ground truth on pixels valid in the truth and in every method",
    "bad_pixels": "fraction of ground-truth-valid pixels off by > 1 mm (missing depth = bad)",
    "bad_steps": (
        "fraction of ground-truth-valid pixels off by more than the depth-noise model's step "
        "limit max(1 mm, 2.5 q z^2) at the true depth z, q from the raw video (noise_quad; "
        "1.5 quantisation steps of structured-light depth; missing depth = bad)"
    ),
}


def _check_compare(compare: Iterable[str]) -> list[str]:
    from ..baselines import get_baseline

    names = [c.strip() for c in compare if c.strip()]
    for name in names:
        info = get_baseline(name)  # ValueError listing the valid names
        if not info.available:
            raise ParameterError(
                f"comparison method {name!r} needs the optional extra fuse4d[{info.needs}] "
                "(its package is not installed)"
            )
        if name in ("raw", "fused"):
            raise ParameterError(f"{name!r} is always shown; do not pass it to compare")
    if len(set(names)) != len(names):
        raise ParameterError(f"compare lists a method twice: {names}")
    return names


class _GroundTruth:
    """Ground-truth depth in chunks: from the raw input, another sequence, or an array."""

    def __init__(self, given: Any, raw: RawSource) -> None:
        self._source: RawSource | None = None
        self._array: NDArray[np.float32] | None = None
        self.name = ""
        if given is None:
            self.available = raw.has_ground_truth
            self._from_raw = True
            self.name = "stored with the input"
            return
        self._from_raw = False
        self.available = True
        if isinstance(given, str | PathLike | Sequence):
            same = raw.part is not None and not isinstance(given, Sequence)
            self._source = open_raw(given, {"frames": raw.part} if same else None)
            self.name = str(given) if not isinstance(given, Sequence) else "given sequence"
            if self._source.num_frames != raw.num_frames or self._source.shape != raw.shape:
                raise ShapeError(
                    "ground_truth",
                    (raw.num_frames, *raw.shape),
                    (self._source.num_frames, *self._source.shape),
                    "one frame per input frame",
                )
        else:
            arr = np.asarray(given, dtype=np.float32)
            if arr.shape != (raw.num_frames, *raw.shape):
                raise ShapeError("ground_truth", (raw.num_frames, *raw.shape), arr.shape, "mm")
            self._array = arr
            self.name = "given array"

    def depth(self, chunk: Sequence, start: int, stop: int) -> NDArray[np.float32] | None:
        """GT depth of frames ``start:stop`` (``chunk`` is the raw chunk of those frames)."""
        if not self.available:
            return None
        if self._from_raw:
            gt = chunk.ground_truth
            return None if gt is None or gt.depth is None else np.asarray(gt.depth)
        if self._array is not None:
            return self._array[start:stop]
        assert self._source is not None
        seq = self._source.chunk(start, stop)
        gt = seq.ground_truth
        return np.asarray(gt.depth) if gt is not None and gt.depth is not None else seq.depth

    def close(self) -> None:
        if self._source is not None:
            self._source.close()


def _chunks(total: int, size: int) -> Iterable[tuple[int, int]]:
    for a in range(0, total, size):
        yield a, min(total, a + size)


def _nice_ceiling(x: float) -> float:
    """Round up to 1, 2 or 5 times a power of ten."""
    if not (math.isfinite(x) and x > 0):
        return 1.0
    p = 10.0 ** math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        if x <= m * p * (1 + 1e-9):
            return m * p
    return 10.0 * p


class _Scan:
    """First pass over the raw input: motion per line, quiet pixels, ranges, GT static mask,
    valid pixels per frame (in all and inside ``roi_mask``)."""

    def __init__(
        self,
        raw: RawSource,
        gt: _GroundTruth,
        chunk_frames: int,
        roi_mask: NDArray[np.bool_] | None = None,
    ) -> None:
        from ..metrics import default_roi, roughness_maps

        h, w = raw.shape
        t_total = raw.num_frames
        self.motion = MotionProfile((h, w))
        i1 = np.zeros((h, w))
        i2 = np.zeros((h, w))
        d1 = np.zeros((h, w))
        d2 = np.zeros((h, w))
        dn = np.zeros((h, w), dtype=np.int64)
        # the depth rule of fuse4d.metrics.static_pixels (as `fuse4d metrics` and the run
        # summary apply it): running min, max and sum of t z, and sigma0 of the same frames
        zmin = np.full((h, w), np.inf)
        zmax = np.full((h, w), -np.inf)
        ztsum = np.zeros((h, w))
        sigma_frames = set(noise_sigma_frames(t_total))
        sigmas: list[float] = []
        lows: list[float] = []
        highs: list[float] = []
        quads: list[float] = []  # depth-noise q of each frame (bad_steps' step limit)
        gt_static = np.ones((h, w), dtype=bool) if gt.available else None
        gt_first: NDArray[np.float32] | None = None
        step = max(1, t_total // 24)
        # roughness range of the figures: 99th percentile of Pi on a few frames (the
        # rendered frame alone gave 0-1 mm where it had no depth)
        rough_step = max(1, math.ceil(t_total / 8))
        rough_highs: list[float] = []
        #: valid raw pixels of each frame, and inside the ROI (the frame choices)
        self.valid_counts = np.zeros(t_total, dtype=np.int64)
        self.roi_counts = np.zeros(t_total, dtype=np.int64)
        for a, b in _chunks(t_total, chunk_frames):
            seq = raw.chunk(a, min(t_total, b + 1))  # one frame more: GT flow of pair b-1 -> b
            for j in range(b - a):
                t = a + j
                d = seq.depth[j]
                i = seq.intensity[j]
                self.motion.add(d, i)
                quads.append(estimate_noise_quad(d))
                i1 += i
                i2 += np.square(i, dtype=np.float64)
                ok = np.isfinite(d)
                x = np.where(ok, d, 0.0)
                d1 += x
                d2 += x * x
                dn += ok
                self.valid_counts[t] = int(ok.sum())
                if roi_mask is not None:
                    self.roi_counts[t] = int(np.count_nonzero(ok & roi_mask))
                ztsum += t * x
                np.fmin(zmin, d, out=zmin, where=ok)
                np.fmax(zmax, d, out=zmax, where=ok)
                if t in sigma_frames:
                    sigmas.append(estimate_depth_noise(d))
                if t % step == 0 and ok.any():
                    lo, hi = np.percentile(d[ok], [1.0, 99.0])
                    lows.append(float(lo))
                    highs.append(float(hi))
                if t % rough_step == 0 and ok.any():
                    pi = roughness_maps(depth_to_points(d, raw.intrinsics))[0]
                    vals = pi[default_roi(d) & np.isfinite(pi)]
                    if vals.size:
                        rough_highs.append(float(np.percentile(vals, 99)))
            if gt_static is not None:
                gdepth = gt.depth(seq, a, min(t_total, b + 1))
                if gdepth is not None:
                    if gt_first is None:
                        gt_first = gdepth[0].copy()
                    for j in range(b - a):
                        gt_static &= np.isfinite(gdepth[j]) & (gdepth[j] == gt_first)
                flow = None if seq.ground_truth is None else seq.ground_truth.flow
                if gt._from_raw and flow is not None and len(flow):
                    gt_static &= np.all(np.asarray(flow)[: b - a] == 0, axis=(0, 3))
        n = float(t_total)
        self.intensity_std = np.sqrt(np.maximum(i2 / n - (i1 / n) ** 2, 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = d1 / dn
            self.raw_std = np.where(
                dn == t_total, np.sqrt(np.maximum(d2 / dn - mean * mean, 0.0)), np.nan
            )
        self.raw_mean = np.where(dn > 0, mean, np.nan)
        self.all_valid = dn == t_total
        self.frames = t_total
        self.depth_range = (float(np.median(lows)), float(np.median(highs))) if lows else (0.0, 1.0)
        if not self.depth_range[1] > self.depth_range[0]:
            self.depth_range = (self.depth_range[0] - 1.0, self.depth_range[0] + 1.0)
        #: upper end of the roughness scale (mm): median over sampled frames of the 99th
        #: percentile of the raw Pi on their default ROI (1 mm where none has one)
        self.rough_max = _nice_ceiling(float(np.median(rough_highs)) if rough_highs else 1.0)
        self.gt_static = gt_static
        self.noise_quad = float(np.median(quads)) if quads else 0.0
        self.noise_sigma = float(np.median(sigmas)) if sigmas else 0.0
        self._depth_static = self.all_valid & is_static(
            zmin, zmax, np.where(self.all_valid, mean, 0.0), self.noise_quad,
            noise_sigma=self.noise_sigma, trend=depth_trend(d1, ztsum, t_total),
            frames=t_total,
        )  # fmt: skip
        # the range rule alone on pixels valid in at least half of the frames, for plane
        # detection: one frame without depth (a dropped frame) left no pixel valid in every
        # frame, so no static pixel and no plane
        mostly = dn >= max(2, (t_total + 1) // 2)
        self.mostly_static = mostly & is_static(
            zmin, zmax, np.where(mostly, mean, 0.0), self.noise_quad,
            noise_sigma=self.noise_sigma,
        )  # fmt: skip

    def static_mask(self) -> tuple[NDArray[np.bool_], str]:
        """Pixels seeing a static surface and how they were found."""
        if self.frames < 2:  # every pixel was "static" in one frame, with a flicker of 0
            return np.zeros_like(self.all_valid), "one frame: no flicker"
        if self.gt_static is not None:
            return self.gt_static & self.all_valid, "static in the ground truth"
        if not self.all_valid.any():
            return np.zeros_like(self.all_valid), "no pixel valid in every frame"
        # the rule of `fuse4d metrics` and the run summary (it was "quiet intensity", another
        # set of pixels: colour resampled onto a wider depth grid is 0, quiet, outside the
        # colour camera's view, 58 % of a RealSense bag)
        return self._depth_static, _static_rule(self.noise_sigma) + " (raw)"


def _sixth_panel(
    layout: VideoLayout,
    support: NDArray[Any] | None,
    valid: NDArray[np.bool_],
    support_max: float,
    source: NDArray[np.uint8] | None,
    j: int,
) -> NDArray[np.uint8] | None:
    """The video's sixth panel: the frame's support, else its source codes, else None."""
    from .layout import source_rgb

    if support is not None:
        values = layout.fit_values(np.where(valid, support.astype(np.float32), np.nan))
        return colorize(values, vmin=0.0, vmax=support_max, cmap="viridis")
    if layout.show_source and source is not None:
        return source_rgb(layout.fit_values(source[j].astype(np.float32)).astype(np.uint8))
    return None


def _nearest(candidates: NDArray[np.bool_], target: int) -> int | None:
    """The index of a True of ``candidates`` nearest ``target`` (the earlier of two), else
    None."""
    idx = np.flatnonzero(candidates)
    return None if idx.size == 0 else int(idx[np.argmin(np.abs(idx - target))])


def _pick_pixels(
    scan: _Scan, static: NDArray[np.bool_], line_axis: str, line: int
) -> list[tuple[int, int, str]]:
    """A typical and a noisy static pixel, and the busiest pixel on the x–t line."""
    out: list[tuple[int, int, str]] = []
    import cv2

    # inside the static region (2 px from any moving or invalid pixel) where it has room
    core = cv2.erode(static.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    std = np.where(core if core.any() else static, scan.raw_std, np.nan)
    h, w = std.shape
    # away from the border where possible (the first match in raster order lay on row 0, its
    # label outside the image), and of equal candidates the one nearest the centre
    my, mx = max(1, h // 12), max(1, w // 12)
    inner = np.full_like(std, np.nan)
    inner[my : h - my, mx : w - mx] = std[my : h - my, mx : w - mx]
    if np.isfinite(inner).any():
        std = inner
    if np.isfinite(std).any():
        vals = std[np.isfinite(std)]
        yy, xx = np.mgrid[0:h, 0:w]
        centre = np.hypot((yy - h / 2) / h, (xx - w / 2) / w)
        for q, label in ((50, "static, typical"), (95, "static, noisy")):
            target = np.percentile(vals, q)
            miss = np.abs(std - target)
            best = np.nanmin(miss)
            ties = np.where(miss <= best + 1e-9 * max(abs(target), 1.0), centre, np.inf)
            r, c = np.unravel_index(int(np.argmin(ties)), std.shape)
            out.append((int(r), int(c), label))
    busy = scan.intensity_std[line] if line_axis == "row" else scan.intensity_std[:, line]
    valid = scan.all_valid[line] if line_axis == "row" else scan.all_valid[:, line]
    if valid.any():
        k = int(np.argmax(np.where(valid, busy, -1.0)))
        r, c = (line, k) if line_axis == "row" else (k, line)
        out.append((r, c, f"busiest on the x–t {line_axis}"))
    if not out:
        h, w = static.shape
        out.append((h // 2, w // 2, "image centre"))
    return out


def _normalize_params(params: Any) -> dict[str, Any] | None:
    if params is None:
        return None
    if hasattr(params, "to_dict"):
        return dict(params.to_dict())
    if isinstance(params, Mapping):
        return dict(params)
    raise TypeError(f"params must be a FusionParams or a mapping, got {type(params).__name__}")


def write_report(
    input: str | PathLike[str] | Sequence,
    fused: Any,
    out_dir: str | PathLike[str],
    *,
    compare: Iterable[str] = (),
    row: int | None = None,
    col: int | None = None,
    roi: tuple[int, int, int, int] | str | None = None,
    ground_truth: str | PathLike[str] | Sequence | ArrayLike | None = None,
    support: ArrayLike | None = None,
    filled: ArrayLike | None = None,
    params: Any = None,
    fusion_seconds: float | None = None,
    fusion_steady_ms: float | None = None,
    frame: int | None = None,
    fps: float | None = None,
    chunk_frames: int = 16,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
    reader_options: dict[str, Any] | None = None,
) -> Path:
    """Write the HTML report of a fusion run (see the module docstring for the files).

    Parameters
    ----------
    input : path or Sequence
        The raw recording: any layout :func:`fuse4d.io.open_frames` reads, or a
        :class:`~fuse4d.Sequence` (depth (T, H, W) mm, intensity, intrinsics, optional
        ground truth) already in memory.
    fused : path, FusionResult, Sequence or (T, H, W) array
        The fused result of exactly this input: the ``.npz`` or frame folder written by
        ``fuse4d run`` (an ``.npz`` also holds support and filled maps), a
        :class:`~fuse4d.FusionResult`, or fused depth in mm.
    out_dir : path
        Report folder (must not exist unless ``overwrite``). It is written under a temporary
        name and renamed at the end, so a failed run leaves no half-written report.
    compare : iterable of str, optional
        Baselines (:func:`fuse4d.baselines.run_baseline` names, e.g. ``"temporal-mean"``)
        shown in the x–t slices and the metrics table. They run on chunks of
        ``chunk_frames`` frames with 8 frames of context on each side.
    row, col : int, optional
        The image row (or column) of the x–t slice; default: the row with the most motion.
    roi : (r0, r1, c0, c1) or "R0:R1,C0:C1", optional
        A flat, static target region (rows r0..r1-1, columns c0..c1-1): the spatial precision
        is measured there instead of on detected planes, and the flicker only inside it. Its
        reference plane is fitted on the frame nearest ``frame`` where the region holds at
        least 10 pixels with depth (:class:`~fuse4d.errors.ParameterError` where none does).
    ground_truth : path, Sequence or (T, H, W) array, optional
        Ground-truth depth (mm); default: the input's own (``depth_gt`` of an npz). Adds
        RMSE and bad pixels to the table; static pixels then come from the ground truth.
    support, filled : (T, H, W) array, optional
        Temporal support (frames) and hole-filled mask, when ``fused`` is a plain array.
    params : FusionParams or mapping, optional
        Parameters to list (a FusionResult brings its own).
    fusion_seconds : float, optional
        Wall time of the fusion (s), shown next to the report's own time per frame.
    fusion_steady_ms : float, optional
        The fusion's wall time per frame once running (ms, I/O included:
        :attr:`fuse4d.RunSummary.steady_ms_per_frame`): shown as the time per frame, with the
        average (``fusion_seconds``, start-up included) beside it.
    frame : int, optional
        Frame of the maps, point-cloud render and PLY, 0-based among the fused frames (for a
        run of part ``A:B`` of the input, frame 0 is the input's frame A; the page and the
        video name both). Default: the frame with depth nearest the middle (at least half
        the valid pixels of the median frame). The planes and the |raw - fused| colour
        range come from this frame, or from the nearest frame with depth where it has none.
    fps : float, optional
        Video frame rate (default: the input's, else 10).
    chunk_frames : int, optional
        Frames held in memory at a time.
    overwrite : bool, optional
        Replace an existing ``out_dir``.
    progress : callable, optional
        ``progress(done, total)`` after each frame of the main pass.
    reader_options : dict, optional
        :func:`fuse4d.io.open_frames` options with which the run read ``input`` (streams,
        camera, ``frames`` range: those of ``fuse4d run``); a ``frames`` range also applies
        to a ``ground_truth`` recording.

    Returns
    -------
    Path
        ``out_dir / "report.html"``.

    Raises
    ------
    ValueError
        Bad arguments, or a fused result that does not match the input (frame count or size);
        :class:`~fuse4d.InputFileError` for unreadable files.
    OutputExistsError
        ``out_dir`` exists and ``overwrite`` is False.

    Examples
    --------
    >>> from fuse4d import fuse_sequence
    >>> from fuse4d.synthetic import make_falling_ball
    >>> seq = make_falling_ball(small=True, num_frames=6)  # doctest: +SKIP
    >>> result = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics)  # doctest: +SKIP
    >>> write_report(seq, result, "report-dir")  # doctest: +SKIP
    PosixPath('report-dir/report.html')
    """
    from ..io import check_output
    from ..io._atomic import atomic_dir

    start_time = time.perf_counter()
    start_cpu = time.process_time()
    if row is not None and col is not None:
        raise ParameterError("give row or col for the x–t slice, not both")
    if isinstance(chunk_frames, bool) or int(chunk_frames) < 1:
        raise ParameterError(f"chunk_frames must be a positive integer, got {chunk_frames!r}")
    chunk_frames = int(chunk_frames)
    if fps is not None and not (math.isfinite(fps) and fps > 0):  # 0 silently meant the default
        raise ParameterError(f"fps must be a video frame rate > 0, got {fps}")
    if fps is not None:
        video_rate(fps)  # one the encoders can write, before any work
    methods_compare = _check_compare(compare)
    roi_box = parse_roi(roi) if isinstance(roi, str) else roi
    inputs = [p for p in (input, fused, ground_truth) if isinstance(p, str | PathLike)]
    check_output(out_dir, overwrite=overwrite, inputs=inputs)
    raw = open_raw(input, reader_options)
    try:
        fres = open_fused(fused, raw, support=support, filled=filled)
    except BaseException:
        raw.close()
        raise
    gt: _GroundTruth | None = None
    try:
        gt = _GroundTruth(ground_truth, raw)
        return _write(
            raw,
            fres,
            gt,
            Path(out_dir),
            atomic_dir,
            compare=methods_compare,
            row=row,
            col=col,
            roi_box=roi_box,
            params=params,
            fusion_seconds=fusion_seconds,
            fusion_steady_ms=fusion_steady_ms,
            frame=frame,
            fps=fps,
            chunk_frames=chunk_frames,
            overwrite=overwrite,
            progress=progress,
            start_time=start_time,
            start_cpu=start_cpu,
        )
    finally:
        raw.close()
        fres.close()
        if gt is not None:
            gt.close()


def _frame_name(t: int, part: range | None) -> str:
    """``frame 5`` (0-based), or ``frame 2 (input frame 42)`` for a run of part of a
    recording."""
    return f"frame {t}" if part is None else f"frame {t} (input frame {part.start + t})"


def _part(part: range | None) -> str:
    """`` (frames A-(B-1) of the input)`` for a run of part of a recording, else ``""``."""
    return "" if part is None else f" (frames {part.start}-{part.stop - 1} of the input)"


def _write(
    raw,
    fres,
    gt,
    out_dir,
    atomic_dir,
    *,
    compare,
    row,
    col,
    roi_box,
    params,
    fusion_seconds,
    fusion_steady_ms,
    frame,
    fps,
    chunk_frames,
    overwrite,
    progress,
    start_time,
    start_cpu,
) -> Path:
    from ..baselines import run_baseline
    from ..io import write_ply
    from ..metrics import default_roi, roughness_maps
    from . import figures
    from .layout import VideoLayout
    from .page import render_page
    from .tally import MetricTally

    k = raw.intrinsics
    h, w = raw.shape
    total = raw.num_frames
    if frame is not None and not 0 <= int(frame) < total:
        raise ParameterError(f"frame must be in [0, {total - 1}], got {frame}")
    if row is not None and not 0 <= int(row) < h:
        raise ParameterError(f"row must be in [0, {h - 1}] for a {h}x{w} image, got {row}")
    if col is not None and not 0 <= int(col) < w:
        raise ParameterError(f"col must be in [0, {w - 1}] for a {h}x{w} image, got {col}")
    roi_mask = None if roi_box is None else box_mask(roi_box, (h, w))
    names = ["raw", "fused", *compare]

    # ---------------------------------------------------------------- pass 1: scan the input
    scan = _Scan(raw, gt, chunk_frames, roi_mask)
    scan_seconds = time.perf_counter() - start_time
    # frames with depth: an empty frame (a dropped one) decided the planes and colour ranges
    with_depth = scan.valid_counts >= max(1.0, 0.5 * float(np.median(scan.valid_counts)))
    if frame is None:  # the frame with depth nearest the middle
        frame = _nearest(with_depth, total // 2)
        frame = total // 2 if frame is None else frame
    frame = int(frame)
    # planes and the |raw - fused| range: the rendered frame, or the nearest one with depth
    ref = _nearest(with_depth, frame)
    ref = frame if ref is None else ref
    if roi_mask is not None:  # the ROI's plane: the nearest frame where it has depth
        fit_frame = _nearest(scan.roi_counts >= MIN_FIT_PIXELS, frame)
        if fit_frame is None:
            r0, r1, c0, c1 = roi_box
            raise ParameterError(
                f"roi {r0}:{r1},{c0}:{c1}: the region holds at most "
                f"{int(scan.roi_counts.max())} pixel(s) with depth in any of the {total} frames "
                f"of {raw.name}; a plane fit needs at least {MIN_FIT_PIXELS} (choose a region "
                "on a flat surface with valid depth)"
            )
    if row is not None:
        line_axis, line, line_how = "row", int(row), "given"
    elif col is not None:
        line_axis, line, line_how = "col", int(col), "given"
    else:
        line_axis, line, line_how = "row", choose_line(scan.motion.rows), "auto: most motion"
    static, static_how = scan.static_mask()
    if roi_mask is not None:
        static = static & roi_mask
        static_how += "; inside the ROI"
    ref_depth = raw.chunk(ref, ref + 1).depth[0]
    ref_points = depth_to_points(ref_depth, k)
    ref_pi, ref_rms = roughness_maps(ref_points)
    ref_roi = default_roi(ref_depth) & np.isfinite(ref_pi)
    finite_pi = ref_pi[ref_roi]
    rough_max = scan.rough_max
    # noise for the plane inlier test: local plane residual, or the temporal std of static
    # pixels when larger (it includes the depth quantisation of far surfaces)
    noise = float(np.median(ref_rms[ref_roi])) if finite_pi.size else math.nan
    static_std = scan.raw_std[static]
    if static_std.size:
        noise = float(np.nanmax([noise, float(np.median(static_std))]))
    if roi_mask is not None:
        fit_points = (
            ref_points
            if fit_frame == ref
            else depth_to_points(raw.chunk(fit_frame, fit_frame + 1).depth[0], k)
        )
        planes: list[Plane] = [given_plane(fit_points, roi_mask)]
    else:
        allowed = static if static.any() else scan.mostly_static
        planes = detect_planes(ref_points, noise_mm=noise, allowed=allowed)
    ref_fused = fres.chunk(ref, ref + 1)
    diff = np.abs(ref_depth - ref_fused.depth[0])
    diff = diff[np.isfinite(diff)]
    diff_max = _nice_ceiling(float(np.percentile(diff, 98)) if diff.size else 1.0)
    support_max = 1.0
    if params is None and fres.params is not None:
        params = fres.params
    params_dict = _normalize_params(params)
    if params_dict and "num_frames" in params_dict:
        support_max = float(params_dict["num_frames"]) - 1
    elif ref_fused.support is not None:
        support_max = float(max(1, int(ref_fused.support.max())))
    pixels = _pick_pixels(scan, static, line_axis, line)
    lo, hi = scan.depth_range
    layout = VideoLayout(
        (h, w),
        depth_range=(lo, hi),
        diff_max=diff_max,
        support_max=support_max,
        show_support=fres.has_support,
        # without support maps (a frame folder) the panel shows the source codes it stores
        show_source=not fres.has_support and fres.chunk(0, 1).source is not None,
    )
    rate = fps or raw.fps or DEFAULT_VIDEO_FPS
    if fps is None:
        try:
            video_rate(rate)
        except ParameterError:  # the input's own rate (a misread timestamp unit): not fatal
            warnings.warn(
                f"{raw.name}: its frame rate {rate:g} fps is not one a video can be written "
                f"at; the video plays at {DEFAULT_VIDEO_FPS:g} fps (--fps sets it)",
                stacklevel=2,
            )
            rate = DEFAULT_VIDEO_FPS
    halo = 8 if compare else 0
    edges = np.linspace(0.0, rough_max, 61)

    with atomic_dir(out_dir, overwrite=overwrite) as tmp:
        # ------------------------------------------------------------ pass 2: stream
        tally = MetricTally(
            names,
            (h, w),
            reference=scan.raw_mean,
            planes=planes,
            roughness_bins=edges,
            noise_quad=scan.noise_quad,
        )
        slices = {n: XtSlice(line, axis=line_axis) for n in names}
        series: dict[str, list[NDArray[np.float32]]] = {n: [] for n in names}
        rr = np.array([p[0] for p in pixels])
        cc = np.array([p[1] for p in pixels])
        support_sum = np.zeros((h, w)) if fres.has_support else None
        filled_sum = np.zeros((h, w)) if fres.has_support else None
        valid_raw = 0
        supported = 0
        filled_count = 0
        sources = _SourceTally()  # pixels per source code, where the result has them
        keep: dict[str, Any] = {}
        compare_seconds = 0.0
        video = Mp4Writer(tmp / "compare.mp4", layout.width, layout.height, fps=rate)
        try:
            for a, b in _chunks(total, chunk_frames):
                ra, rb = max(0, a - halo), min(total, b + halo)
                rseq = raw.chunk(ra, rb)
                fch = fres.chunk(a, b)
                gdepth = gt.depth(rseq, ra, rb)
                others: dict[str, NDArray[np.float32]] = {}
                t0 = time.perf_counter()
                for name in compare:
                    out = np.asarray(run_baseline(name, rseq.depth, rseq.intensity, k))
                    out = out[..., 2] if out.ndim == 4 else out
                    others[name] = out[a - ra : b - ra]
                compare_seconds += time.perf_counter() - t0
                for j in range(b - a):
                    t = a + j
                    d_raw = rseq.depth[t - ra]
                    depths = {"raw": d_raw, "fused": fch.depth[j]}
                    depths.update({n: others[n][j] for n in compare})
                    points = {n: depth_to_points(depths[n], k) for n in names}
                    gt_t = None if gdepth is None else gdepth[t - ra]
                    pis = tally.add(depths, points, depth_gt=gt_t)
                    for n in names:
                        slices[n].add(depths[n])
                        series[n].append(depths[n][rr, cc])
                    ok = np.isfinite(d_raw)
                    valid_raw += int(ok.sum())
                    if fch.source is not None:
                        sources.add(fch.source[j], int(ok.sum()))
                    sup = None if fch.support is None else fch.support[j]
                    fil = None if fch.filled is None else fch.filled[j]
                    if sup is not None and support_sum is not None:
                        support_sum += sup
                        supported += int((sup[ok] > 0).sum())
                    if fil is not None and filled_sum is not None:
                        filled_sum += fil
                        filled_count += int(fil[ok].sum())
                    fit = layout.fit_values  # colour-map at the panel size (cheaper)
                    panels = (
                        colorize(fit(d_raw), vmin=lo, vmax=hi),
                        colorize(fit(depths["fused"]), vmin=lo, vmax=hi),
                        colorize(
                            fit(np.abs(d_raw - depths["fused"])),
                            vmin=0.0,
                            vmax=diff_max,
                            cmap="magma",
                        ),
                        shade_points(points["raw"]),  # normals need the full resolution
                        shade_points(points["fused"]),
                        _sixth_panel(layout, sup, ok, support_max, fch.source, j),
                    )
                    video.write(
                        layout.compose(
                            t,
                            total,
                            panels,
                            label=raw.name[-60:],
                            input_frame=None if raw.part is None else raw.part.start + t,
                        )
                    )
                    if t == frame:
                        keep = {
                            "points": points,
                            "pis": pis,
                            "roughness_roi": tally.last_roi.copy(),
                            "intensity": rseq.intensity[t - ra].copy(),
                            "support": sup,
                            "source": None if fch.source is None else fch.source[j],
                            "normals": {n: normal_map(points[n]) for n in ("raw", "fused")},
                        }
                    if progress is not None:
                        progress(t + 1, total)
        finally:
            video.close()
        stream_seconds = time.perf_counter() - start_time - scan_seconds

        # ------------------------------------------------------------ figures and files
        t_fig = time.perf_counter()
        results = tally.results(static)
        std_maps = {n: tally.std_map(n) for n in names}
        static_eval = static & tally.all_valid
        raw_std = std_maps["raw"][static_eval]
        flick_max = _nice_ceiling(float(np.percentile(raw_std, 99)) if raw_std.size else 1.0)
        xt_imgs = {n: s.image() for n, s in slices.items()}
        raw_line = xt_imgs["raw"]
        finite_line = raw_line[np.isfinite(raw_line)]
        if finite_line.size:
            xt_lo, xt_hi = (float(v) for v in np.percentile(finite_line, [1, 99]))
        else:
            xt_lo, xt_hi = lo, hi
        if not xt_hi > xt_lo:
            xt_lo, xt_hi = xt_lo - 1.0, xt_lo + 1.0
        change = np.abs(np.diff(raw_line, axis=0))
        # non-zero changes: on quantised depth most pixels keep their level from one frame
        # to the next, the median change was 0 and the range fell back to ±1 mm beside
        # 30 mm steps (every change saturated); continuous depth has no exact zeros
        change = change[np.isfinite(change) & (change > 0)]
        change_range = _nice_ceiling(3.0 * float(np.median(change)) if change.size else 1.0)
        pts = keep["points"]
        # orbit about the foreground (median of the nearest 30 % of the points), so that
        # the nearest object stays in view when the scene has a large depth range
        flat = pts["raw"].reshape(-1, 3)
        flat = flat[np.all(np.isfinite(flat), axis=1)]
        if len(flat):
            near = flat[flat[:, 2] <= np.percentile(flat[:, 2], 30)]
            center = np.median(near, axis=0)
        else:
            center = np.zeros(3)
        size = (min(480, max(240, 2 * h)), min(640, max(320, 2 * w)))
        render_raw, scale, offset = splat_points(
            pts["raw"], normals=keep["normals"]["raw"], size=size, center=center
        )
        render_fused, _, _ = splat_points(
            pts["fused"],
            normals=keep["normals"]["fused"],
            size=size,
            center=center,
            scale=scale,
            offset=offset,
        )
        n_raw_pts = write_ply(pts["raw"], tmp / "cloud_raw.ply", colors=keep["intensity"])
        n_fused_pts = write_ply(pts["fused"], tmp / "cloud_fused.ply", colors=keep["intensity"])
        series_arr = {n: np.stack(v) for n, v in series.items()}
        frame_name = _frame_name(frame, raw.part)
        frames_note = (
            "" if raw.part is None else f" Frames counted from 0 = input frame {raw.part.start}."
        )
        ratio = _ratio(results["methods"], "flicker_mean")
        figs = {
            "xt": (
                figures.xt_figure(
                    xt_imgs,
                    axis=line_axis,
                    index=line,
                    vmin=xt_lo,
                    vmax=xt_hi,
                    change_range=change_range,
                ),
                (
                    f"{line_axis} {line} ({line_how}); depth colour range {xt_lo:.4g}–{xt_hi:.4g} "
                    f"mm for every method; change range ±{change_range:g} mm.{frames_note}"
                ),
            ),
            "flicker": (
                figures.flicker_figure(
                    {n: std_maps[n] for n in ("raw", "fused")}, static_eval, vmax=flick_max
                ),
                (
                    f"Per-pixel std of depth over all {total} frames on {int(static_eval.sum())} "
                    f"static pixels ({static_how}; valid in every frame of every method). Mean "
                    f"raw {_fmt_mm(results['methods']['raw']['flicker_mean'])}, fused "
                    f"{_fmt_mm(results['methods']['fused']['flicker_mean'])}: "
                    f"<b>ratio raw/fused {_fmt_ratio(ratio)}</b> (median raw "
                    f"{_fmt_mm(results['methods']['raw']['flicker_median'])}, fused "
                    f"{_fmt_mm(results['methods']['fused']['flicker_median'])})."
                ),
            ),
            "timeseries": (
                figures.timeseries_figure(series_arr, pixels),
                f"Depth of single pixels over time (thick: fused).{frames_note}",
            ),
            "roughness": (
                figures.roughness_figure(
                    {n: keep["pis"][n] for n in ("raw", "fused")},
                    {n: tally.hist[n] for n in ("raw", "fused")},
                    edges,
                    frame=frame,
                    means={n: results["methods"][n]["roughness_mean"] for n in ("raw", "fused")},
                ),
                (
                    f"Π = |Σ_j (p_i − p_j)·n_i| over the 5×5 window (mm) of {frame_name}, fixed "
                    f"scale 0–{rough_max:g} mm; histogram over the ROI pixels of all frames "
                    f"({results['roughness_roi_pixels']} samples, the same pixels for every "
                    f"method; its last bin holds every value of {rough_max:g} mm or more); "
                    "dotted: the roughness means of the table (mean over frames of each "
                    "frame's mean)."
                ),
            ),
            "support": (
                figures.support_figure(
                    None if support_sum is None else (support_sum / total).astype(np.float32),
                    None if filled_sum is None else (filled_sum / total).astype(np.float32),
                    None if keep["support"] is None else keep["support"].astype(np.float32),
                    frame=frame,
                    max_support=support_max,
                    source_frame=keep.get("source"),
                ),
                (
                    (
                        "Support: number of other frames whose track passed every check and was "
                        "fused into the pixel. "
                        if keep["support"] is not None
                        else "Support (frames fused per pixel) is not stored in this fused "
                        "result (an .npz output keeps it). "
                        if keep.get("source") is not None
                        else "Neither support (frames fused per pixel) nor the source of each "
                        "value is stored in this fused result (an .npz output keeps both)."
                    )
                    + (
                        "Source: where each value of the frame comes from — measured (raw depth "
                        "without temporal support), fused (with support), sensor holes filled "
                        "from other frames along the track or in space from one side of the "
                        "depth edges, ToF flying pixels rejected and left empty, no depth, "
                        "and no depth outside the sensor's field of view (never filled)."
                        if keep.get("source") is not None
                        # the hole-filled map is drawn where support is stored and source is not
                        else "Hole-filled: fraction of frames in which a valid raw pixel "
                        "without support was filled from its neighbours (Eq. 6)"
                        + (
                            "; Eq. 6 was off in this run (fill_holes = false)."
                            if params_dict is not None and params_dict.get("fill_holes") is False
                            else "."
                        )
                        if filled_sum is not None
                        else ""
                    )
                ),
            ),
            "cloud": (
                figures.cloud_figure({"raw": render_raw, "fused": render_fused}, frame=frame),
                (
                    f"{frame_name.capitalize()} back-projected and rendered from an oblique "
                    "viewpoint (z-buffered splats, shaded by per-pixel normals: noise shows as "
                    "texture). "
                    f"Point clouds: <a href='cloud_raw.ply'>cloud_raw.ply</a> ({n_raw_pts} points), "
                    f"<a href='cloud_fused.ply'>cloud_fused.ply</a> ({n_fused_pts} points)."
                ),
            ),
        }
        figs["regions"] = (
            figures.regions_figure(
                keep["intensity"],
                static_eval,
                [p.mask for p in planes],
                line_axis=line_axis,
                line=line,
                pixels=pixels,
                roi=roi_box,
                roughness_roi=keep["roughness_roi"],
            ),
            f"{frame_name.capitalize()}. Blue: the {int(keep['roughness_roi'].sum())} pixels of "
            "this frame's roughness ROI (Eq. 7 windows free of depth edges, defined for every "
            f"method). Green: the {int(static_eval.sum())} static pixels of the flicker "
            f"(temporal precision). Coloured outlines: the {len(planes)} planar region(s) of the "
            "spatial precision "
            + (
                "(the given ROI). "
                if roi_box is not None
                else "(RANSAC on this raw frame). "
                if ref == frame
                else f"(RANSAC on raw {_frame_name(ref, raw.part)}, the nearest with depth). "
            )
            + f"Red: the x–t {line_axis}. Numbered: the pixels of the time series.",
        )
        fig_seconds = time.perf_counter() - t_fig
        elapsed = time.perf_counter() - start_time
        timing = {
            "report_ms_per_frame": 1000.0 * elapsed / total,
            "report_cpu_ms_per_frame": 1000.0 * (time.process_time() - start_cpu) / total,
            "report_scan_ms_per_frame": 1000.0 * scan_seconds / total,
            "report_stream_ms_per_frame": 1000.0 * stream_seconds / total,
            "report_compare_ms_per_frame": 1000.0 * compare_seconds / total,
            "report_figures_s": fig_seconds,
            "fusion_ms_per_frame": (
                None if fusion_seconds is None else 1000.0 * fusion_seconds / total
            ),
        }
        if timing["fusion_ms_per_frame"] is None and fres.seconds is not None:
            timing["fusion_ms_per_frame"] = 1000.0 * fres.seconds / total
        if fusion_steady_ms is None and fusion_seconds is None:  # a run's folder, made earlier
            fusion_steady_ms = fres.steady_ms
        timing["fusion_steady_ms_per_frame"] = (
            fusion_steady_ms
            if fusion_steady_ms is not None and math.isfinite(fusion_steady_ms)
            else None
        )
        fill = {
            "support_fraction": supported / valid_raw if fres.has_support and valid_raw else None,
            "filled_fraction": (
                filled_count / valid_raw if fres.has_support and valid_raw else None
            ),
            # sensor holes outside the field of view / filled (A38, A26, A27), flying pixels
            # removed (A36), from the source codes where the result has them
            **sources.shares(),
        }
        metrics = {
            "input": raw.name,
            # "A:B" where the run fused only part of the input
            "input_frames": None if raw.part is None else f"{raw.part.start}:{raw.part.stop}",
            "fused": fres.name,
            "frames": total,
            "size": [h, w],
            "intrinsics": k.to_dict(),
            "methods": names,
            "metrics": results["methods"],
            "definitions": DEFINITIONS,
            "noise_quad": scan.noise_quad,
            "roughness": {
                "window": 5,
                "roi": "default ROI of the raw frame, Pi defined for every method",
                "samples": results["roughness_roi_pixels"],
                "histogram_edges_mm": edges.tolist(),
                "histograms": {n: tally.hist[n].tolist() for n in names},
            },
            "flicker": {
                "static_pixels": results["flicker_pixels"],
                "static_source": static_how,
                "ratio_raw_over_fused": ratio,
                "ratio_of": "flicker_mean",  # the headline (it was the median)
            },
            "planes": [
                {**p.to_dict(), "pixels_per_frame": n}
                for p, n in zip(planes, results["plane_pixels_per_frame"], strict=True)
            ],
            "ground_truth": gt.name if gt.available else None,
            "xt_slice": {"axis": line_axis, "index": line, "how": line_how},
            "timeseries_pixels": [{"row": r, "col": c, "label": lb} for r, c, lb in pixels],
            "frame_rendered": frame,  # 0-based, of the fused frames
            "frame_rendered_input": frame if raw.part is None else raw.part.start + frame,
            "fusion": fill,
            "timing": timing,
            "params": params_dict,
            "video": {
                "file": "compare.mp4",
                "codec": video.codec,
                "frames": video.num_frames,
                "fps": float(video_rate(rate)),
                "size": [video.height, video.width],
            },
        }
        (tmp / "metrics.json").write_text(dumps(metrics, indent=2) + "\n")
        page = render_page(
            title=f"fuse4d report: {Path(raw.name).name}",
            subtitle=f"{total} frames{_part(raw.part)}, {h}×{w} px; fused: {fres.name}",
            video_file="compare.mp4",
            video_note=_video_note(video.codec, diff_max, lo, hi, layout),
            figures=figs,
            metric_rows=_metric_rows(
                results["methods"], names, timing, fill, params_dict, noise_quad=scan.noise_quad
            ),
            method_names=names,
            summary=_summary(results["methods"], ratio) + _quantization_note(fres.depth_unit_mm),
            facts={
                "input": raw.name,
                "fused": fres.name,
                "ground truth": gt.name if gt.available else "none",
                "frames": f"{total}{_part(raw.part)}",
                "size (H×W px)": f"{h}×{w}",
                "intrinsics (fx, fy, cx, cy px)": ", ".join(
                    f"{v:.2f}" for v in (k.fx, k.fy, k.cx, k.cy)
                ),
                "detected planes": len(planes),
                "report time (ms/frame, wall)": timing["report_ms_per_frame"],
                "report CPU time (ms/frame, all threads)": timing["report_cpu_ms_per_frame"],
                "fusion time (ms/frame, wall, start-up included)": timing["fusion_ms_per_frame"],
                # (from the manifest for a report made later from a run's folder)
                "fusion time once running (ms/frame, wall)": timing["fusion_steady_ms_per_frame"],
                "video codec": video.codec,
                "fused depth step (mm)": fres.depth_unit_mm or "float (no rounding)",
            },
            params=params_dict,
        )
        (tmp / "report.html").write_text(page, encoding="utf-8")
    return out_dir / "report.html"


def _ratio(methods: dict[str, dict[str, Any]], key: str) -> float:
    a = methods["raw"].get(key, math.nan)
    b = methods["fused"].get(key, math.nan)
    if not (math.isfinite(a) and math.isfinite(b)) or b <= 0:
        return math.nan
    return a / b


def _fmt_mm(value: float) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.4g} mm"


def _fmt_ratio(value: float) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.3g}×"


def _summary(methods: dict[str, dict[str, Any]], flicker_ratio: float) -> str:
    r = methods["raw"]
    f = methods["fused"]
    flicker = (
        "flicker (per-pixel std over time, mean) "
        f"{_fmt_mm(r['flicker_mean'])} → {_fmt_mm(f['flicker_mean'])}"
    )
    if math.isfinite(flicker_ratio) and flicker_ratio >= 1.0:
        flicker += f" ({_fmt_ratio(flicker_ratio)} less)"
    elif math.isfinite(flicker_ratio) and flicker_ratio > 0.0:  # "(0.5× less)" read backwards
        flicker += f" ({_fmt_ratio(1.0 / flicker_ratio)} more)"
    elif r["flicker_mean"] == 0.0 and f["flicker_mean"] > 0.0:  # was "(0× less)"
        flicker += " (more: raw was still on these pixels)"
    elif not math.isfinite(f["flicker_mean"]):
        flicker = "flicker n/a (it needs 2 frames and static pixels)"
    parts = [
        f"Roughness (Eq. 7) {_fmt_mm(r['roughness_mean'])} → {_fmt_mm(f['roughness_mean'])}",
        flicker,
        f"fill rate {100 * r['fill_rate']:.1f} % → {100 * f['fill_rate']:.1f} %",
    ]
    if "rmse" in f:
        parts.append(f"RMSE to ground truth {_fmt_mm(r['rmse'])} → {_fmt_mm(f['rmse'])}")
    return "<b>Raw → fused:</b> " + "; ".join(parts) + " (same pixels for both)."


def _quantization_note(unit_mm: float | None) -> str:
    if unit_mm is None:
        return ""
    # Eq. 7 sums 25 residuals: rounding to steps of u mm (std u / sqrt(12)) alone gives
    # E[Pi] ~ 25 * 0.8 * u / sqrt(12)
    floor = 25 * 0.8 * unit_mm / math.sqrt(12.0)
    return (
        f" <b>Note:</b> the fused input stores depth in steps of {unit_mm:g} mm; the rounding "
        f"alone adds about {floor:.2g} mm of Eq. 7 roughness on smooth surfaces. Fuse to an "
        ".npz (float depth, with support maps) for a fair roughness comparison."
    )


def _video_note(codec: str, diff_max: float, lo: float, hi: float, layout: VideoLayout) -> str:
    sixth = (
        "temporal support of each pixel"
        if layout.show_support
        else "where each value comes from (the fused result stores no support maps)"
        if layout.show_source
        else "empty: the fused result stores neither support maps nor source codes"
    )
    note = (
        f"Top: raw depth | fused depth (colour range fixed at {lo:.4g}–{hi:.4g} mm) | "
        f"|raw − fused| (0–{diff_max:g} mm). Bottom: raw | fused shaded by per-pixel normals "
        f"(surface noise shows as texture) | {sixth}. Gray: no depth. "
        "<a href='compare.mp4'>compare.mp4</a>"
    )
    if codec != "libx264":
        note += (
            f" (encoded with {codec}: this FFmpeg has no H.264 encoder, so most browsers "
            "cannot play it inline; open the file in a video player)"
        )
    return note


def _metric_rows(
    methods: dict[str, dict[str, Any]],
    names: list[str],
    timing: dict[str, Any],
    fill: dict,
    params: dict[str, Any] | None = None,
    *,
    noise_quad: float = math.nan,
) -> list[dict[str, Any]]:
    def row(key: str, label: str, unit: str, scale: float = 1.0) -> dict[str, Any]:
        return {
            "name": label,
            "values": {
                n: (methods[n].get(key) * scale if methods[n].get(key) is not None else None)
                for n in names
            },
            "unit": unit,
            "meaning": DEFINITIONS[key],
        }

    rows = [
        row("roughness_mean", "roughness mean (Eq. 7)", "mm"),
        row("roughness_std", "roughness std over frames", "mm"),
        row("rms_residual", "local plane RMS residual", "mm"),
        row("spatial_precision", "spatial precision (plane-fit RMS)", "mm"),
        row("flicker_mean", "temporal precision / flicker (mean std)", "mm"),
        row("flicker_median", "flicker (median std)", "mm"),
        row("fill_rate", "fill rate", "%", 100.0),
    ]
    if "rmse" in methods["raw"]:
        rows.append(row("rmse", "RMSE to ground truth", "mm"))
        rows.append(row("bad_pixels", "bad pixels > 1 mm", "%", 100.0))
        rows.append(row("bad_steps", "bad pixels > step limit", "%", 100.0))
        rows[-1]["meaning"] += f"; q = {noise_quad:.3g} /mm"
    if fill["support_fraction"] is not None:
        rows.append(
            {
                "name": "temporal support",
                "values": {"fused": 100.0 * fill["support_fraction"]},
                "unit": "%",
                "meaning": "valid pixels tracked into at least one other frame",
            }
        )
        eq6_off = params is not None and params.get("fill_holes") is False
        rows.append(
            {
                "name": "hole-filled",
                # "0 %" read as "Eq. 6 found nothing to do" where it was switched off
                "values": {"fused": None if eq6_off else 100.0 * fill["filled_fraction"]},
                "unit": "%",
                "meaning": "valid pixels without support, filled by Eq. 6"
                + (" (off in this run: fill_holes = false, A35)" if eq6_off else ""),
            }
        )
    if fill.get("hole_time_fraction") is not None:
        rows.append(
            {
                "name": "sensor holes filled",
                "values": {
                    "fused": 100.0 * (fill["hole_time_fraction"] + fill["hole_space_fraction"])
                },
                "unit": "%",
                "meaning": (
                    "raw pixels without depth inside the sensor's field of view given a "
                    f"value: {100 * fill['hole_time_fraction']:.1f} % from other frames along "
                    f"the track (A26), {100 * fill['hole_space_fraction']:.1f} % in space from "
                    "one side of the depth edges (A27); "
                    f"{100 * (fill['hole_outside_fraction'] or 0.0):.1f} % of the raw holes lie "
                    "outside the field of view and stay empty (A38)"
                ),
            }
        )
    if fill.get("rejected_fraction"):
        rows.append(
            {
                "name": "flying pixels removed",
                "values": {"fused": 100.0 * fill["rejected_fraction"]},
                "unit": "%",
                "meaning": "valid raw pixels removed as ToF flying pixels, left empty (A36)",
            }
        )
    steady, average = timing["fusion_steady_ms_per_frame"], timing["fusion_ms_per_frame"]
    rows.append(
        {
            "name": "time per frame",
            "values": {"fused": average if steady is None else steady},
            "unit": "ms",
            "meaning": (
                f"fusion wall time per frame, start-up and I/O included (this report: "
                f"{timing['report_ms_per_frame']:.1f} ms/frame)"
                if steady is None or average is None
                else f"fusion wall time per frame once running, I/O included; "
                f"{average:.1f} ms/frame with the start-up (this report: "
                f"{timing['report_ms_per_frame']:.1f} ms/frame)"
            ),
            "digits": 4,
        }
    )
    return rows
