"""Under load: concurrent ``fuse4d run`` processes share a numba cache and a flow cache
without crashing or corrupting either."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import file_contents
from fuse4d import Intrinsics, Sequence
from fuse4d.io import write_frame_folder

REPO = Path(__file__).resolve().parents[1]
PROCESSES = 4


def _tiny_recording(path: Path) -> Path:
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:24, 0:32]
    depth = (500 + 0.5 * xx + rng.normal(0, 0.2, (6, 24, 32))).astype(np.float32)
    tex = np.clip(0.5 + 0.3 * np.sin(xx / 3.0) * np.cos(yy / 4.0), 0, 1)
    intensity = np.stack([np.roll(tex, t, axis=1) for t in range(6)]).astype(np.float32)
    seq = Sequence(depth, intensity, Intrinsics(80, 80, 15.5, 11.5, width=32, height=24))
    return write_frame_folder(seq, path, depth_unit_mm=0.01)


def _env(numba_cache: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO / "src"), "NUMBA_CACHE_DIR": str(numba_cache)}


def _start(args: list[str], env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "fuse4d", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _outputs(folder: Path) -> dict[str, bytes]:
    """The images (decoded, :func:`conftest.file_contents`) and the camera, by path."""
    return {
        p.relative_to(folder).as_posix(): file_contents(p)
        for p in [*sorted(folder.rglob("*.png")), folder / "camera.json"]
    }


@pytest.mark.slow
def test_concurrent_runs_share_a_cold_numba_cache(tmp_path):
    """4 runs start together on an empty numba cache (all compile and write it at once);
    all succeed with identical outputs, and a later run loads the cache they wrote."""
    src = _tiny_recording(tmp_path / "in")
    env = _env(tmp_path / "numba-cache")
    procs = [
        _start(["run", str(src), "-o", str(tmp_path / f"out{k}"), "--window", "3"], env)
        for k in range(PROCESSES)
    ]
    for proc in procs:
        _, err = proc.communicate(timeout=1200)
        assert proc.returncode == 0, err[-3000:]
    first = _outputs(tmp_path / "out0")
    for k in range(1, PROCESSES):
        assert _outputs(tmp_path / f"out{k}") == first
    assert any((tmp_path / "numba-cache").rglob("*.nbi"))  # the cache was written
    again = _start(["run", str(src), "-o", str(tmp_path / "again"), "--window", "3"], env)
    _, err = again.communicate(timeout=600)
    assert again.returncode == 0, err[-3000:]
    assert _outputs(tmp_path / "again") == first


_FLOW_WORKER = """
import sys
import numpy as np
from fuse4d.flow import FlowCache
from fuse4d.flow import estimate_flow_pair
cache = FlowCache(sys.argv[1])
rng = np.random.default_rng(0)
frames = [np.clip(rng.random((40, 48)).astype(np.float32), 0, 1) for _ in range(5)]
for _ in range(3):
    for a, b in zip(frames, frames[1:]):
        fwd, bwd = estimate_flow_pair(a, b, method="dis", cache=cache)
        ref = estimate_flow_pair(a, b, method="dis")
        assert np.array_equal(fwd, ref[0]) and np.array_equal(bwd, ref[1])
print(cache.hits, cache.misses)
"""


def test_concurrent_processes_share_a_flow_cache(tmp_path):
    """4 processes fill and read one flow cache at once: every entry they load equals a
    fresh computation, and no temporary or unreadable entry is left behind."""
    cache = tmp_path / "flow-cache"
    env = _env(Path(os.environ.get("NUMBA_CACHE_DIR", tmp_path / "numba-cache")))
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _FLOW_WORKER, str(cache)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(PROCESSES)
    ]
    for proc in procs:
        out, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err[-3000:]
        hits, _ = (int(v) for v in out.split())
        assert hits >= 8  # the second and third passes hit
    entries = sorted(cache.rglob("*"))
    files = [p for p in entries if p.is_file()]
    assert len(files) == 4  # one per pair: same key in every process
    assert not [p for p in files if p.name.startswith(".")]  # no temporaries left
    for p in files:
        array = np.load(p, allow_pickle=False)
        assert array.shape == (2, 40, 48, 2)


_SIGNATURES = """
import sys
from numba.core.registry import CPUDispatcher
from fuse4d.cli import main
assert main(["run", sys.argv[1], "-o", sys.argv[2], "--window", "3"]) == 0
for name, module in list(sys.modules.items()):
    for attr, obj in vars(module).items() if name.startswith("fuse4d") else ():
        if isinstance(obj, CPUDispatcher) and len(obj.signatures) > 1:
            print("SEVERAL", name, attr, obj.signatures)
"""


@pytest.mark.slow
def test_a_run_compiles_one_overload_per_kernel(tmp_path):
    """Every fuse4d numba kernel is called with one signature in a run: two overloads of one
    cached dispatcher, compiled in different orders by concurrent cold processes, can be
    paired with the wrong code in numba's cache index (the hazard the test above guards).

    On a cold cache of its own (about 45 s of compiling): a kernel loaded from a warm cache
    does not register the signatures of the ``@njit`` helpers it calls, so a second overload
    of a helper (stop 49: ``_key_of_rank`` with a literal 0) passed against CI's cache."""
    src = _tiny_recording(tmp_path / "in")
    env = _env(tmp_path / "numba-cache")
    proc = subprocess.run(
        [sys.executable, "-c", _SIGNATURES, str(src), str(tmp_path / "out")],
        env=env,
        check=False,
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "SEVERAL" not in proc.stdout, proc.stdout[proc.stdout.find("SEVERAL") :]
