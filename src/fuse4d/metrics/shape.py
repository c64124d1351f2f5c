"""Shape correctness of the synthetic ball (paper Eq. 8; EVALUATION §2): MLESAC sphere fits.

``C = 1 - |r - r_true| / r_true`` with r estimated by MLESAC (Torr & Zisserman 2000).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._kernels.sphere_fit import _mlesac_score_kernel
from .._validation import check_shape
from ..errors import ParameterError, ShapeError
from ..sequence import GroundTruth, Sequence
from ..synthetic import _seed_of
from .roi import ball_truth

__all__ = [
    "ShapeCorrectness",
    "SphereFit",
    "circle_fit_mlesac",
    "shape_correctness",
    "sphere_fit_mlesac",
]

#: Hypotheses whose minimal system has a larger condition number are skipped (EVALUATION §2).
MAX_CONDITION = 1e8
#: Number of EM iterations for the MLESAC mixing weight.
NUM_EM = 5


@dataclass(frozen=True)
class SphereFit:
    """Result of :func:`sphere_fit_mlesac` / :func:`circle_fit_mlesac` (lengths in mm).

    Attributes
    ----------
    center : (D,) ndarray of float64
        Refined centre (D = 3 sphere, 2 circle).
    radius : float
        Refined radius (nonlinear least squares on the inliers).
    minimal_center : (D,) ndarray of float64
        Centre of the best minimal-sample hypothesis (no refinement).
    minimal_radius : float
        Radius of the best minimal-sample hypothesis.
    inlier_fraction : float
        Final EM mixing weight gamma of the best hypothesis.
    num_inliers : int
        Points with inlier posterior z_i > 0.5 (used for the refinement).
    num_points : int
        Points given.
    """

    center: NDArray[np.float64]
    radius: float
    minimal_center: NDArray[np.float64]
    minimal_radius: float
    inlier_fraction: float
    num_inliers: int
    num_points: int


def _check_fit_args(num_hypotheses: int, sigma: float, nu: float) -> None:
    if (
        isinstance(num_hypotheses, bool)
        or int(num_hypotheses) != num_hypotheses
        or (num_hypotheses < 1)
    ):
        raise ParameterError(f"num_hypotheses must be a positive integer, got {num_hypotheses!r}")
    if not (math.isfinite(sigma) and sigma > 0):
        raise ParameterError(f"sigma must be > 0 (mm), got {sigma!r}")
    if not (math.isfinite(nu) and nu > 0):
        raise ParameterError(f"nu must be > 0 (mm), got {nu!r}")


def _fit_mlesac(
    points: ArrayLike,
    dim: int,
    *,
    num_hypotheses: int,
    sigma: float,
    nu: float,
    rng: int | np.random.Generator | None,
) -> SphereFit:
    """MLESAC for a D-sphere (D = 3 sphere, D = 2 circle) with geometric residuals."""
    from scipy import optimize  # here: scipy's import is ~0.3 s that `fuse4d run` never needs

    _check_fit_args(num_hypotheses, sigma, nu)
    name = "points"
    p = np.asarray(points, dtype=np.float64)
    check_shape(p, ("N", dim), name=name)
    p = p[np.all(np.isfinite(p), axis=1)]
    n = p.shape[0]
    if n < dim + 1:
        raise ParameterError(
            f"{name}: a {'sphere' if dim == 3 else 'circle'} fit needs at least {dim + 1} "
            f"finite points, got {n}"
        )
    offset = p.mean(axis=0)
    q = np.ascontiguousarray(p - offset)  # centred: better-conditioned minimal systems
    gen = np.random.default_rng(rng)
    idx = gen.integers(0, n, size=(num_hypotheses, dim + 1))
    sample = q[idx]  # (M, D+1, D)
    a = np.concatenate([sample, np.ones((*sample.shape[:2], 1))], axis=2)  # [x y (z) 1]
    rhs = -np.sum(sample**2, axis=2)
    with np.errstate(all="ignore"):
        cond = np.linalg.cond(a)
    usable = np.isfinite(cond) & (cond <= MAX_CONDITION)
    sol = np.zeros((num_hypotheses, dim + 1))
    if usable.any():
        sol[usable] = np.linalg.solve(a[usable], rhs[usable][..., None])[..., 0]
    centres = -sol[:, :dim] / 2.0
    r2 = np.sum(centres**2, axis=1) - sol[:, dim]
    usable &= r2 > 0
    radii = np.sqrt(np.where(usable, r2, 1.0))
    nll = np.empty(num_hypotheses)
    gamma = np.empty(num_hypotheses)
    _mlesac_score_kernel(
        q, np.ascontiguousarray(centres), radii, usable, float(sigma), float(nu), NUM_EM, nll, gamma
    )
    if not np.isfinite(nll).any():
        raise ParameterError(f"{name}: every MLESAC hypothesis was degenerate ({n} points)")
    best = int(np.argmin(nll))
    c0, r0, g0 = centres[best], float(radii[best]), float(gamma[best])
    # inlier posteriors of the best hypothesis
    e = np.linalg.norm(q - c0, axis=1) - r0
    dens = g0 * np.exp(-(e**2) / (2 * sigma**2)) / (math.sqrt(2 * math.pi) * sigma)
    z = dens / (dens + (1.0 - g0) / nu)
    inl = q[z > 0.5]
    center, radius = c0, r0
    if inl.shape[0] >= dim + 1:

        def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.linalg.norm(inl - x[:dim], axis=1) - x[dim]

        def jacobian(x: NDArray[np.float64]) -> NDArray[np.float64]:
            diff = inl - x[:dim]
            dist = np.maximum(np.linalg.norm(diff, axis=1, keepdims=True), 1e-12)
            return np.concatenate([-diff / dist, -np.ones((inl.shape[0], 1))], axis=1)

        res = optimize.least_squares(residuals, np.append(c0, r0), jac=jacobian, method="lm")
        center, radius = res.x[:dim], float(abs(res.x[dim]))
    return SphereFit(
        center=center + offset,
        radius=float(radius),
        minimal_center=c0 + offset,
        minimal_radius=r0,
        inlier_fraction=g0,
        num_inliers=int(inl.shape[0]),
        num_points=n,
    )


def sphere_fit_mlesac(
    points: ArrayLike,
    *,
    num_hypotheses: int = 500,
    sigma: float = 0.5,
    nu: float = 50.0,
    rng: int | np.random.Generator | None = 0,
) -> SphereFit:
    """Robust sphere fit: MLESAC on 4-point hypotheses, then least-squares refinement.

    Hypotheses: the algebraic sphere through 4 random points (``[x y z 1] (D, E, F, G)^T =
    -(x^2 + y^2 + z^2)``, ``c = -(D, E, F) / 2``, ``r = sqrt(|c|^2 - G)``; degenerate samples
    skipped). Score: ``L = -sum_i log(gamma N(e_i; 0, sigma^2) + (1 - gamma) / nu)`` with
    ``e_i = | |p_i - c| - r |`` and gamma from 5 EM steps. The best hypothesis is refined with
    ``scipy.optimize.least_squares`` on the points whose inlier posterior exceeds 0.5.

    Parameters
    ----------
    points : (N, 3) ndarray
        Points in mm (non-finite rows ignored).
    num_hypotheses : int, optional
        Number of minimal samples H.
    sigma : float, optional
        Inlier noise std (mm).
    nu : float, optional
        Range of the uniform outlier density (mm).
    rng : int or Generator, optional
        Seed of the sampling (use the same seed for every method compared).

    Returns
    -------
    SphereFit

    References
    ----------
    .. [1] P. H. S. Torr and A. Zisserman, "MLESAC: A new robust estimator with application to
       estimating image geometry", CVIU 78:138-156, 2000.

    Examples
    --------
    >>> d = np.random.default_rng(0).normal(size=(500, 3))
    >>> pts = 140.0 * d / np.linalg.norm(d, axis=1, keepdims=True) + [0, 0, 700]
    >>> round(sphere_fit_mlesac(pts).radius, 6)
    140.0
    """
    return _fit_mlesac(points, 3, num_hypotheses=num_hypotheses, sigma=sigma, nu=nu, rng=rng)


def circle_fit_mlesac(
    points: ArrayLike,
    *,
    num_hypotheses: int = 500,
    sigma: float = 0.5,
    nu: float = 50.0,
    rng: int | np.random.Generator | None = 0,
) -> SphereFit:
    """Robust circle fit of ``(N, 2)`` points (mm): :func:`sphere_fit_mlesac` in 2-D.

    Hypotheses are algebraic circles through 3 points. Used for the profile variant of the
    shape correctness.
    """
    return _fit_mlesac(points, 2, num_hypotheses=num_hypotheses, sigma=sigma, nu=nu, rng=rng)


@dataclass(frozen=True)
class ShapeCorrectness:
    """Per-frame shape correctness (Eq. 8) of the ball; C as a fraction (1.0 = 100 %).

    Attributes
    ----------
    c_3d, c_minimal, c_profile : (T,) ndarray of float64
        ``1 - |r - r_true| / r_true`` for the refined 3D fit (primary), the best minimal
        hypothesis, and the 2D circle fit of the profile row (NaN where a fit was impossible).
    radius_3d, radius_minimal, radius_profile : (T,) ndarray of float64
        The estimated radii (mm).
    num_points : (T,) ndarray of int64
        Points used by the 3D fit.
    true_radius : float
        r_true (mm).
    """

    c_3d: NDArray[np.float64]
    c_minimal: NDArray[np.float64]
    c_profile: NDArray[np.float64]
    radius_3d: NDArray[np.float64]
    radius_minimal: NDArray[np.float64]
    radius_profile: NDArray[np.float64]
    num_points: NDArray[np.int64]
    true_radius: float

    def to_dict(self) -> dict[str, float]:
        """Mean and std over frames of the three C values (fractions), JSON friendly."""
        out: dict[str, float] = {}
        for key in ("c_3d", "c_minimal", "c_profile"):
            vals = getattr(self, key)
            vals = vals[np.isfinite(vals)]
            out[f"{key}_mean"] = float(vals.mean()) if vals.size else math.nan
            out[f"{key}_std"] = float(vals.std()) if vals.size else math.nan
        return out


def _disk(radius: int) -> NDArray[np.bool_]:
    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    return xx**2 + yy**2 <= radius**2


def shape_correctness(
    ground_truth: Sequence | GroundTruth,
    points: ArrayLike,
    *,
    true_radius: float | None = None,
    num_hypotheses: int = 500,
    sigma: float = 0.5,
    nu: float = 50.0,
    rng: int | np.random.Generator | None = 0,
    progress: Callable[[int, int], None] | None = None,
) -> ShapeCorrectness:
    """Shape correctness C (paper Eq. 8) of a point-map sequence of the synthetic ball.

    Data per frame t (EVALUATION §2): points of columns ``fit_columns`` (160..440 inclusive at
    full size) and rows ``v_c(t) +- fit_half_rows`` (140 px), valid and inside the GT ball
    mask eroded by ``mask_erosion_px`` (3 px; a Euclidean disk), all read from the scene's
    :class:`~fuse4d.sequence.BallTruth` (the small variant's are scaled by ``pixel_scale``:
    40..110, +-35 px, 1 px). The profile fit uses the row ``round(v_c(t))`` and the in-plane
    coordinates ``(X, sqrt(Y^2 + Z^2))`` of the plane through the camera centre and that row
    (exact; equal to the spec's (X, Z) up to a factor ``sqrt(1 + y_n^2) < 1.002``).

    Parameters
    ----------
    ground_truth : Sequence or GroundTruth
        The ball scene (GT ``mask`` and :class:`~fuse4d.sequence.BallTruth` ``scene`` from
        :func:`~fuse4d.synthetic.make_falling_ball`). Truth first, as in every metric.
    points : (T, H, W, 3) ndarray
        Point maps in mm (e.g. the output of a filter, back-projected).
    true_radius : float, optional
        r_true in mm (default ``scene.radius_mm``, 140).
    num_hypotheses, sigma, nu : optional
        MLESAC settings (500, 0.5 mm, 50 mm), the same for every method.
    rng : int, Generator or None, optional
        Seed; frame t uses ``default_rng([seed, t])`` (a Generator contributes one draw as the
        seed, None fresh entropy).
    progress : callable, optional
        ``callback(done, total)`` after each frame.

    Returns
    -------
    ShapeCorrectness
    """
    from scipy import ndimage  # here: see _fit_mlesac

    if not isinstance(ground_truth, Sequence | GroundTruth):
        raise TypeError(
            "shape_correctness(ground_truth, points): the ground truth comes first, got "
            f"{type(ground_truth).__name__}"
        )
    gt = ground_truth.ground_truth if isinstance(ground_truth, Sequence) else ground_truth
    if gt is None:
        raise ParameterError("shape_correctness needs the falling-ball ground truth")
    ball = ball_truth(gt, what="shape_correctness")
    base_seed = _seed_of(rng)
    p = np.asarray(points, dtype=np.float32)
    check_shape(p, ("T", "H", "W", 3), name="points")
    mask = np.asarray(gt.mask, dtype=bool)
    if mask.shape != p.shape[:3]:
        raise ShapeError("points", (*mask.shape, 3), p.shape, "must match the ground truth")
    rows_c = np.asarray(ball.center_row, dtype=np.float64).reshape(-1)
    c0, c1 = ball.fit_columns
    half = ball.fit_half_rows
    erosion = ball.mask_erosion_px
    r_true = float(true_radius if true_radius is not None else ball.radius_mm)
    num_t, h, w = mask.shape
    out = {k: np.full(num_t, np.nan) for k in ("c3", "cm", "cp", "r3", "rm", "rp")}
    counts = np.zeros(num_t, dtype=np.int64)
    vv = np.arange(h, dtype=np.float64)[:, None]
    uu = np.arange(w)[None, :]
    in_cols = (uu >= c0) & (uu <= c1)
    structure = _disk(erosion)
    for t in range(num_t):
        eroded = ndimage.binary_erosion(mask[t], structure=structure, border_value=0)
        good = eroded & np.all(np.isfinite(p[t]), axis=2)
        sel = good & in_cols & (np.abs(vv - rows_c[t]) <= half)
        pts = p[t][sel]
        counts[t] = pts.shape[0]
        seed = [base_seed, t]
        if pts.shape[0] >= 4:
            try:
                fit = sphere_fit_mlesac(
                    pts, num_hypotheses=num_hypotheses, sigma=sigma, nu=nu, rng=seed
                )
                out["r3"][t], out["rm"][t] = fit.radius, fit.minimal_radius
            except ValueError:
                pass
        row = round(rows_c[t])
        if 0 <= row < h:
            prof = p[t, row][good[row] & in_cols[0]].astype(np.float64)
            if prof.shape[0] >= 3:
                xy = np.stack([prof[:, 0], np.hypot(prof[:, 1], prof[:, 2])], axis=1)
                try:
                    fit2 = circle_fit_mlesac(
                        xy, num_hypotheses=num_hypotheses, sigma=sigma, nu=nu, rng=seed
                    )
                    out["rp"][t] = fit2.radius
                except ValueError:
                    pass
        if progress is not None:
            progress(t + 1, num_t)
    for c, r in (("c3", "r3"), ("cm", "rm"), ("cp", "rp")):
        out[c] = 1.0 - np.abs(out[r] - r_true) / r_true
    return ShapeCorrectness(
        c_3d=out["c3"],
        c_minimal=out["cm"],
        c_profile=out["cp"],
        radius_3d=out["r3"],
        radius_minimal=out["rm"],
        radius_profile=out["rp"],
        num_points=counts,
        true_radius=r_true,
    )
