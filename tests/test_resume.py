"""Resumable runs: kill ``fuse4d run`` anywhere, ``--resume``, get the uninterrupted result."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import file_contents
from fuse4d import InputFileError, Intrinsics, Sequence
from fuse4d.cli import main
from fuse4d.io import load_sequence, open_frames, write_frame_folder
from fuse4d.io.resume import MANIFEST_NAME, partial_path

REPO = Path(__file__).resolve().parents[1]
FRAMES = 20
RUN_ARGS = ["--window", "5", "--set", "spatial_radius=2"]

#: Run the CLI in a child that kills itself (SIGKILL, or SIGINT = Ctrl-C) at a chosen point:
#: after frame K is complete, or halfway through writing frame K (depth PNG written, intensity
#: not yet).
_CHILD = """
import os, signal, sys
from fuse4d.io import resume
kill_at, where, sig = int(sys.argv[1]), sys.argv[2], getattr(signal, sys.argv[3])
# as in a terminal: a parent started in the background (``cmd &``) hands down SIGINT ignored
signal.signal(signal.SIGINT, signal.default_int_handler)
write, png = resume.ResumableFolderWriter.write, resume.ResumableFolderWriter._png

def write_then_kill(self, *args, **kwargs):
    write(self, *args, **kwargs)
    if where == "after" and self.frames_done == kill_at + 1:
        os.kill(os.getpid(), sig)

def png_then_kill(self, image, sub, name):
    png(self, image, sub, name)
    if where == "during" and sub == "depth" and self.frames_done == kill_at:
        os.kill(os.getpid(), sig)

resume.ResumableFolderWriter.write = write_then_kill
resume.ResumableFolderWriter._png = png_then_kill
from fuse4d.cli import main
sys.argv = ["fuse4d", *sys.argv[4:]]
main()  # as the console script does (exits with the code)
"""


def _moving_sequence(frames: int = FRAMES) -> Sequence:
    """A textured plane drifting 0.7 px/frame: DIS flow (and its warm start) matters."""
    h, w = 40, 56
    rng = np.random.default_rng(16)
    base = rng.random((h + 8, w + 40)).astype(np.float32)
    import cv2

    base = cv2.GaussianBlur(base, (0, 0), 1.5)
    base = (base - base.min()) / (base.max() - base.min())
    yy, xx = np.mgrid[0:h, 0:w]
    depth = np.empty((frames, h, w), np.float32)
    intensity = np.empty((frames, h, w), np.float32)
    for t in range(frames):
        shift = 0.7 * t
        m = np.float32([[1, 0, shift], [0, 1, 0]])
        intensity[t] = cv2.warpAffine(base, m, (w + 40, h + 8))[:h, :w]
        depth[t] = 900.0 + 2.0 * xx + 0.5 * yy + rng.normal(0, 0.8, (h, w))
    k = Intrinsics(60.0, 60.0, (w - 1) / 2, (h - 1) / 2, width=w, height=h)
    return Sequence(depth, np.clip(intensity, 0, 1), k, timestamps=np.arange(frames) / 30.0)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("resume")
    return write_frame_folder(_moving_sequence(), root / "in", depth_unit_mm=0.1)


@pytest.fixture(scope="module")
def reference(recording, tmp_path_factory) -> Path:
    """The uninterrupted run."""
    out = tmp_path_factory.mktemp("resume-ref") / "out"
    assert main(["run", str(recording), "-o", str(out), *RUN_ARGS]) == 0
    return out


def _child(kill_at: int, where: str, sig: str, args: list[str]) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    return subprocess.run(
        [sys.executable, "-c", _CHILD, str(kill_at), where, sig, *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def _contents(folder: Path) -> dict[str, bytes]:
    """Every output file but the manifest, by path (:func:`conftest.file_contents`: PNGs by
    their decoded samples)."""
    return {
        p.relative_to(folder).as_posix(): file_contents(p)
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != MANIFEST_NAME
    }


def _check_partial(partial: Path, frames_done: int) -> None:
    """Only complete frames and the manifest: no temporaries, nothing past frames_done."""
    manifest = json.loads((partial / MANIFEST_NAME).read_text())
    assert manifest["complete"] is False
    assert manifest["frames_done"] == frames_done
    names = {p.relative_to(partial).as_posix() for p in partial.rglob("*") if p.is_file()}
    assert not [n for n in names if Path(n).name.startswith(".")], names  # no temp files
    for sub in ("depth", "intensity"):
        frames = sorted(n for n in names if n.startswith(f"{sub}/"))
        assert frames == [f"{sub}/{k:06d}.png" for k in range(frames_done)]
    assert "camera.json" not in names  # the partial folder never looks like a recording
    with pytest.raises(InputFileError, match="unfinished fuse4d run"):
        open_frames(partial)


def _frames_done_after_signal(out: Path, kill_at: int) -> int:
    """Frames on disk after a signal sent from the writer once frame ``kill_at`` was written.

    Frames are written behind the fusion: the handler runs in the fusion thread at its next
    Python step, and until then the writer thread goes on with the queued frames (at most the
    queue's 2 plus the one being handed over); after it, the queued writes are dropped. How
    many land in between is timing (seen: 0-2), so the test bounds it; that only complete
    frames are left and the resume is exact is checked by the callers."""
    done = json.loads((partial_path(out) / MANIFEST_NAME).read_text())["frames_done"]
    assert kill_at + 1 <= done <= kill_at + 4, done
    return done


def test_killed_runs_resume_to_the_uninterrupted_result(recording, reference, tmp_path):
    """SIGKILL at three random frames (one of them halfway through writing a frame)."""
    out = tmp_path / "out"
    args = ["run", str(recording), "-o", str(out), *RUN_ARGS]
    kill_points = sorted(np.random.default_rng(2026).choice(np.arange(1, FRAMES - 1), 3, False))
    done = 0
    for i, k in enumerate(kill_points):
        where = "during" if i == 1 else "after"
        res = _child(int(k), where, "SIGKILL", [*args, "--resume"] if i else args)
        assert res.returncode == -signal.SIGKILL, res.stderr[-2000:]
        assert not out.exists()
        done = int(k) + 1 if where == "after" else int(k)
        if where == "during":  # a hard kill may leave the half-written frame's temporary
            manifest = json.loads((partial_path(out) / MANIFEST_NAME).read_text())
            assert manifest["frames_done"] == done
        else:
            _check_partial(partial_path(out), done)
    assert main([*args, "--resume"]) == 0
    assert not partial_path(out).exists()
    assert _contents(out) == _contents(reference)  # every sample, bit for bit
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert manifest["complete"] is True
    assert manifest["frames_done"] == FRAMES
    np.testing.assert_array_equal(load_sequence(out).depth, load_sequence(reference).depth)


def test_a_one_frame_window_checkpoints_and_resumes(recording, tmp_path):
    """``--window 1`` computes no flow: its checkpoints carry no warm start (a run past the
    first checkpoint crashed asking the engine for a pair not yet pushed), and a killed run
    resumes to the uninterrupted result."""
    args = ["--window", "1", "--set", "spatial_radius=2"]
    reference = tmp_path / "ref"
    assert main(["run", str(recording), "-o", str(reference), *args]) == 0
    assert load_sequence(reference).num_frames == FRAMES  # past 2 checkpoints of 8 frames
    out = tmp_path / "out"
    res = _child(10, "after", "SIGKILL", ["run", str(recording), "-o", str(out), *args])
    assert res.returncode == -signal.SIGKILL, res.stderr[-2000:]
    assert main(["run", str(recording), "-o", str(out), *args, "--resume"]) == 0
    assert _contents(out) == _contents(reference)


def test_ctrl_c_exits_130_and_leaves_only_complete_frames(recording, reference, tmp_path):
    out = tmp_path / "out"
    args = ["run", str(recording), "-o", str(out), *RUN_ARGS]
    res = _child(12, "after", "SIGINT", args)
    assert res.returncode == 130, res.stderr[-2000:]
    assert "interrupted" in res.stderr
    assert "Traceback" not in res.stderr
    _check_partial(partial_path(out), _frames_done_after_signal(out, 12))
    # a second run without --resume refuses to clobber the unfinished one
    assert main(args) == 2
    assert main([*args, "--resume"]) == 0
    assert _contents(out) == _contents(reference)


def test_resume_of_a_finished_run_does_nothing_and_of_another_refuses(
    recording, reference, tmp_path, capsys
):
    """A rerun with --resume (a batch script after a crash) leaves a finished output of the
    same run as it is and succeeds, as --engine dask does; another run's finished output, or
    a folder that no run wrote, is refused."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(reference, out)
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    args = ["run", str(recording), "-o", str(out), *RUN_ARGS, "--resume"]
    assert main([*args, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["already_complete"] is True
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before  # untouched
    assert not partial_path(out).exists()
    assert main(["run", str(recording), "-o", str(out), "--window", "7", "--resume"]) == 2
    assert "holds a finished run whose fusion differ" in capsys.readouterr().err
    # another flow ROI (was "already complete", and resumed an unfinished run with it)
    assert main([*args, "--flow-roi", "0:20,0:20"]) == 2
    assert "holds a finished run whose flow differ" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before
    stranger = tmp_path / "stranger"
    stranger.mkdir()
    assert main(["run", str(recording), "-o", str(stranger), *RUN_ARGS, "--resume"]) == 2
    assert "output exists" in capsys.readouterr().err


def test_resume_refuses_other_options_and_force_starts_over(recording, reference, tmp_path):
    out = tmp_path / "out"
    args = ["run", str(recording), "-o", str(out), *RUN_ARGS]
    res = _child(3, "after", "SIGKILL", args)
    assert res.returncode == -signal.SIGKILL
    other = ["run", str(recording), "-o", str(out), "--window", "7", "--resume"]
    assert main(other) == 2  # parameters differ from the unfinished run's
    assert partial_path(out).exists()
    assert main([*args, "--force"]) == 0
    assert _contents(out) == _contents(reference)
    assert main([*args, "--resume"]) == 0  # the same run, finished: nothing to do


def test_a_run_killed_inside_close_resumes(recording, reference, tmp_path, capsys):
    """Every frame on disk, the checkpoint's seed removed with resume/, the manifest not yet
    complete (a kill, or a full disk, inside close): every --resume failed with "[Errno 2]
    No such file or directory: .../resume/seed-000016.npy"."""
    import shutil

    out = tmp_path / "out"
    partial = partial_path(out)
    shutil.copytree(reference, partial)
    manifest = json.loads((partial / MANIFEST_NAME).read_text())
    manifest.update(complete=False, checkpoint={"frame": 16, "seed": "stored"})
    (partial / MANIFEST_NAME).write_text(json.dumps(manifest))
    assert not (partial / "resume").exists()
    args = ["run", str(recording), "-o", str(out), *RUN_ARGS]
    assert main([*args, "--resume"]) == 0, capsys.readouterr().err
    assert not partial.exists()
    assert _contents(out) == _contents(reference)
    # killed a step later (the checkpoint dropped, resume/ gone): nothing is fused again
    # (without a checkpoint the resume fused every frame again)
    import fuse4d.run

    out.rename(partial)
    manifest.update(complete=False, checkpoint=None)
    (partial / MANIFEST_NAME).write_text(json.dumps(manifest))
    pushed = []
    real_push = fuse4d.run.FusionEngine.push

    def counting_push(self, *a, **kw):
        pushed.append(1)
        return real_push(self, *a, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fuse4d.run.FusionEngine, "push", counting_push)
        assert main([*args, "--resume"]) == 0
    assert len(pushed) <= 5  # the window's past frames at most, not all 20
    assert _contents(out) == _contents(reference)
    # a partial run whose seed is gone: one error naming the file
    res = _child(10, "after", "SIGKILL", ["run", str(recording), "-o", str(tmp_path / "b")])
    assert res.returncode == -signal.SIGKILL
    for seed in (partial_path(tmp_path / "b") / "resume").glob("seed-*.npy"):
        seed.unlink()
    assert main(["run", str(recording), "-o", str(tmp_path / "b"), "--resume"]) == 2
    assert "the checkpoint's warm-start flow is missing" in capsys.readouterr().err


def test_resume_without_unfinished_run_just_runs(recording, reference, tmp_path):
    out = tmp_path / "out"
    assert main(["run", str(recording), "-o", str(out), *RUN_ARGS, "--resume"]) == 0
    assert _contents(out) == _contents(reference)


def test_resume_of_npz_output_is_refused(tmp_path, small_sequence, capsys):
    from fuse4d.io import write_npz

    src = write_npz(small_sequence, tmp_path / "s.npz")
    assert main(["run", str(src), "-o", str(tmp_path / "o.npz"), "--resume"]) == 2
    assert "--resume applies to frame-folder outputs" in capsys.readouterr().err


def test_warm_start_seed_is_what_makes_resume_bit_identical():
    """Farneback warm-starts each pair from the previous one: restarting the engine at frame
    6 without the stored flow changes the output; with it, the output is identical."""
    from fuse4d import FlowConfig, FusionEngine, FusionParams

    seq = _moving_sequence()
    params = FusionParams(num_frames=5, spatial_radius=2)

    def run(first: int, seed=None):
        engine = FusionEngine(
            seq.intrinsics, fusion=params, flow=FlowConfig("farneback"), initial_flow=seed
        )
        out, flows = {}, {}
        for t in range(first, FRAMES):
            out.update({first + f.index: f.depth for f in engine.push(seq.depth[t],
                                                                       seq.intensity[t])})  # fmt: skip
            if t > first:
                flows[t] = engine.forward_flow(t - first)
        out.update({first + f.index: f.depth for f in engine.flush()})
        return out, flows

    full, flows = run(0)
    seeded, _ = run(6, flows[6])
    unseeded, _ = run(6)
    later = range(8, FRAMES)  # frames whose whole window lies after the restart
    assert all(np.array_equal(full[t], seeded[t], equal_nan=True) for t in later)
    assert not all(np.array_equal(full[t], unseeded[t], equal_nan=True) for t in later)


def test_killed_farneback_run_resumes_bit_identical(recording, tmp_path):
    """The same with a kill after the first checkpoint (resume restarts at frame 8 - 2)."""
    ref = tmp_path / "ref"
    args = [*RUN_ARGS, "--flow", "farneback"]
    assert main(["run", str(recording), "-o", str(ref), *args]) == 0
    out = tmp_path / "out"
    res = _child(13, "after", "SIGKILL", ["run", str(recording), "-o", str(out), *args])
    assert res.returncode == -signal.SIGKILL, res.stderr[-2000:]
    manifest = json.loads((partial_path(out) / MANIFEST_NAME).read_text())
    assert manifest["checkpoint"] == {"frame": 8, "seed": "stored"}
    assert main(["run", str(recording), "-o", str(out), *args, "--resume"]) == 0
    assert _contents(out) == _contents(ref)


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGHUP"])  # SIGHUP: a closed terminal or ssh
def test_sigterm_stops_as_cleanly_as_ctrl_c(recording, reference, tmp_path, sig):
    out = tmp_path / "out"
    args = ["run", str(recording), "-o", str(out), *RUN_ARGS]
    res = _child(5, "after", sig, args)
    assert res.returncode == 130, res.stderr[-2000:]
    _check_partial(partial_path(out), _frames_done_after_signal(out, 5))
    assert main([*args, "--resume"]) == 0
    assert _contents(out) == _contents(reference)


def test_a_resumed_run_times_and_scores_the_frames_it_fused(recording, tmp_path, monkeypatch,
                                                          capsys):  # fmt: skip
    """The summary of a resumed run divided this session's time by every frame, the resumed
    ones too ('12 ms/frame' for 19.5), said 'scored on 32 of 200 frames' of the 128 fused
    now, and its --report divided this session's time by the whole run; now the rates are
    per frame fused now, the table says which frames were scored, the report reads the run's
    time (all sessions) from the manifest."""
    from rich.console import Console

    from fuse4d import FusionParams
    from fuse4d.cli import cmd_report
    from fuse4d.cli.cmd_fuse import run_summary_table
    from fuse4d.run import RunSummary

    out = tmp_path / "out"
    args = ["run", str(recording), "-o", str(out), *RUN_ARGS]
    res = _child(12, "after", "SIGKILL", args)
    assert res.returncode == -signal.SIGKILL, res.stderr[-2000:]
    seen: dict = {}

    def fake_report(input, output, report, **kwargs):  # the report itself: test_report.py
        seen.update(kwargs)
        return Path(report) / "report.html"

    monkeypatch.setattr(cmd_report, "make_report", fake_report)
    rep = ["--report", str(tmp_path / "rep"), "--summary-every", "2"]
    assert main([*args, "--resume", "--json", *rep]) == 0
    s = json.loads(capsys.readouterr().out)
    assert (s["frames"], s["frames_resumed"], s["frames_fused"]) == (FRAMES, 13, 7)
    assert s["ms_per_frame"] == pytest.approx(1000 * s["seconds"] / 7)
    assert s["roughness_frames"] == 4  # frames 13, 15, 17, 19
    assert seen["fusion_seconds"] is None  # make_report reads the manifest's run time
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert manifest["seconds"] > s["seconds"]  # both sessions

    summary = RunSummary(
        input=recording, output=out, input_format="folder", output_format="folder",
        frames=200, shape=(40, 56), flow_method="dis", params=FusionParams(), seconds=2.5,
        frames_resumed=72, roughness_frames=32, timings={"flow": 1.28},
    )  # fmt: skip
    assert summary.frames_fused == 128
    assert summary.ms_per_frame == pytest.approx(2500 / 128)
    assert summary.to_dict()["timings_ms_per_frame"]["flow"] == pytest.approx(10.0)
    console = Console(record=True, width=400)
    console.print(run_summary_table(summary, FusionParams()))
    text = console.export_text()
    assert "20 ms/frame, start-up and I/O included (this session: 128 fused, 72 resumed)" in text
    assert "scored on 32 of 128 frames" in text
    assert "72-199" in text
    assert "frames 0-71, written by the interrupted run, were not scored" in text
