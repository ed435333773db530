"""Runtime wire messages: events, status, control, clock, module descriptions, generic data."""

from __future__ import annotations

from enum import StrEnum

import msgspec

from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import Message, NDArray

ParamValue = bool | int | float | str | list[float | str]


class EventMsg(Message, tag="event"):
    """A detected situation (thesis §6.1): an edge label of a task graph."""

    event: Event  # the event (edge label)
    module: str  # robot/node/module that raised it
    detail: str = ""  # human-readable why
    values: dict[str, float] = {}  # named numbers the event carries (e.g. a detected object's tx, ty, top)


class StatusMsg(Message, tag="status"):
    """Published by every module on change and periodically."""

    module: str  # robot/node/module
    layer: str  # service | primitive | task (thesis §6.1)
    state: Status  # the module's state
    rate_hz: float  # Hz, the module's step rate
    steps: int = 0  # steps run since it started
    cpu_s: float = 0.0  # s of CPU time those steps took (the stepping thread's; waiting costs none): what a tick spends where
    rejected: int = 0  # inputs dropped by validation
    detail: str = ""  # why the state is what it is (an error's message)
    gaps: dict[str, int] = {}  # input port -> sequence numbers its sources skipped (lost messages)
    dropped: dict[str, int] = {}  # input port -> messages pushed out of its full queue (the most queued source's oldest)


class Command(StrEnum):
    RUN = "run"
    STOP = "stop"
    RESET = "reset"
    SET = "set"
    DESCRIBE = "describe"


class ControlRequest(Message, tag="control"):
    """A control message (thesis §6.1): change a module's status or parameters."""

    cmd: Command  # what to do
    params: dict[str, ParamValue] = {}  # SET: parameter name -> value; RUN: parameters for this run
    issuer: str = ""  # who asks (robot/node/module or a tool's name), for the log and claims


class ControlReply(Message, tag="control_reply"):
    """The answer to a control request on a module's ``ctl`` key."""

    ok: bool  # the request was carried out
    error: str = ""  # why not, naming the parameter or state
    state: Status = Status.IDLE  # the module's state after the request
    params: dict[str, ParamValue] = {}  # the module's parameters after the request
    description: str = ""  # YAML module description, for DESCRIBE


class Mark(msgspec.Struct, frozen=True, kw_only=True):
    """The last message a lockstep node's module published on ``key`` during a tick (its header's source and seq)."""

    key: str  # the key expression it was published on
    source: str  # its hdr.source
    seq: int  # its hdr.seq


class Clock(Message, tag="clock"):
    """Simulation clock published by the world; nodes step their modules on it."""

    t: float  # s of simulated time
    real_time_factor: float = 1.0  # simulated over wall seconds, measured by the world
    tick: int = 0  # control tick of the world; lockstep nodes answer each one
    marks: list[Mark] = []  # what the lockstep nodes published during the tick lag + 1 before: a subscriber steps once it has them
    lag: int = 0  # ticks (0 or 1): with 1 the world steps tick k+1 while its nodes step tick k (a pipeline), so what a
    # node sends during tick k reaches the others and the world at tick k+2 instead of k+1, in any process layout


class LockstepAck(Message, tag="lockstep_ack"):
    """A lockstep node stepped its modules for world tick ``tick`` (and sent what they commanded).

    A node that was idle at its ack and then gets work (a primitive told to run) acks the same
    tick again with ``busy``: a world paused while its nodes were idle resumes. A node whose step
    of a tick takes long (a first plan on a loaded machine) says so every second with ``working``:
    not an answer, the world waits on for it (up to its ``max_step``) instead of holding its robots.
    """

    node: str  # the node's name
    tick: int  # the world tick it stepped (with working: the tick it is stepping)
    marks: list[Mark] = []  # the last message of each stream its modules published during the tick
    busy: bool = False  # a primitive or task of the node was running (Module.busy) when it acked
    working: bool = False  # not an answer: the node is still stepping the tick (its loop is alive)


class Vector(Message, tag="vector"):
    """A plain numeric vector output (generic service output)."""

    values: list[float]  # the numbers
    names: list[str] = []  # a name per value (empty: unnamed)


class Array(Message, tag="array"):
    """A generic array output (images, clouds, grids)."""

    max_bytes = 64 << 20
    array: NDArray  # the array
    frame: str = "world"  # coordinate frame of points in it


class Text(Message, tag="text"):
    """A plain text output (generic service output)."""

    text: str  # the text

