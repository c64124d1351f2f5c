"""CLI commands ``fuse4d info`` and ``fuse4d export-ply`` (through fuse4d.cli.main)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fuse4d import Sequence
from fuse4d.cli import main
from fuse4d.io import read_ply, write_npz
from fuse4d.sequence import GroundTruth
from test_io import _write_tum


@pytest.fixture
def npz_path(tmp_path, small_sequence):
    depth = small_sequence.depth.copy()
    depth[:, :2] = np.nan  # 2 of 24 rows invalid
    seq = Sequence(
        depth,
        small_sequence.intensity,
        small_sequence.intrinsics,
        fps=30.0,
        ground_truth=GroundTruth(depth=small_sequence.depth),
    )
    return write_npz(seq, tmp_path / "s.npz")


def test_info_text(npz_path, small_sequence, capsys):
    assert main(["info", str(npz_path)]) == 0
    out = capsys.readouterr().out
    lines = dict(line.split(":", 1) for line in out.splitlines())
    assert lines["format"].strip() == "npz"
    assert lines["frames"].strip() == "4"
    assert lines["size"].strip() == "32 x 24 px (W x H)"
    assert lines["intrinsics"].strip() == "fx=80 fy=80 cx=15.5 cy=11.5 px"
    assert lines["valid pixels"].strip() == "91.7 %"
    # the two first rows never have depth: outside the field of view (A38)
    covers = lines["depth covers"].strip()
    assert covers.startswith("91.7 % of the image (rows 2-23, columns 0-31")
    assert covers.endswith("100.0 % of its pixels valid")
    assert lines["fps"].strip() == "30"
    assert lines["ground truth"].strip() == "depth"
    lo = np.nanmin(small_sequence.depth[:, 2:])
    assert lines["depth range"].strip().startswith(f"{lo:.1f} .. ")


def test_info_json(npz_path, capsys):
    assert main(["info", str(npz_path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == 4
    assert info["width"] == 32
    assert info["height"] == 24
    assert info["valid_fraction"] == pytest.approx(22 / 24)
    assert info["intrinsics"] == {"fx": 80.0, "fy": 80.0, "cx": 15.5, "cy": 11.5}
    assert info["ground_truth"] == ["depth"]
    assert info["format"] == "npz"


def test_info_samples_long_recordings(tmp_path, small_intrinsics, capsys):
    """Over 10 frames, info reads 10 evenly spaced ones (says so); --all-frames reads all."""
    from fuse4d.cli.cmd_io import stats_frames

    assert stats_frames(4, 10) == [0, 1, 2, 3]
    assert stats_frames(100, 10) == [0, 11, 22, 33, 44, 55, 66, 77, 88, 99]
    assert stats_frames(100, None) == list(range(100))
    h, w = small_intrinsics.height, small_intrinsics.width
    depth = np.full((23, h, w), 800.0, dtype=np.float32)
    depth[:, 0, :] = np.nan  # 1 row of 24 invalid everywhere
    depth[3, :, :] = np.nan  # frame 3 (not sampled) fully invalid
    depth[22, 1, 1] = 900.0  # last frame: always sampled
    path = write_npz(Sequence(depth, np.zeros_like(depth), small_intrinsics), tmp_path / "l.npz")
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["stats_frames"] == 10
    assert info["valid_fraction"] == pytest.approx(23 / 24)
    assert info["depth_max_mm"] == 900.0
    assert main(["info", str(path), "--json", "--all-frames"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["stats_frames"] == 23
    assert info["valid_fraction"] == pytest.approx(22 * 23 / (23 * 24))
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "valid pixels: 95.8 % (10 of 23 frames, evenly spaced; --all-frames for all)" in out


def test_info_tum_needs_intrinsics(tmp_path, small_sequence, capsys):
    _write_tum(tmp_path / "tum", small_sequence)
    assert main(["info", str(tmp_path / "tum")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fuse4d: error: {tmp_path}/tum: no intrinsics: TUM folders")
    assert len(err.strip().splitlines()) == 1
    assert main(["info", str(tmp_path / "tum"), "--intrinsics", "freiburg3", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "tum"
    assert info["intrinsics"]["fx"] == pytest.approx(535.4 * 32 / 640)  # scaled to the image
    assert info["depth_unit_mm"] == 0.2


def test_info_bad_input_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"nope")
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"fuse4d: error: {bad}: not a valid .npz file (truncated or corrupt: "
        "File is not a zip file)\n"
    )


def test_export_ply(npz_path, small_sequence, tmp_path, capsys):
    out = tmp_path / "f.ply"
    assert main(["export-ply", str(npz_path), "--frame", "2", "-o", str(out)]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {22 * 32} points (frame 2) to {out}"
    xyz, rgb = read_ply(out)
    assert xyz.shape == (22 * 32, 3)
    np.testing.assert_allclose(xyz[:, 2], small_sequence.depth[2, 2:].ravel())
    expected = np.round(small_sequence.intensity[2, 2:].ravel() * 255)
    np.testing.assert_array_equal(rgb[:, 1], expected)
    # existing output: refused without --force, replaced with it
    assert main(["export-ply", str(npz_path), "--frame", "0", "-o", str(out)]) == 2
    assert "output exists; pass overwrite=True (CLI: --force)" in capsys.readouterr().err
    assert main(["export-ply", str(npz_path), "--frame", "-1", "-o", str(out), "--force"]) == 0
    assert "(frame 3)" in capsys.readouterr().out


def test_export_ply_errors(npz_path, tmp_path, capsys):
    assert main(["export-ply", str(npz_path), "--frame", "9", "-o", str(tmp_path / "x.ply")]) == 2
    assert capsys.readouterr().err == (
        f"fuse4d: error: --frame 9 is out of range: {npz_path} has 4 frames (0..3)\n"
    )
    before = npz_path.read_bytes()
    assert main(["export-ply", str(npz_path), "-o", str(npz_path), "--force"]) == 2
    assert "output would overwrite the input" in capsys.readouterr().err
    assert npz_path.read_bytes() == before
    assert not (tmp_path / "x.ply").exists()
    # a PLY under another name (was written as a.txt)
    assert main(["export-ply", str(npz_path), "-o", str(tmp_path / "a.txt")]) == 2
    assert "give a name ending .ply" in capsys.readouterr().err
    assert not (tmp_path / "a.txt").exists()
