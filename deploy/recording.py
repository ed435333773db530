"""MCAP recordings of the key space: one JSON channel per key with its message's JSON schema, plus view channels.

A key-space channel is named by its zenoh key; its messages are the wire messages re-encoded
as JSON (schema encoding ``jsonschema``, message encoding ``json``), which Foxglove and the
``mcap`` CLI read, and which decode back into the same typed message for a replay. View
channels (topics starting with ``/``) carry the same data in Foxglove's schemas (protobuf).
A metadata record named ``contactflow`` marks a file as a contactflow recording.
"""

from __future__ import annotations

import functools
import importlib
import json
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import msgspec
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from contactflow.deploy.foxglove_view import JsonView
from contactflow.nodes.fieldtables import MESSAGE_MODULES
from contactflow.nodes.wire import SCHEMA_VERSION, Message, registry

META = "contactflow"
"""Name of the metadata record that marks a contactflow recording."""

SCHEMA_PREFIX = "contactflow."
"""A key-space channel's schema is named ``contactflow.<message tag>``."""

_MAGIC = b"\x89MCAP0\r\n"


class RecordingError(ValueError):
    """A file that is not a readable contactflow recording; the message names the file and why."""


def message_types() -> dict[str, type[Message]]:
    """Every wire message type by tag (imports each module that defines messages)."""
    for name in MESSAGE_MODULES:
        importlib.import_module(name)
    return registry()


@functools.cache
def json_schema(cls: type[Message]) -> bytes:
    """The message's JSON schema with ``"type": "object"`` at the top, as Foxglove requires."""
    doc = msgspec.json.schema(cls)
    defs = doc.get("$defs", {})
    name = doc["$ref"].rsplit("/", 1)[-1]
    return json.dumps({**defs[name], "$defs": defs}).encode()


class RecordingWriter:
    """Writes typed key-space messages and Foxglove view messages into one MCAP file."""

    def __init__(self, path: Path, site: str, compression: CompressionType = CompressionType.ZSTD) -> None:
        self.path = Path(path)
        self.site = site
        self.compression = compression
        self._file: BinaryIO | None = None
        self._writer: Writer | None = None
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}  # (topic, schema) -> channel
        self._seqs: dict[int, int] = {}
        self._json = msgspec.json.Encoder()

    def open(self) -> RecordingWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._writer = Writer(self._file, compression=self.compression)
        self._writer.start(library="contactflow")
        self._writer.add_metadata(META, {"site": self.site, "schema_version": str(SCHEMA_VERSION)})
        return self

    def _channel(self, topic: str, schema: str, encoding: str, data: bytes, message_encoding: str,
                 metadata: dict[str, str]) -> int:
        assert self._writer is not None, "open() first"
        cid = self._channels.get((topic, schema))
        if cid is None:
            sid = self._schemas.get(schema)
            if sid is None:
                sid = self._schemas[schema] = self._writer.register_schema(schema, encoding, data)
            cid = self._channels[topic, schema] = self._writer.register_channel(topic, message_encoding, sid, metadata)
        return cid

    def _add(self, cid: int, data: bytes, log_ns: int, publish_ns: int) -> None:
        assert self._writer is not None
        seq = self._seqs[cid] = self._seqs.get(cid, 0) + 1
        self._writer.add_message(cid, log_ns, data, publish_ns, seq)

    def write(self, key: str, msg: Message, log_ns: int) -> None:
        """One key-space message received at ``log_ns`` (ns since the epoch)."""
        tag = type(msg).tag()
        cid = self._channels.get((key, SCHEMA_PREFIX + tag))
        if cid is None:  # a key that carries several types (a robot's command port) has a channel per type
            cid = self._channel(key, SCHEMA_PREFIX + tag, "jsonschema", json_schema(type(msg)), "json",
                                {"key": key, "type": tag})
        publish_ns = int(msg.hdr.t_wall * 1e9) if msg.hdr.t_wall > 0 else log_ns
        self._add(cid, self._json.encode(msg), log_ns, publish_ns)

    def write_view(self, topic: str, msg: Any, log_ns: int) -> None:
        """One view message on a view channel: a Foxglove message (``foxglove.messages``) or a JsonView."""
        if isinstance(msg, JsonView):
            cid = self._channel(topic, msg.schema_name, "jsonschema", json.dumps(msg.schema).encode(), "json", {})
            data = json.dumps(msg.value).encode()
        else:
            schema = type(msg).get_schema()
            cid = self._channel(topic, schema.name, schema.encoding, bytes(schema.data), "protobuf", {})
            data = msg.encode()
        self._add(cid, data, log_ns, log_ns)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.finish()
            self._writer = None
        if self._file is not None:
            self._file.close()
            self._file = None


@dataclass(frozen=True)
class Sample:
    """One recorded key-space message."""

    key: str
    msg: Message
    log_ns: int  # ns since the epoch, when the recorder received it


@dataclass
class Recording:
    """A contactflow recording opened for reading: checked on open, read in log-time order."""

    path: Path
    site: str
    channels: dict[str, frozenset[str]]  # key -> the message tags recorded on it (a channel each)
    counts: dict[str, int]  # key -> messages
    tags: dict[int, str] = field(default_factory=dict)  # channel id -> message tag, the key-space channels
    view_topics: list[str] = field(default_factory=list)  # Foxglove view channels
    start_ns: int = 0
    end_ns: int = 0

    @classmethod
    def open(cls, path: Path) -> Recording:
        """Check that ``path`` is a complete contactflow recording; RecordingError names what is wrong."""
        path = Path(path)
        try:
            with open(path, "rb") as f:
                if f.read(len(_MAGIC)) != _MAGIC:
                    raise RecordingError(f"{path}: not an MCAP file (bad magic)")
                f.seek(0)
                reader = make_reader(f)
                summary = reader.get_summary()
                meta = [m for m in reader.iter_metadata() if m.name == META]
        except OSError as exc:
            raise RecordingError(f"{path}: {exc.strerror or exc}") from None
        except (McapError, struct.error, ValueError, EOFError) as exc:
            raise RecordingError(f"{path}: truncated or damaged MCAP file ({type(exc).__name__}: {exc})") from None
        if summary is None:
            raise RecordingError(f"{path}: truncated MCAP file (no summary: the recorder did not finish it)")
        if not meta:
            raise RecordingError(f"{path}: not a contactflow recording (no {META!r} metadata record)")
        version = meta[0].metadata.get("schema_version", "")
        if version != str(SCHEMA_VERSION):
            raise RecordingError(f"{path}: recorded with wire schema {version!r}, this build reads {SCHEMA_VERSION}")
        channels: dict[str, frozenset[str]] = {}
        counts: dict[str, int] = {}
        tags: dict[int, str] = {}
        view = set()
        stats = summary.statistics
        for cid, ch in summary.channels.items():
            schema = summary.schemas.get(ch.schema_id)
            n = stats.channel_message_counts.get(cid, 0) if stats else 0
            if schema is not None and schema.name.startswith(SCHEMA_PREFIX) and ch.message_encoding == "json":
                tags[cid] = schema.name[len(SCHEMA_PREFIX):]
                channels[ch.topic] = channels.get(ch.topic, frozenset()) | {tags[cid]}
                counts[ch.topic] = counts.get(ch.topic, 0) + n
            else:
                view.add(ch.topic)
        return cls(path, meta[0].metadata.get("site", ""), channels, counts, tags, sorted(view),
                   stats.message_start_time if stats else 0, stats.message_end_time if stats else 0)

    def samples(self, keys: set[str] | None = None) -> Iterator[Sample]:
        """The key-space messages (of ``keys``, or all) in log-time order, decoded into their types."""
        types = message_types()
        decoders: dict[str, msgspec.json.Decoder] = {}
        with open(self.path, "rb") as f:
            reader = make_reader(f)
            topics = [k for k in self.channels if keys is None or k in keys]
            try:
                for schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
                    tag = self.tags.get(channel.id)
                    if tag is None or schema is None:
                        continue
                    cls = types.get(tag)
                    if cls is None:
                        raise RecordingError(f"{self.path}: channel {channel.topic!r} has message type {tag!r}, "
                                             "which this build does not know")
                    dec = decoders.get(tag)
                    if dec is None:
                        dec = decoders[tag] = msgspec.json.Decoder(cls)
                    try:
                        msg = dec.decode(message.data)
                    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
                        raise RecordingError(f"{self.path}: channel {channel.topic!r} message {message.sequence}: "
                                             f"invalid {tag}: {exc}") from None
                    yield Sample(channel.topic, msg, message.log_time)
            except (McapError, struct.error, EOFError) as exc:
                raise RecordingError(f"{self.path}: damaged MCAP data ({type(exc).__name__}: {exc})") from None
