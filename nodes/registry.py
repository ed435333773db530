"""The one registry of module types: short names to classes, loaded lazily per area.

Each area lists its modules in ``contactflow.<area>.catalog`` as ``CATALOG = {name:
"module.path:Class"}``; a configuration names a module type by that short name or by a full
``"package.module:Class"`` path. A path that is not importable from the installed packages is
looked up next to the configuration file (``contactflow new`` writes the module there).
"""

from __future__ import annotations

import functools
import importlib
import sys
import threading
from collections.abc import Collection, Iterator
from pathlib import Path

from contactflow.nodes.module import Layer, Module

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


@functools.cache
def layer_types(layer: Layer) -> frozenset[str]:
    """Short names of the registered module types of ``layer`` (imports every registered type, once)."""
    return frozenset(name for name in catalog() if _layer(name) is layer)


@functools.cache
def _layer(name: str) -> Layer:
    return resolve(name).layer


class LayerTypes(Collection[str]):
    """The registered module types of ``layers``, as a collection that imports a type only to tell whether it is
    one of them: a task file's validation asks about the few types it names, not the ~100 registered (1-2 s of
    imports, on the control query that runs the task). Listing it (an error message) imports them all."""

    def __init__(self, *layers: Layer) -> None:
        self.layers = frozenset(layers)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in catalog() and _layer(name) in self.layers

    def __iter__(self) -> Iterator[str]:
        return iter(sorted(set().union(*(layer_types(layer) for layer in self.layers))))

    def __len__(self) -> int:
        return sum(1 for _ in self)


_PATH_LOCK = threading.Lock()


def _import(mod_name: str, search: Path | None):
    """Import ``mod_name``; when no installed package has it, import it from ``search``."""
    try:
        return importlib.import_module(mod_name)
    except ModuleNotFoundError as exc:
        top = mod_name.partition(".")[0]
        if search is None or exc.name not in (top, mod_name) or not search.is_dir():
            raise
    folder = str(search.resolve())
    with _PATH_LOCK:  # the folder is on the path only while this import (and its own imports) run
        added = folder not in sys.path
        if added:
            sys.path.insert(0, folder)
        try:
            importlib.invalidate_caches()
            return importlib.import_module(mod_name)
        finally:
            if added:
                sys.path.remove(folder)


def resolve(type_name: str, search: Path | None = None) -> type[Module]:
    """The Module class for a short name or ``package.module:Class`` path.

    ``search`` is the folder of the configuration naming the type: a ``module:Class`` path
    that no installed package provides is imported from there.
    """
    path = type_name if ":" in type_name else catalog().get(type_name)
    if path is None:
        known = ", ".join(sorted(catalog()))
        raise UnknownModuleType(f"unknown module type {type_name!r} (known: {known})")
    mod_name, _, cls_name = path.partition(":")
    try:
        cls = getattr(_import(mod_name, search), cls_name)
    except (ImportError, AttributeError) as exc:
        where = f" (also looked in {search})" if search is not None and ":" in type_name else ""
        raise UnknownModuleType(f"module type {type_name!r}: cannot import {path}{where}: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, Module)):
        raise UnknownModuleType(f"module type {type_name!r}: {path} is not a Module")
    return cls
