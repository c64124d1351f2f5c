"""Decode speed and memory of the camera-recording readers (ROS 2 ``.db3`` via rosbags).

Usage::

    python benchmarks/bench_readers.py                       # 200 frames 640x480, 250/2000 small
    python benchmarks/bench_readers.py --frames 500 --long 4000
    python benchmarks/bench_readers.py --kind ros1              # ROS 1 .bag (or mcap)

1. Speed: a synthetic bag with ``--frames`` frames of 640x480 ``mono16`` depth (+ camera_info,
   ``mono8`` infrared) is written with the rosbags writer, then read with
   :func:`fuse4d.io.open_frames` frame by frame (depth float32 mm with NaN, intensity float32
   [0, 1]). Reported: time to open (topic choice + index pass over the bag) and decode
   frames/s of the iteration (target >= 200 fps).
2. Memory: bags of 160x120 frames with ``--short`` and ``--long`` frames are read in a fresh
   subprocess each; the peak RSS of the two must be about equal (flat in length).

Needs the ``sensors`` extra. Temporary bags are written to ``--tmp`` (default: system temp)
and deleted afterwards.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from rosbag_factory import INFO_TOPIC, BagWriter

DEPTH = "/camera/depth/image_rect_raw"
IR = "/camera/infra1/image_rect_raw"


def write_bag(path: Path, frames: int, h: int, w: int, kind: str = "ros2") -> Path:
    """A bag (``kind`` ros1/ros2/mcap) with mono16 depth, camera_info and mono8 IR, 30 fps."""
    rng = np.random.default_rng(0)
    depth = rng.integers(300, 5000, (h, w), dtype=np.uint16)
    ir = rng.integers(0, 256, (h, w), dtype=np.uint8)
    if kind == "ros1":
        path = path.with_suffix(".bag")
    with BagWriter(path, kind) as bag:
        for k in range(frames):
            t = 1_700_000_000 * 10**9 + k * 33_333_333
            bag.write(DEPTH, bag.image(np.roll(depth, k, axis=1), "mono16", t), t)
            bag.write(INFO_TOPIC, bag.camera_info(w, h, t, (380.0, 380.0, w / 2, h / 2)), t)
            bag.write(IR, bag.image(np.roll(ir, k, axis=1), "mono8", t), t)
    return bag.file


def read_all(path: Path) -> dict[str, float]:
    """Open and iterate once; seconds to open, seconds to decode, frames, peak RSS (MiB)."""
    import resource

    from fuse4d.io import open_frames

    t0 = time.perf_counter()
    with open_frames(path, depth_unit_mm=1.0) as reader:
        t1 = time.perf_counter()
        n = 0
        checksum = 0.0
        for frame in reader:
            checksum += float(frame.depth[0, 1]) + float(frame.intensity[0, 1])
            n += 1
        t2 = time.perf_counter()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {"open_s": t1 - t0, "decode_s": t2 - t1, "frames": n, "peak_rss_mib": rss}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=200, help="640x480 frames for the speed")
    parser.add_argument("--short", type=int, default=250, help="short bag (memory), 160x120")
    parser.add_argument("--long", type=int, default=2000, help="long bag (memory), 160x120")
    parser.add_argument(
        "--kind",
        default="ros2",
        choices=("ros2", "ros1", "mcap"),
        help="ros2 (.db3), ros1 (.bag) or mcap",
    )
    parser.add_argument("--tmp", type=Path, default=None, help="folder for the temporary bags")
    parser.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    for name in ("frames", "short", "long"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1, got {getattr(args, name)}")
    if args.child is not None:  # subprocess: read one bag, print JSON
        print(json.dumps(read_all(args.child)))
        return
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        root = Path(tmp)
        big = write_bag(root / "vga", args.frames, 480, 640, args.kind)
        read_all(big)  # warm-up (imports, numba cache)
        r = read_all(big)
        fps = r["frames"] / r["decode_s"]
        size = big.stat().st_size / 2**20
        print(f"640x480 mono16 + mono8 IR, {r['frames']} frames, {size:.0f} MiB {big.suffix}:")
        print(f"  open (topic choice + index pass): {r['open_s']:.2f} s")
        print(f"  decode: {fps:.0f} frames/s ({1000 / fps:.2f} ms/frame), target >= 200")
        rows = []
        for label, n in (("short", args.short), ("long", args.long)):  # distinct names
            bag = write_bag(root / f"small_{label}{n}", n, 120, 160, args.kind)
            out = subprocess.run(
                [sys.executable, __file__, "--child", str(bag)],
                check=True,
                capture_output=True,
                text=True,
            )
            res = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append((n, bag.stat().st_size / 2**20, res))
        print("memory (160x120, fresh process per bag):")
        for n, mib, res in rows:
            print(
                f"  {n:6d} frames ({mib:5.0f} MiB bag): peak RSS {res['peak_rss_mib']:.0f} MiB, "
                f"{res['frames'] / res['decode_s']:.0f} frames/s"
            )
        growth = rows[1][2]["peak_rss_mib"] - rows[0][2]["peak_rss_mib"]
        print(f"  peak RSS growth for {args.long / args.short:.0f}x the length: {growth:+.1f} MiB")


if __name__ == "__main__":
    main()
