"""The in-memory 3D video: depth + registered intensity + camera (+ optional ground truth)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._validation import as_float32, check_shape
from .camera import Intrinsics, depth_to_points
from .errors import ShapeError

__all__ = [
    "GroundTruth",
    "Sequence",
    "check_unit_intensity",
    "normalize_intensity",
    "sanitize_depth",
]


def sanitize_depth(depth: np.ndarray) -> NDArray[np.float32]:
    """Float32 depth (mm) with every invalid value (0, negative, inf, NaN) set to NaN."""
    d = as_float32(depth, name="depth")
    bad = ~(np.isfinite(d) & (d > 0))
    if bad.any():
        d = d.copy() if d is depth else d
        d[bad] = np.nan
    return d


def normalize_intensity(intensity: np.ndarray) -> NDArray[np.float32]:
    """Convert intensity to float32 in [0, 1] (METHOD A16).

    Integers are divided by their dtype's maximum; floats whose maximum exceeds 1 are divided
    by the sequence maximum; floats already in [0, 1] are kept.
    """
    arr = np.asarray(intensity)
    if arr.dtype.kind in "ui":
        info = np.iinfo(arr.dtype)
        return (arr.astype(np.float32) / np.float32(info.max)).clip(0, 1)
    if arr.dtype == np.bool_:
        return arr.astype(np.float32)
    out = as_float32(arr, name="intensity")
    finite_max = np.nanmax(out) if out.size and np.isfinite(out).any() else 0.0
    if finite_max > 1.0:
        out = out / np.float32(finite_max)
    return out


def check_unit_intensity(intensity: np.ndarray, *, name: str = "intensity") -> NDArray[np.float32]:
    """Float intensity as float32, refusing values outside [0, 1] (METHOD A16).

    The fusion's intensity kernel (``sigma_intensity``) and the flow methods expect [0, 1];
    a float frame in 0-255 would silently make every intensity weight ~0. NaN is passed
    through (the flow methods reject it with their own message).

    Parameters
    ----------
    intensity : ndarray
        Float intensity of one frame or a sequence.
    name : str
        How to name it in the error, e.g. ``"intensity (frame 3)"``.

    Returns
    -------
    ndarray of float32
        The intensity (no copy when it already is float32).

    Raises
    ------
    ValueError
        If a finite or infinite value lies outside [0, 1]; the message says how to rescale.
    """
    arr = as_float32(intensity, name=name)
    if arr.size:
        lo, hi = float(arr.min()), float(arr.max())
        if np.isnan(lo) or np.isnan(hi):
            values = arr[~np.isnan(arr)]
            lo, hi = (float(values.min()), float(values.max())) if values.size else (0.0, 0.0)
        if lo < 0.0 or hi > 1.0:
            raise ValueError(
                f"{name} is float with values in [{lo:.4g}, {hi:.4g}], outside [0, 1]; "
                "rescale it to [0, 1] (e.g. divide 8-bit values by 255, or use "
                "fuse4d.sequence.normalize_intensity on the whole sequence), or pass integer "
                "intensity, which is divided by its dtype maximum"
            )
    return arr


@dataclass(frozen=True)
class GroundTruth:
    """Ground truth of a synthetic scene (every field optional).

    Parameters
    ----------
    depth : (T, H, W) ndarray of float32, optional
        Noise-free depth in mm (NaN where no surface).
    mask : (T, H, W) ndarray of bool, optional
        Object mask (e.g. the ball), True = object pixel.
    flow : (T-1, H, W, 2) ndarray of float32, optional
        True forward flow in px, ``[..., 0]`` = du (column), ``[..., 1]`` = dv (row).
    extra : dict, optional
        Scene-specific values (e.g. the ball's projected centre row ``center_row`` per frame,
        the true radius in mm).
    """

    depth: NDArray[np.float32] | None = None
    mask: NDArray[np.bool_] | None = None
    flow: NDArray[np.float32] | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Sequence:
    """A 3D video: pixel-registered depth and intensity frames from one pinhole camera.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm along the optical axis. Converted to float32; 0, negative and inf values
        become NaN (= invalid).
    intensity : (T, H, W) ndarray
        Registered intensity. Converted to float32 in [0, 1] (integers divided by their dtype
        maximum); float input must already be in [0, 1].
    intrinsics : Intrinsics
        Camera; its size must match ``(H, W)``.
    timestamps : (T,) ndarray of float64, optional
        Capture times in seconds, strictly increasing.
    fps : float, optional
        Nominal frame rate (metadata only; fuse4d counts time in frames).
    ground_truth : GroundTruth, optional
        Ground truth, for synthetic scenes.
    name : str, optional
        Human-readable name (file or scene).

    Raises
    ------
    ShapeError
        If depth and intensity differ in shape, are not 3-D, or disagree with the intrinsics.
    ValueError
        If T < 1, intensity is outside [0, 1], timestamps are not increasing, or fps <= 0.
    TypeError
        If intrinsics is not an :class:`Intrinsics`.

    Examples
    --------
    >>> K = Intrinsics(fx=100.0, fy=100.0, cx=1.5, cy=1.5, width=4, height=4)
    >>> seq = Sequence(np.full((2, 4, 4), 500.0), np.zeros((2, 4, 4)), K)
    >>> seq.num_frames, seq.shape
    (2, (4, 4))
    """

    depth: NDArray[np.float32]
    intensity: NDArray[np.float32]
    intrinsics: Intrinsics
    timestamps: NDArray[np.float64] | None = None
    fps: float | None = None
    ground_truth: GroundTruth | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.intrinsics, Intrinsics):
            raise TypeError(
                f"intrinsics must be a fuse4d.Intrinsics, got {type(self.intrinsics).__name__}"
            )
        depth = np.asarray(self.depth)
        intensity = np.asarray(self.intensity)
        if depth.ndim == 2:
            raise ShapeError(
                "depth", ("T", "H", "W"), depth.shape, "For a single frame use depth[None]"
            )
        check_shape(depth, ("T", "H", "W"), name="depth")
        check_shape(intensity, ("T", "H", "W"), name="intensity", hint="convert colour to gray")
        if depth.shape[0] < 1:
            raise ValueError("a sequence needs at least one frame (T >= 1), got T = 0")
        if intensity.shape != depth.shape:
            raise ShapeError(
                "intensity",
                depth.shape,
                intensity.shape,
                f"intensity must match depth {depth.shape} frame for frame",
            )
        k = self.intrinsics
        if depth.shape[1:] != (k.height, k.width):
            raise ShapeError(
                "depth",
                ("T", k.height, k.width),
                depth.shape,
                f"the intrinsics give an image of {k.height}x{k.width} (HxW)",
            )
        d = sanitize_depth(depth)
        if intensity.dtype.kind == "f":
            i = as_float32(intensity, name="intensity")
            finite = i[np.isfinite(i)]
            if finite.size != i.size:
                raise ValueError("intensity contains NaN or inf; intensity must be dense")
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
            if lo < 0.0 or hi > 1.0:
                raise ValueError(
                    f"intensity must lie in [0, 1], got range [{lo:.4g}, {hi:.4g}]; "
                    "use fuse4d.sequence.normalize_intensity() to rescale"
                )
        else:
            i = normalize_intensity(intensity)
        object.__setattr__(self, "depth", d)
        object.__setattr__(self, "intensity", np.ascontiguousarray(i))
        if self.timestamps is not None:
            ts = np.asarray(self.timestamps, dtype=np.float64).ravel()
            if ts.shape != (d.shape[0],):
                raise ShapeError("timestamps", (d.shape[0],), ts.shape, "one time per frame")
            if ts.size > 1 and not np.all(np.diff(ts) > 0):
                raise ValueError("timestamps must be strictly increasing")
            object.__setattr__(self, "timestamps", ts)
        if self.fps is not None:
            fps = float(self.fps)
            if not (np.isfinite(fps) and fps > 0):
                raise ValueError(f"fps must be a positive number, got {self.fps!r}")
            object.__setattr__(self, "fps", fps)
        if self.ground_truth is not None:
            self._check_ground_truth(self.ground_truth)
        valid_fraction = float(np.isfinite(d).mean()) if d.size else 0.0
        if valid_fraction < 0.5:
            warnings.warn(
                f"only {100 * valid_fraction:.1f} % of depth pixels are valid",
                stacklevel=3,
            )

    def _check_ground_truth(self, gt: GroundTruth) -> None:
        shape = self.depth.shape
        if gt.depth is not None:
            check_shape(np.asarray(gt.depth), shape, name="ground_truth.depth")
        if gt.mask is not None:
            check_shape(np.asarray(gt.mask), shape, name="ground_truth.mask")
        if gt.flow is not None:
            check_shape(
                np.asarray(gt.flow), (shape[0] - 1, shape[1], shape[2], 2), name="ground_truth.flow"
            )

    # ------------------------------------------------------------------ properties
    @property
    def num_frames(self) -> int:
        """Number of frames T."""
        return int(self.depth.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """Frame shape ``(H, W)``."""
        return (int(self.depth.shape[1]), int(self.depth.shape[2]))

    @property
    def valid(self) -> NDArray[np.bool_]:
        """``(T, H, W)`` bool: True where depth is valid."""
        return np.isfinite(self.depth)

    def points(self) -> NDArray[np.float32]:
        """Back-projected point maps ``(T, H, W, 3)`` in mm (paper Eq. 2)."""
        return depth_to_points(self.depth, self.intrinsics)

    def frames(self, start: int | None = None, stop: int | None = None) -> Sequence:
        """A new sequence holding frames ``start:stop`` (ground truth sliced to match)."""
        sl = slice(start, stop)
        idx = range(self.num_frames)[sl]
        if len(idx) < 1:
            raise ValueError(
                f"frame range {start}:{stop} selects no frame of a {self.num_frames}-frame sequence"
            )
        gt = self.ground_truth
        if gt is not None:
            a, b = idx.start, idx.stop
            gt = GroundTruth(
                depth=None if gt.depth is None else gt.depth[a:b],
                mask=None if gt.mask is None else gt.mask[a:b],
                flow=None if gt.flow is None else gt.flow[a : max(a, b - 1)],
                extra={
                    k: (
                        v[a:b]
                        if isinstance(v, np.ndarray) and v.shape[:1] == (self.num_frames,)
                        else v
                    )
                    for k, v in gt.extra.items()
                },
            )
        return replace(
            self,
            depth=self.depth[sl],
            intensity=self.intensity[sl],
            timestamps=None if self.timestamps is None else self.timestamps[sl],
            ground_truth=gt,
        )

    def with_depth(self, depth: np.ndarray) -> Sequence:
        """The same sequence with other depth frames (e.g. a filtered result)."""
        return replace(self, depth=depth)
