"""Flying pixels of time-of-flight depth: found, and left out of the fusion (our A36, issue 10).

A ToF pixel whose footprint straddles a depth edge integrates light from both surfaces and
returns a depth between them: a *flying* (mixed) pixel, floating in the empty space behind a
silhouette. It is valid depth, so fusion would keep it, and locally it looks like a surface
seen at grazing incidence. On the ToF model (``fuse4d synth ball --sensor tof``) such pixels
are 1-3 % of the object's pixels and dominate its RMSE (ball 99.8 mm raw with a median error
of 1.6 mm); structured-light and stereo cameras do not mix depths this way (they leave holes).

Test (:func:`flying_pixel_mask`): pixel p is flying when, on one of the four lines through it
(row, column, the two diagonals), with neighbours a and b on either side and a2, b2 one step
further,

1. its depth lies strictly between those of a and b,
2. both depth jumps |z_a - z_p|, |z_b - z_p| exceed :data:`FLYING_MIN_JUMP` times the frame's
   quantisation noise q z^2 (A22; so a staircase step of Kinect-class depth is no jump),
3. both 3D segments p-a and p-b lie within :data:`FLYING_MAX_ANGLE_DEG` of p's viewing ray
   (a surface, however slanted, is crossed by the ray; a mixed pixel sits on it), and
4. each segment is longer than :data:`FLYING_ISOLATION` times the next one on its side (a-a2,
   b-b2): the steep rim of a sphere continues its own surface, a mixed pixel joins neither.

Measured on the ToF model (4 frames each, ``docs/method_notes.md`` A36): 97 % of the ball's and
94 % of the body's pixels more than 100 mm off are found, 0.02 % / 0.04 % of the pixels within
20 mm of the truth are taken too, 0.02 % of the static room; the paper's ball loses 1 pixel in
3 frames, the real Kinect-class clips 0.01 % (``uva_cv2_person_turning``) and 0.04 %
(``static_room_rgbd``). Without test 4 the paper ball lost 0.9 % (its rim), with 15 degrees
instead of 10 the ToF room 0.24 %.

In the engine (``FusionParams(flying_pixels="on")``) the pixels found are removed from the raw
depth before anything else and stay holes: flagged :data:`fuse4d.holes.SOURCE_REJECTED`, never
filled from time or space (which side of the edge such a pixel belongs to is not in the data:
the A26/A27 fills gave the removed pixels of the ToF ball 185 mm RMSE). ``"auto"`` (default)
is on where the recording says it comes from a ToF camera (an Azure Kinect ``.mkv``, a
RealSense L5xx recording, a ``Sequence`` or scene made with ``sensor="tof"``), off otherwise:
:func:`resolve_flying_pixels`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels.flying_pixels import _flying_pixels_kernel
from ._validation import as_float32, check_shape
from .camera import Intrinsics
from .config import FusionParams
from .errors import ParameterError
from .motion import estimate_noise_quad

__all__ = [
    "FLYING_ISOLATION",
    "FLYING_MAX_ANGLE_DEG",
    "FLYING_MIN_JUMP",
    "TOF_SENSOR_KINDS",
    "flying_pixel_mask",
    "resolve_flying_pixels",
]

#: Largest angle (degrees) between a jump segment and the pixel's viewing ray.
FLYING_MAX_ANGLE_DEG = 10.0
#: Smallest depth jump on either side, in units of the frame's quantisation noise q z^2 (A22).
FLYING_MIN_JUMP = 3.0
#: Each segment must be this many times longer than the next step of the surface beyond it.
FLYING_ISOLATION = 3.0
#: Sensor kinds (``Sequence.sensor``, a reader's ``sensor``) whose depth has mixed pixels.
TOF_SENSOR_KINDS = frozenset({"tof"})


def flying_pixel_mask(
    depth: ArrayLike,
    intrinsics: Intrinsics,
    *,
    quad: float | None = None,
    max_angle_deg: float = FLYING_MAX_ANGLE_DEG,
    min_jump: float = FLYING_MIN_JUMP,
    isolation: float = FLYING_ISOLATION,
) -> NDArray[np.bool_]:
    """Flying (mixed) pixels of one depth frame (see the module docstring for the test).

    Parameters
    ----------
    depth : (H, W) array_like
        Depth in mm, NaN (or 0) = invalid.
    intrinsics : Intrinsics
        The depth camera (a pixel's viewing ray).
    quad : float, optional
        The frame's quantisation-noise coefficient q (mm^-1, A22:
        :func:`fuse4d.motion.estimate_noise_quad`); estimated from ``depth`` when omitted.
    max_angle_deg, min_jump, isolation : float
        Tests 3, 2 and 4 of the module docstring.

    Returns
    -------
    (H, W) ndarray of bool
        True at the flying pixels (never at invalid ones).

    Examples
    --------
    >>> K = Intrinsics(fx=500.0, fy=500.0, cx=3.5, cy=0.0, width=8, height=1)
    >>> row = np.array([[1000, 1000, 1000, 1000, 1600, 2000, 2000, 2000]], np.float32)
    >>> np.flatnonzero(flying_pixel_mask(row, K)).tolist()
    [4]
    """
    d = as_float32(depth, name="depth")
    check_shape(d, ("H", "W"), name="depth")
    if d.shape != (intrinsics.height, intrinsics.width):
        raise ParameterError(
            f"depth is {d.shape[0]}x{d.shape[1]} but the intrinsics are for "
            f"{intrinsics.height}x{intrinsics.width}"
        )
    if not 0.0 < max_angle_deg < 90.0:
        raise ParameterError(f"max_angle_deg must lie in (0, 90), got {max_angle_deg}")
    d = np.where(np.isfinite(d) & (d > 0), d, np.float32(np.nan))
    q = estimate_noise_quad(d) if quad is None else float(quad)
    out = np.empty(d.shape, np.bool_)
    k = intrinsics
    _flying_pixels_kernel(
        d,
        k.fx,
        k.fy,
        k.cx,
        k.cy,
        math.cos(math.radians(max_angle_deg)),
        float(min_jump) * q,
        float(isolation),
        out,
    )
    return out


def resolve_flying_pixels(params: FusionParams, sensor: str | None) -> FusionParams:
    """``params`` with ``flying_pixels="auto"`` made "on" for a ToF ``sensor`` kind, else "off".

    ``sensor`` is what the input says about its camera (``"tof"``, ``"structured-light"``,
    ``"active-stereo"``) or None when it does not say. An explicit "on" / "off" is kept.
    """
    if params.flying_pixels != "auto":
        return params
    return params.replace(flying_pixels="on" if sensor in TOF_SENSOR_KINDS else "off")
