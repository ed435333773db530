"""The one registry of module types: short names to classes, loaded lazily per area.

Each area lists its modules in ``contactflow.<area>.catalog`` as ``CATALOG = {name:
"module.path:Class"}``; a configuration names a module type by that short name or by a full
``"package.module:Class"`` path.
"""

from __future__ import annotations

import importlib

from contactflow.nodes.module import Module

AREAS = ("nodes", "embodiments", "embodiments.primitives", "fusion", "recognition", "abstraction", "deploy")


class UnknownModuleType(LookupError):
    pass


def catalog() -> dict[str, str]:
    """Every registered short name with its import path."""
    out: dict[str, str] = {}
    for area in AREAS:
        try:
            mod = importlib.import_module(f"contactflow.{area}.catalog")
        except ModuleNotFoundError as exc:
            if exc.name != f"contactflow.{area}.catalog":
                raise
            continue
        for name, path in getattr(mod, "CATALOG", {}).items():
            if name in out and out[name] != path:
                raise UnknownModuleType(f"module type {name!r} registered twice: {out[name]} and {path}")
            out[name] = path
    return out


def resolve(type_name: str) -> type[Module]:
    """The Module class for a short name or ``package.module:Class`` path."""
    path = type_name if ":" in type_name else catalog().get(type_name)
    if path is None:
        known = ", ".join(sorted(catalog()))
        raise UnknownModuleType(f"unknown module type {type_name!r} (known: {known})")
    mod_name, _, cls_name = path.partition(":")
    try:
        cls = getattr(importlib.import_module(mod_name), cls_name)
    except (ImportError, AttributeError) as exc:
        raise UnknownModuleType(f"module type {type_name!r}: cannot import {path}: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, Module)):
        raise UnknownModuleType(f"module type {type_name!r}: {path} is not a Module")
    return cls
