"""One parameter layer: typed values for fuse4d's frozen parameter dataclasses.

Every parameter object (``FusionParams``, the flow methods' ``DISParams`` / ``PMBPParams`` / ...,
the baselines' knobs) is a frozen dataclass. Values reach them from three places: Python (typed
already), TOML files (typed, but ``"inf"`` is a string there) and the command line (``--set
k=v``, ``--flow-param k=v``: always strings). :func:`coerce_fields` converts such a mapping
to the field types of a dataclass, reading the annotations (``int``, ``float``, ``bool``,
``str``, ``Literal[...]``, ``X | None``, ``tuple[X, ...]``); the dataclass's own
``__post_init__`` then validates ranges with the small checkers below (:func:`check_int`,
:func:`check_number`, :func:`check_bool`, :func:`check_choice`), so a bad value gives the same
message whichever way it came in.

Examples
--------
>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Knobs:
...     radius: int | None = None
...     sigma: float = 1.0
...     mode: str = "a"
>>> coerce_fields(Knobs, {"radius": "3", "sigma": "inf"})
{'radius': 3, 'sigma': inf}
>>> coerce_fields(Knobs, {"radius": "none"})
{'radius': None}
"""

from __future__ import annotations

import math
import types
import typing
from collections.abc import Iterable, Mapping
from dataclasses import fields, is_dataclass
from typing import Any, Literal

import numpy as np

__all__ = [
    "check_bool",
    "check_choice",
    "check_int",
    "check_number",
    "coerce_fields",
    "coerce_value",
]

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}
_NONE = {"none", "null", ""}
_INF = {"inf", "+inf", "infinity", "+infinity"}


def coerce_fields(
    cls: type,
    mapping: Mapping[str, Any],
    *,
    owner: str | None = None,
    extra_keys: Iterable[str] = (),
) -> dict[str, Any]:
    """Convert a mapping of field values to the annotated types of dataclass ``cls``.

    Parameters
    ----------
    cls : type
        A dataclass type.
    mapping : Mapping
        Field name → value; strings (command line) are parsed, typed values (Python, TOML) pass
        through except the TOML spellings ``"inf"`` of a float and ``"none"`` of an optional.
    owner : str, optional
        How to name ``cls`` in error messages (default: its class name).
    extra_keys : iterable of str
        Keys the caller handles itself (listed as valid in the unknown-key error).

    Returns
    -------
    dict
        The converted values (a new dict).

    Raises
    ------
    ValueError
        For an unknown key (the message lists the valid ones) or a value that cannot be read
        as the field's type.
    """
    if not (isinstance(cls, type) and is_dataclass(cls)):
        raise TypeError(f"coerce_fields needs a dataclass type, got {cls!r}")
    who = owner or cls.__name__
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    unknown = sorted(set(mapping) - set(names))
    if unknown:
        valid = ", ".join([*names, *extra_keys]) or "(none)"
        raise ValueError(f"unknown parameter(s) {', '.join(unknown)} for {who}; valid: {valid}")
    return {key: coerce_value(key, value, hints[key]) for key, value in mapping.items()}


def coerce_value(name: str, value: Any, hint: Any) -> Any:
    """Convert one value to the type annotation ``hint`` (see :func:`coerce_fields`).

    Parameters
    ----------
    name : str
        Field name (for the error message).
    value : Any
        The value; strings are parsed.
    hint : type annotation
        ``int``, ``float``, ``bool``, ``str``, ``Literal[...]``, ``X | None``, ``tuple[X, ...]``
        or any other type (then the value passes through unchanged).

    Returns
    -------
    Any
        The converted value.
    """
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        is_none = value is None or (isinstance(value, str) and value.strip().lower() in _NONE)
        if is_none and len(inner) < len(args):
            return None
        errors = []
        for option in inner:
            try:
                return coerce_value(name, value, option)
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError(
            errors[0] if len(errors) == 1 else f"parameter {name}: bad value {value!r}"
        )
    if origin is Literal:
        text = value.strip() if isinstance(value, str) else value
        if text not in args:
            choices = ", ".join(map(str, args))
            raise ValueError(f"parameter {name}: {value!r} is not one of {choices}")
        return text
    if origin is tuple:
        items = value
        if isinstance(value, str):
            items = [v for v in value.replace(";", ",").split(",") if v.strip()]
        if not isinstance(items, list | tuple):
            raise ValueError(f"parameter {name}: expected a list of values, got {value!r}")
        item_hint = args[0] if args else Any
        return tuple(coerce_value(name, v, item_hint) for v in items)
    if hint is bool:
        return _to_bool(name, value)
    if hint is int:
        return _to_int(name, value)
    if hint is float:
        return _to_float(name, value)
    if hint is str and not isinstance(value, str):
        raise ValueError(f"parameter {name}: expected text, got {value!r}")
    return value.strip() if isinstance(value, str) else value


def _to_bool(name: str, value: Any) -> Any:
    if isinstance(value, str):
        lowered = value.strip().lower()
        if lowered in _TRUE:
            return True
        if lowered in _FALSE:
            return False
        raise ValueError(f"parameter {name}: cannot read {value!r} as true/false")
    return value


def _to_int(name: str, value: Any) -> Any:
    if isinstance(value, str):
        try:
            return int(value.strip())
        except ValueError:
            raise ValueError(f"parameter {name}: cannot read {value!r} as an integer") from None
    return value


def _to_float(name: str, value: Any) -> Any:
    if isinstance(value, str):
        text = value.strip().lower()
        if text in _INF:
            return math.inf
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"parameter {name}: cannot read {value!r} as a number") from None
    if isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


# ----------------------------------------------------------------------------- validators
def check_int(owner: str, name: str, value: Any, *, minimum: int = 0) -> None:
    """Raise ``ValueError`` unless ``value`` is an integer (not bool) >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"{owner}.{name} must be an integer >= {minimum}, got {value!r}")


def check_number(
    owner: str,
    name: str,
    value: Any,
    *,
    minimum: float = 0.0,
    strict: bool = True,
    allow_inf: bool = True,
) -> float:
    """Validate a real number > ``minimum`` (``>=`` when not ``strict``); returns it as float.

    Raises ``TypeError`` for a non-number and ``ValueError`` for one out of range (or infinite
    when ``allow_inf`` is False).
    """
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise TypeError(f"{owner}.{name} must be a number, got {value!r}")
    x = float(value)
    ok = (x > minimum if strict else x >= minimum) and not math.isnan(x)
    if not allow_inf and math.isinf(x):
        ok = False
    if not ok:
        op = ">" if strict else ">="
        finite = "finite number" if not allow_inf else "number"
        raise ValueError(f"{owner}.{name} must be a {finite} {op} {minimum}, got {value!r}")
    return x


def check_bool(owner: str, name: str, value: Any) -> None:
    """Raise ``TypeError`` unless ``value`` is a bool."""
    if not isinstance(value, bool | np.bool_):
        raise TypeError(f"{owner}.{name} must be true or false, got {value!r}")


def check_choice(owner: str, name: str, value: Any, options: Iterable[Any]) -> None:
    """Raise ``ValueError`` unless ``value`` is one of ``options``."""
    options = tuple(options)
    if value not in options:
        raise ValueError(
            f"{owner}.{name} must be one of {', '.join(map(repr, options))}, got {value!r}"
        )
