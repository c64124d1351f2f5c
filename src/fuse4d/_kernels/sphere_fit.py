"""Numba kernel of the MLESAC sphere/circle scoring (EVALUATION §2). Private."""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit_parallel, prange


@njit_parallel
def _mlesac_score_kernel(points, centres, radii, usable, sigma, nu, num_em, out_nll, out_gamma):
    """Negative log-likelihood of each sphere hypothesis under the MLESAC mixture.

    ``L = -sum_i log(gamma N(e_i; 0, sigma^2) + (1 - gamma) / nu)`` with geometric residuals
    ``e_i = | |p_i - c| - r |`` and ``gamma`` estimated by ``num_em`` EM steps from 0.5.

    Parameters
    ----------
    points : (N, D) float64
        Data points (mm), D = 3 (sphere) or 2 (circle).
    centres : (M, D) float64
        Hypothesis centres (mm).
    radii : (M,) float64
        Hypothesis radii (mm).
    usable : (M,) bool
        False for degenerate hypotheses (scored +inf).
    sigma, nu : float
        Inlier std (mm) and outlier range (mm).
    num_em : int
        Number of EM iterations for gamma.
    out_nll, out_gamma : (M,) float64
        Filled with L and the final gamma.
    """
    n = points.shape[0]
    d = points.shape[1]
    inv_2s2 = 1.0 / (2.0 * sigma * sigma)
    norm = 1.0 / (math.sqrt(2.0 * math.pi) * sigma)
    outlier = 1.0 / nu
    for m in prange(centres.shape[0]):
        if not usable[m]:
            out_nll[m] = np.inf
            out_gamma[m] = 0.0
            continue
        g = np.empty(n)  # scratch: Gaussian density of each residual
        for i in range(n):
            s = 0.0
            for k in range(d):
                diff = points[i, k] - centres[m, k]
                s += diff * diff
            e = math.sqrt(s) - radii[m]
            g[i] = norm * math.exp(-e * e * inv_2s2)
        gamma = 0.5
        for _ in range(num_em):
            acc = 0.0
            for i in range(n):
                inl = gamma * g[i]
                acc += inl / (inl + (1.0 - gamma) * outlier)
            gamma = acc / n
        nll = 0.0
        for i in range(n):
            nll -= math.log(gamma * g[i] + (1.0 - gamma) * outlier)
        out_nll[m] = nll
        out_gamma[m] = gamma
