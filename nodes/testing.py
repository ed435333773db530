"""In-memory fakes of the runtime, for testing modules without zenoh."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

from contactflow.nodes.messages import Command, ControlReply, EventMsg, ParamValue
from contactflow.nodes.module import LayerError, Module
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import Message, MsgId, decode, encode, stamp


@dataclass
class FakeIO:
    """A :class:`~contactflow.nodes.module.ModuleIO` that records everything in lists.

    Feed inputs with :meth:`feed`; read ``published``, ``events`` and ``commands``. Every
    message is round-tripped through the wire codec so tests catch unencodable messages.
    ``replies`` maps a command target to the reply it gets (default: ok); ``wired_ports``
    are the input ports a configuration would wire.
    """

    module: Module | None = None
    t: float = 0.0
    published: dict[str, list[Message]] = field(default_factory=lambda: defaultdict(list))
    events: list[EventMsg] = field(default_factory=list)
    commands: list[tuple[str, Command, dict[str, ParamValue]]] = field(default_factory=list)
    replies: dict[str, ControlReply] = field(default_factory=dict)
    logs: list[str] = field(default_factory=list)
    wired_ports: set[str] = field(default_factory=set)
    wakes: int = 0  # calls of wake()
    _latest: dict[str, Message] = field(default_factory=dict)
    _queue: dict[str, list[Message]] = field(default_factory=lambda: defaultdict(list))
    _seq: int = 0

    @property
    def now(self) -> float:
        return self.t

    def feed(self, port: str, msg: Message) -> None:
        msg = decode(encode(msg), type(msg), where=f"fake:{port}")
        self._latest[port] = msg
        self._queue[port].append(msg)

    def latest(self, port: str) -> Message | None:
        return self._latest.get(port)

    def take(self, port: str) -> list[Message]:
        out, self._queue[port] = self._queue[port], []
        return out

    def wired(self, port: str) -> bool:
        return port in self.wired_ports

    def _source(self) -> str:
        return self.module.name if self.module else "fake"

    def publish(self, port: str, msg: Message, inputs: list[MsgId] | None = None) -> None:
        self._seq += 1
        if inputs is None:
            inputs = [m.hdr.id for m in self._latest.values()]
        stamp(msg, f"{self._source()}/{port}", self._seq, self.t, inputs)
        self.published[port].append(decode(encode(msg), type(msg), where=f"fake:{port}"))

    def emit(self, event: Event, detail: str = "", values: dict[str, float] | None = None) -> None:
        self._seq += 1
        msg = EventMsg(event=event, module=self._source(), detail=detail, values=values or {})
        self.events.append(stamp(msg, self._source(), self._seq, self.t))

    def command(self, target: str, cmd: Command, params: dict[str, ParamValue] | None = None) -> ControlReply:
        if self.module is not None and not self.module.may_command:
            raise LayerError(f"{self.module.name}: a {self.module.layer} module may not send control messages")
        self.commands.append((target, cmd, dict(params or {})))
        return self.replies.get(target, ControlReply(ok=True, state=Status.RUNNING))

    def log(self, text: str) -> None:
        self.logs.append(text)

    def wake(self) -> None:
        self.wakes += 1

    def event_labels(self) -> list[Event]:
        return [e.event for e in self.events]


def run_module(module: Module, io: FakeIO, steps: int, dt: float | None = None) -> Status:
    """Set up, start and step ``module`` until it finishes or ``steps`` run out."""
    io.module = module
    module.setup(io)
    module.start()
    status = Status.RUNNING
    period = dt if dt is not None else 1.0 / module.params.rate_hz
    for _ in range(steps):
        status = module.step()
        io.t += period
        if status.finished:
            break
    return status
