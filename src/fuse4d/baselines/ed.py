"""6D non-rigid motion-field fusion with an embedded-deformation graph (BASELINES §9).

Dou et al., CVPR 2015, on the Embedded Deformation model of Sumner, Schmid, Pauly (SIGGRAPH
2007). A dense ED warp is estimated between each consecutive pair of frames (both directions)
by Gauss–Newton on sparse normal equations (SciPy); the 9 frames of the window are carried to
frame t through the composed pairwise warps and fused by per-pixel projective box fusion.
No maintained Python library exists for ED; Open3D's SLAC is a different model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from .._params import check_int, check_number
from ..camera import Intrinsics, depth_to_points
from ._common import check_inputs, iterate, resolve_noise_sigma
from ._fusion import grid_normals, projective_fuse

__all__ = ["EDWarp", "embedded_deformation", "estimate_ed_warp"]


@dataclass(frozen=True)
class EDWarp:
    """An embedded-deformation warp: nodes g_j (M, 3) mm, affine A_j (M, 3, 3), t_j (M, 3) mm."""

    nodes: NDArray[np.float64]
    affine: NDArray[np.float64]
    translation: NDArray[np.float64]

    def apply(self, points: NDArray, *, k: int = 4) -> NDArray[np.float64]:
        """Warp (N, 3) points (mm): ṽ = Σ_j w_j [A_j (v − g_j) + g_j + t_j] over k nearest nodes."""
        idx, wts = _node_weights(self.nodes, points, k=k)
        return _warp(points, self.nodes, self.affine, self.translation, idx, wts)


def _node_weights(
    nodes: NDArray[np.float64], points: NDArray, *, k: int = 4
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """k nearest nodes and weights w_j = (1 − |v − g_j|/d_max)², d_max = (k+1)-th distance."""
    m = nodes.shape[0]
    kk = min(k + 1, m)
    dist, idx = cKDTree(nodes).query(points, k=kk)
    dist = dist.reshape(len(points), kk)
    idx = idx.reshape(len(points), kk)
    dmax = dist[:, -1:] if kk > k else dist[:, -1:] + 1.0
    use = min(k, kk)
    w = np.clip(1.0 - dist[:, :use] / np.maximum(dmax, 1e-9), 0.0, None) ** 2
    s = w.sum(axis=1, keepdims=True)
    w = np.where(s > 0, w / np.where(s > 0, s, 1.0), 1.0 / use)
    return idx[:, :use], w


def _warp(points, nodes, affine, translation, idx, wts):
    rel = points[:, None, :] - nodes[idx]  # N x k x 3
    moved = np.einsum("nkab,nkb->nka", affine[idx], rel) + nodes[idx] + translation[idx]
    return np.einsum("nk,nka->na", wts, moved)


def _sample_nodes(points: NDArray[np.float64], spacing: float) -> NDArray[np.float64]:
    """ED nodes (M, 3) mm: voxel-grid subsampling, then no two nodes closer than spacing / 2.

    The voxel grid keeps the first point of each ``spacing`` mm cell. A surface lying on a
    cell boundary (the synthetic wall at Z = 1000 mm = 125 × 8 mm, with 0.2 mm noise) fills
    two layers of cells and nearly doubled its nodes (9299 instead of 5707 at 600x600; normal
    equations with 18.2 M instead of 11.1 M non-zeros). [R] greedy thinning in point order.
    """
    _, first = np.unique(np.floor(points / spacing).astype(np.int64), axis=0, return_index=True)
    g = points[np.sort(first)]
    pairs = cKDTree(g).query_pairs(0.5 * spacing, output_type="ndarray")
    keep = np.ones(g.shape[0], dtype=bool)
    for i, j in pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))].tolist():
        if keep[i]:
            keep[j] = False
    return g[keep]


def _rot_residuals(affine: NDArray) -> tuple[NDArray, NDArray]:
    """Rot(A) residuals (M, 6) and their Jacobian (M, 6, 9) w.r.t. row-major A."""
    c = [affine[:, :, i] for i in range(3)]
    pairs = [(0, 1), (0, 2), (1, 2)]
    m = affine.shape[0]
    res = np.empty((m, 6))
    jac = np.zeros((m, 6, 9))
    for r, (i, j) in enumerate(pairs):
        res[:, r] = np.sum(c[i] * c[j], axis=1)
        for a in range(3):
            jac[:, r, 3 * a + i] = c[j][:, a]
            jac[:, r, 3 * a + j] = c[i][:, a]
    for r, i in enumerate(range(3), start=3):
        res[:, r] = np.sum(c[i] * c[i], axis=1) - 1.0
        for a in range(3):
            jac[:, r, 3 * a + i] = 2.0 * c[i][:, a]
    return res, jac


def _prolongation(fine: NDArray[np.float64], coarse: NDArray[np.float64]) -> sp.csr_matrix:
    """The coarse ED graph's unknowns carried to the fine graph's, linearised (12m × 12M).

    A coarse update (δA_k, δt_k) moves fine node j as the coarse warp does:
    δA_j = Σ_k w_k δA_k and δt_j = Σ_k w_k [δA_k (g_j − G_k) + δt_k], over g_j's 4 nearest
    coarse nodes with the warp's own weights (``_node_weights``). Columns of coarse nodes that
    no fine node uses are dropped, so PᵀAP stays positive definite.
    """
    m = fine.shape[0]
    idx, wts = _node_weights(coarse, fine, k=4)
    node = np.repeat(np.arange(m), idx.shape[1])
    near, w = idx.ravel(), wts.ravel()
    rel = fine[node] - coarse[near]
    rows, cols, vals = [], [], []
    for a in range(3):
        for b in range(3):
            rows += [12 * node + 3 * a + b, 12 * node + 9 + a]  # A_j[a, b] and t_j[a] ...
            cols += [12 * near + 3 * a + b] * 2  # ... from A_k[a, b]
            vals += [w, w * rel[:, b]]
        rows.append(12 * node + 9 + a)  # t_j[a] from t_k[a]
        cols.append(12 * near + 9 + a)
        vals.append(w)
    p = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(12 * m, 12 * coarse.shape[0]),
    )
    return p[:, np.unique(p.indices)].tocsr()


def _solve_spd(
    lhs: sp.csr_matrix,
    rhs: NDArray,
    *,
    direct: bool,
    prolongation: sp.csr_matrix | None = None,
    max_iterations: int = 200,
) -> NDArray[np.float64]:
    """Solve the (SPD) GN normal equations; tiny Tikhonov term for unconstrained directions.

    Large systems use conjugate gradients to a relative residual of 1e-3 (inexact
    Gauss–Newton), preconditioned with a 12×12 block Jacobi (per node) plus, where a coarse
    graph is given (``prolongation``), an exact coarse-graph correction P (PᵀAP)⁻¹ Pᵀ
    (additive two-level). Block Jacobi alone did not converge: the regularisation couples the
    nodes like a graph Laplacian, whose smooth modes it cannot reach (150x150 ball, 51588
    unknowns: relative residual 0.2-1.2 after 200 iterations; two-level: 1e-3 after ~40).
    """
    n = lhs.shape[0]
    lhs = (lhs + sp.identity(n, format="csr") * 1e-6).tocsr()
    if direct:
        return _factorise(lhs).solve(rhs)
    # 12x12 block storage: the same matrix, ~2x faster products than CSR (dense block kernel)
    bsr = lhs.tobsr(blocksize=(12, 12))
    block_row = np.repeat(np.arange(n // 12), np.diff(bsr.indptr))
    diagonal = bsr.data[block_row == bsr.indices]  # one per block row (the Tikhonov term)
    inv_blocks = np.linalg.inv(diagonal)
    coarse = None
    if prolongation is not None:
        restriction = prolongation.T.tocsr()
        coarse = (prolongation, restriction, _factorise(restriction @ (lhs @ prolongation)))
    return _pcg(bsr, rhs, inv_blocks, coarse, rtol=1e-3, max_iterations=max_iterations)


def _factorise(spd: sp.spmatrix):
    """SuperLU in symmetric mode (diagonal pivots, A + Aᵀ ordering): an LDLᵀ-like
    factorisation of an SPD system, 9x faster than the default spsolve (measured on the
    5472-unknown coarse ball graph: 0.06 s vs 0.57 s)."""
    return splu(
        spd.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )  # fmt: skip


def _pcg(
    lhs: sp.spmatrix,
    rhs: NDArray,
    inv_blocks: NDArray,
    coarse: tuple | None,
    *,
    rtol: float,
    max_iterations: int,
) -> NDArray[np.float64]:
    """Preconditioned CG with elementwise reductions: block Jacobi (``inv_blocks``) plus the
    coarse correction ``coarse = (P, Pᵀ, factorised PᵀAP)`` where given.

    Written out instead of ``scipy.sparse.linalg.cg`` because its BLAS dot products stall
    under thread oversubscription on busy machines (measured: 18 ms per 12k-element dot).
    """

    def precond(r: NDArray) -> NDArray:
        z = np.einsum("mab,mb->ma", inv_blocks, r.reshape(-1, 12)).ravel()
        if coarse is not None:
            prolongation, restriction, factor = coarse
            z += prolongation @ factor.solve(restriction @ r)
        return z

    x = np.zeros_like(rhs)
    r = rhs.copy()
    z = precond(r)
    p = z.copy()
    rz = float(np.sum(r * z))
    stop = rtol * float(np.sqrt(np.sum(rhs * rhs)))
    for _ in range(max_iterations):
        ap = lhs @ p
        alpha = rz / float(np.sum(p * ap))
        x += alpha * p
        r -= alpha * ap
        if float(np.sqrt(np.sum(r * r))) <= stop:
            break
        z = precond(r)
        rz_new = float(np.sum(r * z))
        p = z + (rz_new / rz) * p
        rz = rz_new
    return x


def estimate_ed_warp(
    source: NDArray[np.float32],
    target: NDArray[np.float32],
    *,
    node_spacing: float = 8.0,
    stride: int = 2,
    outer_iterations: int = 5,
    gauss_newton_iterations: int = 3,
    max_distance: float = 3.0,
    max_normal_angle: float = 30.0,
    direct_limit: int = 24000,
    coarse_spacing: float | None = 32.0,
    normal_step: int = 3,
    cg_iterations: int = 200,
) -> EDWarp:
    """Register the (H, W, 3) point map ``source`` onto ``target`` (mm) with an ED graph.

    Returns the warp that carries source points onto the target surface.

    Notes
    -----
    Energy (Sumner et al.): w_fit Σ_v (n_c·(ṽ − c))² + w_rot Σ_j Rot(A_j) + w_reg Σ_j Σ_k
    |A_j(g_k − g_j) + g_j + t_j − (g_k + t_k)|². Nodes on a voxel grid of ``node_spacing`` mm
    (first source point per cell), 6-NN node graph, 4-NN point weights. Normals from central
    differences over ±``normal_step`` px (±1 px normals are ~10° noisy at 0.2 mm / 0.7 mm px). Correspondences: the
    closest target point within ``max_distance`` mm whose normal is within
    ``max_normal_angle`` degrees, recomputed every outer iteration. The fit and
    regularisation residuals are linear in the unknowns, so JᵀJ of the fit is formed once per
    outer round and that of the regularisation once per solve; Rot's JᵀJ is block diagonal
    (9x9 per node). The normal equations are solved directly (SuperLU in symmetric mode) up to
    ``direct_limit`` unknowns. Larger graphs (a 600x600 frame with its background has ~9300
    nodes: a direct factorisation takes 7 s and 3 GB per solve) are solved coarse to fine: an
    ED graph with ``coarse_spacing`` mm nodes is solved directly first, fine nodes start from
    its warp, and CG (12x12 block storage, at most ``cg_iterations`` iterations, relative
    tolerance 1e-3) refines them, preconditioned by block Jacobi plus an exact correction on
    the coarse graph (two-level, ``_solve_spd``; block Jacobi alone did not converge on the
    global, low-frequency motion). [R] weighting and schedule:
    w_fit = M/N (M nodes, N source points), w_rot = w_reg = 100 at the start, halved when the
    relative energy decrease is < 1e-3, floored at Sumner's defaults w_rot = 1, w_reg = 10.
    """
    src_all = source[::stride, ::stride].reshape(-1, 3).astype(np.float64)
    src_n_all = (
        grid_normals(source, step=normal_step)[::stride, ::stride].reshape(-1, 3).astype(np.float64)
    )
    keep = np.isfinite(src_all).all(axis=1) & np.isfinite(src_n_all).all(axis=1)
    v, vn = src_all[keep], src_n_all[keep]
    tgt = target.reshape(-1, 3).astype(np.float64)
    tgt_n = grid_normals(target, step=normal_step).reshape(-1, 3).astype(np.float64)
    tk = np.isfinite(tgt).all(axis=1) & np.isfinite(tgt_n).all(axis=1)
    tgt, tgt_n = tgt[tk], tgt_n[tk]
    empty = EDWarp(np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)))
    if v.shape[0] < 8 or tgt.shape[0] < 8:
        return empty
    g = _sample_nodes(v, node_spacing)
    m = g.shape[0]
    knn = min(7, m)
    _, nbr = cKDTree(g).query(g, k=knn)
    nbr = nbr.reshape(m, knn)
    edges = np.array([(j, k) for j in range(m) for k in nbr[j, 1:]], dtype=np.int64).reshape(-1, 2)
    idx, wts = _node_weights(g, v, k=4)
    kk = idx.shape[1]
    tree = cKDTree(tgt)
    affine = np.tile(np.eye(3), (m, 1, 1))
    trans = np.zeros((m, 3))
    if 12 * m > direct_limit and coarse_spacing is not None and coarse_spacing > node_spacing:
        coarse = estimate_ed_warp(
            source, target, node_spacing=coarse_spacing, stride=stride,
            outer_iterations=outer_iterations,
            gauss_newton_iterations=gauss_newton_iterations, max_distance=max_distance,
            max_normal_angle=max_normal_angle, direct_limit=direct_limit,
            coarse_spacing=None, normal_step=normal_step, cg_iterations=cg_iterations,
        )  # fmt: skip
        c_idx, c_w = _node_weights(coarse.nodes, g, k=4)
        trans = _warp(g, coarse.nodes, coarse.affine, coarse.translation, c_idx, c_w) - g
        affine = np.einsum("nk,nkab->nab", c_w, coarse.affine[c_idx])
        prolongation = _prolongation(g, coarse.nodes)
    else:
        prolongation = None
    w_fit = m / v.shape[0]
    w_rot = w_reg = 100.0
    cos_max = np.cos(np.deg2rad(max_normal_angle))
    prev_energy = np.inf
    n_unknown = 12 * m
    rel = v[:, None, :] - g[idx]  # N x k x 3
    # regularisation Jacobian: linear and constant, so its normal matrix is formed once
    ne = edges.shape[0]
    dg = g[edges[:, 1]] - g[edges[:, 0]]
    r_rows, r_cols, r_vals = [], [], []
    for a in range(3):
        row = 3 * np.arange(ne) + a
        for b in range(3):
            r_rows.append(row)
            r_cols.append(12 * edges[:, 0] + 3 * a + b)
            r_vals.append(dg[:, b])
        r_rows += [row, row]
        r_cols += [12 * edges[:, 0] + 9 + a, 12 * edges[:, 1] + 9 + a]
        r_vals += [np.ones(ne), -np.ones(ne)]
    j_reg = sp.csr_matrix(
        (np.concatenate(r_vals), (np.concatenate(r_rows), np.concatenate(r_cols))),
        shape=(3 * ne, n_unknown),
    )
    jtj_reg = (j_reg.T @ j_reg).tocsr()
    blk = (12 * np.arange(m))[:, None] + np.arange(9)  # A_j columns of node j
    rot_rows = np.repeat(blk, 9, axis=1).ravel()
    rot_cols = np.tile(blk, (1, 9)).ravel()
    for _ in range(outer_iterations):
        warped = _warp(v, g, affine, trans, idx, wts)
        wn = np.einsum("nk,nkab,nb->na", wts, affine[idx], vn)
        wn /= np.maximum(np.linalg.norm(wn, axis=1, keepdims=True), 1e-12)
        dist, ci = tree.query(warped, distance_upper_bound=max_distance)
        ok = np.isfinite(dist)
        ci_ok = np.where(ok, ci, 0)
        ok &= np.sum(wn * tgt_n[ci_ok], axis=1) > cos_max
        if ok.sum() < 6:
            break
        c, nc = tgt[ci_ok[ok]], tgt_n[ci_ok[ok]]
        p_idx, p_w, p_rel = idx[ok], wts[ok], rel[ok]
        nf = c.shape[0]
        # fit Jacobian (linear in the unknowns): rows nf, entries per node: 9 (A) + 3 (t)
        coef_a = np.einsum("nk,na,nkb->nkab", p_w, nc, p_rel).reshape(nf, kk, 9)
        coef_t = np.einsum("nk,na->nka", p_w, nc)
        cols_a = (12 * p_idx)[:, :, None] + np.arange(9)
        cols_t = (12 * p_idx)[:, :, None] + 9 + np.arange(3)
        rows_f = np.repeat(np.arange(nf), kk * 12)
        cols_f = np.concatenate([cols_a, cols_t], axis=2).ravel()
        vals_f = np.concatenate([coef_a, coef_t], axis=2).ravel()
        j_fit = sp.csr_matrix((vals_f, (rows_f, cols_f)), shape=(nf, n_unknown))
        jtj_fit = (j_fit.T @ j_fit).tocsr()  # constant within the round (linear residual)
        for _ in range(gauss_newton_iterations):
            warped_ok = _warp(v[ok], g, affine, trans, p_idx, p_w)
            r_fit = np.sum(nc * (warped_ok - c), axis=1)
            r_reg = (
                np.einsum("eab,eb->ea", affine[edges[:, 0]], dg)
                + g[edges[:, 0]]
                + trans[edges[:, 0]]
                - g[edges[:, 1]]
                - trans[edges[:, 1]]
            ).ravel()
            r_rot, jr = _rot_residuals(affine)
            # JᵀJ of Rot is block diagonal (9x9 per node, the A_j entries)
            jtj_rot = sp.csr_matrix(
                (np.einsum("mra,mrb->mab", jr, jr).ravel(), (rot_rows, rot_cols)),
                shape=(n_unknown, n_unknown),
            )
            jtr_rot = np.zeros((m, 12))
            jtr_rot[:, :9] = np.einsum("mra,mr->ma", jr, r_rot)
            energy = w_fit * np.sum(r_fit**2) + w_reg * np.sum(r_reg**2) + w_rot * np.sum(r_rot**2)
            lhs = w_fit * jtj_fit + w_reg * jtj_reg + w_rot * jtj_rot
            rhs = -(w_fit * (j_fit.T @ r_fit) + w_reg * (j_reg.T @ r_reg) + w_rot * jtr_rot.ravel())
            delta = _solve_spd(
                lhs.tocsr(), rhs, direct=n_unknown <= direct_limit,
                prolongation=prolongation, max_iterations=cg_iterations,
            ).reshape(m, 12)  # fmt: skip
            affine = affine + delta[:, :9].reshape(m, 3, 3)
            trans = trans + delta[:, 9:]
            if np.isfinite(prev_energy) and (prev_energy - energy) < 1e-3 * prev_energy:
                w_rot = max(w_rot / 2.0, 1.0)
                w_reg = max(w_reg / 2.0, 10.0)
            prev_energy = energy
    return EDWarp(g, affine, trans)


def embedded_deformation(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 4,
    iterations: int = 1,
    node_spacing: float = 8.0,
    band: float | None = None,
    stride: int = 2,
    max_distance: float | None = None,
    noise_sigma: float | None = None,
) -> NDArray[np.float32]:
    """6D non-rigid fusion: pairwise ED warps, then fusion of ±``size`` frames into frame t.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray or None
        Unused (common signature).
    intrinsics : Intrinsics
        Camera.
    size : int, default 4
        ``temporal_radius`` k: frames t−k..t+k (9 frames at the default, truncated at the
        ends).
    iterations : int, default 1
        Repeated application to its own fused depth (z of the fused points).
    node_spacing : float, default 8
        ED node spacing d_node (mm).
    band : float, optional
        Fusion band (mm) around the per-pixel median z; default max(2 mm, 3 σ̂_d) (2 mm on
        the paper's 0.2 mm sensor; on Kinect-class depth a 2 mm band kept only each pixel's
        own sample, and ``ed`` changed 8 % of the pixels of a real room).
    stride : int, default 2
        Source subsampling for the registration (every 2nd pixel).
    max_distance : float, optional
        Largest point-to-plane residual (mm) of a registration correspondence; default
        max(3 mm, 4 σ̂_d).
    noise_sigma : float, optional
        σ̂_d in mm that scales the defaults above; default the noise model max(σ0, q z²) at
        the median depth (:func:`fuse4d.baselines._common.estimate_noise_model`, A22), as
        :func:`~fuse4d.baselines.kinectfusion`'s.

    Returns
    -------
    (T, H, W, 3) ndarray of float32
        Fused points (mm) per frame; NaN where no warped point lands. Holes can be filled by
        the fusion (part of the method).

    Notes
    -----
    [R] fusion (BASELINES §9): frame T's points are carried to t by composing the pairwise
    warps (T → T∓1 → … → t), projected to frame t's nearest pixel, and averaged over the
    points within ``band`` mm of the per-pixel median z.
    """
    d, _ = check_inputs(depth, intensity, intrinsics)
    radius = check_int("embedded_deformation", "size", size, minimum=0)
    check_int("embedded_deformation", "stride", stride, minimum=1)
    check_number("embedded_deformation", "node_spacing", node_spacing, gt=0, finite=True)
    if band is None or max_distance is None:
        sigma_d = resolve_noise_sigma(d, noise_sigma, owner="embedded_deformation")
        band = max(2.0, 3.0 * sigma_d) if band is None else band
        max_distance = max(3.0, 4.0 * sigma_d) if max_distance is None else max_distance
    check_number("embedded_deformation", "band", band, gt=0, finite=True)
    check_number("embedded_deformation", "max_distance", max_distance, gt=0, finite=True)
    n = d.shape[0]

    def fuse(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        pts = depth_to_points(cur, intrinsics)
        forward: dict[int, EDWarp] = {}  # tau -> warp tau -> tau+1
        backward: dict[int, EDWarp] = {}  # tau -> warp tau -> tau-1
        for tau in range(n - 1):
            if radius == 0:
                break
            forward[tau] = estimate_ed_warp(
                pts[tau], pts[tau + 1], node_spacing=node_spacing, stride=stride,
                max_distance=max_distance,
            )  # fmt: skip
            backward[tau + 1] = estimate_ed_warp(
                pts[tau + 1], pts[tau], node_spacing=node_spacing, stride=stride,
                max_distance=max_distance,
            )  # fmt: skip
        out = np.empty((n, *cur.shape[1:], 3), np.float32)
        for t in range(n):
            chunks = []
            for src in range(max(0, t - radius), min(n, t + radius + 1)):
                p = pts[src].reshape(-1, 3).astype(np.float64)
                p = p[np.isfinite(p).all(axis=1)]
                tau = src
                while tau < t:
                    p = forward[tau].apply(p)
                    tau += 1
                while tau > t:
                    p = backward[tau].apply(p)
                    tau -= 1
                chunks.append(p)
            out[t] = projective_fuse(np.concatenate(chunks), intrinsics, band=band)
        return out

    state: dict[str, NDArray[np.float32]] = {}

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        state["points"] = fuse(cur)
        return state["points"][..., 2]

    iterate(step, d, iterations, owner="embedded_deformation")
    return state["points"]
