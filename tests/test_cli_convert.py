"""``fuse4d convert`` / ``fuse4d.io.convert_recording``: any input, or a part of it, in another
layout, with everything the output layout can hold carried over (the camera kind included)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from fuse4d import Intrinsics, Sequence
from fuse4d.cli import main
from fuse4d.io import convert_recording, load_sequence, open_frames, write_frame_folder, write_npz
from fuse4d.sequence import GroundTruth

SENSORS = Path(__file__).resolve().parents[2] / "shared" / "data" / "sensor_recordings"


def _sequence(frames: int = 7) -> Sequence:
    rng = np.random.default_rng(5)
    h, w = 20, 28
    depth = (1500.0 + rng.normal(0, 3, (frames, h, w))).astype(np.float32)
    depth[:, 3:6, 4:9] = np.nan
    intensity = rng.random((frames, h, w)).astype(np.float32)
    mask = np.zeros((frames, h, w), bool)
    mask[:, 8:12, 10:20] = True
    return Sequence(
        depth,
        intensity,
        Intrinsics(40.0, 41.0, 13.5, 9.5, width=w, height=h),
        timestamps=np.arange(frames) / 15.0,
        fps=15.0,
        ground_truth=GroundTruth(mask=mask),
        sensor="tof",
    )


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return write_frame_folder(
        _sequence(), tmp_path_factory.mktemp("conv") / "in", depth_unit_mm=0.1
    )


@pytest.mark.parametrize(
    ("frames", "says"), [("2:6", "4 frames (frames 2:6 of"), ("4:99", "3 frames (frames 4:7 of"),
                         (":2", "2 frames (frames 0:2 of"), ("-3:", "3 frames (frames -3: of")],
)  # fmt: skip
def test_convert_names_the_part_it_wrote_without_reading_the_input_again(
    folder, tmp_path, capsys, monkeypatch, frames, says
):
    from fuse4d.io import api

    opened = []
    real = api.open_frames

    def counting(path, *args, **kwargs):
        opened.append(str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(api, "open_frames", counting)
    import fuse4d.io

    monkeypatch.setattr(fuse4d.io, "open_frames", counting)
    assert main(["convert", str(folder), str(tmp_path / "p.npz"), "--frames", frames]) == 0
    assert says in capsys.readouterr().out.replace("\n", "")
    assert opened.count(str(folder)) == 1  # a bag's reader passes over all its messages


@pytest.mark.parametrize("suffix", [".npz", "", ".zarr", ".mkv"])
def test_a_part_converts_losslessly_to_every_layout(folder, tmp_path, suffix, capsys):
    if suffix == ".mkv" and importlib.util.find_spec("av") is None:
        pytest.skip("PyAV not installed (the sensors extra)")
    out = tmp_path / f"part{suffix}"
    if suffix in (".zarr", ".mkv"):  # the masks are dropped, with a warning (was silent)
        with pytest.warns(UserWarning, match=rf"{suffix} format does not store ground-truth mask;"):
            assert main(["convert", str(folder), str(out), "--frames", "2:6"]) == 0
    else:
        assert main(["convert", str(folder), str(out), "--frames", "2:6"]) == 0
    said = capsys.readouterr().out.replace("\n", "")
    assert "4 frames (frames 2:6 of" in said
    assert said.endswith(", 28x20 px (WxH)")  # was "20x28", H x W, unlike fuse4d info
    want = load_sequence(folder, frames="2:6")
    got = load_sequence(out)
    np.testing.assert_array_equal(got.depth, want.depth)  # 0.1 mm units kept: exact
    atol = 1e-4 if suffix == ".mkv" else 0.0  # 16-bit intensity in a depth video
    np.testing.assert_allclose(got.intensity, want.intensity, atol=atol)
    np.testing.assert_allclose(got.timestamps, want.timestamps, atol=1e-3)
    assert got.intrinsics == want.intrinsics
    assert got.fps == want.fps
    with open_frames(out) as reader:
        assert reader.sensor == "tof"  # A36 still applies to the converted recording
    if suffix in (".npz", ""):
        np.testing.assert_array_equal(got.ground_truth.mask, want.ground_truth.mask)


def test_npz_ground_truth_survives_conversion_to_npz(tmp_path):
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=6)
    src = write_npz(seq, tmp_path / "ball.npz")
    out = convert_recording(src, tmp_path / "cut.npz", frames=(1, 4))
    got = load_sequence(out)
    np.testing.assert_array_equal(got.ground_truth.depth, seq.ground_truth.depth[1:4])
    np.testing.assert_array_equal(got.depth, seq.depth[1:4])


@pytest.mark.parametrize(
    ("name", "dropped"),
    [("f", "depth, flow, 16 gt_* values"), ("o.zarr", "depth, mask, flow, 16 gt_* values"),
     ("o.mkv", "depth, mask, flow, 16 gt_* values")],
)  # fmt: skip
def test_npz_ground_truth_dropped_by_a_streamed_layout_is_named(tmp_path, name, dropped):
    """Ground truth went missing silently in .zarr / .mkv outputs (and, but for the masks, in
    a folder output, which convert writes frame by frame, not by write_frame_folder)."""
    from fuse4d.synthetic import make_falling_ball

    if name.endswith(".mkv") and importlib.util.find_spec("av") is None:
        pytest.skip("PyAV not installed (the sensors extra)")
    src = write_npz(make_falling_ball(small=True, num_frames=3), tmp_path / "ball.npz")
    out = tmp_path / name
    unit = None if name.endswith(".zarr") else 0.1
    with pytest.warns(UserWarning, match="ground-truth") as rec:
        convert_recording(src, out, out_depth_unit_mm=unit)
    said = [str(w.message) for w in rec if "ground-truth" in str(w.message)]
    want = f"{out}: {_LAYOUT[out.suffix]} format does not store ground-truth {dropped}; use .npz"
    assert said == [f"{want} to keep them"]
    if name == "f":  # the masks are kept
        masks = load_sequence(src).ground_truth.mask
        np.testing.assert_array_equal(load_sequence(out).ground_truth.mask, masks)


_LAYOUT = {"": "the frame-folder", ".zarr": "the .zarr", ".mkv": "the .mkv"}


@pytest.mark.parametrize("suffix", [".npz", ".zarr"])
def test_an_output_depth_unit_for_a_float_depth_output_is_refused(tmp_path, capsys, suffix):
    """``--out-depth-unit-mm`` was silently ignored for an output that stores float depth."""
    src = write_npz(_sequence(), tmp_path / "s.npz")
    out = tmp_path / f"o{suffix}"
    assert main(["convert", str(src), str(out), "--out-depth-unit-mm", "0.5"]) == 2
    err = capsys.readouterr().err
    assert f"{out}: out_depth_unit_mm applies to frame-folder and .mkv outputs" in err
    assert "Traceback" not in err
    assert not out.exists()


def test_an_output_inside_a_file_says_the_file_is_no_folder(tmp_path, capsys):
    src = write_npz(_sequence(), tmp_path / "s.npz")
    (tmp_path / "mk.py").write_text("x = 1\n")
    assert main(["convert", str(src), str(tmp_path / "mk.py" / "x.npz")]) == 2
    assert f"{tmp_path / 'mk.py'} is not a folder" in capsys.readouterr().err


def test_float_depth_to_a_folder_uses_the_unit_asked_for(tmp_path):
    seq = _sequence()
    src = write_npz(seq, tmp_path / "s.npz")
    out = tmp_path / "f"
    assert main(["convert", str(src), str(out), "--out-depth-unit-mm", "0.05"]) == 0
    with open_frames(out) as reader:
        assert reader.depth_unit_mm == 0.05
    np.testing.assert_allclose(load_sequence(out).depth, seq.depth, atol=0.025)


def test_bad_requests_are_one_clear_error_and_write_nothing(folder, tmp_path, capsys):
    out = tmp_path / "o.npz"
    assert main(["convert", str(folder), str(out), "--frames", "9:12"]) == 2
    err = capsys.readouterr().err
    assert "selects no frame" in err
    assert "Traceback" not in err
    assert not out.exists()
    assert main(["convert", str(folder), str(folder)]) == 2  # never onto the input
    out.write_bytes(b"keep")
    assert main(["convert", str(folder), str(out)]) == 2  # exists: --force needed
    assert out.read_bytes() == b"keep"
    assert main(["convert", str(folder), str(out), "--force"]) == 0


def test_a_realsense_bag_converts_to_a_folder_that_reads_the_same(tmp_path):
    bag = SENSORS / "rs2551_swdev_5f.bag"
    if not bag.exists():
        pytest.skip(f"{bag} not found (../shared/data absent)")
    out = tmp_path / "bag_folder"
    assert main(["convert", str(bag), str(out)]) == 0
    want, got = load_sequence(bag), load_sequence(out)
    np.testing.assert_array_equal(got.depth, want.depth)
    np.testing.assert_allclose(got.intensity, want.intensity, atol=1 / 255)
    with open_frames(bag) as a, open_frames(out) as b:
        assert a.depth_unit_mm == b.depth_unit_mm
        assert a.sensor == b.sensor


def test_run_report_lists_the_parameters_as_run(folder, tmp_path):
    """The folder says its camera is ToF: flying_pixels "auto" runs as "on" (A36), and the
    report of the run lists that, with either engine (it used to list "auto")."""
    import json

    rep = tmp_path / "rep"
    args = ["run", str(folder), "-o", str(tmp_path / "out"), "--window", "3", "--no-summary"]
    assert main([*args, "--report", str(rep)]) == 0
    assert json.loads((rep / "metrics.json").read_text())["params"]["flying_pixels"] == "on"
    pytest.importorskip("dask")
    rep2 = tmp_path / "rep2"
    dask = ["run", str(folder), "-o", str(tmp_path / "o.zarr"), "--window", "3", "--engine", "dask"]
    assert main([*dask, "--report", str(rep2)]) == 0
    assert json.loads((rep2 / "metrics.json").read_text())["params"]["flying_pixels"] == "on"


@pytest.mark.parametrize("unit", ["0", "-1", "nan"])
def test_an_output_depth_unit_that_is_no_unit_is_refused(folder, tmp_path, capsys, unit):
    """``--out-depth-unit-mm 0`` silently meant the input's own unit."""
    out = tmp_path / "out"
    assert main(["convert", str(folder), str(out), "--out-depth-unit-mm", unit]) == 2
    assert "out_depth_unit_mm must be > 0 mm" in capsys.readouterr().err
    assert not out.exists()


def _fused_npz(path: Path) -> Path:
    """An .npz as ``fuse4d run`` writes it: the sequence plus per-pixel and other arrays."""
    seq = _sequence(5)
    t, h, w = seq.depth.shape
    codes = (np.arange(t * h * w) % 7).astype(np.uint8).reshape(t, h, w)
    extra = {
        "source": codes,
        "confidence": (codes / 7.0).astype(np.float32),
        "support": (codes % 3).astype(np.uint8),
        "fuse4d_params": np.str_('{"fusion": {}}'),
    }
    return write_npz(seq, path, extra=extra)


def test_a_fused_npz_keeps_its_arrays_in_an_npz_part(tmp_path):
    """npz -> npz dropped the fused arrays (source, confidence, support) without a word."""
    from fuse4d.io import read_npz_extra

    src = _fused_npz(tmp_path / "fused.npz")
    out = tmp_path / "part.npz"
    assert main(["convert", str(src), str(out), "--frames", "1:3"]) == 0
    want, got = read_npz_extra(src, frames="1:3"), read_npz_extra(out)
    assert sorted(got) == ["confidence", "fuse4d_params", "source", "support"]
    for key, value in want.items():
        np.testing.assert_array_equal(got[key], value, strict=True)
    assert got["source"].shape[0] == 2


def test_arrays_a_conversion_drops_are_named(tmp_path):
    """To another layout (or from a fused .zarr) the fused arrays were dropped silently."""
    from fuse4d.io import ZarrWriter

    src = _fused_npz(tmp_path / "fused.npz")
    out = tmp_path / "o.zarr"
    with pytest.warns(UserWarning, match="not carried over|ground-truth mask") as rec:
        convert_recording(src, out)
    said = [str(w.message) for w in rec]
    assert (
        f"{out}: the arrays source, confidence, support, fuse4d_params of {src} are not "
        "carried over (only an .npz converted to an .npz keeps them)" in said
    )
    seq = _sequence(3)
    fused = tmp_path / "fused.zarr"
    with ZarrWriter(fused, seq.intrinsics) as writer:
        for d, i in zip(seq.depth, seq.intensity, strict=True):
            codes = np.ones(d.shape, np.uint8)
            writer.write(d, i, source=codes, confidence=np.full(d.shape, 0.5, np.float32))
    out = tmp_path / "z.npz"
    with pytest.warns(UserWarning, match=r"the arrays source, confidence of .*fused\.zarr are"):
        convert_recording(fused, out, frames="1:3")
    with np.load(out) as written:
        assert {"depth", "intensity"} <= set(written.files)
        assert not {"source", "confidence"} & set(written.files)


def test_export_ply_refuses_a_frame_without_valid_depth(tmp_path, capsys):
    """It wrote a 0-vertex PLY (which Open3D refuses to read) and said 'wrote 0 points'."""
    seq = _sequence(3)
    depth = seq.depth.copy()
    depth[1] = np.nan
    src = write_npz(seq.with_depth(depth), tmp_path / "s.npz")
    out = tmp_path / "f.ply"
    assert main(["export-ply", str(src), "--frame", "1", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == f"fuse4d: error: {src} (frame 1): no valid depth, no point to export\n"
    assert not out.exists()
    assert main(["export-ply", str(src), "--frame", "-1", "-o", str(out)]) == 0
    assert out.exists()
