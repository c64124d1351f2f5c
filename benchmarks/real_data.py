"""fuse4d on the real recordings in ../shared/data (issue 3 "Quality, real" targets).

* ``static_room_rgbd`` (static scene, 12 frames): per-pixel temporal flicker (std over time)
  of raw vs fused depth, on pixels valid in every frame; also restricted to planar pixels
  (walls/floor: default roughness ROI, 5x5 window valid and depth range <= 10 mm).
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
from fuse4d.evaluation import temporal_mean
from fuse4d.metrics import default_roi, roughness_stats, temporal_flicker


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
    return {
        "frames": seq.num_frames,
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
    mean9 = temporal_mean(seq.depth)
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
