"""Strict JSON for fuse4d's ``--json`` outputs and ``metrics.json``. Private.

Python's ``json`` writes NaN and inf as bare ``NaN`` / ``Infinity``, which is not JSON: strict
parsers (JavaScript, Go, serde) reject the whole document. fuse4d's figures are NaN where they
do not apply (a clip without holes has no fill rate), so every JSON it prints goes through
:func:`json_safe` first and is written with ``allow_nan=False``.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def json_safe(value: Any) -> Any:
    """``value`` with NaN/inf as None, numpy scalars as Python numbers, tuples as lists and
    dict keys as strings (recursively)."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps(value: Any, **kwargs: Any) -> str:
    """Strict JSON text of ``value`` (:func:`json_safe`, then ``allow_nan=False``)."""
    return json.dumps(json_safe(value), allow_nan=False, **kwargs)
