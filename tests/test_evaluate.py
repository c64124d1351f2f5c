"""``fuse4d.metrics.evaluate``: one scoring policy, raw and output on the same pixels."""

from __future__ import annotations

import io
import json
import math
import typing
import warnings
from dataclasses import replace

import numpy as np
import pytest
from rich.console import Console

from fuse4d import FusionParams, Intrinsics, Sequence, ShapeError, depth_to_points
from fuse4d.baselines.temporal import temporal_mean
from fuse4d.cli import main
from fuse4d.cli._app import out_console
from fuse4d.cli.cmd_eval import metrics_command
from fuse4d.cli.cmd_fuse import run_summary_table
from fuse4d.errors import ParameterError
from fuse4d.io import load_sequence, save_sequence, write_npz
from fuse4d.metrics import (
    RunningEvaluation,
    default_roi,
    evaluate,
    roughness_maps,
    roughness_stats,
    shape_correctness,
)
from fuse4d.motion import estimate_noise_quad
from fuse4d.range_scenes import make_range_scene
from fuse4d.sequence import BallTruth, GroundTruth
from fuse4d.synthetic import make_falling_ball, make_static_plane


@pytest.fixture(scope="module")
def plane():
    """A static plane without ground truth (so the default, noise-model ROI applies)."""
    seq = make_static_plane(small=True, num_frames=4, depth_noise=0.3, rng=1)
    return seq, Sequence(seq.depth, seq.intensity, seq.intrinsics)


def test_raw_and_output_are_scored_on_the_same_pixels(plane):
    truth, raw = plane
    out = truth.ground_truth.depth.copy()
    out[:, 40:60, 40:60] = np.nan  # the output drops a block the raw has
    rep = evaluate(out, raw=raw, intrinsics=raw.intrinsics)
    np.testing.assert_array_equal(rep.raw.roughness.num_pixels, rep.output.roughness.num_pixels)
    alone = roughness_stats(raw.points(), roi=rep.roi)  # the raw on its own pixels
    assert (alone.num_pixels > rep.raw.roughness.num_pixels).all()
    # the ROI comes from the raw, whatever the output: one ROI for both
    other = evaluate(raw.depth + 1.0, raw=raw, intrinsics=raw.intrinsics)
    np.testing.assert_array_equal(rep.roi, other.roi)
    np.testing.assert_array_equal(rep.roi, default_roi(raw.depth))
    assert rep.static is not None
    assert rep.static.shape == raw.shape
    assert rep.raw.flicker.num_pixels == rep.output.flicker.num_pixels


def test_smoother_is_reported_smoother_and_rougher_rougher(plane, rng):
    truth, raw = plane
    smooth = evaluate(truth.ground_truth.depth, raw=raw, intrinsics=raw.intrinsics)
    assert smooth.output.roughness.mean < 0.3 * smooth.raw.roughness.mean
    assert smooth.output.roughness.rms_mean < smooth.raw.roughness.rms_mean
    assert smooth.output.flicker.step_mean < 0.1 * smooth.raw.flicker.step_mean
    noisy = raw.depth + rng.normal(0.0, 0.5, raw.depth.shape).astype(np.float32)
    rough = evaluate(noisy, raw=raw, intrinsics=raw.intrinsics)
    assert rough.output.roughness.mean > 1.3 * rough.raw.roughness.mean
    assert rough.output.flicker.step_mean > rough.raw.flicker.step_mean
    np.testing.assert_array_equal(rough.roi, smooth.roi)


def test_ground_truth_scene_roi_rmse_and_shape():
    seq = make_falling_ball(small=True, num_frames=3)
    gt = seq.ground_truth
    rep = evaluate(gt.depth, raw=seq, shape=True, shape_frames=[0, 2])
    assert rep.roi_description.startswith("ball ROI")
    assert rep.static_description.startswith("static in the ground truth")
    assert rep.output.rmse_roi == 0.0
    assert rep.raw.rmse_roi == pytest.approx(0.2, rel=0.1)
    assert rep.output.bad_1mm == 0.0
    assert rep.output.shape.c_3d.shape == (2,)
    assert rep.output.shape.c_3d.min() > 0.999
    # interior frames only, and a given ROI replaces the scene ROI for every metric
    inner = evaluate(seq, frames=slice(1, 2))
    assert inner.roi.shape == (1, 150, 150)
    roi = np.zeros(seq.shape, bool)
    roi[:10, :10] = True  # wall only: static
    given = evaluate(seq, roi=roi)
    assert given.roi_description == "the given mask"
    assert given.static.sum() <= roi.sum()
    assert given.output.flicker.num_pixels <= 100


def test_report_to_dict_names_regions_and_both_videos(plane):
    truth, raw = plane
    d = evaluate(truth.ground_truth.depth, raw=raw, intrinsics=raw.intrinsics).to_dict()
    assert set(d) >= {"roi", "static", "output", "raw", "window"}
    assert d["roi"]["pixels_scored"] == d["output"]["roughness_pixels"]
    assert d["raw"]["roughness_pixels"] == d["output"]["roughness_pixels"]
    json.dumps(d)  # JSON friendly


def test_running_evaluation_matches_evaluate_per_frame(plane):
    truth, raw = plane
    out = truth.ground_truth.depth
    run = RunningEvaluation()
    out_pts = depth_to_points(out, raw.intrinsics)
    raw_pts = raw.points()
    for t in range(raw.num_frames):
        run.add(raw_pts[t], out_pts[t])
    res = run.result()
    rep = evaluate(out, raw=raw, intrinsics=raw.intrinsics)
    assert res["raw_roughness"] == pytest.approx(rep.raw.roughness.mean, rel=1e-12)
    assert res["output_roughness"] == pytest.approx(rep.output.roughness.mean, rel=1e-12)
    assert res["static_pixels"] == rep.raw.flicker.num_pixels
    assert res["raw_flicker"] == pytest.approx(rep.raw.flicker.step_mean, rel=1e-9)
    assert res["output_flicker"] == pytest.approx(rep.output.flicker.step_mean, rel=1e-9)


def test_running_evaluation_with_the_callers_noise_quad(plane):
    """Given each frame's q (what ``fuse4d run`` takes from the engine), the scores are those
    of the q it estimates itself; a coarser q (larger steps allowed) widens the ROI."""
    from fuse4d.motion import estimate_noise_quad

    truth, raw = plane
    out_pts = depth_to_points(truth.ground_truth.depth, raw.intrinsics)
    raw_pts = raw.points()
    own, given, other = RunningEvaluation(), RunningEvaluation(), RunningEvaluation()
    for t in range(raw.num_frames):
        own.add(raw_pts[t], out_pts[t])
        q = estimate_noise_quad(raw.depth[t])
        given.add(raw_pts[t], out_pts[t], noise_quad=q)
        other.add(raw_pts[t], out_pts[t], noise_quad=0.01)
    assert given.result() == own.result()
    assert other.result()["roughness_pixels"] > own.result()["roughness_pixels"]


def test_masked_roughness_maps_equal_the_full_maps_on_the_mask(plane):
    from fuse4d.metrics.roughness import _roughness_maps_on

    _, raw = plane
    pts = raw.points()[:2].astype(np.float32)
    pts[0, 5:9, 7:12] = np.nan  # a hole: windows near it are undefined in both
    mask = np.zeros(pts.shape[:3], bool)
    mask[:, ::3] = True  # whole rows
    mask[0, 1, 4:9] = True  # rows with a part of their columns (each row's sums are formed
    mask[1, 2, [0, -1]] = True  # between its first and last mask pixel only)
    mask[1, 4, 6] = True
    full = roughness_maps(pts)
    part = _roughness_maps_on(pts, mask)
    for f, q in zip(full, part, strict=True):
        np.testing.assert_array_equal(q[mask], f[mask])  # bit for bit (NaN where undefined)
        assert np.isnan(q[~mask]).all()


def test_running_evaluation_every_scores_one_frame_in_n(plane):
    """every=n: roughness on frames 0, n, 2n, ... (the same as scoring those alone); the
    flicker on every frame (the same as every=1)."""
    truth, raw = plane
    out_pts = depth_to_points(truth.ground_truth.depth, raw.intrinsics)
    raw_pts = raw.points()
    full, sampled, alone = RunningEvaluation(), RunningEvaluation(every=3), RunningEvaluation()
    for t in range(raw.num_frames):
        full.add(raw_pts[t], out_pts[t])
        sampled.add(raw_pts[t], out_pts[t])
        if t % 3 == 0:
            alone.add(raw_pts[t], out_pts[t])
    f, s, a = full.result(), sampled.result(), alone.result()
    assert s["roughness_frames"] == len(range(0, raw.num_frames, 3)) == a["frames"]
    assert f["roughness_frames"] == f["frames"] == s["frames"] == raw.num_frames
    for key in ("raw_roughness", "output_roughness", "raw_rms_residual", "roughness_pixels"):
        assert s[key] == a[key], key
    for key in ("raw_flicker", "output_flicker", "static_pixels"):
        assert s[key] == f[key], key
    assert f"on {s['roughness_frames']} of {raw.num_frames} frames" in s["roi_description"]
    with pytest.raises(ValueError, match="every"):
        RunningEvaluation(every=0)


def test_run_summary_every_default_matches_the_cli():
    import inspect

    from fuse4d.cli.cmd_fuse import run_command
    from fuse4d.run import SUMMARY_EVERY

    default = inspect.signature(run_command).parameters["summary_every"].default
    assert default == SUMMARY_EVERY


def _summary_and_metrics(capsys, raw, fused, *extra: str) -> tuple[dict, dict]:
    """`fuse4d run RAW -o FUSED [EXTRA]` and `fuse4d metrics RAW FUSED`, JSON."""
    run = ["run", str(raw), "-o", str(fused), *extra, "--json"]
    assert main(run) == 0
    summary = json.loads(capsys.readouterr().out)
    frames = ["--frames", extra[extra.index("--frames") + 1]] if "--frames" in extra else []
    assert main(["metrics", str(raw), str(fused), "--no-shape", *frames, "--json"]) == 0
    return summary.get("summary", summary), json.loads(capsys.readouterr().out)


def test_running_evaluation_estimates_noise_on_the_frames_evaluate_does():
    """With the stream's length known, sigma0 comes from the frames `evaluate` uses (it came
    from every 4th frame: another median on clips longer than 8 frames)."""
    from fuse4d.metrics.evaluate import RunningEvaluation
    from fuse4d.metrics.roi import _median_noise_sigma

    k = Intrinsics(100.0, 100.0, 31.5, 23.5, 64, 48)
    rng = np.random.default_rng(0)
    noise = np.linspace(0.1, 4.0, 20)  # another noise level in every frame
    depth = (1000.0 + noise[:, None, None] * rng.standard_normal((20, 48, 64))).astype(np.float32)
    points = depth_to_points(depth, k)
    for total, expected in ((20, _median_noise_sigma(depth)), (None, None)):
        ev = RunningEvaluation(every=4, total_frames=total)
        for t in range(20):
            ev.add(points[t], points[t])
        if expected is not None:
            assert ev._noise_sigma() == pytest.approx(expected, rel=1e-12)
        else:
            assert ev._noise_sigma() != pytest.approx(_median_noise_sigma(depth), rel=1e-3)


def _body_without_truth(frames: int):
    """The Kinect-model body; no ground truth, so `metrics` detects static pixels too."""
    import dataclasses

    seq = make_range_scene("body", sensor="kinect", small=True, num_frames=frames, rng=3)
    return dataclasses.replace(seq, ground_truth=None)


def test_run_summary_and_metrics_find_the_same_static_pixels(tmp_path, capsys):
    """Both print the same static rule; the summary took the engine's sigma0 (measured
    against another reference), which on quantised depth let moving pixels pass as static
    (uva, frames 0:8: 138067 pixels and fused flicker 0.916 mm against metrics' 120723 and
    0.692 mm). Every frame scored, so both see the same frames' noise estimates."""
    raw, fused = tmp_path / "raw.npz", tmp_path / "fused.npz"
    write_npz(_body_without_truth(8), raw)
    summary, metrics = _summary_and_metrics(capsys, raw, fused, "--window", "3")  # 1 in 4 scored
    assert summary["static_pixels"] == metrics["static"]["pixels"] > 0
    assert summary["raw_flicker_mm"] == pytest.approx(metrics["raw"]["flicker_step_mean"])
    assert summary["fused_flicker_mm"] == pytest.approx(metrics["output"]["flicker_step_mean"])


def test_run_summary_scores_what_a_frame_folder_stores(tmp_path, capsys):
    """A frame folder stores whole units of depth: the summary scored the float result
    (uva: 8.889 mm roughness, its files 11.27 mm with `fuse4d metrics`)."""
    raw, fused = tmp_path / "raw", tmp_path / "fused"
    save_sequence(_body_without_truth(6), raw)
    summary, metrics = _summary_and_metrics(
        capsys, raw, fused, "--window", "3", "--summary-every", "1"
    )
    assert summary["fused_roughness_mm"] == pytest.approx(metrics["output"]["roughness_mean"])
    assert summary["fused_flicker_mm"] == pytest.approx(metrics["output"]["flicker_step_mean"])


@pytest.mark.realdata
def test_run_summary_and_metrics_agree_on_the_real_kinect_clip(shared_data, tmp_path, capsys):
    """The case that differed: uva_cv2_person_turning (see above), 20 frames, 1 in 4 scored:
    the summary's noise estimates come from the frames `metrics` takes, not its scored ones."""
    pytest.importorskip("zarr")
    clip = shared_data / "uva_cv2_person_turning"
    if not clip.is_dir():
        pytest.skip(f"{clip} not present (the shared data)")
    summary, metrics = _summary_and_metrics(capsys, clip, tmp_path / "f.zarr", "--frames", "0:20")
    assert summary["static_pixels"] == metrics["static"]["pixels"] > 0
    assert summary["fused_flicker_mm"] == pytest.approx(metrics["output"]["flicker_step_mean"])


def test_evaluate_input_errors(plane):
    _, raw = plane
    with pytest.raises(ValueError, match="need intrinsics"):
        evaluate(raw.depth)
    with pytest.raises(Exception, match="raw and output must match"):
        evaluate(raw.depth[:2], raw=raw, intrinsics=raw.intrinsics)
    with pytest.raises(TypeError, match="roi must be a boolean"):
        evaluate(raw, roi=np.ones(raw.shape))


# ---------------------------------------------------------------------------- typed GT
def test_ball_truth_is_typed_and_survives_npz_round_trip_and_slicing(tmp_path):
    seq = make_falling_ball(small=True, num_frames=4)
    ball = seq.ground_truth.scene
    assert isinstance(ball, BallTruth)
    assert ball.fit_columns == (40, 110)
    assert ball.mask_erosion_px == 1
    assert "center_row" not in seq.ground_truth.extra
    path = tmp_path / "ball.npz"
    write_npz(seq, path)
    back = load_sequence(path).ground_truth.scene
    np.testing.assert_array_equal(back.center_row, ball.center_row)
    assert back.fit_columns == (40, 110)
    assert isinstance(back.radius_mm, float)
    part = load_sequence(path, frames="1:3").ground_truth.scene
    np.testing.assert_array_equal(part.center_row, ball.center_row[1:3])
    assert part.fit_columns == (40, 110)  # not sliced along with the frames
    np.testing.assert_array_equal(
        seq.frames(1, 3).ground_truth.scene.center_mm, ball.center_mm[1:3]
    )


def test_incomplete_scene_in_npz_is_an_input_error(tmp_path):
    from fuse4d.errors import InputFileError

    seq = make_falling_ball(small=True, num_frames=2)
    gt = GroundTruth(depth=seq.ground_truth.depth, extra={"scene": "ball", "radius_mm": 1.0})
    path = tmp_path / "bad.npz"
    write_npz(Sequence(seq.depth, seq.intensity, seq.intrinsics, ground_truth=gt), path)
    with pytest.raises(InputFileError, match="lacks gt_ keys center_row"):
        load_sequence(path)


def test_shape_correctness_is_truth_first_and_takes_a_generator():
    seq = make_falling_ball(small=True, num_frames=2, depth_noise=0.0)
    with pytest.raises(TypeError, match="the ground truth comes first"):
        shape_correctness(seq.points(), seq)  # type: ignore[arg-type]
    a = shape_correctness(seq, seq.points(), rng=np.random.default_rng(3))
    b = shape_correctness(seq, seq.points(), rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a.c_3d, b.c_3d)


# ---------------------------------------------------------------------------- one guided filter
def test_self_guided_filter_keeps_holes_local():
    from fuse4d.baselines import guided
    from fuse4d.experiments.quality import self_guided

    seq = make_falling_ball(small=True, num_frames=2)
    out = self_guided(seq)
    assert out.shape == seq.depth.shape
    holes = seq.depth.copy()
    holes[:, 70:74, 70:74] = np.nan
    res = guided(holes, None, seq.intrinsics, size=2, eps=10.0, guide="depth")
    assert np.isnan(res[:, 70:74, 70:74]).all()
    # next to the hole the depth stays near the surface (no pull towards a far median)
    assert np.nanmax(np.abs(res[:, 69, 70:74] - seq.ground_truth.depth[:, 69, 70:74])) < 2.0
    with pytest.raises(ValueError, match="needs intensity"):
        guided(seq.depth, None, seq.intrinsics)


# ---------------------------------------------------------------------------- CLI
def test_cli_metrics_raw_fused_compares_on_one_roi(tmp_path, capsys):
    seq = make_falling_ball(small=True, num_frames=3)
    raw_path, fused_path = tmp_path / "raw.npz", tmp_path / "fused.npz"
    write_npz(seq, raw_path)
    write_npz(seq.with_depth(seq.ground_truth.depth), fused_path)
    assert main(["metrics", str(raw_path), str(fused_path), "--json", "--no-shape"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["inputs"] == [str(raw_path), str(fused_path)]
    assert res["raw"]["roughness_pixels"] == res["output"]["roughness_pixels"]
    assert res["output"]["roughness_mean"] < res["raw"]["roughness_mean"]
    assert res["output"]["rmse_roi"] == 0.0
    assert main(["metrics", str(raw_path), str(fused_path), "--no-shape"]) == 0
    text = capsys.readouterr().out
    assert "raw (raw.npz)" in text
    assert "fused.npz" in text
    assert "roughness (Eq. 7)" in text
    assert "frame-to-frame" in text
    assert main(["metrics", str(raw_path), str(fused_path), str(raw_path)]) == 2
    assert "give INPUT or RAW FUSED" in capsys.readouterr().err


def test_cli_metrics_static_mask_and_roi_apply_to_flicker(tmp_path, capsys):
    seq = make_falling_ball(small=True, num_frames=3)
    path = tmp_path / "ball.npz"
    write_npz(seq, path)
    static = np.zeros(seq.shape, bool)
    static[:20, :20] = True
    np.savez(tmp_path / "static.npz", mask=static)
    args = ["metrics", str(path), "--json", "--no-shape", "--static-mask"]
    assert main([*args, str(tmp_path / "static.npz")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["static"]["description"].startswith("the given static mask")
    assert res["output"]["flicker_pixels"] == 400
    assert main([*args, str(tmp_path / "static.npz"), "--roi", str(tmp_path / "static.npz")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["roi"]["pixels"] == 3 * 400
    assert "inside the given ROI" in res["static"]["description"]


def test_run_summary_says_what_each_number_means(tmp_path, capsys):
    seq = make_falling_ball(small=True, num_frames=5)
    src = tmp_path / "ball.npz"
    write_npz(seq, src)
    assert main(["run", str(src), "-o", str(tmp_path / "out.npz"), "--window", "3"]) == 0
    assert "what it means" in capsys.readouterr().out
    out = tmp_path / "o2.npz"
    assert main(["run", str(src), "-o", str(out), "--window", "3", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    from fuse4d.run import fuse_file

    result = fuse_file(src, tmp_path / "o3.npz", fusion=FusionParams(num_frames=3))
    console = Console(width=400, file=io.StringIO())
    console.print(run_summary_table(result, result.params))
    text = console.file.getvalue()
    assert "roughness (Eq. 7)" in text
    assert "(smoother)" in text
    assert f"the same {result.roughness_pixels} pixels (x frames) for both" in text
    assert f"on {result.static_pixels} static pixels" in text
    assert "(steadier)" in text
    assert "keep their own bilateral value (A35)" in text  # Eq. 6 is off by default
    with_eq6 = fuse_file(
        src, tmp_path / "o4.npz", fusion=FusionParams(num_frames=3, fill_holes=True)
    )
    console = Console(width=400, file=io.StringIO())
    console.print(run_summary_table(with_eq6, with_eq6.params))
    assert "not sensor holes" in console.file.getvalue()
    empty = replace(result.params, fill_fallback="nan")  # the sentence follows the fallback
    console = Console(width=400, file=io.StringIO())
    console.print(run_summary_table(result, empty))
    text = console.file.getvalue()
    assert "are left empty (fill_fallback=nan)" in text
    assert "keep their own bilateral value" not in text
    assert summary["fused_roughness_mm"] < summary["raw_roughness_mm"]
    assert summary["roughness_pixels"] > 0
    assert summary["static_pixels"] > 0
    assert math.isfinite(summary["fused_flicker_mm"])
    assert summary["fused_flicker_mm"] < summary["raw_flicker_mm"]


def test_deleting_the_worst_pixels_does_not_lower_the_rmse(tmp_path, capsys):
    """The raw ball with its pixels > 0.25 mm off deleted (no value changed) was reported as
    an RMSE of 0.20 -> 0.13 mm: each side was scored on its own pixels. Now both on the same
    ones, and the deletion shows as bad pixels and a lower fill rate."""
    seq = make_falling_ball(small=True, num_frames=4)
    culled = seq.depth.copy()
    culled[np.abs(culled - seq.ground_truth.depth) > 0.25] = np.nan
    report = evaluate(seq.with_depth(culled), raw=seq)
    assert report.output.rmse == pytest.approx(report.raw.rmse)
    assert report.output.bad_1mm > report.raw.bad_1mm
    assert report.output.fill_rate < report.raw.fill_rate == 1.0
    raw_path, out_path = tmp_path / "raw.npz", tmp_path / "culled.npz"
    write_npz(seq, raw_path)
    write_npz(seq.with_depth(culled), out_path)
    assert main(["metrics", str(raw_path), str(out_path), "--no-shape", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["output"]["rmse"] == pytest.approx(result["raw"]["rmse"])


def test_bad_pixels_at_the_step_limit_see_a_trailing_mean_on_sensor_depth():
    """On Kinect-model depth at metres nearly every pixel is > 1 mm off, and a 9-frame mean
    (trails behind the ball, RMSE 68 -> 120 mm) counted fewer such pixels than raw: the
    fixed threshold called it better. At the noise model's step limit it is worse."""
    seq = make_range_scene("ball", sensor="kinect", small=True, num_frames=12, rng=0)
    mean = temporal_mean(seq.depth, None, seq.intrinsics, size=9)
    report = evaluate(mean, raw=seq)
    assert report.output.rmse > 1.5 * report.raw.rmse
    assert report.output.bad_1mm < report.raw.bad_1mm  # the fixed threshold's blind spot
    assert report.output.bad_steps > 1.2 * report.raw.bad_steps
    assert report.raw.bad_steps < 0.2  # raw is mostly within its own steps
    q = float(np.median([estimate_noise_quad(d) for d in seq.depth]))
    assert report.noise_quad == pytest.approx(q, rel=1e-12)
    # the paper's 0.2 mm noise at 1 m: the step limit is below 1 mm, the two agree
    ball = make_falling_ball(small=True, num_frames=3)
    paper = evaluate(ball.ground_truth.depth + 0.0, raw=ball, intrinsics=ball.intrinsics)
    assert paper.raw.bad_steps == paper.raw.bad_1mm


def test_an_output_without_depth_shows_its_bad_pixels(tmp_path, capsys):
    """An all-NaN output's table hid the RMSE and bad-pixel rows (bad = 100 %)."""
    seq = make_falling_ball(small=True, num_frames=3)
    raw_path, out_path = tmp_path / "raw.npz", tmp_path / "empty.npz"
    write_npz(seq, raw_path)
    with pytest.warns(UserWarning, match="only 0.0 %"):
        empty = seq.with_depth(np.full_like(seq.depth, np.nan))
    write_npz(empty, out_path)
    with pytest.warns(UserWarning, match=r"empty\.npz: only 0\.0 % of depth pixels are valid"):
        assert main(["metrics", str(raw_path), str(out_path), "--no-shape"]) == 0
    text = capsys.readouterr().out
    bad = next(line for line in text.splitlines() if "pixels > 1 mm off" in line)
    assert [c.strip() for c in bad.split("│")[2:4]] == ["0", "1"]
    fill = next(line for line in text.splitlines() if "fill rate" in line)
    assert [c.strip() for c in fill.split("│")[2:4]] == ["1", "0"]


def test_an_empty_roi_mask_is_refused(tmp_path, capsys):
    """An all-false --roi mask printed a table of n/a with no word why."""
    seq = make_falling_ball(small=True, num_frames=2)
    path = write_npz(seq, tmp_path / "b.npz")
    np.savez(tmp_path / "roi.npz", roi=np.zeros((150, 150), bool))
    assert main(["metrics", str(path), "--roi", str(tmp_path / "roi.npz")]) == 2
    assert "--roi: the mask selects no pixel" in capsys.readouterr().err


def test_one_frame_has_no_roughness_spread():
    """The roughness std over frames of one frame printed as 0."""
    seq = make_falling_ball(small=True, num_frames=2).frames(0, 1)
    report = evaluate(seq)
    assert math.isfinite(report.output.roughness.mean)
    assert math.isnan(report.output.roughness.std)


# ------------------------------------------------- single input, headlines, ROI, frame parts
def test_a_single_input_has_no_step_limit_of_its_own():
    """Scored alone, a smooth output took its own q (50x smaller than the sensor's) as the
    step limit of bad_steps: fuse4d's output read 88.5 % bad against raw's 5.7 %. Alone it is
    now not scored without the sensor's q; with it, it reads what RAW FUSED reads."""
    seq = make_range_scene("ball", sensor="kinect", small=True, num_frames=4, rng=0)
    smooth = seq.with_depth(seq.ground_truth.depth)
    alone = evaluate(smooth)
    assert math.isnan(alone.output.bad_steps)
    assert math.isnan(alone.noise_quad)
    assert "--noise-quad" in alone.noise_quad_description
    assert math.isfinite(alone.output.bad_1mm)
    pair = evaluate(smooth, raw=seq)
    given = evaluate(smooth, noise_quad=pair.noise_quad)
    assert given.noise_quad == pair.noise_quad
    assert given.noise_quad_description == "given"
    assert given.output.bad_steps == pair.output.bad_steps
    with pytest.raises(ParameterError, match="noise_quad must be"):
        evaluate(smooth, noise_quad=-1.0)


def test_cli_metrics_alone_says_why_bad_steps_is_not_scored(tmp_path, capsys):
    seq = make_range_scene("ball", sensor="kinect", small=True, num_frames=3, rng=0)
    path = write_npz(seq.with_depth(seq.ground_truth.depth), tmp_path / "smooth.npz")
    assert main(["metrics", str(path), "--no-shape", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["output"]["bad_steps"] is None
    assert "not scored" in res["noise_quad_description"]
    assert main(["metrics", str(path), "--no-shape"]) == 0
    text = capsys.readouterr().out.replace("\n", " ")
    assert "--noise-quad" in text
    assert main(["metrics", str(path), "--no-shape", "--json", "--noise-quad", "7e-6"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["noise_quad"] == 7e-6
    assert res["noise_quad_description"] == "given (--noise-quad)"
    assert 0.0 <= res["output"]["bad_steps"] < 0.05
    assert main(["metrics", str(path), "--no-shape", "--noise-quad", "-1"]) == 2
    assert "--noise-quad must be" in capsys.readouterr().err


def test_flicker_headline_is_the_mean_not_the_median(tmp_path, capsys):
    """Quantised raw depth whose pixels mostly never change level had a median per-pixel std
    of 0 mm ("steadier" than fused) while its mean was 10x the fused one."""
    rng = np.random.default_rng(3)
    k = Intrinsics(100.0, 100.0, 15.5, 15.5, 32, 32)
    raw = np.full((4, 32, 32), 1000.0, np.float32)
    jumpy = rng.random((32, 32)) < 0.3
    raw[1::2, jumpy] += 30.0  # whole quantisation steps on 30 % of the pixels
    fused = (1000.0 + rng.normal(0.0, 2.0, raw.shape)).astype(np.float32)
    static = np.ones((32, 32), bool)
    rep = evaluate(fused, raw=raw, intrinsics=k, static=static)
    assert rep.raw.flicker.median == 0.0 < rep.output.flicker.median
    assert rep.raw.flicker.mean > 2 * rep.output.flicker.mean
    intensity = np.full_like(raw, 0.5)
    raw_path = write_npz(Sequence(raw, intensity, k), tmp_path / "raw.npz")
    fused_path = write_npz(Sequence(fused, intensity, k), tmp_path / "fused.npz")
    np.savez(tmp_path / "static.npz", mask=static)
    args = [
        "metrics",
        str(raw_path),
        str(fused_path),
        "--static-mask",
        str(tmp_path / "static.npz"),
    ]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(out_console, "_width", 200)  # one table row per line
        assert main([*args, "--no-shape"]) == 0
    lines = capsys.readouterr().out.splitlines()
    headline = next(line for line in lines if "(temporal precision)" in line)
    assert "mean" in headline
    raw_cell, fused_cell = (float(c) for c in headline.split("│")[2:4])
    assert raw_cell > 2 * fused_cell
    assert any("median" in line and "quantisation level" in line for line in lines)


def test_shape_keeps_its_own_region_and_says_so(tmp_path, capsys):
    """--roi claimed to apply to every metric; Eq. 8 scores its own region (EVALUATION §2)."""
    seq = make_falling_ball(small=True, num_frames=2)
    roi = np.zeros(seq.shape, bool)
    roi[:20, :20] = True  # background only: Eq. 8 is still scored on the ball
    rep = evaluate(seq, roi=roi, shape=True, shape_frames=[0])
    assert rep.output.shape is not None
    assert rep.output.shape.c_3d[0] > 0.99
    assert "not the ROI" in rep.to_dict()["shape_region"]
    assert "shape_region" not in evaluate(seq).to_dict()
    roi_help = typing.get_type_hints(metrics_command, include_extras=True)["roi"].__metadata__[0]
    assert "but the shape" in roi_help.help


def test_cli_metrics_with_roi_has_no_whole_image_rmse_row(tmp_path, capsys):
    """With --roi the row "RMSE to ground truth, whole image" was the ROI's."""
    seq = make_falling_ball(small=True, num_frames=2)
    path = write_npz(seq, tmp_path / "b.npz")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(out_console, "_width", 200)  # one table row per line
        assert main(["metrics", str(path), "--no-shape"]) == 0
        assert "whole image" in capsys.readouterr().out
        assert main(["metrics", str(path), "--no-shape", "--roi", "40:100,40:100"]) == 0
    text = capsys.readouterr().out
    assert "whole image" not in text
    assert "no whole-image RMSE with --roi" in text
    assert main(["metrics", str(path), "--no-shape", "--json", "--roi", "40:100,40:100"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["roi"]["given"] is True
    assert res["output"]["rmse"] == res["output"]["rmse_roi"]


def test_cli_metrics_scores_the_output_of_a_part(tmp_path, capsys):
    """`fuse4d run --frames A:B`'s output could not be scored against its input: --frames
    applied to every input (FUSED then had too few frames)."""
    seq = make_falling_ball(small=True, num_frames=6)
    raw_path = write_npz(seq, tmp_path / "raw.npz")
    part_path = write_npz(seq.frames(2, 5), tmp_path / "raw_2_5.npz")
    fused = seq.frames(2, 5)
    fused_path = write_npz(fused.with_depth(fused.ground_truth.depth), tmp_path / "fused.npz")
    args = ["metrics", "--no-shape", "--json"]
    assert main([*args, str(raw_path), str(fused_path), "--frames", "2:5"]) == 0
    whole = json.loads(capsys.readouterr().out)
    assert whole["frames"] == [2, 5]
    assert main([*args, str(part_path), str(fused_path)]) == 0
    part = json.loads(capsys.readouterr().out)
    assert whole["raw"] == part["raw"]
    assert whole["output"] == part["output"]
    # the ground truth lines up with RAW's part too; the single input with --gt likewise
    assert (
        main([*args, str(raw_path), str(fused_path), "--frames", "2:5", "--gt", str(raw_path)]) == 0
    )
    assert json.loads(capsys.readouterr().out)["output"]["rmse"] == 0.0
    assert main([*args, str(fused_path), "--frames", "2:5", "--gt", str(raw_path)]) == 0
    assert json.loads(capsys.readouterr().out)["output"]["rmse"] == 0.0
    # without the range: one line that says what to do
    assert main([*args, str(raw_path), str(fused_path)]) == 2
    err = capsys.readouterr().err
    assert "3 frames of 150x150, but" in err
    assert "give the same --frames A:B" in err
    # a `fuse4d run` folder records its part
    folder = tmp_path / "raw_dir"
    with warnings.catch_warnings():  # no ground truth, a coarse unit: not what is tested
        warnings.simplefilter("ignore", UserWarning)
        save_sequence(seq, folder)
    out = tmp_path / "fused_dir"
    assert main(["run", str(folder), "-o", str(out), "--frames", "1:4", "--window", "3"]) == 0
    capsys.readouterr()
    assert main([*args, str(folder), str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == [1, 4]
    assert main([*args, str(folder), str(out), "--frames", "0:3"]) == 2
    assert "was fused from frames 1:4" in capsys.readouterr().err
    # alone, its --frames would count its own frames: refused, not silently shifted
    assert main([*args, str(out), "--frames", "1:4"]) == 2
    assert "holds frames 1:4 of its input" in capsys.readouterr().err
    assert main([*args, str(out)]) == 0


def _tiny_video(rng):
    k = Intrinsics(200.0, 200.0, 15.0, 10.0, 31, 21)
    return 900 + rng.normal(0, 1, (3, 21, 31)), k


def test_a_whole_float_window_scores_as_the_integer_window(rng):
    """window=5.0 crashed in numba in evaluate and RunningEvaluation.add."""
    depth, k = _tiny_video(rng)
    rep = evaluate(depth, intrinsics=k, window=5.0)
    assert type(rep.window) is int
    assert "5x5 windows" in rep.roi_description
    assert rep.output.roughness.mean == evaluate(depth, intrinsics=k).output.roughness.mean
    pts = depth_to_points(depth, k)
    runs = RunningEvaluation(window=5.0), RunningEvaluation()
    for run in runs:
        run.add(pts[0], pts[0])
    assert runs[0].result()["raw_roughness"] == runs[1].result()["raw_roughness"]


@pytest.mark.parametrize("window", [4, 1, 2.5, "5"])
def test_running_evaluation_checks_its_window_when_made(window):
    """RunningEvaluation(window=4) was accepted and failed only in add()."""
    with pytest.raises(ParameterError, match="window must be an odd integer >= 3"):
        RunningEvaluation(window=window)


def test_running_evaluation_names_points_of_the_wrong_shape(rng):
    """A depth map raised an IndexError, maps of two sizes a broadcast ValueError."""
    depth, k = _tiny_video(rng)
    pts = depth_to_points(depth, k)
    with pytest.raises(ShapeError, match=r"raw_points must have shape \(H, W, 3\)"):
        RunningEvaluation().add(depth[0], depth[0])
    with pytest.raises(ShapeError, match=r"output_points must have shape \(21, 31, 3\)"):
        RunningEvaluation().add(pts[0], pts[0, :, :-1])
    run = RunningEvaluation()
    run.add(pts[0], pts[0])
    with pytest.raises(ShapeError, match=r"raw_points must have shape \(21, 31, 3\)"):
        run.add(pts[1, :-1], pts[1, :-1])
    assert run.frames == 1


@pytest.mark.parametrize(
    ("frames", "message"),
    [
        (np.array([0, 5]), r"frames holds frame 5, outside the 3-frame video \(0 \.\. 2\)"),
        (np.array([-4]), "frames holds frame -4, outside"),
        (slice(5, 9), r"frames slice\(5, 9, None\) selects no frame of the 3-frame video"),
        (np.array([], int), "frames selects no frame"),
        (np.array([0.0, 1.0]), "frames must be a slice or a 1-D array of frame indices"),
        (np.array([True, False, True]), "frames must be a slice or a 1-D array"),
    ],
)
def test_evaluate_names_frames_that_select_nothing_or_too_much(rng, frames, message):
    """Out-of-range indices raised an IndexError, an empty slice gave an all-NaN report."""
    depth, k = _tiny_video(rng)
    with pytest.raises(ParameterError, match=message):
        evaluate(depth, intrinsics=k, frames=frames)
    assert evaluate(depth, intrinsics=k, frames=[0, -1]).roi.shape == (2, 21, 31)
