"""Fuzzing every reader: damaged input gives a fuse4d error or a valid result, nothing else.

The normal suite runs a small derandomized sample per reader (a few seconds in all); the
nightly-style run is ``pytest -m fuzz`` (``FUSE4D_FUZZ_EXAMPLES`` cases per reader, default
10 000). Readers are listed in ``tests/fuzz/targets.py``; the contract is in
``tests/fuzz/contract.py``. Set ``FUSE4D_FUZZ_REPORT=file.json`` to get outcome counts.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import pytest

pytest.importorskip("hypothesis", reason="fuzzing needs hypothesis (pip install -e '.[test]')")

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from fuzz.contract import check_contract
from fuzz.targets import TARGETS, FuzzTarget

SAMPLE_EXAMPLES = int(os.environ.get("FUSE4D_FUZZ_SAMPLE", "12"))
NIGHTLY_EXAMPLES = int(os.environ.get("FUSE4D_FUZZ_EXAMPLES", "10000"))
_HEALTH = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much]
# no shrinking: a failure is reported as drawn (shrinking a file-level case takes minutes)
_PHASES = [Phase.explicit, Phase.reuse, Phase.generate]
OUTCOMES: dict[str, Counter] = {t.name: Counter() for t in TARGETS}


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each target's valid fixture, built once."""
    out = {}
    for target in TARGETS:
        folder = tmp_path_factory.mktemp(f"fuzz-{target.name}")
        out[target.name] = target.build(folder)
    return out


def _copy(src: Path, workdir: Path) -> Path:
    dst = workdir / src.name
    if src.is_dir():
        shutil.copytree(src, dst, symlinks=True)
    else:
        shutil.copyfile(src, dst)
    return dst


def _one_case(target: FuzzTarget, source: Path, data: st.DataObject) -> None:
    with tempfile.TemporaryDirectory(prefix=f"fuzz-{target.name}-") as tmp:
        path = _copy(source, Path(tmp))
        for _ in range(data.draw(st.integers(1, 2), label="mutations")):
            mutator = data.draw(st.sampled_from(target.mutators), label="mutator")
            if not path.exists() and not path.is_symlink():
                break
            try:
                mutator(data, path)
            except Exception:  # noqa: BLE001, S112 - a mutator may not fit an already damaged file
                continue
        outcome = check_contract(target.name, target.read, path)
        OUTCOMES[target.name][outcome] += 1


def _fuzz(target: FuzzTarget, source: Path, examples: int, derandomize: bool) -> None:
    @settings(max_examples=examples, derandomize=derandomize, deadline=None, database=None,
              suppress_health_check=_HEALTH, print_blob=True, phases=_PHASES, report_multiple_bugs=False)  # fmt: skip
    @given(data=st.data())
    def run(data: st.DataObject) -> None:
        _one_case(target, source, data)

    run()


@pytest.mark.parametrize("target", TARGETS, ids=[t.name for t in TARGETS])
def test_pristine_fixture_reads(target: FuzzTarget, pristine: dict[str, Path]) -> None:
    assert check_contract(target.name, target.read, pristine[target.name]) == "ok"


@pytest.mark.parametrize("target", TARGETS, ids=[t.name for t in TARGETS])
def test_fuzz_sample(target: FuzzTarget, pristine: dict[str, Path]) -> None:
    """A small derandomized sample (same cases every run) for the normal suite."""
    _fuzz(target, pristine[target.name], SAMPLE_EXAMPLES, derandomize=True)


@pytest.mark.fuzz
@pytest.mark.parametrize("target", TARGETS, ids=[t.name for t in TARGETS])
def test_fuzz_nightly(target: FuzzTarget, pristine: dict[str, Path]) -> None:
    """``pytest -m fuzz``: NIGHTLY_EXAMPLES random cases per reader."""
    _fuzz(target, pristine[target.name], NIGHTLY_EXAMPLES, derandomize=False)
    report = os.environ.get("FUSE4D_FUZZ_REPORT")
    if report:
        Path(report).write_text(json.dumps({k: dict(v) for k, v in OUTCOMES.items()}, indent=1))
