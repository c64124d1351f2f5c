"""The in-memory 3D video: depth + registered intensity + camera (+ optional ground truth)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_float32, check_shape
from .camera import Intrinsics, check_intrinsics, depth_to_points
from .errors import ParameterError, ParameterTypeError, ShapeError

__all__ = [
    "BallTruth",
    "GroundTruth",
    "PlaneTruth",
    "SceneTruth",
    "Sequence",
    "SheetTruth",
    "check_unit_intensity",
    "normalize_intensity",
    "sanitize_depth",
]


def sanitize_depth(depth: ArrayLike) -> NDArray[np.float32]:
    """Float32 depth (mm) with every invalid value (0, negative, inf, NaN) set to NaN; the
    input is never written to (a view of it, e.g. of a memmap, is copied first)."""
    d = as_float32(depth, name="depth")
    bad = ~(np.isfinite(d) & (d > 0))
    if bad.any():
        d = d.copy() if np.may_share_memory(d, depth) else d
        d[bad] = np.nan
    return d


#: The camera kinds of :attr:`Sequence.sensor` (the values of :data:`fuse4d.sensors.SensorKind`,
#: written out so that sequences and readers do not import the models).
_SENSOR_KINDS = ("structured-light", "active-stereo", "tof")

#: Why fuse4d needs an intensity video (said where None was passed).
INTENSITY_REQUIRED = (
    "intensity is required: fuse4d tracks every pixel through the registered intensity (IR or "
    "gray) video; a depth-only recording has none (baselines without a guide, e.g. "
    "temporal-mean, take intensity=None)"
)


def normalize_intensity(intensity: ArrayLike, *, name: str = "intensity") -> NDArray[np.float32]:
    """Convert intensity to float32 in [0, 1] (METHOD A16).

    * uint8 and uint16 are divided by 255 and 65535, bool gives 0 and 1;
    * other integer dtypes (the int64 of a list of Python ints, int32, ...) are refused: their
      range is not the image's (divided by the int64 maximum, 0-255 values all became ~0);
      convert them to uint8 or uint16, or to float in [0, 1];
    * floats already in [0, 1] are kept; floats whose finite values leave [0, 1] are rescaled
      linearly over the whole array: divided by their maximum where none is negative (0-255
      floats), else mapped from [min, max] onto [0, 1] (a constant array gives 0). NaN and inf
      stay (a :class:`Sequence` refuses them).

    Parameters
    ----------
    intensity : array_like
        Intensity of one frame or a sequence.
    name : str, optional
        How to name it in the error.

    Returns
    -------
    ndarray of float32
        In [0, 1] (NaN and inf of float input kept).

    Raises
    ------
    ParameterTypeError
        For integer dtypes other than uint8 and uint16 (the message says which to convert
        to) and for non-numeric input.

    Examples
    --------
    >>> normalize_intensity(np.array([0, 51, 255], np.uint8)).tolist()
    [0.0, 0.20000000298023224, 1.0]
    >>> normalize_intensity(np.array([-0.5, 0.0, 1.5])).tolist()
    [0.0, 0.25, 1.0]
    """
    arr = np.asarray(intensity)
    if arr.dtype == np.bool_:
        return arr.astype(np.float32)
    if arr.dtype.kind in "ui":
        if arr.dtype.kind == "i" or arr.dtype.itemsize > 2:  # (either byte order)
            raise ParameterTypeError(_integer_intensity_message(arr, name))
        white = 255 if arr.dtype.itemsize == 1 else 65535
        return arr.astype(np.float32) / np.float32(white)
    out = as_float32(arr, name=name)
    if not out.size:
        return out
    lo, hi = _finite_range(out)
    if lo < 0.0:
        span = hi - lo
        out = (out - np.float32(lo)) / np.float32(span) if span > 0 else out - np.float32(lo)
    elif hi > 1.0:
        out = out / np.float32(hi)
    return out


def _integer_intensity_message(arr: NDArray[np.integer], name: str) -> str:
    """Why integer intensity of another dtype than uint8/uint16 is refused, and what to do."""
    lo, hi = (int(arr.min()), int(arr.max())) if arr.size else (0, 0)
    todo = "divide by the sensor's white level (e.g. 4095 for 12 bits) for float in [0, 1]"
    for bits, dtype in ((8, "uint8"), (16, "uint16")):
        if lo >= 0 and hi < 1 << bits:
            todo = f"convert with .astype(np.{dtype}) if these are {bits}-bit values, else {todo}"
            break
    return (
        f"{name} has integer dtype {arr.dtype} (values {lo} .. {hi}), which does not say its "
        f"bit depth; pass uint8 (0-255), uint16 (0-65535) or float in [0, 1]: {todo}"
    )


def check_unit_intensity(intensity: np.ndarray, *, name: str = "intensity") -> NDArray[np.float32]:
    """Float intensity as float32, refusing values outside [0, 1] and NaN/inf (METHOD A16).

    The fusion's intensity kernel (``sigma_intensity``) and the flow methods expect [0, 1];
    a float frame in 0-255 would silently make every intensity weight ~0. NaN or inf has no
    intensity weight at all (the flow methods refused it later, naming "image0" instead of
    the frame).

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
    ParameterError
        If a value lies outside [0, 1] or is not finite; the message says how to rescale or
        how many pixels are not finite.
    """
    arr = as_float32(intensity, name=name)
    if arr.size:
        lo, hi = float(arr.min()), float(arr.max())
        if not (np.isfinite(lo) and np.isfinite(hi)):
            bad = int(np.count_nonzero(~np.isfinite(arr)))
            raise ParameterError(
                f"{name} has {bad} NaN or inf pixel(s) of {arr.size}; intensity must be finite, "
                "in [0, 1] (set pixels without an image to 0)"
            )
        if lo < 0.0 or hi > 1.0:
            raise ParameterError(
                f"{name} is float with values in [{lo:.4g}, {hi:.4g}], outside [0, 1]; "
                "rescale it to [0, 1] (e.g. divide 8-bit values by 255, or use "
                "fuse4d.sequence.normalize_intensity on the whole sequence), or pass uint8 or "
                "uint16 intensity, divided by 255 or 65535"
            )
    return arr


#: How far outside [0, 1] float intensity may lie where it is saturated rather than refused
#: (flow input, writers, colours): resampled images over- and undershoot a little (cubic
#: warps: -0.003 .. 1.007); 0-255 floats are far beyond it.
UNIT_RANGE_SLACK = 0.5


def as_storable_intensity(intensity: ArrayLike, *, name: str = "intensity") -> NDArray[np.float32]:
    """Intensity to store or show (writers, point colours): integers as
    :func:`normalize_intensity` and the fusion engine take them (uint8 and uint16 divided by
    255 and 65535; a ``cv2.imread`` uint8 frame used to be stored as 0-255 and saturated to
    white); floats as float32, to be clipped to [0, 1] by the caller, NaN allowed (stored as
    0), refused when farther than :data:`UNIT_RANGE_SLACK` outside [0, 1] (0-255 floats would
    all store as 1).

    Raises
    ------
    ParameterError
        For float values far outside [0, 1], and other integer dtypes than uint8 and uint16.
    """
    arr = np.asarray(intensity)
    if arr.dtype.kind in "uib":
        return normalize_intensity(arr, name=name)
    arr = as_float32(arr, name=name)
    if not arr.size:
        return arr
    lo, hi = _finite_range(arr)
    check_unit_slack(lo, hi, name=name)
    return arr


def _finite_range(arr: NDArray[np.float32]) -> tuple[float, float]:
    """Smallest and largest finite value of a non-empty array ((0, 0) where none is)."""
    lo, hi = float(arr.min()), float(arr.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):  # NaN or inf present: the finite values
        finite = arr[np.isfinite(arr)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    return lo, hi


def check_unit_slack(lo: float, hi: float, *, name: str) -> None:
    """Refuse float intensity whose range [``lo``, ``hi``] lies farther than
    :data:`UNIT_RANGE_SLACK` outside [0, 1] (0-255 data): the one rule and message of the
    writers, point colours and the flow input."""
    if lo < -UNIT_RANGE_SLACK or hi > 1.0 + UNIT_RANGE_SLACK:
        raise ParameterError(
            f"{name} is float with values in [{lo:.4g}, {hi:.4g}], not [0, 1]; rescale it "
            "(e.g. divide 8-bit values by 255) or pass uint8 or uint16, divided by 255 or 65535"
        )


def as_unit_intensity(intensity: np.ndarray, *, name: str = "intensity") -> NDArray[np.float32]:
    """Intensity as float32 in [0, 1]: uint8 and uint16 divided by 255 and 65535, other
    integers refused (:func:`normalize_intensity`), floats checked
    (:func:`check_unit_intensity`), as the fusion engine and the baselines take it."""
    arr = np.asarray(intensity)
    if arr.dtype.kind in "uib":
        return normalize_intensity(arr, name=name)
    return check_unit_intensity(arr, name=name)


class _SceneTruthBase:
    """Shared behaviour of the typed scene geometries (frame selection, npz keys)."""

    scene: ClassVar[str]

    def select(self, index: slice | NDArray[np.integer]) -> Any:
        """The same geometry for the frames ``index`` (a slice or an index array)."""
        changes = {
            f.name: np.asarray(getattr(self, f.name))[index]
            for f in fields(self)  # type: ignore[arg-type]
            if f.metadata.get("per_frame")
        }
        return replace(self, **changes)  # type: ignore[type-var]

    def to_extra(self) -> dict[str, Any]:
        """Plain values keyed by field name plus ``scene``: the npz ``gt_<key>`` layout."""
        out: dict[str, Any] = {"scene": self.scene}
        out.update({f.name: getattr(self, f.name) for f in fields(self)})  # type: ignore[arg-type]
        return out

    @classmethod
    def from_extra(cls, values: dict[str, Any]) -> Any:
        """Build from :meth:`to_extra`'s layout (values as read back from an npz file).

        Raises
        ------
        KeyError
            Naming the missing keys.
        """
        names = [f.name for f in fields(cls)]  # type: ignore[arg-type]
        missing = [n for n in names if n not in values]
        if missing:
            raise KeyError(", ".join(missing))
        kwargs: dict[str, Any] = {}
        for f in fields(cls):  # type: ignore[arg-type]
            value = values[f.name]
            kind = f.metadata.get("kind", "array")
            if kind == "float":
                value = float(np.asarray(value))
            elif kind == "int":
                value = int(np.asarray(value))
            elif kind == "pair_int":
                value = tuple(int(v) for v in np.asarray(value).ravel())
            elif kind == "pair_float":
                value = tuple(float(v) for v in np.asarray(value).ravel())
            else:
                value = np.asarray(value, dtype=np.float64)
            kwargs[f.name] = value
        return cls(**kwargs)


@dataclass(frozen=True, eq=False)
class BallTruth(_SceneTruthBase):
    """Geometry of the synthetic falling ball (:func:`fuse4d.synthetic.make_falling_ball`).

    Image lengths are px of this sequence (full-size values times ``pixel_scale``); the
    metrics of EVALUATION §2-3 (ball ROI, shape correctness) read them from here.

    Attributes
    ----------
    center_row : (T,) ndarray of float64
        Projected centre row v_c(t) (px).
    center_col : float
        Projected centre column (px).
    center_mm : (T, 3) ndarray of float64
        Ball centre C(t) in camera coordinates (mm).
    radius_mm : float
        True radius r (mm), 140.
    speed_px : float
        Image speed of the centre (px/frame).
    pixel_scale : float
        fx / 1000 (1 at full size, 0.25 for the small variant).
    roi_radius_px : float
        Radius of the roughness ROI around the centre (px).
    fit_columns : (int, int)
        First and last column (inclusive) of the shape-correctness fit (px).
    fit_half_rows : float
        Half height of the fit window around v_c(t) (px).
    mask_erosion_px : int
        Erosion of the GT mask before the fit (px, Euclidean disk).
    """

    scene: ClassVar[str] = "ball"

    center_row: NDArray[np.float64] = field(metadata={"kind": "array", "per_frame": True})
    center_col: float = field(metadata={"kind": "float"})
    center_mm: NDArray[np.float64] = field(metadata={"kind": "array", "per_frame": True})
    radius_mm: float = field(metadata={"kind": "float"})
    speed_px: float = field(metadata={"kind": "float"})
    pixel_scale: float = field(metadata={"kind": "float"})
    roi_radius_px: float = field(metadata={"kind": "float"})
    fit_columns: tuple[int, int] = field(metadata={"kind": "pair_int"})
    fit_half_rows: float = field(metadata={"kind": "float"})
    mask_erosion_px: int = field(metadata={"kind": "int"})


@dataclass(frozen=True, eq=False)
class PlaneTruth(_SceneTruthBase):
    """Geometry of the static tilted plane (:func:`fuse4d.synthetic.make_static_plane`).

    Attributes
    ----------
    size_mm : (float, float)
        Width and height of the plane (mm).
    center_mm : (3,) ndarray of float64
        Plane centre (mm).
    normal : (3,) ndarray of float64
        Unit normal.
    tilt_deg : float
        Tilt about the X axis (degrees).
    pixel_scale : float
        fx / 1000.
    """

    scene: ClassVar[str] = "plane"

    size_mm: tuple[float, float] = field(metadata={"kind": "pair_float"})
    center_mm: NDArray[np.float64] = field(metadata={"kind": "array"})
    normal: NDArray[np.float64] = field(metadata={"kind": "array"})
    tilt_deg: float = field(metadata={"kind": "float"})
    pixel_scale: float = field(metadata={"kind": "float"})


@dataclass(frozen=True, eq=False)
class SheetTruth(_SceneTruthBase):
    """Geometry of the deforming sheet (:func:`fuse4d.synthetic.make_deforming_sheet`).

    Attributes
    ----------
    center_x_mm : (T,) ndarray of float64
        Lateral offset X_c(t) of the sheet (mm).
    amplitude : (T,) ndarray of float64
        Bump amplitude a(t) (mm).
    size_mm : (float, float)
        Sheet size (mm).
    sheet_z_mm : float
        Depth of the flat sheet (mm).
    bump_sigma_mm : float
        Width of the Gaussian bump (mm).
    drift_px : float
        Lateral drift (px/frame, this sequence's pixels).
    pixel_scale : float
        fx / 1000.
    """

    scene: ClassVar[str] = "sheet"

    center_x_mm: NDArray[np.float64] = field(metadata={"kind": "array", "per_frame": True})
    amplitude: NDArray[np.float64] = field(metadata={"kind": "array", "per_frame": True})
    size_mm: tuple[float, float] = field(metadata={"kind": "pair_float"})
    sheet_z_mm: float = field(metadata={"kind": "float"})
    bump_sigma_mm: float = field(metadata={"kind": "float"})
    drift_px: float = field(metadata={"kind": "float"})
    pixel_scale: float = field(metadata={"kind": "float"})


#: The typed geometry of a synthetic scene.
SceneTruth = BallTruth | PlaneTruth | SheetTruth
_SCENE_TYPES: dict[str, type[_SceneTruthBase]] = {
    c.scene: c for c in (BallTruth, PlaneTruth, SheetTruth)
}


def split_scene_extra(values: dict[str, Any]) -> tuple[SceneTruth | None, dict[str, Any]]:
    """Separate a typed scene geometry from flat ``gt_<key>`` values (npz boundary).

    ``values["scene"]`` names the geometry (``ball``, ``plane``, ``sheet``); its fields are
    taken out and the rest is returned as the free-form ``extra``. Without a known ``scene``
    key everything stays in ``extra``.

    Raises
    ------
    KeyError
        If ``scene`` names a geometry whose fields are incomplete (message: the missing keys).
    """
    kind = values.get("scene")
    cls = _SCENE_TYPES.get(str(kind)) if kind is not None else None
    if cls is None:
        return None, dict(values)
    truth = cls.from_extra(values)
    names = {f.name for f in fields(cls)} | {"scene"}  # type: ignore[arg-type]
    return truth, {k: v for k, v in values.items() if k not in names}


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
        Free-form values (for the synthetic scenes: the noise settings, background and seed).
    scene : BallTruth, PlaneTruth or SheetTruth, optional
        The typed geometry of a synthetic scene, read by the metrics (ROIs, Eq. 8).
    """

    depth: NDArray[np.float32] | None = None
    mask: NDArray[np.bool_] | None = None
    flow: NDArray[np.float32] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    scene: SceneTruth | None = None

    def select(self, index: slice | NDArray[np.integer], num_frames: int) -> GroundTruth:
        """The ground truth of frames ``index`` of a ``num_frames``-frame sequence.

        A slice of step 1 keeps the flow of the consecutive pairs inside it; another slice
        (its frames are not consecutive, or in reverse order) or an index array drops it.
        """
        flow = None
        if isinstance(index, slice) and self.flow is not None:
            a, b, step = index.indices(num_frames)
            if step == 1:
                flow = self.flow[a : max(a, b - 1)]

        def take(v: Any) -> Any:
            return np.asarray(v)[index]

        return GroundTruth(
            depth=None if self.depth is None else take(self.depth),
            mask=None if self.mask is None else take(self.mask),
            flow=flow,
            extra={
                k: (take(v) if isinstance(v, np.ndarray) and v.shape[:1] == (num_frames,) else v)
                for k, v in self.extra.items()
            },
            scene=None if self.scene is None else self.scene.select(index),
        )


@dataclass(frozen=True)
class Sequence:
    """A 3D video: pixel-registered depth and intensity frames from one pinhole camera.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm along the optical axis. Converted to float32; 0, negative and inf values
        become NaN (= invalid).
    intensity : (T, H, W) ndarray
        Registered intensity. Converted to float32 in [0, 1] (uint8 and uint16 divided by 255
        and 65535; other integer dtypes refused, see :func:`normalize_intensity`); float input
        must already be in [0, 1].
    intrinsics : Intrinsics
        Camera; its size must match ``(H, W)``.
    timestamps : (T,) ndarray of float64, optional
        Capture times in seconds, finite and strictly increasing.
    fps : float, optional
        Nominal frame rate (metadata only; fuse4d counts time in frames).
    ground_truth : GroundTruth, optional
        Ground truth, for synthetic scenes.
    name : str, optional
        Human-readable name (file or scene).
    sensor : str, optional
        What kind of depth camera recorded it, where the input says so: ``"tof"``,
        ``"structured-light"``, ``"active-stereo"`` (:data:`fuse4d.sensors.SensorKind`); None
        when unknown. It decides ``FusionParams(flying_pixels="auto")`` (A36).

    Raises
    ------
    ShapeError
        If depth and intensity differ in shape, are not 3-D, or disagree with the intrinsics.
    ValueError
        If T < 1, intensity is outside [0, 1] or of an integer dtype other than uint8 and
        uint16, timestamps are not finite or not increasing, fps <= 0, or sensor is not a
        known camera kind.
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
    sensor: str | None = None

    def __post_init__(self) -> None:
        check_intrinsics(self.intrinsics)
        depth = np.asarray(self.depth)
        intensity = np.asarray(self.intensity)
        if depth.ndim == 2:
            raise ShapeError(
                "depth", ("T", "H", "W"), depth.shape, "For a single frame use depth[None]"
            )
        check_shape(depth, ("T", "H", "W"), name="depth")
        if self.intensity is None:
            raise ParameterTypeError(INTENSITY_REQUIRED)
        check_shape(intensity, ("T", "H", "W"), name="intensity", hint="convert colour to gray")
        if depth.shape[0] < 1:
            raise ParameterError("a sequence needs at least one frame (T >= 1), got T = 0")
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
                raise ParameterError("intensity contains NaN or inf; intensity must be dense")
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
            if lo < 0.0 or hi > 1.0:
                raise ParameterError(
                    f"intensity must lie in [0, 1], got range [{lo:.4g}, {hi:.4g}]; "
                    "use fuse4d.sequence.normalize_intensity() to rescale"
                )
        else:
            i = normalize_intensity(intensity)
        object.__setattr__(self, "depth", d)
        object.__setattr__(self, "intensity", np.ascontiguousarray(i))
        if self.timestamps is not None:
            try:
                ts = np.asarray(self.timestamps, dtype=np.float64).ravel()
            except (TypeError, ValueError):
                raise ParameterTypeError(
                    "timestamps must be numbers (seconds, one per frame), got "
                    f"{type(self.timestamps).__name__}"
                ) from None
            if ts.shape != (d.shape[0],):
                raise ShapeError("timestamps", (d.shape[0],), ts.shape, "one time per frame")
            bad = np.flatnonzero(~np.isfinite(ts))
            if bad.size:
                raise ParameterError(
                    f"timestamps must be finite (seconds); frame {int(bad[0])} has "
                    f"{ts[bad[0]]}" + (f" ({bad.size} frames in all)" if bad.size > 1 else "")
                )
            if ts.size > 1 and not np.all(np.diff(ts) > 0):
                raise ParameterError("timestamps must be strictly increasing")
            object.__setattr__(self, "timestamps", ts)
        if self.fps is not None:
            try:
                fps = float(self.fps)
            except (TypeError, ValueError):
                raise ParameterTypeError(f"fps must be a number, got {self.fps!r}") from None
            if not (np.isfinite(fps) and fps > 0):
                raise ParameterError(f"fps must be a positive number, got {self.fps!r}")
            object.__setattr__(self, "fps", fps)
        if self.sensor is not None and self.sensor not in _SENSOR_KINDS:
            # "kinect" or "TOF" read as an unknown camera: A36's flying-pixel removal was
            # silently off, and a frame folder written from it could not be read back
            raise ParameterError(
                f"sensor must be one of {', '.join(_SENSOR_KINDS)} or None, got {self.sensor!r}"
            )
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
            raise ParameterError(
                f"frame range {start}:{stop} selects no frame of a {self.num_frames}-frame sequence"
            )
        gt = self.ground_truth
        if gt is not None:
            gt = gt.select(slice(idx.start, idx.stop), self.num_frames)
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


def check_sequence(seq: object, owner: str) -> Sequence:
    """``seq`` itself where it is a :class:`Sequence`; else a
    :class:`~fuse4d.ParameterTypeError` naming ``owner`` and how to make one (an array
    failed later with "'numpy.ndarray' object has no attribute 'depth'")."""
    if not isinstance(seq, Sequence):
        raise ParameterTypeError(
            f"{owner} takes a fuse4d.Sequence, got {type(seq).__name__}; make one with "
            "fuse4d.Sequence(depth, intensity, intrinsics)"
        )
    return seq
