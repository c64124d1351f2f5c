"""CLI tests of ``fuse4d run``, ``bench``, ``demo`` and TOML configuration files."""

from __future__ import annotations

import dataclasses
import io
import json
import math
import threading
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import ndimage as ndi

from conftest import write_ball_folder
from fuse4d import FusionParams, Sequence, load_config, load_sequence, preset
from fuse4d.cli import main
from fuse4d.errors import InputFileError, ParameterError
from fuse4d.holes import SOURCE_FUSED, SOURCE_MEASURED, SOURCE_NONE
from fuse4d.io import FrameFolderWriter, read_npz_extra, write_npz
from fuse4d.synthetic import make_falling_ball, make_scene


@pytest.fixture(scope="module")
def ball_npz(tmp_path_factory):
    path = tmp_path_factory.mktemp("ball") / "ball.npz"
    assert main(["synth", "ball", "--small", "--frames", "6", "-o", str(path)]) == 0
    return path


def test_run_npz_to_npz_keeps_keys_and_adds_support(ball_npz, tmp_path, capsys):
    out = tmp_path / "fused.npz"
    assert main(["run", str(ball_npz), "-o", str(out), "--window", "5", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 6
    assert summary["fused_roughness_mm"] < summary["raw_roughness_mm"]
    assert 0.5 < summary["support_fraction"] <= 1.0
    fused = load_sequence(out)
    raw = load_sequence(ball_npz)
    np.testing.assert_array_equal(fused.intensity, raw.intensity)
    np.testing.assert_array_equal(fused.ground_truth.depth, raw.ground_truth.depth)
    extra = read_npz_extra(out)
    assert extra["support"].shape == (6, 150, 150)
    assert extra["support"].max() <= 4
    # the per-pixel flags: where each value comes from and how many frames measured it
    assert extra["source"].dtype == np.uint8
    measured = np.isin(extra["source"], (SOURCE_MEASURED, SOURCE_FUSED))
    np.testing.assert_array_equal(measured, np.isfinite(raw.depth))
    np.testing.assert_allclose(extra["confidence"][measured], (1 + extra["support"][measured]) / 5)
    # away from the ball's silhouette (3 px band), the fused depth is much closer to GT
    gt = raw.ground_truth
    band = np.stack(
        [
            ndi.binary_dilation(m, iterations=3) & ~ndi.binary_erosion(m, iterations=3)
            for m in gt.mask
        ]
    )
    err_raw = np.sqrt(np.nanmean((raw.depth - gt.depth)[~band] ** 2))
    err_fused = np.sqrt(np.nanmean((fused.depth - gt.depth)[~band] ** 2))
    assert err_fused < 0.6 * err_raw
    # refuses to overwrite, and never writes onto the input
    assert main(["run", str(ball_npz), "-o", str(out)]) == 2
    assert "output exists" in capsys.readouterr().err
    assert main(["run", str(ball_npz), "-o", str(ball_npz), "--force"]) == 2


def test_run_folder_streams_to_folder(tmp_path, capsys):
    seq = make_falling_ball(small=True, num_frames=5)
    src = tmp_path / "rec"
    with FrameFolderWriter(src, seq.intrinsics, depth_unit_mm=0.05) as writer:
        for d, i in zip(seq.depth, seq.intensity, strict=True):
            writer.write(d, i)
    out = tmp_path / "rec_fused"
    assert main(["run", str(src), "-o", str(out), "--causal", "--set", "spatial_radius=2"]) == 0
    text = capsys.readouterr().out
    assert "roughness (Eq. 7)" in text
    assert "raw -> fused" in text
    fused = load_sequence(out)
    assert fused.num_frames == 5
    raw = load_sequence(src)
    # the per-pixel flags beside the depth: source codes and confidence x 255
    source, conf = (
        np.stack(
            [cv2.imread(str(out / sub / f"{t:06d}.png"), cv2.IMREAD_UNCHANGED) for t in range(5)]
        )
        for sub in ("source", "confidence")
    )
    assert source.dtype == np.uint8
    assert conf.dtype == np.uint8
    np.testing.assert_array_equal(source == SOURCE_NONE, fused.depth != fused.depth)
    assert (conf[source == SOURCE_FUSED] > 0).all()
    assert (conf[source == SOURCE_NONE] == 0).all()
    assert np.nanstd(fused.depth - seq.ground_truth.depth) < np.nanstd(
        raw.depth - seq.ground_truth.depth
    )


def test_run_bad_parameters_give_one_line_errors(ball_npz, tmp_path, capsys):
    out = str(tmp_path / "x.npz")
    assert main(["run", str(ball_npz), "-o", out, "--set", "spatial_radius"]) == 2
    assert "--set must look like KEY=VALUE" in capsys.readouterr().err
    assert main(["run", str(ball_npz), "-o", out, "--set", "radius=3"]) == 2
    assert "unknown parameter(s) radius for the fusion" in capsys.readouterr().err
    assert main(["run", str(ball_npz), "-o", out, "--flow", "nope"]) == 2
    assert "unknown flow method 'nope'" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "missing"), "-o", out]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fuse4d: error: ")
    assert "Traceback" not in err


def test_toml_config_round_trip(tmp_path):
    cfg = tmp_path / "fuse.toml"
    cfg.write_text(
        'preset = "fast"\n[fusion]\nnum_frames = 5\nsigma_temporal = "inf"\n'
        '[flow]\nmethod = "dis"\n[flow.params]\npreset = "ultrafast"\n',
        encoding="utf-8",
    )
    chosen = load_config(cfg)
    assert chosen.fusion.num_frames == 5
    assert math.isinf(chosen.fusion.sigma_temporal)
    assert chosen.flow.method == "dis"
    assert chosen.flow.build_params().patch_stride == 4  # DIS ultrafast
    bad = tmp_path / "bad.toml"
    bad.write_text("[fusion]\nradius = 3\n", encoding="utf-8")
    with pytest.raises(
        InputFileError,
        match=r"bad\.toml: unknown parameter\(s\) radius for \[fusion\] of the config file",
    ):
        load_config(bad)
    broken = tmp_path / "broken.toml"
    broken.write_text("[fusion\n", encoding="utf-8")
    with pytest.raises(InputFileError, match="cannot read TOML"):
        load_config(broken)


def test_presets():
    assert preset("fast").flow.method == "dis"
    assert preset("paper").flow.method == "pmbp"
    assert preset("fast").fusion == FusionParams()
    with pytest.raises(ValueError, match="unknown preset 'slow'"):
        preset("slow")


def test_reader_options_keeps_only_given_options_in_one_order():
    from fuse4d.cli._recording_opts import reader_options

    assert reader_options() == {}
    got = reader_options(None, "/ir", None, True, depth_unit_mm=0.5, intrinsics="1,1,0,0")
    assert list(got.items()) == [
        ("intensity_topic", "/ir"),
        ("undistort", False),
        ("depth_unit_mm", 0.5),
        ("intrinsics", "1,1,0,0"),
    ]


BENCH_STAGES = {"flow", "bilateral", "motion_reference", "tracking", "fusion", "fill"}


def _bench_small(capsys, *extra: str) -> dict:
    """The one JSON result of ``fuse4d bench --small`` on 6 frames with a 3-frame window."""
    assert main(["bench", "--small", "--frames", "6", "--window", "3", *extra, "--json"]) == 0
    (result,) = json.loads(capsys.readouterr().out)
    return result


def test_bench_small_reports_every_stage(capsys):
    result = _bench_small(capsys)
    assert set(result["stage_ms"]) == BENCH_STAGES
    assert result["ms_per_frame"] > 0
    assert result["peak_rss_mb"] > 0
    assert result["input_mb"] == pytest.approx(6 * 150 * 150 * 4 * 2 / 2**20)  # depth+intensity


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--quality", "--small", "--frames", "3"], "--quality scores the fixed ball"),
        (["--quality", "--small", "--input", "x"], "--quality scores the fixed ball"),
        (["--small", "--intensity-noise", "0.05"], "--intensity-noise applies to --quality"),
        (["--small", "--no-summary"], "--no-summary applies to --input only"),
        (["--small", "--input", "x"], "--small is the synthetic ball's size"),
    ],
)
def test_bench_options_its_mode_does_not_use_are_refused(capsys, args, says):
    """Each was accepted and ignored: exit 0, another run measured than asked for."""
    assert main(["bench", *args]) == 2
    assert says in capsys.readouterr().err


def test_bench_causal_times_the_causal_engine_stage_by_stage(monkeypatch, capsys):
    from fuse4d.experiments import speed

    seen = []

    class Spy(speed.FusionEngine):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            seen.append((self.params.causal, self.past, self.future))

    monkeypatch.setattr(speed, "FusionEngine", Spy)
    result = _bench_small(capsys, "--causal")
    assert result["causal"] is True
    assert result["window"] == 3
    assert set(result["stage_ms"]) == BENCH_STAGES
    assert result["stage_ms"]["tracking"] > 0
    assert result["ms_per_frame"] > 0
    assert seen
    assert all(s == (True, 2, 0) for s in seen)
    centred = _bench_small(capsys)
    assert centred["causal"] is False
    assert seen[-1] == (False, 1, 1)


def test_bench_pipeline_times_a_given_sequence_in_memory(monkeypatch):
    """``sequence=``: the engine on those frames (their size, their first ``num_frames``), not
    on the ball, with A36 decided for the sequence's camera as ``fuse4d run`` does; no frame
    to time is refused."""
    from fuse4d.experiments import speed

    flying = []

    class Spy(speed.FusionEngine):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            flying.append(self.params.flying_pixels)

    monkeypatch.setattr(speed, "FusionEngine", Spy)
    seq = make_falling_ball(small=True, num_frames=6)
    k = dataclasses.replace(seq.intrinsics, width=120)
    crop = Sequence(seq.depth[:, :, :120].copy(), seq.intensity[:, :, :120].copy(), k)
    result = speed.benchmark_pipeline("fast", num_frames=4, window=3, sequence=crop)
    assert result.size == (150, 120)
    assert result.frames == 4
    assert result.stage_ms["tracking"] > 0
    assert set(flying) == {"off"}
    tof = Sequence(crop.depth, crop.intensity, k, sensor="tof")
    speed.benchmark_pipeline("fast", num_frames=3, window=3, sequence=tof)
    assert flying[-1] == "on"
    with pytest.raises(ParameterError, match="no frame"):
        speed.benchmark_pipeline("fast", num_frames=0, sequence=crop)


def test_bench_causal_refuses_quality():
    assert main(["bench", "--small", "--causal", "--quality"]) != 0


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--small", "--frames", "1"], "--frames must be >= 2, got 1"),
        (["--input", "rec", "--frames", "0"], "--frames must be >= 1, got 0"),  # 0-frame table
        (["--input", "rec", "--frames", "-1"], "--frames must be >= 1, got -1"),  # was a crash
    ],
)
def test_bench_frame_counts_it_cannot_time_are_one_line(tmp_path, monkeypatch, capsys, args, says):
    monkeypatch.chdir(tmp_path)
    assert main(["bench", *args]) == 2
    err = capsys.readouterr().err
    assert says in err
    assert "internal error" not in err


def test_demo_small_writes_figure_and_table(tmp_path, capsys):
    assert main(["demo", "--small", "--frames", "6", "--out", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out
    assert "fuse4d (fast" in out
    payload = json.loads((tmp_path / "demo" / "metrics.json").read_text())
    scores = {s["name"].split(" ")[0]: s for s in payload["scores"]}
    assert scores["fuse4d"]["rmse"] < scores["raw"]["rmse"]
    assert (tmp_path / "demo" / "demo_before_after.png").stat().st_size > 10_000
    # the demo's output is also the HTML report, with its video beside it
    page = (tmp_path / "demo" / "report" / "report.html").read_text(encoding="utf-8")
    assert "<video" in page
    assert (tmp_path / "demo" / "report" / "compare.mp4").stat().st_size > 1000
    assert "report.html" in out.replace("\n", "")  # rich wraps long paths


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*")
            if p.is_file()}  # fmt: skip


def test_demo_replaces_only_its_own_files(tmp_path, monkeypatch, capsys):
    """`demo --out DIR` replaced the user's metrics.json/.md, then failed on their report/
    folder (a half-updated folder), and silently replaced an earlier demo; every output is
    now checked before anything is written, and only --force replaces files. Plain
    `fuse4d demo` reruns into its default folder, replacing its own unchanged files only."""
    monkeypatch.chdir(tmp_path)
    demo = ["demo", "--small", "--frames", "3"]
    assert main(demo) == 0
    own = tmp_path / "fuse4d-demo"
    first = _snapshot(own)
    assert main(demo) == 0  # the README's first command, run again
    assert _snapshot(own).keys() == first.keys()
    (own / "metrics.md").write_text("my notes\n")  # now a file of the user's
    before = _snapshot(own)
    capsys.readouterr()
    assert main(demo) == 2
    assert "metrics.md: output exists" in capsys.readouterr().err
    assert main([*demo, "--out", str(own)]) == 2  # named: --force, as every command
    assert "demo_before_after.png: output exists" in capsys.readouterr().err
    assert _snapshot(own) == before
    mine = tmp_path / "mine"
    (mine / "report").mkdir(parents=True)
    (mine / "metrics.json").write_text('{"my": 1}\n')
    (mine / "metrics.md").write_text("notes\n")
    (mine / "report" / "notes.txt").write_text("keep\n")
    before = _snapshot(mine)
    assert main([*demo, "--out", str(mine)]) == 2
    assert "metrics.json: output exists" in capsys.readouterr().err
    assert main([*demo, "--out", str(mine), "--force"]) == 2  # report/ is not fuse4d's
    assert "report" in capsys.readouterr().err
    assert _snapshot(mine) == before  # nothing replaced before the refusal
    (mine / "report" / "notes.txt").unlink()
    assert main([*demo, "--out", str(mine), "--force"]) == 0
    assert json.loads((mine / "metrics.json").read_text())["frames"] == 3


def _ball_folder(tmp_path, frames=5):
    return write_ball_folder(tmp_path / "rec", frames)


def test_run_read_ahead_and_write_behind_match_the_inline_run(tmp_path, capsys):
    """Issue 13: the threaded streaming path writes exactly what the single-thread one does;
    --no-summary skips the quality tally; I/O and summary are timed stages."""
    from fuse4d.run import IO_STAGES, fuse_file

    src = _ball_folder(tmp_path)
    params = FusionParams(num_frames=3)
    inline = fuse_file(src, tmp_path / "inline", fusion=params, io_queue=0)
    threaded = fuse_file(src, tmp_path / "threaded", fusion=params, io_queue=2)
    np.testing.assert_array_equal(
        load_sequence(tmp_path / "inline").depth, load_sequence(tmp_path / "threaded").depth
    )
    assert inline.fused_roughness == threaded.fused_roughness
    # the read, write and flow (overlap_flow) threads have ended with the run
    names = {t.name for t in threading.enumerate()}
    assert not any(n.startswith(("fuse4d-read", "fuse4d-write", "fuse4d-flow")) for n in names)
    assert set(IO_STAGES) <= set(threaded.timings)
    assert threaded.timings["read"] > 0
    assert threaded.timings["write"] > 0
    assert threaded.timings["summary"] > 0
    out = tmp_path / "quick"
    assert main(["run", str(src), "-o", str(out), "--window", "3", "--no-summary", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 5
    assert summary["fused_roughness_mm"] is None  # not scored (JSON null, not bare NaN)
    assert summary["timings_ms_per_frame"]["summary"] == 0.0
    assert load_sequence(out).num_frames == 5


def test_run_output_clock_separates_start_up_from_the_steady_rate():
    """The summary's steady rate is the interval between frames that each followed a new
    input frame (a centred window's last ``future_frames`` come out of the flush at once and
    are left out); the first hand-over gives the start-up; every call reaches the caller's
    progress; no steady rate from one frame or with fusion iterations."""
    from fuse4d.run import RunSummary, _OutputClock

    seen = []
    clock = _OutputClock(lambda done, total: seen.append((done, total)))
    for done in range(1, 7):
        clock(done, 6)
    assert seen == [(d, 6) for d in range(1, 7)]

    def summary(params, times):
        clock.times = times
        s = RunSummary(Path("in"), Path("out"), "folder", "folder", 6, (2, 2), "dis", params)
        clock.fill(s, start=10.0)
        return s

    # 2 s of start-up, then a frame every 100 ms, then the flush's two frames at once
    times = [12.0, 12.1, 12.2, 12.3, 12.3001, 12.3002]
    centred = summary(FusionParams(num_frames=5), times)  # future_frames 2
    assert centred.first_output_seconds == pytest.approx(2.0)
    assert centred.steady_ms_per_frame == pytest.approx(100.0)
    causal = summary(FusionParams(num_frames=5, causal=True), times)  # all followed a push
    assert causal.steady_ms_per_frame == pytest.approx(1000 * 0.3002 / 5)
    assert math.isnan(summary(FusionParams(num_frames=3), [12.0, 12.1]).steady_ms_per_frame)
    # a clip shorter than the look-ahead (3 frames, window 9): all flushed, none followed a
    # push (the negative stop kept all but the last frame: 100 ms/frame "once running")
    short = summary(FusionParams(num_frames=9), [12.0, 12.1, 12.2])
    assert math.isnan(short.steady_ms_per_frame)
    assert math.isnan(summary(FusionParams(num_frames=3, iterations=2), times).steady_ms_per_frame)
    empty = summary(FusionParams(num_frames=3), [])
    assert math.isnan(empty.first_output_seconds)


def test_run_summary_reports_the_rate_once_running_apart_from_start_up(tmp_path, capsys):
    """The summary names the first-output time and the rate once running, and the JSON has
    them; a run without the clock (dask) says its average includes the start-up.

    Which of the steady rate and the average is larger depends on the process's warmth and
    the machine's load (an earlier test may have loaded the kernels), so only what holds on
    any machine is asserted: the 4 steady intervals (6 frames, 1 flushed) lie after the
    first output and inside the run. The clock's arithmetic is tested on injected times."""
    from fuse4d.cli.cmd_fuse import _time_note
    from fuse4d.run import fuse_file

    src = _ball_folder(tmp_path, frames=6)
    done = []
    s = fuse_file(
        src, tmp_path / "a", fusion=FusionParams(num_frames=3), progress=lambda *a: done.append(a)
    )
    assert len(done) == 6
    assert 0 < s.first_output_seconds < s.seconds
    assert 0 < 4 * s.steady_ms_per_frame <= 1000 * (s.seconds - s.first_output_seconds)
    assert "once running" in _time_note(s)
    s.steady_ms_per_frame = math.nan
    assert _time_note(s) == f"{s.ms_per_frame:.0f} ms/frame, start-up and I/O included"
    out = tmp_path / "b"
    assert main(["run", str(src), "-o", str(out), "--window", "3", "--no-summary", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert 0 < summary["first_output_seconds"] < summary["seconds"]
    inside = 1000 * (summary["seconds"] - summary["first_output_seconds"])
    assert 0 < 4 * summary["steady_ms_per_frame"] <= inside


def test_run_summary_counts_equal_the_numpy_tallies():
    """The summary's per-frame counts (one kernel) are numpy's: raw-valid pixels, of them
    supported and filled, pixels per source code (codes past the tally ignored), with and
    without source codes."""
    from fuse4d.fusion import FusedFrame
    from fuse4d.holes import _SOURCE_CODES
    from fuse4d.run import _QualityTally

    rng = np.random.default_rng(5)
    shape = (23, 31)
    raw = rng.normal(1000.0, 5.0, (*shape, 3)).astype(np.float32)
    raw[rng.random(shape) < 0.3, 2] = np.nan
    raw[0, 0, 2] = np.inf  # not finite: not valid
    support = rng.integers(0, 4, shape).astype(np.uint8)
    filled = rng.random(shape) < 0.2
    source = rng.integers(0, _SOURCE_CODES + 2, shape).astype(np.uint8)
    no_holes = np.zeros(shape, bool)
    with_codes = FusedFrame(0, raw, support, filled, no_holes, source=source)
    without = FusedFrame(1, raw, support, filled, no_holes)
    tally = _QualityTally(every=10**6)
    tally.add(raw, with_codes)
    tally.add(raw, without)
    valid = np.isfinite(raw[..., 2])
    assert tally.valid == 2 * valid.sum()
    assert tally.supported == 2 * (support[valid] > 0).sum()
    assert tally.filled == 2 * filled[valid].sum()
    assert tally.pixels == 2 * valid.size
    expected = np.bincount(source.ravel(), minlength=_SOURCE_CODES + 2)[:_SOURCE_CODES]
    np.testing.assert_array_equal(tally.sources.counts, expected)
    assert tally.sources.pixels == valid.size  # one frame had codes
    assert tally.sources.raw_valid == valid.sum()


def test_run_reader_and_writer_errors_reach_the_caller(tmp_path, monkeypatch):
    from fuse4d import run as run_module

    src = _ball_folder(tmp_path, frames=4)

    def failing_write(self, *args, **kwargs):
        raise OSError("disk full")

    from fuse4d.io.resume import ResumableFolderWriter

    monkeypatch.setattr(ResumableFolderWriter, "write", failing_write)
    with pytest.raises(OSError, match="disk full"):
        run_module.fuse_file(src, tmp_path / "out", fusion=FusionParams(num_frames=3))
    monkeypatch.undo()
    read_ahead = run_module._ReadAhead

    def broken(frames, depth, timings, group=None):
        def gen():
            yield from ()
            raise InputFileError("000000.png", "truncated PNG", frame=0)

        return read_ahead(gen(), depth, timings, group)

    monkeypatch.setattr(run_module, "_ReadAhead", broken)
    with pytest.raises(InputFileError, match="truncated"):
        run_module.fuse_file(src, tmp_path / "out2", fusion=FusionParams(num_frames=3))


def test_bench_input_times_a_recording_with_io_stages(tmp_path, capsys):
    src = _ball_folder(tmp_path, frames=6)
    args = ["bench", "--input", str(src), "--frames", "4", "--window", "3", "--json"]
    assert main(args) == 0
    (result,) = json.loads(capsys.readouterr().out)
    assert result["frames"] == 4
    assert result["input"] == str(src)
    assert {"flow", "fill", "read", "write", "summary", "io_wait"} <= set(result["stage_ms"])
    assert result["stage_ms"]["read"] > 0
    assert result["us_per_pixel"] > 0


def test_bench_input_table_heads_with_width_x_height_and_the_whole_path(tmp_path, capsys):
    """The heading names the frame size W x H and the recording on one line, however narrow
    the table (a title wrapped the path mid-word)."""
    seq = make_falling_ball(small=True, num_frames=5)
    src = tmp_path / ("a-rather-long-recording-folder-name-" * 3)
    k = dataclasses.replace(seq.intrinsics, width=120)  # the left 120 columns
    with FrameFolderWriter(src, k, depth_unit_mm=0.05) as w:
        for d, i in zip(seq.depth, seq.intensity, strict=True):
            w.write(d[:, :120], i[:, :120])
    args = ["bench", "--input", str(src), "--frames", "3", "--window", "3", "--no-summary"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert f"120x150 px, 3-frame window, 3 frames: {src}\n" in out


def test_bench_input_npz_is_refused_with_one_clear_line(tmp_path, capsys):
    """An .npz is not streamed: one error line that says what to give, not an internal error."""
    seq = make_scene("ball", small=True, num_frames=3, rng=0)
    src = tmp_path / "ball.npz"
    write_npz(seq, src)
    assert main(["bench", "--input", str(src), "--frames", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("fuse4d: error:") == 1
    assert "internal error" not in err
    assert "fuse4d convert" in err


def test_bench_input_causal_runs_the_causal_streaming_path(tmp_path, monkeypatch, capsys):
    import fuse4d.run as run_module

    seen = []
    real = run_module._fuse_streaming

    def spy(*args, **kwargs):
        seen.append(kwargs["params"].causal)
        return real(*args, **kwargs)

    monkeypatch.setattr(run_module, "_fuse_streaming", spy)
    src = _ball_folder(tmp_path, frames=6)
    args = ["bench", "--input", str(src), "--frames", "4", "--window", "3", "--causal"]
    assert main([*args, "--no-summary", "--json"]) == 0
    (result,) = json.loads(capsys.readouterr().out)
    assert result["causal"] is True
    assert result["frames"] == 4
    assert {"flow", "tracking", "fill", "read", "write", "io_wait"} <= set(result["stage_ms"])
    assert seen == [True, True]  # warm-up and timed run


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--depth-unit-mm", "1000"], "depth_unit_mm does not apply to .npz files"),
        (["--intrinsics", "100,100,75,75"], ".npz files store their intrinsics"),
        (["--depth-topic", "/depth"], "option depth_topic does not apply to npz input"),
        (["--no-undistort"], "option undistort does not apply to npz input"),
    ],
)
def test_run_refuses_recording_options_an_npz_does_not_take(
    ball_npz, tmp_path, capsys, option, message
):
    """They were ignored: `fuse4d run x.npz --depth-unit-mm 1000` fused the depth as stored."""
    out = tmp_path / "out.npz"
    assert main(["run", str(ball_npz), "-o", str(out), *option]) == 2
    err = capsys.readouterr().err
    assert err == f"fuse4d: error: {message}" + err.split(message, 1)[1]
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_sensor_option_for_a_folder_is_one_line_not_an_internal_error(tmp_path, capsys):
    folder = write_ball_folder(tmp_path / "rec", frames=3)
    assert main(["run", str(folder), "-o", str(tmp_path / "out"), "--depth-topic", "/d"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fuse4d: error: option depth_topic does not apply to folder input")


def test_depth_in_metres_is_warned_about(ball_npz, tmp_path, capsys):
    """Depth in metres (median 1, the wall) ran silently with every mm scale 1000x too large."""
    seq = load_sequence(ball_npz)
    metres = tmp_path / "metres.npz"
    write_npz(seq.with_depth(seq.depth / 1000), metres)
    with pytest.warns(UserWarning, match=r"^depth \(frame 0\) has a median of 1 mm: fuse4d takes"):
        assert main(["run", str(metres), "-o", str(tmp_path / "out.npz"), "--no-summary"]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # and none for the depth in mm
        assert main(["run", str(ball_npz), "-o", str(tmp_path / "mm.npz"), "--no-summary"]) == 0


def _strict_json(text: str):
    """``json.loads`` that refuses NaN/Infinity (Python's accepts them; JSON has none)."""

    def refuse(name: str):
        raise AssertionError(f"not JSON: bare {name}")

    return json.loads(text, parse_constant=refuse)


def test_run_json_of_a_clip_shorter_than_the_look_ahead_is_strict(ball_npz, tmp_path, capsys):
    """3 frames, window 9 (look-ahead 4): every frame came out of the flush, so there is no
    rate once running (the negative slice kept all but the last: 'ms/frame once running' of
    the flush); the hole shares of a ball without holes are undefined: null, not bare NaN."""
    from fuse4d.cli.cmd_fuse import _time_note
    from fuse4d.run import fuse_file

    out = tmp_path / "short.npz"
    assert main(["run", str(ball_npz), "-o", str(out), "--frames", "0:3", "--json"]) == 0
    summary = _strict_json(capsys.readouterr().out)
    assert summary["frames"] == 3
    assert summary["steady_ms_per_frame"] is None
    assert summary["hole_fraction"] == 0.0
    assert summary["hole_outside_fraction"] is None
    assert summary["raw_roughness_mm"] > 0
    s = fuse_file(ball_npz, tmp_path / "again.npz", frames="0:3")
    assert _time_note(s) == f"{s.ms_per_frame:.0f} ms/frame, start-up and I/O included"


def test_print_json_writes_nan_and_inf_as_null(capsys):
    from fuse4d.cli.cmd_fuse import print_json

    print_json({"a": math.nan, "b": [np.float32(1.5), -math.inf], "c": {"d": np.int64(3)}})
    assert _strict_json(capsys.readouterr().out) == {"a": None, "b": [1.5, None], "c": {"d": 3}}


@pytest.mark.parametrize("mode", ["pipeline", "quality"])
def test_bench_json_is_strict(monkeypatch, capsys, mode):
    """The bench's numbers that could not be measured (C_3D of a method that found no plane,
    a rate of too few frames) were printed as bare NaN."""
    from fuse4d.experiments import quality, speed

    class Result:
        def to_dict(self):
            return {"ms_per_frame": math.nan, "c_3d": math.nan, "frames": 2}

    monkeypatch.setattr(speed, "benchmark_pipeline", lambda *a, **k: Result())
    monkeypatch.setattr(quality, "ball_quality_report", lambda *a, **k: Result())
    args = ["bench", "--small", "--json"] + (["--quality"] if mode == "quality" else [])
    assert main(args) == 0
    (result,) = _strict_json(capsys.readouterr().out)
    assert result == {"ms_per_frame": None, "c_3d": None, "frames": 2}


def test_an_explicit_preset_wins_over_the_config_files(ball_npz, tmp_path, monkeypatch, capsys):
    """`--preset fast --config paper.toml` ran PMBP (the file's preset won) and the report
    recorded "fast"; now the command line wins (as --set and --window do), and the preset
    recorded is the one used."""
    from fuse4d.cli import cmd_report
    from fuse4d.cli.cmd_fuse import _resolve

    cfg = tmp_path / "paper.toml"
    cfg.write_text('preset = "paper"\n[fusion]\nnum_frames = 3\n', encoding="utf-8")
    rest = (None, False, None, None, None)
    fusion, flow, name = _resolve("fast", cfg, *rest, preset_given=True)
    assert (flow.method, name, fusion.num_frames) == ("dis", "fast", 3)
    _, flow, name = _resolve("fast", cfg, *rest)  # --preset not typed: the file's
    assert (flow.method, name) == ("pmbp", "paper")
    recorded = []
    monkeypatch.setattr(cmd_report, "make_report", lambda *a, **k: recorded.append(k["params"]))
    out, rep = str(tmp_path / "o.npz"), str(tmp_path / "rep")
    args = ["run", str(ball_npz), "-o", out, "--config", str(cfg), "--frames", "0:3"]
    assert main([*args, "--preset", "fast", "--report", rep, "--json"]) == 0
    assert _strict_json(capsys.readouterr().out)["flow_method"] == "dis"
    assert (recorded[0]["preset"], recorded[0]["flow_method"]) == ("fast", "dis")


def test_a_config_cache_dir_under_home_is_expanded(ball_npz, tmp_path, monkeypatch, capsys):
    """`[flow] cache_dir = "~/fcache"` made a folder named "~" in the working folder (the
    safety check expanded ~, the cache did not)."""
    from fuse4d.flow import FlowCache

    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    assert FlowCache("~/x").directory == home / "x"
    cfg = tmp_path / "c.toml"
    cfg.write_text('[flow]\ncache_dir = "~/fcache"\n', encoding="utf-8")
    args = ["run", str(ball_npz), "-o", "o.npz", "--config", str(cfg), "--frames", "0:3"]
    assert main([*args, "--window", "3", "--no-summary"]) == 0
    assert not (work / "~").exists()
    assert list((home / "fcache").glob("??/*.npy"))


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--save-flows"], "--save-flows: options of --engine dask"),
        (["--no-warm-start"], "--warm-start/--no-warm-start: options of --engine dask"),
        (["--workers", "2", "--scheduler", "threads"], "--scheduler, --workers: options of"),
        (["--chunk-frames", "4"], "--chunk-frames: options of --engine dask"),
        (["--engine", "dask", "--summary-every", "2"], "--summary-every: options of the stream"),
    ],
)
def test_run_refuses_options_of_the_other_engine(ball_npz, tmp_path, capsys, extra, says):
    """Each was accepted and ignored (exit 0, not what was asked for)."""
    out = tmp_path / "o.npz"
    assert main(["run", str(ball_npz), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("fuse4d: error:") == 1
    assert says in err
    assert not out.exists()


def test_run_summary_without_the_summary_says_it_was_skipped(ball_npz, tmp_path, capsys):
    """--no-summary printed "n/a (fewer than 2 frames or no static pixel)", "the same 0
    pixels" and "temporal support n/a", as if they had been scored; Eq. 7 was described as a
    sum of distances over a hard-coded 5x5 window."""
    from rich.console import Console

    from fuse4d.cli.cmd_fuse import run_summary_table
    from fuse4d.run import fuse_file

    summary = fuse_file(ball_npz, tmp_path / "q.npz", frames="0:3", quality=False)
    console = Console(width=400, file=io.StringIO())
    console.print(run_summary_table(summary, summary.params, scored=False))
    text = console.file.getvalue()
    assert "skipped (--no-summary)" in text
    for wrong in ("fewer than 2 frames", "the same 0 pixels", "│ temporal support", "n/a"):
        assert wrong not in text
    scored = fuse_file(
        ball_npz, tmp_path / "s.npz", frames="0:3", fusion=FusionParams(fill_holes=True)
    )
    assert scored.roughness_window == 5
    scored.roughness_window = 7
    console = Console(width=400, file=io.StringIO())
    console.print(run_summary_table(scored, scored.params))
    text = console.file.getvalue()
    assert "N x the centre point's distance to the plane fitted to its 7x7 window" in text
    assert "RMS distance to the 7x7 window's plane" in text
    assert "5x5" not in text
    assert "skipped" not in text
    args = ["run", str(ball_npz), "-o", str(tmp_path / "c.npz"), "--frames", "0:3"]
    assert main([*args, "--no-summary"]) == 0
    assert "skipped (--no-summary)" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--window", "0"], "--window 0: FusionParams.num_frames must be an integer in [1, 256]"),
        (["--set", "spatial_radius=-1"], "--set: FusionParams.spatial_radius must be"),
    ],
)
def test_a_bad_option_value_names_the_option(ball_npz, tmp_path, capsys, extra, says):
    assert main(["run", str(ball_npz), "-o", str(tmp_path / "o.npz"), *extra]) == 2
    assert says in capsys.readouterr().err
    assert main(["live", str(ball_npz), *extra]) == 2
    assert says in capsys.readouterr().err


def test_an_npz_output_records_the_runs_parameters(ball_npz, tmp_path, capsys):
    """A folder output's manifest and a .zarr's attributes hold the parameters; an .npz held
    none, so `fuse4d report IN OUT.npz` could not say what was run."""
    from fuse4d.run import NPZ_PARAMS_KEY

    out = tmp_path / "o.npz"
    args = ["run", str(ball_npz), "-o", str(out), "--frames", "0:3", "--window", "3"]
    assert main([*args, "--set", "temporal_gate=inf", "--no-summary"]) == 0
    record = json.loads(str(read_npz_extra(out)[NPZ_PARAMS_KEY]))
    assert record["flow"] == {"method": "dis", "params": {}}
    params = FusionParams.from_dict(record["fusion"])
    assert params == FusionParams(num_frames=3, temporal_gate=math.inf, flying_pixels="off")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_sequence(out).num_frames == 3  # the reader passes the key by
    again = tmp_path / "again.npz"  # an output fused again records its own run
    assert main(["run", str(out), "-o", str(again), "--window", "5", "--no-summary"]) == 0
    assert json.loads(str(read_npz_extra(again)[NPZ_PARAMS_KEY]))["fusion"]["num_frames"] == 5


def test_bench_setup_is_apart_from_the_steady_rate_in_both_modes(tmp_path, monkeypatch):
    """Building the engine (and, for a recording, opening reader and writer) is one-off
    setup, apart from ``ms_per_frame`` in both modes: ``--input`` had it in its total and no
    row showed it, while the synthetic bench built its engine before the clock."""
    import time
    from types import SimpleNamespace

    import fuse4d.run as run_module
    from fuse4d.experiments import speed

    class Slow(speed.FusionEngine):
        def __init__(self, *args, **kwargs):
            time.sleep(0.3)  # the committed ring buffers of a large window
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(speed, "FusionEngine", Slow)
    synthetic = speed.benchmark_pipeline("fast", small=True, num_frames=3, window=3)
    assert synthetic.setup_ms >= 300
    assert synthetic.wall_ms_per_frame == pytest.approx(
        synthetic.ms_per_frame + synthetic.setup_ms / 3
    )
    covers = synthetic.to_dict()["covers"]
    assert "setup excluded" in covers["ms_per_frame"]

    def streaming(**kwargs):  # 0.4 s of setup (recorded), 0.1 s of frames
        time.sleep(0.5)
        timings = {"flow": 0.05, "read": 0.02, "setup": 0.4}
        return SimpleNamespace(frames=2, flow_method="dis", shape=(4, 4), timings=timings)

    monkeypatch.setattr(run_module, "_fuse_streaming", streaming)
    src = _ball_folder(tmp_path, frames=3)
    recording = speed.benchmark_recording(src, num_frames=2, window=2)
    assert recording.setup_ms == pytest.approx(400)
    assert 50 <= recording.ms_per_frame < 150  # 0.1 s over 2 frames, not 250 ms
    assert "setup" not in recording.stage_ms
    assert recording.stage_ms["flow"] == pytest.approx(25)
    assert recording.wall_ms_per_frame >= 250


def test_bench_engine_out_of_memory_is_a_parameter_error(monkeypatch, capsys):
    """A MemoryError building the engine (a large --window) was an internal error."""
    from fuse4d.experiments import speed

    class Huge(speed.FusionEngine):
        def __init__(self, *args, **kwargs):
            raise MemoryError

    monkeypatch.setattr(speed, "FusionEngine", Huge)
    with pytest.raises(ParameterError, match=r"window=3 \(--window\).* 150x150 px"):
        speed.benchmark_pipeline("fast", small=True, num_frames=3, window=3)
    assert main(["bench", "--small", "--frames", "3", "--window", "3"]) == 2
    err = capsys.readouterr().err
    assert err.count("fuse4d: error:") == 1
    assert "--window" in err
    assert "internal error" not in err


def test_bench_warns_of_a_window_longer_than_the_frames_timed(tmp_path):
    """`bench --small --window 30` on 18 frames headed '30-frame window' and never reached
    it; both modes now say so."""
    from fuse4d.experiments import speed

    with pytest.warns(UserWarning, match="window 4 is longer than the 3 frames timed"):
        speed.benchmark_pipeline("fast", small=True, num_frames=3, window=4)
    src = _ball_folder(tmp_path, frames=3)
    with pytest.warns(UserWarning, match="window 5 is longer than the 3 frames timed"):
        speed.benchmark_recording(src, num_frames=10, window=5, summary=False)


def test_a_streaming_run_records_its_setup_apart_from_the_frames(tmp_path, capsys):
    """The streaming run times its one-off setup (reader, writer, engine; closing) as
    timings['setup']: --json gives it as setup_ms, not as a per-frame stage, and bench
    --input takes it out of its steady rate (it was hidden in the total)."""
    import json

    from fuse4d.experiments import speed

    src = _ball_folder(tmp_path, frames=4)
    assert main(["run", str(src), "-o", str(tmp_path / "o"), "--window", "3", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["setup_ms"] > 0
    assert "setup" not in record["timings_ms_per_frame"]
    bench = speed.benchmark_recording(src, num_frames=4, window=3)
    assert math.isfinite(bench.setup_ms)
    assert bench.setup_ms > 0
    assert bench.wall_ms_per_frame > bench.ms_per_frame


def test_window_and_set_are_checked_together(tmp_path, capsys):
    """--window 16 --set min_temporal_support=12 was refused against the preset's 9 frames
    (--set applied before --window)."""
    src = _ball_folder(tmp_path, frames=3)
    args = ["run", str(src), "-o", str(tmp_path / "o"), "--no-summary"]
    assert main([*args, "--window", "16", "--set", "min_temporal_support=12"]) == 0
    capsys.readouterr()
    assert main([*args, "--window", "3", "--set", "min_temporal_support=9", "--force"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fuse4d: error: --set, --window 3: ")
    assert "num_frames=3" in " ".join(err.split())


def test_a_config_files_fusion_is_checked_with_the_window_given(tmp_path, capsys):
    """A config file's min_temporal_support = 12 with --window 16 was checked against the
    preset's 9 frames before --window applied (the file was blamed)."""
    src = _ball_folder(tmp_path, frames=3)
    cfg = tmp_path / "c.toml"
    cfg.write_text("[fusion]\nmin_temporal_support = 12\n")
    args = ["run", str(src), "-o", str(tmp_path / "o"), "--no-summary", "--config", str(cfg)]
    assert main([*args, "--window", "16"]) == 0
    capsys.readouterr()
    assert main([*args, "--force"]) == 2  # the preset's 9 frames: the file's value is refused
    err = " ".join(capsys.readouterr().err.split())
    assert err.startswith(f"fuse4d: error: {cfg}: ")
    assert "min_temporal_support" in err
