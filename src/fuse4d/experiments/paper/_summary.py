"""Aggregation of tidy rows and Markdown tables (plain Python, no pandas).

Sequence statistics follow EVALUATION §1: the per-frame value F_t is averaged over frames
(mean) and its temporal fluctuation is the std over frames with ddof = 0; both are then
averaged over seeds, and the spread over seeds is the std of the per-seed means.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["SeqStat", "fmt", "group_stats", "markdown_table"]

Row = dict[str, Any]


@dataclass(frozen=True)
class SeqStat:
    """Statistics of one value over the frames and seeds of one group.

    Attributes
    ----------
    mean : float
        Mean over seeds of the per-seed mean over frames.
    std_frames : float
        Mean over seeds of the per-seed std over frames (ddof = 0): temporal fluctuation.
    std_seeds : float
        Std over seeds of the per-seed means (0 with one seed).
    n_frames, n_seeds : int
        Frames (per seed, largest) and seeds with a finite value.
    """

    mean: float
    std_frames: float
    std_seeds: float
    n_frames: int
    n_seeds: int


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def group_stats(
    rows: Iterable[Row],
    keys: Sequence[str],
    value: str,
    *,
    where: Callable[[Row], bool] | None = None,
) -> dict[tuple[Any, ...], SeqStat]:
    """``SeqStat`` of ``value`` per distinct tuple of ``keys`` (rows grouped also by seed)."""
    per: dict[tuple[Any, ...], dict[Any, list[float]]] = defaultdict(lambda: defaultdict(list))
    for row in rows:
        if where is not None and not where(row):
            continue
        v = row.get(value)
        if not _finite(v):
            continue
        per[tuple(row.get(k) for k in keys)][row.get("seed", 0)].append(float(v))
    out = {}
    for key, seeds in per.items():
        means = [float(np.mean(v)) for v in seeds.values()]
        stds = [float(np.std(v)) for v in seeds.values()]
        out[key] = SeqStat(
            mean=float(np.mean(means)),
            std_frames=float(np.mean(stds)),
            std_seeds=float(np.std(means)),
            n_frames=max(len(v) for v in seeds.values()),
            n_seeds=len(means),
        )
    return out


def fmt(x: Any, digits: int = 3) -> str:
    """A number for a table (``–`` for missing)."""
    if isinstance(x, str):
        return x
    if x is None or not _finite(x):
        return "–"
    return f"{x:.{digits}f}"


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A GitHub Markdown table (cells formatted with :func:`fmt` unless already strings)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines.extend("| " + " | ".join(fmt(c) for c in row) + " |" for row in rows)
    return "\n".join(lines) + "\n"
