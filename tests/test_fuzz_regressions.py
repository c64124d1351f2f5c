"""Regression tests for the reader failures found by fuzzing (tests/test_fuzz_readers.py).

Each test is one failure, reduced by hand: the input, and the fuse4d error it must now give.
"""

from __future__ import annotations

import io
import json
import shutil
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from fuse4d import InputFileError, Sequence
from fuse4d.config import load_config
from fuse4d.flow import read_flo
from fuse4d.io import (
    open_frames,
    read_mask,
    read_ply,
    write_frame_folder,
    write_npz,
    write_ply,
)
from fuse4d.io._images import decode_image


def _npz(path: Path, **arrays) -> Path:
    with path.open("wb") as f:
        np.savez(f, **arrays)
    return path


def _valid_arrays(seq: Sequence) -> dict:
    return {"depth": seq.depth, "intensity": seq.intensity,
            "intrinsics": seq.intrinsics.as_array()}  # fmt: skip


def _read_all(path: Path) -> None:
    with open_frames(path) as reader:
        for _ in reader:
            pass


# ----------------------------------------------------------------------------- npz
@pytest.mark.parametrize("value", [np.nan, np.inf, -0.5, 2.0])
def test_npz_intensity_out_of_range_is_an_input_error(tmp_path, small_sequence, value):
    arrays = _valid_arrays(small_sequence)
    arrays["intensity"] = arrays["intensity"].copy()
    arrays["intensity"][1, 2, 3] = value
    path = _npz(tmp_path / "s.npz", **arrays)
    with pytest.raises(InputFileError, match=r"frame 1\).*intensity"):
        _read_all(path)  # was: NaN/out-of-range intensity handed out by the streaming reader


@pytest.mark.parametrize("stamps", [[0, 1, -np.inf, 3], [0, 2, 1, 3], [0, 1, 1, 2]])
def test_npz_bad_timestamps_are_an_input_error(tmp_path, small_sequence, stamps):
    path = _npz(tmp_path / "s.npz", **_valid_arrays(small_sequence), timestamps=np.array(stamps))
    with pytest.raises(InputFileError, match="timestamps"):
        open_frames(path)


@pytest.mark.parametrize("key", ["fps", "name"])
def test_npz_bad_scalar_keys_are_input_errors(tmp_path, small_sequence, key):
    bad = {"fps": np.array([1.0, 2.0]), "name": np.zeros(3)}[key]
    path = _npz(tmp_path / "s.npz", **_valid_arrays(small_sequence), **{key: bad})
    with pytest.raises(InputFileError, match=key):
        open_frames(path)  # was: TypeError from float()/nonsense name


@pytest.mark.parametrize("dtype", ["<U3", "complex64", "f4,i2"])
def test_npz_non_real_depth_dtype_is_an_input_error(tmp_path, small_sequence, dtype):
    arrays = _valid_arrays(small_sequence)
    arrays["depth"] = np.zeros(arrays["depth"].shape, dtype)
    path = _npz(tmp_path / "s.npz", **arrays)
    with pytest.raises(InputFileError, match="real numbers"):
        _read_all(path)  # was: ValueError/ComplexWarning in read_frame


def _rewrite_member(path: Path, name: str, data: bytes) -> None:
    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members[name] = data
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for n, blob in members.items():
            z.writestr(n, blob)


def test_npz_corrupt_deflate_stream_is_an_input_error(tmp_path, small_sequence):
    path = write_npz(small_sequence, tmp_path / "s.npz", compress=True)
    blob = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("depth.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    blob[start + 40 : start + 60] = b"\xff" * 20
    path.write_bytes(bytes(blob))
    with pytest.raises(InputFileError, match="depth"):
        open_frames(path)  # was: zlib.error


def test_npz_compressed_member_declaring_a_huge_shape_is_refused(tmp_path, small_sequence):
    path = write_npz(small_sequence, tmp_path / "s.npz", compress=True)
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f4", "fortran_order": False, "shape": (10**6, 10**6, 10**3)}
    )
    _rewrite_member(path, "depth.npy", b"\x93NUMPY\x01\x00"[:0] + header.getvalue() + b"\0" * 64)
    with pytest.raises(InputFileError, match="truncated"):
        open_frames(path)  # was: numpy allocated the declared 4 PB before reading


def test_npz_reader_closes_the_file_when_opening_fails(tmp_path, small_sequence, recwarn):
    arrays = _valid_arrays(small_sequence)
    del arrays["intrinsics"]
    path = _npz(tmp_path / "s.npz", **arrays)
    with pytest.raises(InputFileError, match="missing key 'intrinsics'"):
        open_frames(path)
    import gc

    gc.collect()
    assert not [w for w in recwarn if issubclass(w.category, ResourceWarning)]


def test_mask_npz_corrupt_zip_does_not_leak_the_file(tmp_path, recwarn):
    path = tmp_path / "roi.npz"
    path.write_bytes(b"PK\x03\x04" + b"\0" * 40)  # a zip magic, then garbage
    with pytest.raises(InputFileError, match=r"not a valid \.npz"):
        read_mask(path)
    import gc

    gc.collect()
    assert not [w for w in recwarn if issubclass(w.category, ResourceWarning)]


# ----------------------------------------------------------------------------- folders
@pytest.fixture
def folder(tmp_path, small_sequence) -> Path:
    return write_frame_folder(small_sequence, tmp_path / "seq", depth_unit_mm=0.01)


def test_folder_duplicated_frame_number_is_an_input_error(folder):
    shutil.copyfile(folder / "depth" / "000001.png", folder / "depth" / "1.png")
    with pytest.raises(InputFileError, match="frame number 1 appears twice"):
        open_frames(folder)  # was: one of the two files silently chosen


def test_png_header_declaring_a_huge_image_is_refused(folder):
    path = folder / "intensity" / "000002.png"
    blob = bytearray(path.read_bytes())
    blob[16:24] = (100_000).to_bytes(4, "big") + (100_000).to_bytes(4, "big")
    path.write_bytes(bytes(blob))
    with pytest.raises(InputFileError, match="100000x100000 px"):
        decode_image(path)  # was: the decoder may allocate the declared 10 G px


def test_jpeg_header_declaring_a_huge_image_is_refused(tmp_path):
    ok, buf = cv2.imencode(".jpg", np.zeros((8, 8), np.uint8))
    assert ok
    blob = bytearray(buf.tobytes())
    sof = blob.index(b"\xff\xc0")
    blob[sof + 5 : sof + 9] = (65_000).to_bytes(2, "big") * 2
    path = tmp_path / "x.jpg"
    path.write_bytes(bytes(blob))
    with pytest.raises(InputFileError, match="65000x65000 px"):
        decode_image(path)


def test_image_that_is_not_a_regular_file_is_refused(tmp_path):
    with pytest.raises(InputFileError, match="not a regular file"):
        decode_image(tmp_path)  # a folder (also: a FIFO or /dev/zero would block or never end)


def _tum(tmp_path: Path, small_sequence: Sequence) -> Path:
    root = tmp_path / "tum"
    (root / "d").mkdir(parents=True)
    depth = np.nan_to_num(small_sequence.depth[0] * 5).astype(np.uint16)
    assert cv2.imwrite(str(root / "d" / "0.png"), depth)
    gray = (small_sequence.intensity[0] * 255).astype(np.uint8)
    assert cv2.imwrite(str(root / "d" / "c.png"), gray)
    (root / "depth.txt").write_text("1.0 d/0.png\n")
    (root / "rgb.txt").write_text("1.0 d/c.png\n")
    (root / "camera.json").write_text(json.dumps({"fx": 80, "fy": 80, "cx": 15.5, "cy": 11.5}))
    return root


@pytest.mark.parametrize("name", ["../outside.png", "/etc/passwd", "/dev/zero"])
def test_tum_list_naming_a_file_outside_the_folder_is_refused(tmp_path, small_sequence, name):
    root = _tum(tmp_path, small_sequence)
    _read_all(root)
    (root / "rgb.txt").write_text(f"1.0 {name}\n")
    with pytest.raises(InputFileError, match="leaves the recording folder"):
        open_frames(root)  # was: read any file the list named (and hung on /dev/zero)


def test_tum_list_that_is_not_utf8_is_an_input_error(tmp_path, small_sequence):
    root = _tum(tmp_path, small_sequence)
    (root / "rgb.txt").write_bytes(b"1.0 d/c.png\xff\xfe\n")
    with pytest.raises(InputFileError, match="cannot read file"):
        open_frames(root)  # was: UnicodeDecodeError


def _frames_json(tmp_path: Path, small_sequence: Sequence) -> Path:
    root = _tum(tmp_path, small_sequence)
    entry = {"info": {"kcam": {"matrix": [[80, 0, 15.5], [0, 80, 11.5], [0, 0, 1]],
                               "image_size": [32, 24]},
                      "depth_scale": 0.001, "depth_bias": 0.0, "timestamp": 0},
             "depth_image": "d/0.png", "rgb_image": "d/c.png"}  # fmt: skip
    (root / "frames.json").write_text(json.dumps({"root": [entry]}))
    return root


@pytest.mark.parametrize(
    ("path", "value"),
    [
        (("info", "kcam", "matrix"), [[1, 2, 3], [4, 5], [6]]),
        (("info", "kcam", "matrix"), [[80, 0, "x"], [0, 80, 1], [0, 0, 1]]),
        (("info", "depth_scale"), "0.001"),
        (("info", "depth_scale"), None),
        (("info", "kcam", "image_size"), 7),
        (("info", "timestamp"), [1]),
        (("info", "depth_bias"), "0"),
        (("depth_image",), "../../x.png"),
        (("rgb_image",), 5),
    ],
)
def test_frames_json_malformed_entry_is_an_input_error(tmp_path, small_sequence, path, value):
    root = _frames_json(tmp_path, small_sequence)
    _read_all(root)
    doc = json.loads((root / "frames.json").read_text())
    node = doc["root"][0]
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    (root / "frames.json").write_text(json.dumps(doc))
    with pytest.raises(InputFileError, match="entry 0"):
        open_frames(root)  # was: ValueError/TypeError from np.asarray/float/tuple


def test_cv2_xml_malformed_xml_is_an_input_error(tmp_path, small_sequence):
    root = tmp_path / "cv2"
    root.mkdir()
    depth = np.nan_to_num(small_sequence.depth[0]).astype(np.uint16)
    assert cv2.imwrite(str(root / "0000_depth.png"), depth)
    assert cv2.imwrite(str(root / "0000.png"), (small_sequence.intensity[0] * 255).astype("u1"))
    (root / "0000_camera.xml").write_text('<?xml version="1.0"?>\n<opencv_storage>\n<intr')
    with pytest.raises(InputFileError, match="OpenCV FileStorage"):
        open_frames(root)  # was: SystemError from cv2.FileStorage


# ----------------------------------------------------------------------------- flo / ply
def test_flo_and_ply_that_are_folders_are_input_errors(tmp_path):
    (tmp_path / "x.flo").mkdir()
    (tmp_path / "x.ply").mkdir()
    with pytest.raises(InputFileError, match="cannot read file"):
        read_flo(tmp_path / "x.flo")  # was: IsADirectoryError
    with pytest.raises(InputFileError, match="cannot read file"):
        read_ply(tmp_path / "x.ply")


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("element vertex 4", "element vertex", "bad header line"),
        ("element vertex 4", "element vertex abc", "bad vertex count"),
        ("element vertex 4", "element vertex -1", "bad vertex count"),
        ("property float y", "property float x", "appears twice"),
        ("property float y\n", "", "properties y missing"),
        ("property float z", "property float", "unsupported vertex property"),
    ],
)
def test_ply_bad_header_is_an_input_error(tmp_path, old, new, match):
    path = tmp_path / "c.ply"
    write_ply(np.ones((4, 3), np.float32), path)
    blob = path.read_bytes()
    end = blob.index(b"end_header\n")
    header = blob[:end].decode().replace(old, new)
    path.write_bytes(header.encode() + blob[end:])
    with pytest.raises(InputFileError, match=match):
        read_ply(path)  # was: IndexError/ValueError from int()/np.dtype/field access


# ----------------------------------------------------------------------------- toml
@pytest.mark.parametrize("text", ["preset = 99\n", 'preset = "nope"\n', "fusion = 3\n"])
def test_toml_bad_preset_or_table_is_an_input_error(tmp_path, text):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(InputFileError, match=r"c\.toml"):
        load_config(path)  # was: bare ValueError for an unknown preset


# ----------------------------------------------------------------------------- found by the
# first random (nightly-style) runs
def test_folder_timestamps_must_be_finite(folder):
    lines = (
        (folder / "timestamps.txt").read_text().splitlines()
        if (folder / "timestamps.txt").exists()
        else ["0.0", "0.1", "0.2", "0.3"]
    )
    lines[2] = "inf"
    (folder / "timestamps.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputFileError, match="finite"):
        open_frames(folder)  # was: a frame with timestamp inf


@pytest.mark.parametrize("unit", [None, 1e308, 1e-300, 0])
def test_camera_json_depth_unit_must_be_plausible(folder, unit):
    cam = json.loads((folder / "camera.json").read_text())
    cam["depth_unit_mm"] = unit
    (folder / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(InputFileError, match="depth_unit_mm"):
        _read_all(folder)  # was: null accepted; 1e308 gave inf depth, 1e-300 depth 0


@pytest.mark.parametrize("stamp", ["nan", "inf"])
def test_tum_timestamps_must_be_finite(tmp_path, small_sequence, stamp):
    root = _tum(tmp_path, small_sequence)
    (root / "depth.txt").write_text(f"{stamp} d/0.png\n")
    with pytest.raises(InputFileError, match="expected 'timestamp filename'"):
        open_frames(root)


def test_mask_npz_corrupt_deflate_is_an_input_error(tmp_path):
    path = tmp_path / "roi.npz"
    np.savez_compressed(path, roi=np.ones((30, 40), bool))
    blob = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("roi.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    blob[start : start + info.compress_size] = b"\xff" * info.compress_size
    path.write_bytes(bytes(blob))
    with pytest.raises(InputFileError, match="not a valid"):
        read_mask(path)  # was: zlib.error


def test_mask_npz_member_declaring_a_huge_shape_is_refused(tmp_path):
    path = tmp_path / "roi.npz"
    np.savez_compressed(path, roi=np.ones((3, 4), bool))
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "|b1", "fortran_order": False, "shape": (10**7, 10**7)}
    )
    _rewrite_member(path, "roi.npy", header.getvalue() + b"\1" * 16)
    with pytest.raises(InputFileError, match="truncated"):
        read_mask(path)  # was: numpy allocated the declared 100 TB


def test_npz_header_with_unbalanced_brackets_is_an_input_error(tmp_path, small_sequence):
    """Found by the 10 000-case run: numpy's header parser raised tokenize.TokenError."""
    path = write_npz(small_sequence, tmp_path / "s.npz")
    header = b"\x93NUMPY\x01\x00" + (118).to_bytes(2, "little")
    text = b"{'descr': '<f4', 'fortran_order': False, 'shape': (4, 24, 32"
    _rewrite_member(path, "depth.npy", header + text.ljust(117, b" ") + b"\n" + b"\0" * 64)
    with pytest.raises(InputFileError, match="depth"):
        open_frames(path)


def test_npz_structured_mask_is_an_input_error(tmp_path, small_sequence):
    """Found by the 10 000-case run after the merge: a structured-dtype ``mask_gt``."""
    arrays = _valid_arrays(small_sequence)
    arrays["mask_gt"] = np.zeros(small_sequence.depth.shape, dtype="f4,i2")
    path = _npz(tmp_path / "s.npz", **arrays)
    with pytest.raises(InputFileError, match="mask_gt' must hold booleans"):
        _read_all(path)  # was: TypeError from numpy's cast to bool
