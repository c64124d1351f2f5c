"""Numba kernels of the 6D rigid baseline: a lazily evaluated projective TSDF, ray cast. Private.

The fused truncated signed distance of a window of registered depth frames is evaluated only
where frame t's camera rays need it (no voxel grid), exactly as a dense Curless–Levoy /
KinectFusion volume would hold it at that point: per frame T, ``sdf_T = D_T(π(x_T)) − z_T``
(projective distance, mm) with ``D_T`` looked up bilinearly; frames with ``sdf_T < −trunc`` or
that do not see ``x`` do not contribute; the others contribute ``min(1, sdf_T / trunc)`` with
weight 1 (uniform, no cap). The ray cast returns the first +→− zero crossing along the ray,
linearly interpolated between samples.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit, njit_parallel, prange


@njit
def _lookup_depth(depth, f, uf, vf, depth_jump):
    """Depth (mm) of frame ``f`` at sub-pixel (uf, vf): bilinear, or nearest across a jump.

    Bilinear when the 4 neighbours are valid and span ≤ ``depth_jump`` mm; otherwise the
    nearest pixel's depth (NaN if invalid or outside the image).
    """
    h = depth.shape[1]
    w = depth.shape[2]
    if not (uf > -0.5 and vf > -0.5 and uf < w - 0.5 and vf < h - 0.5):
        return np.nan
    u0 = int(math.floor(uf))
    v0 = int(math.floor(vf))
    if u0 >= 0 and v0 >= 0 and u0 + 1 < w and v0 + 1 < h:
        d00 = depth[f, v0, u0]
        d01 = depth[f, v0, u0 + 1]
        d10 = depth[f, v0 + 1, u0]
        d11 = depth[f, v0 + 1, u0 + 1]
        lo = min(min(d00, d01), min(d10, d11))
        hi = max(max(d00, d01), max(d10, d11))
        # explicit validity test: min/max skip a NaN operand
        if d00 > 0.0 and d01 > 0.0 and d10 > 0.0 and d11 > 0.0 and hi - lo <= depth_jump:
            a = uf - u0
            b = vf - v0
            top = d00 + a * (d01 - d00)
            bottom = d10 + a * (d11 - d10)
            return top + b * (bottom - top)
    ui = int(math.floor(uf + 0.5))
    vi = int(math.floor(vf + 0.5))
    return depth[f, vi, ui]


@njit
def _fused_tsdf(depth, poses, fx, fy, cx, cy, x, y, z, trunc, depth_jump):
    """Fused TSDF at the point (x, y, z) of the reference camera (mm).

    Returns ``(F, weight, min_sdf)``: the mean truncated SDF (in units of ``trunc``), the
    number of contributing frames, and the smallest untruncated SDF (mm) among them.
    """
    acc = 0.0
    weight = 0
    min_sdf = np.inf
    for f in range(depth.shape[0]):
        xt = poses[f, 0, 0] * x + poses[f, 0, 1] * y + poses[f, 0, 2] * z + poses[f, 0, 3]
        yt = poses[f, 1, 0] * x + poses[f, 1, 1] * y + poses[f, 1, 2] * z + poses[f, 1, 3]
        zt = poses[f, 2, 0] * x + poses[f, 2, 1] * y + poses[f, 2, 2] * z + poses[f, 2, 3]
        if not zt > 0.0:
            continue
        d = _lookup_depth(depth, f, fx * xt / zt + cx, fy * yt / zt + cy, depth_jump)
        if not d > 0.0:  # NaN or invalid
            continue
        sdf = d - zt
        if sdf < -trunc:
            continue
        acc += min(1.0, sdf / trunc)
        weight += 1
        min_sdf = min(min_sdf, sdf)
    if weight == 0:
        return 0.0, 0, min_sdf
    return acc / weight, weight, min_sdf


@njit_parallel
def _tsdf_raycast_kernel(
    depth, poses, fx, fy, cx, cy, z_near, z_far, trunc, step, depth_jump, min_weight, out
):
    """Ray cast the lazily fused projective TSDF of ``depth`` from the reference camera.

    Parameters
    ----------
    depth : (F, H, W) float32
        Depth (mm, NaN invalid) of the window's frames.
    poses : (F, 3, 4) float64
        Rigid transforms [R | t] mapping reference-camera points (mm) into frame f's camera.
    fx, fy, cx, cy : float
        Intrinsics (px), shared by all frames.
    z_near, z_far : (H, W) float32
        Per-pixel depth interval (mm) that holds every observed surface along the ray; NaN =
        nothing observed (output NaN). The march starts at ``z_near − 1.5 trunc`` and stops
        after ``z_far + 1.5 trunc``.
    trunc : float
        Truncation distance (mm).
    step : float
        Sample spacing (mm) inside the truncation band (the voxel size of a dense volume).
        In front of every surface (all contributions truncated to +1) the march skips ahead by
        the smallest SDF minus ``trunc``, as KinectFusion's ray caster does.
    depth_jump : float
        Max depth span (mm) of 4 pixels that are interpolated bilinearly.
    min_weight : int
        Samples with fewer contributing frames count as empty (weight threshold).
    out : (H, W) float32
        Depth (mm) of the first +→− zero crossing along each ray; NaN where none.
    """
    h = out.shape[0]
    w = out.shape[1]
    for v in prange(h):
        ry = (v - cy) / fy
        for u in range(w):
            out[v, u] = np.nan
            zn = z_near[v, u]
            zf = z_far[v, u]
            if not (zn > 0.0 and zf > 0.0):
                continue
            rx = (u - cx) / fx
            z = max(zn - 1.5 * trunc, 0.5 * zn)
            z_end = zf + 1.5 * trunc
            prev_f = 0.0
            prev_z = z
            prev_ok = False
            while z <= z_end:
                f_val, wt, min_sdf = _fused_tsdf(
                    depth, poses, fx, fy, cx, cy, rx * z, ry * z, z, trunc, depth_jump
                )
                if wt < min_weight:
                    prev_ok = False
                    z += trunc
                    continue
                if prev_ok and prev_f > 0.0 and f_val <= 0.0:
                    out[v, u] = prev_z + (z - prev_z) * prev_f / (prev_f - f_val)
                    break
                prev_f = f_val
                prev_z = z
                prev_ok = True
                if f_val >= 1.0:  # in front of every surface: skip to the truncation band
                    z += max(step, min_sdf - trunc)
                else:
                    z += step


@njit
def _surface_bounds_kernel(depth, to_ref, fx, fy, cx, cy, z_near, z_far):
    """Nearest / farthest depth (mm) of every frame's points forward-projected into the reference.

    Parameters
    ----------
    depth : (F, H, W) float32
        Depth (mm, NaN invalid) of the window's frames.
    to_ref : (F, 3, 4) float64
        Rigid transforms mapping frame f's camera points into the reference camera (mm).
    fx, fy, cx, cy : float
        Intrinsics (px).
    z_near, z_far : (H, W) float32
        Filled (must be NaN on entry) with the min / max z landing on each pixel (nearest pixel)
        or any of its 8 neighbours; NaN where nothing lands.
    """
    h = z_near.shape[0]
    w = z_near.shape[1]
    for f in range(depth.shape[0]):
        for v in range(h):
            ry = (v - cy) / fy
            for u in range(w):
                d = depth[f, v, u]
                if not d > 0.0:
                    continue
                x = (u - cx) / fx * d
                y = ry * d
                m = to_ref[f]
                xr = m[0, 0] * x + m[0, 1] * y + m[0, 2] * d + m[0, 3]
                yr = m[1, 0] * x + m[1, 1] * y + m[1, 2] * d + m[1, 3]
                zr = m[2, 0] * x + m[2, 1] * y + m[2, 2] * d + m[2, 3]
                if not zr > 0.0:
                    continue
                uc = int(math.floor(fx * xr / zr + cx + 0.5))
                vc = int(math.floor(fy * yr / zr + cy + 0.5))
                for vv in range(max(vc - 1, 0), min(vc + 2, h)):
                    for uu in range(max(uc - 1, 0), min(uc + 2, w)):
                        if not z_near[vv, uu] <= zr:  # also NaN
                            z_near[vv, uu] = zr
                        if not z_far[vv, uu] >= zr:
                            z_far[vv, uu] = zr
