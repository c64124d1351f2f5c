"""Bounded-memory dask graph for recordings on disk (what ``fuse4d run --engine dask`` runs).

The graph of :func:`fuse4d.scale.graph.fuse` passes frames and flows between tasks as
in-memory blocks: a worker holds its running task's ``c + h`` input frames and pair flows
(24 bytes/px/frame) plus the blocks its neighbours' tasks still need — ≈ 1.5 GB per worker at
600 x 600 with c = 32, more on a cluster where blocks are copied between workers. Here the
tasks pass only tokens and the frames travel through files:

- **flow tasks of chunk k** read its ``c + 1`` intensity frames one at a time from the
  recording, solve the pairs of chunk k (warm-started from chunk k-1's last forward flow, read
  from the seed file that chunk k-1 saved) and write each flow to a scratch file in the
  output's staging folder (``OUT.zarr.partial/.fuse4d-flows/``; with ``save_flows`` also the
  output's ``flow_forward``/``flow_backward`` shard). Where the method solves each direction
  on its own (no pair function, no flow cache: DIS, Farneback, ...) the chunk has two tasks:
  the **forward task** (the warm-start chain: each chunk's waits for the previous chunk's) and
  the **backward task**, which needs only its own chunk's forward flows (each backward solve
  starts from ``-forward``, METHOD §2.3) and so runs on another worker beside the chain;
- **fusion task k** (after flow tasks k-1, k, k+1) reads its frames with the halo one at a time
  from the recording and its pairs from the scratch files, runs the streaming engine, and
  writes its zarr shard and done marker. The frames that two neighbouring chunks both push
  (chunk k's last ``past`` frames and chunk k+1's first ``future``) have their per-frame work
  (:class:`fuse4d.fusion.FrameState`: references, bilateral, noise model) done once: the
  first of the two tasks to push them keeps their states in its process's memory (and, with
  several worker processes, saves them to the scratch folder), the second takes them instead
  of computing them. With one worker the chunks run in order, so that is every boundary:
  ``past + future`` frames per chunk, the halo's redundant per-frame work;
- **drop task k** deletes chunk k's pair files and saved states once fusion tasks k-1, k, k+1
  are done (only the last forward flow stays, to seed a resumed run), so the scratch space is
  a few chunks, not the recording.

A worker holds one engine (≈ 0.3 GB at 600 x 600 and n = 9 with the default composed tracks,
A31; kept between its tasks and reset, :func:`fuse4d.scale.graph.chunk_engine`), one chunk of
outputs (6 bytes/px/frame), a few frames and at most ``2 (past + future)`` handed-over frame
states (24 bytes/px each): flat in the recording's length. The bits are those of the in-memory
graph (same reader, same flow calls in the same order, same engine per chunk).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from collections import OrderedDict
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import dask
import numpy as np
import zarr
from numpy.typing import NDArray

from ..camera import Intrinsics
from ..config import FlowConfig, FusionParams
from ..errors import ParameterError
from ..flow import FlowCache, estimate_flow, get_flow_method
from ..fusion import FrameState
from ..io._atomic import write_errors
from ..io.resume import fingerprint_input
from .graph import _flow_chain, _intensity_frame, chunk_bounds, chunk_engine
from .inputs import read_frame, read_intensity
from .zarr_out import ZarrOutput, _marker, _output_of, write_chunk

__all__ = ["RecordingSource", "flow_scratch", "recording_tasks", "source_of"]

_FLOWS = ".fuse4d-flows"
#: dask priority of the flow tasks (default 0): a worker that can start a flow or a fusion
#: starts the flow, which is on the critical path (each chunk's fusion waits for the flows of
#: its neighbours, and the chain of warm-started flows is sequential).
_FLOW_PRIORITY = 10


@dataclass(frozen=True)
class RecordingSource:
    """A recording on disk as the tasks open it (each worker keeps one reader per source).

    Attributes
    ----------
    path : str
        Absolute path of the ``.npz`` file or folder.
    format : str
        Layout name for :func:`fuse4d.io.open_frames`.
    stamp : str
        The input's :func:`fuse4d.io.resume.fingerprint_input` (its files' names, sizes and
        mtimes): a rewritten input gets new task keys, readers and frame-state keys.
    options : tuple of (str, value)
        Keyword arguments of :func:`fuse4d.io.open_frames`.
    frames : int
        T.
    """

    path: str
    format: str
    stamp: str
    options: tuple[tuple[str, Any], ...]
    frames: int

    def frame(self, index: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """(H, W) float32 depth (mm, NaN = invalid) and intensity of frame ``index``, the
        values :func:`fuse4d.scale.inputs.read_frames` gives the in-memory graph."""
        return read_frame(self.path, self.format, index, self.options, self.stamp)

    def intensity(self, index: int) -> NDArray[np.float32]:
        """(H, W) float32 intensity of frame ``index`` (the flow tasks read nothing else)."""
        return read_intensity(self.path, self.format, index, self.options, self.stamp)


def flow_scratch(staging: Path) -> Path:
    """The scratch folder of the pair flows inside an output's staging folder."""
    return Path(staging) / _FLOWS


def _scratch_errors(scratch: str | Path) -> AbstractContextManager[None]:
    """Report a full disk, a read-only folder, ... while writing the scratch folder
    ``scratch`` (``OUT.zarr.partial/.fuse4d-flows``) as an OutputWriteError naming
    ``OUT.zarr``: one line from the CLI, whichever worker ran the task."""
    return write_errors(_output_of(Path(scratch).parent))


def _pair_files(scratch: str, j: int) -> tuple[Path, Path]:
    """The scratch files of pair j's forward and backward flow."""
    return Path(scratch) / f"forward-{j:07d}.npy", Path(scratch) / f"backward-{j:07d}.npy"


def _seed_file(scratch: str, k: int) -> Path:
    return Path(scratch) / f"seed-{k:06d}.npy"


def _flow_marker(scratch: str, k: int) -> Path:
    """Present while chunk k's pair files are complete."""
    return Path(scratch) / f"flows-{k:06d}"


def _state_key(source: RecordingSource, intrinsics: Intrinsics, params: FusionParams) -> str:
    """What a kept frame state was computed from (a state is only reused with the same)."""
    return hashlib.sha1(repr((source, intrinsics, params)).encode()).hexdigest()


class _StateMemo:
    """The :class:`FrameState` of the frames a fusion task shares with a neighbouring chunk
    that has not run yet, kept in the worker process for the neighbour's task if it runs
    there (with one worker that is every neighbour: the chunks run in order).

    The task that puts states gives the limit: two chunk boundaries' worth, ``2 (past +
    future)`` (the oldest go first). A state is 24 bytes/px (8.6 MB at 600 x 600), so the
    9-frame window keeps at most 16 states, 138 MB per worker. Memory first: at 600 x 600
    computing a state takes ≈ 33 ms and copying it ≈ 2 ms, while writing it to the scratch
    folder took 3-18 ms on the development machine (it varies with the page cache) and
    reading it 1-7 ms; so the scratch files are only written where several worker processes
    run the tasks (``share_states``)."""

    def __init__(self) -> None:
        self._states: OrderedDict[tuple[str, str, int], FrameState] = OrderedDict()
        self._lock = threading.Lock()
        # states handed over to this process's tasks so far, from memory and from the
        # scratch folder (benchmarks/scale.py)
        self.taken = 0
        self.loaded = 0

    def put(self, key: tuple[str, str, int], state: FrameState, limit: int) -> None:
        with self._lock:
            self._states[key] = state
            self._states.move_to_end(key)
            while len(self._states) > limit:
                self._states.popitem(last=False)

    def take(self, key: tuple[str, str, int]) -> FrameState | None:
        """The state kept under ``key`` (removed: each shared frame has one other reader)."""
        with self._lock:
            state = self._states.pop(key, None)
            self.taken += state is not None
            return state


_MEMO = _StateMemo()


def _state_file(scratch: str, t: int) -> Path:
    """The scratch file of frame t's handed-over :class:`FrameState` (several processes)."""
    return Path(scratch) / f"state-{t:07d}.npy"


def _save_state(path: Path, state: FrameState, key: str) -> None:
    """Save atomically: the key, then the arrays one after the other in one ``.npy`` stream
    (no zip, no checksum). Two tasks may save the same frame at once, with the same bits."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}-{threading.get_ident()}.tmp")
    with _scratch_errors(path.parent):
        with tmp.open("wb") as f:
            np.save(f, np.asarray(key), allow_pickle=False)
            np.save(f, np.asarray(state.reference is not None), allow_pickle=False)
            for array in (state.noise, state.smooth, state.bilateral):
                np.save(f, array, allow_pickle=False)
            if state.reference is not None:
                np.save(f, state.reference, allow_pickle=False)
        tmp.replace(path)


def _load_state(path: Path, key: str) -> FrameState | None:
    """The state saved at ``path`` under ``key``; None where there is none (not saved yet,
    deleted meanwhile, or from another input or other parameters)."""
    try:
        with path.open("rb") as f:
            if str(np.load(f, allow_pickle=False)) != key:
                return None
            separate = bool(np.load(f, allow_pickle=False))
            noise, smooth, bilateral = (np.load(f, allow_pickle=False) for _ in range(3))
            reference = np.load(f, allow_pickle=False) if separate else None
    except (OSError, ValueError, EOFError):
        return None
    return FrameState(smooth, reference, bilateral, noise)


def _save(path: Path, array: NDArray[Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with _scratch_errors(path.parent):
        with tmp.open("wb") as f:
            np.save(f, array, allow_pickle=False)
        tmp.replace(path)


def _touch(path: Path, info: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with _scratch_errors(path.parent):
        tmp.write_text(json.dumps(info))
        tmp.replace(path)


# ------------------------------------------------------------------------------------ tasks
def _splits(config: FlowConfig) -> bool:
    """Whether the pairs' two directions can be solved by separate tasks with the same bits:
    the method solves one direction at a time and no flow cache keys the pair as a whole."""
    return get_flow_method(config.method).pair_function is None and config.cache_dir is None


def _store_flows(staging: str | None, name: str, a: int, flows: list[NDArray[Any]]) -> None:
    """The output's shard of these pairs' flows (``save_flows``), written at once."""
    if staging is not None and flows:
        with write_errors(_output_of(staging)):
            root = zarr.open_group(staging, mode="r+")
            root[name][a : a + len(flows)] = np.stack(flows)  # type: ignore[index]


def _flow_task(
    source: RecordingSource,
    scratch: str,
    staging: str | None,
    k: int,
    bounds: tuple[int, int],
    seed_chunk: int | None,
    config: FlowConfig,
    chained: bool,
    *after: Any,
) -> int:
    """Both directions of the pairs ``[a, b)`` of chunk k, chained like
    :func:`fuse4d.scale.graph._flow_block`, to the scratch files (and the output's flow arrays
    at ``staging``), warm-started from the seed file of chunk ``seed_chunk`` (None: cold
    start); saves chunk k's seed and its marker and returns k. For methods whose two
    directions need one call (or a flow cache); the others run :func:`_forward_task` and
    :func:`_backward_task`.

    Only this token travels between tasks, not the seed (8 bytes/px): dask places a task
    where most of its inputs' bytes are, so a 2.9 MB seed (600 x 600) made the scheduler queue
    the next fusion behind the running task of the worker that held it, while the other
    worker idled until work stealing moved it (0.7-1.4 s per occurrence, measured on a
    2-worker LocalCluster). One output, not ``nout=2``, for the same reason: dask runs each
    ``getitem`` of a tuple result as a task of its own on the worker that holds the tuple."""
    a, b = bounds
    method = get_flow_method(config.method)
    params = config.build_params()
    cache = None if config.cache_dir is None else FlowCache(config.cache_dir)
    seed = None if seed_chunk is None else _load_seed(scratch, seed_chunk)
    keep: list[tuple[NDArray[np.float32], NDArray[np.float32]]] = []
    forward = None
    frames = (source.intensity(t) for t in range(a, b + 1))
    for j, (forward, backward) in enumerate(
        _flow_chain(frames, method, params, seed, chained, config.roi, cache), start=a
    ):
        assert backward is not None
        forward_file, backward_file = _pair_files(scratch, j)
        _save(forward_file, forward)
        _save(backward_file, backward)
        if staging is not None:
            keep.append((forward, backward))
    _store_flows(staging, "flow_forward", a, [f for f, _ in keep])
    _store_flows(staging, "flow_backward", a, [g for _, g in keep])
    assert forward is not None
    _save(_seed_file(scratch, k), np.ascontiguousarray(forward))
    _touch(_flow_marker(scratch, k), {"start": a, "stop": b})
    return k


def _forward_task(
    source: RecordingSource,
    scratch: str,
    staging: str | None,
    k: int,
    bounds: tuple[int, int],
    seed_chunk: int | None,
    config: FlowConfig,
    chained: bool,
    *after: Any,
) -> int:
    """The forward flows of the pairs ``[a, b)`` of chunk k: the solves of
    :func:`_flow_task` without the backward ones, in the same order from the same seed;
    saves chunk k's seed and returns k (the marker waits for :func:`_backward_task`)."""
    a, b = bounds
    method = get_flow_method(config.method)
    params = config.build_params()
    seed = None if seed_chunk is None else _load_seed(scratch, seed_chunk)
    keep: list[NDArray[np.float32]] = []
    forward = None
    frames = (source.intensity(t) for t in range(a, b + 1))
    chain = _flow_chain(frames, method, params, seed, chained, config.roi, None, backward=False)
    for j, (forward, _) in enumerate(chain, start=a):
        _save(_pair_files(scratch, j)[0], forward)
        if staging is not None:
            keep.append(forward)
    _store_flows(staging, "flow_forward", a, keep)
    assert forward is not None
    _save(_seed_file(scratch, k), np.ascontiguousarray(forward))
    return k


def _backward_task(
    source: RecordingSource,
    scratch: str,
    staging: str | None,
    k: int,
    bounds: tuple[int, int],
    config: FlowConfig,
    *after: Any,
) -> int:
    """The backward flows of the pairs ``[a, b)`` of chunk k from their forward flows
    (:func:`_forward_task`, saved): each solve as :func:`fuse4d.flow.estimate_flow_pair` runs
    it, warm-started from ``-forward`` where the method takes a warm start. Writes chunk k's
    marker and returns k."""
    a, b = bounds
    method = get_flow_method(config.method)
    params = config.build_params()
    keep: list[NDArray[np.float32]] = []
    frames = (_intensity_frame(source.intensity(t)) for t in range(a, b + 1))
    previous = next(frames)
    for j, current in enumerate(frames, start=a):
        forward_file, backward_file = _pair_files(scratch, j)
        forward = np.load(forward_file, allow_pickle=False)
        backward = estimate_flow(
            current,
            previous,
            method=method,
            params=params,
            init=-forward if method.supports_init else None,
            roi=config.roi,
        )
        _save(backward_file, backward)
        if staging is not None:
            keep.append(backward)
        previous = current
    _store_flows(staging, "flow_backward", a, keep)
    _touch(_flow_marker(scratch, k), {"start": a, "stop": b})
    return k


def _load_seed(scratch: str, k: int) -> NDArray[np.float32]:
    """Chunk k's last forward flow (saved by its flow task, in this run or an interrupted
    one)."""
    return np.load(_seed_file(scratch, k), allow_pickle=False)


def _fuse_task(
    source: RecordingSource,
    scratch: str,
    staging: str,
    k: int,
    frames: tuple[int, int, int, int],
    intrinsics: Intrinsics,
    params: FusionParams,
    on_disk: bool,
    *after: Any,
) -> int:
    """Output frames ``[s, e)`` from the frames ``[lo, hi)``, exactly as
    :func:`fuse4d.scale.graph._fuse_block`, written as chunk k; returns k.

    The frames shared with a neighbouring chunk (``[lo, s + future)`` with chunk k-1,
    ``[e - past, hi)`` with chunk k+1) take their :class:`FrameState` from the neighbour's
    task where it ran in this process (:class:`_StateMemo`) or, ``on_disk``, saved it to the
    scratch folder; they keep theirs (and save them, ``on_disk``) where the neighbour is still
    to run."""
    s, e, lo, hi = frames
    h, w = intrinsics.height, intrinsics.width
    depth = np.empty((e - s, h, w), np.float32)
    support = np.empty((e - s, h, w), np.uint8)
    filled = np.empty((e - s, h, w), np.bool_)
    source_codes = np.empty((e - s, h, w), np.uint8)
    confidence = np.empty((e - s, h, w), np.float32)
    a, b = s - lo, e - lo
    state_key = _state_key(source, intrinsics, params)
    key = (scratch, state_key)
    limit = 2 * (params.past_frames + params.future_frames)
    left = range(lo, min(s + params.future_frames, e)) if s > 0 else range(0)
    right = range(max(e - params.past_frames, lo), hi) if e < source.frames else range(0)
    save_left = bool(left) and not _marker(Path(staging), k - 1).exists()
    save_right = bool(right) and not _marker(Path(staging), k + 1).exists()

    def take(out: list[Any]) -> None:
        for fr in out:
            if a <= fr.index < b:
                depth[fr.index - a] = fr.points[..., 2]
                support[fr.index - a] = fr.support
                filled[fr.index - a] = fr.filled
                source_codes[fr.index - a] = fr.source
                confidence[fr.index - a] = fr.confidence

    with chunk_engine(intrinsics, params, (a, b), hi - lo, stream_start=s == 0) as engine:
        for t in range(lo, hi):
            depth_t, intensity_t = source.frame(t)
            pair = None
            if t > lo:
                forward_file, backward_file = _pair_files(scratch, t - 1)
                pair = (
                    np.load(forward_file, allow_pickle=False),
                    np.load(backward_file, allow_pickle=False),
                )
            state = None
            if t in left or t in right:
                state = _MEMO.take((*key, t))
                if state is None and on_disk:
                    state = _load_state(_state_file(scratch, t), state_key)
                    _MEMO.loaded += state is not None
            take(engine.push(depth_t, intensity_t, pair_flow=pair, state=state))
            if state is None and ((save_left and t in left) or (save_right and t in right)):
                kept = engine.frame_state(t - lo)
                _MEMO.put((*key, t), kept, limit)
                if on_disk and not _state_file(scratch, t).exists():
                    _save_state(_state_file(scratch, t), kept, state_key)
        if hi == source.frames:
            take(engine.flush())
    return write_chunk(
        staging, k, s, depth, support, filled, source=source_codes, confidence=confidence
    )


def _drop_task(scratch: str, k: int, bounds: tuple[int, int], *after: Any) -> int:
    """Delete chunk k's pair files and its frames' saved states (their readers are done);
    its seed stays."""
    with _scratch_errors(scratch):
        _flow_marker(scratch, k).unlink(missing_ok=True)  # first: no marker = must recompute
        for j in range(*bounds):
            for path in _pair_files(scratch, j):
                path.unlink(missing_ok=True)
        for t in range(bounds[0], bounds[1] + 1):  # the pairs' frames
            _state_file(scratch, t).unlink(missing_ok=True)
    return k


# ------------------------------------------------------------------------------------ graph
def recording_tasks(
    source: RecordingSource,
    out: ZarrOutput,
    intrinsics: Intrinsics,
    *,
    fusion: FusionParams,
    flow: FlowConfig,
    chunk_frames: int,
    warm_start: bool = True,
    lookahead: int | None = None,
    share_states: bool = False,
) -> list[Any]:
    """The delayed tasks that fuse ``source`` into ``out`` (the unfinished chunks only).

    Parameters
    ----------
    source : RecordingSource
    out : ZarrOutput
        Created with the same ``chunk_frames``; its staging folder holds the scratch flows.
    intrinsics : Intrinsics
        Pinhole camera (px).
    fusion : FusionParams
        ``iterations`` must be 1 (more iterations need the in-memory graph).
    flow : FlowConfig
        Tracker and its parameters.
    chunk_frames : int
        Frames per fusion task and pairs per flow task.
    warm_start : bool
        Chain warm starts across pairs (the in-memory default).
    lookahead : int, optional
        Each flow task waits for the ``lookahead``-th newest fusion task that does not need
        it, so the flow stage runs at most that many chunks ahead of the fusion (dask's ordering would otherwise solve the whole
        flow chain first, and the scratch files would grow with the recording). Use the
        number of worker threads + 2 (fewer starves the workers); None: unbounded.
    share_states : bool
        Hand the halo frames' states between neighbouring chunks through the scratch folder
        too, not only within a worker process: for more than one worker process (one
        process, however many threads, needs none: its tasks share the memory).

    Returns
    -------
    list of Delayed
        Compute them together (one call); the output is then ready for ``out.finalize()``.
    """
    if fusion.iterations != 1:
        raise ParameterError("recording_tasks fuses one iteration; use fuse() + write_zarr")
    if lookahead is not None and lookahead < 1:
        raise ParameterError(f"lookahead must be >= 1, got {lookahead}")
    total = source.frames
    bounds = chunk_bounds(total, chunk_frames)
    missing = sorted(set(range(len(bounds))) - out.done_chunks())
    if not missing:
        return []
    scratch = flow_scratch(out.staging)
    with _scratch_errors(scratch):
        scratch.mkdir(exist_ok=True)
    pairs = chunk_bounds(max(total - 1, 0), chunk_frames)
    past, future = fusion.past_frames, fusion.future_frames

    def window(k: int) -> tuple[int, int, int, int]:
        s, e = bounds[k]
        return s, e, max(0, s - past), min(total, e + future)

    def flow_chunks(k: int) -> list[int]:
        """The pair chunks fusion chunk k reads (pairs [lo, hi - 1))."""
        _, _, lo, hi = window(k)
        return [j for j, (a, b) in enumerate(pairs) if a < hi - 1 and b > lo]

    consumers: dict[int, list[int]] = {j: [] for j in range(len(pairs))}
    for k in missing:
        for j in flow_chunks(k):
            consumers[j].append(k)
    need = {j for j, ks in consumers.items() if ks}
    if out.save_flows:  # every shard of the output's flow arrays
        need |= {j for j in range(len(pairs)) if not _seed_file(str(scratch), j).exists()}
    chained = warm_start and get_flow_method(flow.method).supports_init
    compute = {j for j in need if not _flow_marker(str(scratch), j).exists()}
    if chained:  # a recomputed chunk starts from its predecessor's seed: saved or recomputed
        for j in sorted(compute, reverse=True):
            i = j - 1
            while i >= 0 and i not in compute and not _seed_file(str(scratch), i).exists():
                compute.add(i)
                i -= 1
    staging = str(out.staging)
    flow_staging = staging if out.save_flows else None
    split = _splits(flow)
    chain: dict[int, Any] = {}  # the task that saves pair chunk j's seed
    tokens: dict[int, Any] = {}  # the task after which pair chunk j is complete
    fused: dict[int, Any] = {}
    drops: dict[int, Any] = {}
    k_next = 0  # fusion tasks are built as soon as their flow tasks exist
    droppable = sorted(need | compute)

    def build(upto: int) -> None:
        """The fusion tasks that read pair chunks <= ``upto`` only, then the drop tasks whose
        readers all exist."""
        nonlocal k_next
        while k_next < len(missing) and max(flow_chunks(missing[k_next]), default=-1) <= upto:
            k = missing[k_next]
            after = [tokens[j] for j in flow_chunks(k) if j in tokens]
            fused[k] = dask.delayed(_fuse_task, pure=False)(
                source,
                str(scratch),
                staging,
                k,
                window(k),
                intrinsics,
                fusion,
                share_states,
                *after,
            )
            k_next += 1
        while droppable and all(k in fused for k in consumers[droppable[0]]):
            j = droppable.pop(0)
            if j > upto and j in compute:
                droppable.insert(0, j)  # its flow task does not exist yet
                break
            after = [fused[k] for k in consumers[j]] + ([tokens[j]] if j in tokens else [])
            drops[j] = dask.delayed(_drop_task, pure=False)(str(scratch), j, pairs[j], *after)

    for j in sorted(compute):
        seed_chunk = j - 1 if chained and j > 0 else None  # saved earlier or by chain[j - 1]
        previous = [chain[j - 1]] if seed_chunk is not None and j - 1 in chain else []
        build(j - 1)
        # bounded look-ahead: pair chunk j waits for the lookahead-th newest fusion task that
        # does not read it, and for the deletion of the pairs that fusion was the last to read
        # (dask would run the cheap deletions last)
        wait = []
        built = sorted(fused)
        if lookahead is not None and len(built) >= lookahead:
            k = built[-lookahead]
            wait.append(fused[k])
            done = [i for i in drops if max(consumers[i], default=-1) <= k]
            if done:
                wait.append(drops[max(done)])
        args = (source, str(scratch), flow_staging, j, pairs[j])
        if split:
            with dask.annotate(priority=_FLOW_PRIORITY + 1):  # the chain first
                chain[j] = dask.delayed(_forward_task, pure=False)(
                    *args, seed_chunk, flow, chained, *previous, *wait
                )
            with dask.annotate(priority=_FLOW_PRIORITY):
                tokens[j] = dask.delayed(_backward_task, pure=False)(*args, flow, chain[j])
        else:
            with dask.annotate(priority=_FLOW_PRIORITY):
                tokens[j] = dask.delayed(_flow_task, pure=False)(
                    *args, seed_chunk, flow, chained, *previous, *wait
                )
            chain[j] = tokens[j]
    build(len(pairs))
    results = [fused[k] for k in missing] + [drops[j] for j in sorted(drops)]
    for j in set(range(len(pairs))) - need - compute:  # left by an interrupted run, unread
        if _flow_marker(str(scratch), j).exists():
            _drop_task(str(scratch), j, pairs[j])
    return results


def source_of(
    path: str | Path, fmt: str, num_frames: int, **reader_options: Any
) -> RecordingSource:
    """The :class:`RecordingSource` of a recording opened by :func:`fuse4d.scale.open_lazy`
    (``num_frames`` frames, read with the :func:`fuse4d.io.open_frames` options
    ``reader_options``, a ``frames`` range among them)."""
    src = Path(path).resolve()
    return RecordingSource(
        str(src), fmt, fingerprint_input(src), tuple(sorted(reader_options.items())), num_frames
    )
