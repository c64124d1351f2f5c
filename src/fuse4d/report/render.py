"""Pixel rendering for the report: colour maps, normal shading and a z-buffered point splat.

Everything here is vectorised NumPy (plus matplotlib's colour tables); no per-pixel Python.
Images are ``(H, W, 3)`` uint8 RGB.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import as_float32, check_shape

__all__ = [
    "INVALID_RGB",
    "colorize",
    "normal_map",
    "shade_normals",
    "splat_points",
]

#: Colour of invalid (NaN) pixels in every rendered map: dark gray.
INVALID_RGB = (48, 48, 48)

#: Direction *towards* the light in the camera frame (X right, Y down, Z forward): up-left,
#: slightly behind the camera, so that surfaces facing the camera are lit.
_LIGHT = np.array([-0.35, -0.5, -1.0]) / math.sqrt(0.35**2 + 0.5**2 + 1.0)


@lru_cache(maxsize=16)
def _lut(cmap: str) -> NDArray[np.uint8]:
    """(256, 3) uint8 colour table of a matplotlib colour map."""
    import matplotlib

    table = matplotlib.colormaps[cmap](np.linspace(0.0, 1.0, 256))[:, :3]
    return np.round(255.0 * table).astype(np.uint8)


def colorize(
    values: ArrayLike, *, vmin: float, vmax: float, cmap: str = "turbo"
) -> NDArray[np.uint8]:
    """Map values to RGB with a *fixed* range (the same for every frame and method).

    Parameters
    ----------
    values : (H, W) ndarray
        Any scalar map (depth in mm, |difference| in mm, support in frames); NaN = invalid.
    vmin, vmax : float
        Values mapped to the first and last colour (clipped outside), same unit as ``values``.
    cmap : str, optional
        Matplotlib colour-map name.

    Returns
    -------
    (H, W, 3) ndarray of uint8
        RGB; invalid pixels are :data:`INVALID_RGB`.

    Examples
    --------
    >>> colorize(np.array([[0.0, 1.0, np.nan]]), vmin=0.0, vmax=1.0, cmap="gray")[0].tolist()
    [[0, 0, 0], [255, 255, 255], [48, 48, 48]]
    """
    v = np.asarray(values, dtype=np.float32)
    if not (math.isfinite(vmin) and math.isfinite(vmax) and vmax > vmin):
        raise ValueError(f"need finite vmin < vmax, got vmin={vmin!r}, vmax={vmax!r}")
    finite = np.isfinite(v)
    scaled = np.where(finite, (v - np.float32(vmin)) * np.float32(255.0 / (vmax - vmin)), 0.0)
    index = np.clip(np.rint(scaled), 0, 255).astype(np.uint8)
    out = _lut(cmap)[index]
    out[~finite] = INVALID_RGB
    return out


def normal_map(points: ArrayLike) -> NDArray[np.float32]:
    """Unit surface normals of an organised point map, from central differences.

    Parameters
    ----------
    points : (H, W, 3) ndarray
        Points in mm (camera frame), NaN = invalid.

    Returns
    -------
    (H, W, 3) ndarray of float32
        Unit normals oriented towards the camera (``n . p < 0``); NaN where a neighbour needed
        by the central difference is invalid (and on the image border).
    """
    p = as_float32(points, name="points")
    check_shape(p, ("H", "W", 3), name="points")
    du = np.full_like(p, np.nan)
    dv = np.full_like(p, np.nan)
    du[:, 1:-1] = p[:, 2:] - p[:, :-2]  # (H, W, 3): d p / d column
    dv[1:-1, :] = p[2:, :] - p[:-2, :]  # (H, W, 3): d p / d row
    n = np.cross(du, dv)
    with np.errstate(invalid="ignore", divide="ignore"):
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        flip = np.sum(n * p, axis=-1) > 0
    n[flip] *= -1.0
    return n.astype(np.float32, copy=False)


def shade_normals(
    normals: ArrayLike, *, light: ArrayLike | None = None, ambient: float = 0.12
) -> NDArray[np.uint8]:
    """Lambert shading of a normal map (the way surface noise is seen), as gray RGB.

    Parameters
    ----------
    normals : (H, W, 3) ndarray
        Unit normals (:func:`normal_map`), NaN = invalid.
    light : (3,) array, optional
        Direction towards the light (default: up-left of the camera).
    ambient : float, optional
        Gray level (in [0, 1]) of surfaces facing away from the light.

    Returns
    -------
    (H, W, 3) ndarray of uint8
        Gray RGB; invalid pixels are :data:`INVALID_RGB`.
    """
    n = np.asarray(normals, dtype=np.float32)
    lvec = _LIGHT if light is None else np.asarray(light, dtype=np.float64)
    lvec = (lvec / np.linalg.norm(lvec)).astype(np.float32)
    with np.errstate(invalid="ignore"):
        lambert = np.clip(n @ lvec, 0.0, 1.0)
    finite = np.isfinite(lambert)
    gray = np.where(finite, ambient + (1.0 - ambient) * lambert, 0.0)
    g = np.clip(np.rint(255.0 * gray), 0, 255).astype(np.uint8)
    out = np.repeat(g[..., None], 3, axis=-1)
    out[~finite] = INVALID_RGB
    return out


def _rotation(yaw_deg: float, pitch_deg: float) -> NDArray[np.float64]:
    """Rotation about the camera's Y axis (yaw) then its X axis (pitch)."""
    a, b = math.radians(yaw_deg), math.radians(pitch_deg)
    ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    return rx @ ry


def splat_points(
    points: ArrayLike,
    *,
    normals: ArrayLike | None = None,
    size: tuple[int, int] = (360, 480),
    yaw_deg: float = 35.0,
    pitch_deg: float = -25.0,
    center: ArrayLike | None = None,
    scale: float | None = None,
) -> tuple[NDArray[np.uint8], float]:
    """Render a point cloud from an oblique viewpoint: z-buffered splats with normal shading.

    The cloud is rotated about ``center`` (yaw about the camera's Y axis, then pitch about its
    X axis), projected with a perspective camera looking at it from the original viewing
    distance, and fitted into the image. Each point is drawn as a k x k square (k from the
    point density) and the nearest point wins every pixel (sort by depth, keep the first per
    pixel: vectorised, no Python loop over points).

    Parameters
    ----------
    points : (H, W, 3) ndarray
        Organised point map in mm (camera frame), NaN = invalid.
    normals : (H, W, 3) ndarray, optional
        Unit normals (default: :func:`normal_map` of ``points``); rotated with the view.
    size : (int, int), optional
        Output image (rows, columns).
    yaw_deg, pitch_deg : float, optional
        Viewpoint rotation in degrees.
    center : (3,) array, optional
        Rotation centre in mm (default: median of the valid points). Pass the same centre
        (and ``scale``) to render several clouds of one frame from the identical viewpoint.
    scale : float, optional
        Image pixels per projected unit (default: fit the cloud into ``size``).

    Returns
    -------
    image : (rows, columns, 3) ndarray of uint8
        Gray shaded render on a dark background.
    scale : float
        The scale used (pass it back for a matching render of another cloud).
    """
    p = as_float32(points, name="points")
    check_shape(p, ("H", "W", 3), name="points")
    n = normal_map(p) if normals is None else np.asarray(normals, dtype=np.float32)
    rows, cols = size
    image = np.empty((rows, cols, 3), dtype=np.uint8)
    image[:] = (24, 24, 28)
    good = np.all(np.isfinite(p), axis=-1)
    if not good.any():
        return image, 1.0 if scale is None else scale
    pts = p[good].astype(np.float64)  # (N, 3)
    nrm = n[good].astype(np.float64)  # (N, 3), NaN normals stay NaN (drawn at ambient)
    c = np.median(pts, axis=0) if center is None else np.asarray(center, dtype=np.float64)
    rot = _rotation(yaw_deg, pitch_deg)
    q = (pts - c) @ rot.T  # (N, 3) rotated about the centre
    dist = max(float(c[2]), 1.0)
    z = q[:, 2] + dist
    keep = z > 1e-3 * dist
    q, z, nrm = q[keep], z[keep], nrm[keep]
    x = q[:, 0] / z  # perspective projection, unit focal length
    y = q[:, 1] / z
    if scale is None:
        half_x = float(np.percentile(np.abs(x), 99.5))
        half_y = float(np.percentile(np.abs(y), 99.5))
        span = max(2.0 * half_x / (0.94 * cols), 2.0 * half_y / (0.94 * rows), 1e-12)
        scale = 1.0 / span
    u = cols / 2.0 + scale * x  # the centre projects to the image centre
    v = rows / 2.0 + scale * y
    # splat size: enough to close the gaps between neighbouring samples
    spacing = scale * float(np.median(np.abs(np.diff(pts[:, 0])))) / dist if len(pts) > 1 else 1
    k = int(np.clip(math.ceil(spacing * 1.2), 1, 4))
    shade = shade_normals((nrm @ rot.T)[None].astype(np.float32))[0, :, 0]  # (N,) gray
    offsets = np.arange(k) - (k - 1) // 2
    du, dv = np.meshgrid(offsets, offsets)
    ui = (np.rint(u)[:, None] + du.ravel()[None]).ravel().astype(np.int64)  # (N * k * k,)
    vi = (np.rint(v)[:, None] + dv.ravel()[None]).ravel().astype(np.int64)
    zz = np.repeat(z, k * k)
    gg = np.repeat(shade, k * k)
    inside = (ui >= 0) & (ui < cols) & (vi >= 0) & (vi < rows)
    lin = vi[inside] * cols + ui[inside]
    zz, gg = zz[inside], gg[inside]
    order = np.lexsort((zz, lin))  # by pixel, then nearest first
    first = np.ones(order.size, dtype=bool)
    first[1:] = lin[order][1:] != lin[order][:-1]
    winner = order[first]
    flat = image.reshape(-1, 3)
    flat[lin[winner]] = gg[winner][:, None]
    return image, float(scale)
