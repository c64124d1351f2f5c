"""fuse4d on the real recordings in ../shared/data (issue 3 "Quality, real" targets).

* ``static_room_rgbd`` (static scene, 12 frames, slightly moving hand-held camera): per-pixel
  temporal flicker (std over time; its mean over the pixels is the headline, the median is
  given beside it) of raw vs fused depth, on pixels valid in every frame, also
  restricted to planar pixels (walls/floor: in the default roughness ROI of the raw depth in
  every frame: 5x5 window valid, no step between neighbours above the noise model's limit). The camera turns ~0.13 deg and moves ~1 mm per frame (1-3 px of image
  motion), so a fixed pixel does not see a fixed surface point; the *pose-compensated* flicker
  first warps every frame into frame 0 (backward, bilinear) with the camera poses and then
  takes the per-pixel std. Pose errors add the same flicker to raw and fused, so both the
  recorded poses (``rt_cam`` in frames.json, camera-to-world, metres) and the same poses
  refined by point-to-plane ICP of the raw frames (Open3D, if installed) are reported, over
  all 12 frames and over the frames whose 9-frame window is complete (4..7: a 12-frame clip
  is mostly window ends, unlike a long recording).
* ``uva_cv2_person_turning`` (person turning, 100 frames): roughness (Eq. 7, 5x5) on the person
  mask, raw vs fused; and a trail check: in a band of +-6 px around the person's silhouette,
  the fraction of pixels whose fused depth is more than 50 mm from the raw depth (a trail would
  put person depth on background pixels or the reverse), next to the same figure for a plain
  9-frame temporal mean.

Every figure comes from :func:`fuse4d.metrics.evaluate`, raw and fused on the same pixels.

Usage: python benchmarks/real_data.py [--data ../shared/data] [--preset fast]

Prints the results as JSON (the recordings found in the data folder; an error naming the
folder when it holds neither).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage as ndi

from fuse4d import depth_to_points, fuse_sequence, load_sequence, preset
from fuse4d.baselines.temporal import temporal_mean
from fuse4d.metrics import default_roi, evaluate


def _poses(path: Path) -> list[np.ndarray]:
    root = json.loads((path / "frames.json").read_text())["root"]
    return [np.array(entry["info"]["rt_cam"]["matrix"], dtype=np.float64) for entry in root]


def _warp_to_reference(depth: np.ndarray, intrinsics, poses, ref: int = 0) -> np.ndarray:
    """Every frame's depth seen from frame ``ref``'s pixels (mm), by backward bilinear warping.

    For each pixel of frame ``ref`` a surface point is placed at its 5x5-median raw depth,
    moved into frame t with the camera poses (camera-to-world, metres), frame t's depth is
    sampled bilinearly there (only between 4 valid neighbours spanning < 30 mm, i.e. not across
    depth edges), and the sampled point is moved back into frame ``ref``: its Z is frame t's
    depth at that pixel. Bilinear sampling avoids the +-0.5 px rounding of a nearest-pixel
    z-buffer, which alone adds ~0.3 mm of "flicker" on slanted walls.
    """
    n, h, w = depth.shape
    k = intrinsics
    guess = cv2.medianBlur(np.nan_to_num(depth[ref]).astype(np.float32), 5).astype(np.float64)
    guess[~np.isfinite(depth[ref]) | (guess <= 0)] = np.nan
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    z0 = guess / 1000.0
    x_ref = np.stack([(uu - k.cx) / k.fx * z0, (vv - k.cy) / k.fy * z0, z0], -1)
    out = np.full((n, h, w), np.nan, np.float32)
    t_ref = poses[ref]
    for t in range(n):
        t_t = poses[t]
        x_t = (x_ref @ t_ref[:3, :3].T + t_ref[:3, 3] - t_t[:3, 3]) @ t_t[:3, :3]
        with np.errstate(invalid="ignore", divide="ignore"):
            u = k.fx * x_t[..., 0] / x_t[..., 2] + k.cx
            v = k.fy * x_t[..., 1] / x_t[..., 2] + k.cy
        ok = np.isfinite(u) & np.isfinite(v)
        u0 = np.where(ok, np.floor(u), -1).astype(np.int64)
        v0 = np.where(ok, np.floor(v), -1).astype(np.int64)
        ok &= (u0 >= 0) & (v0 >= 0) & (u0 < w - 1) & (v0 < h - 1)
        u0, v0 = np.clip(u0, 0, w - 2), np.clip(v0, 0, h - 2)
        fu, fv = u - u0, v - v0
        d = depth[t].astype(np.float64)
        corners = np.stack([d[v0, u0], d[v0, u0 + 1], d[v0 + 1, u0], d[v0 + 1, u0 + 1]])
        with np.errstate(invalid="ignore"):
            ok &= np.isfinite(corners).all(0) & (np.ptp(corners, axis=0) < 30.0)
        z = (
            corners[0] * (1 - fu) * (1 - fv)
            + corners[1] * fu * (1 - fv)
            + corners[2] * (1 - fu) * fv
            + corners[3] * fu * fv
        ) / 1000.0
        y_t = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], -1)
        y_ref = (y_t @ t_t[:3, :3].T + t_t[:3, 3] - t_ref[:3, 3]) @ t_ref[:3, :3]
        out[t] = np.where(ok, y_ref[..., 2] * 1000.0, np.nan)
    return out


def _icp_refined_poses(depth: np.ndarray, intrinsics, poses, ref: int = 0):
    """The recorded poses corrected by point-to-plane ICP of each raw frame onto frame ``ref``.

    Open3D (extra ``fuse4d[6d]``); None without it. Clouds voxel-downsampled to 5 mm, normals
    from a 30 mm radius, 15 mm correspondence distance, recorded relative pose as the start.
    Returns (poses, corrections) with corrections as (mm, degrees) per frame.
    """
    try:
        import open3d as o3d
    except ImportError:
        return None
    reg = o3d.pipelines.registration
    pts = depth_to_points(depth, intrinsics).astype(np.float64)

    def cloud(t):
        p = pts[t].reshape(-1, 3)
        c = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p[np.isfinite(p).all(1)]))
        c = c.voxel_down_sample(5.0)
        c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=30.0, max_nn=30))
        return c

    target = cloud(ref)
    refined, corrections = [], []
    for t in range(depth.shape[0]):
        init = np.linalg.inv(poses[ref]) @ poses[t]  # camera t -> camera ref (metres)
        if t == ref:
            refined.append(poses[ref])
            corrections.append((0.0, 0.0))
            continue
        init_mm = init.copy()
        init_mm[:3, 3] *= 1000.0
        result = reg.registration_icp(
            cloud(t),
            target,
            15.0,
            init_mm,
            reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(max_iteration=50),
        )
        rel = np.asarray(result.transformation).copy()
        rel[:3, 3] /= 1000.0
        delta = np.linalg.inv(init) @ rel
        angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
        corrections.append((1000.0 * float(np.linalg.norm(delta[:3, 3])), float(angle)))
        refined.append(poses[ref] @ rel)
    return refined, corrections


def _compensated_flicker(raw, fused, intrinsics, poses, planar, selections) -> list[dict]:
    """Pose-compensated flicker (mean per-pixel std over time, the median beside it), raw vs
    fused, for each frame selection (slices)."""
    raw0 = _warp_to_reference(raw, intrinsics, poses)
    fused0 = _warp_to_reference(fused, intrinsics, poses)
    out = []
    for frames in selections:
        rep = evaluate(fused0, raw=raw0, intrinsics=intrinsics, static=planar, frames=frames)
        a, b = rep.raw.flicker, rep.output.flicker
        out.append(
            {
                "raw": a.mean,
                "fused": b.mean,
                "ratio": b.mean / a.mean,
                "median": {"raw": a.median, "fused": b.median},
                "pixels": a.num_pixels,
            }
        )
    return out


def _pair(report, key: str, **more) -> dict:
    """``{"raw": ..., "fused": ..., "ratio": ...}`` of one flicker statistic of a report."""
    a, b = getattr(report.raw.flicker, key), getattr(report.output.flicker, key)
    return {"raw": a, "fused": b, "ratio": b / a, **more}


def static_room(path: Path, chosen) -> dict:
    seq = load_sequence(path)
    t0 = time.perf_counter()
    res = fuse_sequence(
        seq.depth, seq.intensity, seq.intrinsics, fusion=chosen.fusion, flow=chosen.flow
    )
    seconds = time.perf_counter() - t0
    everything = np.ones(seq.shape, bool)  # a static scene: every pixel is static
    whole = evaluate(res.depth, raw=seq, static=everything)
    planar = whole.roi.all(axis=0)
    flat = evaluate(res.depth, raw=seq, static=planar)
    n = seq.num_frames
    half = chosen.fusion.past_frames
    full = slice(half, n - chosen.fusion.future_frames)  # frames with the whole window
    recorded = _poses(path)[:n]
    out = {"frames": n, "full_window_frames": [full.start, full.stop - 1]}
    poses_by_name = {"recorded": recorded}
    icp = _icp_refined_poses(seq.depth, seq.intrinsics, recorded)
    if icp is not None:
        poses_by_name["icp"] = icp[0]
        out["icp_pose_corrections_mm_deg"] = icp[1]
    selections = {"all_frames": slice(0, n), "full_window_frames": full}
    for name, poses in poses_by_name.items():
        results = _compensated_flicker(
            seq.depth, res.depth, seq.intrinsics, poses, planar, selections.values()
        )
        for label, result in zip(selections, results, strict=True):
            out[f"pose_compensated_flicker_mean_planar_mm[{name} poses, {label}]"] = result
    out.update(
        {
            # the mean per-pixel std is the headline (as fuse4d metrics): the median reads 0
            # mm for quantised depth whose static pixels mostly never leave their level
            "flicker_mean_mm (uncompensated)": _pair(whole, "mean"),
            "flicker_mean_planar_mm (uncompensated)": _pair(
                flat, "mean", pixels=flat.raw.flicker.num_pixels
            ),
            "flicker_median_mm (uncompensated)": _pair(whole, "median"),
            "flicker_median_planar_mm (uncompensated)": _pair(
                flat, "median", pixels=flat.raw.flicker.num_pixels
            ),
            "flicker_step_mean_planar_mm (uncompensated)": _pair(flat, "step_mean"),
            "roughness_mm": {
                "raw": whole.raw.roughness.mean,
                "fused": whole.output.roughness.mean,
                "roi": whole.roi_description,
            },
            "support_fraction": res.support_fraction,
            "ms_per_frame": 1000 * seconds / n,
        }
    )
    return out


def person(path: Path, chosen) -> dict:
    seq = load_sequence(path)
    mask = seq.ground_truth.mask
    t0 = time.perf_counter()
    res = fuse_sequence(
        seq.depth, seq.intensity, seq.intrinsics, fusion=chosen.fusion, flow=chosen.flow
    )
    seconds = time.perf_counter() - t0
    inner = np.stack([ndi.binary_erosion(m, iterations=3) for m in mask])
    roi = inner & default_roi(seq.depth)
    background = ~mask.any(axis=0)
    mean9 = temporal_mean(seq.depth, None, seq.intrinsics)
    # a given ROI restricts every metric, the flicker too: the person ROI for the roughness,
    # the never-masked background (no ROI) for the flicker
    fused = evaluate(res.depth, raw=seq, roi=roi)
    averaged = evaluate(mean9, raw=seq, roi=roi)
    fused_bg = evaluate(res.depth, raw=seq, static=background)
    averaged_bg = evaluate(mean9, raw=seq, static=background)
    band = np.stack(
        [ndi.binary_dilation(m, iterations=6) & ~ndi.binary_erosion(m, iterations=6) for m in mask]
    )
    valid = np.isfinite(seq.depth) & band

    def trail(depth):
        off = np.abs(depth - seq.depth) > 50.0
        return float((off & valid & np.isfinite(depth)).sum() / valid.sum())

    return {
        "frames": seq.num_frames,
        "roughness_person_mm": {
            "raw": fused.raw.roughness.mean,
            "fused": fused.output.roughness.mean,
            "temporal_mean_9": averaged.output.roughness.mean,
        },
        "silhouette_band_off_by_50mm": {
            "fused": trail(res.depth),
            "temporal_mean_9": trail(mean9),
            "band_pixels": int(valid.sum()),
        },
        "flicker_mean_background_mm": {
            "raw": fused_bg.raw.flicker.mean,
            "fused": fused_bg.output.flicker.mean,
            "temporal_mean_9": averaged_bg.output.flicker.mean,
        },
        "flicker_median_background_mm": {
            "raw": fused_bg.raw.flicker.median,
            "fused": fused_bg.output.flicker.median,
        },
        "flicker_step_mean_background_mm": {
            "raw": fused_bg.raw.flicker.step_mean,
            "fused": fused_bg.output.flicker.step_mean,
            "temporal_mean_9": averaged_bg.output.flicker.step_mean,
            "pixels": fused_bg.raw.flicker.num_pixels,
        },
        "support_fraction": res.support_fraction,
        "ms_per_frame": 1000 * seconds / seq.num_frames,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parents[1]
    parser.add_argument("--data", type=Path, default=here.parent / "shared" / "data")
    parser.add_argument("--preset", default="fast")
    args = parser.parse_args(argv)
    room = args.data / "static_room_rgbd"
    person_dir = args.data / "uva_cv2_person_turning"
    if not (room.is_dir() or person_dir.is_dir()):
        parser.error(
            f"--data {args.data}: holds neither static_room_rgbd nor uva_cv2_person_turning"
        )
    chosen = preset(args.preset)
    out = {"preset": args.preset, "flow": chosen.flow.method}
    if room.is_dir():
        out["static_room_rgbd"] = static_room(room, chosen)
    if person_dir.is_dir():
        out["uva_cv2_person_turning"] = person(person_dir, chosen)
    print(json.dumps(out, indent=2, default=float))


if __name__ == "__main__":
    main()
