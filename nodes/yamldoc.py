"""YAML documents that remember where every value came from, for file:line error messages."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml


class ConfigError(ValueError):
    """A configuration file is invalid; the message reads ``file:line: field: problem``."""


PathKey = tuple[str | int, ...]


def _dotted(path: PathKey) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "<document>"


@dataclass
class YamlDoc:
    """Plain Python data plus the line of every mapping key and sequence item."""

    data: Any
    file: str
    lines: dict[PathKey, int] = field(default_factory=dict)

    @classmethod
    def load(cls, path: str | Path) -> YamlDoc:
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as exc:
            raise ConfigError(f"{p}: cannot read: {exc.strerror}") from None
        return cls.parse(text, str(p))

    @classmethod
    def parse(cls, text: str, file: str = "<string>") -> YamlDoc:
        try:
            node = yaml.compose(text, Loader=yaml.SafeLoader)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = f":{mark.line + 1}" if mark is not None else ""
            raise ConfigError(f"{file}{line}: not valid YAML: {getattr(exc, 'problem', exc)}") from None
        doc = cls(data=None, file=file)
        if node is None:
            raise ConfigError(f"{file}:1: the document is empty")
        doc.data = doc._build(node, ())
        return doc

    def _build(self, node: yaml.Node, path: PathKey) -> Any:
        self.lines.setdefault(path, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            out: dict[str, Any] = {}
            for knode, vnode in node.value:
                key = knode.value
                if key in out:
                    raise ConfigError(f"{self.file}:{knode.start_mark.line + 1}: {_dotted(path + (key,))}: duplicate key")
                self.lines[path + (key,)] = knode.start_mark.line + 1
                out[key] = self._build(vnode, path + (key,))
            return out
        if isinstance(node, yaml.SequenceNode):
            return [self._build(v, path + (i,)) for i, v in enumerate(node.value)]
        loader = yaml.SafeLoader("")
        try:
            return loader.construct_object(node, deep=True)
        except yaml.YAMLError as exc:
            raise ConfigError(f"{self.file}:{node.start_mark.line + 1}: {_dotted(path)}: {exc}") from None
        finally:
            loader.dispose()

    def line(self, path: PathKey) -> int:
        while path and path not in self.lines:
            path = path[:-1]
        return self.lines.get(path, 1)

    def error(self, path: PathKey, problem: str) -> ConfigError:
        return ConfigError(f"{self.file}:{self.line(path)}: {_dotted(path)}: {problem}")

    def mapping(self, path: PathKey, allowed: set[str]) -> dict:
        """The mapping at ``path``; a key outside ``allowed`` is an error naming its line."""
        data = self.get(path, dict) if path else self.data
        if not isinstance(data, dict):
            raise self.error(path, "expected a mapping")
        for k in data:
            if k not in allowed:
                raise self.error(path + (k,), f"unknown field (allowed: {', '.join(sorted(allowed))})")
        return data

    def get(self, path: PathKey, kind: type | tuple[type, ...], default: Any = ..., ) -> Any:
        """The value at ``path`` checked against ``kind``; missing → ``default`` or an error."""
        cur: Any = self.data
        for i, p in enumerate(path):
            if isinstance(p, int):
                ok = isinstance(cur, list) and 0 <= p < len(cur)
            else:
                ok = isinstance(cur, dict) and p in cur
            if not ok:
                if default is not ...:
                    return default
                raise self.error(path[: i + 1], "missing")
            cur = cur[p]
        if kind is float and isinstance(cur, int) and not isinstance(cur, bool):
            cur = float(cur)
        if not isinstance(cur, kind) or (kind in (int, float) and isinstance(cur, bool)):
            names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
            raise self.error(path, f"expected {names}, got {type(cur).__name__} {cur!r}")
        return cur
