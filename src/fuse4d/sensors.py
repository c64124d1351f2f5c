"""Depth-sensor models: what structured-light, active-stereo and time-of-flight cameras do to a
true depth map (issue 10; SENSORS.md).

fuse4d was tuned on the paper's sensor — continuous Gaussian noise of 0.2 mm. The depth that
users hold is different, and these models reproduce the effects that matter for fusion, with
ground truth:

* **structured light** (Kinect v1, Xtion; :data:`KINECT_V1`): depth from the disparity between
  the IR camera and a projector ``baseline_mm`` to its side, ``z = f b / d``. The disparity is
  found by block matching, so its noise is *spatially correlated* over the matching window,
  and it is quantised to ``1/8`` px: depth comes in steps ``Δz = z² q / (f b)`` (≈ 6.5 mm at
  1.5 m, ≈ 26 mm at 3 m for f = 580 px, b = 75 mm). Beside every foreground edge, on the side
  away from the projector, the projector's pattern is shadowed: a band of holes whose width is
  the disparity difference. Dark and grazing surfaces drop out.
* **active stereo** (RealSense D4xx; :data:`D435`): the same disparity geometry between two IR
  cameras 50 mm apart, with 1/32-px subpixel steps and larger correlated noise (subpixel RMS
  0.08 px); occlusion holes beside foreground edges.
* **time of flight** (Azure Kinect, Orbbec Femto; :data:`TOF`): depth noise that grows as the
  returned IR amplitude falls (albedo · cos θ / z²), *flying pixels* between foreground and
  background at depth edges (mixed returns), dropouts where the amplitude is too low, no
  quantisation beyond the mm of the file.

Every model ends as the file stores it: depth rounded to whole mm, 0 (here NaN) = invalid,
outside ``[min_range_mm, max_range_mm]`` invalid.

Examples
--------
>>> import numpy as np
>>> from fuse4d.camera import Intrinsics
>>> k = Intrinsics(580.0, 580.0, 31.5, 23.5, 64, 48)
>>> truth = np.full((1, 48, 64), 3000.0, np.float32)
>>> out = apply_sensor(truth, np.full_like(truth, 0.5), k, KINECT_V1, rng=0)
>>> steps = np.unique(out.depth[np.isfinite(out.depth)])
>>> bool(np.all(np.diff(steps) > 20))  # quantised in ~26 mm disparity steps at 3 m
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from ._validation import check_same_shape
from .camera import Intrinsics, check_intrinsics
from .errors import ParameterError, ShapeError
from .sequence import as_unit_intensity

__all__ = [
    "D435",
    "KINECT_V1",
    "SENSORS",
    "TOF",
    "SensorModel",
    "SensorOutput",
    "apply_sensor",
    "depth_step_mm",
    "get_sensor",
]

SensorKind = Literal["structured-light", "active-stereo", "tof"]


@dataclass(frozen=True)
class SensorModel:
    """Parameters of a depth-sensor model (see the module docstring).

    Parameters
    ----------
    name : str
        Registry name (``kinect``, ``d435``, ``tof``).
    kind : {"structured-light", "active-stereo", "tof"}
        Which physics applies.
    baseline_mm : float
        Projector–camera (or camera–camera) baseline b, mm; the projector / second camera sits
        at +b along the image x axis. Unused for ToF.
    subpixel : float
        Disparity quantisation step q, px (Kinect v1: 1/8; D4xx: 1/32). 0 = continuous.
    disparity_noise_px : float
        Standard deviation of the block-matching disparity error that changes from frame to
        frame (temporal noise), px.
    static_noise_px : float
        Standard deviation of the fixed-pattern disparity error (the same in every frame of a
        recording: calibration residue, speckle-pattern bias), px. Temporal averaging cannot
        remove it; on the real Kinect clip it is the larger part (see ``docs/sensors.md``).
    correlation_px : int
        Side of the matching window, px: the disparity noise is white noise averaged over it
        (then rescaled to ``disparity_noise_px``), so neighbouring pixels err together.
    shadows : bool
        Holes where the projector (second camera) cannot see the surface.
    dropout : float
        Fraction of valid pixels dropped at random (speckle decorrelation, saturation).
    dark_dropout : float
        Pixels whose IR return is below this value drop out: albedo · cos θ for a disparity
        sensor (the pattern's contrast), the amplitude albedo · cos θ / z² (z in m) for ToF
        (the camera's own light falls off with distance; its depth engine invalidates pixels
        of too weak a signal, so a dark surface drops out far away, not near).
    tof_noise_mm : float
        ToF only: depth noise (mm) at amplitude 1 (albedo 1, facing, at 1 m); grows as
        1 / sqrt(amplitude).
    flying_pixels : float
        ToF only: probability that a pixel at a depth edge returns a mix of the two depths.
    min_range_mm, max_range_mm : float
        Valid depth range of the camera, mm.

    Raises
    ------
    ParameterError
        A value no camera has (each check names the field): a disparity sensor without a
        positive baseline, negative or non-finite noise or quantisation, a matching window
        that is not a positive integer, a probability outside [0, 1], or an empty range. Such
        a model gave depth without a single valid pixel, silently.
    """

    name: str
    kind: SensorKind
    baseline_mm: float = 75.0
    subpixel: float = 0.125
    disparity_noise_px: float = 0.035
    static_noise_px: float = 0.0
    correlation_px: int = 9
    shadows: bool = True
    dropout: float = 0.01
    dark_dropout: float = 0.05
    tof_noise_mm: float = 0.0
    flying_pixels: float = 0.0
    min_range_mm: float = 500.0
    max_range_mm: float = 6000.0
    notes: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        def bad(what: str, value: object) -> ParameterError:
            return ParameterError(f"sensor model {self.name!r}: {what}, got {value!r}")

        if self.kind not in ("structured-light", "active-stereo", "tof"):
            raise bad("kind must be structured-light, active-stereo or tof", self.kind)
        for name in ("subpixel", "disparity_noise_px", "static_noise_px", "tof_noise_mm"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise bad(f"{name} must be a finite number >= 0", value)
        if self.kind != "tof" and not (math.isfinite(self.baseline_mm) and self.baseline_mm > 0):
            raise bad("baseline_mm must be > 0 for a disparity sensor (mm)", self.baseline_mm)
        c = self.correlation_px
        if isinstance(c, bool) or not isinstance(c, int | np.integer) or c < 1:
            raise bad("correlation_px must be an integer >= 1 (px)", c)
        for name in ("dropout", "dark_dropout", "flying_pixels"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0.0 <= value <= 1.0):
                raise bad(f"{name} must be in [0, 1]", value)
        lo, hi = self.min_range_mm, self.max_range_mm
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
            raise bad("the range must satisfy 0 <= min_range_mm < max_range_mm (mm)", (lo, hi))


#: Kinect v1 / Asus Xtion-class structured light (Khoshelham & Elberink 2012: 1/8-px
#: disparity, b = 75 mm, f ≈ 580 px). Noise calibrated on the static wall of the real
#: ``uva_cv2_person_turning`` clip at 2.6 m (docs/sensors.md): 23 % of static-wall pixels
#: change level from one frame to the next (model: temporal 0.025 px gives 23 %), one frame
#: departs from a local plane by 12.3 mm RMS (model 11.2) and the 40-frame mean still by
#: 9.7 mm (model 8.6: fixed pattern 0.045 px on top of the 1/8-px quantisation).
KINECT_V1 = SensorModel(
    name="kinect",
    kind="structured-light",
    baseline_mm=75.0,
    subpixel=1.0 / 8.0,
    disparity_noise_px=0.025,
    static_noise_px=0.045,
    correlation_px=9,
    shadows=True,
    dropout=0.01,
    dark_dropout=0.05,
    min_range_mm=500.0,
    max_range_mm=5000.0,
    notes="Kinect v1 / Xtion structured light",
)
#: RealSense D435-class active stereo (b = 50 mm, 1/32-px subpixel, subpixel RMS 0.08 px
#: split into temporal 0.06 px and fixed-pattern 0.05 px: an assumption, no D435 clip with
#: ground truth is at hand).
D435 = SensorModel(
    name="d435",
    kind="active-stereo",
    baseline_mm=50.0,
    subpixel=1.0 / 32.0,
    disparity_noise_px=0.06,
    static_noise_px=0.05,
    correlation_px=7,
    shadows=True,
    dropout=0.01,
    dark_dropout=0.03,
    min_range_mm=300.0,
    max_range_mm=6000.0,
    notes="RealSense D4xx active stereo",
)
#: Azure Kinect / Orbbec Femto-class ToF (≈ 1 mm noise at 1 m on bright surfaces, flying
#: pixels at edges). Dark dropout at amplitude 0.005: the Azure Kinect's operating range
#: (NFOV binned, to 5.46 m) holds for 15-95 % reflectance, and 0.15 / 5.46² ≈ 0.005.
TOF = SensorModel(
    name="tof",
    kind="tof",
    baseline_mm=0.0,
    subpixel=0.0,
    disparity_noise_px=0.0,
    correlation_px=1,
    shadows=False,
    dropout=0.002,
    dark_dropout=0.005,
    tof_noise_mm=0.6,
    flying_pixels=0.5,
    min_range_mm=250.0,
    max_range_mm=5500.0,
    notes="Azure Kinect / Femto time of flight",
)

SENSORS: dict[str, SensorModel] = {m.name: m for m in (KINECT_V1, D435, TOF)}


def get_sensor(name: str | SensorModel) -> SensorModel:
    """The sensor model called ``name`` (``kinect``, ``d435``, ``tof``)."""
    if isinstance(name, SensorModel):
        return name
    try:
        return SENSORS[name]
    except KeyError:
        raise ParameterError(
            f"unknown sensor {name!r}; choose one of {', '.join(SENSORS)}"
        ) from None


def depth_step_mm(model: SensorModel | str, z_mm: float, focal_px: float) -> float:
    """Depth quantisation step of a disparity sensor at depth ``z_mm``: ``z² q / (f b)`` (mm).

    Parameters
    ----------
    model : SensorModel or str
        The sensor or its name (``kinect``, ``d435``, ``tof``).
    z_mm : float
        Depth, mm.
    focal_px : float
        Focal length of the depth camera, px.

    Returns
    -------
    float
        Step between neighbouring depth levels, mm (1 for ToF: the mm of the file).
    """
    model = get_sensor(model)
    if not focal_px > 0:
        raise ParameterError(f"focal_px must be > 0 pixels, got {focal_px!r}")
    if model.kind == "tof" or model.subpixel <= 0:
        return 1.0
    return z_mm * z_mm * model.subpixel / (focal_px * model.baseline_mm)


@dataclass(frozen=True)
class SensorOutput:
    """What a sensor model returns.

    Attributes
    ----------
    depth : (T, H, W) ndarray of float32
        Sensor depth in mm, whole mm, NaN = invalid (0 in a 16-bit file).
    shadow : (T, H, W) ndarray of bool
        Holes from projector / second-camera occlusion.
    dropout : (T, H, W) ndarray of bool
        Holes from dark surfaces, random dropout and range limits.
    flying : (T, H, W) ndarray of bool
        Flying (mixed) pixels at depth edges (ToF).
    """

    depth: NDArray[np.float32]
    shadow: NDArray[np.bool_]
    dropout: NDArray[np.bool_]
    flying: NDArray[np.bool_]


def apply_sensor(
    depth: NDArray[np.floating],
    intensity: NDArray[np.floating],
    intrinsics: Intrinsics,
    model: SensorModel | str,
    *,
    normal_z: NDArray[np.floating] | None = None,
    rng: int | np.random.Generator | None = None,
) -> SensorOutput:
    """Turn true depth into what ``model`` would record.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        True depth, mm (NaN = no surface).
    intensity : (T, H, W) ndarray
        Albedo-like IR reflectance in [0, 1], unshaded (uint8/uint16 divided by 255/65535;
        other integer types refused): dark pixels drop out, and ToF noise grows as it falls. The incidence angle
        is ``normal_z``'s: an image already shaded by it would count it twice.
    intrinsics : Intrinsics
        The depth camera; its ``fx`` sets the disparity scale.
    model : SensorModel or str
        The sensor (:data:`KINECT_V1`, :data:`D435`, :data:`TOF` or their names).
    normal_z : (T, H, W) ndarray, optional
        Minus the cosine of the angle between the surface normal and the viewing ray (the Z
        component of the normal for a surface on the optical axis; -1 = facing the camera):
        grazing surfaces return less light. Default: facing the camera.
    rng : int or Generator, optional
        Seed of the noise.

    Returns
    -------
    SensorOutput
        Sensor depth (mm, NaN holes) and the masks of each kind of hole.
    """
    m = get_sensor(model)
    check_intrinsics(intrinsics)
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    z = np.asarray(depth, dtype=np.float64)
    if z.ndim != 3:
        raise ShapeError("depth", ("T", "H", "W"), z.shape)
    if z.shape[1:] != intrinsics.shape:
        raise ShapeError(
            "depth", ("T", *intrinsics.shape), z.shape, "The intrinsics' height x width"
        )
    # uint8/uint16 divided by 255/65535 (a uint8 albedo was clipped to 1 everywhere)
    albedo = as_unit_intensity(np.asarray(intensity)).astype(np.float64)
    check_same_shape(z, albedo, names=("depth", "intensity"))
    if normal_z is None:
        cos = np.ones_like(z)
    else:
        nz = np.asarray(normal_z, dtype=np.float64)
        check_same_shape(z, nz, names=("depth", "normal_z"))
        cos = np.clip(-nz, 0.0, 1.0)
    t, h, w = z.shape
    out = np.full(z.shape, np.nan, np.float32)
    shadow = np.zeros(z.shape, bool)
    drop = np.zeros(z.shape, bool)
    flying = np.zeros(z.shape, bool)
    f = float(intrinsics.fx)
    fixed = (
        _correlated_noise(gen, (h, w), m.correlation_px, m.static_noise_px)
        if m.static_noise_px > 0
        else np.zeros((h, w))
    )
    for k in range(t):
        zk = z[k]
        valid = np.isfinite(zk) & (zk > 0)
        returned = albedo[k] * cos[k]  # the surface's IR return, albedo · cos θ
        if m.kind == "tof":
            dk, fly = _tof_frame(zk, valid, returned, m, gen)
            flying[k] = fly
            # the camera's own light falls off as 1/z² (z in m): the amplitude decides
            returned = returned / np.where(valid, zk / 1000.0, 1.0) ** 2
        else:
            dk, shadow[k] = _disparity_frame(zk, valid, f, m, gen, fixed)
        lost = (returned < m.dark_dropout) | (gen.random((h, w)) < m.dropout)
        with np.errstate(invalid="ignore"):
            lost |= ~((dk >= m.min_range_mm) & (dk <= m.max_range_mm))
        # holes only where there is a surface: a NaN depth there (a disparity quantised to
        # <= 0, beyond the range a disparity can measure) is a range-limit hole too
        lost &= valid
        drop[k] = lost & ~shadow[k]
        dk = np.where(lost | shadow[k], np.nan, np.round(dk))
        out[k] = dk.astype(np.float32)
    return SensorOutput(depth=out, shadow=shadow, dropout=drop, flying=flying)


def _correlated_noise(
    gen: np.random.Generator, shape: tuple[int, int], window: int, sigma: float
) -> NDArray[np.float64]:
    """White noise box-averaged over ``window`` px, rescaled to standard deviation ``sigma``."""
    white = gen.standard_normal(shape)
    if window > 1:
        white = cv2.blur(white, (window, window), borderType=cv2.BORDER_REFLECT) * window
    return white * sigma


def _disparity_frame(
    z: NDArray[np.float64],
    valid: NDArray[np.bool_],
    focal: float,
    m: SensorModel,
    gen: np.random.Generator,
    fixed: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Structured light / active stereo: correlated disparity noise (temporal + the fixed
    pattern ``fixed``, px), quantisation, shadows."""
    fb = focal * m.baseline_mm
    disparity = np.where(valid, fb / np.where(valid, z, 1.0), 0.0)
    shadow = _projector_shadow(disparity, valid) if m.shadows else np.zeros_like(valid)
    temporal = _correlated_noise(gen, z.shape, m.correlation_px, m.disparity_noise_px)
    noisy = disparity + temporal + fixed
    if m.subpixel > 0:
        noisy = np.round(noisy / m.subpixel) * m.subpixel
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(valid & (noisy > 0), fb / noisy, np.nan)
    return depth, shadow & valid


def _projector_shadow(disparity: NDArray[np.float64], valid: NDArray[np.bool_]) -> NDArray:
    """Pixels the projector (at +b along x) cannot light.

    The projector sees a surface point at column ``u_p = u - d`` (d = disparity, px). Scanning a
    row from right to left, a pixel is shadowed when its ``u_p`` lies beyond the smallest
    ``u_p`` of the pixels to its right: a nearer surface to its right
    covers it from the projector. The band left of a foreground edge is ``d_fg - d_bg`` wide.
    """
    w = disparity.shape[1]
    u = np.arange(w, dtype=np.float64)[None, :]
    up = np.where(valid, u - disparity, np.inf)
    # min of u_p over the columns strictly right of each pixel
    right_min = np.minimum.accumulate(up[:, ::-1], axis=1)[:, ::-1]
    right_min = np.concatenate([right_min[:, 1:], np.full((up.shape[0], 1), np.inf)], axis=1)
    return valid & (up > right_min)


def _tof_frame(
    z: NDArray[np.float64],
    valid: NDArray[np.bool_],
    returned: NDArray[np.float64],
    m: SensorModel,
    gen: np.random.Generator,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Time of flight: amplitude-dependent noise and flying pixels at depth edges."""
    zm = np.where(valid, z, np.nan) / 1000.0
    amplitude = np.maximum(returned, 1e-3) / np.maximum(np.nan_to_num(zm, nan=1.0) ** 2, 1e-6)
    sigma = m.tof_noise_mm / np.sqrt(amplitude)
    depth = np.where(valid, z + gen.standard_normal(z.shape) * sigma, np.nan)
    # flying pixels: a pixel next to a depth jump of > 5 % returns a mix of both depths
    zf = np.where(valid, z, np.inf)
    neighbour = np.full_like(zf, np.inf)
    big = np.zeros(z.shape, bool)
    for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        shifted = _shift(zf, dv, du)
        with np.errstate(invalid="ignore"):
            jump = np.abs(shifted - zf) > 0.05 * np.minimum(shifted, zf)
        farther = jump & (shifted > zf) & np.isfinite(shifted)
        neighbour = np.where(farther & ~big, shifted, neighbour)
        big |= farther
    fly = big & valid & (gen.random(z.shape) < m.flying_pixels)
    mix = gen.random(z.shape)
    depth = np.where(fly, mix * z + (1.0 - mix) * neighbour, depth)
    if not math.isfinite(m.tof_noise_mm):
        raise ParameterError("tof_noise_mm must be finite")
    return depth, fly


def _shift(a: NDArray[np.float64], dv: int, du: int) -> NDArray[np.float64]:
    """``out[v, u] = a[v - dv, u - du]``, inf where that lies outside the image (no wrap)."""
    out = np.full_like(a, np.inf)
    h, w = a.shape
    out[max(dv, 0) : h + min(dv, 0), max(du, 0) : w + min(du, 0)] = a[
        max(-dv, 0) : h + min(-dv, 0), max(-du, 0) : w + min(-du, 0)
    ]
    return out
