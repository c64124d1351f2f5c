"""The public surface is pinned: ``docs/api.md`` lists exactly each module's ``__all__``."""

from __future__ import annotations

import importlib
import inspect
import re
import subprocess
import sys
from pathlib import Path

import pytest

API_PAGE = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def _documented() -> dict[str, list[str]]:
    """Module name → names in its table on the API page, in page order."""
    sections: dict[str, list[str]] = {}
    current = None
    for line in API_PAGE.read_text(encoding="utf-8").splitlines():
        heading = re.match(r"^## `(fuse4d(?:\.\w+)*)`", line)
        if heading:
            current = heading.group(1)
            sections[current] = []
            continue
        row = re.match(r"^\| `([^`]+)` \|", line)
        if row and current is not None:
            sections[current].append(row.group(1))
    return sections


SECTIONS = _documented()


def test_page_has_the_top_level_and_the_subpackages():
    assert {"fuse4d", "fuse4d.flow", "fuse4d.io", "fuse4d.metrics", "fuse4d.baselines"} <= set(
        SECTIONS
    )


@pytest.mark.parametrize("module", sorted(SECTIONS))
def test_page_matches_all(module):
    mod = importlib.import_module(module)
    exported = list(mod.__all__)
    documented = SECTIONS[module]
    assert len(documented) == len(set(documented)), f"{module}: a name is listed twice"
    missing = sorted(set(exported) - set(documented))
    extra = sorted(set(documented) - set(exported))
    assert not missing, f"{module}: in __all__ but not on docs/api.md: {missing}"
    assert not extra, f"{module}: on docs/api.md but not in __all__: {extra}"
    for name in exported:
        assert hasattr(mod, name), f"{module}.__all__ names {name!r}, which does not exist"


def test_top_level_stays_small():
    import fuse4d

    assert len(fuse4d.__all__) <= 30  # 20 entry points + the error family


def test_public_functions_have_numpydoc_sections():
    """Every public function of the top level documents its parameters and what it returns."""
    import fuse4d

    lacking = []
    for name in fuse4d.__all__:
        obj = getattr(fuse4d, name)
        if not inspect.isfunction(obj):
            continue
        doc = inspect.getdoc(obj) or ""
        params = list(inspect.signature(obj).parameters)
        if params and "Parameters\n----------" not in doc:
            lacking.append(f"{name}: Parameters")
        if "Returns\n-------" not in doc and "Yields\n------" not in doc:
            lacking.append(f"{name}: Returns")
    assert not lacking, lacking


def test_import_is_light():
    """``import fuse4d`` does not load the baselines (scipy.sparse, Open3D probes)."""
    code = "import sys, fuse4d; print('fuse4d.baselines' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_lazy_names_resolve():
    import fuse4d

    assert callable(fuse4d.run_baseline)
    assert "temporal-mean" in fuse4d.available_baselines()
    assert fuse4d.metrics.roughness_stats is not None
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        fuse4d.nope


def test_no_import_cycles_in_flow():
    """The flow package's modules import nothing from the package root or its __init__."""
    root = Path(__file__).resolve().parents[1] / "src" / "fuse4d" / "flow"
    for path in root.glob("*.py"):
        if path.name == "__init__.py":
            continue
        text = path.read_text(encoding="utf-8")
        assert "import fuse4d\n" not in text, path
        assert not re.search(r"^from \. import|^from \.\s+import", text, re.MULTILINE), path
        assert not re.search(r"^\s*from \.\. import", text, re.MULTILINE), path


# --------------------------------------------------------------------------- page generator
#: The modules on the page, in order, with their one-line description.
MODULES = [
    ("fuse4d", "The handful of names a user needs"),
    (
        "fuse4d.flow",
        "Optical flow: the registry, OpenCV trackers, the paper's PMBP, cache, .flo, colour coding",
    ),
    ("fuse4d.io", "Readers and writers of recordings, depth video, zarr stores and point clouds"),
    (
        "fuse4d.metrics",
        "Eq. 7 roughness, Eq. 8 shape correctness, RMSE, bad pixels, flicker, flow errors, ROIs",
    ),
    ("fuse4d.motion", "Eq. 3-4: tracks, motion fields, the depth-noise model"),
    ("fuse4d.holes", "Eq. 6 and the filling of sensor holes"),
    ("fuse4d.flying_pixels", "Time-of-flight flying (mixed) pixels: found and left out (A36)"),
    ("fuse4d.baselines", "The paper's comparison methods behind one interface"),
    ("fuse4d.synthetic", "The paper's scenes with ground truth"),
    ("fuse4d.sensors", "Depth-sensor models: structured light, active stereo, time of flight"),
    ("fuse4d.range_scenes", "Scenes at 1-5 m seen through a sensor model, with ground truth"),
    ("fuse4d.camera", "Pinhole camera, Eq. 2 back-projection"),
    (
        "fuse4d.decimate",
        "Depth, intensity and camera at 1/f of the resolution (the RealSense decimation filter)",
    ),
    ("fuse4d.sequence", "The in-memory recording"),
    ("fuse4d.config", "Fusion parameters, presets, TOML files"),
    ("fuse4d.fusion", "The fusion engine (Eq. 5-6)"),
    ("fuse4d.bilateral", "The intensity-guided 3D bilateral (inner sum of Eq. 5)"),
    ("fuse4d.errors", "fuse4d's error types"),
    ("fuse4d.plot", "Figures"),
    ("fuse4d.run", "File in, file out (what `fuse4d run` calls)"),
    ("fuse4d.report", "The HTML report: video, x-t slices, flicker, roughness, point clouds"),
    ("fuse4d.dask", "Chunked fusion on dask: arrays in, lazy arrays out, zarr v3 stores"),
    ("fuse4d.live", "Live fusion of a camera or a recording played in real time"),
]


def _summary(mod, name: str, previous: dict[str, str]) -> str:
    if name in previous:
        return previous[name]
    obj = getattr(mod, name)
    doc = inspect.getdoc(obj) if callable(obj) or inspect.ismodule(obj) else None
    line = doc.strip().split("\n\n")[0].replace("\n", " ") if doc else ""
    line = line.replace("|", "\\|")
    return line if len(line) <= 160 else line[:157].rsplit(" ", 1)[0] + " …"


def render_api_page() -> str:
    """The API page with a row for every name of every module's ``__all__``, keeping the
    existing descriptions (``python tests/test_api.py`` rewrites docs/api.md)."""
    previous: dict[str, str] = {}
    for line in API_PAGE.read_text(encoding="utf-8").splitlines():
        row = re.match(r"^\| `([^`]+)` \| (.*) \|$", line)
        if row:
            previous.setdefault(row.group(1), row.group(2))
    head = API_PAGE.read_text(encoding="utf-8").split("\n## ", 1)[0].rstrip("\n")
    out = [head, ""]
    for name, desc in MODULES:
        mod = importlib.import_module(name)
        out += [f"## `{name}`", "", desc + ".", "", "| name | what it is |", "|---|---|"]
        out += [f"| `{n}` | {_summary(mod, n, previous)} |" for n in mod.__all__]
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    API_PAGE.write_text(render_api_page(), encoding="utf-8")
