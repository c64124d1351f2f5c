"""Hole filling: the paper's Eq. 6 and the sensor's own holes (METHOD §6.2; issue 10, A26/A27).

Two kinds of holes, one home:

* **Eq. 6 holes** (:func:`fill_holes`): pixels *with* valid raw depth but too little temporal
  support to be fused (Eq. 5). Each gets a weighted average of first-order extrapolations from
  the fused neighbours n in its (2 r_h + 1)^2 window::

      p_i = sum_n h(P_i, p_n) (p_n + J_n (x_i - x_n)) / sum_n h(P_i, p_n),
      h(P_i, p_n) = exp(-|P_i - p_n|^2 / (2 delta_h^2)),

  with J_n the 3x2 Jacobian of the fused surface at n (central / one-sided differences over the
  fused set F) and P_i the raw point of the hole. Onion peeling: each pass fills the holes with
  at least ``min_neighbours`` neighbours in F as F stood at the start of the pass, then adds
  them to F. A fill is accepted only within ``gate`` mm of the hole's current (fallback) value
  (A20). The engine runs it only with ``FusionParams(fill_holes=True)`` (our A35: off by
  default, such pixels keep their own bilateral value, which measured more accurate).
* **Sensor holes** (no raw depth: shadow bands beside foreground edges, dark or grazing
  surfaces, dropouts). The paper leaves them empty; two stages fill them where the data
  supports it, each switchable in :class:`fuse4d.FusionParams`:

  1. *From time* (A26, ``fill_from_time``): a pixel without depth at t is tracked through the
     intensity video like any other; where the track lands on valid depth in other frames of
     the window, the motion-trajectory line through those frames' reference points is
     evaluated at t (the A21 trajectory base, without frame t's own sample). This fills holes
     that a moving object uncovers or that flicker from frame to frame.
  2. *In space* (A27, ``fill_max_hole_px``, :func:`fill_small_holes`): each remaining hole
     component (8-connected) that is small and does not touch the image border (no
     extrapolation beyond the sensor's field of view) gets the intensity-weighted plane through
     the valid neighbours on one side of any depth discontinuity in the window (our A37: the
     neighbours sorted by depth split where consecutive depths jump by more than the
     depth-step limit (A22); a slanted floor or wall has no such jump and stays whole), the
     side whose intensity the hole resembles more (an occlusion shadow looks like the
     background it lies on, a dropout on a foreground rim like the rim), so the fill never
     bridges a depth discontinuity. Where the frame's holes show on which side of its
     foreground edges the sensor's shadows lie, a thin hole on the other side cannot be a
     shadow and never takes the far side (a rim of the foreground: where the intensity says
     it belongs to the far surface it is left empty, our A41), and the pixels of a shadow-side hole within the width of
     the projector's shadow (f b (1/z_near - 1/z_far), the baseline b estimated from the
     frame's holes) never take the near side (:func:`_hole_sides`, our A39; without a shadow
     side, as on ToF cameras, a thin hole beside a foreground turning away from the camera
     never takes the far side, A40). Time fills (1.) that disagree with that side are dropped.

  Neither stage fills a pixel outside the sensor's field of view (our A38,
  :func:`fuse4d.fov.field_of_view`): a registered depth image covers less than the colour image it is
  registered to (a band of 30-50 px with no depth around a Kinect-class or aligned RealSense
  frame), and a track from such a pixel lands on valid depth as soon as anything moves, so
  the time fill (1.) extrapolated depth into that band. Those pixels are flagged
  :data:`SOURCE_OUTSIDE`.

  Every filled pixel is flagged (:data:`SOURCE_TIME`, :data:`SOURCE_SPACE` in
  :attr:`fuse4d.FusedFrame.source`), so a user can drop them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels._common import gauss_factor
from ._kernels.fusion import _fill_holes_kernel
from ._kernels.holes import (
    _grazing_rims_kernel,
    _hole_runs_kernel,
    _side_agrees_kernel,
    _side_bounds_kernel,
    _small_components_kernel,
    _spatial_fill_kernel,
    _temporal_fill_kernel,
    _time_fill_agrees_kernel,
)
from ._validation import as_float32, check_shape
from .config import FusionParams
from .errors import ParameterError

__all__ = [
    "SOURCE_FUSED",
    "SOURCE_MEASURED",
    "SOURCE_NONE",
    "SOURCE_OUTSIDE",
    "SOURCE_REJECTED",
    "SOURCE_SPACE",
    "SOURCE_TIME",
    "fill_holes",
    "fill_small_holes",
    "small_hole_mask",
]

#: :attr:`fuse4d.FusedFrame.source` codes: where each output pixel's value comes from.
SOURCE_NONE = 0  # no depth (a hole that was not filled)
SOURCE_MEASURED = 1  # raw depth, no temporal support (spatial bilateral / Eq. 6 only)
SOURCE_FUSED = 2  # raw depth fused with >= 1 tracked frame (Eq. 5)
SOURCE_TIME = 3  # a sensor hole filled from other frames along its track (A26)
SOURCE_SPACE = 4  # a small sensor hole filled from its far-side neighbours (A27)
SOURCE_REJECTED = 5  # raw depth removed as a ToF flying pixel (A36); left empty, never filled
SOURCE_OUTSIDE = 6  # no depth, outside the sensor's field of view (A38); never filled
_SOURCE_CODES = SOURCE_OUTSIDE + 1


class _SourceTally:
    """Pixels per source code over fused frames, and the shares of them that the ``fuse4d
    run`` summary and the report state: of the raw holes, outside the field of view (A38); of
    the raw holes inside it, filled from time (A26) / in space (A27); of the raw-valid pixels,
    removed as ToF flying pixels (A36)."""

    def __init__(self) -> None:
        self.counts = np.zeros(_SOURCE_CODES, np.int64)
        self.pixels = 0
        self.raw_valid = 0

    def add(self, source: NDArray[np.uint8], raw_valid: int) -> None:
        """One frame's source codes and its number of raw-valid pixels."""
        codes = np.asarray(source).ravel()
        counts = np.bincount(codes, minlength=_SOURCE_CODES)[:_SOURCE_CODES]
        self.add_counts(counts, codes.size, raw_valid)

    def add_counts(self, counts: NDArray[np.int64], pixels: int, raw_valid: int) -> None:
        """One frame's pixels per source code (``counts``, one per code), its number of
        pixels and of raw-valid pixels (what :meth:`add` counts)."""
        self.counts += np.asarray(counts, np.int64)[:_SOURCE_CODES]
        self.pixels += int(pixels)
        self.raw_valid += int(raw_valid)

    def shares(self) -> dict[str, float | None]:
        """``hole_outside_fraction``, ``hole_time_fraction``, ``hole_space_fraction``,
        ``rejected_fraction`` (None where nothing was counted)."""
        raw_holes = self.pixels - self.raw_valid
        outside = int(self.counts[SOURCE_OUTSIDE])
        inside = raw_holes - outside
        return {
            "hole_outside_fraction": outside / raw_holes if raw_holes else None,
            "hole_time_fraction": int(self.counts[SOURCE_TIME]) / inside if inside else None,
            "hole_space_fraction": int(self.counts[SOURCE_SPACE]) / inside if inside else None,
            "rejected_fraction": (
                int(self.counts[SOURCE_REJECTED]) / self.raw_valid if self.raw_valid else None
            ),
        }


def small_hole_mask(holes: ArrayLike, max_area_px: int) -> NDArray[np.bool_]:
    """Pixels of hole components (8-connected) small enough to fill spatially.

    Parameters
    ----------
    holes : (H, W) ndarray of bool
        True where there is no depth.
    max_area_px : int
        Largest component (pixels) that is filled; 0 = none.

    Returns
    -------
    (H, W) ndarray of bool
        Pixels of the components with at most ``max_area_px`` pixels that do not touch the
        image border.

    Examples
    --------
    >>> h = np.zeros((6, 6), bool); h[2:4, 2:4] = True; h[0, 5] = True
    >>> small_hole_mask(h, 4).sum()  # the 2x2 inside hole; the border pixel is left
    np.int64(4)
    """
    mask = np.asarray(holes, dtype=bool)
    out = np.zeros(mask.shape, bool)
    if max_area_px <= 0 or not mask.any():
        return out
    n_labels, labels = cv2.connectedComponents(
        np.ascontiguousarray(mask).view(np.uint8), connectivity=8
    )
    _small_components_kernel(labels, n_labels, int(max_area_px), out)
    return out


#: A frame's shadow side is decided when the hole runs on one side of the depth edges outnumber
#: those on the other by this factor (pixels) ...
SHADOW_VOTE_RATIO = 2.0
#: ... and number at least this many pixels.
SHADOW_VOTE_MIN_PX = 64
#: Widest run (px) taken for a rim dropout (Kinect-model ball: rim runs of 1-5 px; the
#: registration band of ``uva_cv2_person_turning``, depth mapped onto its colour camera: 6-10 px).
RIM_MAX_PX = 5


#: The projector-camera baseline of a frame is estimated as this quantile of
#: run length / (f (1/z_near - 1/z_far)) over its shadow-side runs (rim dropouts only lengthen
#: a run; Kinect-model ball / body: 75.9 / 67.9 mm for the true 75) ...
SHADOW_BASELINE_QUANTILE = 0.2
#: ... from at least this many runs, and used only inside this range (mm: RealSense D4xx
#: 50-95, Kinect v1 / Xtion / Astra 75); elsewhere the shadow width is taken as unknown.
SHADOW_MIN_RUNS = 20
SHADOW_BASELINE_RANGE_MM = (20.0, 150.0)
#: Without a shadow side (time of flight), a thin hole (at most :data:`RIM_MAX_PX`) whose near
#: end's surface recedes toward it by more than this many mm of depth per mm across (45°
#: from facing the camera) is taken for a grazing rim: a fill on the far surface is refused (A40).
GRAZING_MIN_SLOPE = 1.0


@dataclass(frozen=True)
class _HoleSides:
    """Which surface the holes beside frame t's depth discontinuities must take.

    Attributes
    ----------
    kind : (H, W) ndarray of int8
        1: a rim dropout of the foreground opposite the shadow side (A27, A41: not the far
        surface); 2: inside the projector's shadow (A39: not the near surface); 3: a thin hole
        beside a foreground that turns away from the camera (A40: not the far surface); 0: the
        intensity rule decides alone. Kinds 1-3 never force a side: the intensity rule picks
        it and a fill on the excluded surface is refused (:meth:`agrees`).
    bound : (H, W) ndarray of float32
        Where ``kind`` > 0, the depth (mm) halfway between the run's two surfaces; NaN
        elsewhere.
    """

    kind: NDArray[np.int8]
    bound: NDArray[np.float32]

    def agrees(self, filled_depth: NDArray[np.float32]) -> NDArray[np.bool_]:
        """False where a fill (mm) lies on the wrong surface: a rim (kind 1 or 3) farther than
        ``bound``, a shadow (kind 2) nearer."""
        out = np.empty(self.kind.shape, np.bool_)
        _side_agrees_kernel(self.kind, self.bound, filled_depth, out)
        return out


def _hole_sides(
    depth: NDArray[np.float32], *, focal_px: float | None, max_step: float, quad: float
) -> _HoleSides:
    """Rim dropouts (A27, A40) and projector shadows (A39) among the holes of one frame.

    A structured-light or stereo camera's shadow lies on the same side of every foreground
    edge (away from the projector or the second imager along the baseline). Each horizontal
    run of holes between a far and a near surface is oriented (:func:`_hole_runs_kernel`)
    and the frame votes, weighted by run length: where one orientation has at least
    :data:`SHADOW_VOTE_RATIO` times the pixels of the other (and :data:`SHADOW_VOTE_MIN_PX`),
    it is the shadow side, and the thin runs (at most :data:`RIM_MAX_PX`) of the other
    orientation are rims (the grazing edge of the foreground) that never take the far
    surface. Without a clear vote (ToF cameras, no edges) nothing is marked; wider runs on the
    other side (the registration gap of depth mapped onto a colour camera, as in
    ``uva_cv2_person_turning``) keep the intensity rule. On the Kinect-model ball the
    intensity rule alone gave the ball's far rim the background's depth (1 m off).

    A41: a rim is not forced onto the near surface either (stop 30 forced it): where the
    intensity rule picks the far side the fill is refused and the pixel stays a hole. Block
    matching also invalidates the *background* beside an edge (its window straddles the
    edge), and those runs look the same; on the Kinect-model body 815 of the forced rim fills
    were > 100 mm off, the background's depth being the truth. Where the intensity image says
    the hole looks like the foreground (as a rim does) it is still filled from it.

    A39: on the shadow side, a foreground edge at z_near over a surface at z_far hides
    f b (1/z_near - 1/z_far) px of that surface from the projector (b the baseline, f the
    focal length ``focal_px``); those pixels next to the run's far end never take the near
    surface, whatever their intensity says (a fill nearer than the bound is refused; forcing
    the far side instead gave the wall to the Kinect-model ball's rim pixels inside the
    predicted width). b is estimated from the frame's own runs
    (:data:`SHADOW_BASELINE_QUANTILE`); a run longer than its shadow by more than
    :data:`RIM_MAX_PX` px (or shorter by more than 1 px) is not split. ``focal_px`` None: rims only.

    A40: without a shadow side (time-of-flight cameras have no projector offset), a thin run
    whose near end's surface recedes toward it faster than :data:`GRAZING_MIN_SLOPE` is a
    dropout at the foreground's grazing rim (where the returned signal fades), not a hole in
    the far surface: a fill on the far side of the bound is refused (the intensity rule
    still picks the side; forcing the near side put the ToF room's dark dropouts beside
    furniture onto the furniture).
    """
    cap = depth.size // 2 + 1
    row, start, length = (np.empty(cap, np.int32) for _ in range(3))
    orient = np.empty(cap, np.int8)
    z_near, z_far = np.empty(cap, np.float64), np.empty(cap, np.float64)
    n = _hole_runs_kernel(
        depth, float(max_step), float(quad), row, start, length, orient, z_near, z_far
    )
    # the vote, weighted by run length; foreground to the run's right: +1
    right = int(length[:n][orient[:n] > 0].sum())
    left = int(length[:n][orient[:n] < 0].sum())
    kind = np.zeros(depth.shape, np.int8)
    bound = np.full(depth.shape, np.nan, np.float32)
    if right >= SHADOW_VOTE_MIN_PX and right >= SHADOW_VOTE_RATIO * left:
        shadow_orient = 1
    elif left >= SHADOW_VOTE_MIN_PX and left >= SHADOW_VOTE_RATIO * right:
        shadow_orient = -1
    else:  # no shadow side (time of flight): rims only where the foreground turns away
        if focal_px is not None:
            _grazing_rims_kernel(
                depth,
                row,
                start,
                length,
                orient,
                z_near,
                z_far,
                n,
                float(focal_px),
                GRAZING_MIN_SLOPE,
                RIM_MAX_PX,
                kind,
                bound,
            )
        return _HoleSides(kind, bound)
    scale = 0.0
    on_side = orient[:n] == shadow_orient
    if focal_px is not None and np.count_nonzero(on_side) >= SHADOW_MIN_RUNS:
        # f b: rim dropouts only lengthen a run, so a low quantile of length / (1/zn - 1/zf)
        ratio = length[:n][on_side] / (1.0 / z_near[:n][on_side] - 1.0 / z_far[:n][on_side])
        scale = float(np.quantile(ratio, SHADOW_BASELINE_QUANTILE))
        lo, hi = SHADOW_BASELINE_RANGE_MM
        if not lo * focal_px <= scale <= hi * focal_px:  # not a camera baseline
            scale = 0.0
    _side_bounds_kernel(
        row, start, length, orient, z_near, z_far, n, shadow_orient, scale, RIM_MAX_PX, kind, bound
    )
    return _HoleSides(kind, bound)


def _fill_from_time(
    fwd_ring: NDArray[np.float32],
    bwd_ring: NDArray[np.float32],
    depth_ring: NDArray[np.float32],
    ref_ring: NDArray[np.float32],
    frame_slot: NDArray[np.int64],
    t: int,
    first: int,
    last: int,
    target: NDArray[np.bool_],
    *,
    fb_threshold: float,
    max_step: float,
    quad: float,
    temporal_weight: NDArray[np.float64],
    min_samples: int = 1,
) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """Unvalidated A26 on the engine's ring buffers (ring convention of
    :mod:`fuse4d._kernels.fusion`): the trajectory points (mm) of the ``target`` pixels of
    frame t and the number of frames that gave a sample (0 = not filled)."""
    h, w = target.shape
    points = np.empty((h, w, 3), np.float32)
    count = np.empty((h, w), np.uint8)
    _temporal_fill_kernel(
        fwd_ring,
        bwd_ring,
        depth_ring,
        ref_ring,
        frame_slot,
        int(t),
        int(first),
        int(last),
        float(fb_threshold),
        float(max_step),
        float(quad),
        temporal_weight,
        int(min_samples),
        target,
        points,
        count,
    )
    return points, count


def _side_consistent(
    filled_depth: NDArray[np.float32],
    depth: NDArray[np.float32],
    intensity: NDArray[np.float32],
    holes: NDArray[np.bool_],
    sides: _HoleSides,
    *,
    radius: int,
    sigma_intensity: float,
    max_step: float,
    quad: float,
) -> NDArray[np.bool_]:
    """Which time fills (A26) agree with the side of frame t's own neighbourhood that the
    intensity image assigns the hole to (the A27 side rule, :func:`_spatial_fill_kernel`).

    A sensor hole beside a moving edge often has its optical flow dragged along by the edge,
    so its track lands on the other surface in other frames. A fill is kept only if it lies
    within the depth-step limit (A22) of that side's depth, or if the window holds no valid
    depth at all (the inside of a large hole: nothing to compare with). Measured on the
    Kinect-model walking body (16 frames): without this check 30 % of the time fills were
    more than 100 mm off. Fills on the wrong surface of a rim or a projector shadow
    (``sides``, :func:`_hole_sides`) are dropped too.
    """
    side = np.empty_like(depth)
    _spatial_fill_kernel(
        depth,
        intensity,
        holes,
        int(radius),
        gauss_factor(sigma_intensity),
        gauss_factor(2.0),
        float(max_step),
        float(quad),
        side,
    )
    out = np.empty(holes.shape, np.bool_)
    _time_fill_agrees_kernel(
        filled_depth, side, holes, float(max_step), float(quad), sides.kind, sides.bound, out
    )
    return out


def _fill_small_holes(
    depth: NDArray[np.float32],
    intensity: NDArray[np.float32],
    holes: NDArray[np.bool_],
    sides: _HoleSides,
    *,
    max_area_px: int,
    radius: int,
    sigma_intensity: float,
    max_step: float,
    quad: float,
    sigma_space: float = 2.0,
    sensor_holes: NDArray[np.bool_] | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Unvalidated A27: fill the small components of ``holes`` in ``depth`` (mm); a fill of
    a rim or a projector shadow (``sides``, :func:`_hole_sides`) on the surface it cannot
    belong to is refused. ``sensor_holes``: the frame's holes before any other fill (default
    ``holes``); the size and border limits apply to its components, and only their pixels
    still in ``holes`` are filled (a large hole that the fill from time broke into pieces
    stays a large hole)."""
    if sensor_holes is None:
        target = small_hole_mask(holes, int(max_area_px))
    else:
        target = small_hole_mask(sensor_holes, int(max_area_px))
        target &= holes
    out = depth.copy()
    if target.any():
        _spatial_fill_kernel(
            depth,
            intensity,
            target,
            int(radius),
            gauss_factor(sigma_intensity),
            gauss_factor(sigma_space),
            float(max_step),
            float(quad),
            out,
        )
    return out, target & np.isfinite(out) & sides.agrees(out)


def fill_small_holes(
    depth: ArrayLike,
    intensity: ArrayLike,
    *,
    max_area_px: int = 64,
    radius: int = 4,
    sigma_intensity: float = 0.1,
    sigma_space: float = 2.0,
    max_step: float = 10.0,
    noise_quad: float = 0.0,
    focal_px: float | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Fill small sensor holes from the neighbours on one side of any depth edge (A27, A37).

    Parameters
    ----------
    depth : (H, W) ndarray
        Depth in mm, NaN = hole.
    intensity : (H, W) ndarray
        Registered intensity in [0, 1]: neighbours of similar intensity weigh more, and decide
        which side of a depth discontinuity the hole belongs to.
    max_area_px : int
        Largest hole component filled (pixels); components touching the image border are
        never filled.
    radius : int
        Neighbourhood radius (px).
    sigma_intensity : float
        Intensity scale of the weights ([0, 1] units).
    sigma_space : float
        Spatial scale of the weights (px).
    max_step : float
        tau_jump (mm): consecutive neighbour depths (sorted) further apart than the
        depth-step limit mark a depth discontinuity; only one side of it is used.
    noise_quad : float
        Depth-noise coefficient (mm^-1, A22); the step limit is max(max_step, 2.5 q z^2).
    focal_px : float, optional
        Focal length fx (px) of a structured-light or stereo camera: the pixels of a hole
        within the width of the projector's shadow take the far side (A39). None: only the
        rims are decided by the hole's geometry.

    Returns
    -------
    depth : (H, W) ndarray of float32
        Depth with the small holes filled (mm).
    filled : (H, W) ndarray of bool
        The pixels that were filled.

    Examples
    --------
    >>> d = np.full((9, 9), 2000.0, np.float32); d[:, 6:] = 1000.0  # foreground on the right
    >>> inten = np.where(np.arange(9) < 6, 0.3, 0.8)[None].repeat(9, 0).astype(np.float32)
    >>> d[3:6, 4:6] = np.nan  # a shadow hole on the wall beside the foreground edge
    >>> out, filled = fill_small_holes(d, inten)
    >>> float(out[4, 5]), int(filled.sum())  # filled with the wall, not a blend
    (2000.0, 6)
    """
    d = as_float32(depth, name="depth")
    check_shape(d, ("H", "W"), name="depth")
    inten = as_float32(intensity, name="intensity")
    check_shape(inten, d.shape, name="intensity")
    return _fill_small_holes(
        d,
        inten,
        np.isnan(d),
        _hole_sides(d, focal_px=focal_px, max_step=max_step, quad=noise_quad),
        max_area_px=max_area_px,
        radius=radius,
        sigma_intensity=sigma_intensity,
        sigma_space=sigma_space,
        max_step=max_step,
        quad=noise_quad,
    )


# ----------------------------------------------------------------------------- Eq. 6
def _fill_holes(
    points: NDArray[np.float32],
    raw_points: NDArray[np.float32],
    hole: NDArray[np.bool_],
    *,
    radius: int,
    sigma: float,
    passes: int,
    min_neighbours: int,
    gate: float,
) -> NDArray[np.bool_]:
    """Unvalidated Eq. 6, in place on ``points`` and ``hole`` (cleared where filled).

    Returns the (H, W) bool mask of the pixels filled.
    """
    filled = np.zeros(hole.shape, np.bool_)
    if not (~hole & ~np.isnan(points[..., 2])).any():
        # F is empty (e.g. the first frame of a causal window: no pixel has temporal
        # support): no hole has a neighbour to extrapolate from, nothing is filled (issue 13)
        return filled
    _fill_holes_kernel(
        points,
        raw_points,
        hole,
        int(radius),
        gauss_factor(sigma),
        int(passes),
        int(min_neighbours),
        float(gate),
        filled,
    )
    return filled


def fill_holes(
    points: ArrayLike,
    raw_points: ArrayLike,
    hole: ArrayLike,
    *,
    radius: int = FusionParams.fill_radius,
    sigma: float = FusionParams.sigma_fill,
    passes: int = FusionParams.fill_passes,
    min_neighbours: int = 3,
    gate: float = math.inf,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Fill the holes of a fused point map by gradient-directed extrapolation (Eq. 6).

    Parameters
    ----------
    points : (H, W, 3) ndarray
        Fused points in mm; holes hold their fallback value (the engine uses the bilateral-only
        point B^t), NaN = no depth (never filled, never used).
    raw_points : (H, W, 3) ndarray
        Raw points P^t in mm (the weights compare a hole's raw point with its neighbours).
    hole : (H, W) bool ndarray
        Pixels to fill.
    radius : int
        r_h in px (default ``FusionParams.fill_radius``).
    sigma : float
        delta_h in mm (default ``FusionParams.sigma_fill``).
    passes : int
        Maximum onion-peeling passes (default ``FusionParams.fill_passes``).
    min_neighbours : int
        Fused neighbours a hole needs in its window to be filled in a pass.
    gate : float
        A20 acceptance gate in mm: a fill farther than this from the hole's current value is
        rejected (the engine uses the frame's temporal gate); ``math.inf`` = literal Eq. 6.

    Returns
    -------
    points : (H, W, 3) ndarray of float32
        A copy of ``points`` with the accepted fills (mm).
    filled : (H, W) ndarray of bool
        Holes that were filled; ``hole & ~filled`` keep their fallback value.

    Examples
    --------
    >>> p = np.zeros((5, 5, 3), np.float32); p[..., 2] = 500.0 + np.arange(5)
    >>> hole = np.zeros((5, 5), bool); hole[2, 2] = True
    >>> out, filled = fill_holes(np.where(hole[..., None], 0, p), p, hole)
    >>> bool(filled[2, 2]), round(float(out[2, 2, 2]), 3)
    (True, 502.0)
    """
    pts = as_float32(points, name="points").copy()
    check_shape(pts, ("H", "W", 3), name="points")
    raw = as_float32(raw_points, name="raw_points")
    check_shape(raw, pts.shape, name="raw_points")
    mask = np.array(hole, dtype=np.bool_, copy=True)
    check_shape(mask, pts.shape[:2], name="hole")
    for name, value in (("radius", radius), ("passes", passes), ("min_neighbours", min_neighbours)):
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise ParameterError(f"{name} must be an integer >= 0, got {value!r}")
    if not sigma > 0:
        raise ParameterError(f"sigma must be > 0 mm, got {sigma}")
    if not gate > 0:
        raise ParameterError(f"gate must be > 0 mm, got {gate}")
    filled = _fill_holes(
        pts,
        raw,
        mask,
        radius=radius,
        sigma=sigma,
        passes=passes,
        min_neighbours=min_neighbours,
        gate=gate,
    )
    return pts, filled
