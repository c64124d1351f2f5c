"""fuse4d.io: round trips of every writer, layouts, streaming, atomicity, PLY and .flo."""

from __future__ import annotations

import dataclasses
import json
import os
import stat
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from fuse4d import (
    InputFileError,
    Intrinsics,
    OutputExistsError,
    Sequence,
    depth_to_points,
)
from fuse4d.errors import ParameterError
from fuse4d.flow import read_flo, write_flo
from fuse4d.io import (
    CAMERA_PRESETS,
    FrameFolderWriter,
    NpzReader,
    associate_timestamps,
    check_output,
    count_frames,
    detect_format,
    iter_frames,
    load_sequence,
    open_frames,
    read_frame_folder,
    read_intensity_image,
    read_intrinsics,
    read_mask,
    read_mask_image,
    read_npz,
    read_npz_extra,
    read_ply,
    read_tum,
    resolve_frames,
    save_sequence,
    write_frame_folder,
    write_npz,
    write_ply,
)
from fuse4d.io._base import resolve_intrinsics
from fuse4d.sequence import GroundTruth


# ----------------------------------------------------------------------------- helpers
def _sequence_with_gt(seq: Sequence, rng: np.random.Generator) -> Sequence:
    t, h, w = seq.depth.shape
    depth = seq.depth.copy()
    depth[:, 0, 0] = np.nan  # some invalid pixels
    gt = GroundTruth(
        depth=np.full((t, h, w), 500.0, np.float32),
        mask=rng.random((t, h, w)) > 0.5,
        flow=rng.normal(0, 1, (t - 1, h, w, 2)).astype(np.float32),
        extra={"center_row": np.arange(t, dtype=np.float64), "radius": 140.0},
    )
    return Sequence(
        depth,
        seq.intensity,
        seq.intrinsics,
        timestamps=np.arange(t) / 30.0,
        fps=30.0,
        ground_truth=gt,
        name="ball",
    )


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _write_cv2_xml(folder: Path, seq: Sequence, *, masks: bool = True) -> None:
    folder.mkdir()
    for t in range(seq.num_frames):
        stem = f"{t:010d}"
        units = np.nan_to_num(np.round(seq.depth[t]), nan=0).astype(np.uint16)
        cv2.imwrite(str(folder / f"{stem}_depth.png"), units)
        gray = np.round(seq.intensity[t] * 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{stem}.png"), cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))
        if masks:
            cv2.imwrite(str(folder / f"{stem}_mask.png"), np.full_like(gray, 255 * (t % 2)))
        fs = cv2.FileStorage(str(folder / f"{stem}_camera.xml"), cv2.FILE_STORAGE_WRITE)
        fs.write("intrinsic", seq.intrinsics.matrix.astype(np.float32))
        fs.write("R", np.eye(3, dtype=np.float32))
        fs.release()


def _write_tum(folder: Path, seq: Sequence, *, rgb_offset: float = 0.01) -> None:
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for t in range(seq.num_frames):
        ts = 1305031102.0 + t / 30.0
        units = np.nan_to_num(np.round(seq.depth[t] * 5.0), nan=0).astype(np.uint16)
        cv2.imwrite(str(folder / f"depth/{ts:.6f}.png"), units)
        cv2.imwrite(
            str(folder / f"rgb/{ts + rgb_offset:.6f}.png"),
            np.round(seq.intensity[t] * 255).astype(np.uint8),
        )
        rgb_lines.append(f"{ts + rgb_offset:.6f} rgb/{ts + rgb_offset:.6f}.png")
        depth_lines.append(f"{ts:.6f} depth/{ts:.6f}.png")
    rgb_lines.append(f"{ts + 1.0:.6f} rgb/unmatched.png")  # no depth partner: ignored
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")


def _write_frames_json(folder: Path, seq: Sequence, *, extra_entries: int = 0) -> None:
    folder.mkdir()
    k = seq.intrinsics
    entries = []
    for t in range(seq.num_frames + extra_entries):
        if t < seq.num_frames:
            units = np.nan_to_num(np.round(seq.depth[t] / 0.2), nan=0).astype(np.uint16)
            cv2.imwrite(str(folder / f"frame_{t:05d}_depth.png"), units)
            gray = np.round(seq.intensity[t] * 255).astype(np.uint8)
            cv2.imwrite(
                str(folder / f"frame_{t:05d}_rgb.png"), cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
            )
        entries.append(
            {
                "info": {
                    "kcam": {"matrix": k.matrix.tolist(), "image_size": [k.width, k.height]},
                    "depth_scale": 0.0002,
                    "depth_bias": 0.0,
                    "timestamp": 33333 * t,
                },
                "depth_image": f"frame_{t:05d}_depth.png",
                "rgb_image": f"frame_{t:05d}_rgb.png",
            }
        )
    (folder / "frames.json").write_text(json.dumps({"root": entries}))


# ----------------------------------------------------------------------------- npz
def test_npz_round_trip_keeps_everything(tmp_path, small_sequence, rng):
    seq = _sequence_with_gt(small_sequence, rng)
    support = rng.random(seq.depth.shape).astype(np.float32)
    out = write_npz(seq, tmp_path / "s.npz", extra={"support": support})
    back = read_npz(out)
    np.testing.assert_array_equal(back.depth, seq.depth)  # NaN positions included
    np.testing.assert_array_equal(back.intensity, seq.intensity)
    assert back.intrinsics == seq.intrinsics
    np.testing.assert_array_equal(back.timestamps, seq.timestamps)
    assert back.fps == 30.0
    assert back.name == "ball"
    gt = back.ground_truth
    np.testing.assert_array_equal(gt.depth, seq.ground_truth.depth)
    np.testing.assert_array_equal(gt.mask, seq.ground_truth.mask)
    np.testing.assert_array_equal(gt.flow, seq.ground_truth.flow)
    np.testing.assert_array_equal(gt.extra["center_row"], np.arange(4.0))
    assert gt.extra["radius"] == 140.0
    np.testing.assert_array_equal(read_npz_extra(out)["support"], support)


def test_npz_frame_selection_slices_ground_truth(tmp_path, small_sequence, rng):
    seq = _sequence_with_gt(small_sequence, rng)
    path = write_npz(seq, tmp_path / "s.npz")
    part = load_sequence(path, frames="1:3")
    assert part.num_frames == 2
    np.testing.assert_array_equal(part.depth, seq.depth[1:3])
    assert part.ground_truth.flow.shape[0] == 1
    np.testing.assert_array_equal(part.ground_truth.flow, seq.ground_truth.flow[1:2])
    np.testing.assert_array_equal(part.ground_truth.extra["center_row"], [1.0, 2.0])
    np.testing.assert_array_equal(part.timestamps, seq.timestamps[1:3])


def test_npz_convert_cuts_per_pair_extra_arrays(tmp_path, small_sequence, rng):
    """A user array of length T - 1 (per pair) was kept whole in a 2-frame output (3 pairs)
    while flow_gt was cut; per-frame arrays are cut to the frames, others kept whole."""
    seq = _sequence_with_gt(small_sequence, rng)
    pairs, per_frame, other = np.arange(15.0).reshape(3, 5), np.arange(4.0), np.arange(7.0)
    path = write_npz(
        seq, tmp_path / "ex.npz", extra={"pairs": pairs, "per_frame": per_frame, "other": other}
    )
    out = tmp_path / "exc.npz"
    from fuse4d.io import convert_recording

    convert_recording(path, out, frames="1:3")  # `fuse4d convert ex.npz exc.npz --frames 1:3`
    extra = read_npz_extra(out)
    np.testing.assert_array_equal(extra["pairs"], pairs[1:2])
    np.testing.assert_array_equal(extra["per_frame"], per_frame[1:3])
    np.testing.assert_array_equal(extra["other"], other)
    assert read_npz(out).ground_truth.flow.shape[0] == 1


def test_npz_streaming_memmaps_uncompressed_and_matches_compressed(tmp_path, small_sequence):
    plain = write_npz(small_sequence, tmp_path / "a.npz")
    packed = write_npz(small_sequence, tmp_path / "b.npz", compress=True)
    with NpzReader(plain) as reader:
        assert isinstance(reader._array("depth"), np.memmap)
        frames = list(reader)
    assert [f.index for f in frames] == [0, 1, 2, 3]
    np.testing.assert_array_equal(np.stack([f.depth for f in frames]), small_sequence.depth)
    np.testing.assert_array_equal(read_npz(packed).depth, small_sequence.depth)
    assert packed.stat().st_size < plain.stat().st_size


def test_read_intensity_equals_the_frames_intensity(tmp_path, small_sequence):
    """The depth-free reads (the dask flow stage) of npz, folder, zarr, TUM, cv2-xml and
    frames-json."""
    from fuse4d.io import FrameReader, open_frames

    write_npz(small_sequence, tmp_path / "a.npz")
    save_sequence(small_sequence, tmp_path / "folder", format="folder", depth_unit_mm=0.01)
    save_sequence(small_sequence, tmp_path / "b.zarr")
    _write_tum(tmp_path / "tum", small_sequence)
    _write_cv2_xml(tmp_path / "xml", small_sequence)
    _write_frames_json(tmp_path / "json", small_sequence)
    paths = ("a.npz", "folder", "b.zarr", "tum", "xml", "json")
    for path in paths:
        options = {"intrinsics": small_sequence.intrinsics} if path == "tum" else {}
        with open_frames(tmp_path / path, **options) as reader:
            # each layout has its own (the base class's default decodes the depth too)
            assert type(reader).read_intensity is not FrameReader.read_intensity, path
            for k in (0, 3, -1):
                alone = reader.read_intensity(k)
                assert alone.dtype == np.float32
                np.testing.assert_array_equal(alone, reader.read_frame(k).intensity)


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="needs Linux /proc")
def test_npz_streaming_resident_memory_does_not_grow_with_frames_read(tmp_path):
    """Frames read through the memory map are released again: reading a 100 MB recording
    frame by frame leaves the reader's resident set flat (it used to grow by the whole file,
    and then by the pages that Linux's fault-around maps before each frame: ≈ 10 MiB here)."""
    t, h, w = 200, 256, 256
    depth = np.full((t, h, w), 1000.0, np.float32)
    intensity = np.full((t, h, w), 0.5, np.float32)
    path = tmp_path / "long.npz"
    np.savez(path, depth=depth, intensity=intensity, intrinsics=np.array([200.0, 200, 128, 128]))
    del depth, intensity

    def resident_mib() -> float:
        return int(Path("/proc/self/statm").read_text().split()[1]) * 4096 / 2**20

    with open_frames(path) as reader:
        reader.read_frame(0)
        before = resident_mib()
        for frame in reader:
            assert frame.depth[0, 0] == 1000.0
        grown = resident_mib() - before
    assert grown < 3.0, f"resident set grew by {grown:.0f} MiB reading 100 MiB of frames"


def test_npz_extra_key_reserved(tmp_path, small_sequence):
    with pytest.raises(ValueError, match="extra key 'depth' is reserved"):
        write_npz(small_sequence, tmp_path / "s.npz", extra={"depth": small_sequence.depth})
    assert not (tmp_path / "s.npz").exists()


# ----------------------------------------------------------------------------- frame folder
def test_folder_round_trip_fine_unit(tmp_path, small_sequence, rng):
    seq = _sequence_with_gt(small_sequence, rng)
    with pytest.warns(UserWarning, match=r"does not store ground-truth depth, flow"):
        out = write_frame_folder(seq, tmp_path / "seq", depth_unit_mm=0.01)
    assert _listing(out) == ["camera.json", "depth", "intensity", "mask", "timestamps.txt"]
    assert _listing(out / "depth")[:2] == ["000000.png", "000001.png"]
    cam = json.loads((out / "camera.json").read_text())
    assert cam["depth_unit_mm"] == 0.01
    assert cam["fx"] == 80.0
    assert cam["fps"] == 30.0
    back = read_frame_folder(out)
    assert np.array_equal(np.isnan(back.depth), np.isnan(seq.depth))
    np.testing.assert_allclose(back.depth, seq.depth, atol=0.005 + 1e-4)
    np.testing.assert_allclose(back.intensity, seq.intensity, atol=0.5 / 65535 + 1e-7)
    np.testing.assert_array_equal(back.ground_truth.mask, seq.ground_truth.mask)
    np.testing.assert_allclose(back.timestamps, seq.timestamps, atol=1e-6)
    assert back.fps == 30.0
    assert back.intrinsics == seq.intrinsics
    raw = cv2.imread(str(out / "depth/000000.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    assert raw[0, 0] == 0


def test_folder_intensity_bits_auto(tmp_path, small_intrinsics):
    levels = np.arange(4 * 24 * 32).reshape(4, 24, 32) % 256 / 255.0
    seq = Sequence(np.full((4, 24, 32), 700.0), levels, small_intrinsics)
    write_frame_folder(seq, tmp_path / "s")
    raw = cv2.imread(str(tmp_path / "s/intensity/000000.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint8  # exactly representable in 8 bits
    np.testing.assert_allclose(
        read_frame_folder(tmp_path / "s").intensity, seq.intensity, atol=1e-7
    )


def test_folder_warns_on_coarse_unit_and_clipping(tmp_path, small_sequence):
    with pytest.warns(UserWarning, match=r"depth_unit_mm=1 is coarse for this data") as rec:
        write_frame_folder(small_sequence, tmp_path / "a")
    assert len(rec) == 1  # one warning for the whole sequence
    far = small_sequence.with_depth(small_sequence.depth + 70000.0)
    with pytest.warns(UserWarning, match=r"3072 depth values above 65535 mm were clipped"):
        write_frame_folder(far, tmp_path / "b")
    assert read_frame_folder(tmp_path / "b").depth.max() == 65535.0
    near = small_sequence.with_depth(np.full(small_sequence.depth.shape, 0.3))
    with pytest.warns(UserWarning, match=r"3072 valid depth values below 0.5 mm were raised"):
        write_frame_folder(near, tmp_path / "c")
    assert np.all(read_frame_folder(tmp_path / "c").depth == 1.0)  # still valid


def test_no_coarse_unit_warning_for_piecewise_constant_depth(tmp_path, small_sequence):
    """Depth whose neighbours are mostly equal (the RealSense chain's output) has a noise
    estimate of 0: "coarse against an estimated pixel noise of 0 mm" is not a finding."""
    steps = np.repeat(np.repeat(small_sequence.depth[:, ::4, ::4], 4, axis=1), 4, axis=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_frame_folder(small_sequence.with_depth(steps + 0.3), tmp_path / "a")
    assert np.all(np.isfinite(read_frame_folder(tmp_path / "a").depth))


def test_save_sequence_passes_warn_coarse_unit_on(tmp_path, small_sequence):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in ("a", "b.mkv"):
            save_sequence(small_sequence, tmp_path / name, warn_coarse_unit=False)
    with pytest.warns(UserWarning, match="is coarse for this data"):
        save_sequence(small_sequence, tmp_path / "c.mkv")


def test_folder_in_the_inputs_own_unit_warns_of_clipping_only(tmp_path, small_sequence):
    """warn_coarse_unit=False (the input's own unit, as `fuse4d run` writes): the same data
    that warns of a coarse unit above writes silently, and clipping is still reported."""
    from fuse4d.io import FrameFolderWriter

    def write(seq, name):
        writer = FrameFolderWriter(tmp_path / name, seq.intrinsics, warn_coarse_unit=False)
        with writer as w:
            for depth, intensity in zip(seq.depth, seq.intensity, strict=True):
                w.write(depth, intensity)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write(small_sequence, "a")
    far = small_sequence.with_depth(small_sequence.depth + 70000.0)
    with pytest.warns(UserWarning, match=r"above 65535 mm were clipped") as rec:
        write(far, "b")
    assert "coarse" not in str(rec[0].message)


def test_folder_no_warning_when_data_on_grid(tmp_path, small_sequence):
    whole = small_sequence.with_depth(np.round(small_sequence.depth))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_frame_folder(whole, tmp_path / "s")
    np.testing.assert_array_equal(read_frame_folder(tmp_path / "s").depth, whole.depth)


def test_folder_colour_intensity_converted_to_gray(tmp_path, small_sequence):
    write_frame_folder(small_sequence, tmp_path / "s", depth_unit_mm=0.01)
    bgr = np.zeros((24, 32, 3), np.uint8)
    bgr[..., 0], bgr[..., 1], bgr[..., 2] = 10, 100, 200
    for t in range(4):
        cv2.imwrite(str(tmp_path / f"s/intensity/{t:06d}.png"), bgr)
    back = read_frame_folder(tmp_path / "s")
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY) / 255.0
    np.testing.assert_allclose(back.intensity[2], expected, atol=1e-6)


def test_colour_jpeg_intensity_is_its_luma_plane(tmp_path, rng):
    """A colour JPEG's intensity is the luma plane it stores (decoded alone, no round trip
    through BGR): the BT.601 gray of the decoded colour up to the round trip's rounding."""
    bgr = (rng.random((48, 64, 3)) * 255).astype(np.uint8)
    bgr = cv2.GaussianBlur(bgr, (5, 5), 0)  # a photo-like image, not JPEG-hostile noise
    path = tmp_path / "c.jpg"
    cv2.imwrite(str(path), bgr)
    gray = read_intensity_image(path)
    luma = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(gray, luma.astype(np.float32) * np.float32(1 / 255))
    via_bgr = cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2GRAY)
    diff = np.abs(luma.astype(int) - via_bgr.astype(int))
    assert diff.max() <= 4
    assert (diff > 0).mean() < 0.05
    # a colour PNG is still converted with COLOR_BGR2GRAY, exactly
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float32) * np.float32(1 / 255)
    np.testing.assert_array_equal(read_intensity_image(tmp_path / "c.png"), expected)


def test_colour_jpeg_luma_keeps_the_stored_orientation(tmp_path, rng):
    """A JPEG whose EXIF tag says "rotate 90 degrees" is read as stored, like the colour
    decode (IMREAD_UNCHANGED), not turned: its pixels must stay registered to the depth."""
    image = pytest.importorskip("PIL.Image")
    rgb = cv2.GaussianBlur((rng.random((48, 64, 3)) * 255).astype(np.uint8), (5, 5), 0)
    exif = image.Exif()
    exif[0x0112] = 6  # orientation: rotate 90 CW to display
    image.fromarray(rgb).save(tmp_path / "r.jpg", exif=exif.tobytes())
    assert cv2.imread(str(tmp_path / "r.jpg"), cv2.IMREAD_GRAYSCALE).shape == (64, 48)
    assert read_intensity_image(tmp_path / "r.jpg").shape == (48, 64)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_mask_threshold_is_half_the_dtype_range_exactly(tmp_path, dtype):
    """The integer threshold of read_mask_image is "gray / max >= 0.5" in float32 for every
    value of the dtype."""
    top = np.iinfo(dtype).max
    values = np.arange(top + 1, dtype=np.int64)
    values = values[(values < 300) | (np.abs(values - top // 2) < 300) | (values > top - 300)]
    image = values.astype(dtype)[None, :]
    cv2.imwrite(str(tmp_path / "m.png"), image)
    expected = image.astype(np.float32) * np.float32(1.0 / top) >= np.float32(0.5)
    np.testing.assert_array_equal(read_mask_image(tmp_path / "m.png"), expected)


def test_folder_overrides_and_camera_presets(tmp_path, small_sequence):
    write_frame_folder(small_sequence, tmp_path / "s", depth_unit_mm=0.01)
    seq = load_sequence(tmp_path / "s", depth_unit_mm=0.02, intrinsics="70,71,15,11")
    np.testing.assert_allclose(seq.depth, 2 * read_frame_folder(tmp_path / "s").depth)
    assert (seq.intrinsics.fx, seq.intrinsics.fy, seq.intrinsics.cx) == (70.0, 71.0, 15.0)
    k = load_sequence(tmp_path / "s", intrinsics="freiburg1").intrinsics
    # a 4:3 image of another size gets the 640x480 preset scaled (its cx, cy lay outside)
    assert k == Intrinsics(*CAMERA_PRESETS["freiburg1"], 640, 480).scaled(32 / 640)
    assert (k.width, k.height) == (32, 24)
    with pytest.raises(ParameterError, match="preset 'freiburg1' is for a 640x480 image"):
        resolve_intrinsics("freiburg1", width=64, height=40)  # not 4:3


def test_frame_folder_writer_streams(tmp_path, small_sequence):
    k = small_sequence.intrinsics
    with FrameFolderWriter(tmp_path / "s", k, depth_unit_mm=0.01, fps=25.0) as writer:
        assert not (tmp_path / "s").exists()  # only the temporary folder exists while writing
        for frame in small_sequence.depth:
            writer.write(frame, np.full(k.shape, 0.5))
    assert writer.num_written == 4
    assert count_frames(tmp_path / "s") == 4
    assert [f.index for f in iter_frames(tmp_path / "s", frames="2:")] == [2, 3]
    assert read_intrinsics(tmp_path / "s") == k
    assert _listing(tmp_path) == ["s"]


def test_frame_folder_writer_error_leaves_nothing(tmp_path, small_sequence):
    k = small_sequence.intrinsics

    def write_then_fail() -> None:
        with FrameFolderWriter(tmp_path / "s", k) as w:
            w.write(np.full(k.shape, 500.0), np.zeros(k.shape))
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        write_then_fail()
    assert _listing(tmp_path) == []  # no destination, no temporary left behind
    with (
        pytest.raises(
            ValueError, match=r"depth of frame 0 has shape \(3, 3\), expected \(24, 32\)"
        ),
        FrameFolderWriter(tmp_path / "s", k) as w,
    ):
        w.write(np.ones((3, 3)), np.zeros((3, 3)))
    assert _listing(tmp_path) == []


def test_frame_folder_writer_overwrite(tmp_path, small_sequence):
    dest = tmp_path / "s"
    write_frame_folder(small_sequence, dest, depth_unit_mm=0.01)
    (dest / "stale.txt").write_text("old")
    with pytest.raises(OutputExistsError, match="output exists; pass overwrite=True"):
        write_frame_folder(small_sequence, dest, depth_unit_mm=0.01)
    assert (dest / "stale.txt").exists()
    two = small_sequence.frames(0, 2)
    write_frame_folder(two, dest, depth_unit_mm=0.01, overwrite=True)
    assert not (dest / "stale.txt").exists()
    assert count_frames(dest) == 2
    assert _listing(tmp_path) == ["s"]
    # a failing overwrite keeps the old folder intact
    with pytest.raises(RuntimeError), FrameFolderWriter(dest, two.intrinsics, overwrite=True):
        raise RuntimeError("fail")
    assert count_frames(dest) == 2


# ----------------------------------------------------------------------------- save/load
def test_save_sequence_infers_format(tmp_path, small_sequence):
    assert save_sequence(small_sequence, tmp_path / "a.npz").is_file()
    assert save_sequence(small_sequence, tmp_path / "b", depth_unit_mm=0.01).is_dir()
    assert detect_format(tmp_path / "a.npz") == "npz"
    assert detect_format(tmp_path / "b") == "folder"
    with pytest.raises(ValueError, match="format must be one of npz, folder, mkv, zarr, got 'tum'"):
        save_sequence(small_sequence, tmp_path / "c", format="tum")
    with pytest.raises(OutputExistsError):
        save_sequence(small_sequence, tmp_path / "a.npz")
    save_sequence(small_sequence, tmp_path / "a.npz", overwrite=True)


def test_resolve_frames():
    assert resolve_frames(None, 5) == range(5)
    assert resolve_frames("1:3", 5) == range(1, 3)
    assert resolve_frames("-2:", 5) == range(3, 5)
    assert resolve_frames("4", 5) == range(4, 5)
    assert resolve_frames((None, 2), 5) == range(2)
    assert resolve_frames(range(1, 4), 5) == range(1, 4)
    with pytest.raises(ValueError, match="frames must be a contiguous range"):
        resolve_frames(slice(0, 4, 2), 5)
    with pytest.raises(ValueError, match="frames 7:9 selects no frame of a 5-frame sequence"):
        resolve_frames("7:9", 5)
    with pytest.raises(ValueError, match="frames must look like 'A:B'"):
        resolve_frames("a:b", 5)


def test_npz_rejects_depth_unit(tmp_path, small_sequence):
    path = write_npz(small_sequence, tmp_path / "s.npz")
    with pytest.raises(ValueError, match=r"depth_unit_mm does not apply to \.npz files"):
        load_sequence(path, depth_unit_mm=1.0)


@pytest.mark.parametrize("kind", ["kinect", "TOF"])
def test_npz_and_sequence_refuse_an_unknown_camera_kind(tmp_path, small_sequence, kind):
    """'kinect' (fuse4d synth's --sensor name) or 'TOF' read as an unknown camera: flying
    pixels silently off, and `convert` wrote a folder fuse4d then refused to read."""
    path = write_npz(small_sequence, tmp_path / "s.npz")
    arrays = dict(np.load(path))
    arrays["sensor"] = np.str_(kind)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputFileError, match=f"bad.npz: key 'sensor' must be one of .*{kind}"):
        load_sequence(tmp_path / "bad.npz")
    with pytest.raises(ParameterError, match=f"sensor must be one of .*'{kind}'"):
        dataclasses.replace(small_sequence, sensor=kind)


# ----------------------------------------------------------------------------- TUM
def test_tum_layout(tmp_path, small_sequence):
    _write_tum(tmp_path / "tum", small_sequence)
    assert detect_format(tmp_path / "tum") == "tum"
    seq = read_tum(tmp_path / "tum", intrinsics="freiburg2")
    assert seq.num_frames == 4
    # 1/5 mm units: quantisation step 0.2 mm
    np.testing.assert_allclose(seq.depth, small_sequence.depth, atol=0.1 + 1e-3)
    np.testing.assert_allclose(seq.timestamps - seq.timestamps[0], np.arange(4) / 30, atol=1e-6)
    assert seq.intrinsics.fx == pytest.approx(CAMERA_PRESETS["freiburg2"][0] * 32 / 640)
    (tmp_path / "tum/camera.json").write_text('{"fx": 90, "fy": 91, "cx": 15, "cy": 11}')
    assert load_sequence(tmp_path / "tum").intrinsics.fy == 91.0
    # rgb 0.5 s after every depth frame: nothing associates
    _write_tum(tmp_path / "far", small_sequence, rgb_offset=0.5)
    with pytest.raises(InputFileError, match=r"no depth/rgb pair within 0.02 s"):
        read_tum(tmp_path / "far", intrinsics="freiburg1")
    reader = open_frames(tmp_path / "tum", intrinsics="freiburg1")
    assert reader.notes == ()  # the unmatched rgb line is simply unused


def test_associate_timestamps_greedy_unique():
    depth = np.array([0.0, 0.033, 0.066, 0.5])
    rgb = np.array([0.010, 0.020, 0.070, 0.9])
    # 0.020 is nearest to both 0.0 (0.02) and 0.033 (0.013): 0.033 wins it, 0.0 takes 0.010
    assert associate_timestamps(depth, rgb) == [(0, 0), (1, 1), (2, 2)]
    for bad in (-0.02, float("nan")):  # a negative tolerance matched nothing, silently
        with pytest.raises(ParameterError, match="max_difference must be a finite number >= 0"):
            associate_timestamps(depth, rgb, max_difference=bad)


# ----------------------------------------------------------------------------- cv2-xml
def test_cv2_xml_layout(tmp_path, small_sequence):
    _write_cv2_xml(tmp_path / "uva", small_sequence)
    assert detect_format(tmp_path / "uva") == "cv2-xml"
    seq = load_sequence(tmp_path / "uva")
    assert seq.intrinsics == small_sequence.intrinsics
    np.testing.assert_allclose(seq.depth, np.round(small_sequence.depth))
    np.testing.assert_allclose(seq.intensity, small_sequence.intensity, atol=0.5 / 255 + 1e-6)
    assert seq.ground_truth.mask.dtype == bool
    np.testing.assert_array_equal(seq.ground_truth.mask.mean(axis=(1, 2)), [0, 1, 0, 1])
    assert seq.timestamps is None
    assert seq.fps is None


# ----------------------------------------------------------------------------- frames-json
def test_frames_json_layout_and_missing_tail(tmp_path, small_sequence):
    _write_frames_json(tmp_path / "fj", small_sequence, extra_entries=3)
    assert detect_format(tmp_path / "fj") == "frames-json"
    reader = open_frames(tmp_path / "fj")
    assert len(reader) == 4
    assert reader.depth_unit_mm == pytest.approx(0.2)
    assert reader.notes[0] == "frames.json lists 7 frames; the last 3 (files absent) were skipped"
    seq = reader.read_sequence()
    np.testing.assert_allclose(seq.depth, small_sequence.depth, atol=0.1 + 1e-3)
    np.testing.assert_allclose(seq.timestamps, np.arange(4) * 0.033333)
    assert seq.intrinsics == small_sequence.intrinsics


# ----------------------------------------------------------------------------- atomic writes
def test_check_output_refuses_input(tmp_path):
    src = tmp_path / "in.npz"
    src.write_bytes(b"x")
    with pytest.raises(ValueError, match=r"output would overwrite the input"):
        check_output(src, overwrite=True, inputs=[src])
    with pytest.raises(ValueError, match=r"output would overwrite the input"):
        check_output(tmp_path / "folder" / "x.png", overwrite=True, inputs=[tmp_path / "folder"])
    with pytest.raises(ValueError, match=r"output folder .*missing does not exist"):
        check_output(tmp_path / "missing" / "x.npz")


def test_overwrite_replaces_only_a_folder_fuse4d_wrote(tmp_path, small_sequence):
    """``fuse4d convert in.npz ~/data --force`` deleted a folder of the user's own files."""
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "todo.txt").write_text("keep me")
    with pytest.raises(ParameterError, match=r"not replaced: .*fuse4d did not write \(todo\.txt\)"):
        save_sequence(small_sequence, mine, overwrite=True)
    assert (mine / "todo.txt").read_text() == "keep me"
    ours = write_frame_folder(small_sequence, tmp_path / "ours", depth_unit_mm=0.01)
    again = save_sequence(small_sequence, ours, overwrite=True, depth_unit_mm=0.01)
    assert again == ours  # camera.json: a folder fuse4d wrote
    (tmp_path / "empty").mkdir()
    assert check_output(tmp_path / "empty", overwrite=True) == tmp_path / "empty"


def test_an_output_named_like_a_foreign_file_is_refused_not_made_a_folder(tmp_path, small_sequence):
    """``-o out.mp4`` used to give a frame folder called out.mp4; a folder name with a dot
    that is no file format stays a folder."""
    from fuse4d.errors import ParameterError
    from fuse4d.io import save_sequence
    from fuse4d.io.api import output_layout

    for name in ("out.mp4", "OUT.AVI", "depth.png", "cloud.ply", "rec.bag"):
        with pytest.raises(ParameterError, match=r"fuse4d does not write \.\w+ files"):
            save_sequence(small_sequence, tmp_path / name)
    assert not list(tmp_path.iterdir())
    assert output_layout(tmp_path / "run_v1.2") == "folder"
    assert output_layout(tmp_path / "a.MKV") == "mkv"


def test_failed_write_keeps_old_file_and_leaves_no_temp(tmp_path, small_sequence, monkeypatch):
    out = write_npz(small_sequence, tmp_path / "s.npz")
    before = out.read_bytes()

    def broken_savez(file, **arrays):
        file.write(b"PK partial")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", broken_savez)
    with pytest.raises(OSError, match="disk full"):
        write_npz(small_sequence, out, overwrite=True)
    assert out.read_bytes() == before
    assert _listing(tmp_path) == ["s.npz"]


def test_written_files_have_normal_permissions(tmp_path, small_sequence):
    out = write_npz(small_sequence, tmp_path / "s.npz")
    assert out.stat().st_mode & 0o044  # readable by group/others (not mkstemp's 0600)


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
def test_written_outputs_take_the_umask_which_is_never_changed(tmp_path, small_sequence):
    """Outputs get the modes of ordinary new files and folders under the caller's umask, and
    the writers never set the process-wide umask (which a concurrent thread would see)."""
    previous = os.umask(0o027)
    try:
        calls = []
        real = os.umask
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(os, "umask", lambda mask: calls.append(mask) or real(mask))
            npz = write_npz(small_sequence, tmp_path / "s.npz")
            folder = write_frame_folder(small_sequence, tmp_path / "seq", depth_unit_mm=0.01)
        assert calls == []
        assert stat.S_IMODE(npz.stat().st_mode) == 0o640
        assert stat.S_IMODE(folder.stat().st_mode) == 0o750
        assert stat.S_IMODE((folder / "camera.json").stat().st_mode) == 0o640
    finally:
        os.umask(previous)


# ----------------------------------------------------------------------------- PLY
def test_ply_round_trip(tmp_path, small_sequence):
    depth = small_sequence.depth[0].copy()
    depth[:3] = np.nan
    points = depth_to_points(depth, small_sequence.intrinsics)
    n = write_ply(points, tmp_path / "f.ply", colors=small_sequence.intensity[0])
    assert n == 21 * 32
    xyz, rgb = read_ply(tmp_path / "f.ply")
    np.testing.assert_array_equal(xyz, points[3:].reshape(-1, 3))
    expected = np.round(small_sequence.intensity[0, 3:].ravel() * 255).astype(np.uint8)
    np.testing.assert_array_equal(rgb[:, 0], expected)
    np.testing.assert_array_equal(rgb[:, 0], rgb[:, 2])
    header = (tmp_path / "f.ply").read_bytes()[:200]
    assert b"format binary_little_endian 1.0" in header
    assert b"element vertex 672" in header
    with pytest.raises(OutputExistsError):
        write_ply(points, tmp_path / "f.ply")
    write_ply(points, tmp_path / "f.ply", overwrite=True)
    assert read_ply(tmp_path / "f.ply")[1] is None
    with pytest.raises(ValueError, match=r"colors must have shape \(24, 32\)"):
        write_ply(points, tmp_path / "g.ply", colors=np.zeros(3))


# ----------------------------------------------------------------------------- .flo
def test_flo_round_trip_and_unknown(tmp_path, rng):
    flow = rng.normal(0, 3, (5, 7, 2)).astype(np.float32)
    flow[1, 2] = np.nan
    write_flo(flow, tmp_path / "f.flo")
    data = (tmp_path / "f.flo").read_bytes()
    assert data[:4] == b"PIEH"
    assert len(data) == 12 + 5 * 7 * 2 * 4
    back = read_flo(tmp_path / "f.flo")
    assert back.shape == (5, 7, 2)
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, flow)  # NaN where unknown
    raw = np.frombuffer(data, "<f4", 70, 12).copy().reshape(5, 7, 2)
    assert raw[1, 2, 0] == np.float32(1e10)
    with pytest.raises(OutputExistsError):
        write_flo(flow, tmp_path / "f.flo")
    with pytest.raises(ValueError, match=r"flow must have shape \(H, W, 2\), got \(5, 7\)"):
        write_flo(flow[..., 0], tmp_path / "g.flo")


# ----------------------------------------------------------------------------- masks
def test_read_mask_sources(tmp_path, small_sequence, rng):
    roi = rng.random((24, 32)) > 0.5
    cv2.imwrite(str(tmp_path / "roi.png"), (roi * 255).astype(np.uint8))
    np.testing.assert_array_equal(read_mask(tmp_path / "roi.png"), roi)
    np.savez(tmp_path / "roi.npz", roi=roi.astype(np.uint8))
    np.testing.assert_array_equal(read_mask(tmp_path / "roi.npz"), roi)
    seq = _sequence_with_gt(small_sequence, rng)
    write_npz(seq, tmp_path / "s.npz")
    np.testing.assert_array_equal(
        read_mask(tmp_path / "s.npz", frames="1:3"), seq.ground_truth.mask[1:3]
    )
    _write_cv2_xml(tmp_path / "uva", small_sequence)
    assert read_mask(tmp_path / "uva").shape == (4, 24, 32)
    with pytest.warns(UserWarning, match="ground-truth"):
        write_frame_folder(seq, tmp_path / "f", depth_unit_mm=0.01)
    np.testing.assert_array_equal(read_mask(tmp_path / "f"), seq.ground_truth.mask)
    write_frame_folder(small_sequence, tmp_path / "nomask", depth_unit_mm=0.01)
    with pytest.raises(InputFileError, match="this recording stores no masks"):
        read_mask(tmp_path / "nomask")
    np.savez(tmp_path / "other.npz", x=roi)
    with pytest.raises(InputFileError, match="no mask key"):
        read_mask(tmp_path / "other.npz")


def test_writers_of_a_sequence_refuse_an_array(tmp_path):
    """write_npz(depth_array, path) failed with "'numpy.ndarray' object has no attribute
    'depth'"; every writer of a Sequence now says what it takes."""
    from fuse4d.errors import ParameterTypeError
    from fuse4d.io import write_depth_video, write_zarr

    depth = np.full((2, 4, 5), 500.0, np.float32)
    for write in (write_npz, save_sequence, write_frame_folder, write_depth_video, write_zarr):
        name = write.__name__
        with pytest.raises(ParameterTypeError, match=rf"^{name} takes a fuse4d\.Sequence, got "):
            write(depth, tmp_path / "out")
    assert not list(tmp_path.iterdir())


# ----------------------------------------------------------------------------- writer errors
def _noisy_sequence(t: int = 4, h: int = 48, w: int = 64, **kwargs) -> Sequence:
    rng = np.random.default_rng(7)
    depth = (500.0 + 1000.0 * rng.random((t, h, w))).astype(np.float32)
    intensity = rng.random((t, h, w)).astype(np.float32)
    k = Intrinsics(60.0, 60.0, (w - 1) / 2, (h - 1) / 2, width=w, height=h)
    return Sequence(depth, intensity, k, fps=30.0, **kwargs)


@pytest.mark.parametrize("name", ["f", "s.zarr", "s.mkv"])
def test_a_full_disk_while_streaming_is_an_output_write_error_naming_the_output(tmp_path, name):
    """A full disk during a folder / .zarr / .mkv write gave a bare OSError (for .mkv naming the
    hidden temporary file): the writers' own I/O ran outside the atomic context's error
    handling. A file size limit (EFBIG, as ENOSPC a write error) fails the real writes."""
    resource = pytest.importorskip("resource")
    from fuse4d.errors import OutputWriteError

    if name.endswith(".mkv"):
        pytest.importorskip("av")
    out = tmp_path / name
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, hard))  # each frame is larger
    try:
        with pytest.raises(OutputWriteError) as err:
            save_sequence(_noisy_sequence(), out, depth_unit_mm=0.1)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert str(err.value).startswith(f"{out}: cannot write the output (File too large)")
    assert ".tmp-" not in str(err.value)
    assert _listing(tmp_path) == []  # no output, no temporary


@pytest.mark.parametrize("name", ["f", "s.zarr"])
def test_an_output_that_cannot_be_set_up_leaves_no_temporary(tmp_path, monkeypatch, name):
    """An error in ``open`` (``__enter__``) left the temporary folder behind: ``with`` does
    not call ``__exit__`` when ``__enter__`` fails."""
    import errno

    from fuse4d.errors import OutputWriteError
    from fuse4d.io.zarrstore import ZarrWriter

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    if name.endswith(".zarr"):
        monkeypatch.setattr(ZarrWriter, "_add_array", full)
    else:
        mkdir = Path.mkdir
        monkeypatch.setattr(
            Path, "mkdir", lambda p, *a, **kw: full() if p.name == "depth" else mkdir(p, *a, **kw)
        )
    out = tmp_path / name
    with pytest.raises(OutputWriteError) as err:
        save_sequence(_noisy_sequence(t=1), out)
    # checked while the traceback (and the writer with it) is alive: the garbage collector
    # removed the temporary only once the writer was dropped
    assert _listing(tmp_path) == []
    assert str(err.value).startswith(f"{out}: cannot write the output (No space left")


def test_an_output_inside_a_file_is_not_a_missing_folder(tmp_path):
    (tmp_path / "mk.py").write_text("x = 1\n")
    with pytest.raises(ParameterError, match=r"x\.npz: .*mk\.py is not a folder$"):
        check_output(tmp_path / "mk.py" / "x.npz")


@pytest.mark.parametrize("suffix", [".zarr", ".mkv"])
def test_save_sequence_names_the_ground_truth_a_layout_drops(tmp_path, small_sequence, suffix):
    """The masks (and any ground truth) went missing silently in .zarr and .mkv outputs."""
    if suffix == ".mkv":
        pytest.importorskip("av")
    mask = np.zeros(small_sequence.depth.shape, bool)
    mask[:, 5:9, 6:12] = True
    seq = dataclasses.replace(small_sequence, ground_truth=GroundTruth(mask=mask))
    out = tmp_path / f"s{suffix}"
    with pytest.warns(UserWarning, match="ground-truth") as rec:
        save_sequence(seq, out, depth_unit_mm=0.01)
    said = [str(w.message) for w in rec if "ground-truth" in str(w.message)]
    want = f"{out}: the {suffix} format does not store ground-truth mask; use .npz to keep them"
    assert said == [want]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_frame_folder(seq, tmp_path / "f", depth_unit_mm=0.01)  # keeps the masks: silent


def test_a_frame_folder_names_the_scene_it_drops(tmp_path):
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=2)
    with pytest.warns(UserWarning, match=r"ground-truth depth, flow, extra\[.*\], scene; use"):
        write_frame_folder(seq, tmp_path / "f", depth_unit_mm=0.1)


def test_mkv_names_the_frames_whose_time_it_moves(tmp_path, small_intrinsics):
    """The .mkv writer moved a non-increasing pts silently (up to 100 ms here)."""
    pytest.importorskip("av")
    from fuse4d.io import DepthVideoWriter

    def write(path: Path, stamps: tuple[float, ...]) -> None:
        depth, intensity = np.full((24, 32), 500.0), np.full((24, 32), 0.5)
        with DepthVideoWriter(path, small_intrinsics) as writer:
            for ts in stamps:
                writer.write(depth, intensity, timestamp=ts)

    out = tmp_path / "t.mkv"
    with pytest.warns(UserWarning, match="1 ms time resolution") as rec:
        write(out, (10.0, 10.0333, 10.0334, 10.0335, 9.9333, 10.2))
    said = f"{out}: 2 frames (first: frame 3) did not come after the previous frame at the "
    said += ".mkv's 1 ms time resolution and were stored later, by up to 102.7 ms (frame 4)"
    assert [str(w.message) for w in rec] == [said]
    with open_frames(out) as reader:
        np.testing.assert_allclose(reader.timestamps, [10, 10.033, 10.034, 10.035, 10.036, 10.2])
    with warnings.catch_warnings():  # moved within the 1 ms rounding: silent
        warnings.simplefilter("error")
        write(tmp_path / "r.mkv", (0.0, 0.0004, 0.0011))


def test_zarr_stores_nan_intensity_as_zero(tmp_path, small_sequence):
    """NaN intensity went into the store as NaN, which load_sequence then refused."""
    from fuse4d.io import ZarrWriter

    k = small_sequence.intrinsics
    intensity = np.full(k.shape, 0.5, np.float32)
    intensity[2, 3] = np.nan
    with ZarrWriter(tmp_path / "s.zarr", k) as writer:
        writer.write(small_sequence.depth[0], intensity)
    got = load_sequence(tmp_path / "s.zarr").intensity[0]
    assert got[2, 3] == 0.0
    assert np.isfinite(got).all()


def test_a_one_pixel_wide_mkv_is_a_parameter_error(tmp_path):
    """FFmpeg's FFV1 encoder refuses a 1-px-wide frame: NotImplementedError from PyAV."""
    pytest.importorskip("av")
    k = Intrinsics(10.0, 10.0, 0.0, 3.0, width=1, height=7)
    seq = Sequence(np.full((2, 7, 1), 500.0, np.float32), np.zeros((2, 7, 1), np.float32), k)
    with pytest.raises(ParameterError, match=r"1 px wide cannot be stored as FFV1 \.mkv"):
        save_sequence(seq, tmp_path / "x.mkv")
    assert _listing(tmp_path) == []


@pytest.mark.parametrize("layout", ["mkv", "folder"])
def test_coarse_unit_warning_points_at_the_callers_with_line(tmp_path, layout):
    """The write-error decorator on close() added a frame: the warning pointed into fuse4d."""
    from fuse4d.io import DepthVideoWriter, FrameFolderWriter

    k = Intrinsics(fx=10.0, fy=10.0, cx=8.0, cy=8.0, width=16, height=16)
    noise = np.random.default_rng(0).normal(0, 0.1, (3, 16, 16)).astype(np.float32)
    cls = DepthVideoWriter if layout == "mkv" else FrameFolderWriter
    path = tmp_path / ("o.mkv" if layout == "mkv" else "o")
    with warnings.catch_warnings(record=True) as record, cls(path, k, depth_unit_mm=1.0) as out:
        warnings.simplefilter("always")
        for t in range(3):
            out.write(1000.0 + noise[t], np.full((16, 16), 0.5, np.float32))
    coarse = [w for w in record if "is coarse for this data" in str(w.message)]
    assert len(coarse) == 1
    assert Path(coarse[0].filename).name == "test_io.py"


@pytest.mark.parametrize("layout", ["zarr", "folder"])
@pytest.mark.parametrize(
    "stamps",
    [
        [0.0, 0.0, 0.1],
        [0.2, 0.1, 0.3],
        [0.0, float("nan"), 0.1],
        [0.0, "x", 0.1],
        [0.0, None, 0.1],  # the zarr writer dropped every time
        [None, 0.0, 0.1],
    ],
)
def test_writers_refuse_times_their_reader_refuses(tmp_path, layout, stamps):
    """The store was written, then refused by fuse4d's own reader."""
    from fuse4d.io import FrameFolderWriter, ZarrWriter

    k = Intrinsics(fx=10.0, fy=10.0, cx=3.5, cy=2.5, width=8, height=6)
    cls = ZarrWriter if layout == "zarr" else FrameFolderWriter
    path = tmp_path / ("o.zarr" if layout == "zarr" else "o")
    depth, inten = np.full((6, 8), 900.0, np.float32), np.full((6, 8), 0.5)
    with cls(path, k) as writer:
        writer.write(depth, inten, timestamp=stamps[0])
        with pytest.raises(ParameterError, match=rf"{path.name} \(frame 1\): "):
            writer.write(depth, inten, timestamp=stamps[1])
        writer.abort()
    assert not path.exists()


def test_zarr_nan_intensity_of_earlier_writers_reads_as_zero(tmp_path, small_sequence):
    """Earlier ZarrWriters stored NaN intensity, which the reader now refuses as not [0, 1]."""
    import zarr

    path = save_sequence(small_sequence, tmp_path / "s.zarr")
    zarr.open_group(str(path), mode="r+")["intensity"][0, 0, :2] = np.nan
    seq = load_sequence(path)
    assert (seq.intensity[0, 0, :2] == 0).all()
    np.testing.assert_array_equal(seq.intensity[1:], small_sequence.intensity[1:])


@pytest.mark.parametrize("stamps", [[None, 0.1, 0.2], [0.0, None, 0.2], [0.0, float("inf"), 0.2]])
def test_mkv_writer_takes_times_for_every_frame_or_none(tmp_path, stamps):
    """Times that started after frame 0 were silently dropped (frames placed at 30 fps)."""
    from fuse4d.io import DepthVideoWriter

    k = Intrinsics(fx=10.0, fy=10.0, cx=3.5, cy=2.5, width=8, height=6)
    depth, inten = np.full((6, 8), 900.0, np.float32), np.full((6, 8), 0.5)
    with DepthVideoWriter(tmp_path / "o.mkv", k) as writer:
        writer.write(depth, inten, timestamp=stamps[0])
        with pytest.raises(ParameterError, match=r"\(frame 1\): "):
            writer.write(depth, inten, timestamp=stamps[1])
        writer.abort()
    assert not (tmp_path / "o.mkv").exists()


def test_folder_writer_refuses_times_equal_at_its_microseconds(tmp_path):
    """timestamps.txt holds microseconds: 0 and 0.4 us were written as two equal times."""
    from fuse4d.io import FrameFolderWriter

    k = Intrinsics(fx=10.0, fy=10.0, cx=3.5, cy=2.5, width=8, height=6)
    depth, inten = np.full((6, 8), 900.0, np.float32), np.full((6, 8), 0.5)
    with FrameFolderWriter(tmp_path / "o", k) as writer:
        writer.write(depth, inten, timestamp=0.0)
        with pytest.raises(ParameterError, match="at the file's 1e-06 s resolution"):
            writer.write(depth, inten, timestamp=4e-7)
        writer.write(depth, inten, timestamp=2e-6)
    assert load_sequence(tmp_path / "o").timestamps.tolist() == [0.0, 2e-6]
