"""``fuse4d run IN... -o OUT --engine dask``: fuse recordings to zarr v3 on one dask scheduler.

One input and an output ending in ``.zarr`` write that store; otherwise the output is a folder
(created if missing) that receives ``<input stem>.zarr`` per input. All inputs' chunks go to
the scheduler in one computation, so many recordings share one cluster.
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import FlowConfig, FusionParams
from ..errors import ParameterError
from ..flying_pixels import resolve_flying_pixels
from ..io._atomic import write_errors
from .cluster import SCHEDULER_ADDRESS_SCHEMES, _connect, check_scheduler, open_compute
from .graph import even_chunk_frames, fuse, release_engines
from .inputs import open_lazy
from .streamed import recording_tasks, source_of
from .zarr_out import ZarrOutput

__all__ = ["DaskRunSummary", "output_paths", "run_dask"]


@dataclass
class DaskRunSummary:
    """One recording of a dask run.

    Attributes
    ----------
    input, output : Path
    frames : int
    shape : (int, int)
        (H, W) px.
    chunks : int
        Time chunks (tasks and zarr shards).
    chunk_frames : int
        Frames per chunk (the last may be shorter): ``run_dask``'s ``chunk_frames`` evened out
        over the recording (:func:`fuse4d.scale.graph.even_chunk_frames`).
    skipped : int
        Chunks already written by an interrupted run (``--resume``).
    seconds : float
        Wall time of the whole run (all inputs together).
    frames_fused : int
        Frames of the chunks fused by this run (``frames`` less those of the skipped chunks).
    """

    input: Path
    output: Path
    frames: int
    shape: tuple[int, int]
    chunks: int
    chunk_frames: int
    skipped: int
    seconds: float = 0.0
    frames_fused: int = 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        out = dataclasses.asdict(self)
        out.update(input=str(self.input), output=str(self.output), shape=list(self.shape))
        return out


def output_paths(inputs: list[Path], output: Path) -> list[Path]:
    """Where each input's store goes (see the module docstring).

    Raises
    ------
    ParameterError
        If several inputs target one ``.zarr`` path, if the output is another kind of file
        (``.npz``, ``.mkv``: a folder of that name was made), or if two inputs share a stem.
    """
    from ..io.api import output_layout

    layout = output_layout(output)
    if layout == "zarr":
        if len(inputs) != 1:
            raise ParameterError(
                f"{len(inputs)} inputs need an output folder, not the single store {output}"
            )
        return [output]
    if layout != "folder":
        raise ParameterError(
            f"{output}: --engine dask writes zarr stores: give OUT.zarr (one input) or a "
            "folder (one OUT/<input>.zarr per input)"
        )
    paths = [output / f"{Path(p).stem}.zarr" for p in inputs]
    if len(set(paths)) != len(paths):
        raise ParameterError("inputs with the same name would write the same store; rename them")
    return paths


def _check_targets(inputs: list[Path], targets: list[Path]) -> None:
    """Refuse a target (or its staging store) that is an input, lies inside an input folder
    or holds one, as :func:`fuse4d.io.check_output` does for the streaming engine: ``--force``
    replaced the recording being read. Also where the output folder is yet to be made."""
    from ..io._atomic import check_not_an_input

    for dst in targets:
        for path in (dst, dst.with_name(dst.name + ".partial")):
            check_not_an_input(path, inputs)


def _absolute_paths(flow: FlowConfig, options: dict[str, Any]) -> tuple[FlowConfig, dict[str, Any]]:
    """``flow`` and the reader ``options`` with their file paths (the flow cache, an
    ``intrinsics`` camera.json) made absolute: a cluster's workers run in another folder."""
    from ..io._base import CAMERA_PRESETS

    if flow.cache_dir is not None:
        # "~" expanded as the stream engine's FlowCache does, then absolute for the workers
        flow = dataclasses.replace(
            flow, cache_dir=str(Path(flow.cache_dir).expanduser().absolute())
        )
    cam = options.get("intrinsics")
    if (
        isinstance(cam, str | os.PathLike)
        and str(cam).strip().lower() not in CAMERA_PRESETS
        and Path(cam).exists()
    ):
        options = {**options, "intrinsics": str(Path(cam).absolute())}
    return flow, options


def _reader_meta(options: dict[str, Any]) -> dict[str, str]:
    """The reader options as the JSON strings stored in the zarr's metadata."""
    return {k: str(v) for k, v in sorted(options.items())}


def _worker_pool(scheduler: str, workers: int | None) -> tuple[int, int]:
    """(processes, threads) that run tasks: one process of ``workers`` (or the CPU count)
    threads for ``threads``/``sync``, that many single-threaded processes for ``processes``,
    the cluster's workers and their threads for a scheduler address (flow look-ahead and the
    halo states' hand-over of :func:`~fuse4d.scale.streamed.recording_tasks`)."""
    if scheduler.startswith(SCHEDULER_ADDRESS_SCHEMES):
        with _connect(scheduler) as client:
            nthreads = client.nthreads()
        if not nthreads:  # an adaptive cluster may add some; else the run waits at 0 %
            warnings.warn(
                f"the dask scheduler at {scheduler} has no workers: the run waits until "
                f"some join (dask worker {scheduler})",
                RuntimeWarning,
                stacklevel=2,
            )
        return max(1, len(nthreads)), max(1, sum(nthreads.values()))
    local = max(1, workers or os.cpu_count() or 1)
    if scheduler == "sync":
        return 1, 1
    return (local if scheduler == "processes" else 1), local


def _source(path: Path) -> dict[str, Any]:
    """What the store records of its input: the path (for the reader; not compared on
    ``--resume``, so a moved input resumes) and the fingerprint of its files
    (:func:`fuse4d.io.resume.fingerprint_input`, as the stream engine's manifest: names, sizes,
    modification times of every file of a folder), which ``--resume`` compares."""
    from ..io.resume import fingerprint_input

    return {"path": str(path.resolve()), "fingerprint": fingerprint_input(path)}


#: Default ``chunk_frames`` of :func:`run_dask` (``fuse4d run --engine dask --chunk-frames``).
#: 16, not the 32 of the block graph (:func:`fuse4d.scale.graph.fuse`): the streamed graph
#: hands the halo frames' states between neighbouring chunks, so a smaller chunk costs little
#: repeated work, and twice as many tasks even out the last wave of a run (300 frames at
#: 600 x 600 on 2 workers: 55.8-56.4 s at 16 against 59.0-60.3 s at 32, the 1-worker run
#: 98.9 against 100.8-101.4 s; docs/scaling.md, "Chunk size").
RUN_CHUNK_FRAMES = 16


def run_dask(
    inputs: list[Path],
    output: Path,
    *,
    fusion: FusionParams,
    flow: FlowConfig,
    chunk_frames: int = RUN_CHUNK_FRAMES,
    scheduler: str = "threads",
    workers: int | None = None,
    resume: bool = False,
    overwrite: bool = False,
    warm_start: bool = True,
    save_flows: bool = False,
    progress: bool = True,
    reader_options: dict[str, Any] | None = None,
) -> list[DaskRunSummary]:
    """Fuse ``inputs`` into zarr v3 stores on one scheduler (see :mod:`fuse4d.scale.zarr_out`).

    Parameters
    ----------
    inputs : list of Path
        Recordings in any layout :func:`fuse4d.io.open_frames` reads (loaded lazily).
    output : Path
        ``OUT.zarr`` (one input) or a folder.
    fusion, flow
        Parameters (as for ``fuse4d run``).
    chunk_frames : int
        Most frames per task and per shard (default :data:`RUN_CHUNK_FRAMES`). Each recording
        is split into the fewest chunks of at most this many frames, of one length as even as
        possible (300 frames by 32: ten of 30, not nine of 32 and one of 12, whose early
        finish would idle a worker).
    scheduler, workers
        See :func:`fuse4d.scale.cluster.open_compute`.
    resume : bool
        Continue interrupted runs, skipping their finished chunks.
    overwrite : bool
        Replace existing outputs (once the new ones are complete).
    warm_start : bool
        Flow warm starts chained across pairs (the in-memory default).
    save_flows : bool
        Store the pair flows in each output (``flow_forward``, ``flow_backward``).
    progress : bool
        dask's progress bar on stderr.
    reader_options : dict, optional
        Keyword arguments of :func:`fuse4d.io.open_frames` for every input (``fuse4d run``'s
        ``--depth-topic``, ``--intensity-topic``, ``--intensity``, ``--no-undistort``,
        ``--depth-unit-mm``, ``--intrinsics``).

    Returns
    -------
    list of DaskRunSummary
    """
    start = time.perf_counter()
    check_scheduler(scheduler, workers)  # before any output is created
    targets = output_paths(inputs, output)
    _check_targets(inputs, targets)
    flow, reader_options = _absolute_paths(flow, reader_options or {})
    flow_meta = {
        "method": flow.method,
        "params": {k: str(v) for k, v in flow.params.items()},
        "roi": None if flow.roi is None else list(flow.roi),
        "warm_start": warm_start,
    }
    jobs: list[tuple[ZarrOutput, DaskRunSummary]] = []
    tasks: list[Any] = []
    processes, threads = _worker_pool(scheduler, workers)
    lookahead = 2 + threads
    # every input opened (and so checked) before any output is made: a bad second input left
    # the first one's staging store, and the next run then asked for --resume
    recs = [open_lazy(src, frames_per_task=chunk_frames, **reader_options) for src in inputs]
    if len(targets) > 1 or targets[0] != output:
        with write_errors(output):  # a read-only folder: one line naming the output
            output.mkdir(parents=True, exist_ok=True)
    # every output checked before any is written: a refused second one (exists, interrupted)
    # left the first one's new staging store, and the next run then asked for --resume
    plans = []
    for dst, rec in zip(targets, recs, strict=True):
        params = resolve_flying_pixels(fusion, rec.sensor)  # A36
        frames = even_chunk_frames(rec.num_frames, chunk_frames)
        out = ZarrOutput(
            dst,
            shape=(rec.num_frames, rec.intrinsics.height, rec.intrinsics.width),
            chunk_frames=frames,
            intrinsics=rec.intrinsics,
            metadata={
                "params": params.to_dict(),
                "flow": flow_meta,
                "source": {**_source(rec.path), "format": rec.format, "fps": rec.fps},
                # streams, camera, frame range: a resume must read the input the same way
                **({"reader_options": _reader_meta(reader_options)} if reader_options else {}),
            },
            resume=resume,
            overwrite=overwrite,
            save_flows=save_flows,
            defer=True,
        )
        plans.append((out, params, frames))
    for src, dst, rec, (out, params, frames) in zip(inputs, targets, recs, plans, strict=True):
        out.prepare()
        done = out.done_chunks()
        if params.iterations == 1:  # bounded memory: frames and flows travel through files
            source = source_of(rec.path, rec.format, rec.num_frames, **reader_options)
            tasks.extend(
                recording_tasks(
                    source,
                    out,
                    rec.intrinsics,
                    fusion=params,
                    flow=flow,
                    chunk_frames=frames,
                    warm_start=warm_start,
                    lookahead=lookahead,
                    share_states=processes > 1,
                )
            )
        else:  # fusion iterations chain whole passes: the in-memory graph
            result = fuse(
                rec.depth,
                rec.intensity,
                rec.intrinsics,
                fusion=params,
                flow=flow,
                chunk_frames=frames,
                warm_start=warm_start,
            )
            tasks.extend(out.tasks(result))
        summary = DaskRunSummary(
            input=src,
            output=dst,
            frames=rec.num_frames,
            shape=(rec.intrinsics.height, rec.intrinsics.width),
            chunks=len(out.bounds),
            chunk_frames=frames,
            skipped=len(done),
            frames_fused=sum(e - s for k, (s, e) in enumerate(out.bounds) if k not in done),
        )
        jobs.append((out, summary))
    if tasks:
        with open_compute(
            scheduler, workers, progress=progress, on_exit=release_engines
        ) as compute:
            compute(*tasks)
    for out, _ in jobs:
        out.finalize()
    seconds = time.perf_counter() - start
    for _, summary in jobs:
        summary.seconds = seconds
    return [s for _, s in jobs]


def print_dask_run(
    inputs: list[Path],
    output: Path,
    fusion: FusionParams,
    flow: FlowConfig,
    options: dict[str, Any],
    resume: bool,
    overwrite: bool,
    warm_start: bool,
    as_json: bool,
) -> list[DaskRunSummary]:
    """The CLI face of :func:`run_dask`: run, then print a table (or JSON) per recording;
    returns the summaries."""

    from rich.table import Table

    from ..cli._app import fail, out_console

    try:  # a scheduler address without distributed: one line, not an internal error
        check_scheduler(options.get("scheduler", "threads"), options.get("workers"))
    except ImportError as exc:
        fail(str(exc))
    summaries = run_dask(
        inputs,
        output,
        fusion=fusion,
        flow=flow,
        resume=resume,
        overwrite=overwrite,
        warm_start=warm_start,
        **options,
    )
    if as_json:
        from .._json import dumps

        print(dumps([s.to_dict() for s in summaries], indent=2))
        return summaries
    table = Table(title=f"fuse4d run --engine dask ({options.get('scheduler', 'threads')})")
    for col in ("input", "output", "frames", "chunks x frames (resumed)"):
        table.add_column(col)
    for s in summaries:
        table.add_row(
            str(s.input),
            str(s.output),
            f"{s.frames} x {s.shape[0]}x{s.shape[1]}",
            f"{s.chunks} x {s.chunk_frames} ({s.skipped})",
        )
    out_console.print(table)
    seconds = summaries[0].seconds if summaries else 0.0
    fused = sum(s.frames_fused for s in summaries)
    resumed = sum(s.frames for s in summaries) - fused
    # per frame fused now: the resumed chunks' frames took no time
    rate = f"{1000 * seconds / fused:.0f} ms/frame" if fused else "nothing to fuse"
    if fused and resumed:
        rate += f" over the {fused} frames fused now, {resumed} resumed"
    out_console.print(f"time {seconds:.1f} s ({rate})")
    return summaries
