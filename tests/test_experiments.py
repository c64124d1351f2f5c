"""The paper experiments (fuse4d.experiments.paper): runner, resume, quick runs, verdicts."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from fuse4d.cli import main
from fuse4d.experiments.paper import EXPERIMENTS, e3, e4, get_profile, run_experiment
from fuse4d.experiments.paper._runner import Unit, read_rows, run_units, unit_file, write_rows
from fuse4d.experiments.paper._summary import group_stats
from fuse4d.experiments.paper.verdicts import (
    compute_verdicts,
    generated_block,
    report_block,
    verdict_table,
)

ROOT = Path(__file__).resolve().parents[1]
COMMITTED = ROOT / "docs" / "reproduction"
CALLS: list[int] = []


def _count(i: int) -> list[dict]:
    CALLS.append(i)
    return [{"frame": 0, "value": float(i)}, {"frame": 1, "value": math.nan}]


def _boom(i: int) -> list[dict]:
    raise KeyboardInterrupt


def test_rows_round_trip(tmp_path):
    rows = [{"a": "x", "b": 1.5, "c": math.nan}, {"a": "y", "d": 2}]
    write_rows(tmp_path / "r.csv", rows)
    back = read_rows(tmp_path / "r.csv")
    assert back[0]["a"] == "x"
    assert back[0]["b"] == 1.5
    assert math.isnan(back[0]["c"])
    assert back[1]["d"] == 2.0
    assert math.isnan(back[1]["b"])


def test_resume_never_recomputes_finished_units(tmp_path):
    CALLS.clear()
    units = [Unit(f"u{i}", _count, {"i": i}) for i in range(3)]
    # an interrupted run: u0 and u1 finish, then Ctrl-C in u2's place
    broken = [*units[:2], Unit("u2", _boom, {"i": 2})]
    with pytest.raises(KeyboardInterrupt):
        run_units("T", broken, tmp_path)
    assert CALLS == [0, 1]
    assert unit_file(tmp_path, "u1").exists()
    assert not unit_file(tmp_path, "u2").exists()
    rows, _ = run_units("T", units, tmp_path)
    assert CALLS == [0, 1, 2]  # only the unfinished unit ran again
    assert [r["value"] for r in rows if r["frame"] == 0] == [0.0, 1.0, 2.0]


def test_rows_of_an_earlier_version_without_a_summary_column_are_recomputed(tmp_path):
    """`real` rows cached before its summary read flicker_mean gave n/a columns on resume."""
    CALLS.clear()
    units = [Unit(f"u{i}", _count, {"i": i}) for i in range(2)]
    write_rows(unit_file(tmp_path, "u0"), [{"frame": 0, "old": 1.0}])  # an older row file
    write_rows(unit_file(tmp_path, "u1"), [{"frame": 0, "value": 5.0}])
    rows, _ = run_units("T", units, tmp_path, columns=("value",))
    assert CALLS == [0]
    assert [r["value"] for r in rows if r["frame"] == 0] == [0.0, 5.0]


def test_group_stats_over_frames_and_seeds():
    rows = [{"m": "a", "seed": s, "v": v} for s, vals in ((0, (1, 3)), (1, (5, 7))) for v in vals]
    st = group_stats(rows, ("m",), "v")[("a",)]
    assert st.mean == 4.0
    assert st.std_frames == 1.0
    assert st.std_seeds == 2.0
    assert st.n_seeds == 2


def test_pareto_front_and_matched_c():
    pts = [(1.0, 99.0, 1, 1), (2.0, 99.5, 2, 1), (1.5, 98.0, 3, 1), (3.0, 99.4, 4, 1)]
    front = e3.pareto_front(pts)
    assert [p[0] for p in front] == [1.0, 2.0]
    assert e3.c_at(front, 1.5) == pytest.approx(99.25)
    assert math.isnan(e3.c_at(front, 0.5))


def test_e4_fit_recovers_model():
    ns = list(range(1, 10))
    ys = [math.sqrt(0.3**2 + 0.8**2 / n) for n in ns]
    ds, dt, r2 = e4.fit(ns, ys)
    assert ds == pytest.approx(0.3, rel=1e-3)
    assert dt == pytest.approx(0.8, rel=1e-3)
    assert r2 == pytest.approx(1.0)


def test_profiles_and_unknown_names():
    assert get_profile("quick").small
    assert not get_profile("paper").small
    with pytest.raises(ValueError, match="unknown profile"):
        get_profile("huge")
    with pytest.raises(ValueError, match="unknown experiment"):
        run_experiment("E9", "x")


def test_e1_quick_subset_writes_every_output(tmp_path):
    """E1 at CI size on two noise levels: CSV, summary, PNG, JSON, and a resumed rerun."""
    import dataclasses

    prof = dataclasses.replace(get_profile("quick"), sigma_d_levels=(0.1, 0.4), num_frames=6)
    res = run_experiment("E1", tmp_path, profile=prof)
    d = tmp_path / "E1"
    for name in ("E1.csv", "E1.md", "E1.json", "E1_roughness_vs_depth_noise.png"):
        assert (d / name).is_file(), name
    rows = read_rows(d / "E1.csv")
    assert len(rows) == res["rows"] == 2 * 9 * 6  # levels x methods x frames
    assert {r["label"] for r in rows} >= {"Raw", "Ours (9 frames)", "Ad-JBF", "ST-MF"}
    stats = group_stats(rows, ("method", "sigma_d"), "roughness")
    assert stats[("ours", 0.4)].mean < stats[("raw", 0.4)].mean
    unit_files = {p: p.stat().st_mtime_ns for p in (d / "rows").glob("*.csv")}
    again = run_experiment("E1", tmp_path, profile=prof)
    assert again["rows"] == res["rows"]
    # nothing recomputed: no unit's rows were written again
    assert len(unit_files) == 9 * 2  # methods x levels
    assert all(p.stat().st_mtime_ns == t for p, t in unit_files.items())
    # another profile in the same folder took these rows as its own (a --profile reduced run
    # in a --quick run's folder mixed 150x150 and 600x600 rows)
    from fuse4d.errors import ParameterError

    other = dataclasses.replace(prof, num_frames=7)
    with pytest.raises(ParameterError, match=r"holds the rows of a E1 run with another profile"):
        run_experiment("E1", tmp_path, profile=other)


def test_real_crop_keeps_the_geometry():
    """The quick profile's crop of a real recording: same 3D points, mask cut to match."""
    from fuse4d.camera import depth_to_points
    from fuse4d.experiments.paper.real import _crop
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=3, rng=0)
    out = _crop(seq, 60, 80)
    assert out.depth.shape == out.intensity.shape == out.ground_truth.mask.shape == (3, 60, 80)
    assert (out.intrinsics.width, out.intrinsics.height) == (80, 60)
    full = depth_to_points(seq.depth, seq.intrinsics)
    ys, xs = np.nonzero(seq.ground_truth.mask.any(axis=0))
    v0 = (ys.min() + ys.max()) // 2 - 30
    u0 = (xs.min() + xs.max()) // 2 - 40
    np.testing.assert_allclose(
        depth_to_points(out.depth, out.intrinsics),
        full[:, v0 : v0 + 60, u0 : u0 + 80],
        rtol=1e-6,
    )
    assert out.ground_truth.mask.sum() == seq.ground_truth.mask[:, v0 : v0 + 60, u0 : u0 + 80].sum()


def test_cli_lists_experiments_and_rejects_bad_name(tmp_path, capsys):
    assert main(["experiments", "E9", "--out", str(tmp_path)]) == 2
    assert "unknown experiment" in capsys.readouterr().err
    assert set(EXPERIMENTS) == {"E1", "E2", "E3", "E4", "E5", "E6", "real"}


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["E1", "--profile", "huge"], "--profile 'huge': choose one of"),
        (["E1", "--quick", "--profile", "reduced"], "pass one"),
        (["E1", "--quick", "--report", "R.md"], "pass --publish DIR too"),
        (["E1", "--quick", "--log", "."], "--log .: cannot be written"),
        (["E1", "--quick", "--publish", "afile"], "--publish afile: exists and is not a folder"),
        (["E1", "--quick", "--publish", "afile/sub"], "--publish afile/sub: cannot be created"),
        (["verdicts", "--report", "nodir/R.md"], "not a Markdown file in an existing folder"),
    ],
)
def test_cli_bad_options_fail_before_any_compute(tmp_path, monkeypatch, capsys, args, says):
    """Every option that would fail after the run (a wrong profile, an unwritable --publish
    or --log, a --report nothing would write) is one clear line before any unit runs."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("")
    assert main(["experiments", *args, "--out", "run"]) == 2
    assert says in capsys.readouterr().err
    assert not (tmp_path / "run" / "E1").exists()  # nothing computed


def test_cli_verdicts_need_a_run_folder_with_results(tmp_path, capsys):
    """A mistyped --out is an error, not a table of twelve N/A."""
    assert main(["experiments", "verdicts", "--out", str(tmp_path / "nope")]) == 2
    assert "no such run folder" in capsys.readouterr().err
    assert main(["experiments", "verdicts", "--out", str(tmp_path)]) == 2
    assert "holds no experiment results" in capsys.readouterr().err


@pytest.mark.skipif(not (COMMITTED / "E1" / "E1.csv").exists(), reason="no committed run")
def test_reproduction_md_verdicts_match_committed_csvs():
    """REPRODUCTION.md's verdict table is exactly what the committed CSVs give."""
    verdicts = compute_verdicts(COMMITTED)
    assert report_block(ROOT / "REPRODUCTION.md") == generated_block(COMMITTED)
    assert all(v.verdict in ("PASS", "FAIL", "N/A") for v in verdicts)


#: The plots every experiment must write (the paper's figures, EVALUATION.md §4).
PLOTS = {
    "E1": ("E1_roughness_vs_depth_noise.png",),
    "E2": ("E2_roughness_vs_intensity_noise.png",),
    "E3": ("E3_tradeoff.png", "E3_side_view.png"),
    "E4": ("E4_roughness_vs_frames.png",),
    "E5": ("E5_table1.png",),
    "E6": ("E6_ablations.png",),
    "real": ("real_person_frame.png", "real_person_xt.png"),
}


@pytest.mark.slow
def test_quick_all_runs_every_experiment(tmp_path):
    """``fuse4d experiments all --quick``: every experiment end to end at CI size, every output
    well-formed (tidy CSV, Markdown summary with its figures, readable PNGs, parameter JSON)."""
    import json

    from PIL import Image

    from fuse4d.experiments.paper.real import RECORDINGS, data_dir

    assert main(["experiments", "all", "--out", str(tmp_path), "--quick"]) == 0
    have_data = all((data_dir() / r).is_dir() for r in RECORDINGS.values())
    for name in EXPERIMENTS:
        d = tmp_path / name
        meta = json.loads((d / f"{name}.json").read_text())
        assert meta["experiment"] == name
        assert meta["profile"]["name"] == "quick"
        assert meta["fuse4d_version"]
        assert "parameters" in meta
        md = (d / f"{name}.md").read_text()
        assert md.startswith("# "), name
        if name == "real" and not have_data:
            assert "skipped" in md
            continue
        rows = read_rows(d / f"{name}.csv")
        assert len(rows) == meta["rows"] > 0, name
        assert all(r["experiment"] == name and isinstance(r["method"], str) for r in rows)
        assert np.isfinite([r["roughness"] for r in rows]).mean() > 0.9, name
        assert "|---" in md, name  # a Markdown table
        for png in PLOTS[name]:
            with Image.open(d / png) as im:
                im.verify()
                assert im.format == "PNG", (name, png)
                assert min(im.size) >= 200, (name, png)
        for link in re.findall(r"!\[[^]]*\]\(([^)]+)\)", md):
            assert (d / link).is_file(), (name, link)
    e5 = read_rows(tmp_path / "E5" / "E5.csv")
    assert {(r["scene"], r["method"]) for r in e5} >= {
        ("plane", "kinectfusion"),
        ("ball", "ed"),
        ("sheet", "ed"),
    }
    assert np.isfinite([r["roughness"] for r in e5]).all()
    assert np.isfinite([r["c_3d"] for r in read_rows(tmp_path / "E3" / "E3.csv")]).any()
    verdicts = compute_verdicts(tmp_path)
    assert [v.claim for v in verdicts] == [f"C{i}" for i in range(1, 13)]
    assert all(v.verdict in ("PASS", "FAIL") for v in verdicts), verdict_table(verdicts)


def test_e3_paper_profile_sweeps_filter_iterations_to_five():
    """EVALUATION §4 E3: the filters' iterations 1-5 in the paper profile, Ours 1-3; the reduced
    and quick sweeps unchanged."""
    paper = e3.settings(get_profile("paper"))
    its = {m: {i for mm, _, i in paper if mm == m} for m, _, _ in paper}
    assert its["dnbf"] == its["adbf"] == its["guided"] == {1, 2, 3, 4, 5}
    assert its["stmf"] == {1, 2, 3}  # its own BASELINES list stops at 3
    assert its["ours"] == {1, 2, 3}
    assert len(e3.settings(get_profile("reduced"))) == 49
    assert len(e3.settings(get_profile("quick"))) == 35


def test_e6_has_the_full_literal_configuration(tmp_path):
    """E6 runs METHOD A3's fully literal configuration (the one definition in fuse4d.config)
    beside the single-switch motion_depth=raw ablation, in every profile, and it runs."""
    import dataclasses

    from fuse4d.config import LITERAL_PAPER, FusionParams
    from fuse4d.experiments.paper import e6
    from fuse4d.experiments.paper._common import Context

    overrides, flow, _ = e6.VARIANTS[e6.LITERAL]
    assert overrides == dict(LITERAL_PAPER)
    assert flow is None
    assert e6.VARIANTS["motion_depth=raw"][0] == {"motion_depth": "raw"}
    FusionParams(**LITERAL_PAPER)  # valid
    quick = get_profile("quick")
    keys = {u.key for u in e6.units(Context(quick, tmp_path))}
    assert {f"{e6.LITERAL}_si0.02", "motion_depth=raw_si0.02", "default_si0.02"} <= keys
    prof = dataclasses.replace(quick, num_frames=6)
    rows = e6.unit(prof, tmp_path / "flow_cache", e6.LITERAL, 0.02, 0)
    assert len(rows) == 6
    assert {r["variant"] for r in rows} == {e6.LITERAL}
    assert np.isfinite([r["roughness"] for r in rows]).all()


def _e6_rows(literal: float, single: float) -> list[dict]:
    rows = []
    for si in (0.02, 0.10):
        for variant, rough in (
            ("raw-input", 1.0),
            ("default", 0.05),
            ("literal-eq5", literal),
            ("motion_depth=raw", single),
        ):
            rows += [
                {
                    "experiment": "E6",
                    "variant": variant,
                    "sigma_i": si,
                    "frame": f,
                    "roughness": rough,
                }
                for f in range(3)
            ]
    return rows


def test_c12_judges_the_full_literal_configuration(tmp_path):
    """C12 compares the literal configuration (not the single switch) with the default."""

    def c12(literal: float, single: float):
        write_rows(tmp_path / "E6" / "E6.csv", _e6_rows(literal, single))
        return next(v for v in compute_verdicts(tmp_path) if v.claim == "C12")

    v = c12(literal=0.9, single=0.1)
    assert v.verdict == "PASS"
    assert "full literal configuration 0.900" in v.ours
    assert "motion_depth=raw: 0.100" in v.ours
    assert c12(literal=0.3, single=0.9).verdict == "FAIL"  # the single switch is not judged
    rows = [r for r in _e6_rows(0.9, 0.9) if r["variant"] != "literal-eq5"]
    write_rows(tmp_path / "E6" / "E6.csv", rows)
    v = next(v for v in compute_verdicts(tmp_path) if v.claim == "C12")
    assert v.verdict == "N/A"  # an E6 run without the literal variant cannot judge C12


def test_compute_total_counts_an_interrupted_call(tmp_path, monkeypatch):
    """The total came from the last JSON, written only at the end: the time of a call
    stopped with Ctrl-C was lost from the resumed run's seconds_compute_total."""
    from fuse4d.experiments import paper

    real = paper.run_units

    def interrupted(*args, **kwargs):
        import time

        time.sleep(0.3)
        raise KeyboardInterrupt

    monkeypatch.setattr(paper, "run_units", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_experiment("E1", tmp_path, profile="quick")
    monkeypatch.setattr(paper, "run_units", real)
    payload = run_experiment("E1", tmp_path, profile="quick")
    assert payload["seconds_compute_total"] >= payload["seconds_this_call"] + 0.3 - 0.05


def test_ctrl_c_prints_one_line_and_exits_130(tmp_path, monkeypatch, capsys):
    """Ctrl-C printed the command's own 'interrupted during E1: ...' and then the CLI's
    'fuse4d: interrupted'; one line now, that still says how to go on (the --log file records
    where it stopped)."""
    from fuse4d.experiments import paper

    def interrupted(name, *args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(paper, "run_experiment", interrupted)
    log = tmp_path / "run.log"
    code = main(["experiments", "E1", "--out", str(tmp_path / "run"), "--log", str(log)])
    assert code == 130
    assert capsys.readouterr().err.strip().splitlines() == [
        "fuse4d: interrupted during E1: finished units are kept; rerun the same command to resume"
    ]
    assert "interrupted during E1" in log.read_text()


def test_e4_rows_are_labelled_with_their_own_frame_count(tmp_path):
    """Every E4 row said 'Ours (9 frames)', those of Ours fusing 1..8 frames too."""
    profile = get_profile("quick")
    rows = e4.unit(profile, tmp_path, "plane", 3, profile.seeds[0])
    assert rows
    assert {r["label"] for r in rows} == {"Ours (3 frames)"}
    assert {r["n_frames"] for r in rows} == {3}
    assert e4.ours_label(1) == "Ours (1 frame)"
    assert e4.ours_label(9) == "Ours (9 frames)"
