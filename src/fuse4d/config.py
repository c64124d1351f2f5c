"""Parameters of the 4D fusion (METHOD.md §3–§6), presets, and TOML configuration files.

A configuration file looks like::

    preset = "fast"            # optional: start from a preset ("fast" or "paper")

    [fusion]                   # any FusionParams field
    num_frames = 9
    spatial_radius = 3

    [flow]
    method = "dis"             # any registered flow method (fuse4d.flow.available_flow_methods())
    [flow.params]              # fields of that method's parameter dataclass
    preset = "medium"
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from os import PathLike
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

from ._params import coerce_fields, param, validate
from .errors import ParameterError, ParameterTypeError

__all__ = ["LITERAL_PAPER", "PRESETS", "FlowConfig", "FusionParams", "load_config", "preset"]

MotionDepth = Literal["smoothed", "raw"]
Quantize = Literal["final", "per_step"]
Tracks = Literal["exact", "composed"]
FillFallback = Literal["bilateral", "nan"]
Output = Literal["ray", "points"]
BilateralMode = Literal["residual", "points"]
FlyingPixels = Literal["auto", "on", "off"]


#: The literal paper (METHOD A3 "raw" ablation): ``FusionParams(**LITERAL_PAPER)`` switches off
#: every fuse4d decision that changes Eq. 3-6 — motion from raw depth (A3), the plain weighted
#: mean of 3D points in the bilateral (A18) and as output (A17), no temporal gate (A19), frame
#: t's own point as base (A21), the fixed δ_d (A25), no sensor-hole fill from time or of far
#: holes (A26/A27), every track chained through its own flows (A31), no static pixels
#: (A33) and the paper's Eq. 6 hole filling on (A35). Per-step rounding
#: (``quantize="per_step"``, A6) is a separate switch.
LITERAL_PAPER: Mapping[str, Any] = MappingProxyType(
    {
        "motion_depth": "raw",
        "bilateral": "points",
        "output": "points",
        "temporal_gate": math.inf,
        "base": "frame",
        "distance_noise_scale": 0.0,
        "fill_from_time": False,
        "fill_max_hole_px": 0,
        "tracks": "exact",
        "static_tracks": False,
        "static_smoothing": 0.0,
        "fill_holes": True,
    }
)


@dataclass(frozen=True)
class FusionParams:
    """Knobs of the spatio-temporal fusion (paper Eq. 4–6; METHOD.md §5.3 defaults).

    fuse4d's own decisions (docs/method_notes.md, A17–A27) are defaults; the literal paper
    (METHOD A3 "raw" ablation) is ``FusionParams(**LITERAL_PAPER)``, see :data:`LITERAL_PAPER`.

    Parameters
    ----------
    num_frames : int
        Frames fused per output frame, n (paper: 9), 1..256 (the per-pixel support count is
        stored as uint8). Window T in [t - floor((n-1)/2), t + ceil((n-1)/2)] (even n: one
        extra future frame, A14); truncated at the ends (A13).
    spatial_radius : int
        Radius r (px) of the (2r+1)^2 window of the intensity-guided 3D bilateral (inner sum of
        Eq. 5).
    sigma_distance : float
        delta_d (mm) of the 3D-distance kernel d(p_i, p_n): the floor of the per-frame value,
        see ``distance_noise_scale``.
    distance_noise_scale : float
        Our A25: per frame, delta_d = max(``sigma_distance``, scale * q * z_med^2) with q the
        frame's depth-quantisation coefficient (A22) and z_med its median depth (mm), so that the
        3D-distance kernel stays wider than the sensor's noise at any range (Kinect-class depth
        at 1.6 m: q z^2 ~ 4 mm, far beyond a fixed 2 mm). 0 = the literal fixed delta_d. Has no
        effect on continuous depth (q z^2 ~ 0.1 mm on the synthetic ball: 4 q z^2 < 2 mm).
        Default 4 (A30; was 1.5): on quantised depth the error left after temporal fusion is
        the static part (quantisation staircase and the sensor's fixed pattern, the same in
        every frame), which only the spatial kernel averages; 1.5 q z^2 still cut neighbours
        one or two levels away. Kinect-model range scenes (640x480, 10 frames, RMSE vs GT):
        ball 12.38 -> 11.73 mm, body 13.54 -> 13.09, room 13.70 -> 13.26 (scale 3: ball 11.82,
        6: 11.67, 8: 11.65: saturated); uva person roughness 3.277 -> 3.264 mm, background
        flicker 1.445 -> 1.223 mm, one frame 3.412 -> 3.401.
    sigma_intensity : float
        delta_g ([0, 1] intensity units) of the intensity kernel g(I_i, I_n).
    sigma_temporal : float
        delta_f (frames) of the temporal kernel f(t, T). ``math.inf`` = uniform.
    fb_threshold : float
        theta (px): forward-backward consistency threshold of Eq. 4, checked per step in the
        image plane (A4).
    max_depth_step : float
        tau_jump (mm): largest depth change along one tracking step; also the range gate of the
        motion-reference smoothing. ``math.inf`` disables the gate (pure paper check).
    motion_sigma : float
        sigma_m (px) of the edge-limited smoothing that gives the motion-reference depth D~
        (A3), METHOD's 3 px. With the trajectory base (A21) frame t's low-frequency noise is
        averaged over time, so a small sigma_m (little curvature bias) costs no accuracy.
    reference_sigma : float
        sigma (px) of the local reference surface used by the residual bilateral (A18) and for
        the output normals (A17); small, so that it follows curved surfaces. 3 px (measured:
        1 px 0.018 mm, 2 px 0.0147 mm, 3 px 0.0138 mm, 4 px 0.0135 mm RMSE, same setting).
    temporal_gate : float
        Temporal range gate (our A19), in units of the frame's robust depth-noise estimate
        sigma_noise (mm): a tracked sample whose mapped-back point B^T[x^] - m^{t,T} differs
        from frame t's own B^t[x] by ``temporal_gate * sigma_noise`` mm or more is rejected
        like a failed track. It stops mis-tracked samples (flow errors at silhouettes, where
        depth changes by mm per pixel) from entering Eq. 5. ``math.inf`` disables it.
    min_gate_mm : float
        Lower bound (mm) of the temporal gate, for noise-free or quantised depth.
    base : {"adaptive", "trajectory", "frame", "quadratic"}
        Base of Eq. 5 to which the averaged detail is added. "trajectory" (our A21): the value
        at t of a weighted least-squares line through the tracked reference positions
        P~^T[x^_i^T] over the window, i.e. motion vectors regularised to be linear in time, so
        frame t's own low-frequency noise is averaged too. "frame": P~^t[x_i] as in METHOD
        §4.3, whose noise is never averaged. Measured (ball 600x600, 0.2 mm / 2 %, DIS, frame
        4, RMSE in the ball ROI): frame base 0.023 mm at sigma_m = 3 px (0.0147 only with
        sigma_m = 12 px, which over-smooths coarse scenes: 150x150 ball 0.175 mm); trajectory
        base 0.0136 mm at sigma_m = 3 px (150x150 ball 0.055 mm). "quadratic" (our A28): a
        weighted least-squares parabola instead of the line, for curved trajectories (a
        turning body, accelerating objects), noisier where the line holds. "adaptive"
        (default, our A32): per pixel the line, or the parabola for all three coordinates
        where some coordinate's curvature is significant (F test at 5 %, Bonferroni over the
        coordinates) *and* moves the base by more than 0.5 sigma(z) (A22 noise model;
        ``fuse4d.fusion.CURVATURE_TEST_LEVEL`` / ``CURVATURE_MIN_BIAS``). Measured against the
        line (``docs/method_notes.md`` A32): Kinect-model ball object RMSE 5.72 -> 3.43 mm
        (its bounce bends the lateral trajectory; the line's chord bias, projected onto the
        pixel's ray across the sphere's slope, was a depth error), body object 6.37 -> 5.55
        mm; static real scenes within 0.1-2.3 % (``static_room_rgbd`` flicker,
        ``uva_cv2_person_turning`` background), the paper's ball unchanged.
    base_smoothing : float
        Our A29: sigma (px) of an edge-limited spatial smoothing (the A3 operator, on frame
        t's depth-continuous segments) of the base offset that the trajectory fit adds to
        P~^t, before the averaged detail is added. The per-pixel offset holds the line's
        chord bias on turning surfaces, which depends on how many frames each pixel was
        tracked through, so it steps by mm where that number changes; smoothing removes the
        steps. 0 = off (each pixel's own fit, A21/A28). No effect with ``base="frame"``.
        Default 2 px, measured (with ``base_fine_limit`` 0.075; ``benchmarks/real_person.py``):
        uva person (30 frames) Eq. 7 6.56 -> 4.50 mm (one frame 4.58), background flicker
        1.44 -> 1.45 mm; Kinect body 34.3 -> 20.1 mm (one frame 21.1); ball RMSE +0.8 %.
    base_fine_limit : float
        Of the base offset's fine-scale part (offset minus its A29 spatial mean), only what
        lies within ``base_fine_limit`` times the frame's quantisation noise q z^2 (A22) is
        kept: the small part that cancels frame t's own reference noise stays (hundredths of
        a mm on the 0.2 mm ball), mm steps from the chord bias go. ``inf`` keeps it all (no
        effect), 0 = the plain spatial mean.
    motion_depth : {"smoothed", "raw"}
        Depth used for the 3D motion vectors m (Eq. 3). "smoothed" (default, A3) or "raw"
        (the literal paper, kept as an ablation).
    quantize : {"final", "per_step"}
        "final": sub-pixel accumulation, round only for lookup (A6). "per_step": literal
        rounding after every step.
    tracks : {"exact", "composed"}
        Our A31 (issue 13). "composed" (default since stop 43): a chain takes its exact first
        step and then follows the chain of the pixel it landed on, computed once for that
        frame as the pairs arrive, shifted by the landing's sub-pixel offset
        (:mod:`fuse4d._kernels.tracks`): two exact steps and n - 3 gathers per frame instead
        of n - 1 bilinear steps per output frame (tracking 48-50 -> 30-34 ms/frame on the
        600x600 ball, end to end -7 to -16 %, streaming and dask alike). "exact" (METHOD, and
        ``LITERAL_PAPER``): every pixel of frame t is chained through each flow of its window.
        Against the exact tracks (window of 9): the same landing pixel for 99.2-100 % of the
        ball's valid tracks and 96-100 % of the real uva clip's, validity different for
        0-0.25 % (ball) and 0-3.1 % (uva, most at the window's ends); ``fuse4d bench
        --quality`` and the uva person's roughness, flicker and trail within 0.2 %; see
        docs/method_notes.md, A31. With ``quantize="per_step"`` the exact chains are used
        (per-step rounding is an ablation of the chain itself).
    static_tracks : bool
        Our A33 (issue 10): a pixel whose motion-reference depth stays within two
        quantisation levels (2 q z^2, A22) at the same pixel over the whole window, and whose
        intensity does not favour the flow's landings over standing still (not moving costs
        at most twice as much, summed over a 5x5 box), is fused from its own samples
        instead of its tracks (:mod:`fuse4d.static_tracks`). DIS answers 0.5-2 px of spurious
        motion on textureless or reflecting static background, so every track landed on
        another step of the quantised depth and the background flickered. Measured
        (``docs/method_notes.md`` A33): uva background flicker 1.16 -> 0.66 mm (9-frame
        temporal mean 0.57), person roughness unchanged, silhouette trail 0 %; the paper's
        moving ball unchanged. With a trajectory ``base`` a static pixel's trajectory is
        constant (our A34: the weighted mean of its motion vectors, not a line through them,
        which at the end of a causal window extrapolates fitted noise): uva background
        flicker causal window 3 / 9 2.78 -> 1.59 / 1.74 -> 1.07 mm, centred 0.66 -> 0.64.
        Off = every pixel follows its tracks (METHOD).
    static_smoothing : float
        Our A42 (issue 10): sigma (px) of an edge-limited spatial smoothing (the A3 operator
        on the fused depth's continuous segments) applied to the *static* pixels of A33 after
        fusion: each moves along its ray toward the smoothed depth, by at most
        ``static_smoothing_limit`` q z^2 (A22). Temporal fusion removes the noise that
        changes from frame to frame; what a structured-light camera gets wrong the same way in
        every frame (its quantisation staircase, and the fixed disparity pattern that stops a
        real wall's 40-frame mean at 9.7 mm from a plane) only spatial support removes. 4 px
        spans about the 9-px matching window of such a camera, the scale below which its
        depth holds no detail. Moving pixels and holes are untouched. Default 4 px
        (0 = off; opt-in in stop 41, the default since stop 42); no effect with
        ``static_tracks`` off or a window of one frame. Measured with 4 px
        (``docs/method_notes.md`` A42): Kinect-model RMSE on raw-valid pixels ball / body /
        room 11.54 / 12.81 / 13.03 -> 8.14 / 9.58 / 9.41 mm (objects unchanged), D435 model
        -2 to -3 %, ToF -0.1 to -0.4 %; uva background flicker 0.648 -> 0.592 mm (9-frame
        temporal mean 0.574), person roughness +0.1 %; ``static_room_rgbd`` roughness 6.92 ->
        4.84 mm, pose-compensated flicker -6 to -21 %; the paper's ball unchanged.
    static_smoothing_limit : float
        The most (in units of the frame's q z^2, A22) that A42 moves a static pixel's depth:
        0.5 q z^2 is less than half a quantisation step (a Kinect step is 1.65 q z^2), enough
        to take the staircase and the fixed pattern off a plane, not enough to round a
        crease. Larger limits and sigmas help more where the fixed pattern dominates (Kinect model, sigma 8 / limit 1: ball 6.09 mm) but bias the creases of
        a scene without one (the model without its fixed pattern: room 1.85 -> 3.17 mm).
    flying_pixels : {"auto", "on", "off"}
        Our A36 (issue 10): remove time-of-flight *flying pixels* (a depth between the two
        surfaces of an edge, :mod:`fuse4d.flying_pixels`) from the raw depth before fusing;
        they stay holes, flagged ``SOURCE_REJECTED`` and never filled. "auto" (default): on
        where the input says it comes from a ToF camera (an Azure Kinect ``.mkv``, a
        RealSense L5xx recording, a scene or ``Sequence`` with ``sensor="tof"``;
        :func:`fuse4d.flying_pixels.resolve_flying_pixels`, applied by ``fuse4d run`` /
        ``live`` / ``run --engine dask`` and by :func:`fuse4d.fuse_sequence` given
        ``sensor=``), off otherwise; an engine fed bare arrays reads "auto" as "off".
        Measured on the ToF model (``docs/method_notes.md`` A36): 97 % / 94 % of the ball's /
        body's pixels > 100 mm off found, 0.02-0.04 % of good pixels taken.
    min_temporal_support : int
        Pixels with fewer valid tracked frames (other than t) have no temporal support: they
        keep their bilateral-only value B^t (``fill_fallback``), or Eq. 6 fills them
        (``fill_holes``). At most ``num_frames`` - 1 (ParameterError otherwise) where
        ``num_frames`` > 1.
    fill_holes : bool
        Run the paper's gradient-directed hole filling (Eq. 6) on the pixels without temporal
        support. Off by default (our A35): its first-order extrapolation from the fused
        neighbours was less accurate than the pixel's own bilateral value on every scene
        measured — Kinect-model object RMSE ball 3.98 -> 3.35 mm, body 6.42 -> 5.08 mm
        without it (one frame: 3.70, 6.27), in a causal window of 3 4.54 -> 3.49 and
        7.56 -> 5.86; uva person Eq. 7 roughness 3.207 -> 3.085 mm; the paper's ball
        unchanged (Eq. 6 fills nothing there). On in ``LITERAL_PAPER``.
    fill_radius : int
        r_h (px) of the hole-filling window.
    sigma_fill : float
        delta_h (mm) of the hole-filling weight.
    fill_passes : int
        Maximum onion-peeling passes.
    fill_fallback : {"bilateral", "nan"}
        Value of holes left after the passes: the frame's bilateral-only point, or NaN.
    fill_from_time : bool
        Our A26: fill *sensor* holes (no raw depth at t) from the other frames of the window
        along the pixel's track through the intensity video (the trajectory line through the
        tracked reference points, evaluated at t). Off = sensor holes stay NaN unless filled in
        space. Never outside the sensor's field of view (A38, :func:`fuse4d.fov.field_of_view`
        of the window's frames). See :mod:`fuse4d.holes`.
    fill_max_hole_px : int
        Our A27: sensor-hole components (8-connected) of at most this many pixels that do not
        touch the image border are filled from their far-side neighbours (never across a depth
        discontinuity). 0 = off.
    fill_space_radius : int
        Neighbourhood radius (px) of the A27 spatial fill.
    causal : bool
        Online mode for live cameras: the window is [t - n + 1, t] (zero look-ahead), so frame
        t is emitted as soon as it arrives.
    iterations : int
        Apply the whole fusion this many times (each pass on the previous output, same flows).
    bilateral : {"residual", "points"}
        Inner sum of Eq. 5. "residual" (default, our A18): the intensity-guided 3D bilateral
        averages the neighbours' residuals from the smooth reference surface P~ (each neighbour
        moved onto the centre's reference surface), which removes noise without the curvature
        flattening and lateral drift of a plain weighted mean of 3D points. "points": the
        literal weighted mean of the neighbours' points (ablation).
    output : {"ray", "points"}
        "ray" (default, our A17): each fused point is moved along the local tangent plane of the
        motion-reference surface onto its own pixel's ray, so the result is a depth image whose
        Z is the fused surface's depth at that pixel. "points": the literal Eq. 5 points, which
        may sit off the pixel's ray (their Z then mixes in lateral shifts on slanted surfaces).
    """

    num_frames: int = param(9, ge=1, le=256)
    spatial_radius: int = param(3, ge=0)
    sigma_distance: float = param(2.0, gt=0)
    distance_noise_scale: float = param(4.0, ge=0)
    sigma_intensity: float = param(0.1, gt=0)
    sigma_temporal: float = param(3.0, gt=0)
    fb_threshold: float = param(2.0, gt=0)
    max_depth_step: float = param(10.0, gt=0)
    motion_sigma: float = param(3.0, gt=0, finite=True)  # a blur radius: inf has none
    reference_sigma: float = param(3.0, gt=0, finite=True)
    temporal_gate: float = param(3.0, gt=0)
    min_gate_mm: float = param(0.05, gt=0)
    base: Literal["adaptive", "trajectory", "frame", "quadratic"] = "adaptive"
    base_smoothing: float = param(2.0, ge=0, finite=True)
    base_fine_limit: float = param(0.075, ge=0)
    motion_depth: MotionDepth = "smoothed"
    quantize: Quantize = "final"
    tracks: Tracks = "composed"
    static_tracks: bool = True
    static_smoothing: float = param(4.0, ge=0, finite=True)
    static_smoothing_limit: float = param(0.5, ge=0)
    flying_pixels: FlyingPixels = "auto"
    min_temporal_support: int = param(1, ge=0)
    fill_holes: bool = False
    fill_radius: int = param(2, ge=0)
    sigma_fill: float = param(2.0, gt=0)
    fill_passes: int = param(10, ge=0)
    fill_fallback: FillFallback = "bilateral"
    fill_from_time: bool = True
    fill_max_hole_px: int = param(64, ge=0)
    fill_space_radius: int = param(4, ge=1)
    causal: bool = False
    iterations: int = param(1, ge=1)
    bilateral: BilateralMode = "residual"
    output: Output = "ray"

    def __post_init__(self) -> None:
        validate(self)
        # a pixel has at most num_frames - 1 other frames: a larger minimum turned temporal
        # fusion off without a word (a window of one frame has none whatever the minimum)
        if self.num_frames > 1 and self.min_temporal_support > self.num_frames - 1:
            raise ParameterError(
                f"FusionParams.min_temporal_support must be <= num_frames - 1 (the other frames "
                f"of the window), got min_temporal_support={self.min_temporal_support} with "
                f"num_frames={self.num_frames}: no pixel could be fused"
            )

    @property
    def past_frames(self) -> int:
        """Frames before t in the window (h_past)."""
        return self.num_frames - 1 if self.causal else (self.num_frames - 1) // 2

    @property
    def future_frames(self) -> int:
        """Frames after t in the window (h_future): the output latency in frames."""
        return 0 if self.causal else self.num_frames - 1 - (self.num_frames - 1) // 2

    def replace(self, **changes: Any) -> FusionParams:
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (TOML/JSON friendly; inf written as the string "inf"); read back by
        :meth:`from_dict`."""
        return {f.name: _jsonable(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FusionParams:
        """Parameters from a mapping of fields, e.g. :meth:`to_dict`'s or a JSON record's
        (``"inf"`` read as ``math.inf``, numbers as text read as numbers; fields not given
        keep their defaults).

        Raises
        ------
        ParameterError
            For an unknown field or a bad value.
        """
        return cls(**coerce_fields(cls, data))


@dataclass(frozen=True)
class FlowConfig:
    """Which optical-flow method tracks the intensity video, its parameters, cache and ROI.

    Parameters
    ----------
    method : str
        A registered method name (``fuse4d.flow.available_flow_methods()``).
    params : dict
        Keyword arguments for that method's parameter dataclass (empty = its defaults; strings
        are converted to the field types, see :func:`fuse4d.flow.flow_params_from_mapping`).
    cache_dir : str or None
        Folder of an on-disk :class:`fuse4d.flow.FlowCache` (METHOD §2.5 item 6): every pair's
        forward/backward flow is stored there and reused by later runs on the same intensity
        frames and flow settings. None = no cache.
    roi : (row0, row1, col0, col1) or None
        Solve the flow only inside this half-open box (px, METHOD §2.5 item 8); the flow is 0
        outside it, so tracks there stay put. None = the whole frame.
    """

    method: str = "dis"
    params: dict[str, Any] = field(default_factory=dict)
    cache_dir: str | None = None
    roi: tuple[int, int, int, int] | None = None

    def build_params(self) -> Any:
        """Instantiate the method's parameter dataclass (validates the name and the keys)."""
        from .flow import flow_params_from_mapping, get_flow_method

        return flow_params_from_mapping(get_flow_method(self.method), self.params)

    def estimator(self, *, warm_start: bool = True) -> Any:
        """A :class:`fuse4d.flow.SequenceFlowEstimator` for this configuration (what the
        fusion engine drives pair by pair)."""
        from .flow import FlowCache, SequenceFlowEstimator

        return SequenceFlowEstimator(
            method=self.method,
            params=self.build_params(),
            warm_start=warm_start,
            roi=self.roi,
            cache=None if self.cache_dir is None else FlowCache(self.cache_dir),
        )


@dataclass(frozen=True)
class Preset:
    """A named pair of fusion and flow settings."""

    name: str
    description: str
    fusion: FusionParams
    flow: FlowConfig


PRESETS: dict[str, str] = {
    "fast": "fuse4d's fusion defaults (A17-A25) with OpenCV DIS flow ('fast' preset): everyday",
    "paper": "fuse4d's fusion defaults (A17-A25) with the paper's PMBP tracker (K = 3)",
}


def preset(name: str) -> Preset:
    """Fusion and flow settings of a named preset.

    Parameters
    ----------
    name : {"fast", "paper"}
        ``"fast"``: fuse4d's fusion defaults with OpenCV DIS (its ``fast`` preset, ~15 ms per
        600×600 pair); ``"paper"``: the same fusion with the paper's PMBP tracker (K = 3).

    Returns
    -------
    Preset
        ``.fusion`` (:class:`FusionParams`) and ``.flow`` (:class:`FlowConfig`).

    Examples
    --------
    >>> preset("paper").flow.method
    'pmbp'
    """
    if name == "fast":
        return Preset(name, PRESETS[name], FusionParams(), FlowConfig("dis"))
    if name == "paper":
        return Preset(name, PRESETS[name], FusionParams(), FlowConfig("pmbp"))
    raise ParameterError(f"unknown preset {name!r}; choose one of: {', '.join(PRESETS)}")


def fusion_params(fusion: FusionParams | None) -> FusionParams:
    """The ``fusion`` argument of the public entry points: itself, or the defaults for None.

    Raises
    ------
    ParameterTypeError
        For anything else (a dict or a preset name failed later as an AttributeError deep
        inside the run); the message says how to make a :class:`FusionParams`.
    """
    if fusion is None:
        return FusionParams()
    if isinstance(fusion, FusionParams):
        return fusion
    if isinstance(fusion, Mapping):
        hint = "FusionParams(**mapping) makes one from a mapping of its fields"
    elif isinstance(fusion, str):
        hint = f"fuse4d.preset({fusion!r}).fusion is a preset's (with its flow: .flow)"
    else:
        hint = "e.g. FusionParams(num_frames=5)"
    raise ParameterTypeError(f"fusion must be a FusionParams, got {type(fusion).__name__}; {hint}")


def load_config(
    path: str | PathLike[str],
    *,
    base: str | None = None,
    override_preset: bool = False,
    fusion_changes: dict[str, Any] | None = None,
) -> Preset:
    """Read a TOML configuration file (format in the module docstring).

    Parameters
    ----------
    path : str or PathLike
        The TOML file.
    base : str, optional
        Preset to start from when the file names none (default "fast").
    override_preset : bool, optional
        Start from ``base`` even where the file names a preset (a ``--preset`` given on the
        command line wins over the file, as ``--set`` does). Default False.
    fusion_changes : dict, optional
        Fusion fields given on top of the file's (``--set``, ``--window``: they win), applied
        in the same step, so that the checks between fields see them together (a file's
        ``min_temporal_support = 12`` with ``--window 16`` was checked against the preset's
        9 frames).

    Returns
    -------
    Preset
        The preset's settings with the file's changes (``.fusion``, ``.flow``).

    Raises
    ------
    InputFileError
        If the file cannot be read or parsed, or holds unknown keys or bad values.
    """
    from .errors import InputFileError

    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputFileError(p, "configuration file not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputFileError(p, f"cannot read TOML: {exc}") from None
    unknown = set(data) - {"preset", "fusion", "flow"}
    if unknown:
        raise InputFileError(
            p, f"unknown top-level key(s) {sorted(unknown)}; expected preset, [fusion], [flow]"
        )
    for table in ("fusion", "flow"):  # `fusion = 5` said "'int' object is not iterable"
        if table in data and not isinstance(data[table], dict):
            raise InputFileError(
                p,
                f"{table} must be a table ([{table}] and key = value lines below it), got "
                f"{type(data[table]).__name__} {data[table]!r}",
            )
    # (the caller's preset, where it wins: its error is not the file's)
    given = preset(base) if override_preset and base else None
    try:
        start = given or preset(str(data.get("preset", base or "fast")))
        fusion_data = coerce_fields(
            FusionParams, dict(data.get("fusion", {})), owner="[fusion] of the config file"
        )
        try:
            fusion = start.fusion.replace(**{**fusion_data, **(fusion_changes or {})})
        except (TypeError, ValueError) as exc:
            if not fusion_changes:
                raise
            raise ParameterError(f"{exc} (with the command line's --set/--window)") from None
        flow_data = coerce_fields(
            FlowConfig, dict(data.get("flow", {})), owner="[flow] of the config file"
        )
        method = flow_data.get("method", start.flow.method)
        params = flow_data.get("params", start.flow.params if method == start.flow.method else {})
        if not isinstance(params, dict):  # `params = 5` said "'int' object is not iterable"
            raise ParameterError(
                f"[flow] params must be a table ([flow.params] and key = value lines below it), "
                f"got {type(params).__name__} {params!r}"
            )
        roi = flow_data.get("roi")
        if roi is not None:  # what does not depend on the frame size (that, when they are read)
            from .flow._checks import check_roi

            roi = check_roi(roi, None)
        flow = FlowConfig(method, dict(params), cache_dir=flow_data.get("cache_dir"), roi=roi)
        flow.build_params()
    except (TypeError, ValueError) as exc:
        raise InputFileError(p, str(exc)) from None
    return Preset(start.name, f"{start.description} (+ {p.name})", fusion, flow)


# ----------------------------------------------------------------------------- helpers
def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    return value
