"""The benchmark scripts' options: bad values are refused in one line (no traceback), and the
options do what their help says.

(The scripts are loaded by path with ``conftest.load_benchmark``.)
"""

from __future__ import annotations

import sys

import pytest

from conftest import load_benchmark


def _load(name: str):
    return load_benchmark(name)


def _refused(main, argv, capsys, match: str) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert match in err


@pytest.mark.parametrize(
    ("script", "argv", "match"),
    [
        ("ab_revisions", ["HEAD", "--pairs", "0", "--ball"], "--pairs must be >= 1"),
        ("background_io", ["--rounds", "0"], "--rounds must be >= 1"),
        ("bench_readers", ["--kind", "bogus"], "invalid choice: 'bogus'"),
        ("bench_readers", ["--short", "0"], "--short must be >= 1"),
        ("scale", ["--workers", "0"], "--workers must be >= 1"),
        ("scale", ["--workers", "1,x"], "--workers must be comma-separated integers"),
        ("scale", ["--size", "1000"], "--size must be 1..600"),
        ("scale", ["--tracks", "composed,exact"], "give --repeats R"),
        ("bench_baselines", ["--frames", "0"], "--frames must be >= 2"),
        ("input_ratio", ["--frames", "1"], "--frames must be >= 2"),
        ("memory_scaling", ["--frames", "60", "0"], "--frames must be >= 1 each"),
    ],
)
def test_bad_options_are_refused_in_one_line(script, argv, match, capsys):
    """These ended in raw tracebacks (StatisticsError, IndexError, dask's or fuse4d's
    ValueError / ParameterError), or, for --kind bogus, were accepted."""
    if script == "bench_readers":
        pytest.importorskip("rosbags")
    _refused(_load(script).main, argv, capsys, match)


def test_real_data_refuses_a_folder_without_the_recordings(tmp_path, capsys):
    """A wrong --data printed '{"preset": "fast", "flow": "dis"}' and exited 0."""
    _refused(_load("real_data").main, ["--data", str(tmp_path)], capsys, str(tmp_path))


def test_scale_size_crops_the_600_px_ball_and_labels_the_frames(tmp_path):
    """--size cropped the 150x150 ball, skipped the crop silently when it did not fit and
    labelled the report with the asked size ('1000x1000' for 150x150 frames)."""
    from fuse4d.io import load_sequence

    scale = _load("scale")
    assert scale._make_recording(tmp_path / "a.npz", 2, False, 300) == (300, 300)
    seq = load_sequence(tmp_path / "a.npz")
    assert seq.depth.shape == (2, 300, 300)
    assert seq.intrinsics.cx == pytest.approx(scale_cx(600) - 150)  # centre of the 600 px ball
    assert scale._make_recording(tmp_path / "b.npz", 2, False, None) == (150, 150)
    assert scale._make_recording(tmp_path / "c.npz", 2, True, 600) == (600, 600)
    with pytest.raises(ValueError, match="--size 601 exceeds the 600x600 frames"):
        scale._make_recording(tmp_path / "d.npz", 2, False, 601)


def scale_cx(width: int) -> float:
    """cx of the falling ball rendered ``width`` px wide."""
    from fuse4d.synthetic import make_falling_ball

    return make_falling_ball(small=width == 150, num_frames=2, rng=0).intrinsics.cx


def test_scale_one_repeat_alternates(monkeypatch, capsys):
    """--repeats 1 was ignored (alternation ran only for R > 1), so --tracks composed,exact
    silently dropped exact."""
    scale = _load("scale")
    calls = []

    def fake_cluster(n, job):
        return 1.0, [100.0], 1.0, 0

    def fake_alternating(rec, folder, args, fusions):
        calls.append((args.repeats, [f.tracks for f in fusions]))
        return {}

    monkeypatch.setattr(scale, "_with_cluster", fake_cluster)
    monkeypatch.setattr(scale, "_alternating", fake_alternating)
    argv = ["--frames", "2", "--workers", "1", "--no-length-check", "--json"]
    assert scale.main([*argv, "--tracks", "composed,exact", "--repeats", "1"]) == 0
    assert calls == [(1, ["composed", "exact"])]
    assert '"size": "150x150"' in capsys.readouterr().out
    assert scale.main(argv) == 0  # default: no alternation
    assert len(calls) == 1


def test_ab_revisions_resolves_a_relative_input_and_folder(tmp_path, monkeypatch):
    """The child process runs in the temp folder: a relative --input (or BASE folder) was
    looked up there and failed."""
    ab = _load("ab_revisions")
    (tmp_path / "rec").mkdir()
    (tmp_path / "tree" / "src" / "fuse4d").mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    seen = []

    def fake_time_side(src, args, rec):
        seen.append((src, rec))
        return 10.0, {}

    monkeypatch.setattr(ab, "time_side", fake_time_side)
    ab.main(["tree", "--new", "tree", "--input", "rec", "--pairs", "1", "--json"])
    assert seen
    for src, rec in seen:
        assert src == tmp_path / "tree" / "src"
        assert rec == str(tmp_path / "rec")


def test_bench_readers_short_and_long_of_one_length(tmp_path, capsys):
    """--short 10 --long 10 named both bags small10: the rosbags writer refused the second."""
    pytest.importorskip("rosbags")
    readers = _load("bench_readers")
    readers.main(["--frames", "2", "--short", "3", "--long", "3", "--tmp", str(tmp_path)])
    out = capsys.readouterr().out
    assert out.count("     3 frames") == 2


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
