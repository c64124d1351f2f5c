"""Scaling of the dask engine: 1 vs N worker processes, per-worker peak RSS, overhead vs the
streaming engine (issue 15 targets).

Usage::

    python benchmarks/scale.py                          # 150x150 ball, 96 and 192 frames
    python benchmarks/scale.py --full --frames 300      # the issue's 600x600 target
    python benchmarks/scale.py --workers 1,2 --chunk-frames 16 --json

What is timed (wall clock, after every worker has loaded the compiled kernels):

- ``stream``: the streaming :class:`fuse4d.FusionEngine` over the recording read frame by frame
  from the same ``.npz``, as one task on a 1-worker cluster (same single-threaded worker
  environment as the dask runs; outputs kept in memory, nothing written);
- ``dask N``: ``fuse4d.dask.fuse`` over the lazily loaded ``.npz`` written to zarr v3 by a
  ``LocalCluster`` of N single-threaded worker processes (``fuse4d run --engine dask
  --scheduler processes --workers N`` does the same);
- CPU seconds of the workers (user + system, all threads): the overhead figure that survives
  a loaded machine, where wall times swing by tens of percent between identical runs;
- peak RSS of every worker process (``VmHWM``, MiB, includes the ~0.3 GB of imported
  libraries), for the recording and for one ``--length-factor`` times as long (flat = independent of
  length);
- with ``--ceiling``: N independent streaming runs at once against one alone on the same
  cluster (``ceiling_speedup_N``), the speed-up this machine gives perfectly parallel work in
  the same sitting, and the dask speed-up as a share of it (``speedup_N_of_ceiling``);
- the halo frame states handed from one fusion task to its neighbour's (in the same worker,
  or through the scratch folder with several workers; ``dask_N_halo_states_taken``, at most
  ``(chunks - 1) (past + future)``), i.e. how much of the halo's per-frame work the run did
  not repeat.

Every timed run starts with the previous run's output deleted and the page cache written back
(``os.sync``): otherwise a run pays for the write-back of the ≈ 2 GB its predecessor wrote.

The machine's load average is printed with the results: on a shared machine the speed-up
ratio is only meaningful if the load is below the core count.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

#: Side of the full falling ball's frames (px), the largest ``--size``.
FULL_SIZE = 600


def _make_recording(
    path: Path, frames: int, full: bool, size: int | None = None
) -> tuple[int, int]:
    """The falling ball (600x600 with ``full``, else 150x150), or with ``size`` the central
    ``size`` x ``size`` px of the 600x600 ball (cheaper runs with the same motion).

    Returns the frames' (height, width) in px."""
    from fuse4d import Intrinsics
    from fuse4d.io import save_sequence
    from fuse4d.sequence import Sequence
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=not (full or size is not None), num_frames=frames, rng=0)
    h, w = seq.depth.shape[1:]
    if size is not None and size > min(h, w):
        raise ValueError(f"--size {size} exceeds the {w}x{h} frames")
    if size is not None and size < min(h, w):
        r, c = (h - size) // 2, (w - size) // 2
        k = seq.intrinsics
        cam = Intrinsics(k.fx, k.fy, k.cx - c, k.cy - r, size, size)
        box = (slice(None), slice(r, r + size), slice(c, c + size))
        seq = Sequence(seq.depth[box].copy(), seq.intensity[box].copy(), cam)
    save_sequence(seq, path)
    return seq.depth.shape[1], seq.depth.shape[2]


def _peak_rss_mib() -> float:
    """This process's peak resident set (``VmHWM``), MiB.

    Not ``ru_maxrss``: Linux carries that across ``execve``, so a worker spawned by a parent
    that once held a large recording reports the parent's peak, not its own."""
    with Path("/proc/self/status").open(encoding="ascii") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # not Linux


def _cpu_seconds() -> float:
    """CPU time (user + system) of this process so far, s."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _warm_up() -> int:
    """Load the compiled kernels and the output libraries in a worker (a 3-frame fusion)."""
    import zarr  # noqa: F401

    import fuse4d.dask  # noqa: F401
    from fuse4d import fuse_sequence
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=3)
    fuse_sequence(seq.depth[:, :40, :40], seq.intensity[:, :40, :40], _crop_k(seq.intrinsics))
    return os.getpid()


def _crop_k(k: Any) -> Any:
    from fuse4d import Intrinsics

    return Intrinsics(k.fx, k.fy, k.cx, k.cy, 40, 40)


def _stream_task(path: str, fusion: Any) -> float:
    """The streaming engine (``fusion``: its :class:`fuse4d.FusionParams`) over the file, frame
    by frame; returns seconds."""
    from fuse4d import FusionEngine
    from fuse4d.io import open_frames

    start = time.perf_counter()
    with open_frames(path) as reader:
        engine = FusionEngine(reader.intrinsics, fusion=fusion)
        depth = np.empty((len(reader), *reader.shape), np.float32)
        for frame in reader:
            for fr in engine.push(frame.depth, frame.intensity):
                depth[fr.index] = fr.depth
        for fr in engine.flush():
            depth[fr.index] = fr.depth
    return time.perf_counter() - start


def _dask_run(
    client: Any, path: Path, out: Path, chunk: int, fusion: Any, graph: str = "streamed"
) -> float:
    """``fuse4d run --engine dask`` on the client's cluster; returns seconds.

    ``graph="streamed"`` is what the CLI runs (:func:`fuse4d.scale.cli.run_dask`: frames and
    flows through files); ``"memory"`` is ``fuse4d.dask.fuse`` + ``write_zarr`` (blocks in
    worker memory)."""
    import fuse4d.dask as fd
    from fuse4d.config import preset
    from fuse4d.scale.cli import run_dask

    shutil.rmtree(out, ignore_errors=True)  # the earlier run's, written back by _settle
    if graph == "streamed":
        start = time.perf_counter()
        run_dask(
            [path],
            out,
            fusion=fusion,
            flow=preset("fast").flow,
            chunk_frames=chunk,
            scheduler=client.scheduler.address,
            overwrite=True,
            progress=False,
        )
        return time.perf_counter() - start
    rec = fd.open_lazy(path, frames_per_task=chunk)
    res = fd.fuse(rec.depth, rec.intensity, rec.intrinsics, fusion=fusion, chunk_frames=chunk)
    start = time.perf_counter()
    fd.write_zarr(
        res,
        out,
        intrinsics=rec.intrinsics,
        overwrite=True,
        compute=lambda *t: client.gather(client.compute(list(t))),
    )
    return time.perf_counter() - start


def _settle() -> None:
    """Start a timed run from the same state as the others: write back what earlier runs left
    in the page cache (their outputs are deleted by :func:`_dask_run`). A dask run
    writes ≈ 2 GB (scratch pairs and states, the zarr store) at 600 x 600, 300 frames; the
    kernel flushes it 30 s later, i.e. during the next run, which took 6-9 % longer here
    (2-worker run after a 1-worker one: 61.9-62.2 s, +16 % worker CPU; the same first:
    57.0 s). Settled, two runs still gave 57.4 and 60.7 s: not the whole story
    (docs/scaling.md, Benchmark)."""
    os.sync()


def _states_taken() -> int:
    """Halo frame states handed to this worker's tasks so far, from its memory or from the
    scratch folder (``fuse4d.scale.streamed``)."""
    from fuse4d.scale import streamed

    return streamed._MEMO.taken + streamed._MEMO.loaded


def _with_cluster(workers: int, job: Any) -> tuple[Any, list[float], float, int]:
    """Run ``job(client)`` on a fresh LocalCluster; return its result, the workers' peak RSS
    (MiB), the CPU seconds the workers spent on it (robust to other load on the machine,
    unlike wall time) and the halo frame states its tasks handed over."""
    from fuse4d.scale.cluster import local_cluster

    with local_cluster(workers) as client:
        client.wait_for_workers(workers)
        client.run(_warm_up)
        _settle()
        before = client.run(_cpu_seconds)
        result = job(client)
        after = client.run(_cpu_seconds)
        rss = sorted(client.run(_peak_rss_mib).values())
        taken = sum(client.run(_states_taken).values())
    return result, rss, sum(after[k] - before[k] for k in after), taken


def _ceiling(rec: Path, workers: int, fusion: Any) -> dict[str, Any]:
    """What this machine gives ``workers`` independent jobs: the streaming engine over the
    recording on one worker of a ``workers``-worker LocalCluster alone, then on every worker
    at once (each its own copy of the file). ``2 one / together`` is the speed-up of perfectly
    parallel work with nothing shared (on 2 cores of a shared VM it stays below 2: the engine
    overlaps its flow in a second thread, which has no idle core when both workers are busy,
    and the neighbours take their share), the yardstick for the dask speed-up of the same
    sitting."""
    from fuse4d.scale.cluster import local_cluster

    copies = [rec]
    for i in range(1, workers):
        copies.append(rec.with_name(f"copy{i}.npz"))
        shutil.copyfile(rec, copies[-1])
    with local_cluster(workers) as client:
        client.wait_for_workers(workers)
        client.run(_warm_up)
        names = list(client.scheduler_info()["workers"])
        _settle()
        start = time.perf_counter()
        client.submit(_stream_task, str(rec), fusion, pure=False, workers=names[:1]).result()
        one = time.perf_counter() - start
        _settle()
        start = time.perf_counter()
        client.gather(
            [
                client.submit(_stream_task, str(path), fusion, pure=False, workers=[name])
                for path, name in zip(copies, names, strict=True)
            ]
        )
        together = time.perf_counter() - start
    for path in copies[1:]:
        path.unlink()
    return {
        f"ceiling_{workers}_one_s": one,
        f"ceiling_{workers}_together_s": together,
        f"ceiling_speedup_{workers}": workers * one / together,
    }


def _alternating(
    rec: Path, folder: Path, args: argparse.Namespace, fusions: list[Any]
) -> dict[str, Any]:
    """Streaming and dask runs alternated on one 1-worker cluster (each of ``fusions`` in
    turn within a round): min wall and worker CPU of each side, and the overhead of the
    minima (keys suffixed with the tracks setting where several are compared)."""
    from fuse4d.scale.cluster import local_cluster

    def tag(fusion: Any) -> str:  # the key suffix of a setting, where several are compared
        return f"_{fusion.tracks}" if len(fusions) > 1 else ""

    sides: dict[str, list[tuple[float, float]]] = {}
    with local_cluster(1) as client:
        client.wait_for_workers(1)
        client.run(_warm_up)
        for _ in range(args.repeats):
            for fusion in fusions:
                for side in ("stream", "dask"):
                    _settle()
                    before = client.run(_cpu_seconds)
                    if side == "stream":
                        task = client.submit(_stream_task, str(rec), fusion, pure=False)
                        wall = task.result()
                    else:
                        out = folder / "alt.zarr"
                        wall = _dask_run(client, rec, out, args.chunk_frames, fusion, args.graph)
                    after = client.run(_cpu_seconds)
                    cpu = sum(after[k] - before[k] for k in after)
                    sides.setdefault(side + tag(fusion), []).append((wall, cpu))
    report: dict[str, Any] = {
        "alternating_runs": {
            k: [[round(w, 2), round(c, 2)] for w, c in v] for k, v in sides.items()
        }
    }
    for fusion in fusions:
        stream, dask_runs = sides["stream" + tag(fusion)], sides["dask" + tag(fusion)]
        (sw, sc), (dw, dc) = (
            tuple(min(v) for v in zip(*r, strict=True)) for r in (stream, dask_runs)
        )
        report["alternating_overhead_wall" + tag(fusion)] = dw / sw - 1.0
        report["alternating_overhead_cpu" + tag(fusion)] = dc / sc - 1.0
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=96, help="recording length (frames)")
    parser.add_argument("--full", action="store_true", help="600x600 instead of 150x150")
    parser.add_argument(
        "--size",
        type=int,
        help=f"the central SIZE x SIZE px of the {FULL_SIZE}x{FULL_SIZE} ball (1..{FULL_SIZE})",
    )
    parser.add_argument(
        "--graph",
        choices=("streamed", "memory"),
        default="streamed",
        help="dask graph: streamed (fuse4d run --engine dask) or memory (fuse + write_zarr)",
    )
    parser.add_argument("--workers", default="1,2", help="worker counts, comma-separated")
    parser.add_argument(
        "--chunk-frames",
        type=int,
        help="most frames per chunk (default: the graph's own, 16 streamed / 32 memory)",
    )
    parser.add_argument("--window", type=int, default=9, help="frames fused per output")
    parser.add_argument(
        "--tracks",
        help="FusionParams.tracks of both engines (default: FusionParams' own); "
        "'composed,exact' alternates both in the --repeats runs (the first for the others; "
        "several settings need --repeats)",
    )
    parser.add_argument(
        "--length-factor",
        type=int,
        default=2,
        help="the length check runs a recording this many times longer (default 2)",
    )
    parser.add_argument("--no-length-check", action="store_true", help="skip the longer run")
    parser.add_argument(
        "--repeats",
        type=int,
        default=0,
        help="also alternate streaming / dask-1-worker runs this many times on one 1-worker "
        "cluster and report the overhead of the minima (robust to a drifting load; default 0: "
        "no alternation)",
    )
    parser.add_argument(
        "--ceiling",
        action="store_true",
        help="also time N independent streaming runs at once against one alone (the speed-up "
        "this machine gives perfectly parallel work, N = the largest --workers)",
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    try:
        counts = [int(v) for v in args.workers.split(",")]
    except ValueError:
        parser.error(f"--workers must be comma-separated integers, got {args.workers!r}")
    if min(counts) < 1:
        parser.error(f"--workers must be >= 1 each, got {args.workers!r}")
    if args.frames < 1:
        parser.error(f"--frames must be >= 1, got {args.frames}")
    if args.size is not None and not 1 <= args.size <= FULL_SIZE:
        parser.error(f"--size must be 1..{FULL_SIZE} (the full ball's frames), got {args.size}")
    if args.repeats < 0:
        parser.error(f"--repeats must be >= 0, got {args.repeats}")
    if args.length_factor < 1:
        parser.error(f"--length-factor must be >= 1, got {args.length_factor}")
    if args.tracks is not None and "," in args.tracks and args.repeats < 1:
        parser.error(
            f"--tracks {args.tracks} compares several settings only in the alternating runs: "
            "give --repeats R (R >= 1)"
        )
    from fuse4d import FusionParams

    settings = [{}] if args.tracks is None else [{"tracks": t} for t in args.tracks.split(",")]
    fusions = [FusionParams(num_frames=args.window, **kw) for kw in settings]
    fusion = fusions[0]
    if args.chunk_frames is None:  # the graph's own default
        import fuse4d.dask as fd
        from fuse4d.scale.cli import run_dask

        default_of = run_dask if args.graph == "streamed" else fd.fuse
        args.chunk_frames = inspect.signature(default_of).parameters["chunk_frames"].default
    report: dict[str, Any] = {
        "size": None,  # the rendered frames' (below)
        "graph": args.graph,
        "frames": args.frames,
        "chunk_frames": args.chunk_frames,
        "window": args.window,
        "tracks": fusion.tracks,
        "cpus": os.cpu_count(),
        "load_before": os.getloadavg(),
    }
    with tempfile.TemporaryDirectory(prefix="fuse4d-scale-") as tmp:
        folder = Path(tmp)
        rec = folder / "rec.npz"
        height, width = _make_recording(rec, args.frames, args.full, args.size)
        report["size"] = f"{width}x{height}"
        seconds, rss, cpu, _ = _with_cluster(
            1, lambda c: c.submit(_stream_task, str(rec), fusion, pure=False).result()
        )
        report["stream_s"] = seconds
        report["stream_cpu_s"] = cpu
        report["stream_rss_mib"] = rss
        for n in counts:
            seconds, rss, cpu, taken = _with_cluster(
                n,
                lambda c: _dask_run(
                    c, rec, folder / "out.zarr", args.chunk_frames, fusion, args.graph
                ),
            )
            report[f"dask_{n}_s"] = seconds
            report[f"dask_{n}_cpu_s"] = cpu
            report[f"dask_{n}_rss_mib"] = rss
            report[f"dask_{n}_halo_states_taken"] = taken
        if args.repeats > 0:
            report.update(_alternating(rec, folder, args, fusions))
        if args.ceiling and max(counts) > 1:
            report.update(_ceiling(rec, max(counts), fusion))
        if not args.no_length_check:
            longer = folder / "long.npz"
            factor = args.length_factor
            _make_recording(longer, factor * args.frames, args.full, args.size)
            n = max(counts)
            seconds, rss, cpu, _ = _with_cluster(
                n,
                lambda c: _dask_run(
                    c, longer, folder / "o2.zarr", args.chunk_frames, fusion, args.graph
                ),
            )
            report["long_frames"] = factor * args.frames
            report[f"dask_{n}_long_s"] = seconds
            report[f"dask_{n}_long_cpu_s"] = cpu
            report[f"dask_{n}_long_rss_mib"] = rss
    report["load_after"] = os.getloadavg()
    one = report.get("dask_1_s")
    if one:
        report["overhead_vs_stream_1_worker_wall"] = one / report["stream_s"] - 1.0
        report["overhead_vs_stream_1_worker_cpu"] = (
            report["dask_1_cpu_s"] / report["stream_cpu_s"] - 1.0
        )
        for n in counts:
            report[f"speedup_{n}_vs_1"] = one / report[f"dask_{n}_s"]
            if f"ceiling_speedup_{n}" in report:  # share of what the machine gives
                report[f"speedup_{n}_of_ceiling"] = (
                    report[f"speedup_{n}_vs_1"] / report[f"ceiling_speedup_{n}"]
                )
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    for key, value in report.items():
        if isinstance(value, float):
            value = f"{value:.3f}"
        elif isinstance(value, dict):
            value = json.dumps(value)
        elif isinstance(value, list | tuple):
            value = ", ".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in value)
        print(f"{key:32s} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
