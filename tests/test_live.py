"""``fuse4d live`` without a camera: a recording played back in real time.

Checks the achieved rate and drop count, that without drops the output equals a causal
:func:`fuse4d.fuse_sequence` bit for bit, that a gap restarts the engine (the frames after it
equal a causal fusion of the frames after the gap alone), and that an overloaded pipeline
drops frames and keeps its latency bounded.
"""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fuse4d import FusionParams, Sequence, fuse_sequence
from fuse4d._signals import ECHO_S
from fuse4d.cli import main
from fuse4d.errors import ParameterError
from fuse4d.io import load_sequence, write_npz
from fuse4d.live import (
    CapturedFrame,
    DropOldestQueue,
    LiveWriter,
    RecordingSource,
    display_available,
    display_problem,
    run_live,
    side_by_side,
)
from fuse4d.synthetic import make_scene

CAUSAL3 = FusionParams(num_frames=3, causal=True)


@pytest.fixture(autouse=True)
def _no_earlier_signal():
    """Each test's first signal counts (not as the echo of another test's, 0.2 s before)."""
    from fuse4d import _signals

    _signals.reset()


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    """The small ball (12 frames, 150x150) as an .npz recording, and its sequence."""
    seq = make_scene("ball", small=True, num_frames=12, rng=0)
    path = tmp_path_factory.mktemp("live") / "ball.npz"
    write_npz(seq, path)
    return path, seq


@pytest.fixture(scope="module")
def reference(ball):
    """Causal 3-frame fusion of the whole ball (the engine's own in-memory face)."""
    _, seq = ball
    return fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=CAUSAL3).depth


class _ListSource:
    """Frames with given source numbers, released at ``fps`` (a camera that dropped some)."""

    def __init__(self, seq, indices, fps: float | None = None) -> None:
        self.seq, self.indices, self.fps = seq, list(indices), fps
        self.intrinsics = seq.intrinsics
        self.depth_unit_mm = None

    def __iter__(self):
        start = time.perf_counter()
        for order, k in enumerate(self.indices):
            if self.fps:
                time.sleep(max(0.0, start + order / self.fps - time.perf_counter()))
            yield CapturedFrame(
                k, self.seq.depth[k], self.seq.intensity[k], None, time.perf_counter()
            )

    def close(self) -> None:
        pass


def _collect():
    frames: dict[int, np.ndarray] = {}

    def sink(captured, fused) -> None:
        frames[captured.index] = fused.depth.copy()

    return frames, sink


def test_drop_oldest_queue():
    q = DropOldestQueue(2)
    assert q.put(1) is None
    assert q.put(2) is None
    assert q.put(3) == 1  # full: the oldest goes
    assert q.dropped == 1
    assert q.get() == 2
    assert q.get() == 3
    assert q.get(timeout=0.01) is None
    q.close()
    assert q.get() is None
    with pytest.raises(ValueError, match="queue size"):
        DropOldestQueue(0)


def test_realtime_playback_without_drops_equals_causal_fusion(ball, reference):
    path, _seq = ball
    frames, sink = _collect()
    source = RecordingSource(path, realtime=True, fps=30.0)
    try:
        stats = run_live(source, fusion=CAUSAL3, queue_size=64, sink=sink)
    finally:
        source.close()
    assert stats.frames_captured == stats.frames_fused == 12
    assert stats.dropped == stats.gaps == stats.restarts == 0
    assert 24.0 <= stats.input_fps <= 31.0  # paced at 30 fps
    assert stats.seconds >= 11 / 30.0 * 0.95
    assert stats.indices == list(range(12))
    assert stats.window_frames == [1, 2] + [3] * 10
    assert set(stats.latency_ms) == {"p50", "p95", "max", "mean"}
    out = np.stack([frames[k] for k in range(12)])
    np.testing.assert_array_equal(out, reference)  # bit for bit, NaNs in the same places


def test_gap_restarts_the_engine(ball, reference):
    """Frame 6 missing: 0-5 as the causal fusion of all; 7-11 as that of frames 7-11 alone."""
    _, seq = ball
    frames, sink = _collect()
    indices = [*range(6), *range(7, 12)]
    stats = run_live(_ListSource(seq, indices), fusion=CAUSAL3, sink=sink, block=True)
    assert stats.gaps == stats.restarts == 1
    assert stats.tracked_gaps == 0
    assert stats.window_frames == [1, 2, 3, 3, 3, 3, 1, 2, 3, 3, 3]
    for k in range(6):
        np.testing.assert_array_equal(frames[k], reference[k])
    after = fuse_sequence(seq.depth[7:], seq.intensity[7:], seq.intrinsics, fusion=CAUSAL3)
    for k in range(7, 12):
        np.testing.assert_array_equal(frames[k], after.depth[k - 7])


def test_gap_tracked_across_is_counted(ball):
    _, seq = ball
    indices = [*range(6), *range(7, 12)]
    stats = run_live(_ListSource(seq, indices), fusion=CAUSAL3, on_gap="track", block=True)
    assert stats.gaps == stats.tracked_gaps == 1
    assert stats.restarts == 0
    assert stats.window_frames[6] == 3  # the window ran on across the gap
    with pytest.raises(ValueError, match="on_gap"):
        run_live(_ListSource(seq, [0]), on_gap="skip")  # type: ignore[arg-type]


def test_overload_drops_oldest_and_keeps_latency_bounded(ball):
    """A fusion step of >= 100 ms against frames every 20 ms: most frames are dropped, and
    no output is older than the queue allows (1 waiting + 1 in fusion, plus slack)."""
    _, seq = ball
    order = list(range(12)) * 3  # the ball three times over: 36 frames at 50 fps
    long = Sequence(
        depth=seq.depth[order], intensity=seq.intensity[order], intrinsics=seq.intrinsics
    )
    source = _ListSource(long, range(36), fps=50.0)
    step = 0.1
    stats = run_live(source, fusion=CAUSAL3, queue_size=1, extra_delay_s=step)
    assert stats.frames_captured == 36
    assert stats.dropped > 10
    assert stats.frames_fused + stats.dropped == stats.frames_captured
    assert stats.gaps == stats.restarts >= 1
    assert stats.fps < 15.0
    assert stats.latency_ms["max"] < 1000 * (2 * step + 0.5)
    assert all(b > a for a, b in zip(stats.indices, stats.indices[1:], strict=False))


def test_stop_event_ends_the_run(ball):
    _, seq = ball
    stop = threading.Event()
    seen = []

    def sink(captured, fused) -> None:
        seen.append(captured.index)
        if len(seen) == 3:
            stop.set()

    source = _ListSource(seq, range(12), fps=30.0)
    stats = run_live(source, fusion=CAUSAL3, sink=sink, stop=stop, warmup=False)
    assert stats.frames_fused < 12
    # every captured frame is accounted for (those waiting at the stop were not)
    assert stats.frames_captured == stats.frames_fused + stats.dropped + stats.unfused_at_stop
    assert stats.to_dict()["unfused_at_stop"] == stats.unfused_at_stop


def test_recording_without_rate_needs_fps(tmp_path, ball):
    _, seq = ball
    path = tmp_path / "norate.npz"
    write_npz(Sequence(depth=seq.depth, intensity=seq.intensity, intrinsics=seq.intrinsics), path)
    with pytest.raises(ValueError, match="--fps"):
        RecordingSource(path, realtime=True)
    RecordingSource(path, realtime=False).close()
    with pytest.raises(ValueError, match="fps must be > 0"):
        RecordingSource(path, fps=0.0)


def test_playback_without_timestamps_stamps_frames_at_the_rate(tmp_path, ball):
    """A recording without timestamps played at --fps: each frame carries its time at that
    rate, so an output of a run that dropped frames keeps the gaps (it used to store fps
    alone, which says the frames were consecutive)."""
    _, seq = ball
    path = tmp_path / "norate.npz"
    write_npz(Sequence(depth=seq.depth, intensity=seq.intensity, intrinsics=seq.intrinsics), path)
    source = RecordingSource(path, realtime=False, fps=10.0, frames="2:6")
    try:
        stamps = [(f.index, f.timestamp) for f in source]
    finally:
        source.close()
    assert stamps == [(2, 0.0), (3, 0.1), (4, 0.2), (5, pytest.approx(0.3))]


def test_live_writer_keeps_the_camera_kind(tmp_path, ball):
    _, seq = ball
    for name in ("o.npz", "o_folder"):
        path = tmp_path / name
        with LiveWriter(
            path, seq.intrinsics, fps=30.0, sensor="tof", behind=0, warn_coarse_unit=False
        ) as writer:
            for k in range(2):
                captured = CapturedFrame(k, seq.depth[k], seq.intensity[k], None, 0.0)
                writer(captured, SimpleNamespace(depth=seq.depth[k], source=None))
        assert load_sequence(path).sensor == "tof", name


def test_side_by_side_image(ball):
    _, seq = ball
    img = side_by_side(seq.depth[0], seq.depth[1])
    assert img.shape == (150, 300, 3)
    assert img.dtype == np.uint8


def test_side_by_side_with_a_kept_scale_equals_the_per_frame_default(ball):
    from fuse4d.live import display_range

    _, seq = ball
    lo, hi = display_range(seq.depth[0])
    assert lo < hi
    np.testing.assert_array_equal(
        side_by_side(seq.depth[0], seq.depth[1], (lo, hi)), side_by_side(seq.depth[0], seq.depth[1])
    )
    assert display_range(np.full((4, 4), np.nan, np.float32)) is None


@pytest.mark.parametrize("suffix", ["", ".mkv"])
def test_live_writer_behind_writes_what_the_inline_writer_writes(ball, tmp_path, suffix):
    """The write-behind LiveWriter (default) and the inline one (behind=0) give equal files."""
    from fuse4d.io import open_frames
    from fuse4d.live import LiveWriter

    if suffix == ".mkv":
        pytest.importorskip("av")
    _, seq = ball
    outs = []
    for behind in (0, 2):
        out = tmp_path / f"w{behind}{suffix}"
        # the recording's own 0.1 mm unit, as `fuse4d live` writes it (no coarse-unit warning)
        writer = LiveWriter(
            out, seq.intrinsics, depth_unit_mm=0.1, fps=30.0, behind=behind, warn_coarse_unit=False
        )
        with writer as w:
            for t, fr in enumerate(
                fuse_sequence(
                    seq.depth[:5], seq.intensity[:5], seq.intrinsics, fusion=CAUSAL3
                ).depth
            ):
                cap = CapturedFrame(t, seq.depth[t], seq.intensity[t], t / 30.0, 0.0)
                w(cap, _Fused(fr))
        with open_frames(out) as r:
            outs.append(np.stack([f.depth for f in r]))
    assert outs[0].shape[0] == 5
    np.testing.assert_array_equal(outs[0], outs[1])


class _Fused:
    def __init__(self, depth) -> None:
        self.depth = depth


def test_cli_live_writes_the_causal_fusion(ball, reference, tmp_path, capsys):
    path, _ = ball
    out = tmp_path / "fused.npz"
    args = ["live", str(path), "--fps", "30", "--window", "3", "--queue", "64", "-o", str(out)]
    assert main([*args, "--json", "--show"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["frames_fused"] == 12
    assert summary["dropped"] == 0
    assert summary["window"] == 3
    assert summary["realtime"] is True
    if not display_available():
        assert f"{display_problem()}: --show skipped" in captured.err
    np.testing.assert_array_equal(load_sequence(out).depth, reference)
    assert main([*args]) == 2  # the output exists: one error line, no fusion
    assert capsys.readouterr().err.count("fuse4d: error:") == 1


def test_show_with_a_headless_opencv_is_skipped_not_a_crash(ball, capsys, monkeypatch):
    """With DISPLAY set, `cv2.imshow` of the headless OpenCV that fuse4d depends on raised
    "The function is not implemented" on the first frame: an internal error, output lost."""
    import cv2

    if "GUI:                           NONE" not in cv2.getBuildInformation():
        pytest.skip("this OpenCV has a GUI")
    monkeypatch.setenv("DISPLAY", ":99")
    path, _ = ball
    assert main(["live", str(path), "--window", "3", "--frames", "3", "--show", "--json"]) == 0
    captured = capsys.readouterr()
    assert "this OpenCV has no GUI (a headless build" in captured.err
    assert json.loads(captured.out)["frames_fused"] == 3


def test_cli_live_says_what_to_do_when_the_fusion_falls_behind(ball, capsys):
    """Overloaded (every fusion step 80 ms longer, 30 fps in): the drops, the frames fused
    per output and the remedies on stderr, the JSON on stdout unchanged; without drops
    (a queue as long as the recording) nothing is said."""
    path, _ = ball
    args = ["live", str(path), "--fps", "30", "--window", "3", "--json"]
    assert main([*args, "--simulate-delay-ms", "80"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["dropped"] > 0.1 * summary["frames_captured"]
    assert f"{summary['dropped']} of {summary['frames_captured']} frames dropped" in captured.err
    assert "--on-gap track" in captured.err
    assert "--decimate 2" in captured.err
    assert main([*args, "--queue", "64"]) == 0
    assert "fell behind" not in capsys.readouterr().err


def test_cli_live_without_camera_fails_cleanly(capsys, monkeypatch):
    import fuse4d.live

    monkeypatch.setattr(fuse4d.live, "realsense_available", lambda: False)
    assert main(["live"]) == 2
    assert "no RealSense camera" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--fps", "nan"], "--fps must be a number > 0, got nan"),
        (["--frames", "0"], "--frames must be >= 1, got 0"),
        (["--duration", "0"], "--duration must be a number of seconds > 0"),
        (["--simulate-delay-ms", "-5"], "--simulate-delay-ms must be >= 0"),
        (["--width", "320", "--serial", "1"], "--width, --serial: for a camera; "),
        (["--set", "iterations=2"], "live fusion fuses each frame once"),
        (["-o", "out.mp4"], "out.mp4: fuse4d does not write .mp4 files"),
    ],
)
def test_cli_live_bad_options_are_one_line_and_write_nothing(
    ball, tmp_path, monkeypatch, capsys, args, says
):
    """Each was an internal error, a silently ignored option or a run of 1 frame (--frames
    0), or an output folder named out.mp4."""
    monkeypatch.chdir(tmp_path)
    assert main(["live", str(ball[0]), *args]) == 2
    assert says in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


class _FakeRealSense:
    """The parts of the pyrealsense2 API that RealSenseSource uses, replaying the ball."""

    def __init__(self, seq, *, fail_after: int | None = None, modes=None) -> None:
        import types

        self.seq = seq
        self.stopped = False
        self.stream = types.SimpleNamespace(depth="depth", infrared="infrared")
        self.format = types.SimpleNamespace(z16="z16", y8="y8")
        self.option = types.SimpleNamespace(emitter_enabled="emitter")
        self.camera_info = types.SimpleNamespace(name="name")
        self.options: dict[str, float] = {}
        self.enabled: list[tuple] = []
        fake = self

        class _Frame:
            def __init__(self, data, number) -> None:
                self.data, self.number = data, number

            def __bool__(self) -> bool:
                return True

            def get_data(self):
                return self.data

            def get_frame_number(self) -> int:
                return self.number

            def get_timestamp(self) -> float:
                return 1000.0 * self.number / 30.0

        class _Frameset:
            def __init__(self, k: int) -> None:
                d = np.nan_to_num(fake.seq.depth[k], nan=0.0)
                self.depth = _Frame(np.round(d).astype(np.uint16), k)
                self.ir = _Frame(np.round(255 * fake.seq.intensity[k]).astype(np.uint8), k)

            def get_depth_frame(self):
                return self.depth

            def get_infrared_frame(self, index: int):
                assert index == 1
                return self.ir

        class _Sensor:
            def get_depth_scale(self) -> float:
                return 0.001  # 1 mm per unit

            def supports(self, option) -> bool:
                return True

            def set_option(self, option, value) -> None:
                fake.options[option] = value

        k = seq.intrinsics
        intr = types.SimpleNamespace(
            fx=k.fx, fy=k.fy, ppx=k.cx, ppy=k.cy, width=k.width, height=k.height
        )
        video = types.SimpleNamespace(get_intrinsics=lambda: intr)
        stream_profile = types.SimpleNamespace(as_video_stream_profile=lambda: video)
        names = {"name": "Intel RealSense D435"}
        device = types.SimpleNamespace(first_depth_sensor=_Sensor, get_info=names.__getitem__)
        profile = types.SimpleNamespace(
            get_device=lambda: device, get_stream=lambda stream: stream_profile
        )

        class _Pipeline:
            def __init__(self) -> None:
                self.k = 0

            def start(self, config):
                if modes is not None and not set(fake.enabled) <= set(modes):
                    raise RuntimeError("Couldn't resolve requests")
                return profile

            def wait_for_frames(self, timeout_ms: int):
                time.sleep(1 / 30)
                if fail_after is not None and self.k >= fail_after:
                    raise RuntimeError(f"Frame didn't arrive within {timeout_ms}")
                self.k += 1
                return _Frameset((self.k - 1) % len(fake.seq.depth))

            def stop(self) -> None:
                fake.stopped = True

        class _Config:
            def enable_stream(self, *args) -> None:
                fake.enabled.append(args)

            def enable_device(self, serial) -> None:
                fake.enabled.append(("device", serial))

        self.pipeline, self.config = _Pipeline, _Config
        self.context = lambda: types.SimpleNamespace(query_devices=lambda: [object()])


def test_realsense_source_against_a_fake_pipeline(ball, monkeypatch):
    """No camera here: the pipeline calls, units and registration against a stand-in."""
    import sys

    from fuse4d.live import RealSenseSource, realsense_available

    _, seq = ball
    fake = _FakeRealSense(seq)
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake)
    assert realsense_available()
    source = RealSenseSource(width=150, height=150, fps=30, serial="123", emitter=False)
    assert ("depth", 150, 150, "z16", 30) in fake.enabled
    assert ("infrared", 1, 150, 150, "y8", 30) in fake.enabled
    assert fake.options == {"emitter": 0.0}
    assert source.depth_unit_mm == pytest.approx(1.0)
    assert source.intrinsics.width == 150
    assert source.sensor == "active-stereo"  # from the camera's name: no flying-pixel removal
    frame = next(iter(source))
    valid = np.isfinite(seq.depth[0])
    assert np.array_equal(np.isfinite(frame.depth), valid & (np.round(seq.depth[0]) > 0))
    np.testing.assert_allclose(frame.depth[valid], seq.depth[0][valid], atol=0.5)
    stats = run_live(source, fusion=CAUSAL3, max_frames=6, queue_size=8)
    source.close()
    assert fake.stopped
    assert stats.frames_fused == 6


def test_a_camera_lost_mid_run_keeps_what_was_fused(ball, tmp_path, monkeypatch, capsys):
    """A camera that stopped delivering (pyrealsense2's RuntimeError "Frame didn't arrive")
    was an internal error, and the frames fused until then were lost. Now one error line,
    exit 2, and the output holds them (a camera's frames cannot be played again)."""
    import sys

    _, seq = ball
    monkeypatch.setitem(sys.modules, "pyrealsense2", _FakeRealSense(seq, fail_after=5))
    out = tmp_path / "cam.npz"
    args = ["live", "--width", "150", "--height", "150", "--window", "3", "-o", str(out)]
    assert main([*args, "--json"]) == 2
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["frames_fused"] == 5
    assert "no frame within 5000 ms (disconnected?)" in summary["source_error"]
    err = captured.err.strip().splitlines()[-1]
    assert err.startswith("fuse4d: error: RealSense camera: no frame within 5000 ms")
    assert err.endswith(f"the 5 frames fused before it are in {out}")
    assert load_sequence(out).num_frames == 5


def test_a_camera_mode_it_cannot_stream_is_one_error(ball, monkeypatch, capsys):
    import sys

    _, seq = ball
    modes = [("depth", 150, 150, "z16", 30), ("infrared", 1, 150, 150, "y8", 30)]
    monkeypatch.setitem(sys.modules, "pyrealsense2", _FakeRealSense(seq, modes=modes))
    assert main(["live", "--width", "150", "--height", "150", "--fps", "15"]) == 2
    err = capsys.readouterr().err
    assert (
        "fuse4d: error: RealSense camera: cannot stream depth z16 + IR y8 at 150x150, 15 fps" in err
    )
    assert "Traceback" not in err
    assert "internal error" not in err
    # 29.97 was truncated to 29, a rate no RealSense streams
    assert main(["live", "--fps", "29.97"]) == 2
    assert "a camera streams at a whole number of frames per second, got 29.97" in (
        capsys.readouterr().err
    )


def test_ctrl_c_stops_the_run_with_what_was_fused(ball):
    """Ctrl-C, SIGTERM, SIGHUP set the stop event (a KeyboardInterrupt raised while the numba
    kernels loaded was swallowed by a ctypes callback, and the run went on); a second one
    interrupts."""
    import os
    import signal

    _, seq = ball
    sent = []

    def sink(captured, fused) -> None:
        sent.append(captured.index)
        if len(sent) == 3:
            os.kill(os.getpid(), signal.SIGINT)

    from fuse4d._signals import INTERRUPTED

    INTERRUPTED.clear()
    stats = run_live(_ListSource(seq, range(12), fps=30.0), fusion=CAUSAL3, sink=sink)
    assert stats.interrupted
    # a normal stop: a bug while writing afterwards must not read as the interrupt
    assert not INTERRUPTED.is_set()
    assert stats.frames_fused == 3  # the loop ends at the stop
    assert stats.to_dict()["interrupted"] is True
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored

    def twice(captured, fused) -> None:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(ECHO_S + 0.05)
        os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(KeyboardInterrupt):
        run_live(_ListSource(seq, range(12), fps=30.0), fusion=CAUSAL3, sink=twice)
    assert INTERRUPTED.is_set()  # (an interrupt even where Python drops it: a __del__)


def test_the_same_signal_twice_at_once_is_one_stop(ball):
    """GNU `timeout -s INT` sends SIGINT to the process and then to its group, ms apart: the
    second read as a second Ctrl-C, and the run was thrown away."""
    import os
    import signal

    _, seq = ball
    sent = []

    def echo(captured, fused) -> None:
        sent.append(captured.index)
        if len(sent) == 3:
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)

    try:
        stats = run_live(_ListSource(seq, range(12), fps=30.0), fusion=CAUSAL3, sink=echo)
    except KeyboardInterrupt:
        pytest.fail("the signal delivered twice at once aborted the run")
    assert stats.interrupted
    assert stats.frames_fused == 3


def test_ctrl_c_before_the_first_frame_interrupts(ball):
    """A camera's first frame can take seconds: a Ctrl-C then ended "normally" with 0 frames
    (with -o: "no frame was written", exit 2)."""
    import os
    import signal

    _, seq = ball

    class _Slow(_ListSource):
        def __iter__(self):
            time.sleep(1.0)
            yield from super().__iter__()

    timer = threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_live(_Slow(seq, range(12)), fusion=CAUSAL3, warmup=False)
    finally:
        timer.cancel()


def test_a_slow_playback_rate_is_kept(tmp_path, ball, monkeypatch):
    """--fps 0.1: every wait of 10 s was taken for a jump in the timestamps and skipped."""
    from fuse4d import live

    _, seq = ball
    path = tmp_path / "norate.npz"
    write_npz(Sequence(depth=seq.depth, intensity=seq.intensity, intrinsics=seq.intrinsics), path)
    monkeypatch.setattr(live, "MAX_PLAYBACK_WAIT_S", 0.05)  # waits of 0.1 s are "long"
    source = RecordingSource(path, realtime=True, fps=10.0, frames="0:4")
    t0 = time.perf_counter()
    try:
        assert len(list(source)) == 4
    finally:
        source.close()
    assert time.perf_counter() - t0 >= 0.29


def test_ctrl_c_during_the_warm_up_interrupts_before_capture(ball, monkeypatch):
    import os
    import signal

    from fuse4d import live

    _, seq = ball
    monkeypatch.setattr(live, "_warm_up", lambda *a: os.kill(os.getpid(), signal.SIGINT))
    source = _ListSource(seq, range(12), fps=30.0)
    with pytest.raises(KeyboardInterrupt):
        run_live(source, fusion=CAUSAL3)


def test_a_jump_in_the_timestamps_is_played_without_the_wait(tmp_path, ball):
    """time.sleep(1e10) raised OverflowError: an internal error (a paused recording, or ns
    stored as s, hung for the length of the jump)."""
    _, seq = ball
    path = tmp_path / "jump.npz"
    three = seq.frames(0, 3)
    ts = np.array([0.0, 1e10, 1e10 + 0.03])
    write_npz(dataclasses.replace(three, timestamps=ts, fps=None), path)
    source = RecordingSource(path, realtime=True)
    t0 = time.perf_counter()
    try:
        with pytest.warns(
            UserWarning, match=r"jump.npz \(frame 1\): the timestamps jump by 1e\+10 s"
        ):
            frames = list(source)
    finally:
        source.close()
    assert [f.index for f in frames] == [0, 1, 2]
    assert time.perf_counter() - t0 < 2.0
    assert source.pace == "its recorded timestamps"


def test_live_output_states_the_recordings_rate_not_the_playback_rate(tmp_path, ball):
    """--fps 60 on a 30 Hz recording with timestamps wrote fps 60 beside 30 Hz times."""
    _, seq = ball
    path, out = tmp_path / "ts.npz", tmp_path / "o.npz"
    write_npz(dataclasses.replace(seq, timestamps=5.0 + np.arange(12) / 30.0, fps=None), path)
    args = ["live", str(path), "--fps", "60", "--window", "3", "--queue", "64", "-o", str(out)]
    assert main(args) == 0  # (a queue as long as the recording: no frame dropped under load)
    written = load_sequence(out)
    assert written.fps == pytest.approx(30.0)
    np.testing.assert_allclose(np.diff(written.timestamps), 1 / 30.0, rtol=1e-6)


def test_an_npz_live_output_without_frames_is_an_error(tmp_path, ball):
    _, seq = ball
    with (
        pytest.raises(ParameterError, match=r"empty\.npz: no frame was written"),
        LiveWriter(tmp_path / "empty.npz", seq.intrinsics),
    ):
        pass
    assert not (tmp_path / "empty.npz").exists()


def test_window_sink_keeps_the_first_frames_scale(ball, monkeypatch):
    import cv2

    from fuse4d.cli.cmd_live import _window_sink

    _, seq = ball
    shown = []
    monkeypatch.setattr(cv2, "imshow", lambda name, image: shown.append(image))
    monkeypatch.setattr(cv2, "waitKey", lambda ms: -1)
    stop = threading.Event()
    sink = _window_sink(stop)
    for t in (0, 1):
        sink(CapturedFrame(t, seq.depth[t], seq.intensity[t], None, 0.0), _Fused(seq.depth[t]))
    assert not stop.is_set()
    np.testing.assert_array_equal(shown[0], side_by_side(seq.depth[0], seq.depth[0]))
    expected = side_by_side(seq.depth[1], seq.depth[1], _scale(seq.depth[0]))  # frame 0's scale
    np.testing.assert_array_equal(shown[1], expected)


def _scale(depth):
    from fuse4d.live import display_range

    return display_range(depth)


def test_cli_live_zarr_output_holds_the_per_pixel_flags(ball, tmp_path, capsys):
    import zarr

    path, _ = ball
    out = tmp_path / "fused.zarr"
    args = ["live", str(path), "--fps", "30", "--window", "3", "--queue", "64", "-o", str(out)]
    assert main([*args, "--json"]) == 0
    capsys.readouterr()
    store = zarr.open_group(str(out), mode="r")
    depth, source, confidence = (store[k][:] for k in ("depth", "source", "confidence"))
    assert depth.shape[0] == 12
    np.testing.assert_array_equal(source == 0, np.isnan(depth))
    assert (confidence[source == 2] > 0).all()


def test_cli_live_reports_the_recordings_rate_and_the_playback_rate(
    tmp_path, ball, capsys, monkeypatch
):
    """`--fps 60` on a 30 Hz recording said "(source 60 fps)" and JSON source_fps 60 (the
    playback rate); a figure that could not be measured was a bare NaN in the JSON."""
    from fuse4d import live
    from fuse4d.cli.cmd_live import _recorded_fps

    _, seq = ball
    path = tmp_path / "ts.npz"
    write_npz(dataclasses.replace(seq, timestamps=5.0 + np.arange(12) / 30.0, fps=None), path)
    real_run_live = live.run_live

    def run_live(*args, **kwargs):  # a rate that could not be measured
        return dataclasses.replace(real_run_live(*args, **kwargs), input_fps=float("nan"))

    monkeypatch.setattr(live, "run_live", run_live)
    args = ["live", str(path), "--window", "3", "--queue", "64", "--frames", "4"]
    assert main([*args, "--fps", "60", "--json"]) == 0

    def refuse(name):
        raise AssertionError(f"not JSON: bare {name}")

    summary = json.loads(capsys.readouterr().out, parse_constant=refuse)
    assert summary["source_fps"] == pytest.approx(30.0)
    assert summary["playback_fps"] == 60.0
    assert summary["input_fps"] is None
    monkeypatch.setattr(live, "run_live", real_run_live)
    assert main(args) == 0  # as fast as possible: the recording's rate, no playback rate
    assert "(source 30 fps)" in capsys.readouterr().out
    assert main([*args, "--fps", "60"]) == 0
    assert "(source 30 fps) (played at 60 fps)" in capsys.readouterr().out
    # a source that says its own rate; one without timestamps played at --fps cannot say it
    assert _recorded_fps(SimpleNamespace(recorded_fps=25.0, fps=60.0), 60.0) == 25.0
    assert _recorded_fps(SimpleNamespace(fps=60.0, output_fps=60.0), 60.0) is None


def _signal_while_finishing(monkeypatch, suffix: str, *gaps: float) -> None:
    """Make the live output's finishing step (the .npz save, the zarr store's close) send
    SIGINT to this process once, then again after each of ``gaps`` seconds."""
    import os
    import signal

    import fuse4d.io
    from fuse4d.io.zarrstore import ZarrWriter

    def signals() -> None:
        os.kill(os.getpid(), signal.SIGINT)
        for gap in gaps:
            time.sleep(gap)
            os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # (a KeyboardInterrupt is raised by now, if one is)

    if suffix == ".npz":
        real_save = fuse4d.io.save_sequence

        def save(*args, **kwargs):
            signals()
            return real_save(*args, **kwargs)

        monkeypatch.setattr(fuse4d.io, "save_sequence", save)
    else:
        real_close = ZarrWriter.close

        def close(self) -> None:
            signals()
            real_close(self)

        monkeypatch.setattr(ZarrWriter, "close", close)


@pytest.mark.parametrize("suffix", [".npz", ".zarr"])
@pytest.mark.parametrize("gaps", [(), (0.002,)], ids=["once", "echoed"])
def test_ctrl_c_while_the_output_is_finished_keeps_it(
    ball, tmp_path, capsys, monkeypatch, suffix, gaps
):
    """All frames fused, the .npz being saved (the zarr store closed): one Ctrl-C (or one
    delivered twice at once, as by `timeout -s INT`) threw the whole run away (exit 130)."""
    path, seq = ball
    out = tmp_path / f"o{suffix}"
    _signal_while_finishing(monkeypatch, suffix, *gaps)
    assert main(["live", str(path), "--window", "3", "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["interrupted"] is True
    assert summary["frames_fused"] == 12
    assert load_sequence(out).depth.shape == seq.depth.shape
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]


@pytest.mark.parametrize("suffix", [".npz", ".zarr"])
def test_a_second_ctrl_c_while_finishing_aborts_and_leaves_nothing(
    ball, tmp_path, capsys, monkeypatch, suffix
):
    path, _ = ball
    out = tmp_path / f"o{suffix}"
    _signal_while_finishing(monkeypatch, suffix, ECHO_S + 0.05)
    assert main(["live", str(path), "--window", "3", "-o", str(out)]) == 130
    assert capsys.readouterr().err.splitlines()[-1] == "fuse4d: interrupted"
    assert list(tmp_path.iterdir()) == []  # no output, no staged temporary


def test_a_recordings_stored_rate_labels_its_frames_whatever_the_playback_rate(tmp_path, ball):
    """fps 30 and no timestamps, played at --fps 10: the frames were stamped 0.1 s apart and
    the output stated fps 10."""
    _, seq = ball
    path = tmp_path / "fps30.npz"
    write_npz(dataclasses.replace(seq, timestamps=None, fps=30.0), path)
    source = RecordingSource(path, realtime=False, fps=10.0, frames="2:6")
    try:
        stamps = [(f.index, f.timestamp) for f in source]
    finally:
        source.close()
    assert stamps == [(k, pytest.approx((k - 2) / 30.0)) for k in range(2, 6)]
    assert (source.fps, source.recorded_fps, source.output_fps) == (10.0, 30.0, 30.0)


def test_the_timestamps_give_the_playback_rate_and_a_pause_does_not_lower_it(tmp_path, ball):
    """Timestamps at 10 Hz beside a stored fps of 30: playback_fps said 30 while it played at
    10. Timestamps alone, 20 Hz with one 20 s pause: the recorded rate was (n - 1) / span,
    0.5 fps here, and the output stated it."""
    _, seq = ball
    path = tmp_path / "ts10fps30.npz"
    write_npz(dataclasses.replace(seq, timestamps=np.arange(12) / 10.0, fps=30.0), path)
    source = RecordingSource(path, realtime=False)
    source.close()
    assert source.fps == pytest.approx(10.0)  # what the timestamps pace it at
    assert source.recorded_fps == source.output_fps == 30.0  # what the recording says
    ts = np.arange(12) / 20.0
    ts[6:] += 20.0
    write_npz(dataclasses.replace(seq, timestamps=ts, fps=None), path := tmp_path / "jump.npz")
    source = RecordingSource(path, realtime=False)
    source.close()
    assert source.fps == source.recorded_fps == source.output_fps == pytest.approx(20.0)


def test_cli_live_reports_the_rate_the_timestamps_play_at(tmp_path, ball, capsys):
    _, seq = ball
    path = tmp_path / "ts10fps30.npz"
    write_npz(dataclasses.replace(seq, timestamps=np.arange(12) / 10.0, fps=30.0), path)
    args = ["live", str(path), "--realtime", "--window", "3", "--frames", "3", "--json"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["playback_fps"] == pytest.approx(10.0)
    assert summary["source_fps"] == 30.0


REAL_DB3 = Path("/work/shared/data/sensor_recordings/rs2591_swdev_5f.db3")


@pytest.mark.skipif(not REAL_DB3.exists(), reason=f"{REAL_DB3} not present")
def test_a_real_recordings_timestamps_give_its_playback_rate():
    """The real RealSense bag stores fps 30 and was recorded at about 19.8 Hz."""
    source = RecordingSource(REAL_DB3, realtime=False)
    source.close()
    assert 19.0 < source.fps < 20.5
    assert source.recorded_fps == 30.0


def test_rates_that_cannot_be_measured_are_null_not_zero(ball, capsys):
    """One frame: "fps": 0.0 and "0.0 fps fused" for rates that were not measured."""
    path, _ = ball
    assert main(["live", str(path), "--window", "3", "--frames", "1", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames_fused"] == 1
    assert summary["fps"] is None
    assert summary["input_fps"] is None
    assert main(["live", str(path), "--window", "3", "--frames", "1"]) == 0
    assert "n/a fps fused, n/a fps in" in capsys.readouterr().out


def test_ctrl_c_while_the_writer_thread_finishes_leaves_no_staged_output(
    ball, tmp_path, monkeypatch
):
    """A KeyboardInterrupt in the wait for the write-behind thread deleted the staged store
    while a write was still under way, and zarr made its folders again."""
    import os
    import signal

    from fuse4d.io import zarrstore

    _, seq = ball
    real_check = zarrstore.check_flags

    def slow_check(*args, **kwargs):  # a write under way: its frame not yet appended
        time.sleep(0.3)
        return real_check(*args, **kwargs)

    monkeypatch.setattr(zarrstore, "check_flags", slow_check)
    timer = threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGINT))
    with (  # noqa: PT012
        pytest.raises(KeyboardInterrupt),
        LiveWriter(tmp_path / "o.zarr", seq.intrinsics, behind=2) as writer,
    ):
        for k in range(2):
            captured = CapturedFrame(k, seq.depth[k], seq.intensity[k], None, 0.0)
            writer(captured, SimpleNamespace(depth=seq.depth[k], source=None))
        timer.start()  # (the default handler: KeyboardInterrupt in the wait)
    time.sleep(0.8)  # what a write still under way would have left by now
    assert list(tmp_path.iterdir()) == []
