"""Running metrics over streamed frames, every method scored on the same pixels.

Memory is a few (H, W) float64 maps per method, whatever the sequence length. The numbers
equal those of :mod:`fuse4d.metrics` on the whole arrays with the masks described in
:meth:`MetricTally.results` (``tests/test_report.py`` checks this).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..metrics import default_roi, roughness_maps, step_limit
from .planes import Plane, plane_fit_rms

__all__ = ["MetricTally"]


class MetricTally:
    """Accumulate roughness, fill rate, flicker, plane RMS and GT errors frame by frame.

    Parameters
    ----------
    names : sequence of str
        Methods, ``"raw"`` first (the ROI and plane inlier tests use the raw frame).
    shape : (int, int)
        Frame shape (H, W).
    reference : (H, W) ndarray
        Depth (mm) subtracted before the running sums of the flicker (numerical
        conditioning only; any value works, NaN is treated as 0).
    planes : list of Plane
        Regions for the spatial precision.
    roughness_bins : (B + 1,) ndarray
        Uniform histogram edges of the roughness (mm); values above the last edge go to the
        last bin.
    window : int, optional
        Roughness window (px).
    edge_mm : float, optional
        Default-ROI depth-range limit (mm).
    bad_threshold_mm : float, optional
        Bad-pixel threshold against ground truth (mm).
    noise_quad : float, optional
        Depth-noise coefficient q (mm^-1) of the raw video: ``bad_steps`` counts the pixels
        off by more than ``max(bad_threshold_mm, 2.5 q z^2)`` at the true depth z
        (:func:`~fuse4d.metrics.bad_pixel_fraction`'s ``noise_quad``).
    """

    def __init__(
        self,
        names: list[str],
        shape: tuple[int, int],
        *,
        reference: NDArray[np.floating],
        planes: list[Plane],
        roughness_bins: NDArray[np.float64],
        window: int = 5,
        edge_mm: float = 10.0,
        bad_threshold_mm: float = 1.0,
        noise_quad: float = 0.0,
    ) -> None:
        self.names = list(names)
        self.shape = shape
        self.window = window
        self.edge_mm = edge_mm
        self.bad_threshold_mm = bad_threshold_mm
        self.noise_quad = noise_quad
        self.planes = planes
        self.bins = np.asarray(roughness_bins, dtype=np.float64)
        self._ref = np.nan_to_num(np.asarray(reference, dtype=np.float64), nan=0.0)
        self.frames = 0
        self.all_valid = np.ones(shape, dtype=bool)  # valid in every frame for every method
        zeros = {n: np.zeros(shape, dtype=np.float64) for n in self.names}
        self._s1 = zeros
        self._s2 = {n: np.zeros(shape, dtype=np.float64) for n in self.names}
        self.frame_pi: dict[str, list[float]] = {n: [] for n in self.names}
        self.frame_rms: dict[str, list[float]] = {n: [] for n in self.names}
        self.roi_pixels: list[int] = []
        self.last_roi: NDArray[np.bool_] | None = None
        self.hist = {n: np.zeros(self.bins.size - 1, dtype=np.int64) for n in self.names}
        self.valid_count = dict.fromkeys(self.names, 0)
        self.plane_rms: list[dict[str, list[float]]] = [{n: [] for n in self.names} for _ in planes]
        self.plane_pixels: list[list[int]] = [[] for _ in planes]
        self.gt_frames = 0
        self._sq = dict.fromkeys(self.names, 0.0)
        self._sq_count = 0
        self._bad = dict.fromkeys(self.names, 0)
        self._bad_steps = dict.fromkeys(self.names, 0)
        self._gt_valid = 0

    def add(
        self,
        depths: dict[str, NDArray[np.float32]],
        points: dict[str, NDArray[np.float32]],
        *,
        depth_gt: NDArray[np.float32] | None = None,
    ) -> dict[str, NDArray[np.float32]]:
        """Add one frame of every method.

        Parameters
        ----------
        depths : dict of str to (H, W) ndarray
            Depth (mm, NaN invalid) per method.
        points : dict of str to (H, W, 3) ndarray
            The matching point maps (mm).
        depth_gt : (H, W) ndarray, optional
            Ground-truth depth (mm).

        Returns
        -------
        dict of str to (H, W) ndarray
            The roughness map Pi (Eq. 7, mm) of each method (for the figures).
        """
        self.frames += 1
        finite = {n: np.isfinite(depths[n]) for n in self.names}
        pis: dict[str, NDArray[np.float32]] = {}
        rmss: dict[str, NDArray[np.float32]] = {}
        for n in self.names:
            pis[n], rmss[n] = roughness_maps(points[n], window=self.window)
            self.valid_count[n] += int(finite[n].sum())
        # roughness: default ROI of the raw frame, Pi defined for every method
        roi = default_roi(depths[self.names[0]], window=self.window, max_step=self.edge_mm)
        for n in self.names:
            roi &= np.isfinite(pis[n])
        count = int(roi.sum())
        self.roi_pixels.append(count)
        self.last_roi = roi  # the frame's roughness ROI (the report draws one frame's)
        for n in self.names:
            if count:
                vals = pis[n][roi].astype(np.float64)
                self.frame_pi[n].append(float(vals.sum() / count))
                self.frame_rms[n].append(float(rmss[n][roi].astype(np.float64).sum() / count))
                self.hist[n] += self._bin_counts(vals)
            else:
                self.frame_pi[n].append(math.nan)
                self.frame_rms[n].append(math.nan)
        # flicker running sums
        both = np.logical_and.reduce([finite[n] for n in self.names])
        self.all_valid &= both
        for n in self.names:
            x = np.where(finite[n], depths[n] - self._ref, 0.0)
            self._s1[n] += x
            self._s2[n] += x * x
        # spatial precision: the same pixels of each plane for every method
        raw_pts = points[self.names[0]]
        for k, plane in enumerate(self.planes):
            sel = plane.mask & both
            if math.isfinite(plane.threshold):
                with np.errstate(invalid="ignore"):
                    dist = np.abs(raw_pts @ plane.normal - plane.offset)
                sel &= dist < 5.0 * plane.threshold
            self.plane_pixels[k].append(int(sel.sum()))
            for n in self.names:
                self.plane_rms[k][n].append(plane_fit_rms(points[n], sel))
        if depth_gt is not None:
            self.gt_frames += 1
            gt_ok = np.isfinite(depth_gt) & (depth_gt > 0)  # as fuse4d.metrics: 0 = no truth
            common = gt_ok & both
            self._sq_count += int(common.sum())
            self._gt_valid += int(gt_ok.sum())
            gt32 = np.asarray(depth_gt, dtype=np.float32)
            limit = step_limit(
                gt32[gt_ok], max_step=self.bad_threshold_mm, noise_quad=self.noise_quad
            ).astype(np.float32)  # as bad_pixel_fraction
            for n in self.names:
                err = gt32[common].astype(np.float64) - depths[n][common]
                self._sq[n] += float(np.sum(err**2))
                with np.errstate(invalid="ignore"):  # float32, as bad_pixel_fraction
                    off = np.abs(gt32[gt_ok] - depths[n][gt_ok])
                    self._bad[n] += int(
                        gt_ok.sum() - (off <= np.float32(self.bad_threshold_mm)).sum()
                    )
                    self._bad_steps[n] += int(gt_ok.sum() - (off <= limit).sum())
        return pis

    def _bin_counts(self, values: NDArray[np.float64]) -> NDArray[np.int64]:
        """Histogram counts on the uniform bins; out-of-range values go to the end bins."""
        nbins = self.bins.size - 1
        width = (self.bins[-1] - self.bins[0]) / nbins
        idx = np.floor((values - self.bins[0]) / width).astype(np.int64)
        return np.bincount(np.clip(idx, 0, nbins - 1), minlength=nbins)

    def std_map(self, name: str) -> NDArray[np.float32]:
        """Per-pixel temporal std (ddof = 0, mm) on pixels valid in every frame of every method."""
        t = max(self.frames, 1)
        mean = self._s1[name] / t
        var = np.maximum(self._s2[name] / t - mean * mean, 0.0)
        out = np.full(self.shape, np.nan, dtype=np.float32)
        out[self.all_valid] = np.sqrt(var[self.all_valid])
        return out

    def results(self, static: NDArray[np.bool_]) -> dict[str, Any]:
        """The metrics of every method (JSON friendly; NaN = not measurable).

        Parameters
        ----------
        static : (H, W) ndarray of bool
            Pixels seeing a static surface (ground truth, or the input's quiet pixels).

        Returns
        -------
        dict
            ``methods[name]`` holds ``fill_rate``, ``roughness_mean``/``roughness_std``
            (= :func:`~fuse4d.metrics.roughness_stats` with ``roi`` = default ROI of the raw
            frame AND Pi defined for all methods), ``rms_residual``, ``flicker_mean`` (the
            headline) / ``flicker_median`` (= :func:`~fuse4d.metrics.temporal_flicker`'s
            ``mean`` / ``median`` with ``static`` = ``static`` AND valid in every frame of
            every method),
            ``spatial_precision`` (mean over frames and planes of the plane-fit RMS), and
            with ground truth ``rmse`` (= :func:`~fuse4d.metrics.depth_rmse` with ``mask`` =
            valid in every method) and ``bad_pixels`` (= :func:`~fuse4d.metrics.
            bad_pixel_fraction`, missing depth counted as bad) and ``bad_steps`` (the same
            with the noise model's step limit, ``noise_quad``).
        """
        # one frame has no flicker (its "std over time" was 0 on every pixel)
        flicker_px = static & self.all_valid if self.frames >= 2 else np.zeros_like(static)
        total = self.frames * self.shape[0] * self.shape[1]
        methods: dict[str, dict[str, Any]] = {}
        for n in self.names:
            fm = np.asarray(self.frame_pi[n], dtype=np.float64)
            rm = np.asarray(self.frame_rms[n], dtype=np.float64)
            std = self.std_map(n)[flicker_px].astype(np.float64)
            plane_means = [
                float(np.nanmean(np.asarray(p[n]))) if np.isfinite(p[n]).any() else math.nan
                for p in self.plane_rms
            ]
            m: dict[str, Any] = {
                "fill_rate": self.valid_count[n] / total if total else math.nan,
                "roughness_mean": _nanmean(fm),
                "roughness_std": _nanstd(fm),
                "rms_residual": _nanmean(rm),
                "flicker_mean": float(std.mean()) if std.size else math.nan,
                "flicker_median": float(np.median(std)) if std.size else math.nan,
                "spatial_precision": _nanmean(np.asarray(plane_means)),
                "spatial_precision_per_plane": plane_means,
                "roughness_frame_means": fm.tolist(),
            }
            if self.gt_frames:
                m["rmse"] = math.sqrt(self._sq[n] / self._sq_count) if self._sq_count else math.nan
                m["bad_pixels"] = self._bad[n] / self._gt_valid if self._gt_valid else math.nan
                m["bad_steps"] = self._bad_steps[n] / self._gt_valid if self._gt_valid else math.nan
            methods[n] = m
        return {
            "methods": methods,
            "roughness_roi_pixels": int(sum(self.roi_pixels)),
            "flicker_pixels": int(flicker_px.sum()),
            "plane_pixels_per_frame": [float(np.mean(p)) if p else 0.0 for p in self.plane_pixels],
        }


def _nanmean(x: NDArray[np.float64]) -> float:
    good = x[np.isfinite(x)]
    return float(good.mean()) if good.size else math.nan


def _nanstd(x: NDArray[np.float64]) -> float:
    """Spread over frames (ddof 0); NaN for fewer than two (one frame printed 0, as
    :func:`fuse4d.metrics.roughness_stats` did before it said n/a)."""
    good = x[np.isfinite(x)]
    return float(good.std(ddof=0)) if good.size >= 2 else math.nan
