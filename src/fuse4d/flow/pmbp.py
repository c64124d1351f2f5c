"""PatchMatch Belief Propagation optical flow, the paper's tracker (METHOD.md §2).

PMBP (Besse, Rother, Fitzgibbon, Kautz, IJCV 2014) is min-sum *particle* belief propagation on
the 4-connected pixel grid. Every pixel keeps K continuous labels (particles, flow vectors in
px); PatchMatch moves (propagation of neighbours' best particles, random search around the
current particles) propose new labels, and a proposal replaces the worst particle when it lowers
the pixel's disbelief (unary + incoming messages). The unary is an adaptive-support-weighted,
truncated patch dissimilarity; the pairwise term is a truncated quadratic.

Three schedules are provided:

``"sequential"``
    The reference raster sweep of METHOD §2.3 (direction ``it % 4``, propagation from the two
    neighbours already visited in the sweep). Single-threaded; used by tests as the reference.
``"lines"`` (default)
    Line-parallel alternating passes, as in GPU PatchMatch: sweep ``it`` scans rows (``it``
    even) or columns (odd), forward or backward (``it % 4``); lines of one parity run in
    parallel, then the other parity. Each pixel propagates from the pixel just visited on its
    line and from its two neighbours on the adjacent lines (other parity, not written during
    the phase), so labels travel a whole line per sweep, as in the reference.
``"parallel"``
    Red-black (checkerboard) schedule (e.g. Felzenszwalb & Huttenlocher 2006; Galliani et al.
    2015): every "red" pixel in parallel from its four black neighbours, then every black one.
    Labels travel one pixel per half sweep, which costs accuracy with few sweeps (Middlebury
    EPE 0.40 against 0.37 for "lines" and 0.33 for "sequential" with the default sweeps
    before decision A23; 0.194 / 0.184 / 0.175 with the A23 post-steps).

Both parallel schedules are deterministic and independent of the thread count: pixels
updated in the same phase never read each other, and each pixel draws its random numbers
from a counter-based generator keyed by (seed, level, iteration, phase, pixel index). Both
are tested to agree in EPE with the reference.

Deviations from METHOD §2 (each a field of :class:`PMBPParams`, so the literal setting stays
available), all measured with ``benchmarks/bench_pmbp.py``:

- coarse-to-fine (``pyramid_levels=3``; METHOD: "no coarse-to-fine"): each level's flow,
  upsampled ×2, seeds the next finer level, whose random search starts at ``refine_radius``
  and whose extra particles are drawn within ``refine_radius`` of it. Without it the
  truncated-quadratic smoothness pins the field near its all-zero initial particle;
- ``data_sweeps=1``: the first sweep on the coarsest level runs with λ = 0 (plain PatchMatch)
  for the same reason;
- the gradient term is on (α = 0.9, the reference demo's value; METHOD default 0, "intensity
  patches"): on Middlebury α = 0 gave EPE 0.77 against 0.40, the ball is unaffected;
- ``presmooth_sigma=1`` (Gaussian on both images), ``inside_target=False`` (labels may point
  off the image, which costs the border cost), fewer sweeps to fit the 2 s budget,
  ``search_best_only`` and ``finest_level`` as speed knobs;
- post-steps (decision A23 of ``docs/method_notes.md``), on by default: a forward-backward
  consistency check (a second PMBP solve, image1 → image0, warm-started with the negated
  forward field) whose failing pixels -- occlusions and the "fattened" foreground along motion
  boundaries -- are refilled with an edge-aware weighted median of the consistent pixels
  around them (``consistency_check``), then OpenCV's variational refinement
  (``cv2.VariationalRefinement``, the Brox et al. energy that DIS and EpicFlow / CPM-Flow
  apply to their matches) for the sub-pixel part (``variational_refinement_iterations``). The
  refinement also regularises, so the MRF smoothness is lowered to λ = 0.01 and the random
  search stops at r_min = 0.2 px (for pmbp 0.3 px with 15 refinement iterations since
  decision A23′). Middlebury mean EPE 0.373 → 0.184 px (pmbp) and 0.418 →
  0.197 px (pmbp-fast), against DIS-medium 0.254 and Dual TV-L1 0.210; the 600x600 solve costs
  1.5x the CPU time (two PMBP solves instead of one, r_min 0.2 instead of 0.05). Both
  post-steps are off with ``consistency_check=False, variational_refinement_iterations=0``,
  which returns the PMBP solve itself (the MRF solution the tests compare to the oracle).

Other speed-ups: early termination of the patch cost, each particle's unary cached (a label's
ψ1 never changes), precomputed adaptive-support weights ((H, W, (2ρ+1)²) float32), separable
bilinear sampling in the image interior, the energy terms inlined into one per-pixel update,
and ``roi`` restriction. SPM-BP (Li et al., ICCV 2015: superpixel-shared particles and an
edge-aware filtered data cost) is *not* implemented: its 50-100x is measured against PMBP with
large aggregation windows (PMBP's cost grows linearly with the window), whereas METHOD's patch
is 5x5, so filter-based aggregation would save much less here. ``"pmbp-fast"`` is K = 1,
solved down to half resolution, line-parallel schedule, 2 sweeps per level, post-steps at
half resolution and the refinement again at full resolution.

Initialisation (METHOD §2.3): the particles of each pixel start from seed labels -- on the
coarsest level zero and the warm start ``init`` (particle 1 in METHOD), on finer levels the
upsampled coarser flow and ``init`` -- then random labels (uniform in [-M, M]² on the coarsest
level). If more valid seeds than K exist (K = 1 with a warm start), the K seeds with the
lowest unary are kept (our rule; METHOD is silent for K = 1).

References
----------
.. [1] F. Besse, C. Rother, A. Fitzgibbon, J. Kautz, "PMBP: PatchMatch Belief Propagation for
   Correspondence Field Estimation", IJCV 110(1):2-13, 2014. :DOI:`10.1007/s11263-013-0653-9`
.. [2] Y. Li, D. Min, M. S. Brown, M. N. Do, J. Lu, "SPM-BP: Sped-up PatchMatch Belief
   Propagation for Continuous MRFs", ICCV 2015.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._kernels import pmbp as _k
from .._params import check_int, param, validate
from .._validation import as_float32, check_same_shape, check_shape
from ..errors import ParameterError
from ._checks import check_image, to_uint8
from ._registry import FlowMethod, register_flow_method

__all__ = [
    "PMBP_FAST",
    "PMBPFastParams",
    "PMBPParams",
    "pmbp_flow",
    "pmbp_flow_fast",
    "pmbp_flow_fast_pair",
    "pmbp_flow_pair",
    "register",
]

Schedule = Literal["parallel", "lines", "sequential"]
_MAX_PARTICLES = 16
_MIN_LEVEL_SIZE = 32  # px: no pyramid level smaller than this (small images get fewer levels)


@dataclass(frozen=True)
class PMBPParams:
    """Knobs of PMBP flow (METHOD.md §2.1 table; intensities in [0, 1], displacements in px).

    Parameters
    ----------
    num_particles : int
        K, particles per pixel (1..16). K = 1 is PatchMatch + smoothness (fast mode).
    patch_radius : int
        ρ: the unary compares (2ρ+1)² patches (clipped to the image).
    gradient_weight : float
        α in [0, 1]: weight of the gradient term of the unary (0: intensity only, the paper and
        METHOD default; 0.9: the reference demo script and our default, see the module notes).
    trunc_intensity : float
        τ1: truncation of |I^t(q) − I^{t+1}(q+s)|.
    trunc_gradient : float
        τ2: truncation of the L1 gradient difference (used only when α > 0).
    asw_gamma : float
        γ: adaptive support weight w_pq = exp(−|Ī(p) − Ī(q)| / γ), Ī = 3x3 median of I^t.
    border_factor : float
        β: cost of a patch sample that falls outside the target image, in units of
        (1−α)τ1 + ατ2.
    pairwise_weight : float
        λ: smoothness weight per px² of the truncated quadratic ψ2. Default 0.01 (0.05 before
        decision A23): with the variational refinement smoothing the result, a weaker MRF
        smoothness keeps boundaries and fine motion (Middlebury 0.200 px at 0.02, 0.184 at
        0.01, 0.172 at 0; we keep λ > 0 so the solve stays BP, not plain PatchMatch).
    pairwise_trunc : float
        T_pw (px²): truncation of the quadratic.
    max_motion : float
        M (px): largest allowed |s|, at full resolution. Default 16 (METHOD: 8): with the
        pyramid a larger M costs nothing, and Middlebury Hydrangea moves 11 px.
    num_iter : int
        Sweeps on the finest pyramid level.
    coarse_num_iter : int or None
        Sweeps on each coarser level (None: ``num_iter``).
    search_radius0 : float or None
        r0 (px, at the level's resolution): first random-search radius on the coarsest level
        (None: M_level / 2, METHOD §2.3).
    refine_radius : float
        First random-search radius (px) on levels seeded from a coarser level (our choice: the
        upsampled coarse flow is already within about a pixel).
    min_search_radius : float
        r_min (px): radii r0, r0/2, ... are drawn while r >= r_min. Default 0.3 (0.05 before
        decision A23, 0.2 before A23′; ``"pmbp-fast"`` keeps 0.2): the variational refinement
        does the sub-pixel part, so the finest radii bought nothing (Middlebury 0.184 px at
        0.05 and 0.2, 0.1835 at 0.3 with 15 refinement iterations) and cost run time (on
        refined levels 0.3 drops the 0.25 px radius: 6 random candidates per pixel, not 9).
    pyramid_levels : int
        Number of pyramid levels (1 = no pyramid, the literal METHOD §2.3); levels whose
        shorter side would be below 32 px are dropped.
    finest_level : int
        Finest pyramid level that is solved (0 = full resolution). With 1, the flow is solved
        at half resolution and upsampled bilinearly (×2 vectors), 4x less work, as DIS does
        with ``finest_scale`` (our speed knob, used by ``"pmbp-fast"``).
    schedule : {"lines", "parallel", "sequential"}
        Line-parallel alternating passes (default), red-black checkerboard, or the reference
        sequential raster sweep of METHOD §2.3 (single-threaded); see the module notes.
    early_termination : bool
        Stop the patch cost once it cannot beat the worst particle (same result, faster).
    search_best_only : bool
        Random search around the min-disbelief particle only, instead of around each of the K
        particles (METHOD §2.3 step 3). K times fewer candidates (our speed knob).
    inside_target : bool
        Constrain labels to keep p + s inside the target image (the literal METHOD §2.1). Off by
        default (our deviation): pixels that leave the view (e.g. the left strip of Middlebury
        Venus, motion −8 px) then take their flow from their neighbours through the pairwise
        term instead of being forced to a wrong in-image label; samples off the image cost
        the border cost either way.
    presmooth_sigma : float
        σ (px) of a Gaussian applied to both images before matching (0: none; our addition).
        It damps sensor noise and the high frequencies that bias bilinear sampling.
    data_sweeps : int
        The first ``data_sweeps`` sweeps on the coarsest level use λ = 0 (plain PatchMatch on
        the unary), then BP with λ (our addition). Starting BP from the all-zero particle
        field lets the truncated-quadratic smoothness pin the field to zero: a lone pixel that
        finds the true label pays up to 4·λ·T_pw, more than it gains in ψ1, and the field only
        creeps toward the motion by ~0.2 px per sweep.
    consistency_check : bool
        Post-step 1 (our addition, decision A23; on by default): solve the backward flow
        (image1 → image0, warm-started with −forward, same parameters and seed), mark the
        pixels p whose p + s(p) leaves the image or whose |s_fw(p) + s_bw(p + s_fw(p))| ≥
        ``consistency_threshold`` (occlusions, foreground fattened over the background along
        motion boundaries), and replace each by the weighted median (per component) of the
        consistent pixels q within ``fill_radius``, weights
        exp(−|Ī(p) − Ī(q)| / ``fill_sigma_intensity`` − |p − q|² / (2 ``fill_sigma_space``²)),
        Ī the presmoothed image0: an occluded pixel takes the flow of the consistent pixels
        that look like it, i.e. of its own surface (as EpicFlow's edge-aware interpolation and
        the left-right check + weighted-median fill of stereo). Runs at the finest solved
        level. Doubles the PMBP work; Middlebury mean EPE 0.231 → 0.184 px with the
        refinement on (Venus 0.467 → 0.328), 0.315 → 0.261 with it off.
    consistency_threshold : float
        Forward-backward cycle error (px) at and above which a pixel is refilled (1 px, as
        the tracking check of METHOD §2.4).
    fill_radius : int
        Half side (px) of the fill window (10); a pixel with no consistent pixel in it keeps
        its value.
    fill_sigma_intensity : float
        Intensity scale of the fill weights (0.05, intensities in [0, 1]).
    fill_sigma_space : float
        Spatial σ (px) of the fill weights (5).
    variational_refinement_iterations : int
        Post-step 2 (our addition, decision A23; on by default): outer fixed-point iterations
        of ``cv2.VariationalRefinement`` (Brox et al. 2004 energy: colour and gradient
        constancy + smoothness, Charbonnier penalties) started from the PMBP field, on the
        unsmoothed images quantised to 8 bit; 0 = off. With ``finest_level`` > 0 it runs at
        the solved level and again at full resolution after upsampling (as DIS refines on
        every level). Middlebury 0.315 → 0.231 px without the fill, 0.261 → 0.184 with it.
        Default 15 (10 before decision A23′, ``"pmbp-fast"`` keeps 10): with r_min 0.3
        Middlebury 0.1835 px at 15, 0.1831 at 20.
    variational_refinement_sor_iterations : int
        Inner SOR iterations per fixed-point iteration (10).
    variational_refinement_alpha : float
        Smoothness weight of the refinement (20, OpenCV's and DIS-medium's default).
    variational_refinement_gamma : float
        Gradient-constancy weight of the refinement (10, OpenCV's default).
    variational_refinement_delta : float
        Brightness-constancy weight of the refinement (5, OpenCV's default).
    roi : tuple of 4 int or None
        (row0, row1, col0, col1), half-open, at full resolution: solve only inside; flow is 0
        outside. None: the whole image. The post-steps see only the roi.
    seed : int
        Seed of all random draws, 0 to 2**63 - 1; results are bit-identical for a fixed seed
        (either schedule, any thread count).
    """

    # Defaults tuned on the 600x600 ball (σ_I 2 % / 10 %, pair 10-11) and the 4 Middlebury
    # pairs (max_motion 16), 2-core machine shared with other jobs, 2026-11-22
    # (benchmarks/bench_pmbp.py). α = 0 (METHOD) scored Middlebury EPE 0.77 (real lighting
    # changes) against 0.40 with α = 0.9; λ ∈ {0.03, 0.05, 0.1, 0.3}: 0.05 keeps the ball at
    # σ_I 10 % under 0.6 px (0.44) with the best Middlebury EPE; 1 finest + 2 coarse sweeps and
    # r_min 0.05 px fit the 2 s budget at equal ball EPE (Middlebury 0.40 vs 0.38 with 2 + 3,
    # checkerboard schedule); the "lines" schedule then gave Middlebury 0.37, ball 0.10 / 0.46.
    # Decision A23 (2026-11-23, same benchmark): FB check + fill and variational refinement
    # on, λ 0.05 → 0.01, r_min 0.05 → 0.2 px: Middlebury 0.373 → 0.184, ball 0.03 / 0.20.
    # Decision A23′ (2026-12-01, issue 13): r_min 0.2 → 0.3 px, refinement 10 → 15 iterations
    # (pmbp only): Middlebury 0.1838 → 0.1835, ball 2 % 0.030 → 0.025, ~6 % less CPU.
    num_particles: int = param(3, ge=1, le=_MAX_PARTICLES)
    patch_radius: int = param(2, ge=0, le=15)
    gradient_weight: float = param(0.9, ge=0, le=1)
    trunc_intensity: float = param(0.3, gt=0)
    trunc_gradient: float = param(0.1, gt=0)
    asw_gamma: float = param(0.1, gt=0)
    border_factor: float = param(0.85, ge=0)
    pairwise_weight: float = param(0.01, ge=0)
    pairwise_trunc: float = param(4.0, gt=0)
    max_motion: float = param(16.0, gt=0)
    num_iter: int = param(1, ge=0)
    coarse_num_iter: int | None = param(2, ge=0)
    search_radius0: float | None = param(None, gt=0)
    refine_radius: float = param(1.0, gt=0)
    min_search_radius: float = param(0.3, gt=0)
    pyramid_levels: int = param(3, ge=1, le=8)
    finest_level: int = param(0, ge=0)
    schedule: Schedule = "lines"
    early_termination: bool = True
    search_best_only: bool = False
    inside_target: bool = False
    presmooth_sigma: float = param(1.0, ge=0, le=100)  # 1e9 hung in GaussianBlur
    data_sweeps: int = param(1, ge=0)
    consistency_check: bool = True
    consistency_threshold: float = param(1.0, gt=0)
    fill_radius: int = param(10, ge=1, le=64)
    fill_sigma_intensity: float = param(0.05, gt=0)
    fill_sigma_space: float = param(5.0, gt=0)
    variational_refinement_iterations: int = param(15, ge=0)
    variational_refinement_sor_iterations: int = param(10, ge=1)
    variational_refinement_alpha: float = param(20.0, ge=0)
    variational_refinement_gamma: float = param(10.0, ge=0)
    variational_refinement_delta: float = param(5.0, ge=0)
    roi: tuple[int, int, int, int] | None = None
    seed: int = param(0, ge=0, le=2**63 - 1)  # the kernels take an int64

    def __post_init__(self) -> None:
        validate(self, finite=True)
        owner = type(self).__name__
        check_int(owner, "finest_level", self.finest_level, maximum=self.pyramid_levels - 1)
        roi = self.roi
        if roi is not None and not (0 <= roi[0] < roi[1] and 0 <= roi[2] < roi[3]):
            raise ParameterError(
                f"{owner}.roi must satisfy 0 <= row0 < row1 and 0 <= col0 < col1, got {roi!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        """Field name → value (for caches and reports)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class PMBPFastParams(PMBPParams):
    """:class:`PMBPParams` with the defaults of the fast setting ``"pmbp-fast"``.

    K = 1, solved down to half resolution (``finest_level=1``) and upsampled, 2 sweeps per
    level; the post-steps (forward-backward fill, variational refinement) run at half
    resolution, and the refinement again at full resolution. Every field can still be
    overridden. Same fields and meaning as :class:`PMBPParams`. SPM-BP (superpixel particles,
    filtered data cost) is not implemented.
    """

    num_particles: int = 1
    finest_level: int = 1
    num_iter: int = 2
    coarse_num_iter: int | None = 2
    min_search_radius: float = 0.2  # the A23 values: decision A23′ changed them for pmbp only
    variational_refinement_iterations: int = 10


#: Parameters of ``"pmbp-fast"``.
PMBP_FAST = PMBPFastParams()


# --------------------------------------------------------------------------------------------
# per-level data


@dataclass
class _Level:
    src4: NDArray[np.float32]  # (H, W, 4): I^t, ∂u I^t, ∂v I^t, 0
    tgt4: NDArray[np.float32]  # (H, W, 4): same for I^{t+1}
    roi: NDArray[np.int64]
    scale: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.src4.shape[:2]


def _channels(image: NDArray[np.float32], gradients: bool) -> NDArray[np.float32]:
    """(H, W, 4) float32: intensity and its central differences (one-sided at the border)."""
    out = np.zeros((*image.shape, 4), np.float32)
    out[..., 0] = image
    if gradients:
        gv, gu = np.gradient(image)
        out[..., 1] = gu
        out[..., 2] = gv
    return out


def _level_roi(roi: tuple[int, int, int, int], shape: tuple[int, int], scale: float):
    h, w = shape
    r0 = min(math.floor(roi[0] / scale), h - 1)
    c0 = min(math.floor(roi[2] / scale), w - 1)
    r1 = max(min(math.ceil(roi[1] / scale), h), r0 + 1)
    c1 = max(min(math.ceil(roi[3] / scale), w), c0 + 1)
    return np.array([r0, r1, c0, c1], dtype=np.int64)


def _build_levels(
    image0: NDArray[np.float32], image1: NDArray[np.float32], p: PMBPParams
) -> list[_Level]:
    h, w = image0.shape
    roi = p.roi if p.roi is not None else (0, h, 0, w)
    levels: list[_Level] = []
    a, b = image0, image1
    for lev in range(p.pyramid_levels):
        if lev > 0:
            if min(a.shape) < 2 * max(_MIN_LEVEL_SIZE, 2 * p.patch_radius + 1):
                break  # coarser images are too small for patches: fewer levels
            a, b = cv2.pyrDown(a), cv2.pyrDown(b)
        scale = float(2**lev)
        grads = p.gradient_weight > 0.0
        levels.append(
            _Level(_channels(a, grads), _channels(b, grads), _level_roi(roi, a.shape, scale), scale)
        )
    return levels


def _asw_weights(image: NDArray[np.float32], p: PMBPParams, roi: NDArray[np.int64]):
    """(H, W, (2ρ+1)²) float32 adaptive-support weights from the 3x3-median-filtered image."""
    guide = cv2.medianBlur(image, 3) if min(image.shape) >= 3 else image
    side = 2 * p.patch_radius + 1
    out = np.zeros((*image.shape, side * side), np.float32)
    _k._asw_kernel(guide, p.patch_radius, float(p.asw_gamma), roi, out)
    return out


def _resize_flow(flow: NDArray[np.float32], shape: tuple[int, int]) -> NDArray[np.float32]:
    """Resample a flow field to ``shape`` (bilinear) and rescale its vectors."""
    h, w = shape
    fh, fw = flow.shape[:2]
    out = cv2.resize(flow, (w, h), interpolation=cv2.INTER_LINEAR)
    out[..., 0] *= w / fw
    out[..., 1] *= h / fh
    return np.ascontiguousarray(out, np.float32)


def _config(p: PMBPParams, scale: float, first_level: bool) -> NDArray[np.float64]:
    cfg = np.zeros(_k._CFG_SIZE, np.float64)
    alpha = float(p.gradient_weight)
    maxmot = p.max_motion / scale
    cfg[_k._CFG_ALPHA] = alpha
    cfg[_k._CFG_TAU1] = p.trunc_intensity
    cfg[_k._CFG_TAU2] = p.trunc_gradient
    cfg[_k._CFG_BORDER] = p.border_factor * (
        (1 - alpha) * p.trunc_intensity + alpha * p.trunc_gradient
    )
    cfg[_k._CFG_LAMBDA] = p.pairwise_weight
    cfg[_k._CFG_TRUNC] = p.pairwise_trunc
    cfg[_k._CFG_MAXMOT] = maxmot
    if first_level:
        cfg[_k._CFG_R0] = p.search_radius0 if p.search_radius0 is not None else maxmot / 2
    else:
        cfg[_k._CFG_R0] = p.refine_radius
    cfg[_k._CFG_RMIN] = p.min_search_radius
    cfg[_k._CFG_EARLY] = 1.0 if p.early_termination else 0.0
    cfg[_k._CFG_INIT_RADIUS] = maxmot if first_level else p.refine_radius
    cfg[_k._CFG_INIT_CENTRED] = 0.0 if first_level else 1.0
    cfg[_k._CFG_INSIDE] = 1.0 if p.inside_target else 0.0
    cfg[_k._CFG_SEARCH_BEST] = 1.0 if p.search_best_only else 0.0
    return cfg


def pmbp_flow(
    image0: ArrayLike,
    image1: ArrayLike,
    params: PMBPParams | None = None,
    init: ArrayLike | None = None,
) -> NDArray[np.float32]:
    """Dense flow from ``image0`` to ``image1`` by PatchMatch Belief Propagation (Eq. 1).

    Signature of a :data:`fuse4d.flow.FlowFunction`.

    Parameters
    ----------
    image0, image1 : (H, W) ndarray
        Gray intensity in [0, 1] (converted to float32); the flow lives on ``image0``'s grid.
    params : PMBPParams, optional
        Knobs; None = ``PMBPParams()`` (the paper preset, K = 3).
    init : (H, W, 2) ndarray of float32, optional
        Warm start in px (``[..., 0]`` = du, ``[..., 1]`` = dv), e.g. the previous pair's flow or
        minus the forward flow for a backward solve; it seeds one particle per pixel on every
        pyramid level (resized there). NaN / inf entries are treated as 0.

    Returns
    -------
    flow : (H, W, 2) ndarray of float32
        Displacement in px, ``image0[v, u] ≈ image1[v + dv, u + du]``; 0 outside ``params.roi``.

    Raises
    ------
    ShapeError
        If the images are not 2D of equal shape, or ``init`` is not (H, W, 2).
    ValueError
        Non-finite input.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> img = cv2.GaussianBlur(rng.random((48, 48)).astype(np.float32), (0, 0), 1.5)
    >>> flow = pmbp_flow(img, img, PMBPParams(num_particles=1, num_iter=2))
    >>> float(np.abs(flow).max())
    0.0
    """
    p, a, b, init_arr = _check_inputs(image0, image1, params, init)
    levels, finest = _prepare(a, b, p)
    flow = _solve(levels, p, init_arr, finest)
    return _complete(flow, None, a, b, levels, p, finest)


def pmbp_flow_pair(
    image0: ArrayLike,
    image1: ArrayLike,
    params: PMBPParams | None = None,
    init: ArrayLike | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Forward and backward flow of one pair with two PMBP solves instead of four.

    Equivalent to ``pmbp_flow(image0, image1, params, init)`` and
    ``pmbp_flow(image1, image0, params, -forward)``, except that the consistency check of each
    direction uses the other direction's solve (which the single-direction function has to
    compute for itself). The backward solve is warm-started with minus the (unrefined)
    forward solve (METHOD §2.3). Signature of a :data:`fuse4d.flow.FlowPairFunction`.

    Returns
    -------
    forward : (H, W, 2) ndarray of float32
        Flow from ``image0`` to ``image1`` on ``image0``'s grid, px.
    backward : (H, W, 2) ndarray of float32
        Flow from ``image1`` to ``image0`` on ``image1``'s grid, px.
    """
    p, a, b, init_arr = _check_inputs(image0, image1, params, init)
    levels, finest = _prepare(a, b, p)
    swapped = [_Level(lv.tgt4, lv.src4, lv.roi, lv.scale) for lv in levels]
    forward = _solve(levels, p, init_arr, finest)
    backward = _solve(swapped, p, -forward, finest)
    return (
        _complete(forward, backward, a, b, levels, p, finest),
        _complete(backward, forward, b, a, swapped, p, finest),
    )


def _check_inputs(
    image0: ArrayLike, image1: ArrayLike, params: PMBPParams | None, init: ArrayLike | None
) -> tuple[PMBPParams, NDArray[np.float32], NDArray[np.float32], NDArray[np.float32] | None]:
    p = PMBPParams() if params is None else params
    if not isinstance(p, PMBPParams):
        raise TypeError(f"params must be a PMBPParams, got {type(p).__name__}")
    a = check_image(image0, "image0")
    b = check_image(image1, "image1")
    check_same_shape(a, b, names=("image0", "image1"))
    h, w = a.shape
    init_arr = None
    if init is not None:
        init_arr = as_float32(init, name="init")
        check_shape(init_arr, (h, w, 2), name="init", hint="Warm start must be (H, W, 2) px")
        init_arr = np.nan_to_num(init_arr, nan=0.0, posinf=0.0, neginf=0.0)
    if p.roi is not None and (p.roi[1] > h or p.roi[3] > w):
        raise ParameterError(f"PMBPParams.roi {p.roi} exceeds the image ({h}, {w})")
    return p, a, b, init_arr


def _prepare(
    a: NDArray[np.float32], b: NDArray[np.float32], p: PMBPParams
) -> tuple[list[_Level], int]:
    """Pyramid levels of the (pre-smoothed) pair and the finest level solved."""
    if p.presmooth_sigma > 0.0:
        a = cv2.GaussianBlur(a, (0, 0), p.presmooth_sigma, borderType=cv2.BORDER_REFLECT)
        b = cv2.GaussianBlur(b, (0, 0), p.presmooth_sigma, borderType=cv2.BORDER_REFLECT)
    levels = _build_levels(a, b, p)
    return levels, min(p.finest_level, len(levels) - 1)


def _complete(
    flow: NDArray[np.float32],
    backward: NDArray[np.float32] | None,
    raw0: NDArray[np.float32],
    raw1: NDArray[np.float32],
    levels: list[_Level],
    p: PMBPParams,
    finest: int,
) -> NDArray[np.float32]:
    """Post-steps (A23) at the finest solved level, then up-sampling to full resolution and the
    second refinement there. ``backward``: the opposite direction's solve at that level, or
    None to solve it here when the consistency check needs it."""
    h, w = raw0.shape
    refine = p.variational_refinement_iterations > 0
    if p.consistency_check or refine:
        # post-steps at the finest solved level (see PMBPParams.consistency_check)
        L = levels[finest]
        img0, img1 = raw0, raw1
        for _ in range(finest):
            img0, img1 = cv2.pyrDown(img0), cv2.pyrDown(img1)
        flow = _post_steps(flow, img0, img1, L, levels, p, finest, backward)
    if finest > 0:
        flow = _resize_flow(flow, (h, w))
        r0, r1, c0, c1 = p.roi if p.roi is not None else (0, h, 0, w)
        if p.roi is not None:
            inside = np.zeros((h, w), bool)
            inside[r0:r1, c0:c1] = True
            flow[~inside] = 0.0
        if refine:  # second refinement at full resolution, as DIS refines on every level
            box = (slice(r0, r1), slice(c0, c1))
            flow[box] = _variational_refinement(
                np.ascontiguousarray(raw0[box]),
                np.ascontiguousarray(raw1[box]),
                np.ascontiguousarray(flow[box]),
                p,
            )
    return flow


def _solve(
    levels: list[_Level],
    p: PMBPParams,
    init_arr: NDArray[np.float32] | None,
    finest: int,
) -> NDArray[np.float32]:
    """The PMBP solve proper, coarse to fine down to level ``finest``; the flow (px at that
    level's resolution) is 0 outside the level's roi. ``init_arr`` (any size) is resized to
    every level."""
    flow: NDArray[np.float32] | None = None
    for lev in range(len(levels) - 1, finest - 1, -1):
        L = levels[lev]
        first = flow is None
        if flow is None:
            seeds = [np.zeros((*L.shape, 2), np.float32)]
        else:
            seeds = [_resize_flow(flow, L.shape)]
        if init_arr is not None:
            same = init_arr.shape[:2] == L.shape
            seeds.append(init_arr if same else _resize_flow(init_arr, L.shape))
        n_iter = p.num_iter if lev == finest else p.coarse_num_iter
        if n_iter is None:
            n_iter = p.num_iter
        flow = _solve_level(L, p, np.ascontiguousarray(np.stack(seeds)), lev, first, n_iter)
    assert flow is not None
    return flow


def _post_steps(
    flow: NDArray[np.float32],
    img0: NDArray[np.float32],
    img1: NDArray[np.float32],
    L: _Level,
    levels: list[_Level],
    p: PMBPParams,
    finest: int,
    backward: NDArray[np.float32] | None = None,
) -> NDArray[np.float32]:
    """Forward-backward check + edge-aware fill, then variational refinement, inside the roi of
    level ``finest`` (``img0`` / ``img1``: the unsmoothed images at that level). ``backward``:
    the opposite solve at that level if already known (else solved here)."""
    r0, r1, c0, c1 = (int(v) for v in L.roi)
    box = (slice(r0, r1), slice(c0, c1))
    sub = np.ascontiguousarray(flow[box])
    if p.consistency_check:
        if backward is None:
            swapped = [_Level(lv.tgt4, lv.src4, lv.roi, lv.scale) for lv in levels]
            backward = _solve(swapped, p, -flow, finest)
        valid = _consistent(sub, np.ascontiguousarray(backward[box]), p.consistency_threshold)
        guide = np.ascontiguousarray(L.src4[box][..., 0])
        sub = _fill_inconsistent(sub, valid, guide, p)
    if p.variational_refinement_iterations > 0:
        sub = _variational_refinement(
            np.ascontiguousarray(img0[box]), np.ascontiguousarray(img1[box]), sub, p
        )
    out = flow.copy()
    out[box] = sub
    return out


def _consistent(
    forward: NDArray[np.float32], backward: NDArray[np.float32], threshold: float
) -> NDArray[np.bool_]:
    """(H, W) bool: p + s_fw(p) lands inside the image and |s_fw(p) + s_bw(p + s_fw(p))| <
    ``threshold`` px (``s_bw`` sampled bilinearly)."""
    h, w = forward.shape[:2]
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    x = cols + forward[..., 0]
    y = rows + forward[..., 1]
    back = cv2.remap(backward, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    err2 = np.sum((forward + back) ** 2, axis=-1)
    inside = (x >= 0.0) & (x <= w - 1.0) & (y >= 0.0) & (y <= h - 1.0)
    return inside & (err2 < np.float32(threshold) ** 2)


def _fill_inconsistent(
    flow: NDArray[np.float32],
    valid: NDArray[np.bool_],
    guide: NDArray[np.float32],
    p: PMBPParams,
) -> NDArray[np.float32]:
    """Inconsistent pixels ← edge-aware weighted median of the consistent ones (see
    :class:`PMBPParams` ``consistency_check``)."""
    out = flow.copy()
    if valid.all() or not valid.any():
        return out
    _k._fill_inconsistent_kernel(
        flow,
        np.ascontiguousarray(valid),
        np.ascontiguousarray(guide, np.float32),
        int(p.fill_radius),
        1.0 / float(p.fill_sigma_intensity),
        1.0 / (2.0 * float(p.fill_sigma_space) ** 2),
        out,
    )
    return out


def _variational_refinement(
    image0: NDArray[np.float32],
    image1: NDArray[np.float32],
    flow: NDArray[np.float32],
    p: PMBPParams,
) -> NDArray[np.float32]:
    """``cv2.VariationalRefinement`` (Brox et al. 2004 energy, as in DIS) started from ``flow``,
    on the unsmoothed images quantised to 8 bit (as DIS does); images smaller than 8 px on a
    side are returned unrefined."""
    if min(image0.shape) < 8:
        return flow
    ref = cv2.VariationalRefinement.create()
    ref.setFixedPointIterations(int(p.variational_refinement_iterations))
    ref.setSorIterations(int(p.variational_refinement_sor_iterations))
    ref.setAlpha(float(p.variational_refinement_alpha))
    ref.setGamma(float(p.variational_refinement_gamma))
    ref.setDelta(float(p.variational_refinement_delta))
    out = np.ascontiguousarray(flow, np.float32).copy()
    ref.calc(to_uint8(image0), to_uint8(image1), out)
    return out


def _solve_level(
    L: _Level, p: PMBPParams, seeds: NDArray[np.float32], lev: int, first: bool, n_iter: int
) -> NDArray[np.float32]:
    h, w = L.shape
    k = p.num_particles
    rho = p.patch_radius
    cfg = _config(p, L.scale, first)
    asw = _asw_weights(np.ascontiguousarray(L.src4[..., 0]), p, L.roi)
    lab = np.zeros((h, w, k, 2), np.float32)
    una = np.zeros((h, w, k), np.float32)
    dis = np.zeros((h, w, k), np.float32)
    found = np.zeros((h, w, 4, k), np.float32)
    args = (L.src4, L.tgt4, asw)
    seed = int(p.seed)
    _k._init_kernel(*args, seeds, lab, una, dis, found, rho, cfg, L.roi, seed, lev)
    lam = cfg[_k._CFG_LAMBDA]
    for it in range(n_iter):
        # data-only (PatchMatch) sweeps first on the coarsest level: see ``data_sweeps``
        cfg[_k._CFG_LAMBDA] = 0.0 if first and it < p.data_sweeps else lam
        if p.schedule == "lines":
            for parity in (0, 1):
                _k._sweep_lines_kernel(
                    *args, lab, una, dis, found, rho, cfg, L.roi, seed, lev, it, parity
                )
        elif p.schedule == "sequential":
            _k._sweep_sequential_kernel(*args, lab, una, dis, found, rho, cfg, L.roi, seed, lev, it)
        else:
            for colour in (0, 1):
                _k._sweep_checkerboard_kernel(
                    *args, lab, una, dis, found, rho, cfg, L.roi, seed, lev, it, colour
                )
    out = np.zeros((h, w, 2), np.float32)
    _k._best_label_kernel(lab, dis, L.roi, out)
    return out


def pmbp_flow_fast(
    image0: ArrayLike,
    image1: ArrayLike,
    params: PMBPParams | None = None,
    init: ArrayLike | None = None,
) -> NDArray[np.float32]:
    """:func:`pmbp_flow` with :data:`PMBP_FAST` as the default parameters (``"pmbp-fast"``)."""
    return pmbp_flow(image0, image1, PMBP_FAST if params is None else params, init)


def pmbp_flow_fast_pair(
    image0: ArrayLike,
    image1: ArrayLike,
    params: PMBPParams | None = None,
    init: ArrayLike | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """:func:`pmbp_flow_pair` with :data:`PMBP_FAST` as the default parameters."""
    return pmbp_flow_pair(image0, image1, PMBP_FAST if params is None else params, init)


def register() -> None:
    """Register ``"pmbp"`` (paper preset, K = 3) and ``"pmbp-fast"`` ."""
    register_flow_method(
        FlowMethod(
            name="pmbp",
            function=pmbp_flow,
            pair_function=pmbp_flow_pair,
            params_type=PMBPParams,
            description="PatchMatch Belief Propagation (the paper's tracker, K=3 particles)",
            supports_init=True,
            paper_method=True,
        )
    )
    register_flow_method(
        FlowMethod(
            name="pmbp-fast",
            function=pmbp_flow_fast,
            pair_function=pmbp_flow_fast_pair,
            params_type=PMBPFastParams,
            description="PMBP fast setting: K=1, solved at half resolution, 2 sweeps per level",
            supports_init=True,
            paper_method=True,
        )
    )
