"""Spatial precision (the depth-camera vendors' "plane-fit RMS") on detected or given planes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import ParameterError

__all__ = ["Plane", "detect_planes", "plane_fit_rms"]

#: Fewest valid pixels a plane fit uses (fewer: no fit, NaN).
MIN_FIT_PIXELS = 10


@dataclass(frozen=True)
class Plane:
    """A planar region of the image.

    Attributes
    ----------
    mask : (H, W) ndarray of bool
        The region's pixels.
    normal : (3,) ndarray of float64
        Unit normal of the reference fit (camera frame).
    offset : float
        ``normal . p = offset`` for points p on the plane, mm.
    threshold : float
        Distance (mm) beyond which a point is not on the plane (occluders are left out).
    source : str
        ``"detected"`` (RANSAC) or ``"given"`` (the user's ROI).
    """

    mask: NDArray[np.bool_]
    normal: NDArray[np.float64]
    offset: float
    threshold: float
    source: str

    def to_dict(self) -> dict[str, object]:
        """JSON-friendly summary (no mask)."""
        return {
            "source": self.source,
            "pixels": int(self.mask.sum()),
            "normal": [float(x) for x in self.normal],
            "offset_mm": float(self.offset),
            "inlier_threshold_mm": float(self.threshold),
        }


def _fit(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], float, float]:
    """Total-least-squares plane of (N, 3) points: (normal, offset, RMS residual in mm)."""
    c = points.mean(axis=0)
    q = points - c
    scatter = q.T @ q  # (3, 3)
    values, vectors = np.linalg.eigh(scatter)  # ascending eigenvalues
    n = vectors[:, 0]
    rms = float(np.sqrt(max(values[0], 0.0) / max(len(points), 1)))
    return n, float(n @ c), rms


def plane_fit_rms(points: NDArray[np.floating], mask: NDArray[np.bool_]) -> float:
    """RMS distance (mm) of the masked points to their own least-squares plane.

    Parameters
    ----------
    points : (H, W, 3) ndarray
        Points in mm, NaN = invalid.
    mask : (H, W) ndarray of bool
        Pixels to fit (invalid ones are skipped).

    Returns
    -------
    float
        RMS plane residual in mm; NaN if fewer than 10 valid pixels.
    """
    sel = points[mask]
    sel = sel[np.all(np.isfinite(sel), axis=1)].astype(np.float64)
    if len(sel) < MIN_FIT_PIXELS:
        return float("nan")
    return _fit(sel)[2]


def detect_planes(
    points: NDArray[np.floating],
    *,
    noise_mm: float,
    allowed: NDArray[np.bool_] | None = None,
    max_planes: int = 2,
    min_fraction: float = 0.05,
    iterations: int = 256,
    rng: int = 0,
) -> list[Plane]:
    """Find the largest planar regions of one frame with RANSAC (vectorised over hypotheses).

    Parameters
    ----------
    points : (H, W, 3) ndarray
        Points in mm, NaN = invalid (a raw frame).
    noise_mm : float
        Typical depth noise (mm); the inlier threshold is ``3 * noise_mm`` (at least 0.5 mm).
    allowed : (H, W) ndarray of bool, optional
        Pixels a plane may use (e.g. the static ones: a flat target, not a moving torso).
    max_planes : int, optional
        At most this many planes (each found after removing the previous one's inliers).
    min_fraction : float, optional
        A plane must cover at least this fraction of the valid pixels.
    iterations : int, optional
        RANSAC hypotheses per plane.
    rng : int, optional
        Seed.

    Returns
    -------
    list of Plane
        Largest first; each mask holds the inliers of the largest connected inlier region
        (closed, then eroded by 2 px so that edges are left out).
    """
    import cv2

    gen = np.random.default_rng(rng)
    p = np.asarray(points, dtype=np.float64)
    valid = np.all(np.isfinite(p), axis=-1)
    total = int(valid.sum())
    if allowed is not None:
        valid &= allowed
    threshold = max(3.0 * float(noise_mm), 0.5) if np.isfinite(noise_mm) else 2.0
    planes: list[Plane] = []
    free = valid.copy()
    for _ in range(max_planes):
        idx = np.flatnonzero(free)
        if idx.size < max(100, min_fraction * total):
            break
        flat = p.reshape(-1, 3)
        sample = flat[gen.choice(idx, size=min(idx.size, 4000), replace=False)]  # (S, 3)
        tri = sample[gen.integers(0, len(sample), size=(iterations, 3))]  # (I, 3, 3)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # (I, 3)
        norm = np.linalg.norm(n, axis=1)
        ok = norm > 1e-9
        if not ok.any():
            break
        n = n[ok] / norm[ok, None]
        d = np.einsum("ij,ij->i", n, tri[ok, 0])
        dist = np.abs(sample @ n.T - d[None, :])  # (S, I)
        best = int(np.argmax((dist < threshold).sum(axis=0)))
        inl = np.abs(flat[idx] @ n[best] - d[best]) < threshold
        normal, offset, _ = _fit(flat[idx[inl]])
        on = np.zeros(valid.size, dtype=bool)
        on[idx] = np.abs(flat[idx] @ normal - offset) < threshold
        on = on.reshape(valid.shape)
        kernel = np.ones((5, 5), np.uint8)
        closed = cv2.morphologyEx(on.astype(np.uint8), cv2.MORPH_CLOSE, kernel) & valid
        count, labels, stats, _ = cv2.connectedComponentsWithStats(
            closed.astype(np.uint8), connectivity=4
        )
        if count < 2:
            break
        largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        region = labels == largest
        region = cv2.erode(region.astype(np.uint8), kernel).astype(bool) & on
        free &= ~on
        if region.sum() < min_fraction * total:
            continue
        planes.append(Plane(region, normal, offset, threshold, "detected"))
    return planes


def given_plane(points: NDArray[np.floating], mask: NDArray[np.bool_]) -> Plane:
    """A plane from a user-given region (fitted to its valid points; no inlier test).

    Parameters
    ----------
    points : (H, W, 3) ndarray
        Points in mm of one frame, NaN = invalid.
    mask : (H, W) ndarray of bool
        The region.

    Raises
    ------
    ParameterError
        The region holds fewer than :data:`MIN_FIT_PIXELS` valid points in this frame.
    """
    sel = np.asarray(points, dtype=np.float64)[mask]
    sel = sel[np.all(np.isfinite(sel), axis=1)]
    if len(sel) < MIN_FIT_PIXELS:
        raise ParameterError(
            f"roi: the region holds {len(sel)} valid pixels in the reference frame; a plane "
            f"fit needs at least {MIN_FIT_PIXELS} (choose a region on a flat surface with "
            "valid depth)"
        )
    normal, offset, _ = _fit(sel)
    return Plane(mask, normal, offset, float("inf"), "given")
