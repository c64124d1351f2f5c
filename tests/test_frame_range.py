"""A part of a recording as a recording of its own: ``open_frames(frames=...)``,
``fuse_file(frames=...)``, ``fuse4d run --frames`` and the report of such a run."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import numpy as np
import pytest

from fuse4d import FusionParams
from fuse4d.cli import main
from fuse4d.io import load_sequence, open_frames, write_frame_folder, write_npz
from fuse4d.io.frame_range import FrameRange
from fuse4d.io.resume import MANIFEST_NAME, partial_path, run_reader_options
from fuse4d.run import fuse_file
from test_resume import RUN_ARGS, _child, _contents, _moving_sequence

PART = (4, 13)


@pytest.fixture(scope="module")
def sequence():
    return _moving_sequence()


@pytest.fixture(scope="module")
def recording(sequence, tmp_path_factory) -> Path:
    return write_frame_folder(sequence, tmp_path_factory.mktemp("range") / "in", depth_unit_mm=0.1)


@pytest.fixture(scope="module")
def part_only(sequence, tmp_path_factory) -> Path:
    """A recording that holds only the frames of PART (what users did by hand before)."""
    a, b = PART
    return write_frame_folder(
        sequence.frames(a, b), tmp_path_factory.mktemp("range") / "part", depth_unit_mm=0.1
    )


def test_a_part_reads_as_a_recording_of_its_own(recording):
    a, b = PART
    with open_frames(recording) as whole, open_frames(recording, frames=f"{a}:{b}") as part:
        assert isinstance(part, FrameRange)
        assert (len(part), part.first_frame, whole.first_frame) == (b - a, a, 0)
        assert part.intrinsics == whole.intrinsics
        assert part.depth_unit_mm == whole.depth_unit_mm
        np.testing.assert_array_equal(part.timestamps, whole.timestamps[a:b])
        frames = list(part)
        assert [f.index for f in frames] == list(range(b - a))
        for k, frame in enumerate(frames):
            np.testing.assert_array_equal(frame.depth, whole[a + k].depth)
            np.testing.assert_array_equal(part.read_intensity(k), whole[a + k].intensity)
        np.testing.assert_array_equal(part[-1].depth, whole[b - 1].depth)  # counts from B
        seq = part.read_sequence((2, 5))
        np.testing.assert_array_equal(seq.depth, whole.read_sequence((a + 2, a + 5)).depth)
        with pytest.raises(IndexError):
            part.read_frame(b - a)


def test_a_part_of_an_npz_keeps_its_ground_truth(sequence, tmp_path):
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=8)
    path = write_npz(seq, tmp_path / "ball.npz")
    part = load_sequence(path, frames="2:6")
    with open_frames(path, frames="2:6") as reader:
        seq_part = reader.read_sequence()
    np.testing.assert_array_equal(seq_part.ground_truth.depth, seq.ground_truth.depth[2:6])
    np.testing.assert_array_equal(part.depth, seq_part.depth)


def test_a_range_that_selects_nothing_is_one_clear_error(recording, capsys):
    with pytest.raises(ValueError, match="selects no frame"):
        open_frames(recording, frames="30:40")
    out = recording.parent / "none"
    assert main(["run", str(recording), "-o", str(out), "--frames", "30:40"]) == 2
    err = capsys.readouterr().err
    assert "selects no frame" in err
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("frames", [(1.5, 3), (0, "3"), slice(True, 3)])
def test_a_bound_that_is_not_a_whole_number_is_a_parameter_type_error(frames):
    """(1.5, 3) raised range's bare TypeError ('slice indices must be integers')."""
    from fuse4d.errors import ParameterTypeError
    from fuse4d.io import resolve_frames

    with pytest.raises(ParameterTypeError, match=r"frames: start, stop and step must be whole"):
        resolve_frames(frames, 10)
    assert resolve_frames((np.int64(1), 3), 10) == range(1, 3)


def test_fusing_a_part_equals_fusing_a_recording_of_only_those_frames(
    recording, part_only, tmp_path
):
    params = FusionParams(num_frames=5, spatial_radius=2)
    a, b = PART
    fuse_file(recording, tmp_path / "ranged", fusion=params, frames=(a, b))
    fuse_file(part_only, tmp_path / "cut", fusion=params)
    ranged, cut = load_sequence(tmp_path / "ranged"), load_sequence(tmp_path / "cut")
    assert ranged.num_frames == b - a
    np.testing.assert_array_equal(ranged.depth, cut.depth)
    manifest = json.loads((tmp_path / "ranged" / MANIFEST_NAME).read_text())
    assert manifest["identity"]["reader_options"] == {"frames": f"{a}:{b}"}
    assert run_reader_options(tmp_path / "ranged") == {"frames": f"{a}:{b}"}
    assert run_reader_options(tmp_path / "cut") == {}


def test_fusing_part_of_an_npz(sequence, tmp_path):
    src = write_npz(sequence, tmp_path / "in.npz")
    params = FusionParams(num_frames=3, spatial_radius=2)
    fuse_file(src, tmp_path / "ranged.npz", fusion=params, frames="5:11")
    fuse_file(write_npz(sequence.frames(5, 11), tmp_path / "cut.npz"), tmp_path / "out.npz",
              fusion=params)  # fmt: skip
    ranged, cut = load_sequence(tmp_path / "ranged.npz"), load_sequence(tmp_path / "out.npz")
    np.testing.assert_array_equal(ranged.depth, cut.depth)


def test_run_frames_then_report_reads_the_same_part(recording, tmp_path, capsys):
    """``fuse4d run --frames A:B --report``; then ``fuse4d report IN OUT`` of that folder takes
    the range from the run's manifest; a zarr output needs ``--frames`` given again."""
    a, b = PART
    out, rep = tmp_path / "out", tmp_path / "rep"
    args = ["run", str(recording), "-o", str(out), *RUN_ARGS, "--frames", f"{a}:{b}"]
    assert main([*args, "--report", str(rep), "--no-summary"]) == 0
    assert load_sequence(out).num_frames == b - a
    metrics = json.loads((rep / "metrics.json").read_text())
    assert metrics["frames"] == b - a
    assert metrics["input_frames"] == f"{a}:{b}"
    assert f"frames {a}-{b - 1} of the input" in (rep / "report.html").read_text()
    assert main(["report", str(recording), str(out), "-o", str(tmp_path / "rep2")]) == 0
    again = json.loads((tmp_path / "rep2" / "metrics.json").read_text())
    assert again["metrics"] == metrics["metrics"]
    # the run's own time, from its manifest (the report of a run folder used to say n/a)
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert again["timing"]["fusion_ms_per_frame"] == pytest.approx(
        1000 * manifest["seconds"] / (b - a)
    )
    # and its rate once running, which the report made during the run shows (it said n/a)
    steady = metrics["timing"]["fusion_steady_ms_per_frame"]
    assert steady > 0
    assert manifest["steady_ms_per_frame"] == pytest.approx(steady)
    assert again["timing"]["fusion_steady_ms_per_frame"] == pytest.approx(steady)
    store = tmp_path / "out.zarr"
    zargs = ["run", str(recording), "-o", str(store), *RUN_ARGS, "--frames", f"{a}:{b}"]
    assert main([*zargs, "--no-summary"]) == 0
    capsys.readouterr()
    assert main(["report", str(recording), str(store), "-o", str(tmp_path / "rep3")]) == 2
    assert "the same --frames" in capsys.readouterr().err
    rep4 = tmp_path / "rep4"
    assert (
        main(["report", str(recording), str(store), "-o", str(rep4), "--frames", f"{a}:{b}"]) == 0
    )


def test_a_killed_run_of_a_part_resumes_to_the_uninterrupted_result(recording, tmp_path):
    a, b = PART
    ref, out = tmp_path / "ref", tmp_path / "out"
    args = [*RUN_ARGS, "--frames", f"{a}:{b}"]
    assert main(["run", str(recording), "-o", str(ref), *args]) == 0
    res = _child(3, "after", "SIGKILL", ["run", str(recording), "-o", str(out), *args])
    assert res.returncode == -signal.SIGKILL, res.stderr[-2000:]
    other = ["run", str(recording), "-o", str(out), *RUN_ARGS, "--frames", f"{a + 1}:{b}"]
    assert main([*other, "--resume"]) == 2  # another part: refused
    assert partial_path(out).exists()
    before = json.loads((partial_path(out) / MANIFEST_NAME).read_text())["seconds"]
    assert main(["run", str(recording), "-o", str(out), *args, "--resume"]) == 0
    assert _contents(out) == _contents(ref)
    # the manifest's run time adds up the killed part and the resumed one
    assert json.loads((out / MANIFEST_NAME).read_text())["seconds"] > before > 0


def test_dask_engine_fuses_the_same_part(recording, tmp_path):
    pytest.importorskip("dask")
    import zarr

    a, b = PART
    args = [*RUN_ARGS, "--frames", f"{a}:{b}", "--no-summary"]
    assert main(["run", str(recording), "-o", str(tmp_path / "s"), *args]) == 0
    store = tmp_path / "d.zarr"
    assert main(["run", str(recording), "-o", str(store), "--engine", "dask", *args]) == 0
    root = zarr.open(str(store), mode="r")
    assert root.attrs["fuse4d"]["reader_options"] == {"frames": f"{a}:{b}"}  # checked on resume
    dask_depth = np.asarray(root["depth"][:])
    stream = load_sequence(tmp_path / "s").depth  # a folder: 0.1 mm PNG steps
    assert dask_depth.shape == stream.shape == (b - a, *stream.shape[1:])
    np.testing.assert_allclose(np.where(dask_depth > 0, dask_depth, np.nan), stream, atol=0.051)


def test_dask_run_writes_its_report_and_report_reads_a_dask_store(recording, tmp_path, capsys):
    """``--report`` with ``--engine dask`` used to be ignored without a word; the report of a
    dask output (fused depth and flags, no intensity) could not be read at all."""
    pytest.importorskip("dask")
    a, b = PART
    store, rep = tmp_path / "d.zarr", tmp_path / "rep"
    args = [*RUN_ARGS, "--frames", f"{a}:{b}", "--no-summary", "--engine", "dask"]
    assert main(["run", str(recording), "-o", str(store), *args, "--report", str(rep)]) == 0
    metrics = json.loads((rep / "metrics.json").read_text())
    assert metrics["frames"] == b - a
    assert metrics["input_frames"] == f"{a}:{b}"
    assert metrics["params"]["spatial_radius"] == 2
    assert metrics["fusion"]["support_fraction"] > 0.5  # the store's support maps
    assert metrics["fusion"]["rejected_fraction"] == 0.0  # its source codes (else None)
    rep2 = tmp_path / "rep2"
    report = ["report", str(recording), str(store), "-o", str(rep2), "--frames", f"{a}:{b}"]
    assert main(report) == 0
    again = json.loads((rep2 / "metrics.json").read_text())
    assert again["metrics"] == metrics["metrics"]
    assert again["params"]["spatial_radius"] == 2  # from the store's metadata
    capsys.readouterr()
    assert main(["info", str(store)]) == 2  # not a recording: says what it is
    assert "a fused output of `fuse4d run --engine dask`" in capsys.readouterr().err
    several = ["run", str(recording), str(recording), "-o", str(tmp_path / "many"), *args]
    assert main([*several, "--report", str(tmp_path / "rep3")]) == 2  # before any work
    assert "--report writes the report of one input" in capsys.readouterr().err
    assert not (tmp_path / "many").exists()
