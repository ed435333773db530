"""Wire messages of the abstraction broker: capabilities, bids, dispatch and abstract progress."""

from __future__ import annotations

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


class Bid(Message, tag="bid"):
    """A robot's answer to a dry run: can it, and how well."""

    robot: str
    ok: bool
    reasons: list[str] = []
    notes: list[str] = []
    estimated_duration: float = 0.0  # s
    busy: bool = False


PlanValue = float | str | list[float]


class RunRequest(Message, tag="run_request"):
    max_bytes = 256 << 10
    task_id: str
    atd: str
    file: str = "<dispatch>"
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
