"""fuse4d.baselines: shared kernel vs oracles/OpenCV, and the per-method behaviour contract."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import warnings

import cv2
import numpy as np
import pytest

from fuse4d import Intrinsics, depth_to_points
from fuse4d._kernels.joint_bilateral import _joint_bilateral_kernel
from fuse4d.baselines import available_baselines, estimate_noise_sigma, run_baseline
from fuse4d.baselines._common import normalized_convolution_fill
from fuse4d.baselines.bilateral import _view_angle, joint_bilateral_frame
from fuse4d.baselines.stmf import block_match, sorting_network
from fuse4d.errors import ParameterError
from naive.baselines import block_match as naive_block_match
from naive.baselines import guided_filter as naive_guided
from naive.baselines import joint_bilateral as naive_joint_bilateral
from naive.baselines import pca_view_angle as naive_pca_view_angle
from naive.baselines import region_grow as naive_region_grow
from naive.baselines import stmf_median as naive_stmf_median
from naive.baselines import temporal_average as naive_temporal_average

T, H, W = 6, 48, 64
HOLE = (slice(None), slice(18, 23), slice(28, 34))
MARGIN = 12  # interior used for "unchanged" checks (border effects differ per method)

NAMES = (
    "adgf", "adbf", "guided", "dnbf", "ta", "adjbf", "stmf",
    "kinectfusion", "ed", "temporal-mean", "realsense",
)  # fmt: skip
SLOW = {"ed", "kinectfusion"}
#: Max |out − GT| (mm) in the interior for a noise-free tilted plane (σ_d passed as 0.2 mm).
CLEAN_TOL = {"guided": 0.3, "adjbf": 0.1, "realsense": 0.25}


@pytest.fixture
def intrinsics() -> Intrinsics:
    # pixel footprint 0.6 mm at 300 mm, like the 1000 fps rig (TSDF voxel 0.5 mm fits)
    return Intrinsics(fx=500.0, fy=500.0, cx=31.5, cy=23.5, width=W, height=H)


@pytest.fixture
def plane() -> tuple[np.ndarray, np.ndarray]:
    """Static tilted plane (mm) and a textured intensity, (T, H, W)."""
    yy, xx = np.mgrid[0:H, 0:W]
    depth = np.broadcast_to(300.0 + 0.05 * xx + 0.03 * yy, (T, H, W)).astype(np.float32)
    tex = np.clip(0.5 + 0.3 * np.sin(xx / 3.0) * np.cos(yy / 4.0), 0, 1)
    return depth, np.broadcast_to(tex, (T, H, W)).astype(np.float32)


def _call(name: str, depth, intensity, intrinsics, **params):
    info = available_baselines()[name]
    if info.needs == "realsense" and not info.available:
        pytest.skip("pyrealsense2 not installed (pip install 'fuse4d[realsense]')")
    # kinectfusion runs its default (projective) backend in-process; the Open3D backend is
    # exercised in a subprocess with a timeout (test_kinectfusion_open3d_backend_in_a_subprocess)
    if info.returns_points:
        params.setdefault("size", 1)
    out = run_baseline(name, depth, intensity, intrinsics, **params)
    return out[..., 2] if info.returns_points else out


def _params(names):
    return [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in names]


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean((a - b) ** 2)))


# --------------------------------------------------------------------------------- registry


def test_registry_names_and_fields():
    infos = available_baselines()
    assert tuple(infos) == NAMES
    for name, info in infos.items():
        assert info.name == name
        assert info.size_sweep
        assert info.iterations_sweep[0] == 1
        assert info.returns_points == (name in ("kinectfusion", "ed"))
        assert info.default_size in info.size_sweep


def test_run_baseline_unknown_name(plane, intrinsics):
    with pytest.raises(ValueError, match=r"unknown baseline 'nope'.*adgf"):
        run_baseline("nope", *plane, intrinsics)


def test_bad_inputs_name_the_parameter(plane, intrinsics):
    depth, tex = plane
    with pytest.raises(ValueError, match="depth"):
        run_baseline("adjbf", depth[0], tex[0], intrinsics)
    with pytest.raises(ValueError, match="intensity"):
        run_baseline("adjbf", depth, tex[:3], intrinsics)
    with pytest.raises(ValueError, match="size"):
        run_baseline("adbf", depth, tex, intrinsics, size=0)
    with pytest.raises(ValueError, match="iterations"):
        run_baseline("ta", depth, tex, intrinsics, iterations=0)


# ------------------------------------------------------------------------- shared helpers


def test_noise_estimate_recovers_sigma(rng):
    yy, xx = np.mgrid[0:64, 0:80]
    for sigma in (0.1, 0.4):
        depth = 600 + 0.2 * xx + 0.1 * yy + rng.normal(0, sigma, (4, 64, 80))
        depth[:, 10:20, 10:20] = np.nan
        assert estimate_noise_sigma(depth) == pytest.approx(sigma, rel=0.05)


def test_normalized_convolution_fill_keeps_valid_and_fills_holes():
    frame = np.full((20, 20), 100.0, np.float32)
    frame[5:9, 5:9] = np.nan
    filled = normalized_convolution_fill(frame, sigma=3.0)
    assert np.all(np.isfinite(filled))
    np.testing.assert_allclose(filled, 100.0, atol=1e-4)


# -------------------------------------------------------------------------- shared kernel


def test_kernel_matches_naive_oracle_adaptive_temporal_nan(rng):
    k, h, w = 3, 14, 17
    depth = (500 + rng.normal(0, 1.0, (k, h, w))).astype(np.float32)
    depth[1, 3:6, 4:8] = np.nan
    depth[2, 7, 9] = np.nan
    intensity = rng.uniform(0, 1, (k, h, w)).astype(np.float32)
    radius = rng.integers(1, 4, (h, w)).astype(np.int32)
    s_s = rng.uniform(0.8, 2.5, (h, w)).astype(np.float32)
    s_r = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
    tw = np.array([0.3, 0.7, 1.0], np.float32)
    for relative, s_range in ((False, s_r), (True, (s_r / 500).astype(np.float32))):
        out = np.empty((h, w), np.float32)
        _joint_bilateral_kernel(
            depth, intensity, 2, tw, radius, 0.5 / s_s**2, 0.5 / 0.2**2, 0.5 / s_range**2,
            relative, out,
        )  # fmt: skip
        ref = naive_joint_bilateral(depth, intensity, 2, tw, radius, s_s, 0.2, s_range, relative)
        np.testing.assert_array_equal(np.isnan(out), np.isnan(depth[2]))
        # float32 coefficients and exp(-x) ~ (1 - x/1024)^1024 (relative error x^2/2048)
        np.testing.assert_allclose(out, ref, rtol=0, atol=2e-3)


def test_view_angle_matches_naive_pca_oracle(rng):
    """Ad-GF's PCA normal angle (box-filtered moments + closed-form 3x3 eigen) vs numpy eigh."""
    intr = Intrinsics(fx=300.0, fy=300.0, cx=20.0, cy=15.0, width=40, height=30)
    yy, xx = np.mgrid[0:30, 0:40]
    depth = 600 + 3 * xx + yy + 40 * np.sin(xx / 4.0) + rng.normal(0, 0.3, (30, 40))
    depth = depth.astype(np.float32)
    depth[5:9, 10:14] = np.nan
    points = depth_to_points(depth, intr)
    ours = _view_angle(points)
    ref = np.minimum(naive_pca_view_angle(points, 2, 3), np.deg2rad(80.0))
    np.testing.assert_allclose(ours, ref, atol=1e-5)
    assert ref.mean() > 0.5  # a sloped surface: the angle is really measured


def test_kernel_golden_cv2_bilateral(rng):
    """Constant σ_r, no NaN: equals cv2.bilateralFilter away from the border."""
    _yy, xx = np.mgrid[0:40, 0:50]
    depth = (400 + 0.3 * xx + 5.0 * (xx > 25) + rng.normal(0, 0.5, (40, 50))).astype(np.float32)
    r, s_s, s_r = 4, 2.0, 1.5
    ours = joint_bilateral_frame(depth, radius=r, sigma_spatial=s_s, sigma_depth=s_r)
    ref = cv2.bilateralFilter(depth, d=2 * r + 1, sigmaColor=s_r, sigmaSpace=s_s)
    inner = (slice(r, -r), slice(r, -r))
    # OpenCV interpolates its float range kernel from a lookup table: ~1e-3 mm differences.
    np.testing.assert_allclose(ours[inner], ref[inner], atol=5e-3)
    assert np.abs(ours[inner] - depth[inner]).mean() > 0.2  # it really filtered


def test_kernel_golden_cv2_joint_bilateral(rng):
    """σ_D = ∞ (no range kernel): equals cv2.ximgproc.jointBilateralFilter in the interior."""
    yy, xx = np.mgrid[0:40, 0:50]
    depth = (400 + 0.3 * xx + rng.normal(0, 0.5, (40, 50))).astype(np.float32)
    guide = np.clip(0.5 + 0.3 * np.sin(xx / 3.0) + 0.2 * (yy > 20), 0, 1).astype(np.float32)
    r, s_s, s_i = 4, 2.0, 0.1
    ours = joint_bilateral_frame(depth, guide, radius=r, sigma_spatial=s_s, sigma_intensity=s_i)
    ref = cv2.ximgproc.jointBilateralFilter(
        joint=guide, src=depth, d=2 * r + 1, sigmaColor=s_i, sigmaSpace=s_s
    )
    inner = (slice(r, -r), slice(r, -r))
    np.testing.assert_allclose(ours[inner], ref[inner], atol=5e-3)


def test_guided_matches_naive_formulas(plane, intrinsics, rng):
    depth, tex = plane
    noisy = depth + rng.normal(0, 0.2, depth.shape).astype(np.float32)
    out = run_baseline("guided", noisy, tex, intrinsics, size=3, eps=0.05**2)
    ref = naive_guided(tex[0], noisy[0], 3, 0.05**2)
    inner = (slice(8, -8), slice(8, -8))
    np.testing.assert_allclose(out[0][inner], ref[inner], atol=2e-3)


@pytest.mark.parametrize("half_window", [0, 1, 2])
def test_stmf_median_kernel_matches_naive_oracle(half_window, rng):
    from fuse4d._kernels.baselines import _stmf_median_kernel

    k, h, w = 5, 13, 19
    depth = (500 + rng.normal(0, 2.0, (k, h, w))).astype(np.float32)
    depth[rng.uniform(size=depth.shape) < 0.15] = np.nan
    intensity = rng.uniform(0, 0.2, (k, h, w)).astype(np.float32)
    vectors = rng.integers(-2, 3, (k, h, w, 2)).astype(np.int32)
    vectors[2] = 0
    size = k * (2 * half_window + 1) ** 2
    out = np.empty((h, w), np.float32)
    _stmf_median_kernel(depth, intensity, 2, vectors, half_window, 0.1, sorting_network(size), out)
    ref = naive_stmf_median(depth, intensity, 2, vectors, half_window, 0.1)
    np.testing.assert_array_equal(np.isnan(out), np.isnan(ref))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-4)
    assert np.isnan(ref).mean() < 0.5  # most pixels have candidates


@pytest.mark.parametrize("size", [1, 2, 5, 9, 27, 45, 75])
def test_stmf_sorting_network_sorts(size, rng):
    """The pruned Batcher network sorts every input of its size (random and 0-1 inputs)."""
    network = sorting_network(size)
    inputs = [rng.normal(size=size) for _ in range(200)]
    inputs += [rng.integers(0, 2, size).astype(float) for _ in range(200)]
    for x in inputs:
        y = x.copy()
        for i, j in network:
            y[i], y[j] = min(y[i], y[j]), max(y[i], y[j])
        np.testing.assert_array_equal(y, np.sort(x))


def test_block_matching_matches_oracle_and_finds_shift(rng):
    tex = cv2.GaussianBlur(rng.uniform(0, 1, (48, 64)).astype(np.float32), (0, 0), 1.5)
    moved = np.roll(tex, (2, -3), axis=(0, 1))  # content moves down 2, left 3
    from fuse4d._kernels.baselines import _block_match_kernel

    raw = np.empty((6, 8, 2), np.int32)
    _block_match_kernel(tex, moved, 8, 8, raw)
    np.testing.assert_array_equal(raw, naive_block_match(tex, moved, 8, 8))
    full = block_match(tex, moved)
    assert np.all(full[8:-8, 8:-8] == (-3, 2))


# ----------------------------------------------------------------- per-method contract


@pytest.mark.parametrize("name", _params(NAMES))
def test_reduces_noise_on_noisy_plane(name, plane, intrinsics, rng):
    depth, tex = plane
    noisy = depth + rng.normal(0, 0.2, depth.shape).astype(np.float32)
    out = _call(name, noisy, tex, intrinsics)
    inner = (slice(None), slice(MARGIN, -MARGIN), slice(MARGIN, -MARGIN))
    raw_err = _rms(noisy[inner], depth[inner])
    out_err = _rms(out[inner], depth[inner])
    assert out_err < 0.8 * raw_err, f"{name}: rms {out_err:.3f} vs raw {raw_err:.3f} mm"


@pytest.mark.parametrize("name", _params(NAMES))
def test_noise_free_plane_unchanged(name, plane, intrinsics):
    depth, tex = plane
    params = {"noise_sigma": 0.2} if name in ("adgf", "adbf", "dnbf", "ta", "adjbf") else {}
    out = _call(name, depth, tex, intrinsics, **params)
    inner = (slice(None), slice(MARGIN, -MARGIN), slice(MARGIN, -MARGIN))
    err = np.abs(out[inner] - depth[inner])
    assert np.all(np.isfinite(err))
    assert err.max() <= CLEAN_TOL.get(name, 0.02), f"{name}: max error {err.max():.3f} mm"


@pytest.mark.parametrize("name", _params(NAMES))
def test_nan_holes_do_not_spread(name, plane, intrinsics, rng):
    depth, tex = plane
    noisy = depth + rng.normal(0, 0.2, depth.shape).astype(np.float32)
    noisy[HOLE] = np.nan
    out = _call(name, noisy, tex, intrinsics)
    hole = np.zeros(depth.shape, bool)
    hole[HOLE] = True
    ring = np.zeros_like(hole)
    ring[:, 14:27, 24:38] = True
    ring &= ~hole
    assert np.all(np.isfinite(out[ring])), f"{name}: NaN spread around the hole"
    assert np.nanmax(np.abs(out[ring] - depth[ring])) < 1.0
    if not available_baselines()[name].fills_holes:
        np.testing.assert_array_equal(np.isnan(out), hole)


@pytest.mark.parametrize("name", _params(NAMES))
def test_knobs_change_the_result(name, plane, intrinsics, rng):
    depth, tex = plane
    noisy = depth + rng.normal(0, 0.2, depth.shape).astype(np.float32)
    info = available_baselines()[name]
    base = _call(name, noisy, tex, intrinsics, iterations=1)
    other_size = next(
        s for s in info.size_sweep if s != (1 if info.returns_points else info.default_size)
    )
    sized = _call(name, noisy, tex, intrinsics, size=other_size)
    iterated = _call(name, noisy, tex, intrinsics, iterations=2)
    assert not np.allclose(base, sized, equal_nan=True, atol=1e-4), f"{name}: size has no effect"
    assert not np.allclose(base, iterated, equal_nan=True, atol=1e-4), (
        f"{name}: iterations no effect"
    )


# ------------------------------------------------------------------------ method details


def test_temporal_mean_ghosts_on_moving_step(intrinsics):
    """A step moving 2 px/frame: the plain mean smears it, TA's range gate does not."""
    depth = np.full((T, H, W), 300.0, np.float32)
    for t in range(T):
        depth[t, :, 20 + 2 * t :] = 320.0
    mean = run_baseline("temporal-mean", depth, None, intrinsics, size=5)
    ta = run_baseline("ta", depth, None, intrinsics, size=5, noise_sigma=0.2)
    assert np.abs(mean - depth).max() > 5.0
    np.testing.assert_allclose(ta, depth, atol=1e-3)


def test_ta_matches_naive(rng, intrinsics):
    depth = (300 + rng.normal(0, 0.3, (T, H, W))).astype(np.float32)
    depth[2, 5:9, 5:9] = np.nan
    out = run_baseline("ta", depth, None, intrinsics, size=3, noise_sigma=0.2)
    ref = naive_temporal_average(depth.astype(np.float64), 3, 0.6)
    np.testing.assert_allclose(out, ref, atol=1e-4)


def test_adjbf_temporal_kalman_reduces_noise(plane, intrinsics, rng):
    depth, tex = plane
    noisy = depth + rng.normal(0, 0.2, depth.shape).astype(np.float32)
    plain = run_baseline("adjbf", noisy, tex, intrinsics)
    kalman = run_baseline("adjbf", noisy, tex, intrinsics, temporal=True)
    assert _rms(kalman[-1], depth[-1]) < _rms(plain[-1], depth[-1])


def test_kinectfusion_fallback_is_labelled_and_exact_on_plane(plane, intrinsics):
    depth, tex = plane
    pts = run_baseline("kinectfusion", depth, tex, intrinsics, backend="projective", size=1)
    assert pts.shape == (*depth.shape, 3)
    np.testing.assert_allclose(pts[..., 2], depth, atol=1e-3)


def test_kinectfusion_auto_is_the_projective_backend(plane, intrinsics):
    depth, tex = plane
    auto = run_baseline("kinectfusion", depth[:3], tex[:3], intrinsics, size=1)
    proj = run_baseline(
        "kinectfusion", depth[:3], tex[:3], intrinsics, size=1, backend="projective"
    )
    np.testing.assert_array_equal(auto, proj)


@pytest.mark.skipif(importlib.util.find_spec("open3d") is None, reason="open3d not installed")
def test_kinectfusion_open3d_backend_in_a_subprocess(tmp_path):
    """The Open3D TSDF path, isolated: its 0.20 ray cast can hang (rigid.py docstring)."""
    script = tmp_path / "kf.py"
    script.write_text(
        "import numpy as np\n"
        "from fuse4d import Intrinsics\n"
        "from fuse4d.baselines import run_baseline\n"
        "k = Intrinsics(200.0, 200.0, 31.5, 23.5, width=64, height=48)\n"
        "d = np.full((3, 48, 64), 500.0, np.float32)\n"
        "p = run_baseline('kinectfusion', d, None, k, size=1, backend='open3d')\n"
        "z = p[..., 2][np.isfinite(p[..., 2])]\n"
        "print(z.size, float(np.median(z)))\n"
    )
    try:
        res = subprocess.run(
            [sys.executable, str(script)], capture_output=True, text=True, timeout=30, check=False
        )
    except subprocess.TimeoutExpired:
        pytest.skip("Open3D 0.20 ray_cast hung (known intermittent issue, see rigid.py)")
    assert res.returncode == 0, res.stderr[-2000:]
    count, median = res.stdout.split()
    assert int(count) > 0
    assert abs(float(median) - 500.0) < 1.0


def test_ed_tracks_a_translating_plane(intrinsics, rng):
    """ED fusion of a plane moving 0.5 mm/frame along Z must not average the motion away."""
    _yy, xx = np.mgrid[0:H, 0:W]
    depth = np.stack([300.0 + 0.05 * xx + 0.5 * t for t in range(4)]).astype(np.float32)
    pts = run_baseline("ed", depth, None, intrinsics, size=1)
    inner = (slice(None), slice(MARGIN, -MARGIN), slice(MARGIN, -MARGIN))
    np.testing.assert_allclose(pts[..., 2][inner], depth[inner], atol=0.05)


def test_no_warnings_on_clean_call(plane, intrinsics):
    depth, tex = plane
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in ("adgf", "adbf", "guided", "dnbf", "ta", "adjbf", "stmf", "temporal-mean"):
            run_baseline(name, depth, tex, intrinsics)


# ------------------------------------------------------------------------------------- CLI


def test_cli_list(capsys):
    from fuse4d.cli import main

    assert main(["baseline", "--list"]) == 0
    out = capsys.readouterr().out
    for name in ("adgf", "temporal-mean", "kinectfusion", "realsense"):
        assert name in out


def test_cli_runs_baseline_and_refuses_overwrite(tmp_path, plane, intrinsics, rng, capsys):
    from fuse4d import Sequence
    from fuse4d.cli import main
    from fuse4d.io import load_sequence, save_sequence

    depth, tex = plane
    noisy = depth + rng.normal(0, 0.2, depth.shape).astype(np.float32)
    src = save_sequence(Sequence(noisy, tex, intrinsics), tmp_path / "in.npz")
    out = tmp_path / "out.npz"
    assert main(["baseline", "adjbf", str(src), "-o", str(out), "--size", "2"]) == 0
    result = load_sequence(out)
    expected = run_baseline("adjbf", noisy, tex, intrinsics, size=2)
    np.testing.assert_allclose(result.depth, expected, atol=1e-5)
    assert main(["baseline", "adjbf", str(src), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["baseline", "nope", str(src), "-o", str(tmp_path / "x.npz")]) == 2
    assert "unknown baseline" in capsys.readouterr().err
    # --size and -p size both given: the -p value was dropped silently
    other = str(tmp_path / "y.npz")
    assert main(["baseline", "adjbf", str(src), "-o", other, "--size", "2", "-p", "size=1"]) == 2
    assert "give --size or --param size=..., not both" in capsys.readouterr().err


def test_cli_realsense_runs_in_the_recordings_own_unit(tmp_path, plane, intrinsics, rng):
    """A 0.1 mm-unit recording (a D405's) ran the chain at 0.02 mm: the SDK's 20-unit delta
    was 0.4 mm, not the 2 mm a RealSense user gets."""
    from fuse4d import Sequence
    from fuse4d.cli import main
    from fuse4d.io import load_sequence, save_sequence

    if not available_baselines()["realsense"].available:
        pytest.skip("pyrealsense2 not installed (pip install 'fuse4d[realsense]')")
    depth, tex = plane
    noisy = depth[:3] + rng.normal(0, 0.5, depth[:3].shape).astype(np.float32)
    src = save_sequence(Sequence(noisy, tex[:3], intrinsics), tmp_path / "in", depth_unit_mm=0.1)
    outs = [tmp_path / "default.npz", tmp_path / "given.npz", tmp_path / "fine.npz"]
    assert main(["baseline", "realsense", str(src), "-o", str(outs[0])]) == 0
    assert (
        main(["baseline", "realsense", str(src), "-o", str(outs[1]), "-p", "depth_unit=0.1"]) == 0
    )
    assert (
        main(["baseline", "realsense", str(src), "-o", str(outs[2]), "-p", "depth_unit=0.02"]) == 0
    )
    default, given, fine = (load_sequence(p).depth for p in outs)
    np.testing.assert_array_equal(default, given)
    assert not np.array_equal(default, fine)


def test_cli_baseline_writes_a_folder_in_the_inputs_own_unit(
    tmp_path, plane, intrinsics, rng, capsys
):
    """A 0.05 mm-unit folder came back in 1 mm steps (5x the noise): Eq. 7 then read the
    rounding as roughness. Now the input's unit, as `fuse4d run` and `convert` write;
    --out-depth-unit-mm overrides it (and warns when coarse); the recording options reach
    the reader."""
    from fuse4d import Sequence
    from fuse4d.cli import main
    from fuse4d.io import load_sequence, save_sequence

    depth, tex = plane
    noisy = depth + rng.normal(0, 0.2, depth.shape).astype(np.float32)
    src = save_sequence(Sequence(noisy, tex, intrinsics), tmp_path / "in", depth_unit_mm=0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["baseline", "temporal-mean", str(src), "-o", str(tmp_path / "a")]) == 0
    own = load_sequence(tmp_path / "a").depth
    exact = run_baseline("temporal-mean", load_sequence(src).depth, None, intrinsics)
    assert np.nanmax(np.abs(own - exact)) <= 0.025 + 1e-4  # half of 0.05 mm
    with pytest.warns(UserWarning, match="is coarse"):  # the input itself, in 1 mm steps
        whole_mm = save_sequence(load_sequence(src), tmp_path / "in_mm", depth_unit_mm=1.0)
    with warnings.catch_warnings():  # its filtered result in the same 1 mm: no warning
        warnings.simplefilter("error")
        assert main(["baseline", "temporal-mean", str(whole_mm), "-o", str(tmp_path / "c")]) == 0
    coarse = ["baseline", "temporal-mean", str(src), "-o", str(tmp_path / "b")]
    with pytest.warns(UserWarning, match="depth_unit_mm=1 is coarse"):
        assert main([*coarse, "--out-depth-unit-mm", "1"]) == 0
    assert np.nanmax(np.abs(load_sequence(tmp_path / "b").depth - exact)) > 0.4
    capsys.readouterr()
    assert main([*coarse, "--force", "--depth-topic", "/d"]) == 2
    assert "option depth_topic does not apply to folder input" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("seed", "threshold", "rounds"), [(0, 0.05, 999), (1, 0.1, 999), (2, 0.3, 3)]
)
def test_region_grow_kernel_matches_the_numpy_rounds(seed, threshold, rounds):
    """Ad-BF's region growing visits only the pixels that can grow; every value, the pixels
    left empty and the round count are those of the numpy loop over the whole image (holes
    of every size, blocked by intensity, a round limit; thresholds not exact in float32)."""
    from fuse4d._kernels.baselines import _region_grow_kernel

    rng = np.random.default_rng(seed)
    h, w = 37, 53
    depth = (1000.0 + 50.0 * rng.random((h, w))).astype(np.float32)
    depth[rng.random((h, w)) < 0.3] = np.nan
    depth[5:20, 10:40] = np.nan  # a large hole
    depth[:, -4:] = np.nan  # a band along the border
    intensity = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.0)
    want, want_todo = depth.copy(), ~np.isfinite(depth)
    naive_region_grow(want, intensity, want_todo, threshold, rounds)
    got, got_todo = depth.copy(), ~np.isfinite(depth)
    grew = _region_grow_kernel(got, intensity, got_todo, np.float32(threshold), np.int64(rounds))
    np.testing.assert_array_equal(got, want)  # NaN where the numpy loop left NaN
    np.testing.assert_array_equal(got_todo, want_todo)
    assert 0 < grew <= rounds
    if rounds == 3:  # stopped by the round limit with holes left
        assert grew == 3
        assert np.isnan(got).any()


def test_region_grow_kernel_matches_on_a_real_frame(shared_data):
    """The same on a real Kinect-class frame (uva: a 40-px band without depth around the
    image, shadows, hair), the case that took the numpy loop 3 s."""
    from fuse4d import load_sequence
    from fuse4d._kernels.baselines import _region_grow_kernel

    folder = shared_data / "uva_cv2_person_turning"
    if not folder.is_dir():
        pytest.skip(f"{folder} not present (the shared data)")
    seq = load_sequence(folder, frames="10:11")
    depth, intensity = seq.depth[0].copy(), seq.intensity[0]
    h, w = depth.shape
    want, want_todo = depth.copy(), ~np.isfinite(depth)
    naive_region_grow(want, intensity, want_todo, 0.05, h + w)
    got, got_todo = depth.copy(), ~np.isfinite(depth)
    _region_grow_kernel(got, intensity, got_todo, np.float32(0.05), np.int64(h + w))
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    ("name", "params", "says"),
    [
        ("adbf", {"size": 10**6}, r"adaptive_bilateral.size must be an integer in \[1, 64\]"),
        ("guided", {"size": 65}, r"guided.size must be an integer in \[1, 64\]"),
        ("adgf", {"size": float("inf")}, r"adaptive_gaussian.size must be a finite number"),
        ("stmf", {"block": 10**6}, r"block must be an integer in \[1, 64\]"),  # was a MemoryError
        ("stmf", {"search": 10**6}, r"search must be an integer in \[0, 64\]"),
        ("realsense", {"spatial_alpha": 0.0}, r"spatial_alpha: 0 is outside the SDK's range"),
        ("realsense", {"persistence": 9}, r"persistence: 9 is outside the SDK's range \[0, 8\]"),
        ("realsense", {"depth_unit": -1.0}, r"depth_unit must be a finite number > 0, got -1"),
        # NaN / inf an internal error, -5 one step, inf baseline or unit an all-NaN output
        ("realsense", {"spatial_delta": np.nan}, "spatial_delta must be a finite number > 0"),
        ("realsense", {"spatial_delta": np.inf}, "spatial_delta must be a finite number > 0"),
        ("realsense", {"temporal_delta": -5.0}, "temporal_delta must be a finite number > 0"),
        ("realsense", {"baseline_mm": np.inf}, "baseline_mm must be a finite number"),
        ("realsense", {"depth_unit": np.inf}, "depth_unit must be a finite number"),
        ("realsense", {"depth_unit": 1e6}, "rounds the nearest depth"),
        # inf / tiny sizes ran for hours in compiled code that only SIGKILL stopped
        ("kinectfusion", {"noise_sigma": np.inf}, "noise_sigma must be a finite number"),
        ("kinectfusion", {"voxel_size": np.inf}, "voxel_size must be a finite number"),
        ("kinectfusion", {"trunc_voxels": 1e9}, "ray steps across the recording's depth range"),
        ("kinectfusion", {"voxel_size": 1e-9}, "ray steps across the recording's depth range"),
        ("adgf", {"size": 1e6}, r"adaptive_gaussian.size must be a finite number in \(0, 19"),
        ("ed", {"band": np.inf}, "band must be a finite number"),
        ("ta", {"noise_sigma": np.inf}, "noise_sigma must be a finite number"),
    ],
)
def test_baseline_knobs_out_of_range_are_parameter_errors(plane, intrinsics, name, params, says):
    """Each hung (a radius of a million px; kinectfusion's ray march with an infinite or
    tiny voxel), ran out of memory (STMF's block), surfaced pyrealsense2's bare 'out of
    range value for argument' as an internal error, or gave an all-NaN output."""
    from fuse4d.errors import ParameterError

    depth, inten = plane
    with pytest.raises(ParameterError, match=says):
        _call(name, depth, inten, intrinsics, **params)


@pytest.mark.parametrize("name", ["dnbf", "adjbf"])
def test_integer_intensity_is_the_unit_intensity_and_0_255_floats_are_refused(
    name, plane, intrinsics, rng
):
    """A uint8 guide was taken as 0-255, so every intensity weight was ~0: the joint filters
    then smoothed nothing. Integers are divided by their dtype maximum, as for the fusion."""
    depth, tex = plane
    noisy = (depth + rng.normal(0, 0.2, depth.shape)).astype(np.float32)
    as_uint8 = np.round(255 * tex).astype(np.uint8)
    from_uint8 = run_baseline(name, noisy, as_uint8, intrinsics)
    np.testing.assert_allclose(from_uint8, run_baseline(name, noisy, as_uint8 / 255.0, intrinsics))
    with pytest.raises(ParameterError, match=r"^intensity is float with values in \[.*, 2\d\d"):
        run_baseline(name, noisy, 255.0 * tex, intrinsics)


# ------------------------------------------------------------------ stop 57 (tester's issues)


def test_depth_guided_filter_is_exact_at_metres_of_depth(intrinsics, rng):
    """guide='depth' ran OpenCV's float32 filter on depth in mm: mean(D^2) - mean(D)^2
    cancelled at metres (NaN even on a constant 3955 mm frame) and most valid depth came out
    NaN. Now float64 box means: equal to the exact filter, no raw-valid pixel lost."""
    yy, xx = np.mgrid[0:H, 0:W]
    depth = np.empty((2, H, W), np.float32)
    depth[0] = 3955.0  # constant: was all NaN
    depth[1] = 3000.0 + 8.0 * xx + 5.0 * yy + rng.normal(0, 3.0, (H, W))
    depth[1, :, 40:] += 400.0  # a step edge
    for radius, eps in ((2, 10.0), (4, 0.01)):
        out = run_baseline("guided", depth, None, intrinsics, size=radius, eps=eps, guide="depth")
        assert np.isfinite(out).all()
        np.testing.assert_allclose(out[0], 3955.0, atol=1e-3)
        ref = naive_guided(depth[1], depth[1], radius, eps)  # float64, valid off the border
        inner = (slice(2 * radius, -2 * radius), slice(2 * radius, -2 * radius))
        np.testing.assert_allclose(out[1][inner], ref[inner], atol=2e-3)
    # holes stay NaN, every raw-valid pixel keeps a value
    holed = depth.copy()
    holed[:, 20:26, 10:30] = np.nan
    out = run_baseline("guided", holed, None, intrinsics, size=2, eps=10.0, guide="depth")
    np.testing.assert_array_equal(np.isfinite(out), np.isfinite(holed))


def test_realsense_disparity_chain_has_no_depth_bias(rng):
    """The disparity domain packed disparity into Z16 steps; the SDK's integer spatial filter
    then added ~+4 steps to the mean: depth moved towards the camera by ~z^2 (-56 mm on this
    4.5 m plane). Now the SDK's own disparity_transform on a sensor that declares its stereo
    baseline: float disparity, no bias. The default delta keeps its meaning (20/32 px)."""
    if not available_baselines()["realsense"].available:
        pytest.skip("pyrealsense2 not installed (pip install 'fuse4d[realsense]')")
    k = Intrinsics(fx=380.0, fy=380.0, cx=31.5, cy=23.5, width=W, height=H)
    noisy = np.rint(4500.0 + rng.normal(0, 40.0, (3, H, W))).astype(np.float32)
    out = run_baseline("realsense", noisy, None, k, hole_filling=None)
    assert np.isfinite(out).all()
    # harmonic vs arithmetic mean of the disparity average alone: -sigma^2/z = -0.36 mm
    assert abs(float(np.mean(out - noisy))) < 3.0
    assert float(np.std(out[-1])) < 0.2 * float(np.std(noisy[-1]))  # it does smooth
    # 20 SDK units = 0.625 px of disparity: at 2 m (9.5 px, 0.625 px = 141 mm) a 160 mm step
    # stays sharp, a 50 mm step is smoothed across
    for step, sharp in ((160.0, True), (50.0, False)):
        plane = np.full((3, H, W), 2000.0, np.float32)
        plane[:, :, 32:] += step
        out = run_baseline("realsense", plane, None, k, hole_filling=None)
        assert np.array_equal(out[-1, 20, 29:35], plane[-1, 20, 29:35]) == sharp


@pytest.mark.parametrize(
    ("name", "params"),
    [
        ("ta", {"noise_sigma": 1e-300}),  # was a ZeroDivisionError
        ("ta", {"noise_sigma": 1e-300, "sigma_temporal": 1e-300}),  # so was this
        ("adbf", {"noise_sigma": 1e-46, "hole_repair": False}),  # 0 in float32: range "off"
        ("adjbf", {"noise_sigma": 1e-46}),
        ("adjbf", {"noise_sigma": 1e-46, "sigma_intensity": 1e-200}),  # ZeroDivisionError
        ("dnbf", {"noise_sigma": 1e-300, "sigma_temporal": 1e-300}),  # NaN time weight
    ],
)
def test_tiny_sigmas_are_the_limit_of_a_narrow_kernel(name, params, plane, intrinsics, rng):
    """A vanishing sigma must act as the narrowest kernel: nothing within range, output ==
    input (a smaller sigma blurred more, or crashed). gauss_factor caps 1 / (2 sigma^2)."""
    depth, tex = plane
    noisy = (depth + rng.normal(0, 0.5, depth.shape)).astype(np.float32)  # all values differ
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = run_baseline(name, noisy, tex, intrinsics, **params)
    np.testing.assert_allclose(out, noisy, rtol=1e-6)


def test_adbf_repair_stays_inside_the_field_of_view(intrinsics, rng):
    """Ad-BF's region growing flooded the no-depth band around a registered depth image
    (99.6 % of it on uva) with invented depth; it now fills holes inside the raw depth's
    field of view only (A38, as fuse4d's own fills)."""
    from fuse4d.fov import field_of_view

    yy, xx = np.mgrid[0:H, 0:W]
    depth = np.broadcast_to(1000.0 + 0.5 * xx + 0.3 * yy, (2, H, W)).astype(np.float32)
    depth = depth + rng.normal(0, 0.3, depth.shape).astype(np.float32)
    depth[:, :5, :] = np.nan  # the band without depth
    depth[:, :, 56:] = np.nan
    depth[:, 20:26, 20:30] = np.nan  # an interior hole
    tex = np.full(depth.shape, 0.5, np.float32)  # flat: the growing accepts every neighbour
    inside = field_of_view(depth)
    assert not inside[:5].any()
    assert not inside[:, 56:].any()
    assert inside[20:26, 20:30].all()
    out = run_baseline("adbf", depth, tex, intrinsics)
    assert np.isnan(out[:, ~inside]).all()
    assert np.isfinite(out[:, inside]).all()  # the interior hole is still repaired


def test_noise_estimate_reads_depth_0_as_no_depth(rng):
    """0 is "no depth" in 16-bit files: a hole stored as 0 counted as noise-free residuals
    (0.349 instead of 0.497 mm on the tester's data)."""
    from fuse4d.baselines._common import estimate_noise_model

    depth = (1000.0 + rng.normal(0, 0.5, (3, 64, 64))).astype(np.float32)
    as_nan, as_zero = depth.copy(), depth.copy()
    as_nan[:, 8:40, 8:40] = np.nan
    as_zero[:, 8:40, 8:40] = 0.0
    assert estimate_noise_sigma(as_nan) == pytest.approx(0.5, rel=0.05)
    assert estimate_noise_sigma(as_zero) == estimate_noise_sigma(as_nan)
    assert estimate_noise_model(as_zero) == estimate_noise_model(as_nan)


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--iterations", "2.5"], "parameter iterations: cannot read '2.5' as an integer\n"),
        (["-p", "iterations=2.5"], "parameter iterations: cannot read '2.5' as an integer\n"),
        (["-p", "noise_sigma=abc"], "parameter noise_sigma: cannot read 'abc' as a number\n"),
        (["--size", "2.5"], "cannot read '2.5' as an integer (size = num_frames)\n"),
        (["-p", "num_frames=x"], "cannot read 'x' as an integer (size = num_frames)\n"),
    ],
)
def test_cli_knob_errors_name_only_what_applies(tmp_path, plane, intrinsics, capsys, args, says):
    """'--iterations 2.5' ended with '(size = num_frames)', irrelevant to --iterations."""
    from fuse4d import Sequence
    from fuse4d.cli import main
    from fuse4d.io import save_sequence

    depth, tex = plane
    src = save_sequence(Sequence(depth[:2], tex[:2], intrinsics), tmp_path / "in.npz")
    assert main(["baseline", "ta", str(src), "-o", str(tmp_path / "o.npz"), *args]) == 2
    assert capsys.readouterr().err.endswith(says)
