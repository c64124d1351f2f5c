"""Start-up: ``import fuse4d.cli`` (and so ``fuse4d --help``) loads no numerics.

Command modules import only typer/rich/stdlib at module level; the heavy modules (numba
kernels, OpenCV, scipy, the baselines, the flow registry) load inside the command that needs
them. Each check runs in a fresh interpreter, since this test process has long imported them.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"

#: Modules that must not be loaded by ``import fuse4d.cli`` / ``import fuse4d``.
HEAVY = ("numba", "cv2", "scipy", "fuse4d.baselines", "fuse4d.flow", "fuse4d.io", "numpy")

#: Every command of the CLI (``fuse4d --help`` must list each of them).
COMMANDS = (
    "baseline",
    "flow",
    "bench-flow",
    "run",
    "bench",
    "demo",
    "synth",
    "metrics",
    "info",
    "convert",
    "export-ply",
    "report",
    "live",
    "experiments",
)


def _python(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(SRC), "COLUMNS": "200"}
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, check=True, env=env, timeout=120
    )


@pytest.mark.parametrize("module", ["fuse4d", "fuse4d.cli"])
def test_import_loads_no_numerics(module):
    code = f"import sys, {module}; print(' '.join(sorted(sys.modules)))"
    loaded = set(_python("-c", code).stdout.split())
    assert not [m for m in HEAVY if m in loaded], sorted(m for m in HEAVY if m in loaded)


#: scipy subpackages that ``fuse4d run`` / ``live`` do not use: each cost 0.17-0.31 s of
#: import on a 2-core machine (numba itself still loads scipy.linalg for its BLAS check)
SCIPY_UNUSED_BY_FUSION = ("scipy.ndimage", "scipy.optimize", "scipy.special", "scipy.stats")


def test_the_fusion_path_loads_no_unused_scipy():
    """Importing ``fuse4d.run`` and ``fuse4d.live`` and building an engine (A32's critical
    values included) leaves scipy's ndimage, optimize, special and stats unloaded."""
    code = (
        "import sys, fuse4d.run, fuse4d.live\n"
        "from fuse4d.camera import Intrinsics\n"
        "from fuse4d.fusion import FusionEngine\n"
        "FusionEngine(Intrinsics(fx=50.0, fy=50.0, cx=8.0, cy=6.0, width=16, height=12))\n"
        "print(' '.join(sorted(sys.modules)))"
    )
    loaded = set(_python("-c", code).stdout.split())
    assert "fuse4d.fusion" in loaded
    assert not [m for m in SCIPY_UNUSED_BY_FUSION if m in loaded]


def test_help_lists_every_command():
    out = _python("-m", "fuse4d", "--help").stdout
    missing = [c for c in COMMANDS if f" {c} " not in out]
    assert not missing, missing


def test_help_paragraphs_flow_to_the_terminal_width():
    """A docstring's line breaks do not reach ``--help`` (typer keeps them, and at 80
    columns every source line would end in a ragged break); paragraphs stay apart."""
    out = _python("-m", "fuse4d", "bench", "--help").stdout
    assert (
        "With --causal: the causal engine (each frame fused with the --window - 1 previous" in out
    )
    assert "as `fuse4d run --causal`" not in out.split("With --causal")[1].splitlines()[1]
    listing = _python("-m", "fuse4d", "--help").stdout
    assert "into OUT/<name>/: tidy CSV, Markdown summary" in listing


def test_help_shows_no_value_for_a_flag():
    """``--small`` takes no value, so ``--help`` shows none (typer >= 0.2x printed
    ``--small <bool>``); an option that takes a value still shows its type."""
    out = _python("-m", "fuse4d", "bench", "--help").stdout
    rows = {line.split()[1]: line for line in out.splitlines() if line.startswith("│ --")}
    assert "<bool>" not in out
    assert "<int>" in rows["--frames"]
    assert rows["--small"].split()[2:4] == ["150x150", "CI"], rows["--small"]
    assert "<bool>" not in _python("-m", "fuse4d", "--help").stdout


def test_registered_commands_are_the_listed_ones():
    from fuse4d.cli import app

    names = [c.name for c in app.registered_commands]
    assert sorted(names) == sorted(COMMANDS)


def test_lazy_top_level_names_resolve_and_dir_lists_them():
    import fuse4d

    for name in fuse4d.__all__:
        assert getattr(fuse4d, name) is not None, name
    assert set(fuse4d.__all__) <= set(dir(fuse4d))
    assert fuse4d.FusionEngine is fuse4d.fusion.FusionEngine


def test_written_out_help_matches_the_registries():
    """The help texts spelled out in the command modules equal what the registries give."""
    from fuse4d.cli.cmd_baseline import SIZE_HELP, _size_help
    from fuse4d.cli.cmd_io import CAMERA_PRESET_NAMES
    from fuse4d.io import CAMERA_PRESETS

    assert _size_help() == SIZE_HELP
    assert tuple(CAMERA_PRESETS) == CAMERA_PRESET_NAMES


def test_io_import_loads_no_numba():
    """``import fuse4d.io`` leaves numba unloaded: the RVL kernels load on the first decode."""
    code = "import sys, fuse4d.io; print('numba' in sys.modules)"
    assert _python("-c", code).stdout.strip() == "False"


def test_info_loads_no_numba(tmp_path):
    """``fuse4d info`` on a recording reads frames without loading numba or the baselines."""
    import numpy as np

    from fuse4d import Intrinsics, Sequence
    from fuse4d.io import write_npz

    depth = np.full((3, 8, 10), 1000.0, dtype=np.float32)
    seq = Sequence(
        depth=depth, intensity=np.zeros_like(depth), intrinsics=Intrinsics(50, 50, 5, 4, 10, 8)
    )
    path = write_npz(seq, tmp_path / "s.npz")
    code = (
        "import sys\nfrom fuse4d.cli import main\n"
        f"rc = main(['info', {str(path)!r}])\n"
        "print('LOADED', [m for m in ('numba', 'fuse4d.baselines', 'fuse4d.flow') if m in sys.modules])\n"
        "sys.exit(rc)"
    )
    out = _python("-c", code).stdout
    assert "LOADED []" in out, out
    assert "valid pixels: 100.0 %" in out


def test_version_names_fuse4d_and_its_numerics_without_importing_them():
    """SECURITY.md asks for ``fuse4d --version`` in a report; the option did not exist."""
    code = (
        "import sys\nfrom fuse4d.cli import main\n"
        "rc = main(['--version'])\n"
        "print('LOADED', [m for m in ('numba', 'cv2', 'scipy') if m in sys.modules])\n"
        "sys.exit(rc)"
    )
    res = _python("-c", code)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("fuse4d ")
    assert "numpy " in res.stdout
    assert "numba " in res.stdout
    assert "LOADED []" in res.stdout
