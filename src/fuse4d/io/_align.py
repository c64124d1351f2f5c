"""Resampling an image of another camera onto the depth camera's pixel grid.

Used for RealSense colour (``--intensity color``): every depth pixel is back-projected with
its depth (pixels without depth use the frame's median depth, so the intensity has no holes),
moved into the colour camera with the recorded extrinsics, projected with the colour
intrinsics and sampled bilinearly. Occlusion (a colour pixel hidden behind a nearer surface)
is not modelled; points that fall outside the colour image get intensity 0.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from ..camera import Intrinsics

__all__ = ["align_to_depth"]


def align_to_depth(
    depth_mm: NDArray[np.float32],
    image: NDArray[np.float32],
    depth_camera: Intrinsics,
    image_camera: Intrinsics,
    rotation: NDArray[np.float64],
    translation_mm: NDArray[np.float64],
) -> NDArray[np.float32]:
    """Sample ``image`` (other camera) at the projections of the depth pixels.

    Parameters
    ----------
    depth_mm : (H, W) float32
        Depth in mm, NaN = invalid.
    image : (h, w) float32
        Grey image of the other camera, values in [0, 1].
    depth_camera, image_camera : Intrinsics
        Pinhole cameras of the depth and of the image (px).
    rotation : (3, 3) float, translation_mm : (3,) float
        Rigid transform from depth-camera coordinates to image-camera coordinates (mm).

    Returns
    -------
    (H, W) float32
        The image on the depth grid, in [0, 1] (0 outside the other camera's view).
    """
    h, w = depth_mm.shape
    valid = np.isfinite(depth_mm) & (depth_mm > 0)
    fill = float(np.median(depth_mm[valid])) if valid.any() else 1000.0
    z = np.where(valid, depth_mm, fill).astype(np.float64)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    k = depth_camera
    pts = np.stack(((u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z), axis=-1)
    pc = pts @ np.asarray(rotation, dtype=np.float64).T + np.asarray(translation_mm, np.float64)
    zc = np.where(pc[..., 2] > 1e-6, pc[..., 2], np.nan)
    c = image_camera
    map_x = (c.fx * pc[..., 0] / zc + c.cx).astype(np.float32)
    map_y = (c.fy * pc[..., 1] / zc + c.cy).astype(np.float32)
    bad = ~np.isfinite(map_x) | ~np.isfinite(map_y)
    map_x[bad] = -1e6
    map_y[bad] = -1e6
    out = cv2.remap(
        np.ascontiguousarray(image, dtype=np.float32),
        map_x,
        map_y,
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.0,
    )
    return np.clip(out, 0.0, 1.0).astype(np.float32)
