"""Run profiles of the paper experiments: how big a run is (EVALUATION.md §3-§4).

Three profiles:

* ``paper`` — the protocol as written: 600x600 scenes, 50 frames, seeds 0-2, all noise levels,
  the paper's PMBP tracker, shape correctness on every frame, the 6D ED baseline on every frame.
* ``reduced`` — what a shared 2-core machine finishes in about an hour: the same 600x600 scenes
  and noise levels, but short sequences, one seed, shape correctness on a few frames, the 6D
  ED baseline on one frame with a coarse (80 mm) node graph.
* ``quick`` — CI size (150x150 scenes, 12 frames, one seed, DIS flow, short sweeps): checks
  that every experiment runs end to end, never for reported numbers.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

__all__ = ["PROFILES", "Profile", "get_profile"]


@dataclass(frozen=True)
class Profile:
    """Size of an experiment run.

    Attributes
    ----------
    name : str
        Profile name (``paper``, ``reduced`` or ``quick``).
    small : bool
        Use the 150x150 CI scenes (``small=True`` of :mod:`fuse4d.synthetic`).
    num_frames : int
        Frames per synthetic sequence.
    seeds : tuple of int
        Scene seeds (noise and texture).
    sigma_d_levels : tuple of float
        E1 depth-noise levels, mm.
    sigma_i_levels : tuple of float
        E2 intensity-noise levels, fraction of the maximum intensity.
    flow_method : str
        Optical-flow tracker of Ours (``pmbp`` is the paper's; ``dis`` is not).
    shape_frames : int or None
        Frames scored for shape correctness C (evenly spaced over the sequence); None = all.
    ed_frames : int
        Frames at which the 6D ED baseline (BASELINES §9; cost grows with the node count) is
        evaluated; each uses only its own window (``ed_params["size"]``, default 4: 9 frames);
        0 = ED is not run.
    e3_iterations : tuple of int
        Iteration counts of the E3 sweep. Each filter runs those in its own BASELINES sweep
        list (1-5; ST-MF 1-3), Ours those up to 3 (EVALUATION §4 E3). Default: 1-5.
    e3_max_sizes : int or None
        At most this many sizes per baseline in E3 (spread over its sweep list); None = all.
    e4_frames : tuple of int
        Numbers of fused frames n of E4.
    e6_sigma_i : tuple of float
        Intensity-noise levels of the E6 ablations.
    real_frames : int
        Frames of each real recording used by ``real``.
    """

    name: str
    small: bool
    num_frames: int
    seeds: tuple[int, ...]
    sigma_d_levels: tuple[float, ...] = (0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40)
    sigma_i_levels: tuple[float, ...] = (0.02, 0.04, 0.06, 0.08, 0.10)
    flow_method: str = "pmbp"
    shape_frames: int | None = None
    ed_frames: int = 50
    e3_iterations: tuple[int, ...] = (1, 2, 3, 4, 5)
    e3_max_sizes: int | None = None
    e4_frames: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8, 9)
    e6_sigma_i: tuple[float, ...] = (0.02, 0.10)
    real_frames: int = 100
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """All fields as plain JSON values."""
        return asdict(self)


PROFILES: dict[str, Profile] = {
    "paper": Profile(name="paper", small=False, num_frames=50, seeds=(0, 1, 2)),
    "reduced": Profile(
        name="reduced",
        small=False,
        num_frames=13,
        seeds=(0,),
        flow_method="pmbp-fast",
        shape_frames=2,
        # ED: one evaluated frame (its own 9-frame window, 16 pairwise warps). At the BASELINES
        # default node spacing of 8 mm the graph has ~6 000 nodes and one frame did not finish
        # in 45 min on the shared machine; 80 mm nodes (~60) and every 16th source pixel in the
        # registration make it a few CPU-s per warp. The fusion itself uses every pixel.
        ed_frames=1,
        e3_iterations=(1, 2),
        e3_max_sizes=3,
        real_frames=20,
        extra={"e4_num_frames": 21, "ed_params": {"node_spacing": 80.0, "stride": 16}},
    ),
    "quick": Profile(
        name="quick",
        small=True,
        num_frames=12,
        seeds=(0,),
        sigma_d_levels=(0.10, 0.25, 0.40),
        sigma_i_levels=(0.02, 0.06, 0.10),
        flow_method="dis",
        shape_frames=2,
        ed_frames=1,
        e3_iterations=(1, 2),
        e3_max_sizes=2,
        e4_frames=(1, 3, 5, 9),
        e6_sigma_i=(0.02,),
        real_frames=6,
        # ED's cost is set by its node count, not the image size: coarse nodes (~60) and a
        # 3-frame window (4 warps instead of 16) keep CI fast
        extra={
            "ed_params": {"node_spacing": 80.0, "stride": 8, "size": 1},
            # real data at a quarter of the pixels (Ad-BF took ~2 min wall on 6 full person frames)
            "real_crop": (240, 320),
        },
    ),
}


def get_profile(name: str) -> Profile:
    """The profile called ``name``.

    Raises
    ------
    ValueError
        Unknown name (the message lists the known ones).
    """
    try:
        return PROFILES[name]
    except KeyError:
        raise ValueError(f"unknown profile {name!r}; choose one of {sorted(PROFILES)}") from None
