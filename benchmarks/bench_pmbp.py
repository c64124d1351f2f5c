"""PMBP benchmark: speed (600x600), accuracy on the synthetic ball and on Middlebury, schedules.

Run (takes a few minutes on 2 cores)::

    python benchmarks/bench_pmbp.py                  # everything
    python benchmarks/bench_pmbp.py --only speed     # speed / compile time only
    python benchmarks/bench_pmbp.py --cold           # also measure numba compile time

Measures
--------
- numba compile time (``--cold``: a fresh ``NUMBA_CACHE_DIR`` in a subprocess) and the
  cached first-call time;
- wall time of one 600x600 forward flow (ball pair 10-11, σ_I 2 %), median of ``--repeat``
  runs, for ``pmbp`` (paper preset, K = 3) and ``pmbp-fast``, with their ball EPE;
- ball-interior EPE (exact image motion (0, speed·Z_c/Z), see ``fuse4d.experiments.flow_accuracy``) at
  σ_I = 2 % and 10 % on pairs (10, 11) and (25, 26), and the forward-backward pass rate
  (|s_fw(p) + s_bw(p + s_fw(p))| < 1 px) at 2 %;
- Middlebury EPE (4 real pairs, unknown GT excluded) for pmbp, pmbp-fast (``max_motion`` 16,
  because Hydrangea moves 11 px), the same before decision A23 (``PRE_A23``: no
  forward-backward fill / variational refinement, λ 0.05, r_min 0.05 px), OpenCV DIS (medium)
  and Dual TV-L1;
- the parallel schedules ("lines", red-black "parallel") vs the reference sequential schedule
  on a 200x200 crop of the ball.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from fuse4d.experiments.flow_accuracy import ball_pairs, middlebury_pairs
from fuse4d.flow import estimate_flow
from fuse4d.flow.opencv import DISParams
from fuse4d.flow.pmbp import PMBPFastParams, PMBPParams, pmbp_flow

DATA = Path(os.environ.get("FUSE4D_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))

#: The settings before decision A23 (docs/method_notes.md): λ = 0.05, r_min = 0.05 px, no
#: forward-backward fill, no variational refinement -- for before/after rows.
PRE_A23 = {
    "pairwise_weight": 0.05,
    "min_search_radius": 0.05,
    "consistency_check": False,
    "variational_refinement_iterations": 0,
}


def _epe(flow, pair) -> float:
    err = np.hypot(*(flow - pair.flow_true).transpose(2, 0, 1))
    return float(err[pair.mask].mean())


def _fb_pass(fw, bw, mask, threshold=1.0) -> float:
    h, w = mask.shape
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    back = cv2.remap(bw, cols + fw[..., 0], rows + fw[..., 1], cv2.INTER_LINEAR)
    err = np.hypot(*(fw + back).transpose(2, 0, 1))
    return float((err[mask] < threshold).mean())


def _timed(fn, repeat):
    """(result, median wall s, wall times, median process CPU s summed over threads)."""
    times, cpu = [], []
    out = None
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        out = fn()
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return out, statistics.median(times), times, statistics.median(cpu)


def bench_compile() -> None:
    code = (
        "import time, numpy as np; t = time.perf_counter(); "
        "from fuse4d.flow.pmbp import pmbp_flow, PMBPParams; "
        "a = np.random.default_rng(0).random((64, 64)).astype(np.float32); "
        "pmbp_flow(a, a, PMBPParams()); "
        "pmbp_flow(a, a, PMBPParams(schedule='sequential')); "
        "print(f'{time.perf_counter() - t:.1f}')"
    )
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        cold = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False
        )
        warm = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False
        )
    print(f"compile (import + first call, empty numba cache): {cold.stdout.strip()} s")
    print(f"first call with the numba cache filled:           {warm.stdout.strip()} s")


def bench_speed(repeat: int) -> None:
    pair = ball_pairs(intensity_noise=0.02)[0]
    print(f"\n600x600 forward flow, ball pair {pair.name}, σ_I 2 %, median of {repeat}")
    print(f"load average before: {os.getloadavg()[0]:.1f} (the machine may be shared)")
    print("| method | params | wall s (median) | runs | CPU s (median) | EPE px |")
    print("|---|---|---|---|---|---|")
    configs = (
        ("pmbp", PMBPParams()),
        ("pmbp-fast", PMBPFastParams()),
        ("pmbp pre-A23", PMBPParams(**PRE_A23)),
        ("pmbp-fast pre-A23", PMBPFastParams(**PRE_A23)),
    )
    for name, params in configs:
        pmbp_flow(pair.image0[:64, :64], pair.image1[:64, :64], params)  # compile / warm up
        flow, med, times, cpu = _timed(
            lambda p=params: pmbp_flow(pair.image0, pair.image1, p), repeat
        )
        runs = ", ".join(f"{t:.2f}" for t in times)
        epe = _epe(flow, pair)
        print(f"| {name} | K={params.num_particles} | {med:.2f} | {runs} | {cpu:.2f} | {epe:.3f} |")


def bench_ball() -> None:
    print("\nball interior EPE (px) and FB pass rate")
    print("| method | σ_I | pair | EPE | FB pass (<1 px) |")
    print("|---|---|---|---|---|")
    for noise in (0.02, 0.10):
        for pair in ball_pairs(intensity_noise=noise):
            for name, params in (("pmbp", PMBPParams()), ("pmbp-fast", PMBPFastParams())):
                fw = pmbp_flow(pair.image0, pair.image1, params)
                fb = ""
                if noise == 0.02:
                    bw = pmbp_flow(pair.image1, pair.image0, params, -fw)
                    fb = f"{100 * _fb_pass(fw, bw, pair.mask):.1f} %"
                print(f"| {name} | {noise:.0%} | {pair.name} | {_epe(fw, pair):.3f} | {fb} |")


def bench_middlebury(baselines: bool) -> None:
    pairs, reason = middlebury_pairs(DATA / "middlebury_flow")
    if not pairs:
        print(f"\nMiddlebury skipped: {reason}")
        return
    entries = [
        ("pmbp", "pmbp", PMBPParams(max_motion=16.0)),
        ("pmbp-fast", "pmbp-fast", PMBPFastParams(max_motion=16.0)),
        ("pmbp pre-A23", "pmbp", PMBPParams(max_motion=16.0, **PRE_A23)),
        ("pmbp-fast pre-A23", "pmbp-fast", PMBPFastParams(max_motion=16.0, **PRE_A23)),
    ]
    if baselines:
        entries += [("dis-medium", "dis", DISParams.from_preset("medium")), ("tvl1", "tvl1", None)]
    print("\nMiddlebury EPE (px); time = one forward flow")
    print("| method | " + " | ".join(p.name for p in pairs) + " | mean |")
    print("|---|" + "---|" * (len(pairs) + 1))
    for label, method, params in entries:
        cells, epes = [], []
        for pair in pairs:
            start = time.perf_counter()
            flow = estimate_flow(pair.image0, pair.image1, method=method, params=params)
            sec = time.perf_counter() - start
            epes.append(_epe(flow, pair))
            cells.append(f"{epes[-1]:.3f} ({sec:.1f} s)")
        print(f"| {label} | " + " | ".join(cells) + f" | {np.mean(epes):.3f} |")


def bench_schedules() -> None:
    pair = ball_pairs(intensity_noise=0.02)[0]
    crop = (slice(150, 350), slice(200, 400))
    a, b = pair.image0[crop], pair.image1[crop]

    class _Crop:
        flow_true = pair.flow_true[crop]
        mask = pair.mask[crop]

    print("\nschedules on a 200x200 crop of the ball (σ_I 2 %)")
    print("| schedule | params | wall s | EPE px |")
    print("|---|---|---|---|")
    for params in (PMBPParams(), PMBPParams(pyramid_levels=1, num_iter=5)):
        for schedule in ("sequential", "lines", "parallel"):
            p = dataclasses.replace(params, schedule=schedule)
            pmbp_flow(a[:64, :64], b[:64, :64], p)
            start = time.perf_counter()
            flow = pmbp_flow(a, b, p)
            sec = time.perf_counter() - start
            desc = f"levels={p.pyramid_levels}, iters={p.num_iter}"
            print(f"| {schedule} | {desc} | {sec:.2f} | {_epe(flow, _Crop):.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--only", choices=["speed", "ball", "middlebury", "schedules"], help="run one part"
    )
    parser.add_argument("--repeat", type=int, default=3, help="timing repeats (median)")
    parser.add_argument("--cold", action="store_true", help="measure numba compile time")
    parser.add_argument("--no-baselines", action="store_true", help="skip DIS / TV-L1")
    args = parser.parse_args()
    print(
        f"cpu cores: {os.cpu_count()}, numba threads: {os.environ.get('NUMBA_NUM_THREADS', 'default')}"
    )
    if args.cold:
        bench_compile()
    parts = {
        "speed": lambda: bench_speed(args.repeat),
        "ball": bench_ball,
        "middlebury": lambda: bench_middlebury(not args.no_baselines),
        "schedules": bench_schedules,
    }
    for name, fn in parts.items():
        if args.only in (None, name):
            fn()


if __name__ == "__main__":
    main()
