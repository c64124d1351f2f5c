"""Shared fixtures: seeded RNG, tiny synthetic sequences, location of ../shared/data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from fuse4d import Intrinsics, Sequence

REPO_ROOT = Path(__file__).resolve().parents[1]


def file_contents(path: Path) -> bytes:
    """What two runs' output files are compared by: a PNG's decoded samples (dtype, shape and
    bytes), any other file's bytes. ISA-L's deflate, which writes fuse4d's PNGs
    (``fuse4d.io._png``), is not byte-reproducible from one process to another: in one CI run
    (stop 48) a child process wrote the same 40 x 56 image, the same filtered rows, as a
    different 181-byte stream."""
    data = path.read_bytes()
    if path.suffix != ".png":
        return data
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    return repr((image.dtype.str, image.shape)).encode() + image.tobytes()


def load_benchmark(name: str):
    """The module of the script ``benchmarks/<name>.py`` (not a package: loaded by path)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_ball_folder(folder: Path, frames: int = 5) -> Path:
    """The small synthetic ball (150 x 150) as a frame folder at ``folder`` (0.05 mm units):
    a recording for the streaming path of ``fuse4d run``."""
    from fuse4d.io import FrameFolderWriter
    from fuse4d.synthetic import make_falling_ball

    seq = make_falling_ball(small=True, num_frames=frames)
    with FrameFolderWriter(folder, seq.intrinsics, depth_unit_mm=0.05) as writer:
        for d, i in zip(seq.depth, seq.intensity, strict=True):
            writer.write(d, i)
    return folder


def shared_data_dir() -> Path:
    """``$FUSE4D_DATA`` or ``<repo>/../shared/data`` (read in place, never copied)."""
    env = os.environ.get("FUSE4D_DATA")
    return Path(env) if env else REPO_ROOT.parent / "shared" / "data"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


@pytest.fixture
def shared_data() -> Path:
    """The shared real-data folder; skips the test (with the reason) when it is absent."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real data folder not found: {path} (set FUSE4D_DATA to its location)")
    return path


@pytest.fixture
def small_intrinsics() -> Intrinsics:
    return Intrinsics(fx=80.0, fy=80.0, cx=15.5, cy=11.5, width=32, height=24)


@pytest.fixture
def small_sequence(small_intrinsics: Intrinsics, rng: np.random.Generator) -> Sequence:
    """4 frames of a noisy textured plane at ~500 mm, 24x32 px."""
    t, h, w = 4, small_intrinsics.height, small_intrinsics.width
    yy, xx = np.mgrid[0:h, 0:w]
    depth = 500.0 + 0.5 * xx + rng.normal(0.0, 0.2, (t, h, w))
    intensity = np.clip(0.5 + 0.3 * np.sin(xx / 3.0) * np.cos(yy / 4.0), 0, 1)
    intensity = np.broadcast_to(intensity, (t, h, w)).copy()
    return Sequence(depth.astype(np.float32), intensity.astype(np.float32), small_intrinsics)


@pytest.fixture(autouse=True)
def _crash_reports_in_tmp(tmp_path_factory: pytest.TempPathFactory, monkeypatch) -> None:
    """Crash reports of CLI tests go to a temporary folder, never to ~/.cache."""
    monkeypatch.setenv("FUSE4D_CRASH_DIR", str(tmp_path_factory.getbasetemp() / "crash"))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """``fuzz`` tests (hours of fuzzing) run only when selected: ``pytest -m fuzz``."""
    if "fuzz" in (config.getoption("-m") or ""):
        return
    skip = pytest.mark.skip(reason="nightly fuzz run; select it with: pytest -m fuzz")
    for item in items:
        if item.get_closest_marker("fuzz") is not None:
            item.add_marker(skip)
