"""Wire messages of the abstraction broker: capabilities, bids, dispatch and abstract progress."""

from __future__ import annotations

import msgspec

from contactflow.nodes.wire import Message


class CapabilitiesRequest(Message, tag="capabilities_request"):
    """Ask a robot's agent what it can do (query on ``broker/robots/<robot>/caps``; the answer is `capabilities`)."""


class Capabilities(Message, tag="capabilities"):
    """What a robot advertises to the broker (answer of ``broker/robots/<robot>/caps``)."""

    robot: str
    hand: str  # the hand's kind
    sensors: list[str]  # the robot's sensors
    primitives: list[str]  # the concrete primitive types it runs
    workspace_center: list[float]  # m, world frame
    workspace_radius: float  # m
    busy: bool = False  # it runs a task now
    node: str = ""  # the node its agent runs on


class TranslateRequest(Message, tag="translate_request"):
    """Dry run: translate this ATD and bid for it."""

    max_bytes = 256 << 10
    task_id: str  # the task's id (see dispatch)
    atd: str  # the ATD text, XML or YAML
    file: str = "<dispatch>"  # the ATD's file, to name it in messages


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
    ok: bool  # it can run the ATD
    reasons: list[str] = []  # why not, naming ATD states and fields
    notes: list[str] = []  # remarks of the translation
    estimated_duration: float = 0.0  # s
    busy: bool = False  # it runs a task now
    estd: Estd | None = None  # the translation, when ``ok``


PlanValue = float | str | list[float]


class RunRequest(Message, tag="run_request"):
    """Run this ESTD (the one the robot's bid carried); the robot checks it before running it."""

    max_bytes = 256 << 10
    task_id: str  # the task's id
    estd: Estd  # the translation to run
    file: str = "<dispatch>"  # the ATD's file, to name it in messages
    attempt: int = 1  # 1, then counts up on failover
    params: dict[str, PlanValue] = {}  # plan parameters (e.g. an object location from perception)


class RunReply(Message, tag="run_reply"):
    """A robot's answer to a run request: did it start the task."""

    ok: bool  # the robot started the task
    robot: str
    error: str = ""  # why not


class DispatchRequest(Message, tag="dispatch_request"):
    """Run an ATD on ``target``: ``any`` (best bid), ``all`` (every capable robot) or a robot name."""

    max_bytes = 256 << 10
    task_id: str  # chosen by the caller: one key segment, not in use
    atd: str  # the ATD text, XML or YAML
    file: str = "<dispatch>"  # the ATD's file, to name it in messages
    target: str = "any"  # any | all | a robot name
    params: dict[str, PlanValue] = {}  # plan parameters (e.g. an object location)


class DispatchReply(Message, tag="dispatch_reply"):
    """The broker's answer to a dispatch: which robots run the task, or why none does.

    The task then reports on ``broker/progress/<task_id>``; it has ended when the broker's
    ``abstract_progress`` with ``final`` true arrives (``outcome`` says how).
    """

    ok: bool  # the task was dispatched
    task_id: str  # the request's id
    robots: list[str] = []  # the robots that run it
    refusals: dict[str, list[str]] = {}  # robot -> why it cannot run it
    error: str = ""  # why not dispatched


class AbstractProgressMsg(Message, tag="abstract_progress"):
    """Progress of a dispatched task in the ATD's own names.

    ``robot`` is the executing robot, or ``broker`` for the broker's own reports
    (assignment, failover, the task's end). ``final`` marks a robot's (or, from the broker,
    the whole task's) last message; ``outcome`` is then the concrete event that ended it.
    """

    task_id: str  # the task's id
    robot: str
    kind: str  # started | entered | event | edge | finished | assigned | failover | refused
    state: str = ""  # the ATD state concerned
    transition: str = ""  # the ATD transition taken
    event: str = ""  # abstract event (Table 7.2)
    concrete: str = ""  # concrete event label
    detail: str = ""  # why (a concrete event's detail)
    final: bool = False  # the robot's (or, from the broker, the task's) last message
    outcome: str = ""  # the concrete event that ended it: success, failure, error, ...
    attempt: int = 1  # 1, then counts up on failover
