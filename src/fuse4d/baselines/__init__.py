"""The comparison methods of the paper behind one interface (BASELINES.md).

Every method has the signature::

    method(depth (T, H, W) mm, intensity (T, H, W) [0, 1], intrinsics, *, size=..., iterations=...,
           **params) -> depth (T, H, W) mm            # or points (T, H, W, 3) mm for 6D methods

and is registered by name. Enumerate them with :func:`available_baselines`, run one with
:func:`run_baseline`.

``size`` is the one knob swept for every method (EVALUATION E3), but it is a different
quantity per method, so each method also gives it a real name (``BaselineInfo.size_name``),
one meaning per name, accepted by :func:`run_baseline` and ``fuse4d baseline -p``:

=================== ======================================= ==================================
``size_name``       meaning                                 methods
=================== ======================================= ==================================
``kernel_scale``    scale s of the noise-model kernel       adgf
``spatial_radius``  pixel radius r (disc; guided: a box)    adbf, guided, dnbf, adjbf
``num_frames``      frames in the temporal window           ta, temporal-mean
``temporal_radius`` k frames either side (2k+1 frames)      stmf, kinectfusion, ed
``filter_passes``   passes of the spatial filter (1..5)     realsense
=================== ======================================= ==================================

Knobs given as strings (command line) are converted to the annotated types of the method's
keywords by :func:`fuse4d._params.coerce_kwargs`, then validated by the method.

Examples
--------
>>> import numpy as np
>>> from fuse4d import Intrinsics
>>> K = Intrinsics(fx=500.0, fy=500.0, cx=15.5, cy=11.5, width=32, height=24)
>>> rng = np.random.default_rng(0)
>>> depth = 500 + rng.normal(0, 0.2, (3, 24, 32))
>>> out = run_baseline("adjbf", depth, np.full((3, 24, 32), 0.5), K)
>>> bool(np.std(out) < np.std(depth))
True
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._params import coerce_kwargs
from ..camera import Intrinsics
from ..errors import ParameterError
from ._common import estimate_noise_sigma
from .bilateral import adaptive_bilateral, adaptive_gaussian, adaptive_joint_bilateral, dnbf
from .ed import embedded_deformation
from .guided import guided
from .realsense import have_pyrealsense2, realsense_chain
from .rigid import kinectfusion
from .stmf import spatio_temporal_median
from .temporal import temporal_average, temporal_mean

__all__ = [
    "BaselineInfo",
    "adaptive_bilateral",
    "adaptive_gaussian",
    "adaptive_joint_bilateral",
    "available_baselines",
    "dnbf",
    "embedded_deformation",
    "estimate_noise_sigma",
    "get_baseline",
    "guided",
    "kinectfusion",
    "realsense_chain",
    "run_baseline",
    "spatio_temporal_median",
    "temporal_average",
    "temporal_mean",
]


@dataclass(frozen=True)
class BaselineInfo:
    """Registry entry of one comparison method.

    Attributes
    ----------
    name : str
        Registry / CLI name.
    function : callable
        ``function(depth, intensity, intrinsics, *, size, iterations, **params)``.
    description : str
        One line (paper, what it does).
    returns_points : bool
        True for the 6D methods (output (T, H, W, 3) points in mm).
    needs : str or None
        Optional extra whose package the method requires ("6d", "realsense"), or None.
    default_size, default_iterations : float, int
        The defaults of the two sweep knobs.
    size_sweep, iterations_sweep : tuple
        Sweep lists (BASELINES.md / EVALUATION.md E3).
    size_name : str
        The real name of ``size`` for this method (table in the module docstring); accepted
        by :func:`run_baseline` in place of ``size``.
    size_meaning : str
        What ``size`` is for this method, with its unit.
    reference : str
        Citation.
    """

    name: str
    function: Callable[..., NDArray[np.float32]]
    description: str
    returns_points: bool = False
    needs: str | None = None
    default_size: float = 1
    default_iterations: int = 1
    size_sweep: tuple[float, ...] = ()
    iterations_sweep: tuple[int, ...] = (1, 2, 3, 4, 5)
    size_name: str = "size"
    size_meaning: str = ""
    reference: str = ""
    fills_holes: bool = False
    _available: Callable[[], bool] = field(default=lambda: True, repr=False, compare=False)

    @property
    def available(self) -> bool:
        """True when the optional package this method needs is importable."""
        return self._available()

    def knobs(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """Keyword arguments for :attr:`function` from ``params`` (typed or strings).

        ``size_name`` is renamed to ``size``; strings are converted to the annotated types
        (:func:`fuse4d._params.coerce_kwargs`); values are validated by the method itself.

        Parameters
        ----------
        params : Mapping
            Knob name → value.

        Returns
        -------
        dict
            The keyword arguments.

        Raises
        ------
        ValueError
            For an unknown knob (the message lists the valid ones), ``size`` given twice, or a
            string that cannot be read as the knob's type.
        """
        values = dict(params)
        if self.size_name != "size" and self.size_name in values:
            if "size" in values:
                raise ParameterError(
                    f"baseline {self.name!r}: give size or {self.size_name}, not both"
                )
            values["size"] = values.pop(self.size_name)
        owner = f"baseline {self.name!r}"
        size = {"size": values.pop("size")} if "size" in values else {}
        kwargs = coerce_kwargs(self.function, values, owner=owner)
        try:  # the size knob apart: only its error says which quantity size is
            kwargs.update(coerce_kwargs(self.function, size, owner=owner))
        except ValueError as exc:
            if self.size_name == "size":
                raise
            raise ParameterError(f"{exc} (size = {self.size_name})") from None
        return kwargs


_REGISTRY: dict[str, BaselineInfo] = {
    info.name: info
    for info in (
        BaselineInfo(
            "adgf",
            adaptive_gaussian,
            "Ad-GF: adaptive Gaussian from the Kinect noise model (normal-angle sigmas)",
            default_size=1.0,
            size_sweep=(1, 1.5, 2, 3, 4, 6),
            size_name="kernel_scale",
            size_meaning="kernel scale s, unitless (sigma_s = s * sigma_L(theta) px)",
            reference="Nguyen, Izadi, Lovell, 3DIMPVT 2012",
        ),
        BaselineInfo(
            "adbf",
            adaptive_bilateral,
            "Ad-BF: region-growing hole repair + depth-adaptive bilateral filter",
            default_size=4,
            size_sweep=(1, 2, 3, 4, 6, 8, 12),
            size_name="spatial_radius",
            size_meaning="pixel radius r of the disc window, px (sigma_s = r/2)",
            reference="Chen, Lin, Li, ICPR 2012",
            fills_holes=True,
        ),
        BaselineInfo(
            "guided",
            guided,
            "Guided filter of depth with the intensity guide (cv2.ximgproc.guidedFilter)",
            default_size=4,
            size_sweep=(2, 4, 8, 12, 16),
            size_name="spatial_radius",
            size_meaning="pixel radius r of the (2r+1)^2 box, px",
            reference="He, Sun, Tang, TPAMI 2013",
        ),
        BaselineInfo(
            "dnbf",
            dnbf,
            "DNBF: causal spatio-temporal bilateral, divisively normalised depth range",
            default_size=3,
            size_sweep=(1, 2, 3, 4, 6, 8, 12),
            size_name="spatial_radius",
            size_meaning="pixel radius r of the disc window, px (sigma_s = 2r/3)",
            reference="Fu, Wang, Lu, Li, Zeng, ISCAS 2012",
        ),
        BaselineInfo(
            "ta",
            temporal_average,
            "TA: causal per-pixel temporal average with a depth-range constraint",
            default_size=5,
            size_sweep=(2, 3, 4, 5, 6, 7, 8, 9),
            size_name="num_frames",
            size_meaning="frames N in the causal window [t-N+1, t]",
            reference="Wasza, Bauer, Hornegger, ICCV Workshops 2011",
        ),
        BaselineInfo(
            "adjbf",
            adaptive_joint_bilateral,
            "Ad-JBF: joint bilateral (intensity + depth-adaptive range kernel)",
            default_size=4,
            size_sweep=(1, 2, 3, 4, 6, 8, 12),
            size_name="spatial_radius",
            size_meaning="pixel radius r of the disc window, px (sigma_s = r/2)",
            reference="Camplani, Mantecon, Salgado, IEEE T-Cybernetics 2013",
        ),
        BaselineInfo(
            "stmf",
            spatio_temporal_median,
            "ST-MF: block-matching motion-compensated spatio-temporal median (non-causal)",
            default_size=2,
            size_sweep=(1, 2, 3, 4),
            iterations_sweep=(1, 2, 3),
            size_name="temporal_radius",
            size_meaning="temporal radius k, frames (2k+1 frames, truncated at the ends)",
            reference="Matyunin, Vatolin, Berdnikov, Smirnov, 3DTV-CON 2011",
            fills_holes=True,
        ),
        BaselineInfo(
            "kinectfusion",
            kinectfusion,
            "6D rigid: ICP (Open3D when installed) + projective TSDF ray cast (numba) of "
            "9 frames; Open3D's volume opt-in with backend='open3d'",
            returns_points=True,
            default_size=4,
            size_sweep=(1, 2, 3, 4),
            iterations_sweep=(1, 2, 3),
            size_name="temporal_radius",
            size_meaning="temporal radius k, frames (2k+1 frames, truncated at the ends)",
            reference="Newcombe et al., ISMAR 2011 / Izadi et al., UIST 2011",
            fills_holes=True,
        ),
        BaselineInfo(
            "ed",
            embedded_deformation,
            "6D non-rigid: embedded-deformation warps + fusion of 9 frames",
            returns_points=True,
            default_size=4,
            size_sweep=(1, 2, 3, 4),
            iterations_sweep=(1, 2, 3),
            size_name="temporal_radius",
            size_meaning="temporal radius k, frames (2k+1 frames, truncated at the ends)",
            reference="Dou, Taylor, Fuchs, Fitzgibbon, Izadi, CVPR 2015; Sumner et al. 2007",
            fills_holes=True,
        ),
        BaselineInfo(
            "temporal-mean",
            temporal_mean,
            "Plain per-pixel mean over a centred window (no motion compensation)",
            default_size=9,
            size_sweep=(2, 3, 4, 5, 6, 7, 8, 9),
            size_name="num_frames",
            size_meaning="frames n in the centred window",
            reference="reference practice",
        ),
        BaselineInfo(
            "realsense",
            realsense_chain,
            "RealSense SDK chain: spatial + temporal + hole filling (pyrealsense2)",
            needs="realsense",
            default_size=2,
            size_sweep=(1, 2, 3, 4, 5),
            iterations_sweep=(1, 2, 3),
            size_name="filter_passes",
            size_meaning="passes of the spatial filter (RealSense filter_magnitude, 1..5)",
            reference="Intel RealSense SDK 2.0 post-processing filters",
            fills_holes=True,
            _available=have_pyrealsense2,
        ),
    )
}


def available_baselines() -> dict[str, BaselineInfo]:
    """All registered baselines by name (including those whose optional package is absent).

    Returns
    -------
    dict of str to BaselineInfo
        In the order of BASELINES.md, then the two references.
    """
    return dict(_REGISTRY)


def get_baseline(name: str) -> BaselineInfo:
    """The registry entry ``name``; ``ValueError`` listing the valid names otherwise."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ParameterError(
            f"unknown baseline {name!r}; choose one of: {', '.join(_REGISTRY)}"
        ) from None


def run_baseline(
    name: str,
    depth: ArrayLike,
    intensity: ArrayLike | None,
    intrinsics: Intrinsics,
    **params: Any,
) -> NDArray[np.float32]:
    """Run the baseline ``name`` (see :func:`available_baselines`).

    Parameters
    ----------
    name : str
        Registry name, e.g. ``"adjbf"``.
    depth : (T, H, W) ndarray
        Depth in mm, NaN = invalid.
    intensity : (T, H, W) ndarray or None
        Intensity in [0, 1] (None only for methods that do not use it).
    intrinsics : Intrinsics
        Camera.
    **params
        ``size`` (or its real name ``info.size_name``, e.g. ``spatial_radius``),
        ``iterations`` and method-specific knobs (``noise_sigma`` etc.); strings are
        converted to the knobs' types.

    Returns
    -------
    ndarray of float32
        (T, H, W) depth in mm, or (T, H, W, 3) points in mm when ``returns_points``.

    Raises
    ------
    ValueError
        Unknown name or bad parameters.
    ImportError
        When the optional package of the method is missing.
    """
    info = get_baseline(name)
    return info.function(depth, intensity, intrinsics, **info.knobs(params))
