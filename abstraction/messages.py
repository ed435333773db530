"""Wire messages of the abstraction broker: capabilities, bids, dispatch and abstract progress."""

from __future__ import annotations

import msgspec

from contactflow.nodes.wire import Message


class Capabilities(Message, tag="capabilities"):
    """What a robot advertises to the broker (answer of ``broker/robots/<robot>/caps``)."""

    robot: str
    hand: str
    sensors: list[str]
    primitives: list[str]
    workspace_center: list[float]  # m, world frame
    workspace_radius: float  # m
    busy: bool = False
    node: str = ""


class TranslateRequest(Message, tag="translate_request"):
    """Dry run: translate this ATD and bid for it."""

    max_bytes = 256 << 10
    task_id: str
    atd: str  # the ATD text, XML or YAML
    file: str = "<dispatch>"


class EdgeEvents(msgspec.Struct, frozen=True, kw_only=True):
    """The concrete triggers of one ESTD edge that stand for one abstract event of its ATD transition."""

    edge: str  # ESTD edge id
    event: str  # abstract event (Table 7.2)
    groups: list[list[str]]  # trigger groups (all of), each any of "event" or "source.event"


class Estd(msgspec.Struct, frozen=True, kw_only=True):
    """An embodiment-specific task description as chosen at bid time: what the robot runs as is."""

    robot: str  # the robot it was translated for
    task: str  # a task file (nodes/taskfile.py) holding the ESTD; node and edge labels are ATD names
    events: list[EdgeEvents] = []  # how progress maps back to the ATD's abstract events


class Bid(Message, tag="bid"):
    """A robot's answer to a dry run: can it, and how well; with the translation it would run."""

    robot: str
    ok: bool
    reasons: list[str] = []
    notes: list[str] = []
    estimated_duration: float = 0.0  # s
    busy: bool = False
    estd: Estd | None = None  # the translation, when ``ok``


PlanValue = float | str | list[float]


class RunRequest(Message, tag="run_request"):
    """Run this ESTD (the one the robot's bid carried); the robot checks it before running it."""

    max_bytes = 256 << 10
    task_id: str
    estd: Estd
    file: str = "<dispatch>"  # the ATD's file, to name it in messages
    attempt: int = 1
    params: dict[str, PlanValue] = {}  # plan parameters (e.g. an object location from perception)


class RunReply(Message, tag="run_reply"):
    ok: bool
    robot: str
    error: str = ""


class DispatchRequest(Message, tag="dispatch_request"):
    """Run an ATD on ``target``: ``any`` (best bid), ``all`` (every capable robot) or a robot name."""

    max_bytes = 256 << 10
    task_id: str
    atd: str
    file: str = "<dispatch>"
    target: str = "any"
    params: dict[str, PlanValue] = {}


class DispatchReply(Message, tag="dispatch_reply"):
    ok: bool
    task_id: str
    robots: list[str] = []
    refusals: dict[str, list[str]] = {}
    error: str = ""


class AbstractProgressMsg(Message, tag="abstract_progress"):
    """Progress of a dispatched task in the ATD's own names.

    ``robot`` is the executing robot, or ``broker`` for the broker's own reports
    (assignment, failover, the task's end). ``final`` marks a robot's (or, from the broker,
    the whole task's) last message; ``outcome`` is then the concrete event that ended it.
    """

    task_id: str
    robot: str
    kind: str  # started | entered | event | edge | finished | assigned | failover | refused
    state: str = ""
    transition: str = ""
    event: str = ""  # abstract event (Table 7.2)
    concrete: str = ""  # concrete event label
    detail: str = ""
    final: bool = False
    outcome: str = ""
    attempt: int = 1
