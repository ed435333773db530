"""Runtime wire messages: events, status, control, clock, module descriptions, generic data."""

from __future__ import annotations

from enum import StrEnum

import msgspec

from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import Message, NDArray

ParamValue = bool | int | float | str | list[float | str]


class EventMsg(Message, tag="event"):
    """A detected situation (thesis §6.1): an edge label of a task graph."""

    event: Event
    module: str  # robot/node/module that raised it
    detail: str = ""
    values: dict[str, float] = {}


class StatusMsg(Message, tag="status"):
    """Published by every module on change and periodically."""

    module: str
    layer: str
    state: Status
    rate_hz: float
    steps: int = 0
    rejected: int = 0  # inputs dropped by validation
    detail: str = ""
    gaps: dict[str, int] = {}  # input port -> sequence numbers its sources skipped (lost messages)


class Command(StrEnum):
    RUN = "run"
    STOP = "stop"
    RESET = "reset"
    SET = "set"
    DESCRIBE = "describe"


class ControlRequest(Message, tag="control"):
    """A control message (thesis §6.1): change a module's status or parameters."""

    cmd: Command
    params: dict[str, ParamValue] = {}
    issuer: str = ""


class ControlReply(Message, tag="control_reply"):
    ok: bool
    error: str = ""
    state: Status = Status.IDLE
    params: dict[str, ParamValue] = {}
    description: str = ""  # YAML module description, for DESCRIBE


class Mark(msgspec.Struct, frozen=True, kw_only=True):
    """The last message a lockstep node's module published on ``key`` during a tick (its header's source and seq)."""

    key: str
    source: str
    seq: int


class Clock(Message, tag="clock"):
    """Simulation clock published by the world; nodes step their modules on it."""

    t: float  # s of simulated time
    real_time_factor: float = 1.0
    tick: int = 0  # control tick of the world; lockstep nodes answer each one
    marks: list[Mark] = []  # what the lockstep nodes published during the previous tick: a subscriber steps once it has them


class LockstepAck(Message, tag="lockstep_ack"):
    """A lockstep node stepped its modules for world tick ``tick`` (and sent what they commanded)."""

    node: str
    tick: int
    marks: list[Mark] = []  # the last message of each stream its modules published during the tick


class Vector(Message, tag="vector"):
    """A plain numeric vector output (generic service output)."""

    values: list[float]
    names: list[str] = []


class Array(Message, tag="array"):
    """A generic array output (images, clouds, grids)."""

    max_bytes = 64 << 20
    array: NDArray
    frame: str = "world"


class Text(Message, tag="text"):
    text: str

