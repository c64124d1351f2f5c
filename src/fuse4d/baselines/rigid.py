"""6D rigid motion-field fusion, KinectFusion style: rigid ICP + TSDF (BASELINES §8).

Registration (``icp``): Open3D's point-to-plane ``registration_icp`` (BASELINES §8 LIB;
normals radius 3 mm / 30 nn, 2 mm correspondences, 30 iterations) when ``open3d`` is
installed, else KinectFusion's own projective-association point-to-plane ICP in NumPy
(``icp="auto"``). Measured on the falling ball: at 600x600 both recover the 1.41 mm/frame
(Open3D 1.6 CPU s per pair, NumPy 0.14 s); at the 150x150 CI scale Open3D's 3 mm normal
radius holds only a few 2.8 mm pixels and it recovers 0.35 mm, the NumPy ICP 1.33 mm. Open3D's
result varies by ~1e-15 between runs (threaded reductions); everything after it is
deterministic.

Fusion and ray cast (``backend``):

* ``"projective"`` (what ``"auto"`` runs): the Curless–Levoy projective TSDF of the window's
  registered frames, evaluated lazily along frame t's camera rays by a numba kernel
  (:mod:`fuse4d._kernels.tsdf`): per sample and frame, bilinear depth lookup, SDF truncated at
  2 mm, uniform weight 1 (no cap), mean; the first +→− zero crossing, linearly interpolated, is
  the output depth. This is what ray casting a dense TSDF volume computes, without the
  voxel discretisation (samples every ``voxel_size`` mm inside the truncation band, skipping
  ahead in free space like KinectFusion's caster). A noise-free plane round-trips to < 1e-3
  mm. Pure numba, never hangs. **[R]** (decision A24 in docs/method_notes.md).
* ``"open3d"`` (opt-in): Open3D's ``VoxelBlockGrid`` integrate + ``ray_cast``. **Known issues
  (Open3D 0.20):** a single ray cast covers only 2.5-80 % of the pixels ("Could not generate
  full range map"), ``ray_cast`` hangs intermittently (2 of 8 runs of a 64x48 plane, in the
  first cast, with numba's threads started before Open3D), and the cast has a
  ≈ 0.2 mm floor on a noise-free plane at 0.5 mm voxels (BASELINES demands < 0.05 mm). Kept
  for comparison only.
* ``"box"``: BASELINES §8's documented fallback (per-pixel projective box fusion of the
  window's points in frame t: mean of the points within ±2 mm of the per-pixel median z).
"""

from __future__ import annotations

import importlib.util

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._kernels.tsdf import _surface_bounds_kernel, _tsdf_raycast_kernel
from .._params import check_choice, check_int, check_number
from ..camera import Intrinsics, depth_to_points
from ..errors import ParameterError
from ._common import check_inputs, iterate, resolve_noise_sigma
from ._fusion import apply_rigid, projective_fuse, projective_icp

__all__ = ["have_open3d", "kinectfusion", "rigid_pair_transforms", "tsdf_raycast"]

_BACKENDS = ("auto", "projective", "open3d", "box")
_ICPS = ("auto", "open3d", "projective")


def have_open3d() -> bool:
    """True when ``open3d`` (or ``open3d-cpu``) can be imported."""
    return importlib.util.find_spec("open3d") is not None


def _import_open3d():
    """``import open3d``, after numba has started its worker threads.

    Open3D bundles an old TBB (interface 12050); once it is loaded, numba's first parallel
    launch finds it, rejects it with a ``NumbaWarning`` (an error under the test suite's
    ``filterwarnings = error``) and falls back to OpenMP. Starting numba's threads first
    (``numba.get_num_threads`` does) selects the layer before Open3D's TBB is visible.
    """
    numba.get_num_threads()
    import open3d

    return open3d


#: Most ray-march steps of one pixel across the recording's depth range at one voxel a step
#: (a worst case: the march skips ahead in front of surfaces). Noise-free depth (a 0.0025 mm
#: voxel over 0.5 m: 2e5) runs in seconds; a 1e-9 mm voxel (1e11) or 1e9 truncation voxels
#: ran for hours.
MAX_RAY_STEPS = 10_000_000


def _check_ray_steps(depth: NDArray[np.float32], voxel: float, trunc: float) -> None:
    """Refuse a voxel size so small, or a truncation so wide, that one pixel's ray would take
    more than :data:`MAX_RAY_STEPS` steps across the recording's depth range: ``voxel_size``
    1e-9 mm or ``trunc_voxels`` 1e9 ran for hours in compiled code that no signal but
    SIGKILL stops."""
    finite = depth[np.isfinite(depth)]
    if finite.size == 0:
        return
    span = float(finite.max() - finite.min()) + 3.0 * trunc
    steps = span / voxel
    if not steps <= MAX_RAY_STEPS:
        raise ParameterError(
            f"kinectfusion: voxel_size {voxel:g} mm with a truncation of {trunc:g} mm gives "
            f"{steps:.3g} ray steps across the recording's depth range (at most "
            f"{MAX_RAY_STEPS}); use a larger voxel_size or fewer trunc_voxels"
        )


def _resolve_backend(backend: str) -> str:
    """Fusion backend: "auto" is the numba projective TSDF (it never hangs; module docstring)."""
    check_choice("kinectfusion", "backend", backend, _BACKENDS)
    if backend == "auto":
        return "projective"
    if backend == "open3d" and not have_open3d():
        raise ImportError("backend='open3d' needs open3d: pip install 'fuse4d[6d]'")
    return backend


def _resolve_icp(icp: str) -> str:
    """ICP implementation: "auto" is Open3D's ``registration_icp`` when installed, else NumPy."""
    check_choice("kinectfusion", "icp", icp, _ICPS)
    if icp == "auto":
        return "open3d" if have_open3d() else "projective"
    if icp == "open3d" and not have_open3d():
        raise ImportError("icp='open3d' needs open3d: pip install 'fuse4d[6d]'")
    return icp


def _open3d_icp(
    source: NDArray[np.float32], target: NDArray[np.float32], *, max_distance: float, stride: int
) -> NDArray[np.float64]:
    o3d = _import_open3d()
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
    icp: str = "auto",
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
    icp : {"auto", "open3d", "projective"}
        ICP implementation ("auto": Open3D when installed, else the NumPy projective ICP).
    max_distance : float, default 2
        Maximum correspondence distance (mm).
    stride : int, default 2
        Source subsampling (every ``stride``-th row and column; our choice, for speed).

    Returns
    -------
    (T-1, 4, 4) ndarray of float64
        ``pairs[τ]`` maps points of frame τ+1 into frame τ (T_{τ+1→τ}).
    """
    icp = _resolve_icp(icp)
    pairs = np.empty((max(points.shape[0] - 1, 0), 4, 4))
    for tau in range(points.shape[0] - 1):
        if icp == "open3d":
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
    o3d = _import_open3d()
    o3c = o3d.core

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
    o3d = _import_open3d()
    o3c = o3d.core

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
    o3c = _import_open3d().core

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


def tsdf_raycast(
    depth: NDArray[np.float32],
    to_reference: NDArray[np.float64],
    intrinsics: Intrinsics,
    *,
    truncation: float = 2.0,
    step: float = 0.5,
    depth_jump: float = 10.0,
    min_weight: int = 1,
) -> NDArray[np.float32]:
    """Fuse registered depth frames into a projective TSDF and ray-cast it from the reference.

    The TSDF is evaluated lazily along the reference camera's rays (module docstring), which is
    what a ray cast of a dense Curless–Levoy volume computes, without voxel discretisation.

    Parameters
    ----------
    depth : (F, H, W) ndarray
        Depth frames (mm, NaN = invalid), all seen by ``intrinsics``.
    to_reference : (F, 4, 4) ndarray
        Rigid transforms mapping frame f's camera points (mm) into the reference camera.
    intrinsics : Intrinsics
        Camera of every frame and of the ray cast.
    truncation : float, default 2
        TSDF truncation (mm).
    step : float, default 0.5
        Ray sample spacing inside the truncation band (mm; the voxel size of a dense volume).
    depth_jump : float, default 10
        Four neighbouring depths spanning more than this (mm) are not interpolated (nearest).
    min_weight : int, default 1
        Minimum number of contributing frames of a ray sample (weight threshold).

    Returns
    -------
    (H, W) ndarray of float32
        Depth (mm) of the first +→− zero crossing along each pixel's ray; NaN where the ray
        finds none (or no frame observed anything near it).
    """
    d = np.ascontiguousarray(depth, dtype=np.float32)
    to_ref = np.asarray(to_reference, dtype=np.float64)
    if d.ndim != 3 or to_ref.shape != (d.shape[0], 4, 4):
        raise ParameterError(
            f"depth must be (F, H, W) and to_reference (F, 4, 4); got {d.shape} and {to_ref.shape}"
        )
    if not (truncation > 0 and step > 0):
        raise ParameterError(f"truncation and step must be > 0 mm, got {truncation!r}, {step!r}")
    k = intrinsics
    h, w = k.height, k.width
    from_ref = np.ascontiguousarray(np.linalg.inv(to_ref)[:, :3, :])
    z_near = np.full((h, w), np.nan, np.float32)
    z_far = np.full((h, w), np.nan, np.float32)
    _surface_bounds_kernel(
        d, np.ascontiguousarray(to_ref[:, :3, :]), k.fx, k.fy, k.cx, k.cy, z_near, z_far
    )
    out = np.empty((h, w), np.float32)
    _tsdf_raycast_kernel(
        d, from_ref, k.fx, k.fy, k.cx, k.cy, z_near, z_far,
        float(truncation), float(step), float(depth_jump), int(min_weight), out,
    )  # fmt: skip
    return out


def kinectfusion(
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    *,
    size: int = 4,
    iterations: int = 1,
    backend: str = "auto",
    icp: str = "auto",
    voxel_size: float | None = None,
    trunc_voxels: float = 4.0,
    max_distance: float | None = None,
    icp_stride: int = 2,
    noise_sigma: float | None = None,
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
        ``temporal_radius`` k: frames t−k..t+k (9 frames at the default, truncated at the
        ends).
    iterations : int, default 1
        Repeated application to its own (ray-cast) depth.
    backend : {"auto", "projective", "open3d", "box"}, default "auto"
        TSDF fusion + ray cast: "auto" = "projective" (numba lazy projective TSDF, exact ray
        cast); "open3d" = Open3D ``VoxelBlockGrid`` (opt-in, see the module docstring);
        "box" = BASELINES §8's per-pixel box fallback.
    icp : {"auto", "open3d", "projective"}, default "auto"
        Registration: "auto" = Open3D ``registration_icp`` when installed, else the NumPy
        projective ICP.
    voxel_size : float, optional
        TSDF voxel size (mm); the ray sample spacing of the "projective" backend. Default
        2.5 σ̂_d (0.5 mm on the paper's 0.2 mm sensor, ~50 mm for a Kinect at 3.5 m).
    trunc_voxels : float, default 4
        Truncation in voxels (10 σ̂_d at the default voxel size); also the "box" z band.
    max_distance : float, optional
        ICP maximum correspondence distance (mm); default 10 σ̂_d (2 mm on the paper's
        sensor).
    icp_stride : int, default 2
        ICP source subsampling (our choice, for speed).
    noise_sigma : float, optional
        σ̂_d in mm that scales the defaults above; default the noise model max(σ0, q z²) at
        the median depth (:func:`fuse4d.baselines._common.estimate_noise_model`, A22).

    Returns
    -------
    (T, H, W, 3) ndarray of float32
        Fused points (mm) in each frame's camera; NaN where the ray finds no surface. Holes of
        the raw depth can be filled by the fusion (part of the method).

    Notes
    -----
    Open3D ICP: ``registration_icp`` (point-to-plane, normals radius 3 mm / 30 nn, 30
    iterations). T_{T→t} is composed from the consecutive-pair transforms.
    """
    d, _ = check_inputs(depth, intensity, intrinsics)
    radius = check_int("kinectfusion", "size", size, minimum=0)
    check_int("kinectfusion", "icp_stride", icp_stride, minimum=1)
    if voxel_size is None or max_distance is None:
        sigma_d = resolve_noise_sigma(d, noise_sigma, owner="kinectfusion")
        voxel_size = 2.5 * sigma_d if voxel_size is None else voxel_size
        max_distance = 10.0 * sigma_d if max_distance is None else max_distance
    check_number("kinectfusion", "voxel_size", voxel_size, gt=0, finite=True)
    check_number("kinectfusion", "trunc_voxels", trunc_voxels, gt=0, finite=True)
    check_number("kinectfusion", "max_distance", max_distance, gt=0, finite=True)
    _check_ray_steps(d, float(voxel_size), float(trunc_voxels) * float(voxel_size))
    resolved = _resolve_backend(backend)
    resolved_icp = _resolve_icp(icp)
    trunc = float(trunc_voxels) * float(voxel_size)
    n = d.shape[0]

    def step(cur: NDArray[np.float32]) -> NDArray[np.float32]:
        points = depth_to_points(cur, intrinsics)
        pairs = rigid_pair_transforms(
            points, intrinsics, icp=resolved_icp, max_distance=max_distance, stride=icp_stride
        )
        out = np.empty_like(cur)
        for t in range(n):
            lo, hi = max(0, t - radius), min(n - 1, t + radius)
            transforms = _window_transforms(pairs, t, lo, hi)
            if resolved == "projective":
                frames = sorted(transforms)
                out[t] = tsdf_raycast(
                    cur[frames], np.stack([transforms[f] for f in frames]), intrinsics,
                    truncation=trunc, step=float(voxel_size),
                )  # fmt: skip
            elif resolved == "open3d":
                out[t] = _tsdf_frame(
                    cur, intrinsics, transforms, t,
                    voxel_size=float(voxel_size), trunc_voxels=float(trunc_voxels),
                )  # fmt: skip
            else:
                pts = np.concatenate(
                    [apply_rigid(m, points[tau].reshape(-1, 3)) for tau, m in transforms.items()]
                )
                out[t] = projective_fuse(pts, intrinsics, band=trunc)[..., 2]
        return out

    fused_depth = iterate(step, d, iterations, owner="kinectfusion")
    return depth_to_points(fused_depth, intrinsics)
