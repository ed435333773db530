"""Wire format: typed message structs encoded as plain MessagePack maps with named fields.

Every message is a ``msgspec`` struct deriving from :class:`Message`. On the wire it is a
MessagePack map whose keys are the field names plus ``"type"`` (the message tag), so any
msgpack client in any language can read it (``docs/protocol.md`` shows how). Numpy arrays
travel as :class:`NDArray` maps ``{dtype, shape, data}``. Decoding validates types, the
schema version and array sizes, and refuses payloads larger than the type allows.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any, ClassVar, TypeVar, Union

import msgspec
import msgspec.inspect as mi
import numpy as np

SCHEMA_VERSION = 1
"""Bumped on any incompatible change of a message layout."""

_ALLOWED_DTYPES = frozenset(
    {"bool", "uint8", "int8", "uint16", "int16", "uint32", "int32", "int64", "uint64",
     "float16", "float32", "float64"}
)

M = TypeVar("M", bound="Message")


class WireError(ValueError):
    """A payload could not be decoded; the message names the key expression and field."""


class MsgId(msgspec.Struct, frozen=True, kw_only=True):
    """Identity of one message: its source (``robot/node/module[/port]``) and sequence."""

    source: str  # the message's hdr.source
    seq: int  # the message's hdr.seq


class Header(msgspec.Struct, kw_only=True):
    """Carried by every message: schema, origin, sequence, time stamps and provenance.

    ``inputs`` lists the messages this one was computed from, so the output of a pipeline
    can be traced back to the sensor reading that caused it (thesis §6.6).
    """

    schema: int = SCHEMA_VERSION  # schema version; a different one is refused
    source: str = ""  # robot/node/module[/port] that produced it
    seq: int = 0  # counts per source from 1 (gaps reveal loss)
    t_sim: float = 0.0  # s, simulation (or robot) clock
    t_wall: float = 0.0  # s since the Unix epoch
    inputs: list[MsgId] = []  # the messages this one was computed from
    tick: int = -1  # the world tick a lockstep node sent it during (subscribers in lockstep see it the tick after, a tick later with a pipelined world); -1: none; a pipelined world stamps its own two before the clock they precede

    def __post_init__(self) -> None:
        if self.schema != SCHEMA_VERSION:
            raise ValueError(f"unknown schema version {self.schema} (this build reads {SCHEMA_VERSION})")
        if self.seq < 0:
            raise ValueError("seq must be >= 0")

    @property
    def id(self) -> MsgId:
        return MsgId(source=self.source, seq=self.seq)


_ITEMSIZE = {name: np.dtype(name).itemsize for name in _ALLOWED_DTYPES}
_NAME_BY_CHAR = {np.dtype(name).char: name for name in _ALLOWED_DTYPES}  # dtype.name is slow
_LITTLE = {name: np.dtype(name).newbyteorder("<") for name in _ALLOWED_DTYPES}  # built once: every decode views arrays


class NDArray(msgspec.Struct, frozen=True, kw_only=True):
    """A numpy array as ``{dtype, shape, data}``; ``data`` is C-order little-endian bytes.

    ``data`` decodes as a zero-copy view of the received payload.
    """

    dtype: str  # numpy dtype name: bool, (u)int8-64, float16-64
    shape: list[int]  # dimensions
    data: memoryview  # C-order little-endian bytes

    def __post_init__(self) -> None:
        itemsize = _ITEMSIZE.get(self.dtype)
        if itemsize is None:
            raise ValueError(f"dtype {self.dtype!r} is not one of {sorted(_ALLOWED_DTYPES)}")
        if len(self.shape) > 8:
            raise ValueError(f"shape {self.shape} has more than 8 dimensions")
        count = 1
        for d in self.shape:
            if d < 0:
                raise ValueError(f"shape {self.shape} has a negative dimension")
            count *= d
        nbytes = self.data.nbytes if isinstance(self.data, memoryview) else len(self.data)
        if count * itemsize != nbytes:
            raise ValueError(f"data has {nbytes} bytes, shape {self.shape} of {self.dtype} needs {count * itemsize}")

    @classmethod
    def of(cls, array: np.ndarray) -> NDArray:
        a = array
        if not a.flags.c_contiguous or a.dtype.byteorder == ">":
            a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
        dt = a.dtype
        name = _NAME_BY_CHAR.get(dt.char) or dt.name
        data = memoryview(a).cast("B") if a.size else memoryview(b"")  # cast refuses zero-size views
        return cls(dtype=name, shape=list(a.shape), data=data)

    def numpy(self) -> np.ndarray:
        return np.frombuffer(self.data, dtype=_LITTLE[self.dtype]).reshape(self.shape)


class Message(msgspec.Struct, kw_only=True, tag_field="type", tag=True):
    """Base of every wire message. Subclasses give ``tag="snake_name"``.

    ``max_bytes`` bounds the encoded size accepted for this type: a 10 MB payload on a key
    that carries small messages is refused before decoding.
    """

    max_bytes: ClassVar[int] = 1 << 20
    nonfinite: ClassVar[frozenset[str]] = frozenset()
    """Fields whose numbers may be NaN or infinite by their definition (a depth image's pixels);
    any other non-finite number refuses the message."""

    hdr: Header = msgspec.field(default_factory=Header)

    @classmethod
    def tag(cls) -> str:
        return str(cls.__struct_config__.tag)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        global _generation
        _generation += 1  # decode_any's decoder of every type is built again


_generation = 0
"""Counts message types defined so far (the registry only grows as modules are imported)."""


def registry() -> dict[str, type[Message]]:
    """Every imported message type by tag; two types may not share a tag."""
    out: dict[str, type[Message]] = {}
    todo = list(Message.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        tag = cls.tag()
        if tag in out and out[tag] is not cls:
            raise TypeError(f"message tag {tag!r} used by {out[tag].__qualname__} and {cls.__qualname__}")
        out[tag] = cls
    return out


_encoder = msgspec.msgpack.Encoder()
_decoders: dict[type, msgspec.msgpack.Decoder] = {}


def encode(msg: Message) -> bytes:
    return _encoder.encode(msg)


def stamp(msg: M, source: str, seq: int, t_sim: float, inputs: list[MsgId] | None = None) -> M:
    """Fill the header of an outgoing message (the runtime does this on publish)."""
    h = msg.hdr
    h.source, h.seq, h.t_sim, h.t_wall = source, seq, t_sim, time.time()
    if inputs is not None:
        h.inputs = inputs
    return msg


class Stamper:
    """Headers for what a component sends outside a module's ports (replies, reports, progress).

    One ``source`` (the full module path), ``seq`` counted from 1 per key it sends on, ``t_sim``
    from the node's one clock (``now``) and ``inputs`` naming what the message answers.
    """

    def __init__(self, source: str, now: Callable[[], float]) -> None:
        self.source, self.now = source, now
        self._seq: dict[str, int] = {}
        self._lock = threading.Lock()

    def __call__(self, msg: M, key: str = "", inputs: list[MsgId] | None = None) -> M:
        with self._lock:
            seq = self._seq[key] = self._seq.get(key, 0) + 1
        return stamp(msg, self.source, seq, self.now(), inputs)


Check = Callable[[Any], "str | None"]
"""Finds the first non-finite number in a decoded value: its path (``.a[2].b``), or None."""

_FLOAT_DTYPES = frozenset({"float16", "float32", "float64"})
_checks: dict[type, Check] = {}
_checks_lock = threading.RLock()
_building: set[type] = set()


def _no_check(value: Any) -> str | None:
    return None


def _check_float(value: Any) -> str | None:
    return "" if isinstance(value, float) and not math.isfinite(value) else None


def _check_floats(value: Any) -> str | None:
    """A list of floats: one pass in C over the common, finite case (a state carries hundreds of them)."""
    if all(map(math.isfinite, value)):
        return None
    return f"[{next(i for i, v in enumerate(value) if not math.isfinite(v))}]"


def _check_array(value: Any) -> str | None:
    if value.dtype not in _FLOAT_DTYPES or not value.data.nbytes:
        return None
    a = np.frombuffer(value.data, dtype=_LITTLE[value.dtype])  # flat: the index is the element's in C order
    return None if np.isfinite(a).all() else f"[{int(np.flatnonzero(~np.isfinite(a))[0])}]"


def _checker(t: mi.Type) -> Check:
    """The finiteness check of a value of type ``t`` (built once per message type)."""
    if isinstance(t, mi.FloatType):
        return _check_float
    if isinstance(t, mi.StructType):
        if t.cls is NDArray:
            return _check_array
        return _struct_check(t.cls)
    if isinstance(t, mi.ListType | mi.VarTupleType):
        item = _checker(t.item_type)
        if item is _no_check:
            return _no_check
        if item is _check_float:
            return _check_floats

        def check_items(value: Any) -> str | None:
            for i, v in enumerate(value):
                bad = item(v)
                if bad is not None:
                    return f"[{i}]{bad}"
            return None
        return check_items
    if isinstance(t, mi.DictType):
        val = _checker(t.value_type)
        if val is _no_check:
            return _no_check

        def check_values(value: Any) -> str | None:
            for k, v in value.items():
                bad = val(v)
                if bad is not None:
                    return f"[{k!r}]{bad}"
            return None
        return check_values
    if isinstance(t, mi.UnionType):  # the check of the member the value decoded as
        parts = [(_python_type(u), c) for u in t.types if (c := _checker(u)) is not _no_check]
        if not parts:
            return _no_check

        def check_any(value: Any) -> str | None:
            for kind, c in parts:
                if isinstance(value, kind):
                    return c(value)
            return None
        return check_any
    return _no_check


def _python_type(t: mi.Type) -> type | tuple[type, ...]:
    """What a value of msgspec type ``t`` decodes to (a union member's checks apply to its values only)."""
    if isinstance(t, mi.StructType):
        return t.cls
    if isinstance(t, mi.ListType | mi.VarTupleType):
        return (list, tuple)
    if isinstance(t, mi.DictType):
        return dict
    return float


def _struct_check(cls: type) -> Check:
    cached = _checks.get(cls)
    if cached is not None:
        return cached
    with _checks_lock:  # zenoh threads decode at once: none may see the placeholder of a check being built
        if cls in _building:
            return _no_check  # a struct that contains itself is checked one level deep
        cached = _checks.get(cls)
        if cached is not None:
            return cached
        _building.add(cls)
        try:
            exempt = getattr(cls, "nonfinite", frozenset())
            fields = [(f.name, c) for f in mi.type_info(cls).fields
                      if f.name not in exempt and (c := _checker(f.type)) is not _no_check]
        finally:
            _building.discard(cls)

        def check(value: Any) -> str | None:
            for name, c in fields:
                bad = c(getattr(value, name))
                if bad is not None:
                    return f".{name}{bad}"
            return None
        _checks[cls] = check if fields else _no_check
        return _checks[cls]


def decode(data: bytes | bytearray | memoryview, type_: type[M], where: str = "") -> M:
    """Decode and validate ``data`` as ``type_``; ``where`` (a key expression) names the place.

    A non-finite number anywhere in a message (NaN or infinity in a float field or a float
    array) is refused like a wrong type: one poisoned reading would stay in a stateful
    module's estimate (a fused voxel space, a filter) for good.
    """
    if len(data) > type_.max_bytes:
        raise WireError(f"{where}: payload of {len(data)} bytes exceeds {type_.max_bytes} for {type_.__name__}")
    dec = _decoders.get(type_)
    if dec is None:
        dec = _decoders[type_] = msgspec.msgpack.Decoder(type_)
    try:
        msg = dec.decode(data)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise WireError(f"{where}: invalid {type_.__name__}: {exc}") from None
    bad = _struct_check(type_)(msg)
    if bad is not None:
        raise WireError(f"{where}: invalid {type_.__name__}: {type_.__name__}{bad} is not a finite number")
    return msg


_any: tuple[int, msgspec.msgpack.Decoder | None] = (-1, None)


def decode_any(data: bytes | bytearray | memoryview, where: str = "") -> Message:
    """Decode a message of any registered type, chosen by its ``type`` tag, in one pass over the payload.

    The checks are :func:`decode`'s; a payload that fails them is diagnosed again, type by type.
    """
    global _any
    generation, dec = _any
    if generation != _generation:  # a tagged union of every type: msgspec picks the struct by the tag
        types = tuple(registry().values())
        dec = msgspec.msgpack.Decoder(Union[types]) if types else None  # noqa: UP007 - a runtime tuple of types
        _any = (_generation, dec)
    try:
        msg = dec.decode(data) if dec is not None else None
    except (msgspec.ValidationError, msgspec.DecodeError):
        msg = None
    if msg is not None:
        cls = type(msg)
        if len(data) <= cls.max_bytes and _struct_check(cls)(msg) is None:
            return msg
    return _diagnose(data, where)


def _diagnose(data: bytes | bytearray | memoryview, where: str) -> Message:
    """Decode ``data`` type by type: the WireError raised names why it is no valid message."""
    try:
        raw = msgspec.msgpack.decode(data)
    except msgspec.DecodeError as exc:
        raise WireError(f"{where}: not MessagePack: {exc}") from None
    tag = raw.get("type") if isinstance(raw, dict) else None
    cls = registry().get(tag) if isinstance(tag, str) else None
    if cls is None:
        raise WireError(f"{where}: unknown message type {tag!r}")
    return decode(data, cls, where)


def to_builtins(msg: Message) -> Any:
    """A plain-Python view of a message (arrays summarised), for printing."""
    def hook(obj: Any) -> Any:
        if isinstance(obj, bytes | memoryview):
            return f"<{len(obj)} bytes>"
        raise NotImplementedError
    return msgspec.to_builtins(msg, enc_hook=hook)
