"""The error contract: user errors → one line, exit 2; bugs → crash report, exit 70."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest

import fuse4d
from fuse4d import (
    Fuse4dError,
    InputFileError,
    InputNotFoundError,
    OutputExistsError,
    OutputWriteError,
    ParameterError,
    Sequence,
    ShapeError,
)
from fuse4d.cli import EXIT_BUG, EXIT_INTERRUPTED, EXIT_USAGE, main
from fuse4d.io import load_sequence, resolve_frames, write_npz


@pytest.fixture
def npz_path(tmp_path, small_sequence: Sequence) -> Path:
    return write_npz(small_sequence, tmp_path / "s.npz")


def test_missing_input_is_a_file_not_found_error(tmp_path):
    with pytest.raises(FileNotFoundError) as info:
        load_sequence(tmp_path / "nope.npz")
    err = info.value
    assert isinstance(err, InputNotFoundError)
    assert isinstance(err, InputFileError)
    assert isinstance(err, ValueError)  # old callers catching ValueError still work
    assert str(err).startswith(str(tmp_path / "nope.npz"))
    assert isinstance(InputFileError("x", "corrupt"), Fuse4dError)
    assert not isinstance(InputFileError("x", "corrupt"), OSError)


@pytest.mark.parametrize(
    "err",
    [
        InputFileError("a/b.png", "file not found", frame=3),
        InputFileError("a/b.png", "corrupt", frame=3),
        ShapeError("depth", ("T", "H", "W"), (2, 3)),
        OutputExistsError("out.npz"),
        OutputWriteError("out.npz", OSError(28, "No space left on device")),
        ParameterError("bad"),
    ],
)
def test_errors_pickle_and_keep_their_message(err):
    copy = pickle.loads(pickle.dumps(err))
    assert type(copy) is type(err)
    assert str(copy) == str(err)
    assert isinstance(copy, Fuse4dError)


def test_write_error_says_what_to_do():
    err = OutputWriteError("out/", OSError(28, "No space left on device"))
    assert "No space left on device" in str(err)
    assert "free some disk space" in str(err)


def test_parameter_errors_are_fuse4d_errors():
    with pytest.raises(ParameterError, match="selects no frame"):
        resolve_frames("5:9", 3)
    with pytest.raises(ParameterError, match="'A:B'"):
        resolve_frames("x", 3)


def _one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    return lines[0]


def test_cli_user_error_is_one_line_exit_2(tmp_path, capsys):
    assert main(["info", str(tmp_path / "missing")]) == EXIT_USAGE
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith("fuse4d: error: ")
    assert "missing" in line
    assert "Traceback" not in line


def test_cli_bad_intrinsics_option_is_a_user_error(npz_path, tmp_path, capsys):
    folder = tmp_path / "seq"
    fuse4d.io.save_sequence(load_sequence(npz_path), folder, depth_unit_mm=0.01)
    assert main(["info", str(folder), "--intrinsics", "1,2,3"]) == EXIT_USAGE
    assert "intrinsics" in _one_error_line(capsys.readouterr().err)
    assert main(["info", str(folder), "--intrinsics", "-1,2,3,4"]) == EXIT_USAGE
    assert "fx must be > 0" in _one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize(
    ("command", "value", "hint"),
    [
        ("run", "12", "':12' is the first 12 frames, '12:13' frame 12 alone"),
        ("convert", "-3", "'-3:' is the last 3 frames, '-3:-2' frame -3 alone"),
    ],
)
def test_cli_bare_frame_number_is_refused_with_both_readings(
    npz_path, tmp_path, capsys, command, value, hint
):
    """bench / live / synth / demo take --frames as a count; run, convert, metrics and report
    take a range, where a bare number would silently select one frame."""
    out = tmp_path / "out.npz"
    args = [command, str(npz_path)] if command == "run" else [command, str(npz_path), str(out)]
    if command == "run":
        args += ["-o", str(out)]
    assert main([*args, "--frames", value]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert hint in " ".join(err.split())
    assert "Traceback" not in err
    assert not out.exists()
    assert main([*args, "--frames", "1:3"]) == 0  # the range still works


def _inject_bug(monkeypatch, exc: BaseException) -> None:
    import fuse4d.io  # the CLI imports its readers when a command runs (fast start-up)

    def broken(*args, **kwargs):
        raise exc

    monkeypatch.setattr(fuse4d.io, "open_frames", broken)


def test_ctrl_c_turned_into_another_error_by_numba_is_an_interrupt(
    npz_path, monkeypatch, tmp_path, capsys
):
    """A Ctrl-C raised inside numba's compiler (a ctypes callback) surfaced as "RuntimeError:
    no compiled object yet for <Library ...>": exit 70 and a crash report for an interrupt."""
    import fuse4d.cli
    import fuse4d.io

    monkeypatch.setenv("FUSE4D_CRASH_DIR", str(tmp_path / "crashes"))

    def interrupted_while_compiling(*args, **kwargs):
        fuse4d.cli._INTERRUPTED.set()  # what the console script's SIGINT handler does
        raise RuntimeError("no compiled object yet for <Library '_roughness_row'>")

    monkeypatch.setattr(fuse4d.io, "open_frames", interrupted_while_compiling)
    assert main(["info", str(npz_path)]) == EXIT_INTERRUPTED
    assert capsys.readouterr().err.strip() == "fuse4d: interrupted"
    assert not (tmp_path / "crashes").exists()
    assert not fuse4d.cli._INTERRUPTED.is_set() or main(["--version"]) == 0  # cleared per run
    assert not fuse4d.cli._INTERRUPTED.is_set()


@pytest.mark.parametrize("exc", [KeyError("oops"), ValueError("shapes (3,) (4,)"), TypeError("x")])
def test_cli_internal_bug_gives_crash_report_exit_70(npz_path, monkeypatch, tmp_path, capsys, exc):
    monkeypatch.setenv("FUSE4D_CRASH_DIR", str(tmp_path / "crashes"))
    _inject_bug(monkeypatch, exc)
    assert main(["info", str(npz_path)]) == EXIT_BUG
    line = _one_error_line(capsys.readouterr().err)
    assert "internal error" in line
    assert "bug in fuse4d" in line
    assert type(exc).__name__ in line
    reports = list((tmp_path / "crashes").glob("crash-*.txt"))
    assert len(reports) == 1
    assert str(reports[0]) in line
    text = reports[0].read_text()
    assert "Traceback (most recent call last)" in text
    assert f"fuse4d: {fuse4d.__version__}" in text
    assert f"command: fuse4d info {npz_path}" in text
    assert "platform: " in text
    assert not list((tmp_path / "crashes").glob(".crash-*"))  # no temporary left


def test_cli_debug_shows_the_traceback(npz_path, monkeypatch):
    with pytest.raises(InputFileError):
        main(["--debug", "info", str(npz_path.with_name("missing.npz"))])
    _inject_bug(monkeypatch, KeyError("oops"))
    with pytest.raises(KeyError):
        main(["--debug", "info", str(npz_path)])
    monkeypatch.setenv("FUSE4D_DEBUG", "1")
    with pytest.raises(KeyError):
        main(["info", str(npz_path)])


def test_cli_debug_flag_does_not_leak_between_calls(npz_path, monkeypatch, capsys):
    _inject_bug(monkeypatch, KeyError("oops"))
    with pytest.raises(KeyError):
        main(["--debug", "info", str(npz_path)])
    assert main(["info", str(npz_path)]) == EXIT_BUG


def test_cli_keyboard_interrupt_exits_130(npz_path, monkeypatch, capsys):
    _inject_bug(monkeypatch, KeyboardInterrupt())
    assert main(["info", str(npz_path)]) == EXIT_INTERRUPTED
    assert "interrupted" in capsys.readouterr().err


def test_cli_unwritable_crash_folder_still_one_line(npz_path, monkeypatch, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("FUSE4D_CRASH_DIR", str(blocker / "sub"))
    _inject_bug(monkeypatch, KeyError("oops"))
    assert main(["info", str(npz_path)]) == EXIT_BUG
    assert "no crash report could be written" in _one_error_line(capsys.readouterr().err)


def test_no_broad_value_error_catch_in_cli():
    """The CLI must not turn ValueError/KeyError from whole commands into user errors."""
    import inspect

    from fuse4d import cli

    source = inspect.getsource(cli)
    assert "KeyError" not in source.split("def main", 1)[1].split("def _debug", 1)[0]
    assert "except (CliError, ValueError" not in source


def test_run_wrong_output_kind_is_a_user_error(npz_path, tmp_path, capsys):
    assert main(["run", str(npz_path), "-o", str(tmp_path / "out_folder")]) == EXIT_USAGE
    assert "give an output ending in .npz" in _one_error_line(capsys.readouterr().err)


def test_folder_writer_rejects_bad_unit_with_parameter_error(tmp_path, small_intrinsics):
    from fuse4d.io import FrameFolderWriter

    with pytest.raises(ParameterError):
        FrameFolderWriter(tmp_path / "x", small_intrinsics, depth_unit_mm=float("nan"))


def _console_script(*args: str):
    """``python -m fuse4d ARGS`` in a fresh process, as the console script runs (warnings go
    through the CLI's one-line printer only there): the CompletedProcess."""
    import os
    import subprocess
    import sys

    src = Path(__file__).resolve().parents[1] / "src"
    env = {**os.environ, "PYTHONPATH": str(src), "COLUMNS": "200"}
    env.pop("FUSE4D_DEBUG", None)
    return subprocess.run(
        [sys.executable, "-m", "fuse4d", *args],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )


def test_console_script_warnings_are_one_line(npz_path, tmp_path):
    """Run as a command, a warning (here: the output's depth unit is coarse for the data)
    prints as ``fuse4d: warning: ...``, not Python's file, line, category and source line."""
    out = tmp_path / "coarse"
    res = _console_script("convert", str(npz_path), str(out), "--out-depth-unit-mm", "5")
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if "coarse" in ln]
    assert lines
    assert all(ln.startswith("fuse4d: warning: ") for ln in lines), res.stderr
    assert "UserWarning" not in res.stderr


def test_console_script_prints_each_warning_once(tmp_path):
    """A recording with few valid pixels warned for the input and again for the filtered
    sequence made from it: the same line twice."""
    import numpy as np

    from fuse4d.synthetic import make_scene

    seq = make_scene("ball", small=True, num_frames=3, rng=0)
    with pytest.warns(UserWarning, match="only 0.0 %"):
        empty = seq.with_depth(np.full_like(seq.depth, np.nan))
    write_npz(empty, tmp_path / "empty.npz")
    res = _console_script(
        "baseline", "guided", str(tmp_path / "empty.npz"), "-o", str(tmp_path / "out.npz")
    )
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("only 0.0 % of depth pixels are valid") == 1
    assert f"fuse4d: warning: {tmp_path / 'empty.npz'}: only 0.0 %" in res.stderr  # names it


def test_the_same_signal_twice_at_once_is_one_interrupt():
    """GNU `timeout -s INT` sends SIGINT to the process, then to its group, a few ms apart:
    the second KeyboardInterrupt cut into the clean-up of the first (staged outputs)."""
    import signal
    import time

    import fuse4d.cli
    from fuse4d import _signals

    _signals.reset()
    with pytest.raises(KeyboardInterrupt):
        fuse4d.cli._terminate(signal.SIGINT, None)
    assert _signals.INTERRUPTED.is_set()
    try:
        fuse4d.cli._terminate(signal.SIGINT, None)  # the echo: ignored
        fuse4d.cli._terminate(signal.SIGINT, None)
    except KeyboardInterrupt:
        pytest.fail("the same signal delivered twice at once was a second interrupt")
    time.sleep(_signals.ECHO_S + 0.05)
    with pytest.raises(KeyboardInterrupt):  # a second Ctrl-C of a person
        fuse4d.cli._terminate(signal.SIGINT, None)
    with pytest.raises(KeyboardInterrupt):  # another signal at once is not an echo
        fuse4d.cli._terminate(signal.SIGTERM, None)
    _signals.reset()


def test_ctrl_c_raised_where_python_drops_it_still_interrupts(npz_path, monkeypatch, capsys):
    """The console script's SIGINT handler raised KeyboardInterrupt inside a weakref callback
    (or a __del__): Python printed "Exception ignored in ..." with a traceback and the command
    finished with exit 0."""
    import os
    import signal

    import fuse4d.cli
    import fuse4d.io

    real_open_frames = fuse4d.io.open_frames

    class _Dropped:
        def __del__(self) -> None:
            os.kill(os.getpid(), signal.SIGINT)  # the handler runs in here
            for _ in range(1000):
                pass

    def open_frames(*args, **kwargs):
        _Dropped()
        return real_open_frames(*args, **kwargs)

    monkeypatch.setattr(fuse4d.io, "open_frames", open_frames)
    previous = signal.signal(signal.SIGINT, fuse4d.cli._terminate)  # the console script's
    try:
        assert main(["info", str(npz_path)]) == EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGINT, previous)
    assert capsys.readouterr().err == "fuse4d: interrupted\n"  # one line, no traceback
