"""fuse4d.io readers on bad input: one InputFileError naming the file and frame (exact text)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from fuse4d import InputFileError, Sequence
from fuse4d.flow import read_flo
from fuse4d.io import (
    load_sequence,
    open_frames,
    read_frame_folder,
    read_npz,
    read_ply,
    read_tum,
    write_frame_folder,
    write_npz,
)
from test_io import _write_cv2_xml, _write_frames_json, _write_tum


def _message(excinfo: pytest.ExceptionInfo) -> str:
    return str(excinfo.value)


@pytest.fixture
def folder(tmp_path: Path, small_sequence: Sequence) -> Path:
    return write_frame_folder(small_sequence, tmp_path / "seq", depth_unit_mm=0.01)


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


# ----------------------------------------------------------------------------- frame folder
def test_truncated_depth_png(folder):
    _truncate(folder / "depth/000003.png")
    reader = open_frames(folder)  # metadata still fine
    reader.read_frame(2)
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/depth/000003.png (frame 3): cannot decode PNG (truncated or corrupt file)"
    )
    assert exc.value.frame == 3


def test_corrupt_intensity_png(folder):
    (folder / "intensity/000001.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(InputFileError) as exc:
        read_frame_folder(folder)
    assert _message(exc) == (
        f"{folder}/intensity/000001.png (frame 1): cannot decode PNG (truncated or corrupt file)"
    )


def test_missing_intrinsics_key(folder):
    cam = json.loads((folder / "camera.json").read_text())
    del cam["fx"]
    (folder / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == f"{folder}/camera.json: missing key 'fx'"


def test_camera_json_without_camera_keys_takes_given_intrinsics(folder, small_sequence):
    """A camera.json holding only the unit made intrinsics= useless ("missing key 'fx'")."""
    (folder / "camera.json").write_text('{"depth_unit_mm": 0.01}')
    seq = load_sequence(folder, intrinsics="50,51,15.5,11.5")
    assert tuple(seq.intrinsics.as_array()) == (50.0, 51.0, 15.5, 11.5)
    np.testing.assert_allclose(seq.depth, small_sequence.depth, atol=0.01)
    tum = folder.parent / "tum"
    _write_tum(tum, small_sequence)
    (tum / "camera.json").write_text('{"depth_unit_mm": 0.2, "fx": 1}')  # fx alone: ignored
    assert read_tum(tum, intrinsics="50,51,15.5,11.5").intrinsics.fx == 50.0
    with pytest.raises(InputFileError, match=r"camera.json: missing key 'fy'"):
        read_tum(tum)
    # beside given intrinsics the file's rate is still read and its size still checked
    (tum / "camera.json").write_text('{"depth_unit_mm": 0.2, "fps": 15}')
    assert read_tum(tum, intrinsics="50,51,15.5,11.5").fps == 15.0
    (tum / "camera.json").write_text('{"depth_unit_mm": 0.2, "width": 99}')
    with pytest.raises(InputFileError, match=r"camera\.json"):
        read_tum(tum, intrinsics="50,51,15.5,11.5")


def test_missing_depth_unit_key(folder):
    cam = json.loads((folder / "camera.json").read_text())
    del cam["depth_unit_mm"]
    (folder / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == f"{folder}/camera.json: missing key 'depth_unit_mm'"
    assert load_sequence(folder, depth_unit_mm=0.01).num_frames == 4  # explicit unit is fine


def test_missing_camera_json(folder):
    (folder / "camera.json").unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/camera.json: file not found (a frame folder needs camera.json with "
        "fx, fy, cx, cy, depth_unit_mm)"
    )


def test_camera_json_bad_value_and_bad_json(folder):
    (folder / "camera.json").write_text(
        '{"fx": "525", "fy": 1, "cx": 1, "cy": 1, "depth_unit_mm": 1}'
    )
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == f"{folder}/camera.json: key 'fx' must be a number, got '525'"
    (folder / "camera.json").write_text('{"fx": 525,')
    with pytest.raises(InputFileError, match=r"camera.json: not valid JSON \(Expecting"):
        load_sequence(folder)


def test_camera_json_size_mismatch(folder):
    cam = json.loads((folder / "camera.json").read_text())
    cam["width"] = 640
    (folder / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/camera.json: camera size 640x24 does not match the 32x24 frames (WxH)"
    )


def test_intensity_shape_mismatch(folder):
    cv2.imwrite(str(folder / "intensity/000002.png"), np.zeros((12, 16), np.uint8))
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/intensity/000002.png (frame 2): image is 16x12 but the depth frame is "
        "32x24 (WxH)"
    )


def test_depth_shape_differs_from_first_frame(folder):
    cv2.imwrite(str(folder / "depth/000001.png"), np.ones((12, 16), np.uint16))
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/depth/000001.png (frame 1): image is 16x12 but frame 0 is 32x24 (WxH)"
    )


def test_depth_png_not_16_bit(folder):
    cv2.imwrite(str(folder / "depth/000000.png"), np.ones((24, 32), np.uint8))
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/depth/000000.png (frame 0): depth PNG must be 16-bit (uint16), got 8-bit "
        "uint8; 8-bit depth loses too much precision"
    )


def test_depth_png_with_colour_channels(folder):
    cv2.imwrite(str(folder / "depth/000001.png"), np.ones((24, 32, 3), np.uint16))
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/depth/000001.png (frame 1): depth image must have one channel, got 3 channels"
    )


def _gray_alpha_png(path, h, w):
    """An 8-bit gray+alpha PNG (colour type 4; cv2.imwrite cannot write one)."""
    import struct
    import zlib

    def chunk(kind, data):
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    rows = b"".join(b"\x00" + bytes(2 * w) for _ in range(h))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 4, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(rows))
        + chunk(b"IEND", b"")
    )


def test_depth_png_with_an_alpha_channel_says_two_channels(folder):
    """OpenCV expands gray+alpha to 4 channels; the message said "got 4 channels"."""
    _gray_alpha_png(folder / "depth/000001.png", 24, 32)
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc).endswith("depth image must have one channel, got 2 channels")


def test_frame_count_mismatch(folder):
    (folder / "intensity/000003.png").unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/intensity: 3 intensity frames but 4 depth frames; every depth frame needs "
        "an intensity frame"
    )


def test_gap_in_numbering(folder):
    (folder / "depth/000002.png").unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}/depth/000002.png (frame 2): file not found (frames must be numbered "
        "0, 1, 2, ... without gaps)"
    )


def test_empty_folder(tmp_path):
    (tmp_path / "empty" / "depth").mkdir(parents=True)
    with pytest.raises(InputFileError) as exc:
        load_sequence(tmp_path / "empty")
    assert _message(exc) == (
        f"{tmp_path}/empty: no depth frames found (expected depth/000000.png, "
        "depth/000001.png, ...)"
    )


def test_empty_folder_without_layout(tmp_path):
    with pytest.raises(InputFileError) as exc:
        load_sequence(tmp_path)
    assert _message(exc) == (
        f"{tmp_path}: no depth frames found (expected depth/000000.png ... with camera.json, "
        "a TUM rgb.txt/depth.txt, a frames.json, or NNNN_depth.png + NNNN_camera.xml)"
    )


def test_missing_path(tmp_path):
    with pytest.raises(InputFileError) as exc:
        load_sequence(tmp_path / "nope")
    assert _message(exc) == f"{tmp_path}/nope: file or folder not found"


def test_missing_intensity_folder(folder):
    for p in (folder / "intensity").iterdir():
        p.unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(folder)
    assert _message(exc) == (
        f"{folder}: no intensity frames found (expected intensity/000000.png, ...)"
    )


# ----------------------------------------------------------------------------- npz
def test_corrupt_npz(tmp_path):
    path = tmp_path / "bad.npz"
    path.write_bytes(b"this is not a zip archive")
    with pytest.raises(InputFileError) as exc:
        load_sequence(path)
    assert _message(exc) == (
        f"{path}: not a valid .npz file (truncated or corrupt: File is not a zip file)"
    )


def test_truncated_npz(tmp_path, small_sequence):
    path = write_npz(small_sequence, tmp_path / "s.npz")
    _truncate(path)
    with pytest.raises(InputFileError) as exc:
        read_npz(path)
    assert _message(exc).startswith(f"{path}: not a valid .npz file (truncated or corrupt")


def test_npz_missing_key(tmp_path, small_sequence):
    path = tmp_path / "s.npz"
    np.savez(path, depth=small_sequence.depth, intensity=small_sequence.intensity)
    with pytest.raises(InputFileError) as exc:
        load_sequence(path)
    assert _message(exc) == (
        f"{path}: missing key 'intrinsics' (a fuse4d .npz needs depth, intensity, intrinsics)"
    )


def test_npz_shape_mismatch(tmp_path, small_sequence):
    path = tmp_path / "s.npz"
    np.savez(
        path,
        depth=small_sequence.depth,
        intensity=small_sequence.intensity[:, :, :31],
        intrinsics=small_sequence.intrinsics.as_array(),
    )
    with pytest.raises(InputFileError) as exc:
        load_sequence(path)
    assert _message(exc) == (
        f"{path}: key 'intensity' has shape (4, 24, 31) but 'depth' has (4, 24, 32)"
    )


def test_npz_bad_intrinsics_and_values(tmp_path, small_sequence):
    path = tmp_path / "s.npz"
    np.savez(path, depth=small_sequence.depth, intensity=small_sequence.intensity,
             intrinsics=np.array([80.0, 80.0, 15.5]))  # fmt: skip
    with pytest.raises(InputFileError) as exc:
        load_sequence(path)
    assert _message(exc) == (
        f"{path}: key 'intrinsics' must hold [fx, fy, cx, cy], got float64 of shape (3,)"
    )
    np.savez(path, depth=small_sequence.depth, intensity=small_sequence.intensity * 2,
             intrinsics=small_sequence.intrinsics.as_array())  # fmt: skip
    with pytest.raises(InputFileError, match=rf"^{path}: intensity must lie in \[0, 1\]"):
        load_sequence(path)


def test_npz_frames_refuse_integer_intensity_of_unknown_depth(tmp_path, small_sequence):
    """Frame by frame, uint32 0-248 was divided by 2**32 - 1 (black) while the whole-sequence
    read refused it; now both refuse, the frame reader naming the frame."""
    path = tmp_path / "s.npz"
    gray = np.round(small_sequence.intensity * 248).astype(np.uint32)
    np.savez(path, depth=small_sequence.depth, intensity=gray,
             intrinsics=small_sequence.intrinsics.as_array())  # fmt: skip
    with (
        open_frames(path) as reader,
        pytest.raises(
            InputFileError, match=rf"^{path} \(frame 2\): key 'intensity' has integer dtype uint32"
        ),
    ):
        reader[2]
    np.savez(path, depth=small_sequence.depth, intensity=gray.astype(np.uint16),
             intrinsics=small_sequence.intrinsics.as_array())  # fmt: skip
    with open_frames(path) as reader:
        np.testing.assert_allclose(reader[2].intensity, gray[2] / 65535, atol=1e-7)


def test_npz_truncated_member_detected(tmp_path, small_sequence):
    """A member whose bytes are cut (zip directory intact) is reported, not memory-mapped."""
    path = write_npz(small_sequence, tmp_path / "s.npz")
    import zipfile

    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("depth.npy")
    data = bytearray(path.read_bytes())
    # shrink the header's shape so the descriptor still parses, then claim a huge array
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    header = bytes(data[start : start + 128])
    bad = header.replace(b"(4, 24, 32)", b"(9, 99, 99)")
    data[start : start + 128] = bad
    path.write_bytes(bytes(data))
    with pytest.raises(InputFileError) as exc:
        read_npz(path)
    assert _message(exc).startswith(f"{path}: key 'depth': cannot read array (truncated or corrupt")


# ----------------------------------------------------------------------------- TUM
def test_tum_without_intrinsics(tmp_path, small_sequence):
    _write_tum(tmp_path / "rgbd_dataset_freiburg1_xyz", small_sequence)
    with pytest.raises(InputFileError) as exc:
        read_tum(tmp_path / "rgbd_dataset_freiburg1_xyz")
    assert _message(exc) == (
        f"{tmp_path}/rgbd_dataset_freiburg1_xyz: no intrinsics: TUM folders do not store them; "
        "add camera.json with fx, fy, cx, cy or pass intrinsics= (one of freiburg1, "
        "freiburg2, freiburg3, kinect-v1) (the folder name suggests 'freiburg1')"
    )


def test_tum_truncated_and_bad_list(tmp_path, small_sequence):
    root = tmp_path / "tum"
    _write_tum(root, small_sequence)
    depth_files = sorted((root / "depth").iterdir())
    _truncate(depth_files[1])
    with pytest.raises(InputFileError) as exc:
        read_tum(root, intrinsics="freiburg1")
    assert _message(exc) == (
        f"{depth_files[1]} (frame 1): cannot decode PNG (truncated or corrupt file)"
    )
    (root / "depth.txt").write_text("# header\n1305031102.0\n")
    with pytest.raises(InputFileError) as exc:
        read_tum(root, intrinsics="freiburg1")
    assert _message(exc) == (
        f"{root}/depth.txt: line 2: expected 'timestamp filename', got '1305031102.0'"
    )
    (root / "depth.txt").unlink()
    with pytest.raises(InputFileError) as exc:
        read_tum(root, intrinsics="freiburg1")
    assert _message(exc) == (
        f"{root}/depth.txt: file not found (a TUM folder needs rgb.txt and depth.txt)"
    )


def test_tum_list_order_bom_and_repeated_stamp(tmp_path, small_sequence):
    """Frames follow the depth timestamps as documented (an unsorted depth.txt was refused
    without naming a line); a BOM is ignored; a timestamp listed twice names both lines."""
    root = tmp_path / "tum"
    _write_tum(root, small_sequence)
    want = read_tum(root, intrinsics="freiburg1")
    lines = (root / "depth.txt").read_text().splitlines()  # a comment, then frames 0..3
    lines[2], lines[3] = lines[3], lines[2]
    (root / "depth.txt").write_text("\ufeff" + "\n".join(lines) + "\n", encoding="utf-8")
    with open_frames(root, intrinsics="freiburg1") as reader:
        assert "depth.txt is not in time order: frames ordered by timestamp" in reader.notes
    got = read_tum(root, intrinsics="freiburg1")
    np.testing.assert_array_equal(got.timestamps, want.timestamps)
    np.testing.assert_array_equal(got.depth, want.depth)
    lines[4] = lines[2].split()[0] + " " + lines[4].split()[1]  # frame 3 at frame 2's time
    (root / "depth.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputFileError) as exc:
        read_tum(root, intrinsics="freiburg1")
    stamp = float(lines[2].split()[0])
    assert (
        _message(exc) == f"{root}/depth.txt: lines 3 and 5: timestamp {stamp:.6f} is listed twice"
    )


def test_tum_folder_without_rgb_list(tmp_path, small_sequence):
    """depth.txt without rgb.txt is not a TUM folder to detection; the frame-folder reader
    said 'no intensity frames found'."""
    root = tmp_path / "tum"
    _write_tum(root, small_sequence)
    (root / "rgb.txt").unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(root, intrinsics="freiburg1")
    assert _message(exc) == (
        f"{root}: TUM folder: rgb.txt not found (a TUM folder needs rgb.txt and depth.txt)"
    )


def test_bad_intrinsics_argument(tmp_path, small_sequence):
    root = tmp_path / "tum"
    _write_tum(root, small_sequence)
    with pytest.raises(ValueError, match=r"intrinsics 'freiburg9' is neither a preset"):
        read_tum(root, intrinsics="freiburg9")
    with pytest.raises(ValueError, match=r"intrinsics must be \[fx, fy, cx, cy\] \(4 numbers\)"):
        read_tum(root, intrinsics=[500.0, 500.0])


# ----------------------------------------------------------------------------- cv2-xml
def test_cv2_xml_missing_intrinsic_node(tmp_path, small_sequence):
    root = tmp_path / "uva"
    _write_cv2_xml(root, small_sequence)
    fs = cv2.FileStorage(str(root / "0000000000_camera.xml"), cv2.FILE_STORAGE_WRITE)
    fs.write("R", np.eye(3))
    fs.release()
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == (
        f"{root}/0000000000_camera.xml (frame 0): missing node 'intrinsic' (3x3 camera matrix)"
    )


def test_cv2_xml_camera_changes(tmp_path, small_sequence):
    root = tmp_path / "uva"
    _write_cv2_xml(root, small_sequence)
    fs = cv2.FileStorage(str(root / "0000000002_camera.xml"), cv2.FILE_STORAGE_WRITE)
    fs.write("intrinsic", small_sequence.intrinsics.scaled(2.0).matrix)
    fs.release()
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == (
        f"{root}/0000000002_camera.xml (frame 2): camera differs from frame 0's; fuse4d needs "
        "one fixed camera (pass intrinsics= to override)"
    )


def test_cv2_xml_missing_colour_mask_and_gap(tmp_path, small_sequence):
    root = tmp_path / "uva"
    _write_cv2_xml(root, small_sequence)
    (root / "0000000001_mask.png").unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == (
        f"{root}/0000000001_mask.jpg (frame 1): file not found (other frames have masks; "
        "give all or none)"
    )
    (root / "0000000003.png").unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == (
        f"{root}/0000000003.jpg (frame 3): file not found (colour image for 0000000003_depth.png)"
    )
    (root / "0000000002_depth.png").unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == (
        f"{root}/0000000002_depth.png (frame 2): file not found (frame numbers must be consecutive)"
    )


def test_cv2_xml_truncated_jpeg(tmp_path, small_sequence):
    root = tmp_path / "uva"
    _write_cv2_xml(root, small_sequence, masks=False)
    image = np.round(small_sequence.intensity[1] * 255).astype(np.uint8)
    (root / "0000000001.png").unlink()
    cv2.imwrite(str(root / "0000000001.jpg"), image)
    _truncate(root / "0000000001.jpg")
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == (
        f"{root}/0000000001.jpg (frame 1): cannot decode JPEG (truncated or corrupt file)"
    )


# ----------------------------------------------------------------------------- frames-json
def test_frames_json_missing_middle_file(tmp_path, small_sequence):
    root = tmp_path / "fj"
    _write_frames_json(root, small_sequence)
    (root / "frame_00001_rgb.png").unlink()
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == f"{root}/frame_00001_rgb.png (frame 1): file not found"


def test_frames_json_missing_key_and_bad_timestamps(tmp_path, small_sequence):
    root = tmp_path / "fj"
    _write_frames_json(root, small_sequence)
    data = json.loads((root / "frames.json").read_text())
    del data["root"][2]["info"]["depth_scale"]
    (root / "frames.json").write_text(json.dumps(data))
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == f"{root}/frames.json: entry 2: missing key 'info.depth_scale'"
    data["root"][2]["info"]["depth_scale"] = 0.0002
    data["root"][2]["info"]["timestamp"] = 0
    (root / "frames.json").write_text(json.dumps(data))
    with pytest.raises(InputFileError) as exc:
        load_sequence(root)
    assert _message(exc) == f"{root}/frames.json: timestamps must be strictly increasing"


# ----------------------------------------------------------------------------- PLY / flo
def test_read_ply_bad(tmp_path):
    path = tmp_path / "x.ply"
    path.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n0 0 0\n")
    with pytest.raises(InputFileError) as exc:
        read_ply(path)
    assert _message(exc) == f"{path}: only binary_little_endian PLY is supported"


def test_read_flo_bad(tmp_path):
    path = tmp_path / "x.flo"
    path.write_bytes(np.array([1.0], "<f4").tobytes() + np.array([2, 2], "<i4").tobytes())
    with pytest.raises(InputFileError) as exc:
        read_flo(path)
    assert _message(exc) == f"{path}: not a Middlebury .flo file (tag 1.0, expected 202021.25)"
    good = np.array([202021.25], "<f4").tobytes() + np.array([2, 2], "<i4").tobytes()
    path.write_bytes(good + b"\0" * 20)
    with pytest.raises(InputFileError) as exc:
        read_flo(path)
    assert _message(exc) == f"{path}: truncated: 2x2 flow needs 32 bytes, got 20"
    with pytest.raises(InputFileError) as exc:
        read_flo(tmp_path / "none.flo")
    assert _message(exc) == f"{tmp_path}/none.flo: file not found"


@pytest.mark.parametrize(
    ("bad", "found"),
    [
        (np.nan, "NaN found"),
        (np.inf, "inf found"),
        (1.5, "1 above 1, up to 1.5 found"),
        # float32 just above 1: a rounded '1' would hide what is wrong
        (np.nextafter(np.float32(1), np.float32(2)), "1 above 1, up to 1.0000001192092896 found"),
        (-0.25, "1 below 0, down to -0.25 found"),
    ],
)
@pytest.mark.parametrize("layout", ["npz", "zarr"])
def test_streamed_intensity_outside_unit_range_names_what_was_found(
    tmp_path, small_sequence, layout, bad, found
):
    """A stored float intensity frame outside [0, 1] is refused naming the frame and what was
    found (the message said 'NaN, inf or values outside found'); a zarr store reads NaN as 0."""
    intensity = np.zeros_like(small_sequence.intensity)
    intensity[2, 3, 4] = bad
    if layout == "npz":
        path = tmp_path / "s.npz"
        np.savez(path, depth=small_sequence.depth, intensity=intensity,
                 intrinsics=small_sequence.intrinsics.as_array())  # fmt: skip
        what = "key 'intensity'"
    else:
        zarr = pytest.importorskip("zarr")
        from fuse4d.io import write_zarr

        path = write_zarr(small_sequence, tmp_path / "s.zarr")
        zarr.open_group(str(path), mode="r+")["intensity"][2] = intensity[2]
        what = "'intensity'"
    reader = open_frames(path)
    reader.read_frame(1)
    if layout == "zarr" and np.isnan(bad):
        assert reader.read_frame(2).intensity[3, 4] == 0
        return
    with pytest.raises(InputFileError) as exc:
        reader.read_frame(2)
    assert _message(exc) == (
        f"{path} (frame 2): {what} must hold finite values in [0, 1] ({found}; rescale with "
        "fuse4d.sequence.normalize_intensity)"
    )
