"""Scenes at the range of commodity depth cameras (1–5 m), seen through a sensor model.

The paper's scenes (:mod:`fuse4d.synthetic`) sit at 1 m in front of a 0.2 mm-noise sensor.
These are the scenes a Kinect, RealSense or Azure Kinect user films, ray-cast exactly (planes,
spheres and ellipsoids, each with a texture attached to its material points) and then turned
into sensor depth by :func:`fuse4d.sensors.apply_sensor`, so that real-sensor effects —
disparity quantisation, correlated noise, shadow holes, flying pixels — come with ground truth:

* ``"ball"``: a 150 mm-radius textured ball crossing the view at 2 m (1 m/s, with a small
  bounce) in front of a wall at 3.5 m above a floor;
* ``"body"``: an articulated body proxy (ellipsoid torso, head, swinging arms and legs)
  walking across at 2.5 m (1.2 m/s) in front of a wall at 4 m — the moving-person case;
* ``"room"``: a static corner (back wall at 4 m, side wall, floor), for flicker and plane
  precision.

Camera: 640 × 480, fx = fy = 580 px (Kinect v1-like), 1 m above the floor, looking
horizontally; 30 fps. ``small=True`` gives the CI variant, 160 × 120 px, f = 145 px: the same
physical scene seen by a quarter-resolution camera (so its depth steps are 4× coarser).

Examples
--------
>>> seq = make_range_scene("ball", sensor="kinect", small=True, num_frames=3, rng=0)
>>> seq.depth.shape, seq.ground_truth.depth.shape
((3, 120, 160), (3, 120, 160))
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .camera import Intrinsics
from .errors import ParameterError
from .sensors import SensorModel, apply_sensor, get_sensor
from .sequence import GroundTruth, Sequence
from .synthetic import _check_fits_in_memory, _check_intensity_noise, _seed_of, _Texture

__all__ = ["RANGE_SCENES", "make_range_scene", "range_intrinsics"]

#: Frames per second of the simulated camera.
FPS = 30.0
#: Camera height above the floor, mm (image y points down, so the floor is the plane Y = +1000).
CAMERA_HEIGHT_MM = 1000.0
#: Peak bytes per pixel and frame that rendering a range scene holds (the frames' renders, the
#: true and sensor depth, the sensor model's float64 work arrays; measured 90-94 with
#: tracemalloc, plus margin).
RANGE_SCENE_BYTES = 110


def range_intrinsics(*, small: bool = False) -> Intrinsics:
    """The depth camera of the range scenes: 640×480, f = 580 px (``small``: 160×120, f = 145)."""
    if small:
        return Intrinsics(fx=145.0, fy=145.0, cx=79.5, cy=59.5, width=160, height=120)
    return Intrinsics(fx=580.0, fy=580.0, cx=319.5, cy=239.5, width=640, height=480)


# ----------------------------------------------------------------------------- primitives
@dataclass
class _Pose:
    centre: NDArray[np.float64]  # (3,) mm
    rotation: NDArray[np.float64]  # (3, 3) local -> camera


@dataclass
class _Primitive:
    """A plane (``normal``, ``offset``: n·X = offset) or an ellipsoid (``axes`` mm, ``pose``)."""

    name: str
    texture: _Texture
    moving: bool
    normal: NDArray[np.float64] | None = None
    offset: float = 0.0
    axes: NDArray[np.float64] | None = None
    pose: Callable[[float], _Pose] | None = None


def _rot_z(angle: float) -> NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(angle: float) -> NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _hit_plane(rays: NDArray[np.float64], p: _Primitive) -> NDArray[np.float64]:
    """Depth Z (= ray parameter, rays have z = 1) of the hit with plane n·X = c; inf if none."""
    assert p.normal is not None
    denom = rays @ p.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = p.offset / denom
    return np.where((t > 0) & np.isfinite(t), t, np.inf)


def _hit_ellipsoid(rays: NDArray[np.float64], p: _Primitive, pose: _Pose) -> NDArray:
    """Nearest positive hit of the rays with an ellipsoid; inf where they miss."""
    assert p.axes is not None
    # in the unit-sphere frame of the ellipsoid: o' = -R^T C / s, d' = R^T r / s
    o = -(pose.rotation.T @ pose.centre) / p.axes
    d = (rays @ pose.rotation) / p.axes
    a = np.einsum("ij,ij->i", d, d)
    b = 2.0 * (d @ o)
    c = float(o @ o) - 1.0
    disc = b * b - 4.0 * a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (2.0 * a)
    return np.where((disc > 0) & (t > 0), t, np.inf)


def _ellipsoid_normal(points: NDArray, p: _Primitive, pose: _Pose) -> NDArray[np.float64]:
    assert p.axes is not None
    local = (points - pose.centre) @ pose.rotation  # (N, 3) local coordinates
    grad = local / p.axes**2
    n = grad @ pose.rotation.T
    return n / np.linalg.norm(n, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- scenes
def _planes(names: tuple[str, ...], streams: list[np.random.Generator]) -> list[_Primitive]:
    """Static background planes (textures in world coordinates, 2-6x coarser than objects)."""
    spec = {
        "wall35": (np.array([0.0, 0.0, 1.0]), 3500.0),
        "wall40": (np.array([0.0, 0.0, 1.0]), 4000.0),
        "floor": (np.array([0.0, 1.0, 0.0]), CAMERA_HEIGHT_MM),
        "side": (np.array([-1.0, 0.0, 0.0]), 1800.0),  # wall at X = -1800
    }
    return [
        _Primitive(
            name,
            _Texture(gen, 3, wavelength_scale=8.0),
            moving=False,
            normal=spec[name][0],
            offset=spec[name][1],
        )
        for name, gen in zip(names, streams, strict=False)
    ]


def _ball_scene(streams: list[np.random.Generator], num_frames: int) -> list[_Primitive]:
    radius = 150.0
    speed = 1000.0 / FPS  # mm per frame across the view

    def pose(t: float) -> _Pose:
        x = -0.5 * speed * (num_frames - 1) + speed * t
        y = 250.0 - 120.0 * abs(math.sin(math.pi * t / 12.0))  # a small bounce
        return _Pose(np.array([x, y, 2000.0]), _rot_z(0.05 * t) @ _rot_x(0.04 * t))

    ball = _Primitive(
        "ball",
        _Texture(streams[0], 3, wavelength_scale=4.0),
        moving=True,
        axes=np.full(3, radius),
        pose=pose,
    )
    return [ball, *_planes(("wall35", "floor"), streams[1:])]


def _body_scene(streams: list[np.random.Generator], num_frames: int) -> list[_Primitive]:
    speed = 1200.0 / FPS
    z0 = 2500.0
    stride = 2.0 * math.pi / 30.0  # one gait cycle per second

    def walker(t: float) -> NDArray[np.float64]:
        return np.array([-0.5 * speed * (num_frames - 1) + speed * t, 0.0, z0])

    def part(offset, pivot, swing, phase):
        """A limb hanging from ``pivot`` (mm, relative to the walker), swinging about x."""

        def pose(t: float) -> _Pose:
            angle = swing * math.sin(stride * t + phase)
            rot = _rot_x(angle)
            centre = walker(t) + np.asarray(pivot) + rot @ np.asarray(offset)
            return _Pose(centre, rot)

        return pose

    # Y is down; hips at Y = +100 (feet on the floor at +1000), shoulders at -440
    specs = [
        ("torso", (170.0, 290.0, 110.0), part((0, 0, 0), (0, -200, 0), 0.03, 0.0)),
        ("head", (100.0, 115.0, 105.0), part((0, 0, 0), (0, -620, 0), 0.02, 1.0)),
        ("leg_l", (75.0, 450.0, 75.0), part((0, 450, 0), (-90, 100, 0), 0.45, 0.0)),
        ("leg_r", (75.0, 450.0, 75.0), part((0, 450, 0), (90, 100, 0), 0.45, math.pi)),
        ("arm_l", (48.0, 310.0, 48.0), part((0, 300, 0), (-215, -440, 0), 0.35, math.pi)),
        ("arm_r", (48.0, 310.0, 48.0), part((0, 300, 0), (215, -440, 0), 0.35, 0.0)),
    ]
    parts = [
        _Primitive(
            name,
            _Texture(gen, 3, wavelength_scale=4.0),
            moving=True,
            axes=np.array(axes),
            pose=pose,
        )
        for (name, axes, pose), gen in zip(specs, streams, strict=False)
    ]
    return [*parts, *_planes(("wall40", "floor"), streams[len(specs) :])]


def _room_scene(streams: list[np.random.Generator], num_frames: int) -> list[_Primitive]:
    del num_frames
    return _planes(("wall40", "floor", "side"), streams)


RANGE_SCENES: dict[str, Callable[[list[np.random.Generator], int], list[_Primitive]]] = {
    "ball": _ball_scene,
    "body": _body_scene,
    "room": _room_scene,
}


@dataclass
class _Render:
    depth: NDArray[np.float64]  # (H, W) mm, inf = nothing
    intensity: NDArray[np.float32]  # shaded: albedo * (0.3 + 0.7 cos), the registered image
    albedo: NDArray[np.float32]  # unshaded reflectance (the sensor model applies cos itself)
    normal_z: NDArray[np.float64]
    moving: NDArray[np.bool_]
    flow: NDArray[np.float32] | None  # (H, W, 2) px to the next frame


def _render(
    prims: list[_Primitive], k: Intrinsics, rays: NDArray[np.float64], t: float, with_flow: bool
) -> _Render:
    n = rays.shape[0]
    best = np.full(n, np.inf)
    which = np.full(n, -1, np.int64)
    poses = [p.pose(t) if p.pose is not None else None for p in prims]
    for i, (p, pose) in enumerate(zip(prims, poses, strict=True)):
        hit = _hit_plane(rays, p) if p.normal is not None else _hit_ellipsoid(rays, p, pose)
        closer = hit < best
        best[closer] = hit[closer]
        which[closer] = i
    points = rays * best[:, None]
    intensity = np.full(n, 0.1, np.float32)
    albedo = np.full(n, 0.1, np.float32)
    normal_z = np.full(n, -1.0)
    flow = np.zeros((n, 2), np.float32) if with_flow else None
    for i, (p, pose) in enumerate(zip(prims, poses, strict=True)):
        sel = which == i
        if not sel.any():
            continue
        pts = points[sel]
        view = rays[sel] / np.linalg.norm(rays[sel], axis=1, keepdims=True)
        if p.normal is not None:
            normal = np.broadcast_to(p.normal / np.linalg.norm(p.normal), pts.shape)
            # orient towards the camera
            normal = np.where(np.einsum("ij,ij->i", normal, view)[:, None] > 0, -normal, normal)
            material = pts
        else:
            normal = _ellipsoid_normal(pts, p, pose)
            material = (pts - pose.centre) @ pose.rotation
        cos_incidence = np.maximum(0.0, -np.einsum("ij,ij->i", normal, view))
        normal_z[sel] = -cos_incidence  # "normal_z" of apply_sensor: -cos of the incidence
        shade = 0.3 + 0.7 * cos_incidence
        albedo[sel] = p.texture.albedo(material)
        intensity[sel] = (albedo[sel] * shade).astype(np.float32)
        if with_flow and p.pose is not None:
            nxt = p.pose(t + 1.0)
            moved = material @ nxt.rotation.T + nxt.centre
            u1 = k.fx * moved[:, 0] / moved[:, 2] + k.cx
            v1 = k.fy * moved[:, 1] / moved[:, 2] + k.cy
            u0 = k.fx * pts[:, 0] / pts[:, 2] + k.cx
            v0 = k.fy * pts[:, 1] / pts[:, 2] + k.cy
            flow[sel] = np.stack([u1 - u0, v1 - v0], axis=1).astype(np.float32)
    moving = np.array([p.moving for p in prims] + [False])[which]
    shape = (k.height, k.width)
    return _Render(
        depth=best.reshape(shape),
        intensity=intensity.reshape(shape),
        albedo=albedo.reshape(shape),
        normal_z=normal_z.reshape(shape),
        moving=moving.reshape(shape),
        flow=None if flow is None else flow.reshape((*shape, 2)),
    )


def make_range_scene(
    name: str,
    *,
    sensor: str | SensorModel = "kinect",
    small: bool = False,
    num_frames: int = 30,
    intensity_noise: float = 0.01,
    rng: int | np.random.Generator | None = 0,
) -> Sequence:
    """A scene at 1–5 m recorded by a sensor model, with ground truth.

    Parameters
    ----------
    name : {"ball", "body", "room"}
        The scene (see the module docstring).
    sensor : str or SensorModel
        ``"kinect"`` (structured light), ``"d435"`` (active stereo) or ``"tof"``.
    small : bool
        160×120 CI variant instead of 640×480.
    num_frames : int
        Frames (30 fps), at least 2.
    intensity_noise : float
        Standard deviation of the Gaussian noise on the registered intensity ([0, 1] units).
    rng : int, Generator or None, optional
        Seed (a non-negative int; a Generator contributes one draw; None: fresh entropy):
        textures, sensor noise and intensity noise derive from it.

    Returns
    -------
    Sequence
        Sensor depth (mm, whole mm, NaN holes), intensity in [0, 1], the camera, 30 fps, and
        ``ground_truth`` with the true depth (mm), the moving-object mask, the true forward
        flow (px) and ``extra["sensor"]`` (the model's name).
    """
    if name not in RANGE_SCENES:
        raise ParameterError(
            f"unknown range scene {name!r}; choose one of {', '.join(RANGE_SCENES)}"
        )
    if isinstance(num_frames, bool) or int(num_frames) != num_frames or num_frames < 2:
        raise ParameterError(f"num_frames must be an integer >= 2, got {num_frames!r}")
    _check_intensity_noise(intensity_noise)
    model = get_sensor(sensor)
    k = range_intrinsics(small=small)
    _check_fits_in_memory(num_frames, k.width * k.height, RANGE_SCENE_BYTES, f"{name} range scene")
    seeds = np.random.SeedSequence(_seed_of(rng)).spawn(3)  # an int seed: the same scene
    texture_streams = [np.random.default_rng(s) for s in seeds[0].spawn(12)]
    prims = RANGE_SCENES[name](texture_streams, int(num_frames))
    xn = (np.arange(k.width) - k.cx) / k.fx
    yn = (np.arange(k.height) - k.cy) / k.fy
    gx, gy = np.meshgrid(xn, yn, indexing="xy")
    rays = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)], axis=1)
    renders = [_render(prims, k, rays, float(t), t < num_frames - 1) for t in range(num_frames)]
    truth = np.stack([r.depth for r in renders]).astype(np.float32)
    truth[~np.isfinite(truth)] = np.nan
    true_intensity = np.stack([r.intensity for r in renders])
    # the sensor's IR return is albedo * cos (apply_sensor applies the cos of normal_z); the
    # shaded intensity, which already holds a cos, is only the registered image
    sensed = apply_sensor(
        truth,
        np.stack([r.albedo for r in renders]),
        k,
        model,
        normal_z=np.stack([r.normal_z for r in renders]),
        rng=np.random.default_rng(seeds[1]),
    )
    noise = np.random.default_rng(seeds[2]).standard_normal(true_intensity.shape)
    intensity = np.clip(true_intensity + noise * intensity_noise, 0.0, 1.0).astype(np.float32)
    gt = GroundTruth(
        depth=truth,
        mask=np.stack([r.moving for r in renders]),
        flow=np.stack([r.flow for r in renders[:-1]]),
        extra={"sensor": model.name},
    )
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="only .* of depth pixels are valid")
        return Sequence(
            sensed.depth,
            intensity,
            k,
            fps=FPS,
            ground_truth=gt,
            name=f"{name}-{model.name}" + ("-small" if small else ""),
            sensor=model.kind,
        )
