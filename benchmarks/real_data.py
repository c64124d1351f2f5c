"""fuse4d on the real recordings in ../shared/data (issue 3 "Quality, real" targets).

* ``static_room_rgbd`` (static scene, 12 frames, slightly moving hand-held camera): per-pixel
  temporal flicker (std over time) of raw vs fused depth, on pixels valid in every frame, also
  restricted to planar pixels (walls/floor: default roughness ROI, 5x5 window valid and depth
  range <= 10 mm). The camera turns ~0.13 deg and moves ~1 mm per frame (1-3 px of image
  motion), so a fixed pixel does not see a fixed surface point; the *pose-compensated* flicker
  first re-projects every frame into frame 0 with the recorded camera poses (``rt_cam`` in
  frames.json, camera-to-world, metres) and then takes the per-pixel std.
* ``uva_cv2_person_turning`` (person turning, 100 frames): roughness (Eq. 7, 5x5) on the person
  mask, raw vs fused; and a trail check: in a band of +-6 px around the person's silhouette,
  the fraction of pixels whose fused depth is more than 50 mm from the raw depth (a trail would
  put person depth on background pixels or the reverse), next to the same figure for a plain
  9-frame temporal mean.

Usage: python benchmarks/real_data.py [--data ../shared/data] [--preset fast] [--json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy import ndimage as ndi

from fuse4d import depth_to_points, fuse_sequence, load_sequence, preset
from fuse4d.baselines.temporal import temporal_mean
from fuse4d.metrics import default_roi, roughness_stats, temporal_flicker


def _poses(path: Path) -> list[np.ndarray]:
    root = json.loads((path / "frames.json").read_text())["root"]
    return [np.array(entry["info"]["rt_cam"]["matrix"], dtype=np.float64) for entry in root]


def _to_frame0(depth: np.ndarray, intrinsics, poses: list[np.ndarray]) -> np.ndarray:
    """Re-project each frame's depth into frame 0's pixel grid (z-buffer, nearest pixel)."""
    n, h, w = depth.shape
    out = np.full((n, h, w), np.inf)
    pts = depth_to_points(depth, intrinsics).astype(np.float64) / 1000.0  # metres
    for t in range(n):
        p = pts[t].reshape(-1, 3)
        p = p[np.isfinite(p[:, 2])]
        world = p @ poses[t][:3, :3].T + poses[t][:3, 3]
        cam0 = (world - poses[0][:3, 3]) @ poses[0][:3, :3]
        z = cam0[:, 2] * 1000.0
        u = np.floor(intrinsics.fx * cam0[:, 0] / cam0[:, 2] + intrinsics.cx + 0.5).astype(int)
        v = np.floor(intrinsics.fy * cam0[:, 1] / cam0[:, 2] + intrinsics.cy + 0.5).astype(int)
        ok = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (z > 0)
        np.minimum.at(out[t], (v[ok], u[ok]), z[ok])
    out[~np.isfinite(out)] = np.nan
    return out.astype(np.float32)


def static_room(path: Path, chosen) -> dict:
    seq = load_sequence(path)
    t0 = time.perf_counter()
    res = fuse_sequence(
        seq.depth, seq.intensity, seq.intrinsics, fusion=chosen.fusion, flow=chosen.flow
    )
    seconds = time.perf_counter() - t0
    raw = temporal_flicker(seq.depth)
    fused = temporal_flicker(res.depth)
    planar = default_roi(seq.depth).all(axis=0)
    raw_p = temporal_flicker(seq.depth, static_mask=planar)
    fused_p = temporal_flicker(res.depth, static_mask=planar)
    roi = default_roi(seq.depth)
    poses = _poses(path)[: seq.num_frames]
    raw0 = _to_frame0(seq.depth, seq.intrinsics, poses)
    fused0 = _to_frame0(res.depth, seq.intrinsics, poses)
    planar0 = planar & np.isfinite(raw0).all(axis=0) & np.isfinite(fused0).all(axis=0)
    comp_raw = temporal_flicker(raw0, static_mask=planar0).median
    comp_fused = temporal_flicker(fused0, static_mask=planar0).median
    return {
        "frames": seq.num_frames,
        "pose_compensated_flicker_median_planar_mm": {
            "raw": comp_raw,
            "fused": comp_fused,
            "ratio": comp_fused / comp_raw,
            "pixels": int(planar0.sum()),
        },
        "flicker_median_mm": {
            "raw": raw.median,
            "fused": fused.median,
            "ratio": fused.median / raw.median,
        },
        "flicker_median_planar_mm": {
            "raw": raw_p.median,
            "fused": fused_p.median,
            "ratio": fused_p.median / raw_p.median,
            "pixels": int(planar.sum()),
        },
        "roughness_mm": {
            "raw": roughness_stats(seq.points(), roi=roi).mean,
            "fused": roughness_stats(res.points, roi=roi).mean,
        },
        "support_fraction": res.support_fraction,
        "ms_per_frame": 1000 * seconds / seq.num_frames,
    }


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
    mean9 = temporal_mean(seq.depth, None, seq.intrinsics)
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
            "raw": roughness_stats(seq.points(), roi=roi).mean,
            "fused": roughness_stats(res.points, roi=roi).mean,
            "temporal_mean_9": roughness_stats(
                depth_to_points(mean9, seq.intrinsics), roi=roi
            ).mean,
        },
        "silhouette_band_off_by_50mm": {
            "fused": trail(res.depth),
            "temporal_mean_9": trail(mean9),
            "band_pixels": int(valid.sum()),
        },
        "flicker_median_background_mm": {
            "raw": temporal_flicker(seq.depth, static_mask=~mask.any(axis=0)).median,
            "fused": temporal_flicker(res.depth, static_mask=~mask.any(axis=0)).median,
        },
        "support_fraction": res.support_fraction,
        "ms_per_frame": 1000 * seconds / seq.num_frames,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parents[1]
    parser.add_argument("--data", type=Path, default=here.parent / "shared" / "data")
    parser.add_argument("--preset", default="fast")
    args = parser.parse_args()
    chosen = preset(args.preset)
    out = {"preset": args.preset, "flow": chosen.flow.method}
    room = args.data / "static_room_rgbd"
    if room.is_dir():
        out["static_room_rgbd"] = static_room(room, chosen)
    person_dir = args.data / "uva_cv2_person_turning"
    if person_dir.is_dir():
        out["uva_cv2_person_turning"] = person(person_dir, chosen)
    print(json.dumps(out, indent=2, default=float))


if __name__ == "__main__":
    main()
