"""Tests of fuse4d.synthetic: geometry, ground truth, noise streams, errors, CLI."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from fuse4d import Sequence
from fuse4d.cli import main
from fuse4d.io import load_sequence
from fuse4d.synthetic import (
    make_deforming_sheet,
    make_falling_ball,
    make_scene,
    make_static_plane,
    scene_intrinsics,
)


@pytest.mark.parametrize("factory", [make_falling_ball, make_static_plane, make_deforming_sheet])
def test_shapes_and_ground_truth(factory):
    seq = factory(small=True, num_frames=3)
    assert isinstance(seq, Sequence)
    assert seq.depth.shape == (3, 150, 150)
    assert seq.depth.dtype == np.float32
    assert seq.intrinsics == scene_intrinsics(small=True)
    gt = seq.ground_truth
    assert gt.depth.shape == (3, 150, 150)
    assert gt.mask.dtype == bool
    assert gt.flow.shape == (2, 150, 150, 2)
    assert gt.flow.dtype == np.float32
    assert seq.intensity.min() >= 0.0
    assert seq.intensity.max() <= 1.0
    assert np.isfinite(seq.depth).all()  # background wall: every pixel valid
    assert gt.extra["seed"] == 0


def test_default_frame_counts():
    assert make_falling_ball(small=True).num_frames == 12
    assert make_falling_ball(small=True, num_frames=5).num_frames == 5


def test_ball_depth_lies_on_the_sphere():
    seq = make_falling_ball(small=True, num_frames=3, depth_noise=0.0)
    gt = seq.ground_truth
    pts = seq.points()
    for t in range(3):
        centre = gt.scene.center_mm[t]
        dist = np.linalg.norm(pts[t][gt.mask[t]] - centre, axis=1)
        np.testing.assert_allclose(dist, 140.0, atol=2e-3)
        assert np.all(pts[t][~gt.mask[t]][:, 2] == 1000.0)
    # projected centre row v_c(t) = 62.125 + 0.5 t (full size: 250 + 2 t)
    np.testing.assert_allclose(gt.scene.center_row, [62.125, 62.625, 63.125])
    rows = np.nonzero(gt.mask[0].any(axis=1))[0]
    assert rows.min() < 62.125 - 45
    assert rows.max() > 62.125 + 45


def test_ball_flow_and_brightness_constancy():
    seq = make_falling_ball(small=True, num_frames=3, intensity_noise=0.0)
    gt = seq.ground_truth
    # exact image motion of a point at depth Z translating along Y: speed * z0 / Z
    on = gt.mask[:-1]
    np.testing.assert_allclose(gt.flow[..., 1][on], 0.5 * 700.0 / gt.depth[:-1][on], rtol=1e-5)
    assert not gt.flow[..., 1][~on].any()
    assert 0.5 < gt.flow[..., 1][on].min() < 0.53
    assert 0.6 < gt.flow[..., 1][on].max() < 0.63  # front of the ball, Z = 560 mm
    assert not gt.flow[..., 0].any()
    _check_brightness_constancy(seq, max_error=0.005)


def test_sheet_flow_brightness_constancy():
    seq = make_deforming_sheet(small=True, num_frames=4, intensity_noise=0.0)
    flow = seq.ground_truth.flow
    on = seq.ground_truth.mask[:-1]
    assert np.abs(flow[..., 0][on] - 0.125).max() < 0.02  # 0.5 px/frame x pixel_scale
    assert not flow[~on].any()
    _check_brightness_constancy(seq, max_error=0.01)


def _check_brightness_constancy(seq, *, max_error):
    """Warp frame t+1 back with the GT flow: the texture must match on the object interior."""
    gt = seq.ground_truth
    h, w = seq.shape
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    for t in range(seq.num_frames - 1):
        mx = cols + gt.flow[t, ..., 0]
        my = rows + gt.flow[t, ..., 1]
        warped = cv2.remap(seq.intensity[t + 1], mx, my, interpolation=cv2.INTER_LINEAR)
        inner = cv2.erode(gt.mask[t].astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
        err = np.abs(warped - seq.intensity[t])[inner]
        assert err.mean() < max_error
        # and the texture is really there: a zero-flow warp is much worse
        assert np.abs(seq.intensity[t + 1] - seq.intensity[t])[inner].mean() > 3 * err.mean()


def test_noise_levels():
    seq = make_falling_ball(small=True, num_frames=4, depth_noise=0.3, intensity_noise=0.05)
    gt = seq.ground_truth
    resid = (seq.depth - gt.depth).ravel()
    assert resid.std() == pytest.approx(0.3, rel=0.02)
    assert abs(resid.mean()) < 0.01
    clean = make_falling_ball(small=True, num_frames=4, depth_noise=0.0, intensity_noise=0.0)
    np.testing.assert_array_equal(clean.depth, gt.depth)
    di = seq.intensity - clean.intensity
    interior = (clean.intensity > 0.2) & (clean.intensity < 0.8)
    assert di[interior].std() == pytest.approx(0.05, rel=0.03)


def test_independent_streams():
    a = make_falling_ball(small=True, num_frames=3, depth_noise=0.1, intensity_noise=0.02)
    b = make_falling_ball(small=True, num_frames=3, depth_noise=0.4, intensity_noise=0.02)
    c = make_falling_ball(small=True, num_frames=3, depth_noise=0.1, intensity_noise=0.08)
    np.testing.assert_array_equal(a.intensity, b.intensity)  # intensity: only (seed, sigma_I)
    np.testing.assert_array_equal(a.depth, c.depth)  # depth: only (seed, sigma_d)
    d = make_falling_ball(small=True, num_frames=3, rng=1)
    assert not np.array_equal(a.intensity, d.intensity)
    # frame t does not depend on the sequence length
    e = make_falling_ball(small=True, num_frames=5, depth_noise=0.1)
    np.testing.assert_array_equal(a.depth, e.depth[:3])
    # the same seed reproduces exactly
    np.testing.assert_array_equal(
        a.depth, make_falling_ball(small=True, num_frames=3, depth_noise=0.1).depth
    )


def test_structural_noise_is_fixed_over_time():
    seq = make_falling_ball(small=True, num_frames=3, depth_noise=0.0, structural_noise=0.15)
    resid = seq.depth - seq.ground_truth.depth
    np.testing.assert_allclose(resid[0], resid[2], atol=1e-4)
    assert resid[0].std() == pytest.approx(0.15, rel=0.05)


def test_background_none_is_nan_without_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        seq = make_falling_ball(small=True, num_frames=2, background="none")
    np.testing.assert_array_equal(np.isfinite(seq.depth), seq.ground_truth.mask)


def test_static_plane_geometry_and_texture_noise():
    seq = make_static_plane(small=True, num_frames=30, structural_noise=0.0)
    gt = seq.ground_truth
    on = gt.mask[0]
    assert (gt.mask == on).all()
    assert not gt.flow.any()
    pts = seq.with_depth(gt.depth).points()[0][on]
    normal = gt.scene.normal
    np.testing.assert_allclose(pts @ normal, 500.0 * normal[2], atol=1e-3)  # on the plane
    assert on.sum() == pytest.approx(120 * 80 * np.cos(np.radians(15)) * (0.25 * 2) ** 2, rel=0.08)
    # texture-correlated noise: dark pixels are noisier
    std = seq.depth.std(axis=0)
    albedo = seq.intensity.mean(axis=0) / (0.3 + 0.7 * np.cos(np.radians(15)))
    dark, bright = on & (albedo < 0.35), on & (albedo > 0.65)
    ratio = std[dark].mean() / std[bright].mean()
    assert 1.3 < ratio < 2.0


def test_static_plane_structural_noise():
    seq = make_static_plane(small=True, num_frames=2, depth_noise=0.0, structural_noise=0.02)
    resid = seq.depth - seq.ground_truth.depth
    np.testing.assert_allclose(resid[0], resid[1], atol=1e-5)
    assert resid.std() == pytest.approx(0.02, rel=0.05)


def test_deforming_sheet_bump():
    seq = make_deforming_sheet(
        small=True, num_frames=30, depth_noise=0.0, period_frames=40.0, drift_px=0.0
    )
    gt = seq.ground_truth
    centre = gt.depth[:, 75, 75]  # 1.1 mm from the sheet centre (no drift): g = 0.997
    bump = 3.0 * np.sin(2 * np.pi * np.arange(30) / 40)
    np.testing.assert_allclose(centre, 550.0 - 0.997 * bump, atol=2e-3)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"depth_noise": -0.1}, "depth_noise must be a finite number >= 0"),
        ({"intensity_noise": 2.0}, "intensity_noise is a fraction"),
        ({"num_frames": 1}, "num_frames must be an integer >= 2"),
        ({"background": "wall"}, "background must be 'plane' or 'none'"),
    ],
)
def test_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make_falling_ball(small=True, **kwargs)


def test_bad_rng_and_scene():
    from fuse4d.errors import ParameterError, ParameterTypeError

    with pytest.raises(ParameterTypeError, match="rng must be a non-negative int seed"):
        make_falling_ball(small=True, rng=1.5)
    # out of the range an .npz holds: refused before rendering, in every scene (2**64 was
    # rendered, then refused by write_npz as an object array)
    for seed in (-1, 2**64):
        for factory in (make_falling_ball, make_static_plane, make_deforming_sheet):
            with pytest.raises(ParameterError, match=r"rng must be a seed in \[0, 2\*\*64\)"):
                factory(small=True, num_frames=2, rng=seed)
    with pytest.raises(ValueError, match="unknown scene 'cube'; choose one of ball, plane, sheet"):
        make_scene("cube")


def test_generator_rng_recorded():
    seq = make_static_plane(small=True, num_frames=2, rng=np.random.default_rng(5))
    again = make_static_plane(small=True, num_frames=2, rng=seq.ground_truth.extra["seed"])
    np.testing.assert_array_equal(seq.depth, again.depth)


def test_the_largest_seed_round_trips_through_npz(tmp_path):
    from fuse4d.io import write_npz

    seq = make_falling_ball(small=True, num_frames=2, rng=2**64 - 1)
    write_npz(seq, tmp_path / "s.npz")
    seed = load_sequence(tmp_path / "s.npz").ground_truth.extra["seed"]
    assert seed == 2**64 - 1
    again = make_falling_ball(small=True, num_frames=2, rng=seed)
    np.testing.assert_array_equal(again.depth, seq.depth)


def test_a_scene_larger_than_the_memory_is_refused_before_rendering(monkeypatch):
    """--frames 99999999999999999999 was numpy's "Maximum allowed size exceeded", 10**9 a
    MemoryError: both are estimated (every array kept) and refused naming num_frames."""
    from fuse4d import synthetic
    from fuse4d.errors import ParameterError

    assert synthetic._available_memory() > 0  # Linux: MemAvailable and the limits are read
    for factory in (make_falling_ball, make_static_plane, make_deforming_sheet):
        with pytest.raises(ParameterError, match=r"num_frames=10{20}: .* GiB of memory, "):
            factory(small=True, num_frames=10**20)
    room = int(11.5 * 150 * 150 * synthetic.PAPER_SCENE_BYTES)  # 11 frames fit, 12 do not
    monkeypatch.setattr(synthetic, "_available_memory", lambda: room)
    with pytest.raises(ParameterError, match=r"num_frames=12: the static plane .* 0.0 GiB is"):
        make_static_plane(small=True, num_frames=12)
    assert make_static_plane(small=True, num_frames=11).num_frames == 11


@pytest.mark.slow
def test_full_size_ball_builds():
    seq = make_falling_ball(num_frames=3)
    assert seq.shape == (600, 600)
    np.testing.assert_allclose(seq.ground_truth.scene.center_row, [250.0, 252.0, 254.0])
    ball_flow = seq.ground_truth.flow[0][seq.ground_truth.mask[0]][:, 1]
    assert 2.0 < ball_flow.min() < 2.1
    assert 2.49 < ball_flow.max() <= 2.5


def test_cli_synth_round_trip(tmp_path, capsys):
    out = tmp_path / "sheet.npz"
    args = ["synth", "sheet", "-o", str(out), "--small", "--frames", "3", "--seed", "4"]
    assert main([*args, "--depth-noise", "0.3", "--intensity-noise", "0.05"]) == 0
    seq = load_sequence(out)
    ref = make_deforming_sheet(
        small=True, num_frames=3, rng=4, depth_noise=0.3, intensity_noise=0.05
    )
    np.testing.assert_array_equal(seq.depth, ref.depth)
    np.testing.assert_array_equal(seq.ground_truth.flow, ref.ground_truth.flow)
    assert seq.ground_truth.extra["depth_noise"] == 0.3
    capsys.readouterr()
    assert main(args) == 2
    assert "output exists; pass --force" in capsys.readouterr().err
    assert main([*args, "--force"]) == 0
    assert (
        main(["synth", "ball", "-o", str(tmp_path / "y.npz"), "--small", "--depth-noise", "-1"])
        == 2
    )
    assert "depth_noise must be a finite number >= 0" in capsys.readouterr().err


def test_cli_synth_prints_the_depth_noise_there_is(tmp_path, capsys):
    """The plane's noise is depth_noise x (2 - albedo) plus a fixed pattern: synth printed
    "depth noise 0.2 mm" where depth - truth had a std of 0.304 mm."""
    import re

    out = tmp_path / "p.npz"
    args = ["synth", "plane", "--small", "--frames", "4", "--depth-noise", "0.2", "-o", str(out)]
    assert main(args) == 0
    err = " ".join(capsys.readouterr().err.split())
    printed = float(re.search(r"depth noise std ([0-9.]+) mm", err).group(1))
    seq = load_sequence(out)
    measured = float(np.nanstd(seq.depth - seq.ground_truth.depth))
    assert printed == pytest.approx(measured, rel=0.01)
    assert printed > 0.25  # not the 0.2 mm base
    assert "--depth-noise 0.2 mm, x1-2 on dark texture, + 0.02 mm fixed pattern" in err
    assert "150x150" in err


def test_cli_synth_help_gives_the_scenes_distances_and_defaults():
    """The help said the paper scenes were at 1 m with 0.2 mm noise: the defaults and
    distances of the code."""
    import inspect

    from fuse4d.cli.cmd_eval import synth_command
    from fuse4d.synthetic import BALL_CENTER_Z_MM, SCENES

    params = inspect.signature(synth_command, eval_str=True).parameters
    scene_help = params["scene"].annotation.__metadata__[0].help
    noise_help = params["depth_noise"].annotation.__metadata__[0].help
    assert "1 m, 0.2 mm" not in scene_help
    assert f"ball centre at {BALL_CENTER_Z_MM / 1000:g} m" in scene_help
    plane = make_static_plane(small=True, num_frames=2).ground_truth.scene
    assert f"plane at {plane.center_mm[2] / 1000:g} m" in scene_help
    sheet = make_deforming_sheet(small=True, num_frames=2).ground_truth.scene
    assert f"sheet at {sheet.sheet_z_mm / 1000:g} m" in scene_help
    for name, factory in SCENES.items():
        default = inspect.signature(factory).parameters["depth_noise"].default
        assert f"{name} {default:g}" in noise_help
    structural = inspect.signature(make_static_plane).parameters["structural_noise"].default
    assert f"{structural:g} mm fixed pattern" in noise_help


def test_a_containers_file_cache_counts_as_available_memory(monkeypatch):
    """memory.current of a cgroup counts the file cache the kernel gives back on demand: a
    container that had read a few GB refused a 0.7 GiB scene ('0.1 GiB is available')."""
    import pathlib

    from fuse4d import synthetic

    gib = 1 << 30
    fake = {
        "/sys/fs/cgroup/memory.max": str(8 * gib),
        "/sys/fs/cgroup/memory.current": str(int(7.9 * gib)),
        # mostly active cache: the kernel keeps inactive_file at a fraction of it
        "/sys/fs/cgroup/memory.stat": f"anon {int(0.9 * gib)}\nfile {7 * gib}\n"
        f"active_file {int(6.7 * gib)}\ninactive_file {int(0.3 * gib)}\nfile_dirty {gib}\n",
        "/proc/meminfo": "MemTotal: 100000000 kB\nMemAvailable: 90000000 kB\nSwapFree: 0 kB\n",
    }
    real = pathlib.Path.read_text
    monkeypatch.setattr(
        pathlib.Path, "read_text", lambda self, *a, **k: fake.get(str(self)) or real(self, *a, **k)
    )
    available = synthetic._available_memory()
    assert 6 * gib <= available <= 6.2 * gib  # 8 - 7.9 + (7 - 1 dirty)
