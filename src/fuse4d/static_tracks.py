"""Static pixels keep still (our A33, ``FusionParams.static_tracks``; issue 10).

On a static background the intensity flow is often not zero: in textureless areas and under
reflections (the glass wall behind ``uva_cv2_person_turning``) DIS answers 0.5-2 px of
spurious motion that changes from pair to pair. Every track then lands beside its pixel, on
another step of the quantised depth, and the fused background flickered where a plain
temporal mean does not (1.16 mm frame-to-frame vs 0.57 mm for the 9-frame mean; with A33
0.66 mm, the person's roughness unchanged; ``docs/method_notes.md`` A33). A pixel is *static*
in frame t's window when two things hold:

* **depth**: frame t's raw depth is valid and the motion reference z~ (METHOD §4, A3') at the
  same pixel stays within ``STATIC_DEPTH_TOLERANCE * q z~_t^2`` mm (two quantisation levels
  of the A22 noise model) in every frame of the window where it is valid;
* **intensity**: over a ``(2 STATIC_BOX_RADIUS + 1)^2`` box and the window, the intensity
  cost of not moving, sum (I_T(x) - I_t(x))^2, is at most ``STATIC_PHOTO_RATIO`` times the
  cost at the flow's landings. A moving textured surface (the paper's ball) fails this even
  where its depth at a pixel barely changes (without this condition the ball's RMSE rose
  26 %); the flow's gain on a static textureless wall is noise, so it passes.

A moving camera over a textureless plane passes too: its pixels then average along the
motion, which leaves a plane's depth as it is (``static_room_rgbd``: flicker with ICP poses
+2-4 %, with the recorded poses -5 to -9 %, roughness -14 %).

A static pixel's samples are the pixel itself in every frame T whose z~ at that pixel is
within the same tolerance (the fusion kernel takes them instead of the tracks, METHOD §5.2
unchanged otherwise). With a trajectory base (A21/A28/A32) its trajectory is constant (our
A34): the base is the weighted mean of its motion vectors, t's own zero included, not a line
through them, whose slope is fitted noise that a causal window (t at its end) extrapolates. The depth condition keeps the no-trail property: a foreground edge
crossing the pixel moves z~ by far more than two levels. Holes of frame t are never static
(the A26 fill from time keeps its tracks).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from ._kernels.static import _static_evidence_kernel

__all__ = [
    "STATIC_BOX_RADIUS",
    "STATIC_DEPTH_TOLERANCE",
    "STATIC_PHOTO_RATIO",
    "static_pixels",
]

#: Depth tolerance of a static pixel, in units of q z~^2 (the A22 quantisation level).
STATIC_DEPTH_TOLERANCE = 2.0
#: A pixel is static when not moving costs at most this times the flow's intensity cost.
STATIC_PHOTO_RATIO = 2.0
#: Radius (px) of the box over which the two intensity costs are summed.
STATIC_BOX_RADIUS = 2


def static_pixels(
    ref_ring: NDArray[np.float32],
    intensity_ring: NDArray[np.float32],
    depth_t: NDArray[np.float32],
    frame_slot: NDArray[np.int64],
    t: int,
    first: int,
    tracks: tuple[NDArray[np.integer], NDArray[np.integer], NDArray[np.bool_]],
    quad: float,
) -> NDArray[np.bool_]:
    """Which pixels of frame t are static over its window (see the module docstring).

    Private and unvalidated (the fusion engine's rings and slot convention).

    Parameters
    ----------
    ref_ring : (S, H, W, 3) ndarray of float32
        Motion-reference points P~ (mm, NaN = invalid) of the ring's frames.
    intensity_ring : (S, H, W) ndarray of float32
        Intensity in [0, 1] of the same frames.
    depth_t : (H, W) ndarray of float32
        Frame t's raw depth (mm, NaN = invalid).
    frame_slot : (K + 1,) ndarray of int64
        Ring slot of each frame first..last.
    t, first : int
        The frame and the first frame of its window.
    tracks : (rows, cols, ok), each (K, H, W)
        Frame t's tracks (rounded landing pixel, validity) through the other frames.
    quad : float
        Frame t's noise coefficient q (mm^-1, A22).

    Returns
    -------
    (H, W) ndarray of bool
        True where the pixel's own samples replace its tracks.
    """
    h, w = depth_t.shape
    still = np.empty((h, w), np.bool_)
    cost_zero = np.empty((h, w), np.float32)
    cost_track = np.empty((h, w), np.float32)
    rows, cols, ok = tracks
    if ok.shape[0] == 0:
        return np.zeros((h, w), np.bool_)
    _static_evidence_kernel(
        ref_ring,
        intensity_ring,
        depth_t,
        frame_slot,
        t,
        first,
        rows,
        cols,
        ok,
        STATIC_DEPTH_TOLERANCE * quad,
        still,
        cost_zero,
        cost_track,
    )
    size = (2 * STATIC_BOX_RADIUS + 1,) * 2
    zero = cv2.boxFilter(cost_zero, -1, size, normalize=False)
    track = cv2.boxFilter(cost_track, -1, size, normalize=False)
    return still & (zero <= np.float32(STATIC_PHOTO_RATIO) * track)
