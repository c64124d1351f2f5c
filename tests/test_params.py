"""The one parameter layer (fuse4d._params): validation, coercion, and the paths that use it
(API, TOML, ``run --set/--flow-param``, ``flow -p``, ``baseline --size/-p``)."""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from fuse4d import FlowConfig, FusionEngine, FusionParams, Intrinsics, Sequence, fuse_sequence
from fuse4d._params import (
    check_value,
    coerce_fields,
    coerce_kwargs,
    param,
    parse_assignments,
    validate,
)
from fuse4d.baselines import available_baselines, get_baseline, guided, run_baseline
from fuse4d.cli import main
from fuse4d.config import load_config
from fuse4d.errors import InputFileError, ParameterError, ParameterTypeError
from fuse4d.flow import (
    DISParams,
    PMBPFastParams,
    PMBPParams,
    TVL1Params,
    estimate_flow,
    flow_params_from_mapping,
    read_flo,
)
from fuse4d.io import load_sequence, save_sequence

# ------------------------------------------------------------------------------- validate


@pytest.mark.parametrize(
    ("factory", "error", "message"),
    [
        (lambda: FusionParams(num_frames=0), ValueError, r"num_frames must be an integer in \[1, 256\], got 0"),
        (lambda: FusionParams(num_frames=257), ValueError, r"FusionParams\.num_frames .* got 257"),
        (lambda: FusionParams(sigma_distance=0), ValueError, r"sigma_distance must be a number > 0, got 0"),
        (lambda: FusionParams(sigma_fill=math.nan), ValueError, r"sigma_fill must be a number > 0, got nan"),
        (lambda: FusionParams(distance_noise_scale=-1), ValueError, r"must be a number >= 0, got -1"),
        (lambda: FusionParams(sigma_intensity="0.1"), TypeError, r"sigma_intensity must be a number, got '0.1'"),
        (lambda: FusionParams(fill_holes=1), TypeError, r"fill_holes must be True or False, got 1"),
        (
            lambda: FusionParams(base="x"),
            ValueError,
            r"base must be one of 'adaptive', 'trajectory', 'frame', 'quadratic', got 'x'",
        ),
        (lambda: PMBPParams(num_particles=17), ValueError, r"PMBPParams\.num_particles must be an integer in \[1, 16\], got 17"),
        (lambda: PMBPParams(num_particles=2.0), ValueError, r"num_particles must be an integer"),
        (lambda: PMBPParams(max_motion=math.inf), ValueError, r"max_motion must be a finite number > 0, got inf"),
        (lambda: PMBPParams(coarse_num_iter="3"), ValueError, r"coarse_num_iter must be None or an integer >= 0, got '3'"),
        (lambda: PMBPParams(search_radius0=0.0), ValueError, r"search_radius0 must be None or a finite number > 0"),
        (lambda: PMBPParams(finest_level=3), ValueError, r"finest_level must be an integer in \[0, 2\], got 3"),
        (lambda: PMBPParams(roi=(0, 4, 0)), ValueError, r"roi must be None or a tuple of 4 integers"),
        (lambda: PMBPParams(roi=(4, 0, 0, 4)), ValueError, r"roi must satisfy 0 <= row0 < row1"),
        (lambda: PMBPFastParams(num_particles=0), ValueError, r"PMBPFastParams\.num_particles must be an integer in \[1, 16\]"),
        (lambda: PMBPFastParams(seed=-1), ValueError, r"PMBPFastParams\.seed must be an integer in \[0, 9223372036854775807\], got -1$"),
        (lambda: check_value("K", "x", -1, int, ge=0, le=10**7), ValueError, r"K\.x must be an integer in \[0, 10000000\], got -1$"),
        (lambda: check_value("K", "x", -1, float, ge=0, le=10**7), ValueError, r"K\.x must be a number in \[0, 1e\+07\], got -1$"),
        (lambda: DISParams(patch_stride=9), ValueError, r"DISParams\.patch_stride must be <= patch_size \(8\), got 9"),
        (lambda: DISParams(finest_scale=-1), ValueError, r"DISParams\.finest_scale must be an integer >= 0, got -1"),
        (lambda: TVL1Params(scale_step=1.0), ValueError, r"TVL1Params\.scale_step must be a finite number in \(0, 1\), got 1.0"),
    ],
)  # fmt: skip
def test_validation_names_class_field_bound_and_value(factory, error, message):
    with pytest.raises(error, match=message):
        factory()


def test_validation_normalises_values():
    p = FusionParams(sigma_distance=2, num_frames=np.int64(5), fill_holes=np.bool_(False))
    assert type(p.sigma_distance) is float
    assert type(p.num_frames) is int
    assert p.fill_holes is False
    assert FusionParams(sigma_temporal=math.inf).sigma_temporal == math.inf  # inf allowed here
    assert FusionParams(num_frames=256).num_frames == 256
    assert PMBPParams(roi=[0, 8, 0, 8]).roi == (0, 8, 0, 8)
    assert PMBPParams(coarse_num_iter=None).coarse_num_iter is None
    assert PMBPFastParams() == PMBPFastParams(num_particles=1, finest_level=1, num_iter=2)
    assert FusionParams() == FusionParams().replace()  # defaults unchanged


def test_param_metadata_on_any_dataclass():
    @dataclass(frozen=True)
    class Knobs:
        radius: int = param(2, ge=1, le=5)
        scale: float | None = param(None, gt=0, lt=1)
        ratio: float = param(0.5, ge=0, le=1, finite=True)
        mode: str = "a"

        def __post_init__(self):
            validate(self)

    assert Knobs(scale=0.5).scale == 0.5
    with pytest.raises(ValueError, match=r"Knobs\.radius must be an integer in \[1, 5\], got 6"):
        Knobs(radius=6)
    with pytest.raises(ValueError, match=r"Knobs\.scale must be None or a number in \(0, 1\)"):
        Knobs(scale=1.0)
    with pytest.raises(TypeError, match=r"Knobs\.mode must be text, got 3"):
        Knobs(mode=3)
    assert check_value("X", "t", [1, 2], tuple[int, ...]) == (1, 2)


# ------------------------------------------------------------------------------- coerce


def test_coerce_fields_reads_every_annotation_kind():
    values = coerce_fields(
        FusionParams,
        {"sigma_temporal": "inf", "fill_holes": "false", "base": "frame", "num_frames": "5"},
    )
    assert values == {
        "sigma_temporal": math.inf,
        "fill_holes": False,
        "base": "frame",
        "num_frames": 5,
    }
    p = FusionParams(**values)
    assert (p.sigma_temporal, p.fill_holes, p.base) == (math.inf, False, "frame")
    with pytest.raises(
        ValueError, match=r"parameter base: 'nope' is not one of adaptive, trajectory, frame"
    ):
        coerce_fields(FusionParams, {"base": "nope"})
    with pytest.raises(
        ValueError, match=r"parameter fill_holes: cannot read 'maybe' as true/false"
    ):
        coerce_fields(FusionParams, {"fill_holes": "maybe"})
    # X | None fields (bug b1)
    p = flow_params_from_mapping("pmbp", {"coarse_num_iter": "3", "search_radius0": "none"})
    assert (p.coarse_num_iter, p.search_radius0) == (3, None)
    assert coerce_fields(PMBPParams, {"roi": "0,8,0,8"}) == {"roi": (0, 8, 0, 8)}


def test_parse_assignments():
    assert parse_assignments(["a=1", " b = x ", "a=2"]) == {"a": "2", "b": "x"}
    assert parse_assignments(None) == {}
    with pytest.raises(ValueError, match="--set must look like KEY=VALUE, got 'a'"):
        parse_assignments(["a"], what="--set")


def test_coerce_kwargs_reads_function_keywords():
    assert coerce_kwargs(guided, {"size": "8", "eps": "0.01", "iterations": "2"}) == {
        "size": 8,
        "eps": 0.01,
        "iterations": 2,
    }
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) bogus for guided; valid: size"):
        coerce_kwargs(guided, {"bogus": 1})


# ------------------------------------------------------------------------------- TOML


def test_toml_goes_through_the_coercer(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(
        'preset = "paper"\n[fusion]\nsigma_temporal = "inf"\nfill_holes = false\nbase = "frame"\n'
        "[flow]\nroi = [0, 16, 0, 16]\n[flow.params]\ncoarse_num_iter = 3\n"
        'search_radius0 = "none"\n',
        encoding="utf-8",
    )
    cfg = load_config(path)
    assert cfg.fusion == FusionParams(sigma_temporal=math.inf, fill_holes=False, base="frame")
    assert cfg.flow.roi == (0, 16, 0, 16)
    assert cfg.flow.build_params() == PMBPParams(coarse_num_iter=3)
    path.write_text('[flow]\nmethod = "dis"\nbogus = 1\n', encoding="utf-8")
    with pytest.raises(InputFileError, match=r"unknown parameter\(s\) bogus for \[flow\]"):
        load_config(path)
    path.write_text("[fusion]\nnum_frames = 300\n", encoding="utf-8")
    with pytest.raises(InputFileError, match=r"FusionParams\.num_frames must be an integer in"):
        load_config(path)
    path.write_text("fusion = 5\n", encoding="utf-8")  # was "'int' object is not iterable"
    with pytest.raises(InputFileError, match=r"fusion must be a table \(\[fusion\] and key"):
        load_config(path)


# ------------------------------------------------------------------------------- CLI, end to end


H = W = 64


@pytest.fixture(scope="module")
def tiny():
    """3 frames of a textured plane at ~500 mm moving 1 px right per frame, 64x64 px."""
    rng = np.random.default_rng(3)
    k = Intrinsics(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=W, height=H)
    yy, xx = np.mgrid[0:H, 0 : W + 4]
    tex = (0.5 + 0.25 * np.sin(xx / 2.5) * np.cos(yy / 3.0)).astype(np.float32)
    intensity = np.stack([tex[:, 2 - t : 2 - t + W] for t in range(3)])
    depth = (500.0 + 0.3 * xx[:, :W] + rng.normal(0, 0.3, (3, H, W))).astype(np.float32)
    return Sequence(depth, intensity, k)


#: PMBP settings that keep the run short (no post-steps), with the b1 field set from a string
_PMBP = {"coarse_num_iter": "3", "consistency_check": "false", "variational_refinement_iterations": "0"}  # fmt: skip


def test_run_flow_param_optional_int_end_to_end(tiny, tmp_path, capsys):
    """Bug b1: ``run --flow pmbp --flow-param coarse_num_iter=3`` failed with 'must be an
    integer >= 0, got '3''; now it runs and equals the API call with the typed value."""
    src = save_sequence(tiny, tmp_path / "in.npz")
    out = tmp_path / "out.npz"
    args = ["run", str(src), "-o", str(out), "--window", "3", "--flow", "pmbp"]
    for key, value in _PMBP.items():
        args += ["--flow-param", f"{key}={value}"]
    assert main(args) == 0, capsys.readouterr().err
    typed = {"coarse_num_iter": 3, "consistency_check": False, "variational_refinement_iterations": 0}  # fmt: skip
    api = fuse_sequence(
        tiny.depth,
        tiny.intensity,
        tiny.intrinsics,
        fusion=FusionParams(num_frames=3),
        flow=FlowConfig("pmbp", typed),
    )
    np.testing.assert_array_equal(load_sequence(out).depth, api.depth)
    assert main([*args[:-2], "--flow-param", "coarse_num_iter=three", "--force"]) == 2
    assert "parameter coarse_num_iter: cannot read 'three' as an integer" in capsys.readouterr().err


def test_run_set_inf_bool_and_literal(tiny, tmp_path, capsys):
    src = save_sequence(tiny, tmp_path / "in.npz")
    out = tmp_path / "out.npz"
    sets = ["sigma_temporal=inf", "fill_holes=false", "base=frame", "spatial_radius=2"]
    args = ["run", str(src), "-o", str(out), "--window", "3"]
    assert main([*args, *(a for s in sets for a in ("--set", s))]) == 0, capsys.readouterr().err
    fusion = FusionParams(
        num_frames=3, sigma_temporal=math.inf, fill_holes=False, base="frame", spatial_radius=2
    )
    api = fuse_sequence(tiny.depth, tiny.intensity, tiny.intrinsics, fusion=fusion)
    np.testing.assert_array_equal(load_sequence(out).depth, api.depth)
    assert main([*args, "--force", "--set", "base=middle"]) == 2
    assert "'middle' is not one of adaptive, trajectory, frame" in capsys.readouterr().err
    assert main([*args, "--force", "--window", "300"]) == 2
    assert "num_frames must be an integer in [1, 256], got 300" in capsys.readouterr().err


def test_every_float_fusion_parameter_at_inf_is_refused_or_runs(tiny):
    """``--set motion_sigma=inf`` (and reference_sigma, base_smoothing, static_smoothing)
    passed validation and crashed in the blur's radius (OverflowError, an internal error):
    each float field either refuses inf or fuses with it."""
    from fuse4d.errors import ParameterError

    ran = []
    for f in dataclasses.fields(FusionParams):
        if not isinstance(getattr(FusionParams(), f.name), float):
            continue
        try:
            params = FusionParams(num_frames=3, **{f.name: math.inf})
        except ParameterError:
            continue
        out = fuse_sequence(tiny.depth, tiny.intensity, tiny.intrinsics, fusion=params)
        assert out.depth.shape == tiny.depth.shape, f.name
        ran.append(f.name)
    assert "sigma_temporal" in ran  # inf there means equal temporal weights (tested above)
    assert "motion_sigma" not in ran


def test_flow_command_param_optional_int(tiny, tmp_path, capsys):
    paths = []
    for t in (0, 1):
        paths.append(tmp_path / f"f{t}.png")
        cv2.imwrite(str(paths[-1]), np.round(255 * tiny.intensity[t]).astype(np.uint8))
    out = tmp_path / "f.flo"
    args = ["flow", str(paths[0]), str(paths[1]), "-o", str(out), "-m", "pmbp"]
    for key, value in _PMBP.items():
        args += ["-p", f"{key}={value}"]
    assert main(args) == 0, capsys.readouterr().err
    images = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float32) / 255 for p in paths]
    params = PMBPParams(
        coarse_num_iter=3, consistency_check=False, variational_refinement_iterations=0
    )
    expected = estimate_flow(images[0], images[1], method="pmbp", params=params)
    np.testing.assert_allclose(read_flo(out), expected, atol=1e-6)


# ------------------------------------------------------------------------------- baselines


def test_every_baseline_names_its_size():
    meanings = {
        "kernel_scale": "kernel scale",
        "spatial_radius": "pixel radius",
        "num_frames": "frames",
        "temporal_radius": "temporal radius",
        "filter_passes": "passes",
    }
    for name, info in available_baselines().items():
        assert info.size_name in meanings, name
        assert meanings[info.size_name] in info.size_meaning, name
    assert get_baseline("adgf").size_name == "kernel_scale"
    assert {n for n, i in available_baselines().items() if i.size_name == "temporal_radius"} == {
        "stmf",
        "kinectfusion",
        "ed",
    }


def test_baseline_size_by_name_and_from_strings(tiny):
    d, i, k = tiny.depth, tiny.intensity, tiny.intrinsics
    ref = run_baseline("guided", d, i, k, size=3, eps=0.01)
    np.testing.assert_array_equal(run_baseline("guided", d, i, k, spatial_radius=3, eps=0.01), ref)
    np.testing.assert_array_equal(run_baseline("guided", d, i, k, size="3", eps="0.01"), ref)
    with pytest.raises(ValueError, match="give size or spatial_radius, not both"):
        run_baseline("guided", d, i, k, size=3, spatial_radius=3)
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) radius for baseline 'guided'"):
        run_baseline("guided", d, i, k, radius=3)
    with pytest.raises(ValueError, match=r"guided\.size must be an integer in \[1, 64\], got 0"):
        run_baseline("guided", d, i, k, size=0)
    with pytest.raises(
        ValueError, match=r"adaptive_gaussian\.size must be a finite number in \(0, "
    ):
        run_baseline("adgf", d, i, k, kernel_scale=0.0)


def test_cli_baseline_size_and_knobs(tiny, tmp_path, capsys):
    src = save_sequence(tiny, tmp_path / "in.npz")
    d, i, k = tiny.depth, tiny.intensity, tiny.intrinsics
    cases = [
        ("guided", ["--size", "3", "-p", "eps=0.01"], {"size": 3, "eps": 0.01}),
        ("guided", ["-p", "spatial_radius=3", "-p", "eps=0.01"], {"size": 3, "eps": 0.01}),
        ("adgf", ["--size", "1.5", "-p", "noise_sigma=0.3"], {"size": 1.5, "noise_sigma": 0.3}),
        ("ta", ["-p", "num_frames=3", "--iterations", "2"], {"size": 3, "iterations": 2}),
    ]
    for n, (name, options, kwargs) in enumerate(cases):
        out = tmp_path / f"out{n}.npz"
        assert main(["baseline", name, str(src), "-o", str(out), *options]) == 0
        expected = run_baseline(name, d, i, k, **kwargs)
        np.testing.assert_array_equal(load_sequence(out).depth, expected)
    capsys.readouterr()
    out = str(tmp_path / "bad.npz")
    assert main(["baseline", "guided", str(src), "-o", out, "--size", "2.5"]) == 2
    assert "parameter size: cannot read '2.5' as an integer" in capsys.readouterr().err
    assert main(["baseline", "guided", str(src), "-o", out, "-p", "bogus=1"]) == 2
    assert "unknown parameter(s) bogus for baseline 'guided'" in capsys.readouterr().err
    assert main(["baseline", "--list"]) == 0
    assert "spatial_radius" in capsys.readouterr().out


# ------------------------------------------------------------------------------- intensity


def test_float_intensity_above_one_is_refused_naming_the_frame(tiny):
    d, k = tiny.depth, tiny.intrinsics
    scaled = tiny.intensity.copy()
    scaled[1] *= 255.0
    with pytest.raises(ValueError, match=r"intensity \(frame 1\) is float with values in .*"
                       r"outside \[0, 1\]; rescale it to \[0, 1\] \(e\.g\. divide 8-bit"):  # fmt: skip
        fuse_sequence(d, scaled, k, flow="dis")
    engine = FusionEngine(k)
    with pytest.raises(ValueError, match=r"intensity \(frame 0\) is float with values in \[-0\.2"):
        engine.push(d[0], tiny.intensity[0] - 0.5)
    # integers are still divided by their dtype maximum
    as_uint8 = np.round(255 * tiny.intensity).astype(np.uint8)
    assert fuse_sequence(d, as_uint8, k, flow="dis").depth.shape == d.shape


def test_non_finite_intensity_is_refused_naming_the_frame(tiny):
    """A NaN intensity pixel was passed on to the flow, which named "image0" (and a one-frame
    window, which computes no flow, would have weighed it as NaN)."""
    d, k = tiny.depth, tiny.intrinsics
    holes = tiny.intensity.copy()
    holes[2, :2, :3] = np.nan
    with pytest.raises(ParameterError, match=r"^intensity \(frame 2\) has 6 NaN or inf pixel"):
        fuse_sequence(d, holes, k, flow="dis")
    bright = tiny.intensity[0].copy()
    bright[3, 4] = np.inf
    with pytest.raises(ParameterError, match=r"^intensity \(frame 0\) has 1 NaN or inf"):
        FusionEngine(k).push(d[0], bright)


@pytest.mark.parametrize(
    ("fusion", "hint"),
    [
        ({"num_frames": 3}, r"got dict; FusionParams\(\*\*mapping\)"),
        ("fast", r"got str; fuse4d.preset\('fast'\).fusion"),
        (3, r"got int; e.g. FusionParams\(num_frames=5\)"),
    ],
)
def test_fusion_argument_of_another_type_says_how_to_make_one(tiny, fusion, hint):
    """``fusion={...}`` failed deep inside the run with an AttributeError."""
    d, k = tiny.depth, tiny.intrinsics
    with pytest.raises(ParameterTypeError, match=r"^fusion must be a FusionParams, " + hint):
        fuse_sequence(d, tiny.intensity, k, fusion=fusion)
    with pytest.raises(ParameterTypeError, match="fusion must be a FusionParams"):
        FusionEngine(k, fusion=fusion)


def test_intrinsics_of_another_type_say_how_to_make_them(tiny):
    """A tuple of fx, fy, cx, cy failed as an AttributeError inside the engine; one check
    (``camera.check_intrinsics``) serves the engine, fuse_sequence, Sequence, the baselines
    and the writers."""
    from fuse4d.baselines import run_baseline
    from fuse4d.io import FrameFolderWriter

    d, i = tiny.depth, tiny.intensity
    k = tuple(getattr(tiny.intrinsics, f) for f in ("fx", "fy", "cx", "cy"))
    message = r"^intrinsics must be a fuse4d.Intrinsics, got tuple; e.g. Intrinsics\(fx="
    for call in (
        lambda: FusionEngine(k),
        lambda: fuse_sequence(d, i, k),
        lambda: Sequence(d, i, k),
        lambda: run_baseline("temporal-mean", d, i, k),
        lambda: FrameFolderWriter("unused", k),
    ):
        with pytest.raises(ParameterTypeError, match=message):
            call()


def test_pair_flow_that_is_not_a_pair_is_named(tiny):
    engine = FusionEngine(tiny.intrinsics)
    engine.push(tiny.depth[0], tiny.intensity[0])
    flow = np.zeros((*tiny.depth.shape[1:], 2), np.float32)
    with pytest.raises(ParameterTypeError, match=r"^pair_flow must be a \(forward, backward\)"):
        engine.push(tiny.depth[1], tiny.intensity[1], pair_flow=flow)
    engine.push(tiny.depth[1], tiny.intensity[1], pair_flow=(flow, flow))
    assert [f.index for f in engine.flush()] == [0, 1]  # the refused push left no frame


def test_engine_refuses_an_unknown_flow_method_when_made():
    """FusionEngine(k, flow="nope") was made, and failed at the second frame's flow."""
    k = Intrinsics(fx=50.0, fy=50.0, cx=8.0, cy=6.0, width=16, height=12)
    with pytest.raises(ParameterError, match="unknown flow method 'nope'"):
        FusionEngine(k, flow="nope")
    with pytest.raises(ParameterError, match="bogus"):
        FusionEngine(k, flow=FlowConfig("dis", params={"bogus": 1}))


def test_no_intensity_says_why_it_is_needed(tiny):
    """intensity=None gave "intensity must have shape (T, H, W), got (). convert colour to
    gray"."""
    d, k = tiny.depth, tiny.intrinsics
    for call in (
        lambda: Sequence(d, None, k),
        lambda: fuse_sequence(d, None, k),
        lambda: FusionEngine(k).push(d[0], None),
    ):
        with pytest.raises(ParameterTypeError, match=r"^intensity is required: fuse4d tracks"):
            call()


def test_dark_or_black_intensity_is_warned_about_once(tiny):
    """16-bit IR stored raw (0-3000 of 65535) reached the flow as ~12 gray levels and was
    tracked silently badly; an all-0 IR (a test recording's) gave nothing to track."""
    raw_ir = np.round(3000 * tiny.intensity).astype(np.uint16)
    n = tiny.depth.shape[0]
    with pytest.warns(
        UserWarning, match=rf"^intensity \(frames 0-{n - 1}\) is dark: 99\.5 %"
    ) as rec:
        fuse_sequence(tiny.depth, raw_ir, tiny.intrinsics, flow="dis")
    assert len([w for w in rec if "is dark" in str(w.message)]) == 1
    with pytest.warns(UserWarning, match=rf"^intensity \(frames 0-{n - 1}\) is black"):
        fuse_sequence(tiny.depth, np.zeros_like(tiny.intensity), tiny.intrinsics, flow="dis")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fuse_sequence(tiny.depth, tiny.intensity, tiny.intrinsics, flow="dis")


def test_dark_first_frames_of_a_camera_settling_are_not_warned_about(tiny):
    """A camera's auto-exposure may still be settling in the first frames: only a stream
    whose first DARK_CHECK_FRAMES frames are all dark is warned about."""
    from fuse4d.fusion import DARK_CHECK_FRAMES

    engine = FusionEngine(tiny.intrinsics, fusion=FusionParams(num_frames=1))
    frames = DARK_CHECK_FRAMES + 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for t in range(frames):
            scale = 0.01 if t < DARK_CHECK_FRAMES - 1 else 1.0  # bright from the 8th frame on
            engine.push(tiny.depth[t % len(tiny.depth)], scale * tiny.intensity[0])
        engine.flush()
    engine = FusionEngine(tiny.intrinsics, fusion=FusionParams(num_frames=1))
    for t in range(DARK_CHECK_FRAMES - 1):
        engine.push(tiny.depth[t % len(tiny.depth)], 0.01 * tiny.intensity[0])
    with pytest.warns(UserWarning, match=rf"^intensity \(frames 0-{DARK_CHECK_FRAMES - 1}\)"):
        engine.push(tiny.depth[0], 0.01 * tiny.intensity[0])  # the 8th dark frame


def test_toml_preset_given_by_the_caller_wins_over_the_files(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('preset = "paper"\n[fusion]\nnum_frames = 5\n', encoding="utf-8")
    assert load_config(path, base="fast").flow.method == "pmbp"  # the file's, over a default
    chosen = load_config(path, base="fast", override_preset=True)  # an explicit --preset
    assert (chosen.name, chosen.flow.method, chosen.fusion.num_frames) == ("fast", "dis", 5)
    with pytest.raises(ParameterError, match="unknown preset 'nope'") as info:
        load_config(path, base="nope", override_preset=True)
    assert not isinstance(info.value, InputFileError)  # the caller's, not the file's


@pytest.mark.parametrize(
    ("flow", "says"),
    [
        ("params = 5", r"\[flow\] params must be a table \(\[flow.params\]"),  # was "'int' ..."
        ("roi = [0.5, 100, 0, 100]", r"four whole numbers of px, got \(0.5, 100, 0, 100\)"),
        ("roi = [1, 2]", r"roi must be \(row0, row1, col0, col1\)"),
        ("roi = [10, 5, 0, 100]", r"roi \(10, 5, 0, 100\) must satisfy 0 <= row0 < row1, "),
    ],
)
def test_toml_flow_errors_name_the_file(tmp_path, flow, says):
    """A fractional ROI was truncated (0.5 -> 0), a bad one failed when the frames were read
    without naming the file, `params = 5` was "'int' object is not iterable"."""
    path = tmp_path / "c.toml"
    path.write_text(f"[flow]\n{flow}\n", encoding="utf-8")
    with pytest.raises(InputFileError, match=r"c\.toml: .*" + says):
        load_config(path)


def test_flow_roi_values_must_be_whole_pixels():
    from fuse4d.flow._checks import check_roi

    assert check_roi((0, 100.0, np.int64(2), "40"), (150, 150)) == (0, 100, 2, 40)
    for bad in ((0.5, 100, 0, 100), (0, math.inf, 0, 10), (0, math.nan, 0, 10), (True, 9, 0, 9)):
        with pytest.raises(ParameterError, match="four whole numbers of px"):
            check_roi(bad, (150, 150))
    with pytest.raises(ParameterError, match=r"<= 150, 0 <= col0 < col1 <= 150"):
        check_roi((0, 200, 0, 10), (150, 150))


def test_fusion_params_round_trip_through_to_dict():
    """`to_dict` writes inf as "inf" (JSON has no inf): FusionParams(**d) refused it."""
    from fuse4d.config import LITERAL_PAPER

    for params in (FusionParams(**LITERAL_PAPER), FusionParams(sigma_temporal=math.inf)):
        assert FusionParams.from_dict(params.to_dict()) == params
    assert FusionParams.from_dict({"num_frames": "5"}) == FusionParams(num_frames=5)
    with pytest.raises(ParameterError, match="unknown parameter"):
        FusionParams.from_dict({"radius": 3})


def test_min_temporal_support_above_the_windows_other_frames_is_refused(tiny, tmp_path, capsys):
    """``--window 3 --set min_temporal_support=9`` was accepted and turned temporal fusion off
    ('temporal support 0.0 %'): a pixel has at most num_frames - 1 other frames."""
    with pytest.raises(ParameterError, match=r"min_temporal_support=9 with num_frames=3"):
        FusionParams(num_frames=3, min_temporal_support=9)
    with pytest.raises(ParameterError, match=r"min_temporal_support=3 with num_frames=3"):
        FusionParams(min_temporal_support=3).replace(num_frames=3)
    assert FusionParams(num_frames=3, min_temporal_support=2).min_temporal_support == 2
    assert FusionParams(num_frames=1).min_temporal_support == 1  # one frame: no other anyway
    src = save_sequence(tiny, tmp_path / "in.npz")
    args = ["run", str(src), "-o", str(tmp_path / "out.npz"), "--window", "3"]
    assert main([*args, "--set", "min_temporal_support=5"]) == 2
    err = capsys.readouterr().err
    assert "min_temporal_support=5 with num_frames=3" in err
    assert "internal error" not in err
