"""Synthetic scenes with ground truth (EVALUATION.md §3 and §4 E5).

Three scenes, each returned as a :class:`fuse4d.Sequence` whose ``ground_truth`` holds the
noise-free depth (mm), the object mask, the true forward flow (px), the typed scene geometry
in ``scene`` (:class:`~fuse4d.sequence.BallTruth`, :class:`~fuse4d.sequence.PlaneTruth`,
:class:`~fuse4d.sequence.SheetTruth`) and the noise settings and seed in ``extra``:

* :func:`make_falling_ball` — the paper's falling textured ball (§3);
* :func:`make_static_plane` — a static tilted textured plane with texture-correlated and
  fixed-pattern depth noise (E5-a);
* :func:`make_deforming_sheet` — a textured sheet with a breathing Gaussian bump, drifting
  sideways ("face" proxy, E5-c).

Common conventions
------------------
* Camera: 600 x 600 px, fx = fy = 1000 px, cx = cy = 299.5 px. ``small=True`` gives the CI
  variant: 150 x 150 px, fx = fy = 250 px, cx = cy = 74.5 px, 12 frames. The *physical* scene is
  the same, so every image-space length (speeds, ROI radii, fit windows) scales by
  ``pixel_scale = fx / 1000`` (0.25): the ball falls 0.5 px/frame instead of 2 px/frame.
* Texture: a sum of 40 random sinusoids attached to material points, normalised to unit
  standard deviation by the analytic factor ``sqrt(40 / 2)``; albedo
  ``clip(0.5 + 0.2 T, 0.05, 0.95)``; shading ``0.3 + 0.7 max(0, n . (0, 0, -1))``.
  Deviation (small variant only): texture wavelengths are multiplied by ``1 / pixel_scale``
  (16-120 mm instead of 4-30 mm) so that the texture keeps the same size in pixels (7-54 px
  on the ball) and does not alias at the coarser sampling.
* Background (``background="plane"``, the default): a static textured wall at Z = 1000 mm,
  valid depth, facing the camera (shading 1). ``background="none"``: NaN depth and a flat
  intensity of 0.1 (plus intensity noise) outside the object.
* Noise: depth ``D = Z_GT + N(0, depth_noise^2)`` i.i.d. per pixel and frame on valid pixels;
  intensity ``clip(I_true + N(0, intensity_noise^2), 0, 1)``. Randomness comes from
  ``numpy.random.SeedSequence(seed).spawn(5)``: object texture, background texture, depth
  noise, intensity noise and the fixed-pattern (structural) noise each have their own stream.
  Hence the intensity frames depend only on ``(seed, intensity_noise)`` and the depth frames
  only on ``(seed, depth_noise, structural_noise)``; a full frame of noise is drawn per frame
  whatever the validity, so frame t is also independent of ``num_frames``.
* GT flow ``(T-1, H, W, 2)``: defined on the pixel grid of frame t by the surface seen there
  (a background pixel about to be covered by the ball has flow (0, 0)).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ._memory import available_memory as _available_memory
from .camera import Intrinsics
from .errors import ParameterError, ParameterTypeError
from .sequence import BallTruth, GroundTruth, PlaneTruth, Sequence, SheetTruth

__all__ = [
    "SCENES",
    "make_deforming_sheet",
    "make_falling_ball",
    "make_scene",
    "make_static_plane",
    "scene_intrinsics",
]

Background = Literal["plane", "none"]

#: Number of sinusoids of every texture (EVALUATION §3).
NUM_SINUSOIDS = 40
#: Texture wavelength range in mm at full size (|omega| in [1/30, 1/4] mm^-1).
WAVELENGTH_RANGE_MM = (4.0, 30.0)
#: Depth of the background wall (mm) and its flat intensity when ``background="none"``.
BACKGROUND_Z_MM = 1000.0
BACKGROUND_NONE_INTENSITY = 0.1
#: The falling ball at full size (EVALUATION §2-3): radius (mm), depth of the centre (mm),
#: roughness-ROI radius (px), shape-fit columns (px, inclusive), fit half height (px) and GT
#: mask erosion (px). The small variant scales the image lengths by ``pixel_scale``.
BALL_RADIUS_MM = 140.0
BALL_CENTER_Z_MM = 700.0
BALL_ROI_RADIUS_PX = 100.0
BALL_FIT_COLUMNS_PX = (160, 440)
BALL_FIT_HALF_ROWS_PX = 140.0
BALL_MASK_EROSION_PX = 3


# ----------------------------------------------------------------------------- helpers
def scene_intrinsics(*, small: bool = False) -> Intrinsics:
    """The synthetic camera: 600x600, f = 1000 px (``small``: 150x150, f = 250 px)."""
    if small:
        return Intrinsics(fx=250.0, fy=250.0, cx=74.5, cy=74.5, width=150, height=150)
    return Intrinsics(fx=1000.0, fy=1000.0, cx=299.5, cy=299.5, width=600, height=600)


#: Integer seeds are ``0 <= seed < SEED_LIMIT``: the largest that ``extra["seed"]`` can hold in
#: an .npz (uint64; a larger int became an object array that :func:`fuse4d.io.write_npz`
#: refused, after the whole scene was rendered).
SEED_LIMIT = 2**64


def _pixels(small: bool) -> int:
    """Pixels of one frame of the synthetic camera."""
    k = scene_intrinsics(small=small)
    return k.width * k.height


def _seed_of(rng: int | np.random.Generator | np.random.SeedSequence | None) -> int:
    """An integer seed (recorded in ``extra["seed"]``) from the ``rng`` argument.

    ``None`` draws fresh OS entropy; a ``Generator`` contributes one draw.

    Raises
    ------
    ParameterTypeError
        ``rng`` is neither an int, a Generator, a SeedSequence nor None.
    ParameterError
        An int seed outside ``[0, 2**64)`` (:data:`SEED_LIMIT`).
    """
    if rng is None:
        return int(np.random.SeedSequence().entropy % (2**63))  # type: ignore[operator]
    if isinstance(rng, np.random.Generator):
        return int(rng.integers(0, 2**63 - 1))
    if isinstance(rng, np.random.SeedSequence):
        return int(rng.generate_state(2, np.uint64)[0] % (2**63))
    if isinstance(rng, bool) or not isinstance(rng, int | np.integer):
        raise ParameterTypeError(
            f"rng must be a non-negative int seed, a Generator or None, got {rng!r}"
        )
    if not 0 <= int(rng) < SEED_LIMIT:
        raise ParameterError(f"rng must be a seed in [0, 2**64), got {int(rng)}")
    return int(rng)


#: Peak bytes per pixel and frame that rendering a paper scene holds (noisy and true depth and
#: intensity, mask, flow and the temporaries; measured 34-37 with tracemalloc, plus margin).
PAPER_SCENE_BYTES = 40


class _SceneTooLarge(ParameterError):
    """A scene of ``num_frames`` frames does not fit in memory (``detail`` says why; the CLI
    names its ``--frames`` option with it)."""

    def __init__(self, num_frames: int, detail: str) -> None:
        super().__init__(f"num_frames={num_frames}: {detail}")
        self.num_frames = num_frames
        self.detail = detail


def _check_fits_in_memory(num_frames: int, pixels: int, bytes_per_pixel: int, what: str) -> None:
    """Refuse a scene whose ``num_frames * pixels * bytes_per_pixel`` bytes (every array kept
    while it is rendered) exceed the memory available (:func:`_available_memory`): it was a
    MemoryError, numpy's "Maximum allowed size exceeded" or, for the range scenes, frames
    rendered one by one until the system killed the process.

    Raises
    ------
    ParameterError
        (:class:`_SceneTooLarge`) naming ``num_frames``, the bytes needed and available.
    """
    need = int(num_frames) * int(pixels) * int(bytes_per_pixel)
    available = _available_memory()
    if available is not None and need > available:
        raise _SceneTooLarge(
            int(num_frames),
            f"the {what} of that many frames needs about {need / 2**30:,.1f} GiB of memory, "
            f"{available / 2**30:,.1f} GiB is available; render fewer frames",
        )


@dataclass(frozen=True)
class _Streams:
    """Independent random streams of one scene (see the module docstring)."""

    texture_object: np.random.Generator
    texture_background: np.random.Generator
    depth: np.random.Generator
    intensity: np.random.Generator
    structural: np.random.Generator

    @classmethod
    def from_seed(cls, seed: int) -> _Streams:
        children = np.random.SeedSequence(seed).spawn(5)
        return cls(*(np.random.default_rng(c) for c in children))


class _Texture:
    """``T(q) = sum_k sin(2 pi omega_k . q + phi_k) / sqrt(K/2)`` on D-dimensional points (mm)."""

    def __init__(self, rng: np.random.Generator, dim: int, *, wavelength_scale: float) -> None:
        direction = rng.normal(size=(NUM_SINUSOIDS, dim))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        lo, hi = (1.0 / (w * wavelength_scale) for w in WAVELENGTH_RANGE_MM[::-1])
        magnitude = rng.uniform(lo, hi, size=NUM_SINUSOIDS)
        self.omega = (2.0 * np.pi * direction * magnitude[:, None]).astype(np.float32)  # (K, D)
        self.phase = rng.uniform(0.0, 2.0 * np.pi, size=NUM_SINUSOIDS).astype(np.float32)
        self.norm = np.float32(1.0 / math.sqrt(NUM_SINUSOIDS / 2.0))

    def __call__(self, q: NDArray[np.floating]) -> NDArray[np.float32]:
        """Texture value (unit std) at points ``q (N, D)`` in material coordinates (mm)."""
        q32 = np.asarray(q, dtype=np.float32)
        out = np.empty(q32.shape[0], dtype=np.float32)
        step = 65536
        for start in range(0, q32.shape[0], step):
            arg = q32[start : start + step] @ self.omega.T  # (n, K)
            arg += self.phase
            np.sin(arg, out=arg)
            out[start : start + step] = arg.sum(axis=1) * self.norm
        return out

    def albedo(self, q: NDArray[np.floating]) -> NDArray[np.float32]:
        """Albedo ``clip(0.5 + 0.2 T(q), 0.05, 0.95)``."""
        return np.clip(0.5 + 0.2 * self(q), 0.05, 0.95).astype(np.float32)


def _shading(normal_z: NDArray[np.floating]) -> NDArray[np.float32]:
    """``0.3 + 0.7 max(0, n . (0, 0, -1))`` from the Z component of the unit normal."""
    return (0.3 + 0.7 * np.maximum(0.0, -normal_z)).astype(np.float32)


def _rays(intrinsics: Intrinsics) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Normalised ray coordinates ``x_n (W,)`` and ``y_n (H,)`` of the pixel centres."""
    k = intrinsics
    xn = (np.arange(k.width, dtype=np.float64) - k.cx) / k.fx
    yn = (np.arange(k.height, dtype=np.float64) - k.cy) / k.fy
    return xn, yn


def _check_intensity_noise(intensity_noise: float) -> None:
    """A Gaussian intensity noise std in [0, 1] (fractions of the maximum intensity)."""
    if not (math.isfinite(float(intensity_noise)) and float(intensity_noise) >= 0.0):
        raise ParameterError(
            f"intensity_noise must be a finite number >= 0, got {intensity_noise!r}"
        )
    if float(intensity_noise) > 1.0:
        raise ParameterError(
            f"intensity_noise is a fraction of the maximum intensity 1.0 (e.g. 0.02 = 2 %), "
            f"got {intensity_noise!r}"
        )


def _check_common(
    depth_noise: float,
    intensity_noise: float,
    structural_noise: float,
    num_frames: int,
    background: str,
) -> None:
    for name, value in (("depth_noise", depth_noise), ("structural_noise", structural_noise)):
        if not (math.isfinite(float(value)) and float(value) >= 0.0):
            raise ParameterError(f"{name} must be a finite number >= 0, got {value!r}")
    _check_intensity_noise(intensity_noise)
    if isinstance(num_frames, bool) or int(num_frames) != num_frames or int(num_frames) < 2:
        raise ParameterError(f"num_frames must be an integer >= 2, got {num_frames!r}")
    if background not in ("plane", "none"):
        raise ParameterError(f"background must be 'plane' or 'none', got {background!r}")


class _Background:
    """Static textured wall at Z = 1000 mm (or nothing)."""

    def __init__(
        self, kind: str, intrinsics: Intrinsics, streams: _Streams, wavelength_scale: float
    ) -> None:
        shape = (intrinsics.height, intrinsics.width)
        if kind == "plane":
            xn, yn = _rays(intrinsics)
            xy = np.stack(np.meshgrid(xn, yn, indexing="xy"), axis=-1) * BACKGROUND_Z_MM
            texture = _Texture(streams.texture_background, 2, wavelength_scale=wavelength_scale)
            self.depth = np.full(shape, BACKGROUND_Z_MM, dtype=np.float32)
            self.intensity = texture.albedo(xy.reshape(-1, 2)).reshape(shape)  # shading 1
        else:
            self.depth = np.full(shape, np.nan, dtype=np.float32)
            self.intensity = np.full(shape, BACKGROUND_NONE_INTENSITY, dtype=np.float32)


def _noisy(
    depth_gt: NDArray[np.float32],
    intensity_true: NDArray[np.float32],
    streams: _Streams,
    *,
    depth_sigma: float | NDArray[np.float32],
    intensity_noise: float,
    structural_noise: float,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Add depth noise (per frame; ``depth_sigma`` scalar or (T, H, W) mm) and intensity noise."""
    t, h, w = depth_gt.shape
    structural = streams.structural.standard_normal((h, w), dtype=np.float32)
    structural *= np.float32(structural_noise)
    depth = np.empty_like(depth_gt)
    intensity = np.empty_like(intensity_true)
    sigma_map = np.ndim(depth_sigma) == 3
    for k in range(t):
        noise = streams.depth.standard_normal((h, w), dtype=np.float32)
        sigma = depth_sigma[k] if sigma_map else np.float32(depth_sigma)  # type: ignore[index]
        depth[k] = depth_gt[k] + noise * sigma + structural  # NaN stays NaN
        noise_i = streams.intensity.standard_normal((h, w), dtype=np.float32)
        intensity[k] = np.clip(intensity_true[k] + noise_i * np.float32(intensity_noise), 0, 1)
    return depth, intensity


def _sequence(
    depth: NDArray[np.float32],
    intensity: NDArray[np.float32],
    intrinsics: Intrinsics,
    gt: GroundTruth,
    name: str,
) -> Sequence:
    with warnings.catch_warnings():
        # background="none" leaves most pixels invalid on purpose.
        warnings.filterwarnings("ignore", message="only .* of depth pixels are valid")
        return Sequence(depth, intensity, intrinsics, ground_truth=gt, name=name)


# ----------------------------------------------------------------------------- ball
def make_falling_ball(
    *,
    depth_noise: float = 0.2,
    intensity_noise: float = 0.02,
    num_frames: int | None = None,
    small: bool = False,
    background: Background = "plane",
    structural_noise: float = 0.0,
    rng: int | np.random.Generator | None = 0,
) -> Sequence:
    """The falling textured ball of the paper's synthetic experiment (EVALUATION §3).

    A sphere of radius 140 mm with centre ``C(t) = (0, Y(t), 700)`` mm falls (+Y, +row) at
    2 px/frame: its projected centre row is ``v_c(t) = 250 + 2 t``. Depth is the Z of the
    nearest ray-sphere intersection through each pixel centre (analytic, no meshing).

    Parameters
    ----------
    depth_noise : float, optional
        Std of the i.i.d. Gaussian depth noise, mm (sigma_d).
    intensity_noise : float, optional
        Std of the intensity noise as a fraction of the maximum intensity 1.0 (sigma_I).
    num_frames : int, optional
        Number of frames T (default 50, or 12 with ``small``).
    small : bool, optional
        CI variant: 150x150 px, f = 250 px, 0.5 px/frame (for tests only).
    background : {"plane", "none"}, optional
        Textured static wall at Z = 1000 mm, or NaN depth.
    structural_noise : float, optional
        Std (mm) of a per-pixel depth offset fixed over time (E4/E5; default 0).
    rng : int, Generator or None, optional
        Seed of the independent streams (recorded in ``extra["seed"]``).

    Returns
    -------
    Sequence
        Noisy depth (mm) and intensity; ``ground_truth`` holds ``depth`` (T, H, W) mm,
        ``mask`` (T, H, W) bool (ball pixels), ``flow`` (T-1, H, W, 2) px (``(0, speed * 700 / Z)``
        on the ball: the exact image motion of a point at depth Z; 0 elsewhere), ``scene`` a
        :class:`~fuse4d.sequence.BallTruth` (centre row/column and position, radius, speed,
        ROI and fit geometry: full-size values times ``pixel_scale``) and ``extra`` the noise
        settings and seed.

    Examples
    --------
    >>> seq = make_falling_ball(small=True, num_frames=3)
    >>> seq.depth.shape, seq.ground_truth.flow.shape
    ((3, 150, 150), (2, 150, 150, 2))
    >>> round(float(seq.ground_truth.flow[0][seq.ground_truth.mask[0]][:, 1].min()), 2)
    0.52
    """
    num_frames = (12 if small else 50) if num_frames is None else num_frames
    _check_common(depth_noise, intensity_noise, structural_noise, num_frames, background)
    _check_fits_in_memory(num_frames, _pixels(small), PAPER_SCENE_BYTES, "falling ball")
    seed = _seed_of(rng)
    streams = _Streams.from_seed(seed)
    k = scene_intrinsics(small=small)
    scale = k.fx / 1000.0
    wavelength_scale = 1.0 / scale
    radius, z0 = BALL_RADIUS_MM, BALL_CENTER_Z_MM
    speed = 2.0 * scale
    v0 = k.cy + (250.0 - 299.5) * scale
    t_idx = np.arange(num_frames, dtype=np.float64)
    center_row = v0 + speed * t_idx
    center_y = (center_row - k.cy) * z0 / k.fy

    texture = _Texture(streams.texture_object, 3, wavelength_scale=wavelength_scale)
    back = _Background(background, k, streams, wavelength_scale)
    xn, yn = _rays(k)
    h, w = k.height, k.width
    depth_gt = np.empty((num_frames, h, w), dtype=np.float32)
    intensity_true = np.empty((num_frames, h, w), dtype=np.float32)
    mask = np.zeros((num_frames, h, w), dtype=bool)
    dd = xn[None, :] ** 2 + yn[:, None] ** 2 + 1.0  # |d|^2, (H, W)
    for t in range(num_frames):
        cy_mm = center_y[t]
        dc = yn[:, None] * cy_mm + z0 + 0.0 * xn[None, :]  # d . C
        disc = dc**2 - dd * (cy_mm**2 + z0**2 - radius**2)
        hit = disc >= 0.0
        s = (dc[hit] - np.sqrt(disc[hit])) / dd[hit]  # = Z of the near intersection
        rows, cols = np.nonzero(hit)
        q = np.stack([s * xn[cols], s * yn[rows] - cy_mm, s - z0], axis=1)  # material point
        depth_gt[t] = back.depth
        depth_gt[t][hit] = s
        intensity_true[t] = back.intensity
        intensity_true[t][hit] = texture.albedo(q) * _shading(q[:, 2] / radius)
        mask[t] = hit
    # A material point at depth Z moves by dY = speed * z0 / fy mm per frame, i.e. by
    # fy * dY / Z = speed * z0 / Z px in the image (exact for a translation along Y): 2 px at
    # the centre's depth, up to ~2.5 px on the front of the ball.
    flow = np.zeros((num_frames - 1, h, w, 2), dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        ball_dv = (speed * z0 / depth_gt[:-1]).astype(np.float32)
    flow[..., 1] = np.where(mask[:-1], ball_dv, np.float32(0.0))
    depth, intensity = _noisy(
        depth_gt,
        intensity_true,
        streams,
        depth_sigma=depth_noise,
        intensity_noise=intensity_noise,
        structural_noise=structural_noise,
    )
    ball = BallTruth(
        center_row=center_row,
        center_col=float(k.cx),
        center_mm=np.stack([np.zeros_like(center_y), center_y, np.full_like(center_y, z0)], 1),
        radius_mm=radius,
        speed_px=speed,
        pixel_scale=scale,
        roi_radius_px=BALL_ROI_RADIUS_PX * scale,
        fit_columns=(round(BALL_FIT_COLUMNS_PX[0] * scale), round(BALL_FIT_COLUMNS_PX[1] * scale)),
        fit_half_rows=BALL_FIT_HALF_ROWS_PX * scale,
        mask_erosion_px=max(1, round(BALL_MASK_EROSION_PX * scale)),
    )
    extra: dict[str, Any] = {
        "depth_noise": float(depth_noise),
        "intensity_noise": float(intensity_noise),
        "structural_noise": float(structural_noise),
        "background": background,
        "seed": seed,
    }
    gt = GroundTruth(depth=depth_gt, mask=mask, flow=flow, extra=extra, scene=ball)
    return _sequence(depth, intensity, k, gt, "synthetic falling ball")


# ----------------------------------------------------------------------------- plane
def make_static_plane(
    *,
    depth_noise: float = 0.05,
    intensity_noise: float = 0.02,
    structural_noise: float = 0.02,
    texture_correlated: bool = True,
    num_frames: int | None = None,
    small: bool = False,
    background: Background = "plane",
    tilt_deg: float = 15.0,
    rng: int | np.random.Generator | None = 0,
) -> Sequence:
    """Static textured plane (EVALUATION §4 E5-a).

    A 120 x 80 mm plane centred at (0, 0, 500) mm, tilted by ``tilt_deg`` about the X axis
    (its lower edge further away), in front of the background wall.

    Parameters
    ----------
    depth_noise : float, optional
        Base temporal depth-noise std, mm. With ``texture_correlated`` the per-pixel std is
        ``depth_noise * (1 + (1 - A(x)))`` with A the albedo seen at the pixel (dark texture is
        noisier), on every valid pixel (plane and wall).
    intensity_noise : float, optional
        Intensity-noise std, fraction of the maximum intensity 1.0.
    structural_noise : float, optional
        Std (mm) of the fixed-pattern noise (constant over time, per pixel).
    texture_correlated : bool, optional
        If False the temporal noise is i.i.d. with std ``depth_noise`` (E4 uses that with
        0.15 mm / 0.15 mm).
    num_frames : int, optional
        Default 50 (12 with ``small``).
    small : bool, optional
        CI variant (150x150 px, f = 250 px).
    background : {"plane", "none"}, optional
        Textured wall at Z = 1000 mm (default, so most pixels are valid) or NaN.
    tilt_deg : float, optional
        Tilt about the X axis in degrees.
    rng : int, Generator or None, optional
        Seed.

    Returns
    -------
    Sequence
        ``ground_truth``: depth (mm), mask (plane pixels), zero flow, ``scene`` a
        :class:`~fuse4d.sequence.PlaneTruth` (size, centre, normal, tilt), ``extra`` the noise
        settings (plane coordinates of a pixel: ``a = X``, ``b = Y cos(tilt) + (Z - 500)
        sin(tilt)``).

    Examples
    --------
    >>> seq = make_static_plane(small=True, num_frames=2)
    >>> bool(seq.ground_truth.mask.any()), float(abs(seq.ground_truth.flow).max())
    (True, 0.0)
    """
    num_frames = (12 if small else 50) if num_frames is None else num_frames
    _check_common(depth_noise, intensity_noise, structural_noise, num_frames, background)
    _check_fits_in_memory(num_frames, _pixels(small), PAPER_SCENE_BYTES, "static plane")
    seed = _seed_of(rng)
    streams = _Streams.from_seed(seed)
    k = scene_intrinsics(small=small)
    scale = k.fx / 1000.0
    wavelength_scale = 1.0 / scale
    half_w, half_h, z0 = 60.0, 40.0, 500.0
    theta = math.radians(tilt_deg)
    e2 = np.array([0.0, math.cos(theta), math.sin(theta)])
    normal = np.array([0.0, -math.sin(theta), math.cos(theta)])  # e1 x e2, e1 = X axis
    xn, yn = _rays(k)
    xx, yy = np.meshgrid(xn, yn, indexing="xy")
    denom = yy * normal[1] + normal[2]
    s = normal[2] * z0 / denom  # ray parameter = Z
    a = s * xx
    b = (s * yy) * e2[1] + (s - z0) * e2[2]
    on_plane = (np.abs(a) <= half_w) & (np.abs(b) <= half_h) & (s > 0)
    texture = _Texture(streams.texture_object, 2, wavelength_scale=wavelength_scale)
    back = _Background(background, k, streams, wavelength_scale)
    albedo_plane = texture.albedo(np.stack([a[on_plane], b[on_plane]], axis=1))
    depth1 = back.depth.copy()
    depth1[on_plane] = s[on_plane]
    intensity1 = back.intensity.copy()
    intensity1[on_plane] = albedo_plane * _shading(np.array(-normal[2]))
    shape = (num_frames, k.height, k.width)
    depth_gt = np.broadcast_to(depth1, shape).copy()
    intensity_true = np.broadcast_to(intensity1, shape).copy()
    mask = np.broadcast_to(on_plane, shape).copy()
    if texture_correlated:
        # Albedo seen at each pixel: texture albedo (plane, wall); flat value without a wall.
        albedo = intensity1 / np.where(on_plane, _shading(np.array(-normal[2])), 1.0)
        sigma = (depth_noise * (1.0 + (1.0 - albedo))).astype(np.float32)
        depth_sigma: float | NDArray[np.float32] = np.broadcast_to(sigma, shape)
    else:
        depth_sigma = depth_noise
    depth, intensity = _noisy(
        depth_gt,
        intensity_true,
        streams,
        depth_sigma=depth_sigma,
        intensity_noise=intensity_noise,
        structural_noise=structural_noise,
    )
    plane = PlaneTruth(
        size_mm=(2 * half_w, 2 * half_h),
        center_mm=np.array([0.0, 0.0, z0]),
        normal=normal,
        tilt_deg=float(tilt_deg),
        pixel_scale=scale,
    )
    extra: dict[str, Any] = {
        "depth_noise": float(depth_noise),
        "intensity_noise": float(intensity_noise),
        "structural_noise": float(structural_noise),
        "texture_correlated": bool(texture_correlated),
        "background": background,
        "seed": seed,
    }
    flow = np.zeros((num_frames - 1, k.height, k.width, 2), dtype=np.float32)
    gt = GroundTruth(depth=depth_gt, mask=mask, flow=flow, extra=extra, scene=plane)
    return _sequence(depth, intensity, k, gt, "synthetic static plane")


# ----------------------------------------------------------------------------- sheet
def make_deforming_sheet(
    *,
    depth_noise: float = 0.1,
    intensity_noise: float = 0.02,
    structural_noise: float = 0.0,
    num_frames: int | None = None,
    small: bool = False,
    background: Background = "plane",
    amplitude_mm: float = 3.0,
    period_frames: float = 100.0,
    drift_px: float = 0.5,
    rng: int | np.random.Generator | None = 0,
) -> Sequence:
    """Deforming textured sheet, the "face" proxy of EVALUATION §4 E5-c.

    A 120 x 120 mm sheet at Z = 550 mm with a Gaussian bump (sigma 20 mm) toward the camera:
    ``Z(x_m, y_m, t) = 550 - a(t) exp(-(x_m^2 + y_m^2) / (2 * 20^2))``, ``a(t) = amplitude_mm *
    sin(2 pi t / period_frames)``. The sheet (texture and bump) drifts along +X by
    ``drift_px`` px/frame (at full size; times ``pixel_scale`` for ``small``), i.e.
    ``X = x_m + X_c(t)``, ``X_c(t) = t * drift_px * 550 / 1000`` mm, ``Y = y_m``. The texture is
    attached to the material coordinates ``(x_m, y_m)``; the bump moves material in Z only.

    Parameters
    ----------
    depth_noise, intensity_noise, structural_noise : float, optional
        As in :func:`make_falling_ball` (defaults 0.1 mm, 2 %, 0 mm).
    num_frames : int, optional
        Default 50 (12 with ``small``).
    small : bool, optional
        CI variant (150x150 px, f = 250 px).
    background : {"plane", "none"}, optional
        Textured wall at Z = 1000 mm or NaN.
    amplitude_mm, period_frames, drift_px : float, optional
        Bump amplitude (mm), its period (frames) and the lateral drift (px/frame, full size).
    rng : int, Generator or None, optional
        Seed.

    Returns
    -------
    Sequence
        ``ground_truth``: depth (mm), mask (sheet pixels), the analytic forward flow (px) of the
        material seen at each sheet pixel (0 on the wall), ``scene`` a
        :class:`~fuse4d.sequence.SheetTruth` (``center_x_mm`` (T,) mm, ``amplitude`` (T,) mm,
        size, depth; material coordinates of a sheet pixel: ``x_m = X - center_x_mm[t]``,
        ``y_m = Y``).

    Notes
    -----
    Shading follows the bump's normal, so brightness constancy holds only approximately
    (shading changes by < 1 % for a 3 mm bump).

    Examples
    --------
    >>> seq = make_deforming_sheet(small=True, num_frames=3)
    >>> seq.ground_truth.flow.shape
    (2, 150, 150, 2)
    """
    num_frames = (12 if small else 50) if num_frames is None else num_frames
    _check_common(depth_noise, intensity_noise, structural_noise, num_frames, background)
    _check_fits_in_memory(num_frames, _pixels(small), PAPER_SCENE_BYTES, "deforming sheet")
    seed = _seed_of(rng)
    streams = _Streams.from_seed(seed)
    k = scene_intrinsics(small=small)
    scale = k.fx / 1000.0
    wavelength_scale = 1.0 / scale
    half, z0, bump_sigma = 60.0, 550.0, 20.0
    t_idx = np.arange(num_frames + 1, dtype=np.float64)  # one extra frame for the flow
    amplitude = amplitude_mm * np.sin(2.0 * np.pi * t_idx / period_frames)
    center_x = t_idx * drift_px * scale * z0 / k.fx

    def bump(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.exp(-(x**2 + y**2) / (2.0 * bump_sigma**2))

    texture = _Texture(streams.texture_object, 2, wavelength_scale=wavelength_scale)
    back = _Background(background, k, streams, wavelength_scale)
    xn, yn = _rays(k)
    xx, yy = np.meshgrid(xn, yn, indexing="xy")
    h, w = k.height, k.width
    depth_gt = np.empty((num_frames, h, w), dtype=np.float32)
    intensity_true = np.empty((num_frames, h, w), dtype=np.float32)
    mask = np.zeros((num_frames, h, w), dtype=bool)
    flow = np.zeros((num_frames - 1, h, w, 2), dtype=np.float32)
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    for t in range(num_frames):
        z = np.full((h, w), z0)
        for _ in range(12):  # fixed point Z = z0 - a g(Z x_n - X_c, Z y_n); contraction << 1
            z = z0 - amplitude[t] * bump(z * xx - center_x[t], z * yy)
        xm, ym = z * xx - center_x[t], z * yy
        on = (np.abs(xm) <= half) & (np.abs(ym) <= half)
        g = bump(xm, ym)
        # unit normal of Z = z0 - a g: (dZ/dX, dZ/dY, -1) / norm; n_z = -1 / norm
        gx = amplitude[t] * g * xm / bump_sigma**2
        gy = amplitude[t] * g * ym / bump_sigma**2
        normal_z = -1.0 / np.sqrt(gx**2 + gy**2 + 1.0)
        depth_gt[t] = back.depth
        depth_gt[t][on] = z[on]
        intensity_true[t] = back.intensity
        q = np.stack([xm[on], ym[on]], axis=1)
        intensity_true[t][on] = texture.albedo(q) * _shading(normal_z[on])
        mask[t] = on
        if t < num_frames - 1:
            z1 = z0 - amplitude[t + 1] * g[on]
            u1 = k.fx * (xm[on] + center_x[t + 1]) / z1 + k.cx
            v1 = k.fy * ym[on] / z1 + k.cy
            flow[t][on] = np.stack([u1 - cols[on], v1 - rows[on]], axis=1)
    depth, intensity = _noisy(
        depth_gt,
        intensity_true,
        streams,
        depth_sigma=depth_noise,
        intensity_noise=intensity_noise,
        structural_noise=structural_noise,
    )
    sheet = SheetTruth(
        center_x_mm=center_x[:num_frames],
        amplitude=amplitude[:num_frames],
        size_mm=(2 * half, 2 * half),
        sheet_z_mm=z0,
        bump_sigma_mm=bump_sigma,
        drift_px=drift_px * scale,
        pixel_scale=scale,
    )
    extra: dict[str, Any] = {
        "depth_noise": float(depth_noise),
        "intensity_noise": float(intensity_noise),
        "structural_noise": float(structural_noise),
        "background": background,
        "seed": seed,
    }
    gt = GroundTruth(depth=depth_gt, mask=mask, flow=flow, extra=extra, scene=sheet)
    return _sequence(depth, intensity, k, gt, "synthetic deforming sheet")


#: Scene name -> generator (used by ``fuse4d synth``).
SCENES: dict[str, Callable[..., Sequence]] = {
    "ball": make_falling_ball,
    "plane": make_static_plane,
    "sheet": make_deforming_sheet,
}


def make_scene(name: str, **kwargs: Any) -> Sequence:
    """Build the scene ``name`` (``"ball"``, ``"plane"`` or ``"sheet"``) with ``kwargs``."""
    try:
        factory = SCENES[name]
    except KeyError:
        raise ParameterError(
            f"unknown scene {name!r}; choose one of {', '.join(sorted(SCENES))}"
        ) from None
    return factory(**kwargs)
