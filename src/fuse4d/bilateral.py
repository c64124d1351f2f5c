"""The intensity-guided 3D bilateral of one frame: the inner sum of Eq. 5 (METHOD §5.1)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels._common import gauss_factor
from ._kernels.fusion import _bilateral3d_kernel, _bilateral_planes_kernel
from ._validation import as_float32, check_output_buffer, check_shape
from .errors import ParameterError
from .sequence import as_unit_intensity

__all__ = ["bilateral_filter_points"]


def bilateral_filter_points(
    points: ArrayLike,
    intensity: ArrayLike,
    *,
    radius: int = 3,
    sigma_distance: float = 2.0,
    sigma_intensity: float = 0.1,
    reference: ArrayLike | None = None,
    out: NDArray[np.float32] | None = None,
) -> NDArray[np.float32]:
    """Intensity-guided 3D bilateral filter of one point map (inner sum of paper Eq. 5).

    ``B[c] = sum_n d(P[c], P[n]) g(I[c], I[n]) P[n] / sum_n d g`` over the (2r+1)^2 window,
    with ``d = exp(-|p - q|^2 / (2 sigma_distance^2))`` (3D distance, mm) and
    ``g = exp(-(a - b)^2 / (2 sigma_intensity^2))``. Invalid (NaN) points get no weight and
    stay NaN. The weights use exp(-x) ~ (1 - x/1024)^1024 (relative error x^2/2048: 0.05 % at
    x = 1, 0.8 % at x = 4), pure arithmetic so that the kernel vectorises.

    Parameters
    ----------
    points : (H, W, 3) ndarray
        Point map in mm (paper :math:`P^T`), NaN = invalid.
    intensity : (H, W) ndarray
        Registered intensity in [0, 1] (uint8/uint16 divided by 255/65535).
    radius : int
        Window radius r in px.
    sigma_distance : float
        :math:`\\delta_d` in mm.
    sigma_intensity : float
        :math:`\\delta_g` in intensity units.
    reference : (H, W, 3) ndarray, optional
        A smooth reference surface P~ (mm). When given, the filter averages the residuals
        ``P[n] - P~[n]`` and adds them to ``P~[c]`` (our A18): the weights are unchanged, but
        curvature is not flattened and the result stays on the centre pixel's ray.
    out : (H, W, 3) ndarray of float32, optional
        Output buffer (C-contiguous, writeable).

    Returns
    -------
    (H, W, 3) ndarray of float32
        Filtered points (mm).

    Examples
    --------
    >>> p = np.zeros((4, 4, 3), np.float32); p[..., 2] = 500
    >>> bilateral_filter_points(p, np.zeros((4, 4)))[0, 0].tolist()
    [0.0, 0.0, 500.0]
    """
    p = as_float32(points, name="points")
    check_shape(p, ("H", "W", 3), name="points")
    i = as_unit_intensity(np.asarray(intensity))
    check_shape(i, p.shape[:2], name="intensity")
    if radius < 0 or int(radius) != radius:
        raise ParameterError(f"radius must be an integer >= 0, got {radius!r}")
    if not (sigma_distance > 0 and sigma_intensity > 0):
        raise ParameterError("sigma_distance and sigma_intensity must be > 0")
    if out is None:
        out = np.empty_like(p)
    else:  # the kernels write through it: a wrong buffer corrupted memory
        check_output_buffer(out, p.shape, name="out")
    if reference is not None:
        ref = as_float32(reference, name="reference")
        check_shape(ref, p.shape, name="reference")
        scratch = np.empty((2, 3, *p.shape[:2]), np.float32)
        return _residual_bilateral(
            p, i, ref, radius, sigma_distance, sigma_intensity, scratch=scratch, out=out
        )
    # literal mean of the points, taken about a constant (float32 precision)
    planes = [np.ascontiguousarray(p[..., c]) for c in range(3)]
    finite = p[np.isfinite(p[..., 2])]
    centre = np.median(finite, axis=0) if finite.size else np.zeros(3, np.float32)
    values = [np.ascontiguousarray(p[..., c] - np.float32(centre[c])) for c in range(3)]
    return _planar_bilateral(planes, i, values, radius, sigma_distance, sigma_intensity, out)


def _residual_bilateral(
    points: NDArray[np.float32],
    intensity: NDArray[np.float32],
    reference: NDArray[np.float32],
    radius: int,
    sigma_distance: float,
    sigma_intensity: float,
    *,
    scratch: NDArray[np.float32],
    out: NDArray[np.float32],
) -> NDArray[np.float32]:
    """Unvalidated :func:`bilateral_filter_points` with a ``reference`` (A18), its planar
    inputs built in ``scratch`` (2, 3, H, W) float32: the fusion engine passes a buffer it
    keeps, because two fresh 3.7 MB arrays per 640x480 frame can cost 1800 page faults
    (2 ms) on this kind of VM, ten times the work of filling them."""
    planes, values = scratch[0], scratch[1]
    _bilateral_planes_kernel(points, reference, planes, values)
    return _planar_bilateral(
        planes, intensity, values, radius, sigma_distance, sigma_intensity, out
    )


def _planar_bilateral(
    planes: Sequence[NDArray[np.float32]],
    intensity: NDArray[np.float32],
    values: Sequence[NDArray[np.float32]],
    radius: int,
    sigma_distance: float,
    sigma_intensity: float,
    out: NDArray[np.float32],
) -> NDArray[np.float32]:
    """:func:`_bilateral3d_kernel` on the three (H, W) coordinate ``planes`` and the three
    ``values`` averaged, with the weights' exponent factors 1 / (2 sigma^2); returns ``out``."""
    _bilateral3d_kernel(
        *planes,
        intensity,
        *values,
        int(radius),
        gauss_factor(sigma_distance),
        gauss_factor(sigma_intensity),
        out,
    )
    return out
