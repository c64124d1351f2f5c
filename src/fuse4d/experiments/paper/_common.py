"""What every experiment module shares: the run context and the tidy-row layout."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ._config import Profile
from ._scenes import FILTERS, LABELS

__all__ = ["HALF_WINDOW", "METHODS", "Context", "tidy"]

#: Methods of E1-E3 (BASELINES §1-7 and Ours), in the paper's order.
METHODS: tuple[str, ...] = ("raw", *FILTERS, "ours")
#: Half window h of Ours' 9 frames: frames h..N-1-h are "interior" (full window).
HALF_WINDOW = 4


@dataclass(frozen=True)
class Context:
    """Where and how big an experiment runs.

    Attributes
    ----------
    profile : Profile
        Run size.
    out : Path
        The run's root folder (each experiment writes ``out/<name>/``).
    """

    profile: Profile
    out: Path

    @property
    def cache_dir(self) -> Path:
        """Flow cache shared by all experiments of the run."""
        return self.out / "flow_cache"

    def exp_dir(self, name: str) -> Path:
        """Output folder of experiment ``name``."""
        return self.out / name


def tidy(
    experiment: str,
    scene: str,
    method: str,
    seed: int,
    scored: list[dict[str, Any]],
    num_frames: int,
    **setting: Any,
) -> list[dict[str, Any]]:
    """Tidy rows: identification columns, the setting's columns, then the frame's scores."""
    rows = []
    for s in scored:
        f = int(s["frame"])
        rows.append(
            {
                "experiment": experiment,
                "scene": scene,
                "method": method,
                "label": LABELS.get(method, method),
                **setting,
                "seed": seed,
                **s,
                "interior": int(HALF_WINDOW <= f <= num_frames - 1 - HALF_WINDOW),
            }
        )
    return rows
