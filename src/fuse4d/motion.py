"""Tracks and 3D motion fields from 2D flow (paper Eq. 3–4, METHOD.md §3–§4): their one home.

Everything here works on the pixel grid: a pixel x_i of frame t is followed through the
consecutive flows with sub-pixel accumulation (bilinear flow sampling), validated per step by
the forward–backward check (Eq. 4, in px), valid depth and the depth-step rule
``max(max_depth_step, 2.5 quad z^2)`` (A22), and looked up at the rounded position
``floor(X + 0.5)``.

Layers: the public :func:`track_frame` / :func:`compute_motion_field` validate their input and
call the private, unvalidated :func:`_track_window` / :func:`_pair_motion`, which the streaming
engine (:class:`fuse4d.FusionEngine`) calls directly on its ring buffers. This module owns the
ring-slot convention of those helpers: with ring size S, frame T lives in slot ``T % S`` of the
depth and point rings, and the flows of the pair (T-1, T) live in slot ``T % S`` of the flow
rings (forward s^{T-1,T} on frame T-1's grid, backward s^{T,T-1} on frame T's grid).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels.fusion import _pair_diagnostics_kernel, _track_kernel
from ._kernels.noise import _median64, _noise_quad_ratios, _trimmed_residuals
from ._kernels.segment_smooth import _segment_smooth_sweep_kernel
from ._kernels.tracks import _compose_kernel, _one_step_kernel
from ._memory import committed
from ._validation import as_float32, check_shape
from .camera import Intrinsics, check_intrinsics, depth_to_points
from .config import FusionParams
from .errors import ParameterError
from .sequence import sanitize_depth

__all__ = [
    "Tracks",
    "compute_motion_field",
    "estimate_depth_noise",
    "estimate_noise_quad",
    "motion_reference_depth",
    "track_frame",
]


def motion_reference_depth(
    depth: ArrayLike,
    *,
    sigma: float = FusionParams.motion_sigma,
    max_step: float = FusionParams.max_depth_step,
    noise_quad: float = 0.0,
) -> NDArray[np.float32]:
    """Edge-limited smoothing of one depth frame: the motion-reference depth D~ (A3).

    METHOD §4.3 asks for a normalised Gaussian (sigma_m) over valid pixels that never mixes
    depths more than ``max_step`` apart. We compute it as two box-filter passes along rows and
    two along columns (a separable triangle kernel with the same variance as the Gaussian),
    each a local-linear fit over its window (so truncated windows at borders and edges carry no
    slope bias),
    each pass confined to *depth-continuous segments*: runs of valid pixels whose consecutive
    depths differ by less than ``max_step`` mm. Windows are truncated at segment ends and
    renormalised. Compared with METHOD's centre-relative range gate this is identical on smooth
    surfaces, likewise never crosses a depth discontinuity or a hole, and costs O(1) per pixel
    (prefix sums) instead of O(sigma^2) (A3' in docs/method_notes.md).

    Parameters
    ----------
    depth : (H, W) ndarray
        Depth in mm, NaN = invalid.
    sigma : float
        sigma_m in px (box radius r with (2r+1)^2 = 6 sigma^2 + 1, at least 1); default
        ``FusionParams.motion_sigma`` (3 px, METHOD's value).
    max_step : float
        tau_jump in mm (default ``FusionParams.max_depth_step``): a larger step between
        neighbouring pixels ends a segment.
    noise_quad : float
        Quadratic depth-noise coefficient (mm^-1, see :func:`estimate_noise_quad`): at depth z
        the step limit is ``max(max_step, 2.5 * noise_quad * z^2)`` (A22, the rule tracking
        uses), so quantisation steps of far structured-light depth do not cut segments.

    Returns
    -------
    (H, W) ndarray of float32
        Smoothed depth in mm, NaN where ``depth`` is NaN.

    Examples
    --------
    >>> d = np.full((5, 5), 500.0, np.float32); d[2, 2] = np.nan; d[:, 4] = 900.0
    >>> r = motion_reference_depth(d, sigma=1.0)
    >>> float(r[0, 0]), float(r[0, 4]), bool(np.isnan(r[2, 2]))
    (500.0, 900.0, True)
    """
    d = as_float32(depth, name="depth")
    check_shape(d, ("H", "W"), name="depth")
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ParameterError(f"sigma must be a finite number > 0 px, got {sigma}")
    return _segment_smooth(d, d, sigma=sigma, max_step=max_step, noise_quad=noise_quad)


def _segment_smooth(
    values: NDArray[np.float32],
    depth: NDArray[np.float32],
    *,
    sigma: float,
    max_step: float,
    noise_quad: float = 0.0,
) -> NDArray[np.float32]:
    """The edge-limited smoothing of :func:`motion_reference_depth` applied to any value map.

    ``values`` (H, W) are averaged over the depth-continuous segments of ``depth`` (H, W) mm
    (NaN = excluded): two local-linear box passes along rows and two along columns, radius r
    with (2r+1)^2 = 6 sigma^2 + 1 (sigma in px). Returns (H, W) float32, NaN where ``depth``
    is NaN. ``_segment_smooth(d, d, ...)`` is the motion-reference depth D~; the base offsets
    of A29 are smoothed with it too.
    """
    d = np.ascontiguousarray(depth, dtype=np.float32)
    h, w = d.shape
    radius = _box_radius(sigma)
    step, quad = float(max_step), float(noise_quad)
    # two sweeps (rows, then columns), each finding a line's segments once for both of its
    # passes and writing its result transposed: the values of four _segment_box_rows_kernel
    # passes, bit for bit (_kernels/segment_smooth.py); cv2.transpose: 0.04 ms a 640x480 plane
    rows_t = np.empty((w, h), np.float32)
    values32 = np.ascontiguousarray(values, dtype=np.float32)
    _segment_smooth_sweep_kernel(values32, d, radius, step, quad, rows_t)
    out = np.empty((h, w), np.float32)
    _segment_smooth_sweep_kernel(rows_t, cv2.transpose(d), radius, step, quad, out)
    return out


#: Largest box radius (px): beyond any image, so a larger sigma smooths the same (each box
#: stops at its segment's ends); ``--set motion_sigma=1e20`` gave an integer numba could not
#: type, 1e300 an OverflowError.
MAX_BOX_RADIUS = 1 << 20


def _box_radius(sigma: float) -> int:
    """Box radius r (px) of the two-pass triangle with the variance of a Gaussian of ``sigma``
    px: (2r+1)^2 = 6 sigma^2 + 1, at least 1, at most :data:`MAX_BOX_RADIUS`."""
    s = min(float(sigma), float(MAX_BOX_RADIUS))
    return max(1, min(MAX_BOX_RADIUS, round((math.sqrt(6.0 * s * s + 1.0) - 1.0) / 2.0)))


def estimate_noise_quad(depth: ArrayLike) -> float:
    """Quadratic coefficient of a frame's depth-noise model sigma(z) = quad * z^2 (A22), mm^-1.

    Structured-light and stereo depth is noisier, and quantised more coarsely, further away
    (step ~ z^2). ``quad`` is the median over pixels (every 2nd row) of |second difference
    along the row| / z^2, over non-zero values below 5 % of the depth (edges excluded), divided
    by 1.65: second differences cancel surface slope; for Gaussian noise their median
    magnitude is 1.65 sigma, on quantised depth it is one quantisation level. Returns 0.0 when
    no pixel qualifies.
    """
    d = as_float32(depth, name="depth")
    check_shape(d, ("H", "W"), name="depth")
    h, w = d.shape
    ratios = np.empty(((h + 1) // 2) * max(w - 2, 0), np.float64)
    n = _noise_quad_ratios(d, ratios)  # one pass (issue 13), numpy's values and order
    return _median64(ratios, n) / 1.65 if n else 0.0  # np.median(ratios[:n]), bit for bit


def estimate_depth_noise(depth: ArrayLike, *, reference: ArrayLike | None = None) -> float:
    """Robust estimate of the per-pixel depth noise of one frame, in mm.

    The residual r between the depth and a small-scale edge-limited smoothing (sigma = 2 px,
    or ``reference`` when given), subsampled 2x2, summarised as ``1.2533 * mean(|r|)`` over
    the residuals below their 95th percentile (a trimmed mean absolute deviation, scaled to a
    Gaussian sigma; trimming ignores depth edges). Unlike the median absolute deviation it does
    not collapse to 0 on quantised depth (structured-light cameras, where most residuals are
    exactly 0). Depth 0, negative and inf is invalid, as NaN (a 16-bit file's hole is 0).
    Returns 0.0 for a frame without valid depth.
    """
    d = sanitize_depth(depth)
    check_shape(d, ("H", "W"), name="depth")
    ref = motion_reference_depth(d, sigma=2.0) if reference is None else np.asarray(reference)
    if ref.dtype == np.float32 and ref.shape == d.shape:  # one kernel (issue 13), same value
        return _depth_noise(d, np.ascontiguousarray(ref)[..., None], 0)
    r = np.abs(d[::2, ::2] - ref[::2, ::2]).ravel()
    r = r[np.isfinite(r)]
    if r.size == 0:
        return 0.0
    keep = r[r <= np.quantile(r, 0.95)]
    return float(1.2533 * keep.mean()) if keep.size else 0.0


def _depth_noise(depth: NDArray[np.float32], points: NDArray[np.float32], channel: int) -> float:
    """:func:`estimate_depth_noise` of C-contiguous float32 ``depth`` (H, W) with the reference
    ``points[..., channel]`` (C-contiguous float32 (H, W, C); the engine passes its smoothed
    points, z = channel 2): the residuals, their 95th percentile and the trim in one kernel
    (:func:`fuse4d._kernels.noise._trimmed_residuals`), numpy's float32 mean of the kept
    ones. The value of the numpy expressions, bit for bit (tested); 0.94 -> 0.2 ms on the
    600 x 600 ball."""
    h, w = depth.shape
    kept = np.empty(((h + 1) // 2) * ((w + 1) // 2), np.float32)
    k = _trimmed_residuals(depth, points, channel, kept)
    return float(1.2533 * kept[:k].mean()) if k else 0.0


@dataclass(frozen=True)
class Tracks:
    """Tracks of every pixel of frame ``t`` through its temporal window.

    Attributes
    ----------
    t : int
        Reference frame.
    frames : (K,) ndarray of int
        The other frames T of the window, increasing (t excluded).
    rows, cols : (K, H, W) ndarray of int32
        Rounded landing pixel x^_i^T (row, column) of the track from pixel i.
    valid : (K, H, W) ndarray of bool
        nu_i^{t,T}: AND of the per-step checks along the chain (METHOD §4.1).
    """

    t: int
    frames: NDArray[np.int64]
    rows: NDArray[np.int32]
    cols: NDArray[np.int32]
    valid: NDArray[np.bool_]


def _pair_ring(flow: NDArray[np.float32]) -> NDArray[np.float32]:
    """(T-1, H, W, 2) pair flows -> (T, H, W, 2) ring of size T: slot T holds pair (T-1, T)."""
    return np.concatenate([np.zeros_like(flow[:1]), flow], axis=0)


def _window(t: int, past: int, future: int, available: int) -> tuple[int, int]:
    """First and last frame of frame ``t``'s temporal window, truncated to frames
    0..available-1 (A13)."""
    return max(0, t - past), min(available - 1, t + future)


class _TimeFill(NamedTuple):
    """The A26 fill that :func:`_track_window` does beside the tracks (private).

    ``target`` (H, W) bool: frame t's holes to fill ((0, 0): none); ``ref_ring`` (S, H, W, 3)
    the motion-reference points P~ (mm) of the ring; ``temporal_weight`` f(t, T) by |T - t|;
    ``min_samples``: samples a fill needs; ``points`` (H, W, 3) float32 and ``count`` (H, W)
    uint8: the outputs of :func:`fuse4d._kernels.holes._temporal_fill_kernel`.
    """

    target: NDArray[np.bool_]
    ref_ring: NDArray[np.float32]
    temporal_weight: NDArray[np.float64]
    min_samples: int
    points: NDArray[np.float32]
    count: NDArray[np.uint8]


#: :func:`_track_window` without a fill: empty arrays of the kernel's types
_NO_FILL = _TimeFill(
    np.zeros((0, 0), np.bool_),
    np.zeros((1, 1, 1, 3), np.float32),
    np.ones(1, np.float64),
    1,
    np.zeros((1, 1, 3), np.float32),
    np.zeros((1, 1), np.uint8),
)


def _track_window(
    fwd_ring: NDArray[np.float32],
    bwd_ring: NDArray[np.float32],
    depth_ring: NDArray[np.float32],
    t: int,
    first: int,
    last: int,
    *,
    fb_threshold: float,
    max_step: float,
    quad: float,
    per_step: bool,
    out: tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.bool_]] | None = None,
    fill: _TimeFill | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int32], NDArray[np.bool_]]:
    """Tracks of every pixel of frame ``t`` through frames ``first..last`` (Eq. 4 per step).

    Private and unvalidated: rings follow the module's slot convention (ring size S =
    ``depth_ring.shape[0]``), float32 (S, H, W, 2) flows and (S, H, W) depth in mm.
    ``quad`` is frame t's depth-noise coefficient (mm^-1) of the step rule (A22).
    ``out``: (rows, cols, ok) buffers of at least K = last - first frames, reused between
    calls (the streaming engine's; the results are views of their first K frames).
    ``fill``: the holes of frame t to fill from the other frames in the same pass (A26,
    :class:`_TimeFill`; its ``points`` and ``count`` are written at the targets).

    Returns
    -------
    frame_slot : (K + 1,) ndarray of int64
        Ring slot of each frame first..last.
    rows, cols : (K, H, W) ndarray of int32
        Rounded landing pixel of the track in each other frame (increasing, t excluded).
    ok : (K, H, W) ndarray of bool
        nu^{t,T}: AND of the per-step checks along the chain.
    """
    _s, h, w = depth_ring.shape
    k = last - first
    frame_slot = np.arange(first, last + 1, dtype=np.int64) % depth_ring.shape[0]
    if out is None:
        rows = np.empty((k, h, w), np.int32)
        cols = np.empty((k, h, w), np.int32)
        ok = np.empty((k, h, w), np.bool_)
    else:
        rows, cols, ok = out[0][:k], out[1][:k], out[2][:k]
    if k == 0:  # a window of frame t alone: nothing to track
        return frame_slot, rows, cols, ok
    f = _NO_FILL if fill is None else fill
    _track_kernel(
        fwd_ring,
        bwd_ring,
        depth_ring,
        frame_slot,
        t,
        first,
        last,
        float(fb_threshold),
        float(max_step),
        float(quad),
        bool(per_step),
        rows,
        cols,
        ok,
        f.target,
        f.ref_ring,
        f.temporal_weight,
        int(f.min_samples),
        f.points,
        f.count,
    )
    return frame_slot, rows, cols, ok


class _ComposedTracks:
    """Composed tracks of a streaming engine (``FusionParams(tracks="composed")``, A31).

    Built frame by frame as the pairs arrive (:meth:`add_frame`), each step shared by every
    output frame that uses it (:mod:`fuse4d._kernels.tracks`); :meth:`window` gives frame t's
    tracks in the layout of :func:`_track_window`. Engine-local frame indices from 0; a frame's
    tracks depend only on the pairs inside its window, so an engine that starts later (a dask
    chunk with its halo) computes the same ones.

    Memory: ``future + 1`` frames of (past + future) landing pixels (int16) and validity (5
    bytes per pixel and other frame: 72 MB at 600 x 600 and n = 9), the forward one-step maps
    of the last ``future`` pairs and the backward chains of the last two frames (9 bytes per
    pixel and frame each).
    """

    def __init__(self, height: int, width: int, past: int, future: int) -> None:
        self.past, self.future = past, future
        k = past + future
        self._slots = future + 1  # frames whose tracks are kept (not yet emitted)
        # landing pixels as int16 where the image allows (half the memory and traffic)
        index = np.int16 if max(height, width) <= np.iinfo(np.int16).max else np.int32
        # every buffer written now, not during the first frames (fuse4d._memory)
        self._rows = committed((self._slots, k, height, width), index)
        self._cols = committed((self._slots, k, height, width), index)
        self._ok = committed((self._slots, k, height, width), np.bool_)

        def maps(n: int) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_]]:
            shape = (n, height, width)
            return (
                committed(shape, np.float32),
                committed(shape, np.float32),
                committed(shape, bool),
            )

        # forward: pair (s, s+1) from s's pixels in slot s % future, and the chains s -> N of
        # the newest N while composing; backward: the chains of frames N and N - 1
        self._step_fwd = maps(future) if future > 0 else None
        self._ahead = (maps(1), maps(1)) if future > 0 else None
        self._back = (maps(past), maps(past)) if past > 0 else None

    @staticmethod
    def buffer_bytes(height: int, width: int, past: int, future: int) -> int:
        """Bytes that ``_ComposedTracks(height, width, past, future)`` allocates: the track
        tables, quadratic in the window ((future + 1) x (past + future) x H x W x 5 B: 47 GiB
        at 640 x 480 and n = 256), and the step maps (9 B per pixel each)."""
        pixels = int(height) * int(width)
        index = 2 if max(height, width) <= np.iinfo(np.int16).max else 4
        tables = (future + 1) * (past + future) * pixels * (2 * index + 1)
        maps = future + (2 if future > 0 else 0) + 2 * past
        return tables + maps * pixels * 9

    def add_frame(
        self,
        index: int,
        fwd_ring: NDArray[np.float32],
        bwd_ring: NDArray[np.float32],
        depth_ring: NDArray[np.float32],
        quads: NDArray[np.float64],
        *,
        fb_threshold: float,
        max_step: float,
        first_output: int = 0,
        stop_output: int | None = None,
    ) -> None:
        """Extend the tracks with frame ``index`` >= 1, whose pair (index - 1, index) is in the
        rings (ring convention of :mod:`fuse4d._kernels.fusion`; ``quads`` (S,) the frames'
        noise coefficients, mm^-1: a step is checked with its start frame's, a composed
        landing with its own frame's).

        Only frames ``first_output`` <= t < ``stop_output`` will be emitted (a dask chunk's
        halo frames are sources only): the forward chains of earlier frames and the backward
        chains of frames from ``stop_output`` on are not built (nothing needs them)."""
        s_ring = depth_ring.shape[0]
        n, prev = index % s_ring, (index - 1) % s_ring
        theta, step = float(fb_threshold), float(max_step)
        lowest = max(index - self.future, first_output, 0)  # lowest start s of chains to index
        if self.future > 0 and index - 1 >= lowest:
            # chains s -> index for s = index - 1, index - 2, ... (newest first: each follows
            # the one of s + 1 just computed)
            f = self._step_fwd
            j = (index - 1) % self.future
            slot = (index - 1) % self._slots
            jj = self.past  # other-frame index of T = s + 1 in frame s's layout
            _one_step_kernel(
                fwd_ring[n], bwd_ring[n], depth_ring[prev], depth_ring[n], theta, step,
                float(quads[prev]), f[0][j], f[1][j], f[2][j],
                self._rows[slot, jj], self._cols[slot, jj],
            )  # fmt: skip
            self._ok[slot, jj] = f[2][j]
            follow = (f[0][j], f[1][j], f[2][j])
            for s in range(index - 2, lowest - 1, -1):
                slot = s % self._slots
                jj = index - s + self.past - 1
                out = self._ahead[s % 2]
                first = s % self.future
                _compose_kernel(
                    f[0][first], f[1][first], f[2][first], *follow, depth_ring[n], step,
                    float(quads[n]), out[0][0], out[1][0], out[2][0],
                    self._rows[slot, jj], self._cols[slot, jj],
                )  # fmt: skip
                self._ok[slot, jj] = out[2][0]
                follow = (out[0][0], out[1][0], out[2][0])
        if self.past > 0 and (stop_output is None or index < stop_output):
            # chains index -> index - k: the exact step to index - 1, then frame index - 1's
            cur, old = self._back[index % 2], self._back[(index - 1) % 2]
            slot = index % self._slots
            _one_step_kernel(
                bwd_ring[n], fwd_ring[n], depth_ring[n], depth_ring[prev], theta, step,
                float(quads[n]), cur[0][0], cur[1][0], cur[2][0],
                self._rows[slot, self.past - 1], self._cols[slot, self.past - 1],
            )  # fmt: skip
            self._ok[slot, self.past - 1] = cur[2][0]
            for k in range(2, min(self.past, index) + 1):
                c = (index - k) % s_ring
                _compose_kernel(
                    cur[0][0], cur[1][0], cur[2][0], old[0][k - 2], old[1][k - 2],
                    old[2][k - 2], depth_ring[c], step, float(quads[c]),
                    cur[0][k - 1], cur[1][k - 1], cur[2][k - 1],
                    self._rows[slot, self.past - k], self._cols[slot, self.past - k],
                )  # fmt: skip
                self._ok[slot, self.past - k] = cur[2][k - 1]

    def window(
        self, t: int, first: int, last: int
    ) -> tuple[NDArray[np.integer], NDArray[np.integer], NDArray[np.bool_]]:
        """Frame t's tracks through ``first..last`` (as :func:`_track_window`'s rows, cols,
        ok, but int16 rows/cols for images below 32768 px: views, valid until frame
        t + future + 1 is added)."""
        off = first - (t - self.past)
        k = last - first
        slot = t % self._slots
        return (
            self._rows[slot, off : off + k],
            self._cols[slot, off : off + k],
            self._ok[slot, off : off + k],
        )


def _pair_motion(
    fwd_ring: NDArray[np.float32],
    bwd_ring: NDArray[np.float32],
    ref_ring: NDArray[np.float32],
    depth_ring: NDArray[np.float32],
    t: int,
    *,
    fb_threshold: float,
    max_step: float,
    quad: float,
    per_step: bool,
    motion: NDArray[np.float32] | None = None,
    fb_error: NDArray[np.float32] | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """One-step 3D motion m^{t,t+1} (Eq. 3) and FB error (Eq. 4) of the pair (t, t+1).

    Private and unvalidated: rings follow the module's slot convention (ring size S =
    ``depth_ring.shape[0]``); ``ref_ring`` (S, H, W, 3) holds the motion-reference points P~ in
    mm. A step is valid exactly when the first step of :func:`_track_window` from frame t is
    (same FB check, same depth-step rule with frame t's ``quad``), so the motion field shows
    the validity nu the fusion uses.

    Returns
    -------
    motion : (H, W, 3) ndarray of float32
        P~^{t+1}[x^] - P~^t[x] in mm, NaN where the step is invalid.
    fb_error : (H, W) ndarray of float32
        Forward-backward error in px, NaN where the step leaves the image.
    """
    s, h, w = depth_ring.shape
    if motion is None:
        motion = np.empty((h, w, 3), np.float32)
    if fb_error is None:
        fb_error = np.empty((h, w), np.float32)
    st, s1 = t % s, (t + 1) % s
    _pair_diagnostics_kernel(
        fwd_ring,
        bwd_ring,
        s1,
        ref_ring[st],
        ref_ring[s1],
        depth_ring[st],
        depth_ring[s1],
        float(fb_threshold),
        float(max_step),
        float(quad),
        bool(per_step),
        fb_error,
        motion,
    )
    return motion, fb_error


def _check_flows(
    flow_forward: ArrayLike, flow_backward: ArrayLike, depth: ArrayLike
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Validated float32 copies: depth (T, H, W), flows (T-1, H, W, 2) each."""
    d = as_float32(depth, name="depth")
    check_shape(d, ("T", "H", "W"), name="depth")
    n, h, w = d.shape
    fwd = as_float32(flow_forward, name="flow_forward")
    bwd = as_float32(flow_backward, name="flow_backward")
    check_shape(fwd, (n - 1, h, w, 2), name="flow_forward")
    check_shape(bwd, (n - 1, h, w, 2), name="flow_backward")
    return fwd, bwd, d


def track_frame(
    flow_forward: ArrayLike,
    flow_backward: ArrayLike,
    depth: ArrayLike,
    t: int,
    *,
    params: FusionParams | None = None,
) -> Tracks:
    """Chain the flows from every pixel of frame ``t`` over its window (METHOD §4.1).

    Parameters
    ----------
    flow_forward : (T-1, H, W, 2) ndarray
        s^{t,t+1} in px on frame t's grid (``[..., 0]`` = du, column).
    flow_backward : (T-1, H, W, 2) ndarray
        s^{t+1,t} in px on frame t+1's grid.
    depth : (T, H, W) ndarray
        Raw depth in mm (NaN = invalid): validity and depth-jump gate.
    t : int
        Reference frame.
    params : FusionParams, optional
        Window (``num_frames``, ``causal``), ``fb_threshold``, ``max_depth_step``, ``quantize``.

    Returns
    -------
    Tracks

    Notes
    -----
    The depth-jump gate is ``max(max_depth_step, 2.5 quad z^2)`` with ``quad`` from
    :func:`estimate_noise_quad` on frame t, exactly as in the fusion engine (A22): both call
    the same private ``_track_window``.
    """
    params = params or FusionParams()
    fwd, bwd, d = _check_flows(flow_forward, flow_backward, depth)
    n = d.shape[0]
    if not 0 <= t < n:
        raise ParameterError(f"t must be in [0, {n - 1}], got {t}")
    first, last = _window(t, params.past_frames, params.future_frames, n)
    _slots, rows, cols, valid = _track_window(
        _pair_ring(fwd),
        _pair_ring(bwd),
        d,
        t,
        first,
        last,
        fb_threshold=params.fb_threshold,
        max_step=params.max_depth_step,
        quad=estimate_noise_quad(d[t]),
        per_step=params.quantize == "per_step",
    )
    frames = np.array([T for T in range(first, last + 1) if t != T], dtype=np.int64)
    return Tracks(t=t, frames=frames, rows=rows, cols=cols, valid=valid)


def compute_motion_field(
    flow_forward: ArrayLike,
    flow_backward: ArrayLike,
    depth: ArrayLike,
    intrinsics: Intrinsics,
    *,
    params: FusionParams | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Per-step 3D motion field m^{t,t+1} (Eq. 3) and the forward–backward error (Eq. 4).

    Parameters
    ----------
    flow_forward, flow_backward : (T-1, H, W, 2) ndarray
        Consecutive-pair flows in px.
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intrinsics : Intrinsics
    params : FusionParams, optional
        ``motion_depth`` ("smoothed": motion from D~, A3; "raw": literal), ``motion_sigma``,
        ``fb_threshold``, ``max_depth_step``, ``quantize``.

    Returns
    -------
    motion : (T-1, H, W, 3) ndarray of float32
        P~^{t+1}[x^] - P~^t[x] in mm (scene flow), NaN where the step is invalid: the same
        validity nu^{t,t+1} as the tracks of :func:`track_frame` and the fusion engine (FB
        check and the depth-step rule ``max(max_depth_step, 2.5 quad z^2)`` with frame t's
        ``quad``, A22).
    fb_error : (T-1, H, W) ndarray of float32
        |s^{t,t+1}(x) + s^{t+1,t}(x + s^{t,t+1}(x))| in px; NaN where the step leaves the image.
    """
    params = params or FusionParams()
    check_intrinsics(intrinsics)
    fwd, bwd, d = _check_flows(flow_forward, flow_backward, depth)
    n, h, w = d.shape
    quads = [estimate_noise_quad(f) for f in d]
    if params.motion_depth == "smoothed":
        ref_depth = np.stack(
            [
                motion_reference_depth(
                    f, sigma=params.motion_sigma, max_step=params.max_depth_step, noise_quad=q
                )
                for f, q in zip(d, quads, strict=True)
            ]
        )
    else:
        ref_depth = d
    ref = depth_to_points(ref_depth, intrinsics)
    motion = np.empty((max(n - 1, 0), h, w, 3), np.float32)
    fb = np.empty((max(n - 1, 0), h, w), np.float32)
    fwd_ring = _pair_ring(fwd)
    bwd_ring = _pair_ring(bwd)
    for t in range(n - 1):
        _pair_motion(
            fwd_ring,
            bwd_ring,
            ref,
            d,
            t,
            fb_threshold=params.fb_threshold,
            max_step=params.max_depth_step,
            quad=quads[t],
            per_step=params.quantize == "per_step",
            motion=motion[t],
            fb_error=fb[t],
        )
    return motion, fb
