"""Peak memory of ``fuse4d run`` on PNG-folder input: does it grow with the sequence length?

Writes two frame folders of the 600x600 falling ball (60 and 300 frames; the 60-frame ball
clip is played forwards and backwards so the motion stays continuous), runs
``fuse4d run FOLDER -o OUT --preset fast`` on each in a fresh process, and reports the peak
resident set size of each run (``resource.getrusage(RUSAGE_CHILDREN)``).

Usage: python benchmarks/memory_scaling.py [--frames 60 300] [--workdir DIR]
Target (issue 3): the 300-frame run within 1.3x the 60-frame one, both under 1.5 GB.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from fuse4d.io import FrameFolderWriter
from fuse4d.synthetic import make_falling_ball


def write_folder(path: Path, num_frames: int, clip) -> None:
    order = list(range(clip.num_frames)) + list(range(clip.num_frames - 2, 0, -1))
    with FrameFolderWriter(path, clip.intrinsics, depth_unit_mm=0.02) as writer:
        for k in range(num_frames):
            t = order[k % len(order)]
            writer.write(clip.depth[t], clip.intensity[t])


def peak_rss_of_run(folder: Path, out: Path) -> tuple[float, float]:
    """Run ``fuse4d run`` in a child process; return (peak RSS MiB, seconds)."""
    cmd = [sys.executable, "-m", "fuse4d.cli", "run", str(folder), "-o", str(out), "--force"]
    code = (
        "import resource, subprocess, sys, json, time;"
        "t0 = time.perf_counter();"
        f"r = subprocess.run({cmd!r});"
        "dt = time.perf_counter() - t0;"
        "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0;"
        "print(json.dumps({'rc': r.returncode, 'peak_mib': peak, 'seconds': dt}))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    info = json.loads(res.stdout.strip().splitlines()[-1])
    if info["rc"] != 0:
        raise RuntimeError(f"fuse4d run failed on {folder}: {res.stderr[-2000:]}")
    return info["peak_mib"], info["seconds"]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[60, 300])
    parser.add_argument("--workdir", type=Path, default=None)
    args = parser.parse_args(argv)
    if min(args.frames) < 1:
        parser.error(f"--frames must be >= 1 each, got {' '.join(map(str, args.frames))}")
    work = args.workdir or Path(tempfile.mkdtemp(prefix="fuse4d-mem-"))
    work.mkdir(parents=True, exist_ok=True)
    clip = make_falling_ball(num_frames=60)
    results = {}
    for n in args.frames:
        folder = work / f"ball_{n}"
        if not folder.exists():
            t0 = time.perf_counter()
            write_folder(folder, n, clip)
            print(f"wrote {n} frames in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        peak, seconds = peak_rss_of_run(folder, work / f"fused_{n}")
        results[n] = {
            "peak_rss_mib": round(peak, 1),
            "seconds": round(seconds, 1),
            "ms_per_frame": round(1000 * seconds / n, 1),
        }
        print(f"{n} frames: peak RSS {peak:.0f} MiB, {seconds:.0f} s", file=sys.stderr)
    first, last = args.frames[0], args.frames[-1]
    ratio = results[last]["peak_rss_mib"] / results[first]["peak_rss_mib"]
    print(
        json.dumps(
            {
                "results": results,
                f"ratio_{last}_over_{first}": round(ratio, 3),
                "resource_self_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
