"""The dask engine (fuse4d.dask): chunked == in-memory == streaming, bit for bit; zarr output,
resume, CLI; the same through a real LocalCluster of 2 worker processes."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dask.array")
pytest.importorskip("zarr")

import dask
import zarr

import fuse4d.dask as fd
from fuse4d import FusionEngine, FusionParams, Intrinsics, fuse_sequence, fuse_stream
from fuse4d.cli import main
from fuse4d.flow import estimate_sequence_flow, get_flow_method
from fuse4d.io import open_frames, save_sequence, write_frame_folder
from fuse4d.scale import graph
from fuse4d.scale._deps import require_scale_extra
from fuse4d.sequence import Sequence
from fuse4d.synthetic import make_falling_ball

ROW0, COL0, H, W = 40, 55, 32, 40


def _crop(seq: Sequence, frames: int) -> Sequence:
    k = seq.intrinsics
    cam = Intrinsics(k.fx, k.fy, k.cx - COL0, k.cy - ROW0, W, H)
    box = (slice(0, frames), slice(ROW0, ROW0 + H), slice(COL0, COL0 + W))
    return Sequence(seq.depth[box].copy(), seq.intensity[box].copy(), cam)


@pytest.fixture(scope="module")
def ball() -> Sequence:
    """20 frames of the falling ball, 32x40 px around the ball (moving edges, holes)."""
    return _crop(make_falling_ball(small=True, num_frames=20), 20)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)


def _assert_equal(res: fd.DaskFusion, ref, **compute) -> None:
    points, depth, support, filled = dask.compute(
        res.points, res.depth, res.support, res.filled, **compute
    )
    assert _same(points, ref.points)
    assert _same(depth, ref.depth)
    assert _same(support, ref.support)
    assert _same(filled, ref.filled)


def _stream(seq: Sequence, fusion: FusionParams, **engine) -> np.ndarray:
    eng = FusionEngine(seq.intrinsics, fusion=fusion, **engine)
    frames = []
    for t in range(seq.num_frames):
        frames += eng.push(seq.depth[t], seq.intensity[t])
    frames += eng.flush()
    return np.stack([f.points for f in frames])


@pytest.fixture(scope="module")
def reference(ball: Sequence):
    return fuse_sequence(ball.depth, ball.intensity, ball.intrinsics)


def test_streaming_engine_equals_in_memory(ball, reference):
    streamed = np.stack(
        [
            f.points
            for f in fuse_stream(zip(ball.depth, ball.intensity, strict=True), ball.intrinsics)
        ]
    )
    assert _same(streamed, reference.points)


@pytest.mark.parametrize("chunk_frames", [1, 3, 7, 20, 64])
def test_chunked_equals_in_memory(ball, reference, chunk_frames):
    res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=chunk_frames)
    assert res.depth.chunks[0][-1] == (20 % chunk_frames or min(chunk_frames, 20))
    _assert_equal(res, reference, scheduler="threads")
    fwd, bwd = dask.compute(res.flows.forward, res.flows.backward)
    assert _same(fwd, reference.flow_forward)
    assert _same(bwd, reference.flow_backward)


@pytest.mark.parametrize("chunk_frames", [3, 7])
def test_chunked_exact_tracks_equal_in_memory(ball, chunk_frames):
    """A31 off (``tracks="exact"``, METHOD; composed tracks are the default and covered by
    ``test_chunked_equals_in_memory``): the chunk engines fuse as the in-memory engine does."""
    fusion = FusionParams(tracks="exact")
    expected = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion)
    res = fd.fuse(
        ball.depth, ball.intensity, ball.intrinsics, fusion=fusion, chunk_frames=chunk_frames
    )
    _assert_equal(res, expected, scheduler="threads")


def test_chunk_engines_are_reused_and_give_the_same_bits(ball, reference):
    """A process's fusion tasks hand their engine on (``graph._EnginePool``): the next chunk
    resets it instead of building one. An engine whose buffers hold another recording's
    frames (bright noise, depth 300 mm nearer, holes elsewhere) must fuse as a new one; an
    engine of other parameters is not taken."""
    rng = np.random.default_rng(5)
    other_depth = ball.depth[::-1] - 300.0 + rng.normal(0, 3, ball.depth.shape).astype(np.float32)
    other_depth[:, :8] = np.nan
    other_inten = rng.random(ball.intensity.shape).astype(np.float32)
    pool = graph._ENGINES
    pool.clear()
    fd.fuse(other_depth, other_inten, ball.intrinsics, chunk_frames=6).depth.compute(
        scheduler="synchronous"
    )
    built, reused = pool.built, pool.reused
    assert pool._idle is not None
    res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=6)
    _assert_equal(res, reference, scheduler="synchronous")
    assert pool.built == built  # every chunk (4 of them, computed once) took the idle engine
    assert pool.reused >= reused + 4
    fusion = FusionParams(num_frames=5)
    expected = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion)
    res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion, chunk_frames=20)
    _assert_equal(res, expected, scheduler="synchronous")
    assert pool.built > built  # other parameters: a new engine


def test_release_engines_here_and_on_a_clients_workers(ball):
    """``fuse4d.dask.release_engines`` drops the idle chunk engine of this process and, given a
    client, of each of its workers (one worker process here)."""
    pytest.importorskip("distributed")
    from fuse4d.scale.cluster import local_cluster

    pool = graph._ENGINES
    res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=12)
    res.depth.compute(scheduler="synchronous")
    assert pool._idle is not None
    assert fd.release_engines() == 1
    assert pool._idle is None
    assert fd.release_engines() == 0
    with local_cluster(1) as client:  # (the project's: no allocator warning in later tests)
        res.depth.compute()  # in the worker process: this process's pool stays empty
        assert pool._idle is None
        assert fd.release_engines(client) == 1
        assert fd.release_engines(client) == 0


def test_fewer_frames_than_window(ball):
    seq = _crop(make_falling_ball(small=True, num_frames=5), 5)
    ref = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics)  # 9-frame window, T = 5
    for c in (2, 5):
        _assert_equal(fd.fuse(seq.depth, seq.intensity, seq.intrinsics, chunk_frames=c), ref)
    one = fuse_sequence(seq.depth[:1], seq.intensity[:1], seq.intrinsics)
    _assert_equal(fd.fuse(seq.depth[:1], seq.intensity[:1], seq.intrinsics), one)


def test_causal_mode(ball):
    fusion = FusionParams(causal=True, num_frames=5)
    ref = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion)
    assert _same(_stream(ball, fusion), ref.points)
    for c in (3, 8):
        res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion, chunk_frames=c)
        _assert_equal(res, ref)


def test_without_warm_start_equals_cold_in_memory_and_streaming(ball):
    fusion = FusionParams(num_frames=5)
    cold = estimate_sequence_flow(ball.intensity, warm_start=False)
    ref = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion, flow=cold)
    assert _same(_stream(ball, fusion, warm_start=False), ref.points)
    res = fd.fuse(
        ball.depth, ball.intensity, ball.intrinsics, fusion=fusion, chunk_frames=6,
        warm_start=False,
    )  # fmt: skip
    _assert_equal(res, ref)
    assert not res.flows.warm_start


@pytest.mark.parametrize("warm_start", [True, False])
def test_flow_chain_equals_sequence_flow_split_anywhere(ball, warm_start):
    """graph._flow_chain (shared by the in-memory and the streamed graph) gives the bits of
    estimate_sequence_flow, also when split into two chains seeded with the last forward."""
    ref = estimate_sequence_flow(ball.intensity[:8], warm_start=warm_start)
    method = get_flow_method("dis")

    def chain(frames, seed):
        return list(graph._flow_chain(frames, method, None, seed, warm_start, None, None))

    whole = chain(iter(ball.intensity[:8]), None)  # any iterable: read lazily, in order
    head = chain(list(ball.intensity[:4]), None)
    tail = chain(list(ball.intensity[3:8]), head[-1][0])
    for pairs in (whole, head + tail):
        assert len(pairs) == 7
        assert _same(np.stack([f for f, _ in pairs]), ref.forward)
        assert _same(np.stack([g for _, g in pairs]), ref.backward)


def test_every_pair_flow_and_chunk_is_computed_once(ball, monkeypatch, tmp_path):
    calls = {"estimate_flow_pair": 0, "_fuse_block": 0}

    def counted(name):
        original = getattr(graph, name)

        def wrapper(*args, **kwargs):
            calls[name] += 1
            return original(*args, **kwargs)

        monkeypatch.setattr(graph, name, wrapper)

    counted("estimate_flow_pair")
    counted("_fuse_block")
    emitted: list[int] = []
    emit = FusionEngine._emit
    monkeypatch.setattr(
        FusionEngine, "_emit", lambda self, t, **kw: emitted.append(t) or emit(self, t, **kw)
    )
    res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=3)
    dask.compute(res.depth, res.support, res.filled, res.flows.forward, scheduler="threads")
    assert calls == {"estimate_flow_pair": ball.num_frames - 1, "_fuse_block": res.num_chunks}
    # halo frames are inputs, not fused outputs; only the chunk before the last one, whose
    # halo reaches the end of the sequence, flushes (4 = future_frames) frames it does not keep
    assert ball.num_frames <= len(emitted) <= ball.num_frames + 4
    calls.update(estimate_flow_pair=0, _fuse_block=0)
    fd.write_zarr(res, tmp_path / "once.zarr", intrinsics=ball.intrinsics)
    assert calls == {"estimate_flow_pair": ball.num_frames - 1, "_fuse_block": res.num_chunks}


def test_iterations_and_precomputed_zarr_inputs(ball, tmp_path):
    fusion = FusionParams(num_frames=5, iterations=2)
    ref = fuse_sequence(ball.depth, ball.intensity, ball.intrinsics, fusion=fusion)
    root = zarr.open_group(str(tmp_path / "in.zarr"), mode="w")
    depth = root.create_array("depth", data=ball.depth, chunks=(4, H, W))
    intensity = root.create_array("intensity", data=ball.intensity, chunks=(4, H, W))
    forward = root.create_array("forward", data=ref.flow_forward, chunks=(5, H, W, 2))
    backward = root.create_array("backward", data=ref.flow_backward, chunks=(5, H, W, 2))
    res = fd.fuse(depth, intensity, ball.intrinsics, fusion=fusion, flow=(forward, backward))
    _assert_equal(res, ref)
    flows = fd.flows(intensity, chunk_frames=4).compute()
    assert _same(flows.forward, ref.flow_forward)
    assert _same(flows.backward, ref.flow_backward)


def test_zarr_output_and_resume_after_interruption(ball, reference, tmp_path):
    res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=3)
    out = tmp_path / "out.zarr"

    def crash_after_two(*tasks):
        dask.compute(*tasks[:2])
        raise KeyboardInterrupt  # the run dies here

    with pytest.raises(KeyboardInterrupt):
        fd.write_zarr(res, out, intrinsics=ball.intrinsics, compute=crash_after_two)
    assert not out.exists()  # incomplete output stays under OUT.zarr.partial
    partial = zarr.open_group(str(tmp_path / "out.zarr.partial"), mode="r")
    assert partial.attrs["fuse4d"]["complete"] is False
    with pytest.raises(FileExistsError, match="--resume"):
        fd.write_zarr(res, out, intrinsics=ball.intrinsics)

    def only_the_rest(*tasks):
        assert len(tasks) == res.num_chunks - 2  # finished chunks are not recomputed
        return dask.compute(*tasks)

    fd.write_zarr(res, out, intrinsics=ball.intrinsics, resume=True, compute=only_the_rest)
    store = zarr.open_group(str(out), mode="r")
    assert store.attrs["fuse4d"]["complete"] is True
    assert store.attrs["intrinsics"]["fx"] == ball.intrinsics.fx
    assert store["depth"].metadata.dimension_names == ("t", "y", "x")
    assert store["depth"].shards == (3, H, W)
    assert _same(store["depth"][:], reference.depth)
    assert _same(store["support"][:], reference.support)
    assert _same(store["filled"][:], reference.filled)
    assert _same(store["source"][:], reference.source)
    assert _same(store["confidence"][:], reference.confidence)
    other = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=3,
                    fusion=FusionParams(num_frames=5))  # fmt: skip
    with pytest.raises(FileExistsError):
        fd.write_zarr(other, out, intrinsics=ball.intrinsics)


def test_saved_flows_are_the_fusion_flows_and_can_be_reused(ball, reference, tmp_path):
    res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=6)
    out = fd.write_zarr(res, tmp_path / "f.zarr", intrinsics=ball.intrinsics, save_flows=True)
    root = zarr.open_group(str(out), mode="r")
    assert root["flow_forward"].metadata.dimension_names == ("t", "y", "x", "uv")
    assert _same(root["flow_forward"][:], reference.flow_forward)
    assert _same(root["flow_backward"][:], reference.flow_backward)
    again = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=4,
                    flow=(root["flow_forward"], root["flow_backward"]))  # fmt: skip
    _assert_equal(again, reference)


def test_cli_many_inputs_share_one_run(ball, tmp_path, capsys):
    second = Sequence(ball.depth[:11], ball.intensity[:11], ball.intrinsics)
    save_sequence(ball, tmp_path / "a.npz")
    save_sequence(second, tmp_path / "b.npz")
    outdir = tmp_path / "fused"
    args = ["run", str(tmp_path / "a.npz"), str(tmp_path / "b.npz"), "-o", str(outdir)]
    assert main([*args, "--engine", "dask", "--chunk-frames", "4", "--workers", "2", "--json"]) == 0
    assert '"frames": 11' in capsys.readouterr().out
    for name, seq in (("a", ball), ("b", second)):
        ref = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics)
        store = zarr.open_group(str(outdir / f"{name}.zarr"), mode="r")
        assert _same(store["depth"][:], ref.depth)
        assert _same(store["support"][:], ref.support)
    dask_args = [*args, "--engine", "dask", "--chunk-frames", "4"]
    assert main([*dask_args, "--resume"]) == 0  # complete: nothing to do
    assert main(dask_args) == 2  # exists
    assert main(args) == 2  # several inputs need the dask engine
    assert "need --engine dask" in capsys.readouterr().err


def test_a_run_killed_inside_finalize_resumes_and_report_refuses_an_unfinished_store(
    ball, tmp_path, capsys
):
    """A kill after the store was marked complete and its chunk markers removed, before the
    rename: --resume recomputed every chunk and then failed on the missing marker folder,
    on every retry. And `fuse4d report` scored an unfinished store's unwritten chunks (all
    NaN) as the fused result."""
    import json
    import shutil

    save_sequence(ball, tmp_path / "a.npz")
    out = tmp_path / "o.zarr"
    args = ["run", str(tmp_path / "a.npz"), "-o", str(out), "--engine", "dask",
            "--chunk-frames", "4", "--workers", "1"]  # fmt: skip
    assert main(args) == 0
    reference = zarr.open_group(str(out), mode="r")["depth"][:]
    partial = tmp_path / "o.zarr.partial"
    shutil.copytree(out, partial)
    meta = json.loads((partial / "zarr.json").read_text())
    # the state a kill between finalize's marking and its rename leaves
    out_moved = tmp_path / "done.zarr"
    out.rename(out_moved)
    assert meta["attributes"]["fuse4d"]["complete"] is True
    assert main([*args, "--resume", "--json"]) == 0
    capsys.readouterr()
    assert not partial.exists()
    assert _same(zarr.open_group(str(out), mode="r")["depth"][:], reference)
    # an unfinished store: refused by the report
    shutil.copytree(out_moved, partial)
    meta["attributes"]["fuse4d"]["complete"] = False
    (partial / "zarr.json").write_text(json.dumps(meta))
    rep = tmp_path / "rep"
    assert main(["report", str(tmp_path / "a.npz"), str(partial), "-o", str(rep)]) == 2
    err = capsys.readouterr().err
    assert "o.zarr.partial: unfinished fuse4d run --engine dask" in err
    assert not rep.exists()


def test_cli_checks_every_input_and_the_output_kind_before_writing(ball, tmp_path, capsys):
    """A bad second input left the first one's staging store (the next run then asked for
    --resume); -o x.npz made a folder called x.npz."""
    save_sequence(ball, tmp_path / "a.npz")
    (tmp_path / "bad.npz").write_bytes(b"garbage")
    out = tmp_path / "fused"
    args = ["run", str(tmp_path / "a.npz"), str(tmp_path / "bad.npz"), "-o", str(out)]
    assert main([*args, "--engine", "dask"]) == 2
    assert "bad.npz: not a valid .npz file" in capsys.readouterr().err
    assert not out.exists()
    npz_out = tmp_path / "m.npz"
    assert main(["run", str(tmp_path / "a.npz"), "-o", str(npz_out), "--engine", "dask"]) == 2
    assert "--engine dask writes zarr stores" in capsys.readouterr().err
    assert not npz_out.exists()


def test_cli_chunk_frames_default_is_run_dasks(ball, tmp_path, monkeypatch):
    """`fuse4d run --engine dask` without --chunk-frames uses run_dask's default (the CLI
    spells the number out so that --help does not import dask)."""
    from fuse4d.scale import cli as scale_cli

    seen = {}

    def record(inputs, output, fusion, flow, opts, *args):
        seen.update(opts)

    monkeypatch.setattr(scale_cli, "print_dask_run", record)
    save_sequence(ball, tmp_path / "a.npz")
    assert (
        main(["run", str(tmp_path / "a.npz"), "-o", str(tmp_path / "o.zarr"), "--engine", "dask"])
        == 0
    )
    assert seen["chunk_frames"] == scale_cli.RUN_CHUNK_FRAMES == 16


@pytest.mark.parametrize("frames_per_task", [1, 6])
def test_lazy_frame_folder_equals_streaming_reader(ball, tmp_path, frames_per_task):
    folder = write_frame_folder(ball, tmp_path / "rec", depth_unit_mm=0.1)
    rec = fd.open_lazy(folder, frames_per_task=frames_per_task)
    assert rec.format == "folder"
    assert rec.depth.numblocks[0] == -(-ball.num_frames // frames_per_task)
    with open_frames(folder) as reader:  # what the streaming `fuse4d run` sees
        frames = list(reader)
    depth = np.stack([f.depth for f in frames])
    intensity = np.stack([f.intensity for f in frames])
    ref = fuse_sequence(depth, intensity, rec.intrinsics)
    _assert_equal(fd.fuse(rec.depth, rec.intensity, rec.intrinsics, chunk_frames=7), ref)


def test_reader_options_reach_every_read_task(ball, tmp_path, capsys):
    """``--depth-unit-mm`` / ``--intrinsics`` (and the topic options, by the same path) are
    used by the dask engine's read tasks exactly as by the streaming reader."""
    folder = write_frame_folder(ball, tmp_path / "rec", depth_unit_mm=0.1)
    k = ball.intrinsics
    cam = f"{k.fx * 1.1},{k.fy * 1.1},{k.cx},{k.cy}"
    options = {"depth_unit_mm": 0.2, "intrinsics": cam}
    with open_frames(folder, **options) as reader:
        frames = list(reader)
        intrinsics = reader.intrinsics
    depth = np.stack([f.depth for f in frames])
    intensity = np.stack([f.intensity for f in frames])
    assert np.nanmax(depth) > 1.5 * np.nanmax(ball.depth)  # the option changes what is read
    ref = fuse_sequence(depth, intensity, intrinsics)
    rec = fd.open_lazy(folder, frames_per_task=6, **options)
    assert rec.intrinsics == intrinsics
    _assert_equal(fd.fuse(rec.depth, rec.intensity, rec.intrinsics, chunk_frames=7), ref)
    out = tmp_path / "out.zarr"
    args = ["run", str(folder), "-o", str(out), "--engine", "dask", "--chunk-frames", "6"]
    assert main([*args, "--depth-unit-mm", "0.2", "--intrinsics", cam, "--json"]) == 0
    capsys.readouterr()
    store = zarr.open_group(str(out), mode="r")
    assert _same(store["depth"][:], ref.depth)
    assert _same(store["support"][:], ref.support)


def test_bad_dask_options_are_user_errors_not_crashes(tmp_path, capsys):
    """A wrong scheduler, chunk size or output is the user's: exit 2 with one line naming
    it, not "internal error (a bug in fuse4d)" with a crash report."""
    seq = _crop(make_falling_ball(small=True, num_frames=3), 3)
    folder = write_frame_folder(seq, tmp_path / "rec", depth_unit_mm=0.05)
    other = write_frame_folder(seq, tmp_path / "rec2", depth_unit_mm=0.05)
    base = ["run", str(folder), "-o", str(tmp_path / "o.zarr"), "--engine", "dask"]
    cases = [
        (["--scheduler", "bogus"], "scheduler must be"),
        (["--workers", "-1"], "workers must be >= 1"),  # was an internal error
        (["--workers", "0"], "workers must be >= 1"),
        (["--chunk-frames", "0"], "chunk_frames must be >= 1"),
        (["run", str(folder), str(other), "-o", str(tmp_path / "o.zarr"), "--engine", "dask"],
         "2 inputs need an output folder"),
        (["run", str(folder), "-o", str(tmp_path / "no" / "o.zarr"), "--engine", "dask"],
         "does not exist"),
    ]  # fmt: skip
    for extra, message in cases:
        args = extra if extra[0] == "run" else [*base, *extra]
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert message in err
        assert "internal error" not in err
        # nothing written: no store, and no partial one that the next run calls interrupted
        assert sorted(p.name for p in tmp_path.iterdir()) == ["rec", "rec2"], args


def test_force_replaces_neither_the_input_nor_a_folder_fuse4d_did_not_write(ball, tmp_path, capsys):
    """--engine dask --force replaced the zarr recording it read, deleted a folder of the
    user's files, and failed ("Not a directory", a hidden .old left) on a file of the
    output's name: the streaming engine's output checks, on every target."""
    save_sequence(ball, tmp_path / "a.npz")
    victim = tmp_path / "victim.zarr"
    assert main(["convert", str(tmp_path / "a.npz"), str(victim)]) == 0
    before = sorted(p.name for p in victim.iterdir())
    args = ["--engine", "dask", "--chunk-frames", "4", "--force"]
    assert main(["run", str(victim), "-o", str(victim), *args]) == 2
    assert "would overwrite the input" in capsys.readouterr().err
    assert sorted(p.name for p in victim.iterdir()) == before
    assert not (tmp_path / "victim.zarr.partial").exists()
    mine = tmp_path / "important.zarr"
    mine.mkdir()
    (mine / "thesis.txt").write_text("x")
    assert main(["run", str(tmp_path / "a.npz"), "-o", str(mine), *args]) == 2
    assert "fuse4d did not write (thesis.txt)" in capsys.readouterr().err
    assert (mine / "thesis.txt").read_text() == "x"
    assert not (tmp_path / "important.zarr.partial").exists()
    a_file = tmp_path / "file.zarr"
    a_file.write_text("d")
    assert main(["run", str(tmp_path / "a.npz"), "-o", str(a_file), *args, "--json"]) == 0
    capsys.readouterr()
    assert zarr.open_group(str(a_file), mode="r")["depth"].shape == ball.depth.shape
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "a.npz", "file.zarr", "important.zarr", "victim.zarr"
    ]  # fmt: skip


def test_every_output_is_checked_before_any_is_written(ball, tmp_path, capsys):
    """A refused second output (it exists, or an interrupted run's does) left the first
    one's new, empty staging store, and the next run asked for --resume."""
    save_sequence(ball, tmp_path / "a.npz")
    save_sequence(ball, tmp_path / "b.npz")
    out = tmp_path / "fused"
    args = ["run", str(tmp_path / "a.npz"), str(tmp_path / "b.npz"), "-o", str(out),
            "--engine", "dask", "--chunk-frames", "4"]  # fmt: skip
    for blocker, message in (("b.zarr", "exists"), ("b.zarr.partial", "--resume")):
        (out / blocker).mkdir(parents=True)
        assert main(args) == 2
        assert message in capsys.readouterr().err
        assert sorted(p.name for p in out.iterdir()) == [blocker]
        (out / blocker).rmdir()


def test_relative_paths_reach_workers_in_another_folder(ball, tmp_path, monkeypatch):
    """A cluster's workers run in their own folder: the staging store, the flow cache and
    an --intrinsics camera.json were passed to the tasks as the relative paths given."""
    from fuse4d.config import FlowConfig
    from fuse4d.scale import cli as scale_cli

    write_frame_folder(ball, tmp_path / "rec", depth_unit_mm=0.1)
    (tmp_path / "cam.json").write_text((tmp_path / "rec" / "camera.json").read_text())
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(tmp_path)
    real = scale_cli.open_compute

    @contextlib.contextmanager
    def in_another_folder(*args, **kwargs):
        with real(*args, **kwargs) as compute:

            def run(*tasks):
                here = Path.cwd()
                os.chdir(elsewhere)  # where the worker runs
                try:
                    return compute(*tasks)
                finally:
                    os.chdir(here)

            yield run

    monkeypatch.setattr(scale_cli, "open_compute", in_another_folder)
    (summary,) = scale_cli.run_dask(
        [Path("rec")], Path("o.zarr"), fusion=FusionParams(), flow=FlowConfig(cache_dir="cache"),
        chunk_frames=7, scheduler="sync", progress=False, reader_options={"intrinsics": "cam.json"},
    )  # fmt: skip
    with open_frames(tmp_path / "rec") as reader:
        frames = list(reader)
    ref = fuse_sequence(np.stack([f.depth for f in frames]),
                        np.stack([f.intensity for f in frames]), reader.intrinsics)  # fmt: skip
    assert _same(zarr.open_group(str(tmp_path / "o.zarr"), mode="r")["depth"][:], ref.depth)
    assert summary.frames_fused == ball.num_frames
    assert any((tmp_path / "cache").iterdir())  # the flow cache where it was asked for
    assert not any(elsewhere.iterdir())


def test_bad_scheduler_addresses_are_user_errors(tmp_path, capsys):
    """A malformed address or one no scheduler answers (tls:// without TLS settings) was an
    internal error: checked with distributed's parser, the connection's failure reported."""
    pytest.importorskip("distributed")
    seq = _crop(make_falling_ball(small=True, num_frames=3), 3)
    save_sequence(seq, tmp_path / "a.npz")
    base = ["run", str(tmp_path / "a.npz"), "-o", str(tmp_path / "o.zarr"), "--engine", "dask"]
    cases = [
        ("tcp://", "scheduler must be"),
        ("tcp://127.0.0.1:abc", "scheduler must be"),
        ("inproc://x", "scheduler must be"),
        ("tls://127.0.0.1:1", "--scheduler tls://127.0.0.1:1: cannot connect"),
    ]
    for address, message in cases:
        assert main([*base, "--scheduler", address]) == 2, address
        err = capsys.readouterr().err
        assert message in err
        assert "internal error" not in err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]


def test_scheduler_address_without_distributed_is_one_clear_error(tmp_path, monkeypatch, capsys):
    """distributed was imported before the extra's check: ModuleNotFoundError, exit 70."""
    import importlib.util

    save_sequence(_crop(make_falling_ball(small=True, num_frames=3), 3), tmp_path / "a.npz")
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec",
        lambda name, *a: None if name.split(".")[0] == "distributed" else real(name, *a),
    )  # fmt: skip
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed fails
    args = ["run", str(tmp_path / "a.npz"), "-o", str(tmp_path / "o.zarr"), "--engine", "dask",
            "--scheduler", "tcp://127.0.0.1:abc"]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "needs distributed" in err
    assert "internal error" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]


def test_a_resumed_run_times_the_frames_it_fuses(ball, tmp_path, capsys):
    """ms/frame of a resumed run divided by every frame, the resumed chunks' too."""
    import json
    import shutil

    save_sequence(ball, tmp_path / "a.npz")
    out = tmp_path / "o.zarr"
    args = ["run", str(tmp_path / "a.npz"), "-o", str(out), "--engine", "dask",
            "--chunk-frames", "4", "--workers", "1"]  # fmt: skip
    assert main(args) == 0
    capsys.readouterr()
    partial = tmp_path / "o.zarr.partial"  # interrupted before the last of 5 chunks
    shutil.move(out, partial)
    meta = json.loads((partial / "zarr.json").read_text())
    meta["attributes"]["fuse4d"]["complete"] = False
    (partial / "zarr.json").write_text(json.dumps(meta))
    (partial / ".fuse4d-done").mkdir()
    for k in range(4):
        (partial / ".fuse4d-done" / f"chunk-{k:06d}").write_text("{}")
    assert main([*args, "--resume"]) == 0
    assert "ms/frame over the 4 frames fused now, 16 resumed)" in capsys.readouterr().out
    assert main([*args, "--resume", "--json"]) == 0
    assert '"frames_fused": 0' in capsys.readouterr().out


def test_missing_extra_gives_one_clear_error(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "zarr" else real(name, *a)
    )
    with pytest.raises(ImportError, match=r"fuse4d\[scale\]"):
        require_scale_extra()


def _cli_env() -> dict[str, str]:
    env = dict(os.environ)
    src = str(Path(fd.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")])
    return env


def _done_markers(folder: Path) -> list[Path]:
    """The chunks' done markers, as ``ZarrOutput.done_chunks`` reads them: not a
    ``chunk-N.tmp`` that a kill caught between writing and renaming it."""
    return [p for p in folder.glob("chunk-*") if p.suffix == ""]


@pytest.mark.slow
def test_resume_after_killed_cli_run_equals_uninterrupted(tmp_path):
    seq = _crop(make_falling_ball(small=True, num_frames=60), 60)
    save_sequence(seq, tmp_path / "rec.npz")
    base = [sys.executable, "-m", "fuse4d", "run", str(tmp_path / "rec.npz"), "--engine", "dask"]
    opts = ["--chunk-frames", "2", "--workers", "1", "--window", "5"]
    out = tmp_path / "killed.zarr"
    markers = tmp_path / "killed.zarr.partial" / ".fuse4d-done"
    proc = subprocess.Popen([*base, "-o", str(out), *opts], env=_cli_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if markers.is_dir() and len(_done_markers(markers)) >= 3:
            os.kill(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.01)
    proc.wait()
    if out.exists():
        pytest.skip("the run finished before it could be killed")
    done_before = len(_done_markers(markers))
    assert 3 <= done_before < 30
    run = subprocess.run([*base, "-o", str(out), *opts, "--resume", "--json"], env=_cli_env(),
                         capture_output=True, text=True, check=True)  # fmt: skip
    assert f'"skipped": {done_before}' in run.stdout
    ref = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=FusionParams(num_frames=5))
    store = zarr.open_group(str(out), mode="r")
    assert _same(store["depth"][:], ref.depth)
    assert _same(store["support"][:], ref.support)
    assert _same(store["filled"][:], ref.filled)


@pytest.mark.slow
def test_ctrl_c_of_a_process_cluster_run_is_one_line(tmp_path):
    """Ctrl-C reaches the whole process group: each worker printed a KeyboardInterrupt
    traceback, and the clean-up met dead workers ("Stream is closed", exit 2 instead of
    130)."""
    pytest.importorskip("distributed")
    seq = _crop(make_falling_ball(small=True, num_frames=40), 40)
    save_sequence(seq, tmp_path / "rec.npz")
    out = tmp_path / "o.zarr"
    markers = tmp_path / "o.zarr.partial" / ".fuse4d-done"
    args = [sys.executable, "-m", "fuse4d", "run", str(tmp_path / "rec.npz"), "-o", str(out),
            "--engine", "dask", "--scheduler", "processes", "--workers", "2",
            "--chunk-frames", "4", "--flow", "pmbp"]  # fmt: skip
    proc = subprocess.Popen(args, env=_cli_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if markers.is_dir() and _done_markers(markers):
            os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole group
            break
        time.sleep(0.02)
    _, err = proc.communicate(timeout=120)
    if out.exists():
        pytest.skip("the run finished before it could be interrupted")
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err
    assert err.rstrip().endswith("fuse4d: interrupted")
    assert err.rstrip().split("\n")[-1] == "fuse4d: interrupted"  # the progress bar's line ended
    assert "still alive" not in err  # the nanny's warnings on killing workers busy in a kernel


@pytest.mark.slow
def test_local_cluster_with_two_worker_processes(ball, reference, tmp_path):
    pytest.importorskip("distributed")
    from fuse4d.scale.cluster import local_cluster

    with local_cluster(2) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        res = fd.fuse(ball.depth, ball.intensity, ball.intrinsics, chunk_frames=4, client=client)
        points, support, filled = client.gather(
            client.compute([res.points, res.support, res.filled])
        )
        assert _same(points, reference.points)
        assert _same(support, reference.support)
        assert _same(filled, reference.filled)
        # zarr output written by the worker processes
        out = fd.write_zarr(res, tmp_path / "lc.zarr", intrinsics=ball.intrinsics,
                            compute=lambda *t: client.gather(client.compute(list(t))))  # fmt: skip
        assert _same(zarr.open_group(str(out), mode="r")["depth"][:], reference.depth)


def test_fuse_refuses_intrinsics_and_fusion_of_another_type():
    """A tuple of intrinsics failed as an AttributeError (one check: camera.check_intrinsics)."""
    from fuse4d.errors import ParameterTypeError

    depth = np.full((3, 12, 16), 800.0, np.float32)
    intensity = np.zeros((3, 12, 16), np.float32)
    with pytest.raises(ParameterTypeError, match=r"^intrinsics must be a fuse4d\.Intrinsics"):
        fd.fuse(depth, intensity, (50.0, 50.0, 8.0, 6.0))
    k = Intrinsics(fx=50.0, fy=50.0, cx=8.0, cy=6.0, width=16, height=12)
    with pytest.raises(ParameterTypeError, match=r"^fusion must be a FusionParams, got dict"):
        fd.fuse(depth, intensity, k, fusion={"num_frames": 3})


@pytest.mark.parametrize(("iterations", "chunk_frames"), [(1, 5), (2, 5), (1, 2)])
def test_dark_intensity_warned_once_with_the_recordings_frame_numbers(
    ball, iterations, chunk_frames, monkeypatch
):
    """Every chunk engine (and every iteration) warned 'intensity (frames 0-7) is dark',
    each numbering its own frames from 0; now only the chunk that starts the recording
    checks, as the whole-stream engine does."""
    import warnings

    dark = (ball.intensity * 0.05).astype(np.float32)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        res = fd.fuse(
            ball.depth, dark, ball.intrinsics, chunk_frames=chunk_frames,
            fusion=FusionParams(iterations=iterations),
        )  # fmt: skip
        # a new engine per chunk, as concurrent tasks or worker processes have
        monkeypatch.setattr(graph._ENGINES, "give_back", lambda *args: None)
        res.depth.compute(scheduler="synchronous")
    messages = [str(w.message) for w in rec if "is dark" in str(w.message)]
    assert len(messages) == 1
    seen = min(8, chunk_frames + 4)  # the first chunk and its look-ahead halo (window 9)
    assert messages[0].startswith(f"intensity (frames 0-{seen - 1}) is dark")


@pytest.mark.parametrize("iterations", [2, 3])
def test_filled_flags_are_the_last_passs_chunked_as_in_memory(iterations):
    """With iterations > 1 the chunked ``filled`` (Eq. 6) was ORed over the passes while
    support and source were the last pass's: flagged pixels had support > 0 and were fused."""
    from fuse4d.holes import SOURCE_MEASURED
    from fuse4d.range_scenes import make_range_scene

    seq = make_range_scene("ball", sensor="tof", small=True, num_frames=6, rng=0)
    fusion = FusionParams(num_frames=3, fill_holes=True, iterations=iterations, flying_pixels="on")
    ref = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=fusion)
    res = fd.fuse(seq.depth, seq.intensity, seq.intrinsics, fusion=fusion, chunk_frames=2)
    support, filled, source = dask.compute(res.support, res.filled, res.source, scheduler="sync")
    assert _same(filled, ref.filled)
    assert filled.any()
    assert (support[filled] == 0).all()  # filled: no temporal support (Eq. 6)
    assert (source[filled] == SOURCE_MEASURED).all()
