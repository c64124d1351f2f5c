"""6D rigid motion-field fusion, KinectFusion style: rigid ICP + TSDF (BASELINES §8).

Two backends:

* ``"open3d"``: point-to-plane ``registration_icp`` and a ``VoxelBlockGrid`` TSDF with
  ``ray_cast`` (optional extra ``fuse4d[6d]``). **Known issue (Open3D 0.20):** a single ray cast
  covers only 2.5-80 % of the pixels ("Could not generate full range map"), and the second
  cast that fixes it hangs intermittently (about every second run of
  ``tests/test_baselines.py::test_nan_holes_do_not_spread[kinectfusion]``, also with
  ``OMP_NUM_THREADS=1``). It is therefore opt-in.
* ``"projective"`` (what ``"auto"`` runs): KinectFusion's projective-association point-to-plane
  ICP in NumPy, and per-pixel projective box fusion in frame t (a TSDF with box weights
  evaluated along frame-t rays, BASELINES §8's documented fallback). Label results as such.
"""

from __future__ import annotations

import importlib.util

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import Intrinsics, depth_to_points
from ._common import check_inputs, check_positive_int, iterate
from ._fusion import apply_rigid, projective_fuse, projective_icp

__all__ = ["have_open3d", "kinectfusion", "rigid_pair_transforms"]


def have_open3d() -> bool:
    """True when ``open3d`` (or ``open3d-cpu``) can be imported."""
    return importlib.util.find_spec("open3d") is not None


def _resolve_backend(backend: str) -> str:
    if backend not in ("auto", "open3d", "projective"):
        raise ValueError(f"backend must be 'auto', 'open3d' or 'projective', got {backend!r}")
    if backend == "auto":  # Open3D's ray cast can hang (module docstring): opt-in only
        return "projective"
    if backend == "open3d" and not have_open3d():
        raise ImportError("backend='open3d' needs open3d: pip install 'fuse4d[6d]'")
    return backend


def _open3d_icp(
    source: NDArray[np.float32], target: NDArray[np.float32], *, max_distance: float, stride: int
) -> NDArray[np.float64]:
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = source[::stride, ::stride].reshape(-1, 3)
    tgt = target.reshape(-1, 3)
    src = src[np.isfinite(src).all(axis=1)].astype(np.float64)
    tgt = tgt[np.isfinite(tgt).all(axis=1)].astype(np.float64)
    if src.shape[0] < 6 or tgt.shape[0] < 6:
        return np.eye(4)
    pcd_s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src))
    pcd_t = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tgt))
    pcd_t.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3.0, max_nn=30))
    result = reg.registration_icp(
        pcd_s,
        pcd_t,
        max_correspondence_distance=max_distance,
        init=np.eye(4),
        estimation_method=reg.TransformationEstimationPointToPlane(),
        criteria=reg.ICPConvergenceCriteria(
            relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=30
        ),
    )
    return np.asarray(result.transformation, dtype=np.float64)


def rigid_pair_transforms(
    points: NDArray[np.float32],
    intrinsics: Intrinsics,
    *,
    backend: str = "auto",
    max_distance: float = 2.0,
    stride: int = 2,
) -> NDArray[np.float64]:
    """Rigid ICP between consecutive frames.

    Parameters
    ----------
    points : (T, H, W, 3) ndarray
        Point maps (mm).
    intrinsics : Intrinsics
        Camera (used by the projective fallback).
    backend : {"auto", "open3d", "projective"}
        ICP implementation.
    max_distance : float, default 2
        Maximum correspondence distance (mm).
    stride : int, default 2
        Source subsampling (every ``stride``-th row and column; our choice, for speed).

    Returns
    -------
    (T-1, 4, 4) ndarray of float64
        ``pairs[τ]`` maps points of frame τ+1 into frame τ (T_{τ+1→τ}).
    """
    backend = _resolve_backend(backend)
    pairs = np.empty((max(points.shape[0] - 1, 0), 4, 4))
    for tau in range(points.shape[0] - 1):
        if backend == "open3d":
            pairs[tau] = _open3d_icp(
                points[tau + 1], points[tau], max_distance=max_distance, stride=stride
            )
        else:
            pairs[tau] = projective_icp(
                points[tau + 1], points[tau], intrinsics, max_distance=max_distance, stride=stride
            )
    return pairs


def _window_transforms(pairs: NDArray[np.float64], t: int, lo: int, hi: int) -> dict:
    """T_{T→t} for T in [lo, hi] from consecutive T_{τ+1→τ}."""
    out = {t: np.eye(4)}
    acc = np.eye(4)
    for tau in range(t + 1, hi + 1):  # T > t: T_{T→t} = P[t] @ ... @ P[T-1]
        acc = acc @ pairs[tau - 1]
        out[tau] = acc.copy()
    acc = np.eye(4)
    for tau in range(t - 1, lo - 1, -1):  # T < t: inverse of P[T] @ ... @ P[t-1]
        acc = pairs[tau] @ acc
        out[tau] = np.linalg.inv(acc)
    return out


def _tsdf_frame(
    depth: NDArray[np.float32],
    intrinsics: Intrinsics,
    transforms: dict,
    t: int,
    *,
    voxel_size: float,
    trunc_voxels: float,
) -> NDArray[np.float32]:
    import open3d as o3d
    import open3d.core as o3c

    h, w = intrinsics.height, intrinsics.width
    k = o3c.Tensor(intrinsics.matrix, dtype=o3c.float64)
    valid = np.isfinite(depth[sorted(transforms)])
    if not valid.any():
        return np.full((h, w), np.nan, np.float32)
    zs = depth[sorted(transforms)][valid]
    depth_max = float(zs.max()) * 1.5 + 10.0 * voxel_size
    depth_min = max(float(zs.min()) * 0.5, 1e-3)
    area = float(np.median(zs) / intrinsics.fx) ** 2 * h * w
    block_mm = 16 * voxel_size
    block_count = int(min(max(4 * area / block_mm**2, 1000), 200_000))  # ~2 layers x motion
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight"),
        attr_dtypes=(o3c.float32, o3c.float32),
        attr_channels=((1), (1)),
        voxel_size=voxel_size,
        block_resolution=16,
        block_count=block_count,
        device=o3c.Device("CPU:0"),
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        _integrate_all(vbg, depth, k, transforms, depth_max, trunc_voxels)
        out = _cast_depth(vbg, k, w, h, depth_min, depth_max, trunc_voxels)
    out[~(out > 0)] = np.nan
    return out


def _integrate_all(vbg, depth, k, transforms, depth_max, trunc_voxels) -> None:
    import open3d as o3d
    import open3d.core as o3c

    for tau, t_to_ref in sorted(transforms.items()):
        img = o3d.t.geometry.Image(
            o3c.Tensor(np.ascontiguousarray(np.nan_to_num(depth[tau], nan=0.0)))
        )
        extr = o3c.Tensor(np.linalg.inv(t_to_ref), dtype=o3c.float64)
        coords = vbg.compute_unique_block_coordinates(
            img, k, extr, depth_scale=1.0, depth_max=depth_max, trunc_voxel_multiplier=trunc_voxels
        )
        vbg.integrate(
            coords, img, k, extr, depth_scale=1.0, depth_max=depth_max,
            trunc_voxel_multiplier=trunc_voxels,
        )  # fmt: skip


def _cast_depth(vbg, k, w, h, depth_min, depth_max, trunc_voxels) -> NDArray[np.float32]:
    import open3d.core as o3c

    def cast() -> NDArray[np.float32]:
        result = vbg.ray_cast(
            block_coords=vbg.hashmap().key_tensor(),
            intrinsic=k,
            extrinsic=o3c.Tensor(np.eye(4), dtype=o3c.float64),
            width=w,
            height=h,
            render_attributes=["depth"],
            depth_scale=1.0,
            depth_min=depth_min,
            depth_max=depth_max,
            weight_threshold=1.0,
            trunc_voxel_multiplier=trunc_voxels,
            range_map_down_factor=8,
        )
        return result["depth"].numpy().reshape(h, w).astype(np.float32)

    # Open3D 0.20: a ray cast whose range-map fragment buffer is too small ("Could not
    # generate full range map") returns only a few hits, and resizes the buffer for the next
    # call (measured: 2.5 % then 98.5 % of pixels at 600x600). So cast twice; keep the better.
    first = cast()
    second = cast()
    return second if np.count_nonzero(second > 0) >= np.count_nonzero(first > 0) else first


def kinectfusion(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 4,
    iterations: int = 1,
    backend: str = "auto",
    voxel_size: float = 0.5,
    trunc_voxels: float = 4.0,
    max_distance: float = 2.0,
    icp_stride: int = 2,
) -> NDArray[np.float32]:
    """6D rigid fusion: consecutive-frame rigid ICP, TSDF fusion of ±``size`` frames, ray cast.

    Parameters
    ----------
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray or None
        Unused (common signature).
    intrinsics : Intrinsics
        Camera.
    size : int, default 4
        Temporal radius (window 2·size+1 = 9 frames, truncated at the ends).
    iterations : int, default 1
        Repeated application to its own (ray-cast) depth.
    backend : {"auto", "open3d", "projective"}, default "auto"
        "auto" = "projective" (NumPy fallback); "open3d" is opt-in (see the module docstring).
    voxel_size : float, default 0.5
        TSDF voxel size (mm).
    trunc_voxels : float, default 4
        Truncation in voxels (2 mm at the default voxel size); also the fallback's z band.
    max_distance : float, default 2
        ICP maximum correspondence distance (mm).
    icp_stride : int, default 2
        ICP source subsampling (our choice, for speed).

    Returns
    -------
    (T, H, W, 3) ndarray of float32
        Fused points (mm) in each frame's camera; NaN where the ray finds no surface. Holes of
        the raw depth can be filled by the fusion (part of the method).

    Notes
    -----
    Open3D path: ``registration_icp`` (point-to-plane, normals radius 3 mm / 30 nn, 30
    iterations), ``VoxelBlockGrid`` (uniform weight 1, no cap), ``ray_cast`` from frame t.
    """
    d, _ = check_inputs(depth, intensity, intrinsics)
    radius = check_positive_int(size, name="size", minimum=0)
    check_positive_int(icp_stride, name="icp_stride")
    if not float(voxel_size) > 0:
        raise ValueError(f"voxel_size must be > 0 mm, got {voxel_size!r}")
    resolved = _resolve_backend(backend)
    n = d.shape[0]

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        points = depth_to_points(cur, intrinsics)
        pairs = rigid_pair_transforms(
            points, intrinsics, backend=resolved, max_distance=max_distance, stride=icp_stride
        )
        out = np.empty_like(cur)
        for t in range(n):
            lo, hi = max(0, t - radius), min(n - 1, t + radius)
            transforms = _window_transforms(pairs, t, lo, hi)
            if resolved == "open3d":
                out[t] = _tsdf_frame(
                    cur, intrinsics, transforms, t,
                    voxel_size=float(voxel_size), trunc_voxels=float(trunc_voxels),
                )  # fmt: skip
            else:
                pts = np.concatenate(
                    [apply_rigid(m, points[tau].reshape(-1, 3)) for tau, m in transforms.items()]
                )
                fused = projective_fuse(pts, intrinsics, band=float(trunc_voxels * voxel_size))
                out[t] = fused[..., 2]
        return out

    fused_depth = iterate(step, d, iterations)
    return depth_to_points(fused_depth, intrinsics)
