"""The public API as a numpy user calls it: integer intensity, buffers, views, bad values.

Each case failed before (silently wrong, an input written to, memory overwritten, or an
internal exception instead of one of fuse4d's own).
"""

from __future__ import annotations

import numpy as np
import pytest

import fuse4d
from fuse4d import Intrinsics, ParameterError, Sequence, ShapeError
from fuse4d.baselines import run_baseline
from fuse4d.bilateral import bilateral_filter_points
from fuse4d.errors import ParameterTypeError
from fuse4d.io import load_sequence, read_ply, write_ply
from fuse4d.io.folder import FrameFolderWriter
from fuse4d.sensors import apply_sensor, depth_step_mm
from fuse4d.sequence import sanitize_depth

K32 = Intrinsics(fx=100.0, fy=100.0, cx=15.5, cy=15.5, width=32, height=32)


def _ramp_u8() -> np.ndarray:
    return np.tile(np.arange(0, 256, 8, dtype=np.uint8), (32, 1))


# ----------------------------------------------------------------- output buffers
def test_bilateral_refuses_an_out_buffer_it_cannot_write_through():
    """A (3, 3, 3) buffer was written through as (32, 32, 3): memory corruption, segfault."""
    points = fuse4d.depth_to_points(np.full((32, 32), 1000.0, np.float32), K32)
    gray = np.zeros((32, 32), np.float32)
    with pytest.raises(ShapeError, match=r"out must have shape \(32, 32, 3\)"):
        bilateral_filter_points(points, gray, out=np.zeros((3, 3, 3), np.float32))
    with pytest.raises(ParameterTypeError, match="out must be a float32 ndarray, got float64"):
        bilateral_filter_points(points, gray, out=np.zeros((32, 32, 3)))
    with pytest.raises(ParameterError, match="C-contiguous, writeable"):
        bilateral_filter_points(points, gray, out=np.zeros((32, 3, 32), np.float32).swapaxes(1, 2))
    out = np.zeros((32, 32, 3), np.float32)
    assert bilateral_filter_points(points, gray, out=out) is out


# ----------------------------------------------------------------- integer intensity
def test_bilateral_takes_uint8_intensity_as_the_engine_does():
    """A uint8 texture was taken as 0-255: every intensity weight but the equal pixels' ~0."""
    from fuse4d.sequence import normalize_intensity

    rng = np.random.default_rng(0)
    depth = (1000.0 + rng.normal(0.0, 1.0, (32, 32))).astype(np.float32)
    points = fuse4d.depth_to_points(depth, K32)
    u8 = rng.integers(100, 110, (32, 32)).astype(np.uint8)  # gray levels 2-40 apart (x 1/255)
    a = bilateral_filter_points(points, u8, sigma_distance=40.0)  # pixels 10 mm apart
    b = bilateral_filter_points(points, normalize_intensity(u8), sigma_distance=40.0)
    np.testing.assert_array_equal(a, b)
    smoothed = np.nanstd(a[..., 2]) < 0.5 * np.nanstd(points[..., 2])
    assert smoothed  # 10 gray levels apart at sigma_intensity 0.1 (25 levels): it averages


def test_writers_take_uint8_intensity_as_the_engine_does(tmp_path):
    """A 0..248 uint8 ramp was stored as [0, 1, 1, ...] (taken as 0-255 floats, clipped)."""
    u8 = _ramp_u8()
    depth = np.full((32, 32), 1000.0, np.float32)
    for name in ("folder", "v.mkv", "z.zarr"):
        path = tmp_path / name
        seq = Sequence(depth[None], u8[None] / np.float32(255), K32)
        if name == "folder":
            with FrameFolderWriter(path, K32) as w:
                w.write(depth, u8)
        else:
            pytest.importorskip("av" if name.endswith(".mkv") else "zarr")
            from fuse4d.io.api import stream_writer

            cls, _ = stream_writer(path)
            with cls(path, K32) as w:
                w.write(depth, u8)
        back = load_sequence(path)
        np.testing.assert_allclose(back.intensity, seq.intensity, atol=0.5 / 255, err_msg=name)


def test_writers_refuse_float_intensity_in_0_255(tmp_path):
    with (
        pytest.raises(
            ParameterError, match=r"intensity of frame 0 is float with values in \[0, 248\]"
        ),
        FrameFolderWriter(tmp_path / "f", K32) as w,
    ):
        w.write(np.full((32, 32), 1000.0, np.float32), _ramp_u8().astype(np.float32))
    assert not (tmp_path / "f").exists()


def test_ply_colours_take_uint8(tmp_path):
    points = np.array([[0.0, 0.0, 1000.0], [1.0, 0.0, 1000.0], [2.0, 0.0, 1000.0]], np.float32)
    write_ply(points, tmp_path / "a.ply", colors=np.array([64, 128, 255], np.uint8))
    _, colours = read_ply(tmp_path / "a.ply")
    assert np.asarray(colours).ravel()[:3].tolist() != [255, 255, 255]
    np.testing.assert_allclose(np.asarray(colours).reshape(3, -1)[:, 0], [64, 128, 255], atol=1)


def test_sensor_model_takes_uint8_albedo():
    """A uint8 albedo of 5 (0.02) was clipped to 1: no dark dropout; float 0.02 dropped all."""
    depth = np.full((2, 32, 32), 1500.0)
    albedo = np.full((2, 32, 32), 0.02)
    k = Intrinsics(300.0, 300.0, 15.5, 15.5, 32, 32)
    as_float = apply_sensor(depth, albedo, k, "kinect", rng=0).dropout.mean()
    as_u8 = apply_sensor(depth, np.full((2, 32, 32), 5, np.uint8), k, "kinect", rng=0)
    assert as_float == as_u8.dropout.mean() == 1.0


# ----------------------------------------------------------------- inputs never written to
def test_sanitize_depth_never_writes_into_a_memmap(tmp_path):
    mm = np.memmap(tmp_path / "d.dat", np.float32, "w+", shape=(2, 4, 4))
    mm[:] = 1000.0
    mm[0, 0, 0] = 0.0
    out = sanitize_depth(mm)
    assert np.isnan(out[0, 0, 0])
    assert mm[0, 0, 0] == 0.0


# ----------------------------------------------------------------- fuse4d's own errors
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"cx": 1e39}, "Intrinsics.cx must be at most 3.4e+38 pixels"),
        ({"fx": 1e-300}, "Intrinsics.fx must be at least 1.18e-38 pixels"),
        ({"width": "abc"}, "Intrinsics.width must be a positive integer, got 'abc'"),
        ({"width": None}, "Intrinsics.width must be a positive integer, got None"),
        ({"height": float("inf")}, "Intrinsics.height must be a positive integer, got inf"),
    ],
)
def test_intrinsics_refuse_values_the_float32_kernels_cannot_hold(kwargs, message):
    """cx = 1e39 became inf in float32: every fused pixel NaN, with no error."""
    base = {"fx": 100.0, "fy": 100.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 3}
    base.update(kwargs)
    with pytest.raises(ParameterError, match="^" + message.replace(".", r"\.").replace("+", r"\+")):
        Intrinsics(**base)


@pytest.mark.parametrize("name", ["adbf", "adjbf", "stmf", "guided"])
def test_guided_baselines_say_they_need_intensity(name):
    depth = np.full((3, 32, 32), 1000.0, np.float32)
    with pytest.raises(ParameterTypeError, match="needs intensity: it is guided by"):
        run_baseline(name, depth, None, K32)


def test_baseline_depth_of_another_size_is_a_shape_error():
    with pytest.raises(ShapeError, match=r"depth must have shape \(T, 32, 32\)"):
        run_baseline("temporal-mean", np.ones((2, 8, 8), np.float32), None, K32)


@pytest.mark.parametrize(
    "call",
    [
        lambda: fuse4d.depth_to_points(np.ones((32, 32)), None),
        lambda: fuse4d.camera.project_points(np.ones((4, 3)), (100, 100, 1, 1)),
    ],
)
def test_camera_functions_check_their_intrinsics(call):
    with pytest.raises(ParameterTypeError, match=r"intrinsics must be a fuse4d\.Intrinsics"):
        call()


def test_sensor_model_checks_its_inputs():
    depth = np.full((2, 32, 32), 1500.0)
    albedo = np.full((2, 32, 32), 0.5)
    with pytest.raises(ShapeError, match="intensity must have shape"):
        apply_sensor(depth, albedo[:1], K32, "kinect")
    with pytest.raises(ShapeError, match="normal_z must have shape"):
        apply_sensor(depth, albedo, K32, "kinect", normal_z=albedo[0])
    with pytest.raises(ShapeError, match="depth must have shape"):
        apply_sensor(depth, albedo, Intrinsics(100, 100, 1, 1, 8, 8), "kinect")
    with pytest.raises(ParameterError, match="focal_px must be > 0"):
        depth_step_mm("kinect", 1000.0, 0.0)
    assert depth_step_mm("kinect", 1000.0, 580.0) == pytest.approx(
        depth_step_mm(fuse4d.sensors.get_sensor("kinect"), 1000.0, 580.0)
    )


def test_fuse_stream_takes_reader_frames_and_names_a_bad_item(tmp_path):
    """Its docstring's own example, ``fuse_stream(iter_frames(path), ...)``, failed to
    unpack a Frame."""
    from fuse4d.io import iter_frames, write_npz
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=4)
    path = write_npz(seq, tmp_path / "b.npz")
    params = fuse4d.FusionParams(num_frames=3)
    from_frames = list(fuse4d.fuse_stream(iter_frames(path), seq.intrinsics, fusion=params))
    from_pairs = list(
        fuse4d.fuse_stream(
            zip(seq.depth, seq.intensity, strict=True), seq.intrinsics, fusion=params
        )
    )
    for a, b in zip(from_frames, from_pairs, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
    with pytest.raises(ParameterTypeError, match="item 0 is a ndarray"):
        list(fuse4d.fuse_stream([seq.depth[0]], seq.intrinsics, fusion=params))


def test_engine_and_motion_reference_refuse_odd_numbers():
    with pytest.raises(ParameterTypeError, match=r"ring_size must be an integer, got 10\.5"):
        fuse4d.FusionEngine(K32, ring_size=10.5)
    with pytest.raises(ParameterError, match="ring_size must be >= 0"):
        fuse4d.FusionEngine(K32, ring_size=-3)
    engine = fuse4d.FusionEngine(K32)
    with pytest.raises(ParameterTypeError, match=r"first must be an integer, got 1\.5"):
        engine.set_output_range(1.5, 3)  # was truncated to 1
    with pytest.raises(ParameterTypeError, match=r"stop must be an integer, got 3\.0"):
        engine.set_output_range(1, 3.0)
    from fuse4d.motion import motion_reference_depth

    with pytest.raises(ParameterError, match="sigma must be a finite number > 0 px, got inf"):
        motion_reference_depth(np.ones((4, 4)), sigma=float("inf"))


def test_non_numeric_arrays_are_a_parameter_type_error():
    with pytest.raises(ParameterTypeError, match="depth must be a numeric array"):
        fuse4d.depth_to_points(np.array([["a"]]), Intrinsics(1, 1, 0, 0, 1, 1))


def test_frames_one_pixel_wide_say_what_is_wrong():
    """The flow's 'image0 must have shape (H, W)' used to be the answer."""
    k = Intrinsics(10.0, 10.0, 0.0, 3.5, width=1, height=8)
    depth = np.full((3, 8, 1), 1000.0, np.float32)
    gray = np.full((3, 8, 1), 0.5, np.float32)
    with pytest.raises(ShapeError, match=r"depth frames must have shape \(H >= 2, W >= 2\)"):
        fuse4d.fuse_sequence(depth, gray, k)
    one = fuse4d.fuse_sequence(depth, gray, k, fusion=fuse4d.FusionParams(num_frames=1))
    assert one.depth.shape == (3, 8, 1)


@pytest.mark.parametrize(
    "field",
    ["sigma_distance", "sigma_intensity", "sigma_temporal", "motion_sigma", "base_smoothing"],
)
def test_huge_finite_sigmas_act_as_their_limit(field):
    """1e300 raised OverflowError (sigma ** 2), 1e20 an integer numba could not type (box
    radius): an internal error (exit 70). Now the limit of a wide kernel."""
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=3)
    params = fuse4d.FusionParams(num_frames=3, **{field: 1e300})
    out = fuse4d.fuse_sequence(seq.depth, seq.intensity, seq.intrinsics, fusion=params)
    assert np.isfinite(out.depth).mean() > 0.99
    if field == "base_smoothing":
        again = fuse4d.fuse_sequence(
            seq.depth, seq.intensity, seq.intrinsics, fusion=params.replace(base_smoothing=1e20)
        )
        np.testing.assert_array_equal(again.depth, out.depth)
