"""The real recordings in ../shared/data load through the public API (read-only)."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d.cli import main
from fuse4d.flow import read_flo
from fuse4d.io import (
    count_frames,
    detect_format,
    iter_frames,
    load_sequence,
    read_mask,
)

pytestmark = pytest.mark.realdata


def test_uva_person_turning(shared_data):
    path = shared_data / "uva_cv2_person_turning"
    assert detect_format(path) == "cv2-xml"
    assert count_frames(path) == 100
    seq = load_sequence(path, frames="0:20")
    assert seq.depth.shape == (20, 480, 640)
    assert seq.depth.dtype == np.float32
    k = seq.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (525.0, 525.0, 320.0, 240.0, 640, 480)
    invalid = float(np.isnan(seq.depth).mean())
    assert 0.24 < invalid < 0.30  # README: ~27 % zeros
    person = np.nanmedian(np.where(seq.ground_truth.mask, seq.depth, np.nan))
    assert 800 < person < 950  # README: person at ~0.87 m -> depth really in mm
    assert np.nanmax(seq.depth) <= 2905.0
    assert np.nanmin(seq.depth) > 0
    assert 0.1 < seq.ground_truth.mask.mean() < 0.3
    assert seq.intensity.min() >= 0.0
    assert seq.intensity.max() <= 1.0
    assert seq.timestamps is None
    np.testing.assert_array_equal(read_mask(path, frames="3:5"), seq.ground_truth.mask[3:5])


def test_static_room(shared_data):
    path = shared_data / "static_room_rgbd"
    assert detect_format(path) == "frames-json"
    seq = load_sequence(path)
    assert seq.depth.shape == (12, 480, 640)
    assert seq.intrinsics.fx == pytest.approx(544.4733, abs=1e-3)
    assert (seq.intrinsics.cx, seq.intrinsics.cy) == (320.0, 240.0)
    assert 0.86 < np.isfinite(seq.depth).mean() < 0.90  # README: ~88 % valid
    assert 1400 < np.nanmedian(seq.depth) < 1800  # median ~1.57 m -> mm
    assert np.nanmax(seq.depth) == 2333.0
    np.testing.assert_allclose(np.diff(seq.timestamps)[[0, 6]], [0.033432, 0.066866], atol=2e-6)
    frames = iter_frames(path, frames="11:")
    assert [f.index for f in frames] == [11]


def test_info_on_real_data(shared_data, capsys):
    assert main(["info", str(shared_data / "static_room_rgbd")]) == 0
    out = capsys.readouterr().out
    assert "frames-json" in out
    assert "87.9 %" in out
    assert "the last 19 (files absent) were skipped" in out


def test_middlebury_flo(shared_data):
    flow = read_flo(shared_data / "middlebury_flow/other-gt-flow/RubberWhale/flow10.flo")
    assert flow.shape == (388, 584, 2)
    unknown = np.isnan(flow[..., 0]).mean()
    assert 0.01 < unknown < 0.03  # README: 1.6 %
    assert np.nanmax(np.hypot(flow[..., 0], flow[..., 1])) < 5.0  # README: max 4.6 px
