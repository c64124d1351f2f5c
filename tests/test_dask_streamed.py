"""The bounded-memory graph behind ``fuse4d run --engine dask`` (fuse4d.scale.streamed):
same bits as the in-memory path, scratch flows dropped, resumable."""

from __future__ import annotations

import dataclasses
import os
import warnings

import pytest

pytest.importorskip("dask.array")
pytest.importorskip("zarr")

import dask
import zarr

from fuse4d import FusionParams, fuse_sequence
from fuse4d.config import preset
from fuse4d.flow import estimate_sequence_flow
from fuse4d.io import save_sequence
from fuse4d.scale import streamed
from fuse4d.scale.cli import run_dask
from fuse4d.scale.zarr_out import ZarrOutput
from fuse4d.sequence import Sequence
from test_dask import _crop, _same, make_falling_ball


@pytest.fixture(scope="module")
def ball() -> Sequence:
    return _crop(make_falling_ball(small=True, num_frames=20), 20)


def _check(store_path, ref) -> None:
    store = zarr.open_group(str(store_path), mode="r")
    assert _same(store["depth"][:], ref.depth)
    assert _same(store["support"][:], ref.support)
    assert _same(store["filled"][:], ref.filled)
    assert _same(store["source"][:], ref.source)
    assert _same(store["confidence"][:], ref.confidence)


def _run(seq, tmp_path, name, **kwargs):
    path = tmp_path / f"{name}.npz"
    save_sequence(seq, path)
    kwargs.setdefault("fusion", FusionParams())
    kwargs.setdefault("flow", preset("fast").flow)
    (summary,) = run_dask([path], tmp_path / f"{name}.zarr", progress=False, **kwargs)
    return summary


@pytest.mark.parametrize(
    ("chunk_frames", "fusion"),
    [
        (3, FusionParams()),  # chunk < halo, uneven last chunk
        (7, FusionParams()),
        (32, FusionParams()),  # one chunk
        (4, FusionParams(num_frames=5, causal=True)),
        (7, FusionParams(tracks="composed")),  # A31: the halos' chains (FusionEngine._emit_stop)
        (4, FusionParams(num_frames=5, causal=True, tracks="composed")),
    ],
)
def test_streamed_equals_in_memory(ball, tmp_path, chunk_frames, fusion):
    summary = _run(ball, tmp_path, "r", chunk_frames=chunk_frames, fusion=fusion)
    _check(
        summary.output, fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion)
    )
    assert not (summary.output / ".fuse4d-flows").exists()


def test_run_releases_the_idle_chunk_engine(ball, tmp_path):
    """A finished ``fuse4d run --engine dask`` leaves no chunk engine (≈ 0.3 GB at 600 x 600)
    in the process that ran its tasks (here the caller's: threads scheduler)."""
    from fuse4d.scale import graph

    built = graph._ENGINES.built
    _run(ball, tmp_path, "release", chunk_frames=7, scheduler="threads", workers=1)
    assert graph._ENGINES.built > built  # the run's tasks used the pool...
    assert graph._ENGINES._idle is None  # ...and the run gave its engine back


def test_chunks_are_evened_out_over_the_recording(ball, tmp_path):
    summary = _run(ball, tmp_path, "even", chunk_frames=6)  # 20 frames: 4 x 5, not 6+6+6+2
    assert (summary.chunks, summary.chunk_frames) == (4, 5)
    assert zarr.open_group(str(summary.output), mode="r")["depth"].shards[0] == 5
    _check(summary.output, fuse_sequence(ball.depth, ball.intensity, ball.intrinsics))


@pytest.mark.parametrize(
    "fusion", [FusionParams(), FusionParams(num_frames=5, causal=True)], ids=["9", "causal"]
)
def test_halo_frames_are_prepared_once(ball, tmp_path, monkeypatch, fusion):
    """The frames two chunks both push: the second task takes the first's FrameState."""
    from fuse4d.fusion import FusionEngine

    derived = []
    real = FusionEngine._derive
    monkeypatch.setattr(
        FusionEngine, "_derive", lambda self, *a: derived.append(1) or real(self, *a)
    )
    taken = streamed._MEMO.taken
    summary = _run(ball, tmp_path, "halo", chunk_frames=10, fusion=fusion, workers=1)
    # 2 chunks, 1 boundary: its frames computed by the first task, taken by the second
    assert streamed._MEMO.taken - taken == fusion.past_frames + fusion.future_frames
    assert len(derived) == ball.num_frames  # each frame's state computed once
    assert not [k for k in streamed._MEMO._states if k[0].startswith(str(tmp_path))]  # all taken
    assert not (summary.output / ".fuse4d-flows").exists()
    _check(
        summary.output, fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion)
    )


def test_halo_states_cross_worker_processes_through_the_scratch_folder(ball, tmp_path, monkeypatch):
    """share_states (several worker processes): a neighbour in another process, which does
    not see this one's memory, loads the saved state instead of computing it."""
    monkeypatch.setattr(streamed._MEMO, "take", lambda key: None)  # as in another process
    loaded = []
    load = streamed._load_state

    def counted(*args):
        state = load(*args)
        loaded.append(state is not None)
        return state

    monkeypatch.setattr(streamed, "_load_state", counted)
    path = tmp_path / "rec.npz"
    save_sequence(ball, path)
    k = ball.intrinsics
    out = ZarrOutput(tmp_path / "o.zarr", shape=ball.depth.shape, chunk_frames=10,
                     intrinsics=k, metadata={})  # fmt: skip
    source = streamed.source_of(path, "npz", ball.num_frames)
    tasks = streamed.recording_tasks(source, out, k, fusion=FusionParams(),
                                     flow=preset("fast").flow, chunk_frames=10,
                                     share_states=True)  # fmt: skip
    dask.compute(*tasks, scheduler="sync")
    assert sum(loaded) == 8  # the one boundary's past + future frames
    assert not list(streamed.flow_scratch(out.staging).glob("state-*"))  # dropped once read
    _check(out.finalize(), fuse_sequence(ball.depth, ball.intensity, k))


def test_a_stale_saved_state_is_not_loaded(ball, tmp_path):
    from fuse4d.fusion import FusionEngine

    engine = FusionEngine(ball.intrinsics)
    engine.push(ball.depth[0], ball.intensity[0])
    path = tmp_path / "state-0000000.npy"
    streamed._save_state(path, engine.frame_state(0), "key-a")
    back = streamed._load_state(path, "key-a")
    assert _same(back.bilateral, engine.frame_state(0).bilateral)
    assert streamed._load_state(path, "key-b") is None  # other input or parameters
    path.write_bytes(path.read_bytes()[:1000])  # truncated
    assert streamed._load_state(path, "key-a") is None
    assert streamed._load_state(tmp_path / "missing.npy", "key-a") is None


def test_flow_cache_solves_both_directions_in_one_task(ball, tmp_path, monkeypatch):
    """A flow cache keys the pair as a whole, so its chunks keep one flow task (the path of
    the pair-function methods, PMBP); same bits as in memory, and a second run hits the
    cache."""
    calls = []
    real = streamed._flow_task
    monkeypatch.setattr(streamed, "_flow_task", lambda *a: calls.append(a[3]) or real(*a))
    flow = dataclasses.replace(preset("fast").flow, cache_dir=str(tmp_path / "cache"))
    summary = _run(ball, tmp_path, "cached", chunk_frames=7, flow=flow)
    assert sorted(calls) == [0, 1, 2]
    _check(summary.output, fuse_sequence(ball.depth, ball.intensity, ball.intrinsics))
    assert any((tmp_path / "cache").rglob("*"))


def test_streamed_fewer_frames_than_window_and_one_frame(ball, tmp_path):
    for t in (3, 1):
        seq = Sequence(ball.depth[:t], ball.intensity[:t], ball.intrinsics)
        summary = _run(seq, tmp_path, f"t{t}", chunk_frames=2)
        _check(summary.output, fuse_sequence(seq.depth, seq.intensity, seq.intrinsics))


def test_streamed_without_warm_start_and_saved_flows(ball, tmp_path):
    summary = _run(ball, tmp_path, "cold", chunk_frames=6, warm_start=False, save_flows=True)
    flows = estimate_sequence_flow(ball.intensity, warm_start=False)
    ref = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, flow=flows)
    _check(summary.output, ref)
    root = zarr.open_group(str(summary.output), mode="r")
    assert _same(root["flow_forward"][:], flows.forward)
    assert _same(root["flow_backward"][:], flows.backward)


def test_scratch_flows_are_dropped_and_resume_recomputes_only_what_is_missing(
    ball, tmp_path, monkeypatch
):
    path = tmp_path / "rec.npz"
    save_sequence(ball, path)
    ref = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics)
    k = ball.intrinsics
    fast = preset("fast")

    def output(resume=False):
        return ZarrOutput(tmp_path / "o.zarr", shape=ball.depth.shape, chunk_frames=4,
                          intrinsics=k, metadata={}, resume=resume)  # fmt: skip

    source = streamed.source_of(path, "npz", ball.num_frames)
    out = output()
    tasks = streamed.recording_tasks(source, out, k, fusion=FusionParams(), flow=fast.flow,
                                     chunk_frames=4)  # fmt: skip
    fuse_tasks = [t for t in tasks if "_fuse_task" in str(t.key)]
    assert len(fuse_tasks) == 5
    dask.compute(*fuse_tasks[:2], scheduler="sync")  # interrupted after two chunks
    scratch = streamed.flow_scratch(out.staging)
    assert len(list(scratch.glob("forward-*.npy"))) > 0
    calls = []
    for name in ("_forward_task", "_backward_task"):  # DIS: the directions split
        real = getattr(streamed, name)
        monkeypatch.setattr(
            streamed, name, lambda *a, f=real, n=name: calls.append((n, a[3])) or f(*a)
        )
    out = output(resume=True)
    assert out.done_chunks() == {0, 1}
    rest = streamed.recording_tasks(source, out, k, fusion=FusionParams(), flow=fast.flow,
                                    chunk_frames=4)  # fmt: skip
    dask.compute(*rest, scheduler="sync")
    # pair chunks 0-2 (read by chunks 0-1) were kept
    assert sorted(calls) == [(n, j) for n in ("_backward_task", "_forward_task") for j in (3, 4)]
    assert not list(scratch.glob("*ward-*.npy"))  # every pair file dropped once read
    _check(out.finalize(), ref)


@pytest.mark.parametrize("lookahead", [1, 2, None])
def test_bounded_lookahead_keeps_few_scratch_files(ball, tmp_path, monkeypatch, lookahead):
    path = tmp_path / "rec.npz"
    save_sequence(ball, path)
    k = ball.intrinsics
    out = ZarrOutput(tmp_path / "o.zarr", shape=ball.depth.shape, chunk_frames=2,
                     intrinsics=k, metadata={})  # fmt: skip
    source = streamed.source_of(path, "npz", ball.num_frames)
    scratch = streamed.flow_scratch(out.staging)
    most = []
    real = streamed._fuse_task
    monkeypatch.setattr(
        streamed, "_fuse_task",
        lambda *a: most.append(len(list(scratch.glob("forward-*.npy")))) or real(*a),
    )  # fmt: skip
    tasks = streamed.recording_tasks(source, out, k, fusion=FusionParams(), flow=preset("fast").flow,
                                     chunk_frames=2, lookahead=lookahead)  # fmt: skip
    dask.compute(*tasks, scheduler="sync")
    _check(out.finalize(), fuse_sequence(ball.depth, ball.intensity, k))
    if lookahead is None:
        assert max(most) == ball.num_frames - 1  # dask solves the whole flow chain first
    else:  # pairs of the chunks being read, and lookahead chunks ahead of them
        assert max(most) <= 2 * (lookahead + 4), most


@pytest.mark.slow
def test_streamed_through_a_local_cluster_with_two_worker_processes(ball, tmp_path):
    pytest.importorskip("distributed")
    from fuse4d.scale.cluster import local_cluster, slow_allocator_workers

    with local_cluster(2) as client, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert slow_allocator_workers(client) == []  # glibc's adaptive mmap threshold
        stealing = client.run_on_scheduler(
            lambda dask_scheduler: dask_scheduler.periodic_callbacks["stealing"].callback_time
        )
        assert stealing == 100  # ms: an idle worker takes a queued 0.3 s flow task early
        # distributed's own background work is quiet (QUIET_CONFIG): no stack profiler, the
        # event-loop tick and the monitors at 1-2 s, in the workers and the scheduler
        periods = client.run(
            lambda dask_worker: {
                k: c.callback_time for k, c in dask_worker.periodic_callbacks.items()
            }
        )
        for period in periods.values():
            assert not {"profile", "profile-cycle"} & set(period), period
            assert (period["tick"], period["memory_monitor"], period["monitor"]) == (
                1000,
                1000,
                2000,
            )
        assert (
            client.run_on_scheduler(
                lambda dask_scheduler: dask_scheduler.periodic_callbacks["tick"].callback_time
            )
            == 1000
        )
        summary = _run(ball, tmp_path, "lc", chunk_frames=4,
                       scheduler=client.scheduler.address)  # fmt: skip
    assert not [w for w in caught if "MALLOC_TRIM_THRESHOLD_" in str(w.message)]
    _check(summary.output, fuse_sequence(ball.depth, ball.intensity, ball.intrinsics))


@pytest.mark.slow
def test_workers_with_distributed_allocator_settings_get_a_warning(ball):
    """A stock LocalCluster's workers run with MALLOC_TRIM_THRESHOLD_ (distributed's
    default, ~1.4x slower fusion): open_compute on its address and fuse4d.dask.fuse with its
    client say how to start them."""
    pytest.importorskip("distributed")
    from distributed import Client, LocalCluster

    import fuse4d.dask as fd
    from fuse4d.scale.cluster import _restore_environ, open_compute

    saved = dict(os.environ)  # the nanny leaves its pre-spawn environment in os.environ
    try:
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                               dashboard_address=":0")  # fmt: skip
        with cluster:
            with (
                pytest.warns(RuntimeWarning, match="1 of 1 dask workers run with MALLOC_TRIM"),
                open_compute(cluster.scheduler_address, progress=False) as compute,
            ):
                assert compute() == ()
            with Client(cluster) as client, pytest.warns(RuntimeWarning, match="MALLOC_TRIM"):
                fd.fuse(ball.depth, ball.intensity, ball.intrinsics, client=client)
    finally:
        _restore_environ(saved)


def test_worker_pool_of_the_local_schedulers():
    from fuse4d.scale.cli import _worker_pool

    assert _worker_pool("threads", 3) == (1, 3)  # one process: states shared in memory
    assert _worker_pool("processes", 3) == (3, 3)  # states also through the scratch folder
    assert _worker_pool("sync", 3) == (1, 1)


def test_a_scheduler_without_workers_gets_a_warning():
    """A tcp:// scheduler with no workers left the run at 0 % with no word why."""
    pytest.importorskip("distributed")
    from distributed import LocalCluster

    from fuse4d.scale.cli import _worker_pool

    with (
        LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster,
        pytest.warns(RuntimeWarning, match="has no workers: the run waits"),
    ):
        assert _worker_pool(cluster.scheduler_address, None) == (1, 1)


def test_a_worker_that_died_before_the_allocator_check_is_named():
    """A dead worker made the allocator check (an advice) fail the run with "Stream is
    closed": the others are checked, and a warning says which did not answer."""
    from fuse4d.scale.cluster import slow_allocator_workers, warn_if_slow_allocator

    class Client:
        def run(self, function, on_error="raise"):
            answers = {"tcp://a:1": "65536", "tcp://b:1": None, "tcp://c:1": OSError("closed")}
            if on_error == "raise":
                raise answers["tcp://c:1"]
            return answers

        def scheduler_info(self):
            return {"workers": {"tcp://a:1": {}, "tcp://b:1": {}}}

    assert slow_allocator_workers(Client()) == ["tcp://a:1"]
    with pytest.warns(RuntimeWarning) as caught:
        warn_if_slow_allocator(Client())
    messages = [str(w.message) for w in caught]
    assert any("did not answer (tcp://c:1)" in m and "workers' logs" in m for m in messages)
    assert any(m.startswith("1 of 2 dask workers run with MALLOC_TRIM") for m in messages)


def _interrupt(store, done: int) -> None:
    """Turn the finished ``store`` into the staging store of a run interrupted after its
    first ``done`` chunks (as a Ctrl-C leaves it)."""
    import json
    import shutil

    partial = store.with_name(store.name + ".partial")
    shutil.move(store, partial)
    meta = json.loads((partial / "zarr.json").read_text())
    meta["attributes"]["fuse4d"]["complete"] = False
    (partial / "zarr.json").write_text(json.dumps(meta))
    (partial / ".fuse4d-done").mkdir()
    for k in range(done):
        (partial / ".fuse4d-done" / f"chunk-{k:06d}").write_text("{}")


def test_resume_compares_the_input_files_not_the_folder(ball, tmp_path):
    """The input is identified by its files' fingerprint, as the stream engine's manifest
    does: an input with a frame rewritten in place is refused (its folder's own size and
    mtime stay the same: it was resumed, chunks of two recordings mixed, and a finished
    store of it was 'already complete'); a moved copy, or a folder whose mtime changed with
    no file changed, is the same input."""
    import shutil

    from fuse4d import OutputExistsError, ParameterError
    from fuse4d.io import write_frame_folder

    rec = write_frame_folder(ball, tmp_path / "rec", depth_unit_mm=0.1)
    kwargs = {"fusion": FusionParams(), "flow": preset("fast").flow, "progress": False}
    kwargs |= {"chunk_frames": 4, "scheduler": "sync"}
    store = tmp_path / "o.zarr"
    (first,) = run_dask([rec], store, **kwargs)
    assert first.chunks == 5
    ref = zarr.open_group(str(shutil.copytree(store, tmp_path / "ref.zarr")), mode="r")
    moved = shutil.copytree(rec, tmp_path / "elsewhere" / "rec")  # mtimes kept (cp -a)
    (moved / "x").touch()  # the folder's mtime changes, no file of the recording does
    (moved / "x").unlink()
    edited = shutil.copytree(rec, tmp_path / "edited" / "rec")
    shutil.copyfile(edited / "depth" / "000015.png", edited / "depth" / "000010.png")
    shutil.copyfile(edited / "intensity" / "000015.png", edited / "intensity" / "000010.png")
    # a finished store: the same input (moved) is complete, an edited one is not
    (done,) = run_dask([moved], store, resume=True, **kwargs)
    assert (done.skipped, done.frames_fused) == (5, 0)
    with pytest.raises(OutputExistsError):
        run_dask([edited], store, resume=True, **kwargs)
    _interrupt(store, 3)
    with pytest.raises(ParameterError, match=r"differs in \['source'\]"):
        run_dask([edited], store, resume=True, **kwargs)
    (resumed,) = run_dask([moved], store, resume=True, **kwargs)
    assert (resumed.skipped, resumed.frames_fused) == (3, 8)
    out = zarr.open_group(str(store), mode="r")
    for name in ("depth", "support", "filled", "source", "confidence"):
        assert _same(out[name][:], ref[name][:]), name


def test_a_read_only_output_folder_gives_one_clear_line(ball, tmp_path, monkeypatch, capsys):
    """`--engine dask` into a read-only folder printed the bare "[Errno 30] Read-only file
    system: .../x.zarr.partial"; now the one line of every other command (OutputWriteError).
    Root ignores permission bits: the read-only mount is simulated."""
    import errno
    import pathlib

    from fuse4d.cli import main

    save_sequence(ball, tmp_path / "a.npz")
    ro = tmp_path / "ro"
    ro.mkdir()
    real_mkdir = pathlib.Path.mkdir

    def mkdir(self, *args, **kwargs):
        if ro in pathlib.Path(self).absolute().parents:
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return real_mkdir(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "mkdir", mkdir)
    run = ["run", str(tmp_path / "a.npz"), "--engine", "dask", "--workers", "1"]
    for out in (ro / "x.zarr", ro / "folder" / "sub"):  # one store; a folder of stores
        assert main([*run, "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"fuse4d: error: {out}: cannot write the output (Read-only"), err
        assert "choose another output path" in err
        assert len(err.splitlines()) == 1, err
    assert list(ro.iterdir()) == []


@pytest.mark.parametrize(
    ("where", "scheduler"),
    [
        ("/depth/c/", "threads"),  # a zarr shard of write_chunk
        ("/.fuse4d-flows/forward-", "threads"),  # a scratch flow of a flow task
        ("/.fuse4d-flows/flows-", "sync"),  # a flow task's marker
    ],
)
def test_a_full_disk_during_the_tasks_gives_one_clear_line(
    ball, tmp_path, monkeypatch, capsys, where, scheduler
):
    """A full disk while a task wrote a chunk or a scratch flow printed "fuse4d: error:
    [Errno 28] ..." naming a temporary (or an internal error); now the one line of
    OutputWriteError naming the output, and --resume finishes the run once there is space."""
    import errno
    import pathlib

    from fuse4d.cli import main

    save_sequence(ball, tmp_path / "a.npz")
    out = tmp_path / "x.zarr"
    real_open = pathlib.Path.open
    full = [True]

    def open_(self, mode="r", *args, **kwargs):
        if full[0] and "w" in mode and where in pathlib.Path(self).absolute().as_posix():
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return real_open(self, mode, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "open", open_)
    run = ["run", str(tmp_path / "a.npz"), "-o", str(out), "--engine", "dask"]
    run += ["--scheduler", scheduler, "--workers", "1", "--chunk-frames", "7"]
    assert main(run) == 2
    err = capsys.readouterr().err.strip()  # the progress bar, then the error
    line = err.splitlines()[-1]
    assert line.startswith(f"fuse4d: error: {out}: cannot write the output (No space left"), err
    assert "free some disk space" in line
    assert "Traceback" not in err, err
    assert "internal error" not in err, err
    assert not out.exists()
    full[0] = False
    assert main([*run, "--resume"]) == 0
    assert zarr.open_group(str(out), mode="r").attrs["fuse4d"]["complete"] is True


def test_the_report_of_a_resumed_run_is_not_given_this_sessions_time(
    ball, tmp_path, monkeypatch, capsys
):
    """`--engine dask --resume --report`: the report divided this session's time by every
    frame; the store does not record the earlier sessions' time, so it gets none."""
    from fuse4d.cli import cmd_report, main

    seen: list = []
    monkeypatch.setattr(
        cmd_report,
        "make_report",
        lambda input, output, report, **kw: seen.append(kw["fusion_seconds"]) or report,
    )
    save_sequence(ball, tmp_path / "a.npz")
    store = tmp_path / "o.zarr"
    args = ["run", str(tmp_path / "a.npz"), "-o", str(store), "--engine", "dask",
            "--chunk-frames", "4", "--workers", "1", "--report", str(tmp_path / "rep")]  # fmt: skip
    assert main(args) == 0
    _interrupt(store, 3)
    assert main([*args, "--resume"]) == 0
    assert seen[0] > 0
    assert seen[1] is None


@pytest.mark.parametrize("layout", ["npz", "folder"])
def test_a_rewritten_input_is_read_anew_in_the_same_process(ball, tmp_path, layout):
    """The tasks and this process's readers were keyed on the input's own mtime (a folder's
    stays when a frame file is rewritten in place) or not at all (the reader cache): a second
    run in the same process (a notebook, a cluster's long-lived workers) read the old frames."""
    import numpy as np

    from fuse4d.scale import open_lazy

    path = tmp_path / ("in.npz" if layout == "npz" else "in")
    other = tmp_path / ("other.npz" if layout == "npz" else "other")
    brighter = dataclasses.replace(ball, intensity=np.clip(ball.intensity + 0.25, 0, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the folder layout's lossy notes
        save_sequence(ball, path)
        save_sequence(brighter, other)
    before = open_lazy(path).intensity[:].compute()
    source = streamed.source_of(path, "npz" if layout == "npz" else "folder", ball.depth.shape[0])
    first = source.intensity(0)
    mtime = path.stat().st_mtime_ns
    for f in sorted(p for p in other.rglob("*") if p.is_file()) if path.is_dir() else [other]:
        target = path / f.relative_to(other) if path.is_dir() else path
        target.write_bytes(f.read_bytes())  # in place: the folder's mtime stays
    if path.is_dir():
        os.utime(path, ns=(mtime, mtime))
    after = open_lazy(path).intensity[:].compute()
    assert not np.array_equal(after, before)
    assert np.array_equal(after, open_lazy(other).intensity[:].compute())
    rewritten = streamed.source_of(
        path, "npz" if layout == "npz" else "folder", ball.depth.shape[0]
    )
    assert rewritten.stamp != source.stamp
    assert not np.array_equal(rewritten.intensity(0), first)
