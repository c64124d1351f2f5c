"""The flow-method registry: the :data:`FlowFunction` protocol, :class:`FlowMethod`, lookup by
name, and parameter objects built from mappings (config files, ``--flow-param k=v``).

This module imports nothing else of :mod:`fuse4d.flow`, so the method modules
(:mod:`fuse4d.flow.opencv`, :mod:`fuse4d.flow.pmbp`) import it without a cycle; the package
``__init__`` registers the built-in methods.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, is_dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._params import coerce_fields
from ..errors import ParameterError, ParameterTypeError

__all__ = [
    "FlowFunction",
    "FlowMethod",
    "FlowPairFunction",
    "Roi",
    "available_flow_methods",
    "flow_params_from_mapping",
    "get_flow_method",
    "register_flow_method",
    "resolve_flow_params",
]

#: ``(image0, image1, params, init) -> flow``: image0/image1 float32 ``(H, W)`` in [0, 1],
#: ``params`` the method's frozen dataclass, ``init`` an optional float32 ``(H, W, 2)`` initial
#: flow (px); returns float32 ``(H, W, 2)`` flow from image0 to image1 (px, du then dv).
#: Inputs are validated by :func:`estimate_flow` before the function is called.
FlowFunction = Callable[
    [NDArray[np.float32], NDArray[np.float32], Any, NDArray[np.float32] | None],
    NDArray[np.float32],
]

#: ``(image0, image1, params, init) -> (forward, backward)``: both directions of one pair at
#: once, for methods that share work between them (PMBP's consistency check solves the
#: opposite direction anyway). ``init`` warm-starts the forward solve.
FlowPairFunction = Callable[
    [NDArray[np.float32], NDArray[np.float32], Any, NDArray[np.float32] | None],
    tuple[NDArray[np.float32], NDArray[np.float32]],
]

#: Region of interest ``(row0, row1, col0, col1)``, half-open, in px.
Roi = tuple[int, int, int, int]


@dataclass(frozen=True)
class FlowMethod:
    """A registered optical-flow method.

    Parameters
    ----------
    name : str
        Registry name (``"dis"``, ``"pmbp"``, ...), used by the API, the CLI and config files.
    function : FlowFunction
        ``(image0, image1, params, init) -> flow``; see :data:`FlowFunction`.
    params_type : type
        Frozen dataclass of the method's parameters; ``params_type()`` gives the defaults.
    description : str
        One line for ``--help`` and benchmark tables.
    supports_init : bool
        Whether ``function`` uses ``init`` (warm starts, METHOD §2.3). If False, ``init`` is
        never passed (``None``).
    paper_method : bool
        True only for the paper's tracker (PMBP); results of other methods must say so.
    pair_function : FlowPairFunction, optional
        Both directions of a pair in one call (used by :func:`estimate_flow_pair` when given);
        None = ``function`` forward, then backward warm-started with ``-forward``.
    """

    name: str
    function: FlowFunction
    params_type: type
    description: str
    supports_init: bool
    paper_method: bool
    pair_function: FlowPairFunction | None = None

    def __post_init__(self) -> None:
        if not self.name or self.name != self.name.strip().lower() or " " in self.name:
            raise ParameterError(
                f"flow method name must be lower-case without spaces: {self.name!r}"
            )
        if not callable(self.function):
            raise ParameterTypeError(f"flow method {self.name!r}: function must be callable")
        if not (isinstance(self.params_type, type) and is_dataclass(self.params_type)):
            raise ParameterTypeError(
                f"flow method {self.name!r}: params_type must be a dataclass type"
            )


_REGISTRY: dict[str, FlowMethod] = {}


def register_flow_method(method: FlowMethod, *, replace: bool = False) -> None:
    """Add ``method`` to the registry under ``method.name``.

    Registering the same object twice is a no-op; a *different* method under an existing name
    raises ``ValueError`` unless ``replace=True``.
    """
    if not isinstance(method, FlowMethod):
        raise ParameterTypeError(f"expected a FlowMethod, got {type(method).__name__}")
    existing = _REGISTRY.get(method.name)
    if existing is not None and existing != method and not replace:
        raise ParameterError(
            f"a flow method named {method.name!r} is already registered; pass replace=True"
        )
    _REGISTRY[method.name] = method


def available_flow_methods() -> dict[str, FlowMethod]:
    """All registered methods by name (a copy, in registration order)."""
    return dict(_REGISTRY)


def get_flow_method(name: str | FlowMethod) -> FlowMethod:
    """Look a method up by name; the error lists the registered names."""
    if isinstance(name, FlowMethod):
        return name
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        names = ", ".join(sorted(_REGISTRY))
        raise ParameterError(f"unknown flow method {name!r}; available methods: {names}") from None


def resolve_flow_params(method: str | FlowMethod, params: Any = None) -> Any:
    """The parameter object for ``method``.

    ``None`` → the method's defaults; a mapping → :func:`flow_params_from_mapping`; an instance
    of ``method.params_type`` → itself. Anything else raises ``TypeError``.
    """
    m = get_flow_method(method)
    if params is None:
        return m.params_type()
    if isinstance(params, m.params_type):
        return params
    if isinstance(params, Mapping):
        return flow_params_from_mapping(m, params)
    raise ParameterTypeError(
        f"params for flow method {m.name!r} must be a {m.params_type.__name__} "
        f"(or a mapping of its fields), got {type(params).__name__}"
    )


def flow_params_from_mapping(method: str | FlowMethod, mapping: Mapping[str, Any]) -> Any:
    """Build ``method``'s parameter dataclass from a mapping (config file, ``--param k=v``).

    String values are converted to the field's type (``"3"`` → 3, ``"true"`` → True). The key
    ``"preset"`` selects a starting point for parameter types that have ``from_preset`` (DIS:
    ``ultrafast``/``fast``/``medium``); the other keys override it. Unknown keys raise
    ``ValueError`` listing the valid ones.
    """
    m = get_flow_method(method)
    ptype = m.params_type
    values = dict(mapping)
    preset = values.pop("preset", None)
    extra = ("preset",) if hasattr(ptype, "from_preset") else ()
    converted = coerce_fields(ptype, values, owner=f"flow method {m.name!r}", extra_keys=extra)
    if preset is not None:
        if not hasattr(ptype, "from_preset"):
            raise ParameterError(f"flow method {m.name!r} has no presets")
        return ptype.from_preset(str(preset), **converted)
    return ptype(**converted)
