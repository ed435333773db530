"""Client side of the broker: dispatch an ATD and follow its abstract progress."""

from __future__ import annotations

import itertools
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field

from contactflow.abstraction.messages import (
    AbstractProgressMsg,
    Capabilities,
    CapabilitiesRequest,
    DispatchReply,
    DispatchRequest,
    PlanValue,
)
from contactflow.fusion.messages import ContactEventMsg
from contactflow.nodes.acl import AccessDenied
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.transport import Transport
from contactflow.nodes.wire import WireError, decode, encode, stamp


def new_task_id(stem: str) -> str:
    safe = "".join(c if c.isalnum() or c in "_-" else "_" for c in stem)[:40] or "task"
    return f"{safe}-{uuid.uuid4().hex[:6]}"


_SEQ = itertools.count(1)  # this process's dispatch requests, whichever source names them


@dataclass
class TaskFollow:
    """Everything seen of one dispatched task."""

    task_id: str
    reply: DispatchReply | None = None
    progress: list[AbstractProgressMsg] = field(default_factory=list)
    contacts: list[ContactEventMsg] = field(default_factory=list)
    final: AbstractProgressMsg | None = None
    done: threading.Event = field(default_factory=threading.Event)
    handles: list = field(default_factory=list)

    @property
    def outcome(self) -> str:
        if self.final is not None:
            return self.final.outcome
        return "refused" if self.reply is not None and not self.reply.ok else "unfinished"


def dispatch(transport: Transport, ks: KeySpace, atd: str, file: str, target: str = "any",
             params: dict[str, PlanValue] | None = None, task_id: str | None = None,
             on_progress: Callable[[AbstractProgressMsg], None] | None = None,
             on_contact: Callable[[ContactEventMsg], None] | None = None,
             timeout: float = 10.0, source: str = "site/tool/dispatch") -> TaskFollow:
    """Send ``atd`` to the broker; progress and contact events stream into the result.

    ``source`` names the caller in the request's header (a tool, or robot/node/module).
    """
    follow = TaskFollow(task_id or new_task_id(file.rsplit("/", 1)[-1].split(".")[0]))

    def on_prog(key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, AbstractProgressMsg, key)
        except WireError:
            return
        follow.progress.append(msg)
        if on_progress is not None:
            on_progress(msg)
        if msg.robot == "broker" and msg.final:
            follow.final = msg
            follow.done.set()

    def on_ev(key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, ContactEventMsg, key)
        except WireError:
            return
        follow.contacts.append(msg)
        if on_contact is not None:
            on_contact(msg)

    follow.handles = [transport.subscribe(ks.progress(follow.task_id), on_prog),
                      transport.subscribe(ks.fused("*", "events"), on_ev)]
    req = stamp(DispatchRequest(task_id=follow.task_id, atd=atd, file=file, target=target, params=params or {}),
                source, next(_SEQ), time.time())
    try:
        replies = transport.query(ks.dispatch(), encode(req), timeout=timeout)
    except AccessDenied as exc:
        follow.reply = DispatchReply(ok=False, task_id=follow.task_id, error=str(exc))
        follow.done.set()
        return follow
    if not replies:
        follow.reply = DispatchReply(ok=False, task_id=follow.task_id, error=f"no broker answers on {ks.dispatch()}")
        follow.done.set()
    else:
        follow.reply = decode(replies[0][1], DispatchReply, replies[0][0])
        if not follow.reply.ok:
            follow.done.set()
    return follow


def close(follow: TaskFollow) -> None:
    for h in follow.handles:
        h.close()
    follow.handles.clear()


def robots(transport: Transport, ks: KeySpace, timeout: float = 2.0) -> list[Capabilities]:
    """Capabilities of every robot advertising on the site."""
    out = []
    for key, payload in transport.query(ks.robot_service("*", "caps"), encode(CapabilitiesRequest()),
                                      timeout=timeout):
        try:
            out.append(decode(payload, Capabilities, key))
        except WireError:
            continue
    return sorted(out, key=lambda c: c.robot)
