"""Frozen typed parameter dataclasses: coercion and validation of online parameter changes."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any


class ParamError(ValueError):
    """A parameter name or value is not accepted; the message names the field."""


def _coerce(name: str, hint: Any, value: Any) -> Any:
    origin = typing.get_origin(hint)
    if hint is float:
        if isinstance(value, bool):
            raise ParamError(f"{name}: expected a number, got {value!r}")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ParamError(f"{name}: expected a number, got {value!r}") from None
        if math.isnan(number):  # NaN compares false with every bound a module checks: it would pass them all
            raise ParamError(f"{name}: expected a number, got {value!r}")
        return number
    if hint is int:
        if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
            raise ParamError(f"{name}: expected an integer, got {value!r}")
        try:
            return int(value)
        except (TypeError, ValueError):
            raise ParamError(f"{name}: expected an integer, got {value!r}") from None
    if hint is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false", "1", "0", "yes", "no"):
            return value.lower() in ("true", "1", "yes")
        raise ParamError(f"{name}: expected true/false, got {value!r}")
    if hint is str:
        if not isinstance(value, str):
            raise ParamError(f"{name}: expected a string, got {value!r}")
        return value
    if origin is tuple:
        if isinstance(value, str):
            value = [v.strip() for v in value.replace("[", "").replace("]", "").split(",") if v.strip()]
        if not isinstance(value, list | tuple):
            raise ParamError(f"{name}: expected a list, got {value!r}")
        args = [a for a in typing.get_args(hint) if a is not Ellipsis]
        if args and all(a is str for a in args):
            if not all(isinstance(v, str) for v in value):
                raise ParamError(f"{name}: expected a list of strings, got {value!r}")
            return tuple(value)
        try:
            numbers = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            raise ParamError(f"{name}: expected a list of numbers, got {value!r}") from None
        if any(math.isnan(v) for v in numbers):
            raise ParamError(f"{name}: expected a list of numbers, got {value!r}")
        return numbers
    if isinstance(hint, type) and issubclass(hint, str):  # StrEnum
        try:
            return hint(value)
        except ValueError:
            allowed = [m.value for m in hint]  # type: ignore[attr-defined]
            raise ParamError(f"{name}: {value!r} is not one of {allowed}") from None
    if origin in (types.UnionType, typing.Union):
        return value
    return value


def replace_params(params: Any, changes: dict[str, Any], where: str = "") -> Any:
    """Return ``params`` with ``changes`` applied, coerced to the declared field types.

    Unknown names and values of the wrong type raise :class:`ParamError` naming the field;
    the original object is never modified (it is frozen).
    """
    fields = {f.name: f for f in dataclasses.fields(params)}
    resolved = typing.get_type_hints(type(params))
    out: dict[str, Any] = {}
    for key, value in changes.items():
        if key not in fields:
            raise ParamError(f"{where}{key}: unknown parameter (known: {', '.join(sorted(fields))})")
        out[key] = _coerce(f"{where}{key}", resolved.get(key, fields[key].type), value)
    rate = out.get("rate_hz")
    if rate is not None and not (math.isfinite(rate) and rate > 0.0):  # a host steps a module every 1/rate_hz s
        raise ParamError(f"{where}rate_hz: expected a positive finite rate in Hz, got {changes['rate_hz']!r}")
    new = dataclasses.replace(params, **out)
    check = getattr(new, "validate", None)
    if callable(check):
        try:
            check()
        except ValueError as exc:
            raise ParamError(f"{where}{exc}") from None
    return new


def params_dict(params: Any) -> dict[str, Any]:
    """Parameters as plain wire values (tuples become lists, enums their value)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        if isinstance(v, tuple):
            v = list(v)
        elif isinstance(v, str):
            v = str(v)  # a StrEnum travels as its plain value
        out[f.name] = v
    return out
