"""Field tables of every wire message, generated from the msgspec structs (``docs/messages.md``).

The document is written by ``contactflow protocol fields`` and checked by the tests, so it
cannot drift from the code: a field's type and default come from ``msgspec.inspect``, its unit
and meaning from the comment after it in the struct's source, and a message's meaning from
its docstring.
"""

from __future__ import annotations

import ast
import enum
import importlib
import inspect
import io
import re
import textwrap
import tokenize
from pathlib import Path

import msgspec
import msgspec.inspect as mi

from contactflow.nodes.wire import Message, registry

MESSAGE_MODULES = (
    "contactflow.nodes.wire",
    "contactflow.nodes.messages",
    "contactflow.nodes.task_module",
    "contactflow.embodiments.messages",
    "contactflow.fusion.messages",
    "contactflow.recognition.messages",
    "contactflow.abstraction.messages",
)
"""Every module that defines wire messages, in the order the document lists them."""

DOC = Path(__file__).resolve().parent.parent / "docs" / "messages.md"

COMMON = {
    "hdr": "header: schema, source, seq, time stamps, provenance ([Header](#header))",
    "robot": "robot name (one key segment)",
}
"""Meanings of fields that mean the same in every message that has them."""


def _comments(cls: type) -> dict[str, str]:
    """Field name -> the comment after it in ``cls``'s body (empty for a field without one)."""
    try:
        src = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    by_line: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            by_line[tok.start[0]] = tok.string.lstrip("#").strip()
    body = ast.parse(src).body[0]
    out: dict[str, str] = {}
    for node in getattr(body, "body", []):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out[node.target.id] = by_line.get(node.end_lineno or node.lineno, "")
        elif isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            out[node.targets[0].id] = by_line.get(node.end_lineno or node.lineno, "")  # an enum member
    return out


def _doc(cls: type) -> str:
    """The first paragraph of a class's docstring, on one line."""
    text = inspect.cleandoc(cls.__dict__.get("__doc__") or "")  # its own, not a base's
    return _md(" ".join(text.split("\n\n", 1)[0].split()))


def _type(t: mi.Type, nested: list[type]) -> str:
    """A field type as the table shows it; structs it names are added to ``nested``."""
    if isinstance(t, mi.StructType):
        if t.cls not in nested:
            nested.append(t.cls)
        return f"[{t.cls.__name__}](#{t.cls.__name__.lower()})"
    if isinstance(t, mi.ListType | mi.VarTupleType | mi.SetType | mi.FrozenSetType):
        item = _type(t.item_type, nested)
        return f"list of ({item})" if isinstance(t.item_type, mi.UnionType) else f"list of {item}"
    if isinstance(t, mi.TupleType):
        return "[" + ", ".join(_type(i, nested) for i in t.item_types) + "]"
    if isinstance(t, mi.DictType):
        return f"map {_type(t.key_type, nested)} → {_type(t.value_type, nested)}"
    if isinstance(t, mi.UnionType):
        return " or ".join(_type(i, nested) for i in t.types)
    if isinstance(t, mi.EnumType):
        values = "one of " + " ".join(f"`{m.value}`" for m in t.cls)
        if not any(_comments(t.cls).values()):
            return values
        if t.cls not in nested:
            nested.append(t.cls)
        return f"[{t.cls.__name__}](#{t.cls.__name__.lower()}): {values}"
    if isinstance(t, mi.LiteralType):
        return "one of " + " ".join(f"`{v}`" for v in t.values)
    names = {mi.IntType: "int", mi.FloatType: "float", mi.StrType: "str", mi.BoolType: "bool", mi.NoneType: "nil",
             mi.BytesType: "bin", mi.MemoryViewType: "bin", mi.ByteArrayType: "bin", mi.AnyType: "any"}
    for kind, name in names.items():
        if isinstance(t, kind):
            return name
    return type(t).__name__.removesuffix("Type").lower()


def _default(f: mi.Field) -> str:
    if f.required:
        return "required"
    if f.default_factory is not mi.NODEFAULT:
        value = f.default_factory()
        return "empty" if value in ([], {}, ()) else ("a fresh header" if isinstance(value, msgspec.Struct) else repr(value))
    d = f.default
    if isinstance(d, enum.Enum):
        return f"`{d.value}`"
    if isinstance(d, str):
        return f'`"{d}"`'
    return "nil" if d is None else f"`{d!r}`"


def _md(text: str) -> str:
    """Docstring markup as Markdown: ``x`` and :class:`~a.B` become `x` and `B`."""
    return re.sub(r":\w+:`~?(?:\w+\.)*(\w+)`", r"`\1`", text).replace("``", "`")


def _cell(text: str) -> str:
    return _md(text).replace("|", "\\|").replace("\n", " ")


def _notes(cls: type) -> dict[str, str]:
    """Field name -> its unit and meaning: its comment (or an inherited field's), else the common one."""
    notes: dict[str, str] = {}
    for c in cls.__mro__:
        for name, note in _comments(c).items():
            if not notes.get(name):
                notes[name] = note
    return {f.name: notes.get(f.name) or COMMON.get(f.name, "") for f in mi.type_info(cls).fields}


def _table(cls: type, nested: list[type]) -> list[str]:
    if issubclass(cls, enum.Enum):
        notes = _comments(cls)
        return ["| value | meaning |", "|---|---|", *(f"| `{m.value}` | {_cell(notes.get(m.name, ''))} |" for m in cls)]
    info = mi.type_info(cls)
    notes = _notes(cls)
    rows = ["| field | type | default | unit, meaning |", "|---|---|---|---|"]
    if issubclass(cls, Message):
        rows.append(f"| `type` | str | `\"{cls.tag()}\"` | the message's tag |")
    for f in sorted(info.fields, key=lambda f: f.name != "hdr"):  # the header first, as in every message
        rows.append(f"| `{f.encode_name}` | {_cell(_type(f.type, nested))} | {_cell(_default(f))} | {_cell(notes[f.name])} |")
    return rows


def message_types() -> list[type[Message]]:
    """Every wire message type, grouped by the module that defines it, in source order."""
    for name in MESSAGE_MODULES:
        importlib.import_module(name)
    order = {m: i for i, m in enumerate(MESSAGE_MODULES)}
    types = [t for t in registry().values() if t.__module__.startswith("contactflow.")]  # not a test's or a plugin's
    unknown = sorted(t.__module__ for t in types if t.__module__ not in order)
    if unknown:
        raise RuntimeError(f"messages defined outside MESSAGE_MODULES: {unknown}")
    return sorted(types, key=lambda t: (order[t.__module__], inspect.getsourcelines(t)[1]))


def documented() -> tuple[list[type[Message]], list[type]]:
    """The message types, and the structures inside them (in the order the tables first name them)."""
    messages = message_types()
    nested: list[type] = []
    for cls in messages:
        _table(cls, nested)
    i = 0
    while i < len(nested):
        _table(nested[i], nested)
        i += 1
    return messages, [c for c in nested if c not in messages]


def render() -> str:
    """The whole ``docs/messages.md``."""
    messages, nested = documented()
    out = ["# Wire messages: every field", "",
           "Generated from the msgspec structs by `contactflow protocol fields`; do not edit by hand (a test",
           "compares this file with the code). [protocol.md](protocol.md) says which key carries which",
           "message. Every message is a MessagePack map: its fields by name, plus `type` (the tag). A",
           "field at its default may be left out by a sender; a receiver fills the default in. `bin` is",
           "MessagePack binary; a field typed [NDArray](#ndarray) is a map `{dtype, shape, data}`.", ""]
    module = ""
    for cls in messages:
        if cls.__module__ != module:
            module = cls.__module__
            out += [f"## `{module.removeprefix('contactflow.')}`", ""]
        out += [f"### `{cls.tag()}`", "", f"{_doc(cls)} (`{cls.__name__}`)", "", *_table(cls, []), ""]
    out += ["## Structures inside messages", ""]
    for cls in nested:
        out += [f"### {cls.__name__}", "", _doc(cls), "", *_table(cls, []), ""]
    return "\n".join(out)


def missing() -> list[str]:
    """What the document could give no meaning for: a type without a docstring, a field without a comment."""
    messages, nested = documented()
    out = [f"{c.__module__}.{c.__name__}: no docstring" for c in [*messages, *nested] if not _doc(c)]
    for cls in [*messages, *nested]:
        notes = {m.name: _comments(cls).get(m.name, "") for m in cls} if issubclass(cls, enum.Enum) else _notes(cls)
        out += [f"{cls.__module__}.{cls.__name__}.{name}: no comment" for name, note in notes.items() if not note]
    return out
