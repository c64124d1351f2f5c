"""Tests of ``fuse4d report`` / :func:`fuse4d.report.write_report` (issue 14).

The page is opened in headless Chromium (Debian's ``chromium`` package; skipped with the reason
when the binary is absent): every image and the video must load, with no script error. The MP4
must decode to one frame per input frame, and the numbers of ``metrics.json`` must equal those of
the :mod:`fuse4d.metrics` functions (and ``fuse4d metrics``) on the same pixels.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from fuse4d import Sequence, depth_to_points, fuse_sequence, load_sequence, save_sequence
from fuse4d.cli import main
from fuse4d.errors import OutputExistsError, ParameterError
from fuse4d.metrics import (
    bad_pixel_fraction,
    default_roi,
    depth_rmse,
    roughness,
    roughness_stats,
    static_mask_from_ground_truth,
    temporal_flicker,
)
from fuse4d.motion import estimate_noise_quad
from fuse4d.report import count_video_frames, parse_roi, write_report
from fuse4d.report.render import (
    INVALID_RGB,
    colorize,
    normal_map,
    shade_normals,
    shade_points,
    splat_points,
)
from fuse4d.report.xt import XtSlice, choose_line
from fuse4d.synthetic import make_falling_ball

FRAMES = 6


@pytest.fixture(scope="module")
def run_with_report(tmp_path_factory):
    """``fuse4d synth`` + ``fuse4d run ... --report``: (raw npz, fused npz, report folder)."""
    root = tmp_path_factory.mktemp("report")
    raw, fused, rep = root / "ball.npz", root / "fused.npz", root / "rep"
    assert main(["synth", "ball", "--small", "--frames", str(FRAMES), "-o", str(raw)]) == 0
    args = ["run", str(raw), "-o", str(fused), "--window", "5", "--report", str(rep), "--json"]
    assert main(args) == 0
    return raw, fused, rep


@pytest.fixture(scope="module")
def small_ball():
    return make_falling_ball(small=True, num_frames=4)


@pytest.fixture(scope="module")
def small_fused(small_ball):
    return fuse_sequence(small_ball.depth, small_ball.intensity, small_ball.intrinsics)


def _metrics(rep: Path) -> dict:
    return json.loads((rep / "metrics.json").read_text())


# --------------------------------------------------------------------------- files and numbers
def test_report_folder_holds_page_video_metrics_and_clouds(run_with_report):
    _, _, rep = run_with_report
    names = sorted(p.name for p in rep.iterdir())
    assert names == [
        "cloud_fused.ply",
        "cloud_raw.ply",
        "compare.mp4",
        "metrics.json",
        "report.html",
    ]
    page = (rep / "report.html").read_text()
    assert "http://" not in page
    assert "https://" not in page  # self-contained: no CDN, no network
    assert page.count("data:image/png;base64,") == 7
    m = _metrics(rep)
    assert m["methods"] == ["raw", "fused"]
    assert m["params"]["num_frames"] == 5  # recorded by fuse4d run --report
    assert m["timing"]["fusion_ms_per_frame"] > 0
    # the rate once running (fuse4d run's clock), apart from the start-up in the average: its
    # FRAMES - 3 intervals (window 5 flushes 2 frames) lie inside the run (which of the two
    # rates is larger depends on the process's warmth and the machine's load)
    steady, average = (
        m["timing"][k] for k in ("fusion_steady_ms_per_frame", "fusion_ms_per_frame")
    )
    assert 0 < (FRAMES - 3) * steady <= FRAMES * average
    assert "time per frame" in page
    assert "once running" in page
    assert m["timing"]["report_ms_per_frame"] > 0
    assert 0.5 < m["fusion"]["support_fraction"] <= 1.0
    assert m["xt_slice"]["how"].startswith("auto")
    # the run's npz holds the per-pixel source codes: the support figure maps them
    assert "Source: where each value of the frame comes from" in page
    assert m["fusion"]["rejected_fraction"] == 0.0  # source codes read, no ToF input
    assert "hole_time_fraction" in m["fusion"]


def test_mp4_decodes_to_one_frame_per_input_frame(run_with_report):
    _, _, rep = run_with_report
    assert count_video_frames(rep / "compare.mp4") == FRAMES
    m = _metrics(rep)
    assert m["video"]["frames"] == FRAMES
    height, width = m["video"]["size"]
    assert height % 2 == 0
    assert width % 2 == 0


def test_metrics_equal_the_library_functions_on_the_same_pixels(run_with_report):
    raw_path, fused_path, rep = run_with_report
    m = _metrics(rep)["metrics"]
    raw = load_sequence(raw_path)
    fused = load_sequence(fused_path)
    k = raw.intrinsics
    p_raw, p_fused = depth_to_points(raw.depth, k), depth_to_points(fused.depth, k)
    # Eq. 7 roughness on the default ROI of the raw frame where Pi is defined for both
    roi = default_roi(raw.depth) & np.isfinite(roughness(p_raw)) & np.isfinite(roughness(p_fused))
    for name, pts in (("raw", p_raw), ("fused", p_fused)):
        stats = roughness_stats(pts, roi=roi)
        assert m[name]["roughness_mean"] == pytest.approx(stats.mean, rel=1e-9)
        assert m[name]["roughness_std"] == pytest.approx(stats.std, rel=1e-6, abs=1e-12)
        assert m[name]["rms_residual"] == pytest.approx(stats.rms_mean, rel=1e-9)
    assert m["fused"]["roughness_mean"] < 0.6 * m["raw"]["roughness_mean"]
    # flicker on GT-static pixels valid in every frame of both
    both = np.all(np.isfinite(raw.depth), axis=0) & np.all(np.isfinite(fused.depth), axis=0)
    static = static_mask_from_ground_truth(raw.ground_truth) & both
    for name, seq in (("raw", raw), ("fused", fused)):
        flick = temporal_flicker(seq.depth, static=static)
        assert m[name]["flicker_median"] == pytest.approx(flick.median, rel=1e-6)
        assert m[name]["flicker_mean"] == pytest.approx(flick.mean, rel=1e-6)
    assert m["fused"]["flicker_median"] < 0.5 * m["raw"]["flicker_median"]
    assert m["fused"]["flicker_mean"] < 0.5 * m["raw"]["flicker_mean"]
    # ground truth: RMSE on pixels valid in both, bad pixels with missing = bad
    gt = raw.ground_truth.depth
    common = np.isfinite(raw.depth) & np.isfinite(fused.depth)
    q = float(np.median([estimate_noise_quad(d) for d in raw.depth]))
    assert _metrics(rep)["noise_quad"] == pytest.approx(q, rel=1e-12)
    for name, seq in (("raw", raw), ("fused", fused)):
        assert m[name]["rmse"] == pytest.approx(depth_rmse(gt, seq.depth, roi=common), rel=1e-9)
        assert m[name]["bad_pixels"] == pytest.approx(bad_pixel_fraction(gt, seq.depth), rel=1e-12)
        steps = bad_pixel_fraction(gt, seq.depth, noise_quad=q)
        assert m[name]["bad_steps"] == pytest.approx(steps, rel=1e-12)
        assert m[name]["fill_rate"] == pytest.approx(float(np.isfinite(seq.depth).mean()))


def test_metrics_agree_with_fuse4d_metrics_cli(run_with_report, capsys):
    raw_path, fused_path, rep = run_with_report
    m = _metrics(rep)["metrics"]
    capsys.readouterr()
    # one video alone scores bad_steps only with the sensor's q: the report's (raw's)
    q = repr(_metrics(rep)["noise_quad"])
    for name, path in (("raw", raw_path), ("fused", fused_path)):
        assert main(["metrics", str(path), "--json", "--no-shape", "--noise-quad", q]) == 0
        cli = json.loads(capsys.readouterr().out)["output"]
        # the ball's raw depth is valid everywhere, so "valid in all methods" = "valid in one"
        assert m[name]["flicker_mean"] == pytest.approx(cli["flicker_std_mean"], rel=1e-6)
        assert m[name]["flicker_median"] == pytest.approx(cli["flicker_std_median"], rel=1e-6)
        assert m[name]["rmse"] == pytest.approx(cli["rmse"], rel=1e-9)
        assert m[name]["bad_pixels"] == pytest.approx(cli["bad_1mm"], rel=1e-12)
        assert m[name]["bad_steps"] == pytest.approx(cli["bad_steps"], rel=1e-12)


# --------------------------------------------------------------------------- the browser
def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def _chromium_run(binary: str, *args: str) -> subprocess.CompletedProcess[str]:
    with tempfile.TemporaryDirectory() as profile:
        return subprocess.run(
            [
                binary,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--enable-logging=stderr",
                "--v=0",
                f"--user-data-dir={profile}",
                "--virtual-time-budget=10000",
                *args,
            ],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
            env={**os.environ, "HOME": profile},
        )


@pytest.mark.slow
def test_page_loads_in_headless_chromium(run_with_report, tmp_path):
    binary = _chromium()
    if binary is None:
        pytest.skip("no chromium binary on PATH (Debian: apt-get install -y chromium)")
    _, _, rep = run_with_report
    url = (rep / "report.html").resolve().as_uri()
    shot = tmp_path / "report.png"
    done = _chromium_run(binary, f"--screenshot={shot}", "--window-size=1400,2400", url)
    assert shot.is_file(), done.stderr[-2000:]
    assert shot.stat().st_size > 50_000  # a rendered page, not a blank one
    dom = _chromium_run(binary, "--dump-dom", url)
    assert dom.returncode == 0, dom.stderr[-2000:]
    start = dom.stdout.index('<pre id="load-status">') + len('<pre id="load-status">')
    status = json.loads(dom.stdout[start : dom.stdout.index("</pre>", start)])
    assert status["images"] == 7
    assert status["images_ok"] == status["images"], status
    assert status["videos"] == 1
    if _metrics(rep)["video"]["codec"] == "libx264":  # MPEG-4 part 2 does not play in browsers
        assert status["videos_ok"] == 1, status
    assert status["errors"] == []
    console = [
        line
        for line in done.stderr.splitlines() + dom.stderr.splitlines()
        if "CONSOLE" in line or "Uncaught" in line
    ]
    assert console == []


# --------------------------------------------------------------------------- Python API
@pytest.mark.slow
def test_api_with_arrays_compare_column_and_roi(small_ball, small_fused, tmp_path):
    out = tmp_path / "rep"
    page = write_report(
        small_ball,
        small_fused.depth,
        out,
        support=small_fused.support,
        filled=small_fused.filled,
        compare=["temporal-mean"],
        col=75,
        roi=(118, 146, 4, 40),  # the static wall below-left of the ball
        chunk_frames=3,
    )
    assert page == out / "report.html"
    m = _metrics(out)
    assert m["methods"] == ["raw", "fused", "temporal-mean"]
    assert m["xt_slice"] == {"axis": "col", "index": 75, "how": "given"}
    assert [p["source"] for p in m["planes"]] == ["given"]
    sp = {n: m["metrics"][n]["spatial_precision"] for n in m["methods"]}
    assert sp["fused"] < sp["raw"]  # the wall is flatter after fusion
    assert 0.15 < sp["raw"] < 0.25  # sigma_d = 0.2 mm on a fronto-parallel wall
    assert 0 < m["flicker"]["static_pixels"] <= 28 * 36
    assert m["fusion"]["support_fraction"] is not None
    assert count_video_frames(out / "compare.mp4") == 4


def test_one_frame_report_has_no_flicker(small_ball, small_fused, tmp_path):
    """A one-frame report said "flicker 0 mm → 0 mm" over every pixel called static."""
    one = small_ball.frames(0, 1)
    write_report(one, small_fused.depth[:1], tmp_path / "rep")
    m = _metrics(tmp_path / "rep")
    assert m["flicker"]["static_pixels"] == 0
    assert m["metrics"]["fused"]["flicker_median"] is None
    assert m["metrics"]["fused"]["flicker_mean"] is None
    assert m["metrics"]["raw"]["roughness_std"] is None  # one frame has no spread (it said 0)
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "flicker n/a (it needs 2 frames and static pixels)" in page
    # the page draws where the headline roughness comes from, and says the histogram clips
    assert "pixels of this frame's roughness ROI" in page
    assert "its last bin holds every value of" in page


@pytest.mark.slow
def test_chunked_equals_unchunked(small_ball, small_fused, tmp_path):
    a = write_report(small_ball, small_fused, tmp_path / "a", chunk_frames=1)
    b = write_report(small_ball, small_fused, tmp_path / "b", chunk_frames=64)
    ma, mb = _metrics(a.parent)["metrics"], _metrics(b.parent)["metrics"]
    for name in ("raw", "fused"):
        for key in (
            "roughness_mean",
            "flicker_mean",
            "flicker_median",
            "rmse",
            "bad_pixels",
            "fill_rate",
        ):
            assert ma[name][key] == pytest.approx(mb[name][key], rel=1e-12), key


def test_bad_input_raises_and_leaves_no_report(small_ball, small_fused, tmp_path):
    out = tmp_path / "rep"
    with pytest.raises(ValueError, match="frames"):
        write_report(small_ball, small_fused.depth[:3], out)
    with pytest.raises(ValueError, match="not both"):
        write_report(small_ball, small_fused, out, row=3, col=4)
    with pytest.raises(ValueError, match="unknown baseline"):
        write_report(small_ball, small_fused, out, compare=["nope"])
    with pytest.raises(ValueError, match="not a non-empty region"):
        write_report(small_ball, small_fused, out, roi=(0, 10, 140, 200))
    with pytest.raises(ValueError, match="row must be"):
        write_report(small_ball, small_fused, out, row=999)
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
    out.mkdir()
    with pytest.raises(OutputExistsError):
        write_report(small_ball, small_fused, out)


def test_failure_midway_leaves_no_report(small_ball, small_fused, tmp_path, monkeypatch):
    from fuse4d.report import figures

    def broken(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(figures, "xt_figure", broken)
    with pytest.raises(RuntimeError, match="boom"):
        write_report(small_ball, small_fused, tmp_path / "rep")
    assert list(tmp_path.iterdir()) == []  # neither the report nor its temporary folder


def test_cli_report_errors_are_one_line(run_with_report, tmp_path, capsys):
    raw, fused, _ = run_with_report
    code = main(["report", str(raw), str(fused), "-o", str(tmp_path / "r"), "--compare", "x"])
    assert code == 2
    assert "unknown baseline" in capsys.readouterr().err
    assert main(["report", str(raw), str(fused), "-o", str(tmp_path / "r"), "--roi", "3"]) == 2
    assert "R0:R1,C0:C1" in capsys.readouterr().err
    for fps in ("0", "nan", "-5"):  # nan and -5 were internal errors, 0 meant the default
        assert main(["report", str(raw), str(fused), "-o", str(tmp_path / "r"), "--fps", fps]) == 2
        assert "fps must be a video frame rate > 0" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


# --------------------------------------------------------------------------- pieces
def test_parse_roi():
    assert parse_roi("10:20,30:45") == (10, 20, 30, 45)
    with pytest.raises(ValueError, match="R0:R1,C0:C1"):
        parse_roi("10:20")


def test_colorize_fixed_range_and_invalid():
    img = colorize(np.array([[-5.0, 0.0, 0.5, 1.0, 7.0, np.nan]]), vmin=0.0, vmax=1.0, cmap="gray")
    assert img[0, :, 0].tolist() == [0, 0, 128, 255, 255, INVALID_RGB[0]]
    with pytest.raises(ValueError, match="vmin < vmax"):
        colorize(np.zeros((2, 2)), vmin=1.0, vmax=1.0)


def test_shade_points_kernel_matches_numpy_oracle(small_ball):
    pts = depth_to_points(small_ball.depth[0], small_ball.intrinsics)
    pts[40:50, 60:70] = np.nan
    fast = shade_points(pts).astype(int)
    slow = shade_normals(normal_map(pts)).astype(int)
    assert np.abs(fast - slow).max() <= 1  # float32 vs float64 rounding of the gray level
    assert (fast == slow).mean() > 0.999
    assert (fast[0] == INVALID_RGB).all()  # border: no central difference


def test_normals_face_the_camera_and_light_is_lambert():
    from fuse4d import Intrinsics

    k = Intrinsics(fx=100.0, fy=100.0, cx=9.5, cy=9.5, width=20, height=20)
    pts = depth_to_points(np.full((20, 20), 500.0), k)
    n = normal_map(pts)
    np.testing.assert_allclose(n[10, 10], [0.0, 0.0, -1.0], atol=1e-6)
    gray = shade_normals(n, light=[0.0, 0.0, -1.0], ambient=0.0)
    assert gray[10, 10, 0] == 255
    assert shade_normals(n, light=[1.0, 0.0, 0.0], ambient=0.2)[10, 10, 0] == round(0.2 * 255)


def test_splat_zbuffer_keeps_the_nearest_surface():
    from fuse4d import Intrinsics

    k = Intrinsics(fx=100.0, fy=100.0, cx=19.5, cy=19.5, width=40, height=40)
    depth = np.full((40, 40), 1000.0)
    depth[10:30, 10:30] = 500.0  # a near square in front of a far wall
    pts = depth_to_points(depth, k)
    normals = np.zeros_like(pts)
    normals[..., 2] = -1.0
    normals[10:30, 10:30] = [1.0, 0.0, 0.0]  # near square: lit from the side -> ambient gray
    img, scale, offset = splat_points(
        pts, normals=normals, size=(80, 80), yaw_deg=0.0, pitch_deg=0.0
    )
    assert scale > 0
    same, _, _ = splat_points(
        pts,
        normals=normals,
        size=(80, 80),
        yaw_deg=0.0,
        pitch_deg=0.0,
        scale=scale,
        offset=offset,
    )
    np.testing.assert_array_equal(same, img)
    centre = img[40, 40, 0]
    assert centre == round(0.12 * 255)  # the near square wins the z-buffer at the centre
    assert img[5, 40, 0] > centre  # the far wall (facing the camera) elsewhere


def test_xt_slice_and_line_choice():
    xt = XtSlice(2, axis="col")
    for t in range(3):
        xt.add(np.full((4, 5), float(t)))
    assert xt.image().shape == (3, 4)
    assert xt.image()[:, 0].tolist() == [0.0, 1.0, 2.0]
    energy = np.zeros(50)
    energy[30:33] = [2.0, 5.0, 2.0]
    assert choose_line(energy) == 31  # ties of the smoothed energy: the busiest line wins
    assert choose_line(np.zeros(10)) == 5


def test_rerun_recording_has_every_frame(run_with_report, tmp_path):
    from fuse4d.report.rerun import have_rerun, write_rerun

    if not have_rerun():
        pytest.skip("rerun-sdk not installed (optional extra fuse4d[viz])")
    raw, fused, _ = run_with_report
    out = write_rerun(raw, fused, tmp_path / "out.rrd")
    assert out.stat().st_size > 100_000  # 2 x 6 depth frames of 150 x 150 float32 at least
    with pytest.raises(OutputExistsError):
        write_rerun(raw, fused, out)


def test_rerun_missing_is_one_line_cli_error(run_with_report, tmp_path, capsys, monkeypatch):
    import fuse4d.report.rerun as rr_mod

    monkeypatch.setattr(rr_mod, "have_rerun", lambda: False)
    raw, fused, _ = run_with_report
    out = tmp_path / "r"
    assert main(["report", str(raw), str(fused), "-o", str(out), "--rerun", "x.rrd"]) == 2
    assert "fuse4d[viz]" in capsys.readouterr().err
    assert not out.exists()


def test_report_reads_the_parameters_of_a_run_folder(tmp_path):
    """`fuse4d report IN OUT` on a frame folder that `fuse4d run` wrote: the parameters come
    from the run's manifest (as `fuse4d run --report` passes them), the source codes from
    its source/ PNGs."""
    from fuse4d.io import FrameFolderWriter
    from fuse4d.report._sources import FusedSource
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=4)
    src = tmp_path / "rec"
    with FrameFolderWriter(src, seq.intrinsics, depth_unit_mm=0.05) as writer:
        for d, i in zip(seq.depth, seq.intensity, strict=True):
            writer.write(d, i)
    assert FusedSource(src).params is None  # a recording, not a run's output
    out = tmp_path / "fused"
    assert main(["run", str(src), "-o", str(out), "--window", "3", "--no-summary"]) == 0
    fused = FusedSource(out)
    assert fused.params["num_frames"] == 3
    assert fused.params["flow_method"] == "dis"
    assert fused.chunk(0, 4).source is not None
    fused.close()


def test_video_shows_the_source_codes_where_support_is_not_stored(small_ball, tmp_path):
    """A frame-folder output stores source codes but no support maps: the video's sixth panel
    said "not stored"; it now shows the codes, in the page's colours."""
    from fuse4d.io import write_frame_folder
    from fuse4d.report import _sixth_panel
    from fuse4d.report.layout import SOURCE_RGB, VideoLayout, source_rgb

    layout = VideoLayout((150, 150), depth_range=(500, 1000), diff_max=1.0, support_max=4.0,
                         show_support=False, show_source=True)  # fmt: skip
    codes = np.full((1, 150, 150), 2, np.uint8)
    codes[0, :10] = 6
    panel = _sixth_panel(layout, None, np.ones((150, 150), bool), 4.0, codes, 0)
    assert panel.shape == (layout.ph, layout.pw, 3)
    assert (panel[-1, -1] == SOURCE_RGB[2]).all()
    assert (panel[0, 0] == SOURCE_RGB[6]).all()
    np.testing.assert_array_equal(source_rgb(np.array([[0, 9]])), SOURCE_RGB[[0, 6]][None])
    bare = Sequence(small_ball.depth, small_ball.intensity, small_ball.intrinsics)
    rec = write_frame_folder(bare, tmp_path / "rec", depth_unit_mm=0.05)
    out = tmp_path / "fused"
    assert main(["run", str(rec), "-o", str(out), "--window", "3", "--no-summary"]) == 0
    write_report(rec, out, tmp_path / "rep")
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "where each value comes from (the fused result stores no support maps)" in page


def test_summary_says_more_flicker_when_fusion_added_some():
    """A ratio below 1 printed "(0.5× less)", and raw flicker 0 "(0× less)"."""
    from fuse4d.report import _summary

    def methods(raw, fused):
        row = {"roughness_mean": 1.0, "fill_rate": 1.0}
        return {"raw": {**row, "flicker_mean": raw}, "fused": {**row, "flicker_mean": fused}}

    assert "(4× less)" in _summary(methods(2.0, 0.5), 4.0)
    assert "(2× more)" in _summary(methods(1.0, 2.0), 0.5)
    assert "(more: raw was still on these pixels)" in _summary(methods(0.0, 2.5), 0.0)
    assert "less" not in _summary(methods(0.0, 2.5), 0.0)


def test_flicker_headline_is_the_mean_on_quantised_depth(tmp_path, capsys):
    """The report headlined the median per-pixel std over time: 0 mm for quantised Kinect
    depth whose static pixels mostly never leave their level in a short clip, so it said
    fusion added flicker ("raw was still on these pixels") while the mean fell from about 25
    to 2 mm. Now the mean, as `fuse4d metrics`; the median stays as a second row."""
    from fuse4d.cli.cmd_report import print_report_summary
    from fuse4d.range_scenes import make_range_scene

    seq = make_range_scene("ball", sensor="kinect", small=True, num_frames=4)
    fused = fuse_sequence(seq.depth, seq.intensity, seq.intrinsics)
    page_path = write_report(seq, fused, tmp_path / "rep")
    m = _metrics(tmp_path / "rep")
    raw, out = m["metrics"]["raw"], m["metrics"]["fused"]
    assert raw["flicker_median"] == 0.0 < out["flicker_median"]  # the misleading median
    assert raw["flicker_mean"] > 5 * out["flicker_mean"] > 0
    ratio = m["flicker"]["ratio_raw_over_fused"]
    assert ratio == pytest.approx(raw["flicker_mean"] / out["flicker_mean"], rel=1e-12)
    page = page_path.read_text()
    mean_mm = f"{raw['flicker_mean']:.4g} mm → {out['flicker_mean']:.4g} mm"
    assert f"flicker (per-pixel std over time, mean) {mean_mm} ({ratio:.3g}× less)" in page
    assert "raw was still" not in page
    capsys.readouterr()
    print_report_summary(page_path)
    line = next(x for x in capsys.readouterr().out.splitlines() if "temporal precision" in x)
    assert "mean std" in line
    assert f"{raw['flicker_mean']:.4g}" in line


def test_report_shows_the_parameters_a_run_stored_in_its_npz(small_ball, tmp_path):
    """`fuse4d run IN -o OUT.npz` stores its parameters (key fuse4d_params); the report read
    them only from a run folder's manifest and said "Not recorded" for an .npz."""
    from fuse4d.run import NPZ_PARAMS_KEY

    raw, fused = tmp_path / "raw.npz", tmp_path / "fused.npz"
    save_sequence(small_ball, raw)
    assert main(["run", str(raw), "-o", str(fused), "--window", "3", "--no-summary"]) == 0
    write_report(raw, fused, tmp_path / "rep")
    with np.load(fused) as z:
        members = {k: z[k] for k in z.files}
    record = json.loads(str(members[NPZ_PARAMS_KEY]))
    params = _metrics(tmp_path / "rep")["params"]
    assert params == {**record["fusion"], "flow_method": record["flow"]["method"]}
    assert params["num_frames"] == 3
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "Not recorded in the fused input" not in page
    # a record that does not parse: no parameters shown, the report is still written
    members[NPZ_PARAMS_KEY] = np.str_("{not json")
    np.savez(tmp_path / "odd.npz", **members)
    write_report(raw, tmp_path / "odd.npz", tmp_path / "rep2")
    assert _metrics(tmp_path / "rep2")["params"] is None
    assert "Not recorded in the fused input" in (tmp_path / "rep2" / "report.html").read_text()


def test_report_refuses_other_frames_and_warns_of_another_input(tmp_path, capsys):
    """`--frames 50:56` replaced the range a run folder records (raw frames 50-55 scored
    against fused 10-15): refused; a result of another recording was scored against this
    one without a word: a warning."""
    seq = make_falling_ball(small=True, num_frames=10)
    other = make_falling_ball(small=True, num_frames=10, rng=7)
    a, b = tmp_path / "a", tmp_path / "b.npz"
    with pytest.warns(UserWarning, match="does not store ground-truth"):
        save_sequence(seq, a, depth_unit_mm=0.05)  # a frame folder: run writes one, manifest
    save_sequence(other, b)
    run = tmp_path / "run"
    assert main(["run", str(a), "-o", str(run), "--frames", "2:8", "--window", "3"]) == 0
    capsys.readouterr()
    assert main(["report", str(a), str(run), "-o", str(tmp_path / "r1"), "--frames", "3:9"]) == 2
    assert "--frames 3:9: " in capsys.readouterr().err
    # the same range spelled otherwise is the same range
    assert main(["report", str(a), str(run), "-o", str(tmp_path / "r0"), "--frames", "2:-2"]) == 0
    capsys.readouterr()
    # another recording: said (a warning: an .mkv or .zarr output does not record how its
    # input was read, so a true result read otherwise differs too)
    with pytest.warns(UserWarning, match=r"its intensity \(frame 0\) is not that of .*b\.npz"):
        assert main(["report", str(b), str(run), "-o", str(tmp_path / "r2")]) == 0
    assert not (tmp_path / "r1").exists()


def test_video_rate_is_the_rate_asked_for():
    """--fps 7.5 played at 8 and 0.4 at 1 (rounded to a whole number, at least 1)."""
    from fractions import Fraction

    from fuse4d.report.video import video_rate

    assert video_rate(7.5) == Fraction(15, 2)
    assert video_rate(0.4) == Fraction(2, 5)
    assert float(video_rate(29.97)) == pytest.approx(29.97, abs=1e-9)
    assert video_rate(30) == 30
    assert video_rate(90.0009).numerator <= 65535  # the mpeg4 fallback's limit (was 90091)
    with pytest.raises(ParameterError, match=r"fps must be in \[0.001, 65535\]"):
        video_rate(0.0004)  # was 0/1: PyAV's default 24 fps, and "fps": 0.0 in metrics.json


def test_report_static_pixels_are_those_of_fuse4d_metrics(tmp_path, capsys):
    """Without ground truth the report found its static pixels by quiet intensity, another
    set than `fuse4d metrics` and the run summary (colour resampled onto a wider depth grid
    is 0, quiet, outside the colour camera's view: 58 % of a RealSense bag was "static").
    Now the depth rule of all three: the same pixels, the same per-pixel std."""
    import dataclasses

    from fuse4d.range_scenes import make_range_scene

    seq = make_range_scene("body", sensor="kinect", small=True, num_frames=6, rng=3)
    inten = seq.intensity.copy()
    inten[:, :, :60] = 0.0  # no guide signal in the left columns
    seq = dataclasses.replace(seq, intensity=inten, ground_truth=None)
    raw, fused = tmp_path / "raw.npz", tmp_path / "fused.npz"
    save_sequence(seq, raw)
    assert main(["run", str(raw), "-o", str(fused), "--window", "3", "--no-summary"]) == 0
    assert main(["report", str(raw), str(fused), "-o", str(tmp_path / "rep")]) == 0
    m = _metrics(tmp_path / "rep")
    capsys.readouterr()
    assert main(["metrics", str(raw), str(fused), "--no-shape", "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    assert m["flicker"]["static_pixels"] == cli["static"]["pixels"] > 0
    assert m["flicker"]["static_source"] == cli["static"]["description"].split(";")[0]
    for name, key in (("raw", "raw"), ("fused", "output")):
        assert m["metrics"][name]["flicker_mean"] == pytest.approx(
            cli[key]["flicker_std_mean"], rel=1e-6
        )
        assert m["metrics"][name]["flicker_median"] == pytest.approx(
            cli[key]["flicker_std_median"], rel=1e-6
        )


def test_an_input_rate_no_video_can_have_falls_back_with_a_warning(
    small_ball, small_fused, tmp_path
):
    """A recording's own rate of 100000 fps (a misread timestamp unit) failed the report after
    all its work, naming an option the user never gave."""
    import dataclasses

    fast = dataclasses.replace(small_ball.frames(0, 3), fps=100000.0)
    with pytest.warns(UserWarning, match="its frame rate 100000 fps is not one a video"):
        write_report(fast, small_fused.depth[:3], tmp_path / "rep")
    assert _metrics(tmp_path / "rep")["video"]["fps"] == 10.0


def test_ground_truth_zero_is_no_truth_as_in_fuse4d_metrics(small_ball, small_fused, tmp_path):
    """A 0 in the ground truth counted as a true depth of 0 mm: RMSE ~1.8 m in the report
    against tens of mm from fuse4d metrics, which takes 0 as invalid."""
    from fuse4d.metrics import depth_rmse

    gt = np.array(small_ball.ground_truth.depth, dtype=np.float32)
    gt[:, :, :30] = 0.0
    write_report(small_ball, small_fused, tmp_path / "rep", ground_truth=gt)
    rmse = _metrics(tmp_path / "rep")["metrics"]["fused"]["rmse"]
    assert rmse == pytest.approx(depth_rmse(gt, small_fused.depth), rel=1e-6)
    assert rmse < 100.0


# --------------------------------------------------------------------------- dropped frames
@pytest.fixture(scope="module")
def dropped_ball(small_ball, tmp_path_factory):
    """The 4-frame ball saved with frame 2 (the middle one) dropped: all-NaN depth."""
    import dataclasses

    depth = np.array(small_ball.depth, dtype=np.float32)
    depth[2] = np.nan
    path = tmp_path_factory.mktemp("dropped") / "drop.npz"
    save_sequence(dataclasses.replace(small_ball, depth=depth), path)
    return path


def test_a_dropped_middle_frame_decides_neither_frame_nor_ranges_nor_planes(
    dropped_ball, small_fused, tmp_path, monkeypatch
):
    """With the middle frame empty the report rendered it, set the roughness scale and
    histogram to 0-1 mm (85 % of raw in the overflow bin), found no plane, and drew the
    histogram means from clipped bin centres, not the table's; with --frames its captions
    named no input frame; the video counted from 1, the page from 0."""
    from fuse4d.report import figures

    seen: dict = {}
    draw = figures.roughness_figure

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return draw(*args, **kwargs)

    monkeypatch.setattr(figures, "roughness_figure", spy)
    out = tmp_path / "rep"
    # frames 1:4 of the input: 1, 2 (empty), 3; the middle one of the run is input frame 2
    fused = small_fused.depth[1:4]  # a plain array: neither support nor source stored
    write_report(dropped_ball, fused, out, reader_options={"frames": "1:4"})
    m = _metrics(out)
    assert m["frame_rendered"] == 0  # the nearest frame with depth (was 1, the empty one)
    assert m["frame_rendered_input"] == 1
    edges = m["roughness"]["histogram_edges_mm"]
    assert edges[-1] > 1.0  # was 1 mm, the fallback of an empty frame
    raw_hist = np.array(m["roughness"]["histograms"]["raw"])
    assert raw_hist[-1] < 0.05 * raw_hist.sum()  # the overflow bin
    assert [p["source"] for p in m["planes"]] == ["detected"]  # the wall (none before)
    assert m["metrics"]["raw"]["spatial_precision"] > 0
    assert seen["means"] == {n: m["metrics"][n]["roughness_mean"] for n in ("raw", "fused")}
    page = (out / "report.html").read_text()
    assert "Frame 0 (input frame 1) back-projected" in page
    assert "Frames counted from 0 = input frame 1." in page
    assert "dotted: the roughness means of the table" in page
    # what the page says of panels that are not drawn (an .mkv result stores neither)
    assert "temporal support of each pixel" not in page
    assert "stores neither support maps nor source codes" in page
    assert "Hole-filled" not in page
    assert "Neither support (frames fused per pixel) nor the source" in page


def test_roi_plane_is_fitted_where_the_region_has_depth(dropped_ball, small_fused, tmp_path):
    """--roi on an empty rendered frame, or on a region too small for a plane fit, was an
    internal error (a plain ValueError from given_plane)."""
    roi = (118, 146, 4, 40)  # the static wall below-left of the ball
    write_report(dropped_ball, small_fused, tmp_path / "rep", roi=roi, frame=2)
    m = _metrics(tmp_path / "rep")
    assert m["frame_rendered"] == 2  # as asked, though empty
    assert [p["source"] for p in m["planes"]] == ["given"]
    assert 0.15 < m["metrics"]["raw"]["spatial_precision"] < 0.25  # sigma_d = 0.2 mm
    code = main(
        ["report", str(dropped_ball), str(dropped_ball), "-o", str(tmp_path / "r"),
         "--roi", "5:6,5:6"]
    )  # fmt: skip
    assert code == 2  # one line, not "internal error" (exit 70)
    with pytest.raises(ParameterError, match="roi 5:6,5:6: the region holds at most 1 pixel"):
        write_report(dropped_ball, small_fused, tmp_path / "r", roi=(5, 6, 5, 6))
    assert not (tmp_path / "r").exists()


def test_video_note_and_header_say_what_is_shown(monkeypatch):
    """The note described a support panel the video did not have, and the header counted
    frames from 1 where the page and --frame count from 0."""
    from fuse4d.report import _video_note
    from fuse4d.report.layout import VideoLayout

    def layout(support: bool, source: bool) -> VideoLayout:
        return VideoLayout((20, 30), depth_range=(500, 1000), diff_max=1.0, support_max=4.0,
                           show_support=support, show_source=source)  # fmt: skip

    assert "temporal support of each pixel" in _video_note("libx264", 1, 0, 1, layout(True, 0))
    assert "where each value comes from" in _video_note("libx264", 1, 0, 1, layout(False, 1))
    bare = _video_note("libx264", 1, 0, 1, layout(False, False))
    assert "temporal support" not in bare
    assert "stores neither support maps nor source codes" in bare
    texts: list[str] = []
    lay = layout(True, False)
    monkeypatch.setattr(lay, "_text", lambda img, text, *a, **k: texts.append(text))
    panels = (np.zeros((20, 30, 3), np.uint8),) * 6
    lay.compose(5, 12, panels, label="x.npz")
    lay.compose(2, 8, panels, label="x.npz", input_frame=42)
    assert texts == ["frame 5 of 0-11   x.npz", "frame 2 of 0-7 (input frame 42)   x.npz"]


def test_figures_have_whole_frame_ticks_and_no_log_scale_of_nothing(monkeypatch):
    """An all-NaN result printed matplotlib's "Data has no positive values, and therefore
    cannot be log-scaled" as a fuse4d warning; time axes had ticks at frame 2.5 (0.2 for two
    frames)."""
    from fuse4d.report import figures

    drawn: list = []
    monkeypatch.setattr(figures, "png_bytes", lambda fig, **kwargs: drawn.append(fig) or b"")
    edges = np.linspace(0.0, 1.0, 61)
    empty = {n: np.zeros(60, np.int64) for n in ("raw", "fused")}
    maps = {n: np.full((8, 8), np.nan, np.float32) for n in ("raw", "fused")}
    nan = float("nan")
    figures.roughness_figure(maps, empty, edges, frame=0, means={"raw": nan, "fused": nan})
    assert drawn[-1].axes[-1].get_yscale() == "linear"
    figures.timeseries_figure({"raw": np.arange(2.0)[:, None]}, [(1, 1, "p")])
    ticks = drawn[-1].axes[0].get_xticks()
    figures.xt_figure(
        {"raw": np.zeros((3, 8), np.float32)}, axis="row", index=3, vmin=0, vmax=1,
        change_range=1,
    )  # fmt: skip
    ticks = np.concatenate([ticks, *(ax.get_yticks() for ax in drawn[-1].axes[:2])])
    assert len(ticks) > 2
    np.testing.assert_array_equal(ticks, np.round(ticks))
