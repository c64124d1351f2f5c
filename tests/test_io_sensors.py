"""Camera recordings: RealSense .bag/.db3, Azure Kinect .mkv, generic ROS 1/ROS 2/MCAP bags,
the FFV1 .mkv and zarr writers, and the CLI on them (fixtures read in place, never copied)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from fuse4d import Intrinsics, Sequence
from fuse4d.cli import main
from fuse4d.errors import InputFileError, OutputExistsError
from fuse4d.io import (
    DepthVideoWriter,
    ZarrWriter,
    detect_format,
    load_sequence,
    open_frames,
    save_sequence,
)
from fuse4d.io._extras import MissingDependencyError, require
from fuse4d.io.mkv import k4a_depth_camera
from fuse4d.io.rvl import decode_rvl, encode_rvl

rosbags = pytest.importorskip("rosbags", reason="needs the sensors extra (rosbags)")
av = pytest.importorskip("av", reason="needs the sensors extra (PyAV)")
zarr = pytest.importorskip("zarr", reason="needs the sensors extra (zarr)")

from rosbag_factory import (
    DEPTH_TOPIC,
    IR_TOPIC,
    K,
    depth_frames,
    ir_frames,
    write_generic_bag,
)


@pytest.fixture
def recordings(shared_data: Path) -> Path:
    path = shared_data / "sensor_recordings"
    if not path.is_dir():
        pytest.skip(f"sensor fixtures not found: {path}")
    return path


def _expected_swdev_depth() -> np.ndarray:
    """README: frame i holds 10000 + i in units of 1e-4 m, i.e. 1000 + 0.1 i mm."""
    return (1000.0 + 0.1 * np.arange(5)).astype(np.float32)


def _run(args: list[str], capsys) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


# ----------------------------------------------------------------- RealSense fixtures
@pytest.mark.realdata
@pytest.mark.parametrize(
    "name",
    ["rs2551_swdev_5f.bag", "rs2551_swdev_5f_lz4.bag", "rs2591_swdev_5f.db3",
     "rs2591_swdev_5f_compressed.db3"],
)  # fmt: skip
def test_realsense_swdev_fixtures(recordings, name):
    path = recordings / name
    assert detect_format(path) == "rosbag"
    with open_frames(path) as reader:
        assert len(reader) == 5
        assert reader.depth_unit_mm == pytest.approx(0.1)  # 1e-4 m, from the file
        k = reader.intrinsics
        assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (50, 50, 32, 24, 64, 48)
        assert reader.fps == 30.0
        seq = reader.read_sequence()
        notes = " ".join(reader.notes)
    assert seq.depth.dtype == np.float32
    assert seq.intensity.dtype == np.float32
    np.testing.assert_allclose(seq.depth[:, 10, 10], _expected_swdev_depth(), atol=1e-3)
    assert np.all(seq.depth == seq.depth[:, :1, :1])  # constant frames
    # no IR stream in these files: colour (10 i) is used, aligned with the identity extrinsics
    np.testing.assert_allclose(seq.intensity[:, 5, 5], 10 * np.arange(5) / 255, atol=1e-6)
    assert "colour is used" in notes
    assert np.all(np.diff(seq.timestamps) > 0)
    if "2551" in name:
        assert reader._quirk  # 2.47-2.57 writer: 4 trailing bytes per Image


@pytest.mark.realdata
def test_realsense_legacy_fixture(recordings):
    path = recordings / "realsense_legacy_single_depth_color_640x480.bag"
    with open_frames(path) as reader:
        assert len(reader) == 2  # 2 depth frames, paired with the single colour frame
        assert reader.depth_unit_mm == pytest.approx(1.0)  # option Depth Units = 0.001
        k = reader.intrinsics
        assert (k.width, k.height) == (640, 480)
        assert (k.fx, k.cx, k.cy) == pytest.approx((390.4314575, 331.3878784, 242.1873474))
        assert reader.fps == 6.0
        seq = reader.read_sequence()
        assert reader._align is not None  # colour resampled with the recorded extrinsics
    valid = np.isfinite(seq.depth)
    assert 0.9 < valid.mean() < 0.96
    assert np.nanmin(seq.depth) > 300
    assert np.nanmax(seq.depth) < 4000
    assert seq.intensity.min() >= 0.0
    assert seq.intensity.max() <= 1.0
    assert seq.intensity.mean() > 0.1
    np.testing.assert_allclose(seq.timestamps, [360.815089, 360.981765])


@pytest.mark.realdata
def test_realsense_intensity_choice(recordings, capsys):
    path = recordings / "rs2551_swdev_5f.bag"
    with open_frames(path, intensity="color") as reader:
        assert reader[4].intensity[0, 0] == pytest.approx(40 / 255)
    code, _, err = _run(["info", path, "--intensity", "ir"], capsys)
    assert code == 2
    assert "no infrared image topic" in err
    assert "--intensity color" in err
    assert "Traceback" not in err


# ----------------------------------------------------------------- Azure Kinect fixture
@pytest.mark.realdata
def test_azure_kinect_fixture(recordings):
    path = recordings / "azure_kinect_recording.mkv"
    assert detect_format(path) == "mkv"
    calib = json.loads((recordings / "azure_kinect_calibration.json").read_text())
    depth_cam = next(
        c
        for c in calib["CalibrationInformation"]["Cameras"]
        if c["Purpose"] == "CALIBRATION_CameraPurposeDepth"
    )
    cx_n, cy_n, fx_n, fy_n = depth_cam["Intrinsics"]["ModelParameters"][:4]
    with open_frames(path) as reader:
        assert len(reader) == 1
        k = reader.intrinsics
        assert (k.width, k.height) == (640, 576)  # NFOV_UNBINNED
        assert k.fx == pytest.approx(fx_n * 1024)
        assert k.fy == pytest.approx(fy_n * 1024)
        assert k.cx == pytest.approx(cx_n * 1024 - 192 - 0.5)
        assert k.cy == pytest.approx(cy_n * 1024 - 180 - 0.5)
        assert reader.depth_unit_mm == 1.0
        frame = reader[0]
        assert frame.timestamp == pytest.approx(0.463945)
        assert any("distortion" in n and "removed" in n for n in reader.notes)
    assert frame.depth.dtype == np.float32
    assert 0.8 < np.isfinite(frame.depth).mean() < 0.95
    assert np.nanmin(frame.depth) > 150
    assert np.nanmax(frame.depth) < 4000
    assert frame.intensity.min() >= 0.0
    assert frame.intensity.max() <= 1.0
    raw = open_frames(path, undistort=False)
    with raw:
        d = raw[0].depth
    assert np.nanmax(d) == np.nanmax(frame.depth)  # nearest-neighbour resampling keeps values
    assert not np.array_equal(d, frame.depth, equal_nan=True)


@pytest.mark.realdata
def test_azure_kinect_ir_white_level_is_taken_before_undistortion(recordings):
    """Taken on the undistorted IR, whose bilinear remap blends saturated pixels (65535) into
    grey ones, the white level was 39384.8 instead of the raw IR's 13837.5 (27 % darker)."""
    from fuse4d.io._rosimage import amplitude_to_gray

    path = recordings / "azure_kinect_recording.mkv"
    with av.open(str(path)) as container:
        track = next(s for s in container.streams if s.metadata.get("title") == "IR")
        raw = next(container.decode(track)).to_ndarray()
    white = float(np.percentile(raw[(raw > 0) & (raw < 65535)], 99.5))
    assert white == pytest.approx(13837.5, abs=0.1)
    for undistort in (True, False):
        with open_frames(path, undistort=undistort) as reader:
            frame = reader[0]
            assert f"sqrt(IR / {white:g})" in "".join(reader.notes)
    np.testing.assert_allclose(frame.intensity, amplitude_to_gray(raw, white), atol=1e-6)


@pytest.mark.realdata
def test_azure_kinect_ir_keeps_the_far_scene_trackable(recordings):
    """ToF IR is shown as sqrt(IR / white): divided linearly by the white level that a mug at
    25 cm sets, the 1.5-2 m background sat at a median of 0.0086 (about 2 gray levels). A
    known ~1 px shift of the frame is tracked on that background far better (DIS)."""
    import cv2

    from fuse4d.flow import estimate_flow

    with open_frames(recordings / "azure_kinect_recording.mkv") as reader:
        frame = reader[0]
        assert any("sqrt(IR" in n for n in reader.notes)
    gray, depth = frame.intensity, frame.depth
    background = np.isfinite(depth) & (depth > 1000) & (gray > 0)
    assert np.median(gray[background] ** 2) < 0.02  # the linear mapping: about 2 gray levels
    assert np.median(gray[background]) > 0.06  # about 19
    h, w = gray.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = np.float32(0.8), np.float32(-0.5)
    fov = cv2.erode((gray > 0).astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    inside = background & fov
    errors = {}
    for name, image in (("sqrt", gray), ("linear", gray**2)):
        moved = cv2.remap(image, xx - u, yy - v, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        flow = estimate_flow(image, moved)
        errors[name] = float(np.hypot(flow[..., 0] - u, flow[..., 1] - v)[inside].mean())
    assert errors["sqrt"] < 0.5 * errors["linear"], errors


def test_amplitude_to_gray_is_the_square_root_of_the_scaled_amplitude():
    from fuse4d.io._rosimage import amplitude_to_gray

    ir = np.array([[0, 100, 400], [1600, 3000, 65535]], dtype=np.uint16)
    gray = amplitude_to_gray(ir, 1600.0)
    assert gray.dtype == np.float32
    np.testing.assert_allclose(gray, [[0, 0.25, 0.5], [1, 1, 1]], atol=1e-7)


def test_tof_bag_ir_is_square_rooted(tmp_path):
    """A 16-bit IR topic of a time-of-flight RealSense (L515) gets the ToF mapping; of another
    camera, the linear white level."""
    path = write_generic_bag(tmp_path / "a.bag", "ros1")
    img = np.array([[0, 100, 400, 1600, 2000]], dtype=np.uint16)
    with open_frames(path) as reader:
        linear = reader._normalise(img, 0)
    with open_frames(path) as reader:
        reader.sensor = "tof"
        tof = reader._normalise(img, 0)
        assert any("square root" in n for n in reader.notes)
    np.testing.assert_allclose(tof, np.sqrt(linear), atol=1e-7)
    assert linear[0, 2] < 0.3 < tof[0, 2]


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["azure_kinect_recording.mkv", "rs2551_swdev_5f.bag"])
@pytest.mark.parametrize("unit", ["-1", "0", "1e-30", "nan"])
def test_sensor_readers_refuse_a_bad_depth_unit(recordings, capsys, name, unit):
    """-1 gave negative depth from an .mkv; a bag raised a plain ValueError (exit 70)."""
    code, _, err = _run(["info", recordings / name, f"--depth-unit-mm={unit}"], capsys)
    assert code == 2
    assert "depth_unit_mm must be in [1e-06, 10000] mm" in err


@pytest.mark.realdata
def test_bag_reader_refuses_an_unknown_intensity_choice(recordings, capsys):
    code, _, err = _run(["info", recordings / "rs2551_swdev_5f.bag", "--intensity", "IR"], capsys)
    assert code == 2
    assert "intensity must be one of auto, ir, color, got 'IR'" in err


@pytest.mark.realdata
def test_k4a_modes_table(recordings):
    calib = json.loads((recordings / "azure_kinect_calibration.json").read_text())
    sizes = {}
    for mode in ("NFOV_2X2BINNED", "NFOV_UNBINNED", "WFOV_2X2BINNED", "WFOV_UNBINNED"):
        cam, dist = k4a_depth_camera(calib, mode, path=Path("x"))
        sizes[mode] = (cam.width, cam.height)
        assert dist.shape == (8,)
    assert sizes == {"NFOV_2X2BINNED": (320, 288), "NFOV_UNBINNED": (640, 576),
                     "WFOV_2X2BINNED": (512, 512), "WFOV_UNBINNED": (1024, 1024)}  # fmt: skip


@pytest.mark.realdata
def test_mkv_without_calibration(recordings, tmp_path, capsys):
    data = (recordings / "azure_kinect_recording.mkv").read_bytes()
    bad = tmp_path / "nocal.mkv"
    bad.write_bytes(data.replace(b"calibration.json", b"calibration.txt_"))
    out = tmp_path / "out"
    code, _, err = _run(["run", bad, "-o", out], capsys)
    assert code == 2
    assert f"{bad}: no calibration.json attachment" in err
    assert "--intrinsics" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nocal.mkv"]
    with open_frames(bad, intrinsics="500,500,320,288") as reader:
        assert reader.intrinsics.fx == 500.0


@pytest.mark.realdata
@pytest.mark.parametrize(
    "name",
    ["realsense_legacy_single_depth_color_640x480.bag", "rs2551_swdev_5f.bag",
     "rs2591_swdev_5f_compressed.db3", "azure_kinect_recording.mkv"],
)  # fmt: skip
def test_info_lists_streams(recordings, name, capsys):
    code, out, _ = _run(["info", recordings / name, "--json"], capsys)
    assert code == 0
    summary = json.loads(out)
    used = {s["used_as"]: s for s in summary["streams"] if s["used_as"]}
    assert set(used) == {"depth", "intensity"}
    assert used["depth"]["width"] == summary["width"]
    assert summary["depth_unit_mm"] is not None
    assert summary["fps"] > 0
    assert any(n.startswith("intrinsics:") for n in summary["notes"])


# ----------------------------------------------------------------- generic bags
@pytest.mark.parametrize(
    ("kind", "options"),
    [
        ("ros1", {}),
        ("ros2", {}),
        ("mcap", {}),
        ("ros2", {"compressed": "png"}),
        ("ros1", {"compressed": "rvl"}),
        ("ros2", {"encoding": "32FC1"}),
    ],
)
def test_generic_bag(tmp_path, kind, options):
    name = "rec.bag" if kind == "ros1" else "rec"
    path = write_generic_bag(tmp_path / name, kind, **options)
    want = depth_frames(4).astype(np.float32)
    want[want == 0] = np.nan
    seq = load_sequence(path)
    np.testing.assert_allclose(seq.depth, want, rtol=1e-6)
    np.testing.assert_allclose(seq.intensity, ir_frames(4) / 255.0, atol=1e-6)
    assert tuple(seq.intrinsics.as_array()) == K
    assert seq.fps == pytest.approx(30.0, rel=1e-4)
    assert seq.timestamps[0] == pytest.approx(1.7e9)


def test_rosbag2_folder_and_magic_detection(tmp_path):
    path = write_generic_bag(tmp_path / "rec", "ros2")
    assert detect_format(tmp_path / "rec") == "rosbag"  # folder with metadata.yaml
    other = tmp_path / "recording.bin"
    other.symlink_to(path)  # no telling extension: magic bytes decide
    assert detect_format(other) == "rosbag"
    assert load_sequence(other).num_frames == 4


def test_mono16_needs_unit(tmp_path, capsys):
    path = write_generic_bag(tmp_path / "rec", "ros2", encoding="mono16")
    code, _, err = _run(["info", path], capsys)
    assert code == 2
    assert "does not say its depth unit" in err
    assert DEPTH_TOPIC in err
    seq = load_sequence(path, depth_unit_mm=0.1)
    assert np.nanmax(seq.depth[0]) == pytest.approx(0.1 * (1000 + 31))


def test_topic_overrides(tmp_path, capsys):
    path = write_generic_bag(tmp_path / "rec", "ros2")
    with open_frames(path, depth_topic=DEPTH_TOPIC, intensity_topic=IR_TOPIC) as reader:
        assert len(reader) == 4
    code, _, err = _run(["info", path, "--depth-topic", "/nope/depth"], capsys)
    assert code == 2
    assert f"{path}: no depth topic /nope/depth in the bag" in err
    assert DEPTH_TOPIC in err
    code, _, err = _run(["info", path, "--depth-topic", IR_TOPIC], capsys)
    assert code == 2
    assert "not depth images" in err
    with pytest.raises(ValueError, match="does not apply to npz"):
        open_frames(tmp_path / "x.npz", format="npz", depth_topic="/a")


def test_bag_without_depth(tmp_path, capsys):
    path = write_generic_bag(tmp_path / "rec", "ros2", with_depth=False)
    out = tmp_path / "out"
    code, _, err = _run(["run", path, "-o", out], capsys)
    assert code == 2
    assert f"{path}: no depth topic" in err
    assert IR_TOPIC in err
    assert "--depth-topic" in err
    assert "Traceback" not in err
    assert not out.exists()


def test_bag_without_camera_info(tmp_path, capsys):
    path = write_generic_bag(tmp_path / "rec", "ros1", with_info=False)
    code, _, err = _run(["info", path], capsys)
    assert code == 2
    assert "no camera_info" in err
    assert "--intrinsics" in err
    assert load_sequence(path, intrinsics="60,61,15.5,11.5").num_frames == 4


def test_mismatched_resolution(tmp_path, capsys):
    path = write_generic_bag(tmp_path / "rec.bag", "ros1", ir_size=(12, 16))
    out = tmp_path / "out.zarr"
    code, _, err = _run(["run", path, "-o", out], capsys)
    assert code == 2
    assert f"intensity topic {IR_TOPIC} is 16x12 but depth topic {DEPTH_TOPIC} is 32x24" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.bag"]


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_truncated_bag(tmp_path, kind, capsys):
    path = write_generic_bag(tmp_path / ("rec.bag" if kind == "ros1" else "rec"), kind)
    data = path.read_bytes()
    bad = tmp_path / ("cut.bag" if kind == "ros1" else "cut.db3")
    bad.write_bytes(data[: len(data) // 2])
    code, _, err = _run(["run", bad, "-o", tmp_path / "out.mkv"], capsys)
    assert code == 2
    assert str(bad) in err
    assert "truncated or corrupt" in err
    assert "Traceback" not in err
    assert not (tmp_path / "out.mkv").exists()


def test_db3_cut_near_its_end_is_an_input_error(tmp_path):
    """A .db3 that opens but whose last pages are gone fails while walking the messages, in
    apsw (which rosbags reads SQLite through), not in sqlite3: still a clear InputFileError."""
    data = write_generic_bag(tmp_path / "rec", "ros2", frames=8).read_bytes()
    bad = tmp_path / "cut.db3"
    errors = []
    for cut in range(len(data) - 8192, len(data), 512):
        bad.write_bytes(data[:cut])
        try:
            load_sequence(bad)
        except InputFileError as exc:
            errors.append(str(exc))
    assert all(e.startswith(f"{bad}: cannot ") for e in errors)
    assert all("(truncated or corrupt: " in e for e in errors)
    assert any("cannot read messages" in e for e in errors)


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_16bit_bag_ir_white_level_is_frame_0s_whatever_is_read(tmp_path, capsys, kind):
    """The white level was the first frame decoded's: frame 4 of a bag whose IR brightens was
    0.97 in a whole conversion but 0.55 with --frames 4:6 (or export-ply --frame 4)."""
    from fuse4d.io._rosimage import normalise_intensity, white_level
    from rosbag_factory import INFO_TOPIC, BagWriter

    d, ir = depth_frames(6), _brightening_ir(6)
    path = tmp_path / ("ir.bag" if kind == "ros1" else "ir")
    t0, period = 10**18, 33_333_333
    with BagWriter(path, kind) as bag:  # an unpaired, saturated IR image before frame 0's
        bag.write(IR_TOPIC, bag.image(np.full_like(ir[0], 60000), "mono16", t0 - 10**9), t0 - 10**9)
        for k in range(6):
            t = t0 + k * period
            bag.write(DEPTH_TOPIC, bag.image(d[k], "16UC1", t), t)
            bag.write(INFO_TOPIC, bag.camera_info(32, 24, t), t)
            bag.write(IR_TOPIC, bag.image(ir[k], "mono16", t + 1000), t + 1000)
    white = white_level(ir[0])
    with open_frames(path) as reader:
        whole = np.stack([f.intensity for f in reader])
    np.testing.assert_allclose(whole, normalise_intensity(ir, white), atol=1e-6)
    with open_frames(path) as reader:
        np.testing.assert_array_equal(reader[4].intensity, whole[4])
        np.testing.assert_array_equal(reader[2].intensity, whole[2])
        assert f"scaled by 1/{white:g} (99.5th percentile of the unsaturated pixels of frame 0" in (
            "".join(reader.notes)
        )
    with open_frames(path, frames="4:6") as part:
        np.testing.assert_array_equal(np.stack([f.intensity for f in part]), whole[4:])
    out = tmp_path / "part.npz"
    assert main(["convert", str(path), str(out), "--frames", "4:6"]) == 0
    np.testing.assert_array_equal(load_sequence(out).intensity, whole[4:])


def _float_ir_bag(path: Path, ir: np.ndarray) -> Path:
    """A ROS 1 bag of 16UC1 depth and 32FC1 IR ``ir`` (T, 24, 32)."""
    from rosbag_factory import INFO_TOPIC, BagWriter

    d, t0, period = depth_frames(len(ir)), 10**18, 33_333_333
    with BagWriter(path, "ros1") as bag:
        for k in range(len(ir)):
            t = t0 + k * period
            bag.write(DEPTH_TOPIC, bag.image(d[k], "16UC1", t), t)
            bag.write(INFO_TOPIC, bag.camera_info(32, 24, t), t)
            bag.write(IR_TOPIC, bag.image(ir[k].astype(np.float32), "32FC1", t + 1000), t + 1000)
    return path


def test_float_bag_ir_is_not_clipped_silently(tmp_path):
    """32FC1 IR in sensor units (0-255 floats) read as 99.6 % exactly 1: it is scaled by frame
    0's white level like 16-bit IR, with a note; NaN (no return) reads as 0; values left
    outside [0, 1] are refused naming the topic and frame."""
    ir = ir_frames(3).astype(np.float32)
    ir[1, 0, :2] = np.nan
    path = _float_ir_bag(tmp_path / "raw.bag", ir)
    white = float(np.percentile(ir[0][ir[0] > 0], 99.5))
    with open_frames(path) as reader:
        got = np.stack([f.intensity for f in reader])
        assert f"float intensity outside [0, 1] scaled by 1/{white:g}" in "".join(reader.notes)
    np.testing.assert_allclose(got, np.minimum(np.nan_to_num(ir) / white, 1), atol=1e-6)
    assert (got == 1).mean() < 0.05
    assert (got[1, 0, :2] == 0).all()

    unit = ir_frames(3).astype(np.float32) / 255  # already intensity: kept as is
    unit[2, 3, 4] = 1.5
    path = _float_ir_bag(tmp_path / "unit.bag", unit)
    with open_frames(path) as reader:
        np.testing.assert_allclose(reader[1].intensity, unit[1], atol=1e-7)
        assert "float intensity" not in "".join(reader.notes)
        with pytest.raises(
            InputFileError,
            match=rf"unit\.bag \(frame 2\): intensity topic {IR_TOPIC} must hold finite values "
            r"in \[0, 1\] \(1 above 1, up to 1\.5 found",
        ):
            reader[2]


def test_random_access_matches_streaming(tmp_path):
    path = write_generic_bag(tmp_path / "rec.bag", "ros1", frames=6)
    with open_frames(path) as reader:
        streamed = [f.depth for f in reader]
        for k in (4, 1, 5, 0, -1):
            np.testing.assert_array_equal(reader[k].depth, streamed[k], strict=True)
        assert [f.index for f in reader.iter_frames("2:4")] == [2, 3]
        with pytest.raises(IndexError):
            reader[6]


def test_pairing_skips_unmatched(tmp_path):
    from rosbag_factory import BagWriter

    d, ir = depth_frames(5), ir_frames(5)
    path = tmp_path / "rec"
    period = 33_333_333
    with BagWriter(path, "ros2") as bag:
        for k in range(5):
            t = 10**18 + k * period
            bag.write(DEPTH_TOPIC, bag.image(d[k], "16UC1", t), t)
            bag.write("/camera/depth/camera_info", bag.camera_info(32, 24, t), t)
            if k >= 3:  # IR starts late (1 ms early): frame 0 is ~3 periods from any IR frame
                bag.write(IR_TOPIC, bag.image(ir[k], "mono8", t - 10**6), t - 10**6)
    with open_frames(path) as reader:
        assert len(reader) == 4  # tolerance 2 periods: frame 0 skipped, frame 1 kept
        assert any("skipped" in n for n in reader.notes)
        np.testing.assert_allclose(reader[0].intensity, ir[3] / 255.0, atol=1e-6)


@pytest.mark.parametrize(("stamps", "prev"), [((0, 1, 1, 2), 1), ((0, 2, 1, 3), 2)])
def test_bag_refuses_depth_stamps_that_do_not_increase(tmp_path, capsys, stamps, prev):
    """A repeated or backwards depth header stamp is refused, naming the frame (it used to
    pair two depth frames with one IR frame and write times nothing could read back)."""
    from rosbag_factory import BagWriter

    d, ir = depth_frames(4), ir_frames(4)
    path = tmp_path / "rec"
    with BagWriter(path, "ros2") as bag:
        for k in range(4):
            t, stamp = 10**18 + k * 10**8, 10**18 + stamps[k] * 10**8
            bag.write(DEPTH_TOPIC, bag.image(d[k], "16UC1", stamp), t)
            bag.write("/camera/depth/camera_info", bag.camera_info(32, 24, t), t)
            bag.write(IR_TOPIC, bag.image(ir[k], "mono8", stamp), t + 1000)
    code, _, err = _run(["info", path], capsys)
    assert code == 2
    assert f"{path} (frame 2): depth topic {DEPTH_TOPIC}: header stamp" in err
    assert f"is not after frame 1's ({1e9 + prev / 10:.6f} s)" in err


# ----------------------------------------------------------------- RVL codec
def test_rvl_round_trip(rng):
    img = rng.integers(0, 65536, (30, 40), dtype=np.uint16)
    img[rng.random(img.shape) < 0.4] = 0
    img[:2] = 0
    img[-1, -5:] = [65535, 0, 1, 65535, 0]
    assert np.array_equal(decode_rvl(encode_rvl(img), 40, 30), img)
    zeros = np.zeros((3, 5), np.uint16)
    assert np.array_equal(decode_rvl(encode_rvl(zeros), 5, 3), zeros)
    with pytest.raises(ValueError, match="truncated"):
        decode_rvl(encode_rvl(img)[:100], 40, 30)


def test_rvl_decode_runs_and_errors(rng):
    """The decoder's phases: zero runs, empty nonzero runs, a run ending at the last pixel;
    a stream for a larger image is corrupt for a smaller one."""
    img = np.zeros((4, 6), np.uint16)
    img[0, 5] = img[1, 0] = 7  # a nonzero run across a row end
    img[3, 3:] = [1, 65535, 2]  # wraps around 16 bits, ends at the last pixel
    assert np.array_equal(decode_rvl(encode_rvl(img), 6, 4), img)
    full = rng.integers(1, 65536, (3, 5), dtype=np.uint16)  # no zero at all
    assert np.array_equal(decode_rvl(encode_rvl(full), 5, 3), full)
    with pytest.raises(ValueError, match="corrupt"):
        decode_rvl(encode_rvl(full), 4, 3)


# ----------------------------------------------------------------- writers
@pytest.fixture
def float_sequence(rng) -> Sequence:
    k = Intrinsics(50.0, 51.0, 15.5, 11.5, width=32, height=24)
    depth = rng.uniform(300, 5000, (3, 24, 32)).astype(np.float32)
    depth[:, 0, :4] = np.nan
    intensity = rng.random((3, 24, 32)).astype(np.float32)
    ts = np.array([5.0, 5.0333, 5.0667])
    return Sequence(depth, intensity, k, timestamps=ts, fps=30.0)


@pytest.mark.parametrize(
    ("fps", "period_s", "frames"),
    [(29.97, 1 / 29.97, 600), (30.0, 0.01, 8), (None, 0.0505, 5)],
    ids=["ntsc", "100Hz-stated-30", "no-fps"],
)
def test_ffv1_keeps_timestamps_to_the_ms(tmp_path, fps, period_s, frames):
    """The encoder's time base was 1/round(fps): ms pts were snapped onto a 1/30 s grid, so
    29.97 fps frames collided (frame 487 'missing' on reading back) and 100 Hz ones all did
    (frame 0 missing); 50 ms steps came back as 67/33 ms."""
    k = Intrinsics(20.0, 20.0, 7.5, 7.5, width=16, height=16)
    ts = 5.0 + np.arange(frames) * period_s
    seq = Sequence(
        np.full((frames, 16, 16), 1000.0, np.float32),
        np.full((frames, 16, 16), 0.5, np.float32),
        k,
        timestamps=ts,
        fps=fps,
    )
    back = load_sequence(save_sequence(seq, tmp_path / "t.mkv"))
    assert back.num_frames == frames
    np.testing.assert_allclose(back.timestamps, ts, atol=5e-4)


def test_ffv1_round_trip_bit_exact(tmp_path, float_sequence):
    seq = float_sequence
    units = np.round(np.nan_to_num(seq.depth, nan=0.0)).astype(np.uint16)
    exact = seq.with_depth(np.where(units > 0, units, np.nan).astype(np.float32))
    path = save_sequence(exact, tmp_path / "d.mkv")
    assert detect_format(path) == "mkv"
    back = load_sequence(path)
    np.testing.assert_array_equal(back.depth, exact.depth)  # lossless 16-bit
    np.testing.assert_allclose(back.intensity, seq.intensity, atol=0.5 / 65535 + 1e-7)
    assert back.intrinsics == seq.intrinsics
    assert back.fps == 30.0
    np.testing.assert_allclose(back.timestamps, seq.timestamps, atol=5e-4)  # 1 ms pts
    with av.open(str(path)) as container:
        codecs = {s.codec_context.name for s in container.streams.video}
        fmts = {s.codec_context.pix_fmt for s in container.streams.video}
    assert codecs == {"ffv1"}
    assert fmts == {"gray16le"}
    with open_frames(path) as reader:  # random access (seek) as well as streaming
        for k in (2, 0, 1, -1):
            np.testing.assert_array_equal(reader[k].depth, exact.depth[k])


def test_ffv1_unit(tmp_path, float_sequence):
    path = tmp_path / "d.mkv"
    with DepthVideoWriter(path, float_sequence.intrinsics, depth_unit_mm=0.25) as w:
        w.write(np.full((24, 32), 1000.25, np.float32), np.zeros((24, 32), np.float32))
    with open_frames(path) as reader:
        assert reader.depth_unit_mm == 0.25
        assert reader[0].depth[0, 0] == 1000.25


@pytest.mark.parametrize("fps", [None, 15.0])
def test_ffv1_of_frames_without_times_reads_back_without_times(tmp_path, float_sequence, fps):
    """The writer makes pts up for frames without timestamps; they used to come back as
    timestamps (and a 29.85 fps measured from them)."""
    seq = Sequence(float_sequence.depth, float_sequence.intensity, float_sequence.intrinsics,
                   fps=fps)  # fmt: skip
    back = load_sequence(save_sequence(seq, tmp_path / "d.mkv"))
    assert back.num_frames == 3
    assert back.timestamps is None
    assert back.fps == fps


def _k4a_like_mkv(
    path: Path, depth_pts: list[int], ir_pts: list[int], ir: np.ndarray | None = None
) -> Path:
    """A tiny DEPTH + IR Matroska (pts in ms) read as an Azure Kinect recording; IR frames
    ``ir`` (uint16, one per IR pts; default 1000 everywhere)."""
    from fractions import Fraction

    with av.open(str(path), "w", format="matroska") as out:
        streams = []
        for title in ("DEPTH", "IR"):  # all tracks before the first packet (the header)
            s = out.add_stream("ffv1", rate=30)
            s.width, s.height, s.pix_fmt = 32, 24, "gray16le"
            s.metadata["title"] = title
            s.time_base = Fraction(1, 1000)
            streams.append(s)
        for s, pts, images in zip(streams, (depth_pts, ir_pts), (None, ir), strict=True):
            for j, p in enumerate(pts):
                image = np.full((24, 32), 1000, "<u2") if images is None else images[j]
                fr = av.VideoFrame.from_ndarray(image.astype("<u2"), format="gray16le")
                fr.pts, fr.time_base = p, s.time_base
                for packet in s.encode(fr):
                    out.mux(packet)
            for packet in s.encode():
                out.mux(packet)
    return path


def test_mkv_pts_pairing_problems_are_named(tmp_path):
    """A repeated DEPTH pts was 'frame 0: frame missing (truncated file?)'; an IR track that
    ends early, or no IR frame at all, said nothing or 'no ... equal pts'; unpaired frames
    were dropped silently."""
    spec = "50,50,15.5,11.5"
    path = _k4a_like_mkv(tmp_path / "dup.mkv", [100, 133, 133, 167], [100, 133, 167, 200])
    with pytest.raises(
        InputFileError, match=r"dup\.mkv \(frame 2\): DEPTH track: pts 0\.133000 s is not after"
    ):
        open_frames(path, intrinsics=spec)
    path = _k4a_like_mkv(tmp_path / "short.mkv", [100, 133, 167, 200], [100, 133, 167])
    with open_frames(path, intrinsics=spec) as reader:
        assert len(reader) == 3
        assert "the IR track ends before the DEPTH track (truncated file?): the last 1 " in "".join(
            reader.notes
        )
    path = _k4a_like_mkv(tmp_path / "gap.mkv", [100, 133, 167, 200], [100, 167, 200])
    with open_frames(path, intrinsics=spec) as reader:
        assert [f.timestamp for f in reader] == [0.1, 0.167, 0.2]
        assert "1 DEPTH frames without an IR frame of equal pts skipped" in reader.notes
    path = _k4a_like_mkv(tmp_path / "noir.mkv", [100, 133], [])
    with pytest.raises(InputFileError, match=r"noir\.mkv: the IR track holds no frame"):
        open_frames(path, intrinsics=spec)


def _brightening_ir(frames: int) -> np.ndarray:
    """uint16 IR (T, 24, 32) that gets brighter every frame (frame k: about k + 1 times 0's)."""
    rng = np.random.default_rng(3)
    return np.stack(
        [(rng.uniform(100, 1000, (24, 32)) * (1 + k)).astype(np.uint16) for k in range(frames)]
    )


def test_mkv_ir_white_level_is_frame_0s_whatever_is_read(tmp_path):
    """The white level was the first frame decoded's: frame 3 read on its own, or in a part
    3:5, came out darker than in a whole read (another level per part, per dask worker)."""
    from fuse4d.io._rosimage import amplitude_to_gray, white_level

    ir = _brightening_ir(5)
    pts = [100, 133, 167, 200, 233]
    path = _k4a_like_mkv(tmp_path / "ir.mkv", pts, pts, ir=ir)
    spec = "50,50,15.5,11.5"
    white = white_level(ir[0])
    with open_frames(path, intrinsics=spec) as reader:
        whole = np.stack([f.intensity for f in reader])
    np.testing.assert_allclose(whole, amplitude_to_gray(ir, white), atol=1e-6)
    with open_frames(path, intrinsics=spec) as reader:
        np.testing.assert_array_equal(reader[3].intensity, whole[3])
        np.testing.assert_array_equal(reader[1].intensity, whole[1])
        assert f"sqrt(IR / {white:g}) (99.5th percentile of frame 0's raw IR" in "".join(
            reader.notes
        )
    with open_frames(path, intrinsics=spec, frames="3:5") as part:
        np.testing.assert_array_equal(np.stack([f.intensity for f in part]), whole[3:])


def test_zarr_round_trip(tmp_path, float_sequence):
    seq = float_sequence
    path = save_sequence(seq, tmp_path / "s.zarr")
    assert detect_format(path) == "zarr"
    back = load_sequence(path)
    np.testing.assert_array_equal(back.depth, seq.depth)
    np.testing.assert_array_equal(back.intensity, seq.intensity)
    np.testing.assert_array_equal(back.timestamps, seq.timestamps)
    assert back.intrinsics == seq.intrinsics
    assert back.fps == 30.0
    group = zarr.open_group(str(path), mode="r")
    assert group["depth"].metadata.dimension_names == ("t", "y", "x")
    assert group["depth"].chunks == (1, 24, 32)
    assert [c.cname.value for c in group["depth"].compressors] == ["lz4"]  # as --engine dask
    assert group.attrs["depth_unit"] == "mm"
    assert group.attrs["intrinsics"]["fx"] == 50.0


def test_truncated_mkv_warns_instead_of_reading_as_a_shorter_recording(tmp_path, rng):
    k = Intrinsics(50.0, 51.0, 15.5, 11.5, width=32, height=24)
    seq = Sequence(
        rng.uniform(300, 5000, (12, 24, 32)).astype(np.float32),
        rng.random((12, 24, 32)).astype(np.float32),
        k,
        fps=30.0,
    )
    path = save_sequence(seq, tmp_path / "d.mkv")
    assert len(load_sequence(path).depth) == 12  # whole: no warning (they are errors here)
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with (
        pytest.warns(UserWarning, match=r"cut\.mkv: the frames end at .* header says 0\.4"),
        open_frames(cut) as reader,
    ):
        assert 0 < len(reader) < 12


def test_zarr_damaged_chunk_names_store_and_frame(tmp_path, float_sequence):
    """A truncated chunk raised blosc's RuntimeError (exit 70, 'a bug in fuse4d')."""
    path = save_sequence(float_sequence, tmp_path / "s.zarr")
    chunk = path / "depth" / "c" / "1" / "0" / "0"
    chunk.write_bytes(chunk.read_bytes()[:40])
    with pytest.raises(InputFileError, match=r"s\.zarr \(frame 1\): cannot read chunk"):
        load_sequence(path)


@pytest.mark.parametrize(
    ("timestamps", "problem"),
    [
        ([0.0, 0.1], "'timestamps' has 2 values for 3 frames"),
        ([0.0, 0.1, 0.1], "'timestamps' must be strictly increasing"),
        ([0.0, np.nan, 0.2], "'timestamps' holds NaN or inf"),
    ],
)
def test_zarr_bad_timestamps_are_refused_at_open(tmp_path, float_sequence, timestamps, problem):
    """Checked as the npz reader checks them (a short array was an IndexError at frame 2)."""
    path = save_sequence(float_sequence, tmp_path / "s.zarr")
    group = zarr.open_group(str(path), mode="r+")
    group.create_array("timestamps", data=np.array(timestamps), overwrite=True)
    with pytest.raises(InputFileError, match=rf"s\.zarr: {problem}"):
        open_frames(path)


@pytest.mark.parametrize("fps", ["fast", -30.0, 0, True])
def test_zarr_fps_attribute_is_checked(tmp_path, float_sequence, fps):
    """A non-numeric rate was an internal ValueError, a negative one was accepted."""
    path = save_sequence(float_sequence, tmp_path / "s.zarr")
    zarr.open_group(str(path), mode="r+").attrs["fps"] = fps
    with pytest.raises(InputFileError, match=r"attribute 'fps' must be a number > 0, got "):
        open_frames(path)


def test_zarr_without_intrinsics_says_so_once(tmp_path, float_sequence):
    path = save_sequence(float_sequence, tmp_path / "s.zarr")
    group = zarr.open_group(str(path), mode="r+")
    del group.attrs["intrinsics"]
    with pytest.raises(InputFileError) as exc:
        open_frames(path)
    assert str(exc.value) == f"{path}: no 'intrinsics' attribute; pass --intrinsics"


def test_zarr_intrinsics_attribute_size_and_list(tmp_path, float_sequence):
    """A camera for another image size was read as is (principal point outside the 32x24
    image); a [fx, fy, cx, cy] list was taken for a missing attribute."""
    path = save_sequence(float_sequence, tmp_path / "s.zarr")
    group = zarr.open_group(str(path), mode="r+")
    cam = {"fx": 525, "fy": 525, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480}
    group.attrs["intrinsics"] = cam
    with pytest.raises(
        InputFileError,
        match=r"s\.zarr: attribute 'intrinsics': camera size 640x480 does not match the 32x24 "
        r"frames \(WxH\)",
    ):
        open_frames(path)
    group.attrs["intrinsics"] = {**cam, "width": 32, "height": 24}
    with open_frames(path) as reader:
        assert reader.intrinsics == Intrinsics(525, 525, 319.5, 239.5, width=32, height=24)
    group.attrs["intrinsics"] = [50.0, 51.0, 15.5, 11.5]
    with open_frames(path) as reader:
        assert reader.intrinsics == Intrinsics(50.0, 51.0, 15.5, 11.5, width=32, height=24)
    group.attrs["intrinsics"] = [50.0, 51.0, 15.5]
    with pytest.raises(InputFileError, match=r"bad 'intrinsics' attribute \(.*4 numbers.*\); "):
        open_frames(path)
    group.attrs["intrinsics"] = {"fx": 50.0}
    with pytest.raises(InputFileError) as exc:
        open_frames(path)
    assert str(exc.value).endswith(
        "bad 'intrinsics' attribute ('fy'); it must be {fx, fy, cx, cy, width, height} (px; "
        "width and height optional) or [fx, fy, cx, cy]"
    )


def test_zarr_v2_store_is_read(tmp_path, float_sequence):
    """A zarr v2 group (.zgroup, no zarr.json) was 'no depth frames found'."""
    seq = float_sequence
    path = tmp_path / "v2.zarr"
    group = zarr.open_group(str(path), mode="w", zarr_format=2)
    group.create_array("depth", data=seq.depth, chunks=(1, 24, 32))
    group.create_array("intensity", data=seq.intensity, chunks=(1, 24, 32))
    group.attrs.update({"intrinsics": seq.intrinsics.to_dict(), "fps": 30.0})
    assert detect_format(path) == "zarr"
    back = load_sequence(path)
    np.testing.assert_array_equal(back.depth, seq.depth)
    np.testing.assert_array_equal(back.intensity, seq.intensity)
    assert back.intrinsics == seq.intrinsics
    with open_frames(path) as reader:
        assert reader.notes[0].startswith("zarr v2 store")
    lone = tmp_path / "lone.zarr"  # an array, not a group
    zarr.open_array(str(lone), mode="w", shape=(3,), dtype="f4", zarr_format=2)
    with pytest.raises(InputFileError, match=r"lone\.zarr: cannot open the zarr store"):
        open_frames(lone)


@pytest.mark.parametrize(
    ("dtype", "values"), [("uint32", (0, 248)), ("int16", (-3, 200)), ("int8", (0, 100))]
)
def test_zarr_integer_intensity_other_than_uint8_uint16_is_refused(
    tmp_path, float_sequence, dtype, values
):
    """uint32 0-248 was divided by 2**32-1 (black); int16 with negative values was refused by a
    later check naming no frame."""
    path = save_sequence(float_sequence, tmp_path / "s.zarr")
    group = zarr.open_group(str(path), mode="r+")
    gray = np.full(float_sequence.intensity.shape, values[1], dtype=dtype)
    gray[1, 0, 0] = values[0]
    group.create_array("intensity", data=gray, chunks=(1, 24, 32), overwrite=True)
    with pytest.raises(
        InputFileError,
        match=rf"s\.zarr \(frame 0\): 'intensity' has integer dtype {dtype}, .*store uint8",
    ):
        load_sequence(path)
    group.create_array("intensity", data=gray.astype(bool), chunks=(1, 24, 32), overwrite=True)
    assert load_sequence(path).intensity.max() == 1.0


def test_zarr_reader_sanitises_depth_and_checks_intensity(tmp_path, float_sequence):
    """Depth <= 0 is invalid (NaN) as in every reader; float intensity outside [0, 1] is
    refused naming the store and frame, integer intensity is scaled to [0, 1]."""
    path = save_sequence(float_sequence, tmp_path / "s.zarr")
    group = zarr.open_group(str(path), mode="r+")
    depth = float_sequence.depth.copy()
    depth[1, 5, :3] = [0.0, -5.0, np.inf]
    group["depth"][:] = depth
    frame = load_sequence(path).depth[1]
    assert np.isnan(frame[5, :3]).all()
    np.testing.assert_array_equal(frame[6], float_sequence.depth[1, 6])
    inten = float_sequence.intensity.copy()
    inten[2] *= 255
    group["intensity"][:] = inten
    with pytest.raises(InputFileError, match=r"s\.zarr \(frame 2\): 'intensity' must hold"):
        load_sequence(path)
    gray = np.round(float_sequence.intensity * 255).astype(np.uint8)
    group.create_array("intensity", data=gray, chunks=(1, 24, 32), overwrite=True)
    np.testing.assert_allclose(load_sequence(path).intensity, gray / 255, atol=1e-7)


@pytest.mark.parametrize("cls", [DepthVideoWriter, ZarrWriter])
def test_writers_atomic(tmp_path, float_sequence, cls):
    path = tmp_path / ("o.mkv" if cls is DepthVideoWriter else "o.zarr")
    k = float_sequence.intrinsics

    def write_bad_second_frame() -> None:
        with cls(path, k) as w:
            w.write(float_sequence.depth[0], float_sequence.intensity[0])
            w.write(np.zeros((2, 2)), np.zeros((2, 2)))

    with pytest.raises(ValueError, match="shape"):
        write_bad_second_frame()
    assert list(tmp_path.iterdir()) == []
    with cls(path, k) as w:
        w.write(float_sequence.depth[0], float_sequence.intensity[0])
    with pytest.raises(OutputExistsError):
        cls(path, k)


def test_run_refuses_to_overwrite_input(tmp_path, float_sequence, capsys):
    path = save_sequence(float_sequence, tmp_path / "s.mkv", depth_unit_mm=1.0)
    before = path.read_bytes()
    code, _, err = _run(["run", path, "-o", path, "--force"], capsys)
    assert code == 2
    assert "overwrite the input" in err
    assert path.read_bytes() == before


# ----------------------------------------------------------------- recording -> run -> read
@pytest.mark.parametrize(("kind", "out_name"), [("ros1", "out.mkv"), ("ros2", "out.zarr"),
                                                ("mcap", "out")])  # fmt: skip
def test_recording_run_read_back(tmp_path, kind, out_name, capsys):
    src = write_generic_bag(tmp_path / ("rec.bag" if kind == "ros1" else "rec"), kind, frames=5)
    out = tmp_path / out_name
    code, stdout, err = _run(["run", src, "-o", out, "--window", "3", "--json"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["input_format"] == "rosbag"
    assert (
        summary["output_format"]
        == {"out.mkv": "mkv", "out.zarr": "zarr", "out": "folder"}[out_name]
    )
    back = load_sequence(out)
    assert back.depth.shape == (5, 24, 32)
    assert tuple(back.intrinsics.as_array()) == K
    raw = load_sequence(src).depth
    valid = np.isfinite(raw)
    assert np.array_equal(np.isfinite(back.depth)[valid], valid[valid])
    assert np.nanmax(np.abs(back.depth - raw)) < 20.0  # fused, close to the input


@pytest.mark.realdata
def test_realsense_and_kinect_run(recordings, tmp_path, capsys):
    out = tmp_path / "rs.zarr"
    code, _, err = _run(["run", recordings / "rs2591_swdev_5f_compressed.db3", "-o", out], capsys)
    assert code == 0, err
    assert load_sequence(out).depth.shape == (5, 48, 64)
    out = tmp_path / "k4a.mkv"
    code, _, err = _run(["run", recordings / "azure_kinect_recording.mkv", "-o", out], capsys)
    assert code == 0, err
    back = load_sequence(out)
    assert back.depth.shape == (1, 576, 640)
    assert back.intrinsics.fx == pytest.approx(504.6076)
    assert back.sensor == "tof"  # a ToF output stays one (A36 on a later run); it was dropped
    folder = tmp_path / "k4a_folder"
    code, _, err = _run(
        ["run", recordings / "azure_kinect_recording.mkv", "-o", folder, "--no-summary"], capsys
    )
    assert code == 0, err
    assert load_sequence(folder).sensor == "tof"
    ply = tmp_path / "f.ply"
    code, _, err = _run(["export-ply", recordings / "rs2551_swdev_5f.bag", "-o", ply], capsys)
    assert code == 0
    assert ply.stat().st_size > 0


# ----------------------------------------------------------------- missing extras
def test_missing_extra_message(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "av", None)  # import av -> ImportError
    with pytest.raises(MissingDependencyError, match=r'pip install "fuse4d\[sensors\]"'):
        require("av", what="reading .mkv depth video")
    src = tmp_path / "v.mkv"
    src.write_bytes(b"\x1a\x45\xdf\xa3" + b"\0" * 60)
    code, _, err = _run(["info", src], capsys)
    assert code == 2
    assert 'pip install "fuse4d[sensors]"' in err


def test_not_a_bag(tmp_path):
    """A file named like a recording whose first bytes are not that says so (was "unknown
    file type (expected ... an .mkv ...)" for an .mkv)."""
    for name, says in (
        ("x.bag", "its name says a ROS 1 bag, its first bytes do not"),
        ("x.mkv", "its name says a Matroska video"),
        ("x.db3", "its name says a ROS 2 SQLite bag"),
    ):
        bad = tmp_path / name
        bad.write_bytes(b"hello")
        with pytest.raises(InputFileError, match=says):
            detect_format(bad)
    other = tmp_path / "x.dat"
    other.write_bytes(b"hello")
    with pytest.raises(InputFileError, match="unknown file type"):
        detect_format(other)


# ----------------------------------------------------------------- RealSense layout, synthetic
def _realsense_bag(path: Path, *, with_ir: bool, color_shift_m: float = 0.01) -> Path:
    """librealsense ROS 1 layout: Z16 depth (0.1 mm units), Infrared_1, a 2x larger colour."""
    from rosbag_factory import BagWriter

    h, w = 24, 32
    base = "/device_0/sensor_0"
    with BagWriter(path, "ros1") as bag:
        f32 = bag.ts.types["std_msgs/msg/Float32"]
        bag.write(f"{base}/option/Depth Units/value", f32(data=np.float32(1e-4)), 1)
        bag.write(f"{base}/Depth_0/info/camera_info", bag.camera_info(w, h, 1, K), 1)
        fx, fy, cx, cy = K
        color_k = (2 * fx, 2 * fy, 2 * cx + 0.5, 2 * cy + 0.5)
        bag.write("/device_0/sensor_1/Color_0/info/camera_info",
                  bag.camera_info(2 * w, 2 * h, 1, color_k), 1)  # fmt: skip
        tf = bag.ts.types["geometry_msgs/msg/Transform"]
        vec = bag.ts.types["geometry_msgs/msg/Vector3"]
        quat = bag.ts.types["geometry_msgs/msg/Quaternion"]
        bag.write(
            f"{base}/Depth_0/tf/0",
            tf(translation=vec(x=0.0, y=0.0, z=0.0), rotation=quat(x=0, y=0, z=0, w=1)),
            1,
        )
        bag.write("/device_0/sensor_1/Color_0/tf/0",
                  tf(translation=vec(x=color_shift_m, y=0.0, z=0.0),
                     rotation=quat(x=0, y=0, z=0, w=1)), 1)  # fmt: skip
        xc = np.arange(2 * w, dtype=np.float64)
        gray = np.broadcast_to(np.round(xc / (2 * w) * 255), (2 * h, 2 * w)).astype(np.uint8)
        color = np.repeat(gray[..., None], 3, axis=2)
        for k in range(3):
            t = 10**9 + k * 33_333_333
            depth = np.full((h, w), 10000, np.uint16)  # 1000 mm
            bag.write(f"{base}/Depth_0/image/data", bag.image(depth, "mono16", t), t)
            if with_ir:
                ir = np.full((h, w), 50 + k, np.uint8)
                bag.write(f"{base}/Infrared_1/image/data", bag.image(ir, "mono8", t), t)
                bag.write(f"{base}/Infrared_2/image/data", bag.image(ir * 0, "mono8", t), t)
            bag.write("/device_0/sensor_1/Color_0/image/data", bag.image(color, "rgb8", t), t)
    return path


def test_realsense_layout_ir_default(tmp_path):
    path = _realsense_bag(tmp_path / "rs.bag", with_ir=True)
    with open_frames(path) as reader:
        assert reader.realsense
        assert reader.depth_unit_mm == pytest.approx(0.1)
        assert reader._inten.topic == "/device_0/sensor_0/Infrared_1/image/data"
        frame = reader[2]
    assert np.all(frame.depth == 1000.0)
    np.testing.assert_allclose(frame.intensity, 52 / 255, atol=1e-7)


def test_realsense_color_alignment(tmp_path):
    """Colour 2x the depth size, 10 mm to the side: sampled where the depth pixel projects."""
    path = _realsense_bag(tmp_path / "rs.bag", with_ir=True)
    with open_frames(path, intensity="color") as reader:
        frame = reader[0]
        assert any("resampled onto the depth grid" in n for n in reader.notes)
    fx = K[0]
    u = np.arange(32, dtype=np.float64)
    # stream->reference extrinsics: x_colour = x_depth - 10 mm at Z = 1000 mm
    x_color = 2 * fx * ((u - K[2]) / fx * 1000.0 - 10.0) / 1000.0 + 2 * K[2] + 0.5
    want = (
        np.round(np.floor(x_color) / 64 * 255) / 255
        + (x_color % 1)
        * (np.round((np.floor(x_color) + 1) / 64 * 255) - np.round(np.floor(x_color) / 64 * 255))
        / 255
    )
    inside = (x_color >= 0) & (x_color < 63)
    np.testing.assert_allclose(frame.intensity[5, inside], want[inside], atol=2e-3)


@pytest.mark.realdata
def test_realsense_camera_name_gives_the_sensor_kind(recordings):
    """librealsense records the camera's name: a D435 is active stereo (so fuse4d's ToF
    flying-pixel removal stays off, A36); the software-device fixtures say nothing."""
    with open_frames(recordings / "realsense_legacy_single_depth_color_640x480.bag") as reader:
        assert reader.sensor == "active-stereo"
        assert "camera: Intel RealSense D435 (active-stereo)" in reader.notes
    with open_frames(recordings / "rs2551_swdev_5f.bag") as reader:
        assert reader.sensor is None


def test_realsense_sensor_kind_by_product_line():
    from fuse4d.io._realsense import realsense_sensor_kind

    assert realsense_sensor_kind("Intel RealSense D455") == "active-stereo"
    assert realsense_sensor_kind("Intel RealSense L515") == "tof"
    assert realsense_sensor_kind("Intel RealSense SR305") == "structured-light"
    assert realsense_sensor_kind("Software-Device") is None


def test_float_bag_ir_dark_first_frame_and_saturated_returns(tmp_path):
    """A float IR stream whose frame 0 has no return (an emitter warming up) took frame 0 as
    'intensity already in [0, 1]' and refused the 0-255 frames after it; a saturated +inf
    return in a [0, 1] stream was refused (it read as 1 before). The level is the first
    frame with a return, the same for a part read; +inf is 1; after an error the next
    frame reads."""
    ir = ir_frames(4).astype(np.float32)
    ir[0] = 0.0
    dark = _float_ir_bag(tmp_path / "dark.bag", ir)
    with open_frames(dark) as reader:
        whole = [reader[k].intensity for k in range(4)]
    with open_frames(dark, frames="2:4") as reader:
        part = [f.intensity for f in reader]
    assert whole[1].max() == 1.0
    assert np.array_equal(whole[2], part[0])
    assert np.array_equal(whole[3], part[1])
    unit = ir_frames(4).astype(np.float32) / 255
    unit[1, 0, 0] = np.inf
    unit[2, 0, 0] = -0.5  # still refused, naming the frame
    saturated = _float_ir_bag(tmp_path / "inf.bag", unit)
    with open_frames(saturated) as reader:
        assert reader[1].intensity[0, 0] == 1.0
        with pytest.raises(InputFileError, match=r"\(frame 2\)"):
            reader[2]
        assert reader[3].intensity.max() <= 1.0  # not 'message missing'
