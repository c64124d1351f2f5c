"""Tests of the optical-flow stage: registry, OpenCV wrappers, pair/sequence driver, cache, ROI,
colour wheel, and the ``flow`` / ``bench-flow`` CLI commands."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import cv2
import numpy as np
import pytest

from fuse4d.cli import main
from fuse4d.errors import ParameterError, ShapeError
from fuse4d.flow import (
    DeepFlowParams,
    DISParams,
    FarnebackParams,
    FlowCache,
    FlowMethod,
    SequenceFlowEstimator,
    TVL1Params,
    available_flow_methods,
    estimate_flow,
    estimate_flow_pair,
    estimate_sequence_flow,
    flow_params_from_mapping,
    read_flo,
    register_flow_method,
    resolve_flow_params,
    warp_image,
)
from fuse4d.flow import _registry as flow_mod
from fuse4d.flow.vis import flow_to_color, make_color_wheel

OPENCV_METHODS = ("dis", "farneback", "tvl1", "deepflow")
BORDER = 12  # px excluded from "interior" checks (OpenCV methods are unreliable at the border)


def texture(shape=(96, 112), *, seed=0, sigma=2.0) -> np.ndarray:
    """Smooth random texture, float32 in [0, 1] (full range)."""
    rng = np.random.default_rng(seed)
    image = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), sigma)
    return ((image - image.min()) / (image.max() - image.min())).astype(np.float32)


def shifted(image: np.ndarray, du: float, dv: float) -> np.ndarray:
    """``image`` moved by (du, dv) px: result(x) = image(x - (du, dv)); flow image→result = (du, dv)."""
    h, w = image.shape
    m = np.float32([[1, 0, du], [0, 1, dv]])
    return cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def interior(flow: np.ndarray) -> np.ndarray:
    return flow[BORDER:-BORDER, BORDER:-BORDER]


def epe(flow: np.ndarray, du: float, dv: float) -> float:
    return float(np.hypot(flow[..., 0] - du, flow[..., 1] - dv).mean())


@pytest.fixture
def recorder(monkeypatch):
    """A registered fake method that records its calls and returns a constant (du, dv) field."""
    calls = []

    def fake(image0, image1, params, init):
        calls.append({"shape": image0.shape, "init": None if init is None else init.copy()})
        out = np.empty((*image0.shape, 2), np.float32)
        out[..., 0] = params.du + float(image1.mean() - image0.mean())
        out[..., 1] = params.dv
        return out

    from dataclasses import dataclass

    @dataclass(frozen=True)
    class FakeParams:
        du: float = 1.5
        dv: float = -0.5

    method = FlowMethod("recorder", fake, FakeParams, "test double", True, False)
    monkeypatch.setitem(flow_mod._REGISTRY, "recorder", method)
    return calls


# ---------------------------------------------------------------------------------------------
# registry and parameters
# ---------------------------------------------------------------------------------------------


def test_registry_lists_opencv_methods():
    methods = available_flow_methods()
    for name in OPENCV_METHODS:
        assert name in methods
        assert not methods[name].paper_method
    assert methods["deepflow"].supports_init is False
    assert methods["dis"].params_type is DISParams


def test_unknown_method_lists_available():
    with pytest.raises(ValueError, match=r"unknown flow method 'nope'; available methods: .*dis"):
        estimate_flow(texture(), texture(), method="nope")


def test_register_conflict_and_replace(monkeypatch):
    monkeypatch.setattr(flow_mod, "_REGISTRY", dict(flow_mod._REGISTRY))
    other = replace(available_flow_methods()["dis"], description="other")
    with pytest.raises(ValueError, match="already registered"):
        register_flow_method(other)
    register_flow_method(other, replace=True)
    assert available_flow_methods()["dis"].description == "other"
    register_flow_method(other)  # the same object again: no-op


def test_flow_method_validates_name():
    with pytest.raises(ValueError, match="lower-case"):
        FlowMethod("My Method", estimate_flow, DISParams, "", True, False)


def test_dis_presets_match_opencv():
    presets = {
        "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
        "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
        "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
    }
    for name, code in presets.items():
        ours = DISParams.from_preset(name)
        dis = cv2.DISOpticalFlow.create(code)
        assert ours.finest_scale == dis.getFinestScale()
        assert ours.patch_size == dis.getPatchSize()
        assert ours.patch_stride == dis.getPatchStride()
        assert ours.gradient_descent_iterations == dis.getGradientDescentIterations()
        assert ours.variational_refinement_iterations == dis.getVariationalRefinementIterations()
        assert ours.variational_refinement_alpha == pytest.approx(
            dis.getVariationalRefinementAlpha()
        )
        assert ours.use_spatial_propagation == dis.getUseSpatialPropagation()
    assert DISParams() == DISParams.from_preset("fast")


@pytest.mark.parametrize(
    ("factory", "message"),
    [
        (lambda: DISParams(patch_size=0), "patch_size"),
        (lambda: DISParams(patch_stride=9), "patch_stride"),
        (lambda: DISParams.from_preset("slow"), "unknown DIS preset"),
        (lambda: FarnebackParams(pyr_scale=1.5), "pyr_scale"),
        (lambda: FarnebackParams(levels=0), "levels"),
        (lambda: TVL1Params(median_filtering=4), "median_filtering"),
        (lambda: TVL1Params(data_weight=-1.0), "data_weight"),
    ],
)
def test_params_validation(factory, message):
    with pytest.raises(ValueError, match=message):
        factory()


def test_params_bool_type_checked():
    with pytest.raises(TypeError, match="use_mean_normalization must be True or False"):
        DISParams(use_mean_normalization=1)


def test_params_from_mapping_coerces_strings():
    p = flow_params_from_mapping(
        "dis", {"preset": "fast", "patch_size": "12", "use_mean_normalization": "false"}
    )
    assert p == DISParams.from_preset("fast", patch_size=12, use_mean_normalization=False)
    assert flow_params_from_mapping("tvl1", {"data_weight": 1}).data_weight == 1.0
    with pytest.raises(ValueError, match="parameter levels: cannot read 'x' as an integer"):
        flow_params_from_mapping("farneback", {"levels": "x"})
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) bogus .*valid: pyr_scale"):
        flow_params_from_mapping("farneback", {"bogus": 1})
    with pytest.raises(ValueError, match="has no presets"):
        flow_params_from_mapping("farneback", {"preset": "fast"})


def test_resolve_params_types():
    assert resolve_flow_params("farneback") == FarnebackParams()
    assert resolve_flow_params("dis", {"patch_stride": 2}).patch_stride == 2
    with pytest.raises(TypeError, match="must be a DISParams"):
        resolve_flow_params("dis", FarnebackParams())


def test_default_flow_and_dis_by_name_are_one_setting():
    """flow=None, flow="dis", FlowConfig("dis") and preset("fast") track with the same DIS."""
    from fuse4d import FlowConfig, FusionEngine, Intrinsics, preset

    k = Intrinsics(100.0, 100.0, 16.0, 16.0, 32, 32)
    built = {
        FusionEngine(k).flow_config.build_params(),
        FusionEngine(k, flow="dis").flow_config.build_params(),
        FlowConfig("dis").build_params(),
        preset("fast").flow.build_params(),
        resolve_flow_params("dis"),
    }
    assert built == {DISParams.from_preset("fast")}
    assert preset("paper").flow.method == "pmbp"
    assert DISParams.from_preset("medium") != DISParams()


def test_optional_numeric_fields_from_strings():
    """--flow-param strings reach ``int | None`` / ``float | None`` fields typed (bug b1)."""
    p = flow_params_from_mapping("pmbp", {"coarse_num_iter": "3", "search_radius0": "4.5"})
    assert p.coarse_num_iter == 3
    assert p.search_radius0 == 4.5
    assert flow_params_from_mapping("pmbp", {"coarse_num_iter": "none"}).coarse_num_iter is None
    with pytest.raises(ValueError, match="coarse_num_iter"):
        flow_params_from_mapping("pmbp", {"coarse_num_iter": "three"})


# ---------------------------------------------------------------------------------------------
# OpenCV methods on known motion
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", OPENCV_METHODS)
def test_zero_motion_gives_zero_flow(method):
    image = texture()
    flow = estimate_flow(image, image, method=method)
    assert flow.dtype == np.float32
    assert flow.shape == (*image.shape, 2)
    assert np.abs(interior(flow)).max() < 0.02


@pytest.mark.parametrize(
    ("method", "params", "tolerance"),
    [
        ("dis", DISParams.from_preset("medium"), 0.1),
        ("deepflow", None, 0.1),
        ("tvl1", None, 0.1),
        ("farneback", None, 0.15),
    ],
)
def test_subpixel_translation_recovered(method, params, tolerance):
    image = texture((120, 140))
    du, dv = 1.3, -0.6
    flow = estimate_flow(image, shifted(image, du, dv), method=method, params=params)
    assert epe(interior(flow), du, dv) < tolerance


def test_sign_convention_pure_horizontal_shift():
    """Content moving right by 2 px: du = +2 (column), dv = 0; backward = -2."""
    image = texture()
    moved = np.roll(image, 2, axis=1)  # moved[v, u] = image[v, u - 2]
    forward, backward = estimate_flow_pair(image, moved, method="dis")
    f, b = interior(forward), interior(backward)
    assert np.median(f[..., 0]) == pytest.approx(2.0, abs=0.05)
    assert np.abs(np.median(f[..., 1])) < 0.05
    assert np.median(b[..., 0]) == pytest.approx(-2.0, abs=0.05)
    # backward warping of frame t+1 with the forward flow reproduces frame t
    warped = warp_image(moved, forward)
    assert np.abs(interior(warped) - interior(image)).mean() < 0.01


def test_vertical_shift_is_dv():
    image = texture()
    moved = np.roll(image, 3, axis=0)  # rows: content moves down
    flow = estimate_flow(image, moved, method="dis", params={"preset": "medium"})
    assert np.median(interior(flow)[..., 1]) == pytest.approx(3.0, abs=0.05)
    assert np.abs(np.median(interior(flow)[..., 0])) < 0.05


@pytest.mark.parametrize(
    ("method", "params"),
    [("dis", None), ("farneback", FarnebackParams(levels=1)), ("tvl1", TVL1Params(num_scales=1))],
)
def test_init_is_used(method, params):
    """A 20 px motion is out of reach cold, but found from a correct initial flow."""
    image = texture((120, 140), sigma=1.5)
    du, dv = 20.4, 0.0
    moved = shifted(image, du, dv)
    init = np.zeros((*image.shape, 2), np.float32)
    init[..., 0] = du
    cold = estimate_flow(image, moved, method=method, params=params)
    warm = estimate_flow(image, moved, method=method, params=params, init=init)
    assert epe(interior(cold), du, dv) > 5.0
    assert epe(interior(warm), du, dv) < 0.2


def test_dis_does_not_keep_a_stale_init():
    image = texture()
    moved = shifted(image, 1.0, 0.5)
    cold = estimate_flow(image, moved, method="dis")
    estimate_flow(image, moved, method="dis", init=np.full((*image.shape, 2), 5, np.float32))
    again = estimate_flow(image, moved, method="dis")
    np.testing.assert_array_equal(cold, again)


@pytest.mark.parametrize("shape", [(3, 3), (8, 11), (5, 40), (12, 40), (16, 128), (31, 640)])
def test_dis_on_images_it_cannot_take(shape):
    """OpenCV's DIS raises on images under 12 px and crashes the process on short, wide ones
    (12 x 40 px at its fast preset); fuse4d pads them (a small --roi crop is a valid input):
    the flow has the image's shape, cold and warm-started (the start is padded alike)."""
    image = texture(shape, sigma=1.0)
    moved = np.roll(image, 1, axis=1)
    init = np.ones((*shape, 2), np.float32)
    for start in (None, init):
        flow = estimate_flow(image, moved, method="dis", init=start)
        assert flow.shape == (*shape, 2)
        assert np.isfinite(flow).all()


def test_dis_runs_on_every_small_shape():
    """No shape up to 64 px crashes the process (run in a child process: a crash there is a
    failed test here), with each preset and the finest scales / patch sizes around them; the
    presets run on every shape, other settings where OpenCV would keep their patch size."""
    script = """
import numpy as np
from fuse4d.errors import ParameterError
from fuse4d.flow.opencv import DISParams, dis_flow
presets = [DISParams.from_preset(p) for p in ("ultrafast", "fast", "medium")]
settings = presets + [DISParams(finest_scale=f, patch_size=s, patch_stride=s // 2)
                      for f in (0, 3, 4) for s in (8, 12)]
sizes = (2, 5, 8, 11, 12, 15, 16, 23, 24, 31, 32, 47, 64)
for p in settings:
    for h in sizes:
        for w in sizes + (100, 300, 640):
            for a, b in ((h, w), (w, h)):
                img = np.random.default_rng(a * 1000 + b).random((a, b), dtype=np.float32)
                try:
                    assert dis_flow(img, img, p, None).shape == (a, b, 2)
                except ParameterError:
                    assert p not in presets and p.finest_scale in (3, 4) and p.patch_size == 8
print("ok")
"""
    done = subprocess.run(
        [sys.executable, "-c", script], check=False, capture_output=True, text=True
    )
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    assert done.stdout.strip() == "ok"


def test_init_ignored_for_deepflow():
    image = texture()
    init = np.full((*image.shape, 2), 3.0, np.float32)
    a = estimate_flow(image, image, method="deepflow", init=init)
    b = estimate_flow(image, image, method="deepflow")
    np.testing.assert_array_equal(a, b)


# ---------------------------------------------------------------------------------------------
# input validation
# ---------------------------------------------------------------------------------------------


def test_bad_inputs_have_clear_errors():
    image = texture()
    with pytest.raises(ShapeError, match="image1 must have shape"):
        estimate_flow(image, image[:-1])
    with pytest.raises(ShapeError, match="image0 must have shape"):
        estimate_flow(np.stack([image, image]), image)
    bad = image.copy()
    bad[3, 4] = np.nan
    with pytest.raises(ParameterError, match=r"^image1 has 1 NaN or inf pixel\(s\)"):
        estimate_flow(image, bad)
    with pytest.raises(ShapeError, match="init must have shape"):
        estimate_flow(image, image, init=np.zeros((4, 4, 2)))
    with pytest.raises(ValueError, match="roi"):
        estimate_flow(image, image, roi=(10, 5, 0, 20))
    with pytest.raises(ValueError, match="at least 2 frames"):
        estimate_sequence_flow(image[None])


def test_flow_takes_integer_images_as_the_engine_does_and_refuses_0_255_floats():
    """A uint8 frame (``cv2.imread``) was taken as 0-255 and saturated to white: the flow of
    a 1.5 px shift came out near zero. Now integers are divided by their dtype maximum."""
    image = texture()
    shifted = np.roll(image, 1, axis=1)
    as_float = estimate_flow(image, shifted, method="dis")
    as_uint8 = estimate_flow(*(np.round(255 * im).astype(np.uint8) for im in (image, shifted)))
    inner = (slice(8, -8), slice(8, -8))
    assert abs(float(np.median(as_uint8[inner][..., 0])) - 1.0) < 0.3  # (was ~0)
    assert np.abs(as_uint8 - as_float)[inner].mean() < 0.05
    with pytest.raises(ParameterError, match=r"^image0 is float with values in \[0, 2\d\d"):
        estimate_flow(255 * image, 255 * shifted)
    estimate_flow(image * 1.01 - 0.005, shifted)  # a resampling's slight overshoot is kept
    video = np.stack([image, shifted])
    as_video = estimate_sequence_flow(np.round(255 * video).astype(np.uint8), method="dis")
    np.testing.assert_allclose(as_video.forward[0], as_uint8, atol=1e-6)
    with pytest.raises(ParameterError, match=r"^frame pair \(0, 1\): image0 is float"):
        estimate_sequence_flow(255 * video)


def test_method_returning_wrong_shape_is_reported(monkeypatch):
    broken = FlowMethod(
        "broken", lambda a, b, p, i: np.zeros((2, 2, 2)), DeepFlowParams, "", False, False
    )
    monkeypatch.setitem(flow_mod._REGISTRY, "broken", broken)
    with pytest.raises(RuntimeError, match="'broken' returned shape"):
        estimate_flow(texture(), texture(), method="broken")


# ---------------------------------------------------------------------------------------------
# pairs, sequences, warm starts, ROI, cache
# ---------------------------------------------------------------------------------------------


def test_sequence_shapes_warm_starts_and_single_solve(recorder):
    video = np.stack([texture(seed=s) for s in range(4)])
    result = estimate_sequence_flow(video, method="recorder")
    assert result.forward.shape == (3, *video.shape[1:], 2)
    assert result.backward.shape == (3, *video.shape[1:], 2)
    assert result.method == "recorder"
    assert result.paper_method is False
    assert result.num_pairs == 3
    assert len(recorder) == 6  # each pair solved once per direction
    forward_calls, backward_calls = recorder[0::2], recorder[1::2]
    assert forward_calls[0]["init"] is None
    for t in range(3):
        # backward of pair t starts from -forward[t]
        np.testing.assert_array_equal(backward_calls[t]["init"], -result.forward[t])
        if t:
            # forward of pair t starts from forward[t-1]
            np.testing.assert_array_equal(forward_calls[t]["init"], result.forward[t - 1])


def test_sequence_without_warm_start(recorder):
    video = np.stack([texture(seed=s) for s in range(3)])
    estimate_sequence_flow(video, method="recorder", warm_start=False)
    assert recorder[0]["init"] is None
    assert recorder[2]["init"] is None
    assert recorder[1]["init"] is not None  # backward always starts from -forward


def test_sequence_flow_matches_pairwise_directions():
    image = texture((80, 96))
    video = np.stack([image, np.roll(image, 1, axis=1), np.roll(image, 2, axis=1)])
    calls = []
    result = estimate_sequence_flow(
        video,
        method="dis",
        params={"preset": "medium"},
        progress=lambda d, t: calls.append((d, t)),
    )
    assert calls == [(1, 2), (2, 2)]
    for t in range(2):
        assert np.median(interior(result.forward[t])[..., 0]) == pytest.approx(1.0, abs=0.05)
        assert np.median(interior(result.backward[t])[..., 0]) == pytest.approx(-1.0, abs=0.05)


def test_estimator_checks_continuity(recorder):
    a, b, c = (texture(seed=s) for s in range(3))
    estimator = SequenceFlowEstimator(method="recorder")
    estimator(a, b)
    estimator(b, c)
    assert estimator.warm_starts == 1
    estimator(a, c)  # not a continuation of (b, c): cold start
    assert estimator.warm_starts == 1
    assert recorder[4]["init"] is None
    estimator.reset()
    estimator(c, a)
    assert recorder[6]["init"] is None


def test_roi_solves_only_inside(recorder):
    image = texture((60, 70))
    roi = (10, 40, 5, 50)
    forward, backward = estimate_flow_pair(image, image, method="recorder", roi=roi)
    assert recorder[0]["shape"] == (30, 45)
    inside = np.zeros(image.shape, bool)
    inside[10:40, 5:50] = True
    assert np.all(forward[~inside] == 0)
    assert np.all(backward[~inside] == 0)
    np.testing.assert_allclose(forward[inside], np.broadcast_to([1.5, -0.5], (1350, 2)))


def test_roi_with_opencv():
    image = texture((100, 120))
    moved = np.roll(image, 2, axis=1)
    flow = estimate_flow(image, moved, method="dis", roi=(20, 80, 20, 100))
    assert np.all(flow[:20] == 0)
    assert np.median(flow[35:65, 35:85, 0]) == pytest.approx(2.0, abs=0.05)


def test_cache_hits_and_misses(tmp_path, recorder):
    cache = FlowCache(tmp_path / "flows")
    a, b = texture(seed=1), texture(seed=2)
    first = estimate_flow_pair(a, b, method="recorder", cache=cache)
    assert (cache.hits, cache.misses, len(recorder)) == (0, 1, 2)
    second = estimate_flow_pair(a, b, method="recorder", cache=cache)
    assert (cache.hits, cache.misses, len(recorder)) == (1, 1, 2)  # nothing recomputed
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1], second[1])
    params = flow_mod._REGISTRY["recorder"].params_type(du=2.0)
    third = estimate_flow_pair(a, b, method="recorder", params=params, cache=cache)
    assert (cache.hits, cache.misses) == (1, 2)
    assert not np.array_equal(third[0], first[0])
    estimate_flow_pair(a, b, method="recorder", roi=(0, 50, 0, 50), cache=cache)
    estimate_flow_pair(b, a, method="recorder", cache=cache)
    assert (cache.hits, cache.misses) == (1, 4)
    assert len(list((tmp_path / "flows").glob("??/*.npy"))) == 4
    assert not list((tmp_path / "flows").glob("??/.tmp-*"))


def test_cache_sequence_roundtrip(tmp_path):
    video = np.stack([np.roll(texture((64, 80)), k, axis=1) for k in range(3)])
    cache = FlowCache(tmp_path)
    cold = estimate_sequence_flow(video, method="dis", cache=cache)
    warm = estimate_sequence_flow(video, method="dis", cache=cache)
    assert cache.hits == 2
    np.testing.assert_array_equal(cold.forward, warm.forward)
    np.testing.assert_array_equal(cold.backward, warm.backward)


def test_cache_corrupt_entry_is_a_miss(tmp_path):
    cache = FlowCache(tmp_path)
    key = "ab" + "0" * 62
    cache.store(key, np.ones((2, 3, 4, 2), np.float32))
    cache.path(key).write_bytes(b"garbage")
    assert cache.load(key) is None
    assert cache.misses == 1
    assert cache.clear() == 1
    with pytest.raises(ValueError, match="hex"):
        cache.path("../etc")


# ---------------------------------------------------------------------------------------------
# helpers: warp and colour wheel
# ---------------------------------------------------------------------------------------------


def test_warp_image_integer_shift_and_nan_border():
    image = texture((20, 30))
    flow = np.zeros((20, 30, 2), np.float32)
    flow[..., 0] = 2.0
    warped = warp_image(image, flow, border="nan")
    np.testing.assert_allclose(warped[:, :-2], image[:, 2:], atol=1e-6)
    assert np.isnan(warped[:, -1]).all()
    with pytest.raises(ShapeError, match="flow must have shape"):
        warp_image(image, flow[:, :-1])


def test_color_wheel_known_colours():
    wheel = make_color_wheel()
    assert wheel.shape == (55, 3)
    assert wheel[0].tolist() == [255, 0, 0]
    assert wheel[15].tolist() == [255, 255, 0]  # yellow starts the YG segment
    assert wheel[21].tolist() == [0, 255, 0]  # green starts GC
    flow = np.array([[[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1], [2, 0], [1e10, 0]]], np.float32)
    rgb = flow_to_color(flow, max_magnitude=1.0)[0].astype(int)
    assert rgb[0].tolist() == [255, 255, 255]  # no motion: white
    assert rgb[1].tolist() == [255, 0, 0]  # right: red
    assert rgb[2].tolist() == [0, 209, 255]  # left: cyan-blue
    np.testing.assert_allclose(rgb[3], [255, 229, 0], atol=1)  # down: orange-yellow
    np.testing.assert_allclose(rgb[4], [88, 0, 255], atol=1)  # up: blue-violet
    assert rgb[5].tolist() == [191, 0, 0]  # beyond max: darkened to 75 %
    assert rgb[6].tolist() == [0, 0, 0]  # unknown: black
    half = flow_to_color(np.array([[[0.5, 0]]], np.float32), max_magnitude=1.0)[0, 0]
    assert half.tolist() == [255, 127, 127]  # half saturation


def test_color_default_scale_and_errors():
    flow = np.zeros((2, 2, 2), np.float32)
    flow[0, 0] = (4.0, 0.0)
    assert flow_to_color(flow)[0, 0].tolist() == [255, 0, 0]
    assert flow_to_color(np.zeros((2, 2, 2), np.float32)).min() == 255
    with pytest.raises(ValueError, match="max_magnitude"):
        flow_to_color(flow, max_magnitude=0.0)


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------


@pytest.fixture
def png_pair(tmp_path):
    image = (texture((90, 110)) * 255).round().astype(np.uint8)
    moved = np.roll(image, 2, axis=1)
    p0, p1 = tmp_path / "a.png", tmp_path / "b.png"
    cv2.imwrite(str(p0), image)
    cv2.imwrite(str(p1), cv2.cvtColor(moved, cv2.COLOR_GRAY2BGR))  # colour → gray
    return p0, p1


def test_cli_flow_writes_flo_and_vis(png_pair, tmp_path, capsys):
    out, vis = tmp_path / "f.flo", tmp_path / "f.png"
    code = main(["flow", str(png_pair[0]), str(png_pair[1]), "-o", str(out), "--vis", str(vis)])
    assert code == 0
    assert "not the paper's tracker" in capsys.readouterr().err
    flow = read_flo(out)
    assert flow.shape == (90, 110, 2)
    assert np.median(interior(flow)[..., 0]) == pytest.approx(2.0, abs=0.05)
    picture = cv2.imread(str(vis))
    assert picture.shape == (90, 110, 3)


def test_cli_flow_refuses_to_overwrite(png_pair, tmp_path, capsys):
    out = tmp_path / "f.flo"
    out.write_bytes(b"x")
    args = ["flow", str(png_pair[0]), str(png_pair[1]), "-o", str(out)]
    assert main(args) == 2
    assert "pass --force" in capsys.readouterr().err
    assert main([*args, "--force", "-m", "farneback", "-p", "levels=3"]) == 0
    assert read_flo(out).shape == (90, 110, 2)


def test_cli_flow_checks_max_magnitude_before_the_solve(png_pair, tmp_path, capsys):
    """--max-magnitude 0 was refused by the PNG writer after the .flo was written (the rerun
    then said "output exists"); without --vis any value was ignored."""
    out, vis = tmp_path / "x.flo", tmp_path / "x.png"
    args = ["flow", str(png_pair[0]), str(png_pair[1]), "-o", str(out)]
    assert main([*args, "--vis", str(vis), "--max-magnitude", "0"]) == 2
    assert "--max-magnitude must be a number of pixels > 0, got 0" in capsys.readouterr().err
    assert main([*args, "--max-magnitude", "5"]) == 2
    assert "give --vis too" in capsys.readouterr().err
    assert not out.exists()
    assert not vis.exists()


def test_cli_bench_flow_refuses_no_method_and_a_missing_data_folder(tmp_path, capsys):
    assert main(["bench-flow", "--methods", "", "--no-middlebury", "--small"]) == 2
    assert "names no flow method" in capsys.readouterr().err
    missing = tmp_path / "nope"
    assert main(["bench-flow", "--data", str(missing), "--small", "--methods", "dis"]) == 2
    assert f"--data {missing}: folder not found" in capsys.readouterr().err


def test_cli_flow_unknown_method(png_pair, tmp_path, capsys):
    args = ["flow", str(png_pair[0]), str(png_pair[1]), "-o", str(tmp_path / "f.flo")]
    assert main([*args, "--method", "hornschunck"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fuse4d: error: unknown flow method 'hornschunck'")
    for name in ("deepflow", "dis", "farneback", "tvl1"):
        assert name in err
    assert not (tmp_path / "f.flo").exists()


def test_cli_flow_size_mismatch(png_pair, tmp_path, capsys):
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((10, 10), np.uint8))
    code = main(["flow", str(png_pair[0]), str(small), "-o", str(tmp_path / "f.flo")])
    assert code == 2
    assert "differs from" in capsys.readouterr().err


def test_cli_bench_flow_small_ball_json(capsys):
    code = main(
        ["bench-flow", "--small", "--no-middlebury", "--methods", "dis-medium,farneback", "--json"]
    )
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    labels = {r["label"] for r in report["summary"]}
    assert labels == {"dis-medium", "farneback"}
    datasets = {r["dataset"] for r in report["summary"]}
    assert datasets == {"ball 2%", "ball 10%"}
    dis = next(r for r in report["summary"] if r["label"] == "dis-medium" and "2%" in r["dataset"])
    assert dis["epe_px"] < 0.12  # vs the exact ball motion (0, 0.5 Z_c / Z) px
    assert len(report["pairs"]) == 8


def test_cli_bench_flow_unknown_method(capsys):
    assert main(["bench-flow", "--methods", "nope", "--no-middlebury", "--small"]) == 2
    assert "unknown flow method(s) nope" in capsys.readouterr().err


@pytest.mark.realdata
def test_cli_bench_flow_middlebury_table(shared_data, capsys):
    code = main(
        ["bench-flow", "--data", str(shared_data), "--no-ball", "--methods", "dis-ultrafast"]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "middlebury" in out
    assert "dis-ultrafast" in out


@pytest.mark.realdata
def test_middlebury_pairs_mask_unknown(shared_data):
    from fuse4d.experiments.flow_accuracy import middlebury_pairs

    pairs, reason = middlebury_pairs(shared_data / "middlebury_flow")
    assert reason == ""
    assert [p.name for p in pairs] == ["Dimetrodon", "Hydrangea", "RubberWhale", "Venus"]
    venus = pairs[-1]
    assert venus.image0.shape == (380, 420)
    assert venus.mask.all()  # Venus has no unknown GT
    assert 0.9 < pairs[0].mask.mean() < 0.99  # Dimetrodon: 4.8 % unknown
    assert np.abs(pairs[0].flow_true).max() < 10


def test_to_uint8_kernel_gives_the_numpy_expressions_bytes():
    """The flow methods' 8-bit input (one numba pass since stop 48) equals
    ``clip(image * 255 + 0.5, 0, 255)`` in float32, truncated: every level's centre and both
    rounding edges, the ends of [0, 1] and beyond, random values, a non-contiguous view."""
    from fuse4d.flow._checks import to_uint8

    levels = np.arange(256, dtype=np.float32)
    edges = np.concatenate([levels / 255, (levels + 0.5) / 255, (levels - 0.5) / 255])
    values = np.concatenate(
        [edges, np.nextafter(edges, np.float32(2)), np.nextafter(edges, np.float32(-1))]
    )
    values = np.concatenate([values, [-0.3, 0.0, 1.0, 1.2, 1e6, -1e6]]).astype(np.float32)
    rng = np.random.default_rng(3)
    image = np.concatenate([values, rng.random(2 * 96 * 96 - values.size, np.float32)])
    image = image.reshape(96, 192)
    for a in (image, image[:, ::2]):
        expected = np.empty(a.shape, np.uint8)
        np.clip(a * np.float32(255) + np.float32(0.5), 0, 255, out=expected, casting="unsafe")
        np.testing.assert_array_equal(to_uint8(a), expected)


def test_cli_flow_one_pixel_high_image_names_the_file(tmp_path, capsys):
    line = tmp_path / "line.png"
    cv2.imwrite(str(line), np.full((1, 50), 100, np.uint8))
    assert main(["flow", str(line), str(line), "-o", str(tmp_path / "f.flo")]) == 2
    assert f"{line}: 50x1 px; flow needs at least 2 px" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("method", "param", "value"),
    [
        ("dis", "patch_size", 100000),
        ("farneback", "poly_n", 100000),
        ("pmbp", "presmooth_sigma", 1e9),
    ],
)
def test_flow_parameters_far_past_any_use_are_refused(method, param, value):
    """Each passed validation and then was killed for memory (DIS) or hung (Farneback's
    polynomial expansion, PMBP's Gaussian pre-smoothing)."""
    from fuse4d.errors import ParameterError
    from fuse4d.flow import flow_params_from_mapping

    with pytest.raises(ParameterError, match=param):
        flow_params_from_mapping(method, {param: value})


# ---------------------------------------------------------------------------------------------
# DIS settings OpenCV would replace, NaN flows, parameter bounds, CLI outputs, bench-flow data
# ---------------------------------------------------------------------------------------------


def test_dis_never_hands_opencv_a_stride_above_the_patch_it_would_use():
    """On an image too small for finest_scale OpenCV takes patch size 8 (or 12) but kept the
    stride: patch_size=24 patch_stride=12 on 140 x 100 px aborted the process, 100/100 freed
    memory twice. Run in a child process (a crash there is a failed test here): every such
    setting is refused with a ParameterError that names what fits."""
    script = """
import itertools
import numpy as np
from fuse4d.errors import ParameterError
from fuse4d.flow import DISParams, estimate_flow
refused = 0
for (h, w), ps, st, fs in itertools.product(
    [(100, 140), (48, 64), (30, 200)], [8, 24, 64, 100], [1, 8, 24, 64, 100], [0, 2]
):
    if st > ps or (st == 1 and ps > 8):
        continue
    a = np.random.default_rng(0).random((h, w), dtype=np.float32)
    try:
        flow = estimate_flow(a, np.roll(a, 1, 1), method="dis",
                             params=DISParams(patch_size=ps, patch_stride=st, finest_scale=fs))
    except ParameterError as exc:
        assert "it runs with" in str(exc), str(exc)
        refused += 1
    else:
        assert np.isfinite(flow).all()
print(refused)
"""
    done = subprocess.run(
        [sys.executable, "-c", script], check=False, capture_output=True, text=True
    )
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    assert int(done.stdout) > 0


def test_dis_refuses_a_patch_size_opencv_would_replace():
    """patch_size 16 at finest_scale 2 on 140 x 100 px gave the bytes of patch_size 8: OpenCV
    replaced it without a word. Now refused, naming the finest_scale and patch_size that fit;
    these run as asked."""
    image = texture((100, 140))
    moved = shifted(image, 1.0, 0.0)
    with pytest.raises(ParameterError, match="patch_size=16") as info:
        estimate_flow(image, moved, method="dis", params={"patch_size": 16})
    message = str(info.value)
    assert "140 x 100 px" in message
    assert "OpenCV would replace patch_size by 8" in message
    assert "it runs with finest_scale=1 or patch_size=12" in message
    as_asked = estimate_flow(
        image, moved, method="dis", params={"patch_size": 16, "finest_scale": 1}
    )
    other = estimate_flow(image, moved, method="dis", params={"patch_size": 8, "finest_scale": 1})
    assert not np.array_equal(as_asked, other)


def test_dis_refuses_padding_out_of_proportion():
    """finest_scale 0 with patch_size 512 padded 140 x 100 px to 724 x 725 px (with stride 1 a
    solve of many minutes that SIGTERM could not stop). Small crops are still padded for
    OpenCV's own patch sizes."""
    image = texture((100, 140))
    params = {"finest_scale": 0, "patch_size": 512, "patch_stride": 512}
    with pytest.raises(ParameterError, match=r"patch_size=512 is too large for a 140 x 100 px"):
        estimate_flow(image, image, method="dis", params=params)
    thin = texture((2, 640), sigma=1.0)
    assert estimate_flow(thin, thin, method="dis").shape == (2, 640, 2)


def test_dis_finest_scale_opencv_replaces_is_said(png_pair, tmp_path, capsys):
    """finest_scale 9 on a 110 x 90 px pair solved what finest_scale 0 solves, silently; the
    flow command now says which level OpenCV chose (and nothing when it keeps the value)."""
    args = ["flow", str(png_pair[0]), str(png_pair[1]), "-o", str(tmp_path / "f.flo")]
    assert main([*args, "-p", "finest_scale=9"]) == 0
    err = capsys.readouterr().err
    assert "too small for DIS finest_scale=9: OpenCV chose finest level 0 instead" in err
    assert main([*args, "--force", "-p", "finest_scale=1"]) == 0
    assert "note:" not in capsys.readouterr().err


@pytest.mark.parametrize(
    ("factory", "message"),
    [
        (lambda: DISParams(variational_refinement_epsilon=1e-30), "epsilon must be"),
        (
            lambda: TVL1Params(median_filtering=7),
            r"median_filtering must be an integer in \[1, 5\]",
        ),
    ],
)
def test_params_opencv_cannot_take_are_refused(factory, message):
    """epsilon 1e-30 underflows when OpenCV squares it (every flow vector NaN); a TV-L1
    median of 7 was an OpenCV assertion (its float median takes 1, 3, 5): internal errors."""
    with pytest.raises(ParameterError, match=message):
        factory()
    assert DISParams(variational_refinement_epsilon=1e-6).variational_refinement_epsilon == 1e-6
    assert TVL1Params(median_filtering=3).median_filtering == 3


def test_a_non_finite_flow_is_refused_before_it_is_used(monkeypatch):
    """An all-NaN forward flow was written out (exit 0) or passed, negated, as DIS's backward
    warm start (segmentation fault). Now every method's output is checked."""
    calls = []

    def nan_flow(image0, image1, params, init):
        calls.append(init)
        out = np.zeros((*image0.shape, 2), np.float32)
        out[5, 7] = np.nan
        return out

    nan_method = FlowMethod("nanflow", nan_flow, DeepFlowParams, "", True, False)
    monkeypatch.setitem(flow_mod._REGISTRY, "nanflow", nan_method)
    image = texture()
    with pytest.raises(ParameterError, match=r"'nanflow' returned NaN or inf at 1 of 10752 px"):
        estimate_flow(image, image, method="nanflow")
    with pytest.raises(ParameterError, match=r"image0 -> image1 \(forward\)"):
        estimate_flow_pair(image, image, method="nanflow")
    assert len(calls) == 2  # the backward solve never ran
    video = np.stack([image, image, image])
    with pytest.raises(ParameterError, match=r"^frame pair \(0, 1\): flow method 'nanflow'"):
        estimate_sequence_flow(video, method="nanflow")


def test_cli_flow_refuses_a_folder_or_a_non_png_vis_before_the_solve(png_pair, tmp_path, capsys):
    """A folder as --vis or -o failed only after the solve (with the .flo already written);
    --vis x.jpg / x.bmp / x wrote PNG bytes under that name."""
    folder = tmp_path / "dd"
    folder.mkdir()
    out = tmp_path / "w.flo"
    args = ["flow", str(png_pair[0]), str(png_pair[1]), "--force"]
    assert main([*args, "-o", str(out), "--vis", str(folder)]) == 2
    assert f"{folder}: is a folder" in capsys.readouterr().err
    assert not out.exists()
    assert main([*args, "-o", str(folder)]) == 2
    assert f"{folder}: is a folder" in capsys.readouterr().err
    for name in ("v.jpg", "v.bmp", "v"):
        assert main([*args, "-o", str(out), "--vis", str(tmp_path / name)]) == 2
        assert "name it *.png" in capsys.readouterr().err
        assert not (tmp_path / name).exists()
        assert not out.exists()
    from fuse4d.flow.vis import write_flow_png

    with pytest.raises(ParameterError, match="name it"):
        write_flow_png(np.zeros((4, 4, 2), np.float32), tmp_path / "v.jpg")


def _middlebury_copy(root, shape0=(20, 24), shape1=(20, 24), shape_gt=(20, 24)):
    from fuse4d.flow import write_flo

    frames, gt = root / "other-data" / "Venus", root / "other-gt-flow" / "Venus"
    frames.mkdir(parents=True)
    gt.mkdir(parents=True)
    cv2.imwrite(str(frames / "frame10.png"), (texture(shape0) * 255).astype(np.uint8))
    cv2.imwrite(str(frames / "frame11.png"), (texture(shape1) * 255).astype(np.uint8))
    write_flo(np.zeros((*shape_gt, 2), np.float32), gt / "flow10.flo")
    return frames, gt


def test_middlebury_pairs_name_the_file_that_does_not_fit(tmp_path):
    """Another sequence's flow10.flo or frame11.png failed as 'flow_test must have shape ...'
    or 'image1 must have shape ...' without a file name; a missing frame10.png skipped the
    sequence silently where a missing frame11.png was an error."""
    from fuse4d.errors import InputFileError
    from fuse4d.experiments.flow_accuracy import middlebury_pairs

    pairs, reason = middlebury_pairs(_middlebury_copy(tmp_path / "ok")[0].parent.parent)
    assert [p.name for p in pairs] == ["Venus"]
    assert reason == ""
    for name, shapes in (
        ("flow10.flo", {"shape_gt": (18, 24)}),
        ("frame11.png", {"shape1": (20, 22)}),
    ):
        root = tmp_path / name
        _middlebury_copy(root, **shapes)
        with pytest.raises(InputFileError, match=rf"{name}: .*Middlebury sequence Venus"):
            middlebury_pairs(root)
    for name in ("frame10.png", "frame11.png", "flow10.flo"):
        root = tmp_path / f"no-{name}"
        frames, gt = _middlebury_copy(root)
        (frames / name if name.startswith("frame") else gt / name).unlink()
        with pytest.raises(InputFileError, match=rf"{name}: file not found .*Venus is incomplete"):
            middlebury_pairs(root)


def test_bench_flow_methods_in_any_case():
    """--methods DIS was refused while flow -m DIS was accepted."""
    from fuse4d.experiments.flow_accuracy import default_bench_entries

    labels = [e.label for e in default_bench_entries(["DIS", " Farneback", "DIS-Medium"])]
    assert labels == ["dis-ultrafast", "dis-fast", "dis-medium", "farneback"]


def test_integer_images_without_a_bit_depth_are_refused_naming_the_image():
    """A list of 0-255 ints (int64) was divided by the int64 maximum: an all-zero flow."""
    from fuse4d.errors import ParameterTypeError
    from fuse4d.flow import estimate_flow, estimate_sequence_flow

    image = (np.random.default_rng(0).random((20, 30)) * 255).astype(np.int64)
    with pytest.raises(ParameterTypeError, match=r"^image0 has integer dtype int64 \(values 0"):
        estimate_flow(image.tolist(), image.tolist())
    with pytest.raises(ParameterTypeError, match=r"^intensity has integer dtype int32"):
        estimate_sequence_flow(np.stack([image, image]).astype(np.int32))


def test_middlebury_pair_without_known_ground_truth_is_refused_naming_the_file(tmp_path, capsys):
    """A flow10.flo whose vectors are all unknown (1e10) made the pair's EPE NaN, and the
    dataset's mean EPE with it, with exit 0 and nothing in 'skipped'."""
    from fuse4d.errors import InputFileError
    from fuse4d.experiments.flow_accuracy import middlebury_pairs
    from fuse4d.flow import write_flo

    _frames, gt = _middlebury_copy(tmp_path)
    write_flo(np.full((20, 24, 2), 1e10, np.float32), gt / "flow10.flo", overwrite=True)
    with pytest.raises(InputFileError, match=r"flow10\.flo: no known flow vector .*Venus"):
        middlebury_pairs(tmp_path)
    code = main(["bench-flow", "--data", str(tmp_path), "--no-ball", "--methods", "dis-ultrafast"])
    assert code == 2
    assert "flow10.flo: no known flow vector" in capsys.readouterr().err


def test_cli_bench_flow_default_data_folder_is_the_experiments_one(tmp_path, monkeypatch):
    """bench-flow looked for ../shared/data from the working folder, fuse4d experiments beside
    the source checkout: run from any other folder, bench-flow found no Middlebury pairs."""
    from fuse4d.cli.cmd_flow import _data_root
    from fuse4d.experiments.paper.real import data_dir

    monkeypatch.delenv("FUSE4D_DATA", raising=False)
    monkeypatch.chdir(tmp_path)
    assert _data_root(None) == data_dir()
    assert _data_root(None).is_absolute()
    monkeypatch.setenv("FUSE4D_DATA", str(tmp_path / "d"))
    assert _data_root(None) == tmp_path / "d"
    assert _data_root(tmp_path / "x") == tmp_path / "x"
