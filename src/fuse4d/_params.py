"""One parameter layer: typed, validated values for fuse4d's frozen parameter dataclasses.

Every parameter object (``FusionParams``, the flow methods' ``DISParams`` / ``PMBPParams`` / ...)
is a frozen dataclass, and the baselines take keyword arguments. Values reach them from three
places: Python (typed already), TOML files (typed, but ``"inf"`` is a string there) and the
command line (``--set k=v``, ``--flow-param k=v``, ``fuse4d flow -p``, ``fuse4d baseline -p``:
always strings, split by :func:`parse_assignments`).

Coercion (strings → field types) is one function for every path: :func:`coerce_fields` for a
dataclass and :func:`coerce_kwargs` for a function's keywords, both reading the annotations
(``int``, ``float``, ``bool``, ``str``, ``Literal[...]``, ``X | None``, ``tuple[X, ...]``)
through :func:`coerce_value`.

Validation is one function too: a field declares its range with :func:`param` (``x: float =
param(1.0, gt=0)``) and ``__post_init__`` calls :func:`validate`, which checks every field
against its annotation and bounds and normalises it (numpy scalars → Python, int → float in
float fields). Cross-field rules stay explicit in the class. Keyword knobs (the baselines) use
the same checkers directly: :func:`check_int`, :func:`check_number`, :func:`check_bool`,
:func:`check_choice`. Every message reads ``Owner.field must be <bound>, got <value>``, so a bad
value gives the same message whichever way it came in.

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

import dataclasses
import functools
import inspect
import math
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import fields, is_dataclass
from typing import Any, Literal

import numpy as np

from .errors import ParameterError, ParameterTypeError

__all__ = [
    "check_bool",
    "check_choice",
    "check_int",
    "check_number",
    "check_value",
    "coerce_fields",
    "coerce_kwargs",
    "coerce_value",
    "param",
    "parse_assignments",
    "validate",
]

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}
_NONE = {"none", "null", ""}
_KIND = {int: "integers", float: "numbers", bool: "booleans", str: "strings"}
_INF = {"inf", "+inf", "infinity", "+infinity"}


def parse_assignments(items: Iterable[str] | None, *, what: str = "parameter") -> dict[str, str]:
    """Split command-line ``KEY=VALUE`` items into a mapping (values stay strings).

    Parameters
    ----------
    items : iterable of str or None
        E.g. ``["num_iter=3", "schedule=lines"]``; a later key overrides an earlier one.
    what : str
        The option's name for the error message (``"--set"``).

    Returns
    -------
    dict of str to str
        Key → value, both stripped.

    Raises
    ------
    ValueError
        For an item without ``=`` or with an empty key.
    """
    out: dict[str, str] = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ParameterError(f"{what} must look like KEY=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


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
        raise ParameterTypeError(f"coerce_fields needs a dataclass type, got {cls!r}")
    who = owner or cls.__name__
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    unknown = sorted(set(mapping) - set(names))
    if unknown:
        valid = ", ".join([*names, *extra_keys]) or "(none)"
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)} for {who}; valid: {valid}")
    return {key: coerce_value(key, value, hints[key]) for key, value in mapping.items()}


def coerce_kwargs(
    function: Callable[..., Any], mapping: Mapping[str, Any], *, owner: str | None = None
) -> dict[str, Any]:
    """Convert a mapping of keyword arguments to the annotated types of ``function``'s keywords.

    The function counterpart of :func:`coerce_fields`, for knobs that are keyword arguments
    (the baselines): ``coerce_kwargs(guided, {"size": "8", "eps": "0.01"})``.

    Parameters
    ----------
    function : callable
        A function with annotated keyword(-only) parameters.
    mapping : Mapping
        Name → value (strings are parsed as in :func:`coerce_value`).
    owner : str, optional
        How to name ``function`` in error messages (default: its ``__name__``).

    Returns
    -------
    dict
        The converted values (a new dict).

    Raises
    ------
    ValueError
        For an unknown keyword (the message lists the valid ones) or an unreadable value.
    """
    who = owner or getattr(function, "__name__", repr(function))
    hints = typing.get_type_hints(function)
    names = [
        p.name
        for p in inspect.signature(function).parameters.values()
        if p.kind is inspect.Parameter.KEYWORD_ONLY
    ]
    unknown = sorted(set(mapping) - set(names))
    if unknown:
        valid = ", ".join(names) or "(none)"
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)} for {who}; valid: {valid}")
    return {key: coerce_value(key, value, hints.get(key, Any)) for key, value in mapping.items()}


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
        raise ParameterError(
            errors[0] if len(errors) == 1 else f"parameter {name}: bad value {value!r}"
        )
    if origin is Literal:
        text = value.strip() if isinstance(value, str) else value
        if text not in args:
            choices = ", ".join(map(str, args))
            raise ParameterError(f"parameter {name}: {value!r} is not one of {choices}")
        return text
    if origin is tuple:
        items = value
        if isinstance(value, str):
            items = [v for v in value.replace(";", ",").split(",") if v.strip()]
        if not isinstance(items, list | tuple):
            raise ParameterError(f"parameter {name}: expected a list of values, got {value!r}")
        item_hint = args[0] if args else Any
        return tuple(coerce_value(name, v, item_hint) for v in items)
    if hint is bool:
        return _to_bool(name, value)
    if hint is int:
        return _to_int(name, value)
    if hint is float:
        return _to_float(name, value)
    if hint is str and not isinstance(value, str):
        raise ParameterError(f"parameter {name}: expected text, got {value!r}")
    return value.strip() if isinstance(value, str) else value


def _to_bool(name: str, value: Any) -> Any:
    if isinstance(value, str):
        lowered = value.strip().lower()
        if lowered in _TRUE:
            return True
        if lowered in _FALSE:
            return False
        raise ParameterError(f"parameter {name}: cannot read {value!r} as true/false")
    return value


def _to_int(name: str, value: Any) -> Any:
    if isinstance(value, str):
        try:
            return int(value.strip())
        except ValueError:
            raise ParameterError(f"parameter {name}: cannot read {value!r} as an integer") from None
    return value


def _to_float(name: str, value: Any) -> Any:
    if isinstance(value, str):
        text = value.strip().lower()
        if text in _INF:
            return math.inf
        try:
            return float(text)
        except ValueError:
            raise ParameterError(f"parameter {name}: cannot read {value!r} as a number") from None
    if isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


# ----------------------------------------------------------------------------- validators
def param(
    default: Any = dataclasses.MISSING,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    finite: bool | None = None,
) -> Any:
    """A dataclass field whose range :func:`validate` checks (bounds in the field's units).

    Parameters
    ----------
    default : Any
        The field's default value.
    ge, gt, le, lt : float, optional
        Inclusive (``ge``, ``le``) or strict (``gt``, ``lt``) bounds; integer fields take
        ``ge``/``le`` only.
    finite : bool, optional
        Reject ``inf`` for a float field (default: the ``finite`` argument of :func:`validate`).

    Returns
    -------
    dataclasses.Field
        ``field(default=default, metadata={...})``.
    """
    bounds = {"ge": ge, "gt": gt, "le": le, "lt": lt, "finite": finite}
    return dataclasses.field(
        default=default, metadata={k: v for k, v in bounds.items() if v is not None}
    )


def validate(obj: Any, *, finite: bool = False) -> None:
    """Check every field of the frozen dataclass ``obj`` against its type and bounds.

    Types come from the annotations (``int``, ``float``, ``bool``, ``str``, ``Literal[...]``,
    ``X | None``, ``tuple[...]``; other types are not checked), bounds from :func:`param`
    metadata (looked up along the class hierarchy, so a subclass may re-declare a field to
    change its default only). Values are normalised in place: numpy scalars become Python
    scalars, ints in float fields become floats, lists in tuple fields become tuples.

    Parameters
    ----------
    obj : dataclass instance
        Usually ``self`` in ``__post_init__``.
    finite : bool
        Default for float fields without their own ``finite`` (True: reject ``inf``).

    Raises
    ------
    ValueError
        A value out of range, not an integer (int fields) or not an allowed choice; the
        message names ``Class.field``, the bound and the bad value.
    TypeError
        A non-number in a float field, a non-bool in a bool field, a non-string in a str field.
    """
    cls = type(obj)
    for name, check in _field_checkers(cls, finite):
        value = getattr(obj, name)
        checked = check(value)
        if checked is not value:
            object.__setattr__(obj, name, checked)


@functools.cache
def _field_checkers(cls: type, finite: bool) -> tuple[tuple[str, Callable[[Any], Any]], ...]:
    """(name, value -> checked value) per field of ``cls``; bounds looked up along the MRO."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in fields(cls):
        bounds: Mapping[str, Any] = {}
        for klass in cls.__mro__:
            spec = getattr(klass, "__dataclass_fields__", {}).get(f.name)
            if spec is not None and spec.metadata:
                bounds = spec.metadata
                break
        hint = hints[f.name]
        kwargs = {"finite": finite, **bounds}
        if hint is float:  # the common case, without the annotation dispatch
            check = functools.partial(check_number, cls.__name__, f.name, **kwargs)
        elif hint is int:
            check = functools.partial(
                check_int, cls.__name__, f.name, minimum=bounds.get("ge"), maximum=bounds.get("le")
            )
        else:
            check = functools.partial(_check_hinted, cls.__name__, f.name, hint, kwargs)
        out.append((f.name, check))
    return tuple(out)


def _check_hinted(owner: str, name: str, hint: Any, bounds: Mapping[str, Any], value: Any) -> Any:
    return check_value(owner, name, value, hint, **bounds)


def check_value(owner: str, name: str, value: Any, hint: Any, **bounds: Any) -> Any:
    """Check one value against a type annotation and bounds; return it normalised.

    Parameters
    ----------
    owner, name : str
        Class and field name for the message (``owner.name must be ...``).
    value : Any
        The value.
    hint : type annotation
        As in :func:`validate`.
    **bounds
        ``ge``, ``gt``, ``le``, ``lt``, ``finite`` as in :func:`param`.

    Returns
    -------
    Any
        The value (Python scalar, float for float fields, tuple for tuple fields).
    """
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            try:
                return check_value(owner, name, value, inner[0], **bounds)
            except (TypeError, ValueError) as exc:
                if type(None) not in args:
                    raise
                text = str(exc).replace(" must be ", " must be None or ", 1)
                raise type(exc)(text) from None
        return value
    if origin is Literal:
        return check_choice(owner, name, value, args)
    if origin is tuple:
        fixed = bool(args) and not (len(args) == 2 and args[1] is Ellipsis)
        kinds = {_KIND.get(a, "values") for a in (args if fixed else args[:1])}
        what = kinds.pop() if len(kinds) == 1 else "values"
        message = f"{owner}.{name} must be a tuple of {len(args) if fixed else ''}"
        message = f"{message} {what}, got {value!r}".replace("of  ", "of ")
        if not isinstance(value, tuple | list) or (fixed and len(value) != len(args)):
            raise ParameterError(message)
        items = args if fixed else (args[:1] or (Any,)) * len(value)
        try:
            return tuple(check_value(owner, name, v, h) for v, h in zip(value, items, strict=True))
        except (TypeError, ValueError):
            raise ParameterError(message) from None
    if hint is bool:
        return check_bool(owner, name, value)
    if hint is int:
        return check_int(owner, name, value, minimum=bounds.get("ge"), maximum=bounds.get("le"))
    if hint is float:
        return check_number(owner, name, value, **bounds)
    if hint is str and not isinstance(value, str):
        raise ParameterTypeError(f"{owner}.{name} must be text, got {value!r}")
    return value


def check_int(
    owner: str, name: str, value: Any, *, minimum: int | None = 0, maximum: int | None = None
) -> int:
    """Return ``value`` as int; ``ValueError`` unless it is an integer (not bool) in range.

    Parameters
    ----------
    owner, name : str
        For the message ``owner.name must be an integer >= minimum, got value``.
    value : Any
        The value.
    minimum, maximum : int or None
        Inclusive bounds (None: unbounded).

    Returns
    -------
    int
        The value.
    """
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool)
    ok = ok and (minimum is None or value >= minimum) and (maximum is None or value <= maximum)
    if not ok:
        raise ParameterError(
            f"{owner}.{name} must be an integer"
            f"{_range(minimum, maximum, '[', ']', integer=True)}, got {value!r}"
        )
    return int(value)


def check_number(
    owner: str,
    name: str,
    value: Any,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    finite: bool = False,
) -> float:
    """Return ``value`` as float; raise unless it is a real number (not NaN) within bounds.

    Parameters
    ----------
    owner, name : str
        For the message ``owner.name must be a [finite] number > 0, got value``.
    value : Any
        The value.
    ge, gt, le, lt : float, optional
        Inclusive or strict bounds.
    finite : bool
        Reject ``inf``.

    Returns
    -------
    float
        The value.

    Raises
    ------
    TypeError
        For a non-number (bools included).
    ValueError
        For NaN, a value out of range or (``finite``) an infinite one.
    """
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ParameterTypeError(f"{owner}.{name} must be a number, got {value!r}")
    x = float(value)
    ok = not math.isnan(x) and not (finite and math.isinf(x))
    ok = ok and (ge is None or x >= ge) and (gt is None or x > gt)
    ok = ok and (le is None or x <= le) and (lt is None or x < lt)
    if not ok:
        lo, lo_open = (gt, True) if gt is not None else (ge, False)
        hi, hi_open = (lt, True) if lt is not None else (le, False)
        text = _range(lo, hi, "(" if lo_open else "[", ")" if hi_open else "]", lo_open, hi_open)
        kind = "a finite number" if finite else "a number"
        raise ParameterError(f"{owner}.{name} must be {kind}{text}, got {value!r}")
    return x


def _range(
    lo: float | None,
    hi: float | None,
    left: str,
    right: str,
    lo_open: bool = False,
    hi_open: bool = False,
    *,
    integer: bool = False,
) -> str:
    """The bounds' text for a message; ``integer`` (an int field's) prints them exactly, where
    ``:g`` would round 2**63 - 1 to 9.22337e+18."""

    def text(bound: float) -> str:
        return str(int(bound)) if integer else f"{bound:g}"

    if lo is not None and hi is not None:
        return f" in {left}{text(lo)}, {text(hi)}{right}"
    if lo is not None:
        return f" {'>' if lo_open else '>='} {text(lo)}"
    if hi is not None:
        return f" {'<' if hi_open else '<='} {text(hi)}"
    return ""


def check_bool(owner: str, name: str, value: Any) -> bool:
    """Return ``value`` as bool; ``TypeError`` unless it is a bool (or numpy bool)."""
    if not isinstance(value, bool | np.bool_):
        raise ParameterTypeError(f"{owner}.{name} must be True or False, got {value!r}")
    return bool(value)


def check_choice(owner: str, name: str, value: Any, options: Iterable[Any]) -> Any:
    """Return ``value``; ``ValueError`` unless it is one of ``options``."""
    options = tuple(options)
    if value not in options:
        raise ParameterError(
            f"{owner}.{name} must be one of {', '.join(map(repr, options))}, got {value!r}"
        )
    return value
