"""The robot side of the broker: advertise capabilities, bid on ATDs, run the ESTD, report.

A robot agent lives on the robot's control node. It announces the robot with a liveliness
token, answers ``caps``, ``translate`` (a dry run whose bid carries the ESTD), ``run`` (that
ESTD, sent back by the broker and checked before it runs) and ``cancel`` queryables, and
runs the task with an :class:`Executor`, streaming progress in the ATD's own state and
transition names on ``broker/progress/<task_id>``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from contactflow.abstraction.atd import AtdError, parse_atd
from contactflow.abstraction.bid import bid
from contactflow.abstraction.estd import EstdError, estd_message, received
from contactflow.abstraction.messages import (
    AbstractProgressMsg,
    Bid,
    Capabilities,
    RunReply,
    RunRequest,
    TranslateRequest,
)
from contactflow.abstraction.profiles import RobotProfile
from contactflow.abstraction.translator import (
    AbstractProgress,
    Translation,
)
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.status import Event
from contactflow.nodes.transport import Handle, Transport
from contactflow.nodes.wire import Stamper, WireError, decode, encode


class Executor(Protocol):
    """Runs a translated task; returns the concrete event that ended it."""

    def __call__(self, translation: Translation, report: Callable[[AbstractProgress], None],
                 cancel: threading.Event, params: dict[str, Any]) -> Event: ...


def dry_run(profile: RobotProfile, atd_text: str, file: str) -> tuple[Bid, Translation | None]:
    """Parse and translate for ``profile``: a bid (carrying the ESTD), and the translation when it succeeded."""
    try:
        atd = parse_atd(atd_text, file)
    except AtdError as exc:
        return Bid(robot=profile.name, ok=False, reasons=exc.issues), None
    b = bid(atd, profile)
    if not b.ok or b.translation is None:
        return Bid(robot=profile.name, ok=False, reasons=list(b.reasons)), None
    tr = b.translation
    if not math.isfinite(b.duration):  # a wire message carries finite numbers only
        return Bid(robot=profile.name, ok=False, reasons=[f"{file}: no state sequence of the translation reaches success"]), None
    return Bid(robot=profile.name, ok=True, notes=list(tr.notes), estimated_duration=b.duration,
               estd=estd_message(tr)), tr


EXAMPLES = Path(__file__).parent / "examples"


def warm(profile: RobotProfile) -> None:
    """Translate the shipped example ATDs for ``profile`` once, keeping nothing: the first
    dispatch then finds the primitives' modules imported (open3d, pinocchio models...)."""
    for f in sorted(EXAMPLES.glob("*.xml")):
        dry_run(profile, f.read_text(), f.name)


@dataclass
class _Job:
    task_id: str
    attempt: int
    cancel: threading.Event
    thread: threading.Thread
    ended: bool = False  # its final report is going out: the robot takes the next task (the thread only returns)

    @property
    def running(self) -> bool:
        return not self.ended and self.thread.is_alive()


class RobotAgent:
    """Advertises one robot and runs dispatched tasks on it (one at a time)."""

    def __init__(self, profile: RobotProfile, transport: Transport, ks: KeySpace, executor: Executor,
                 node: str = "", source: str = "", now: Callable[[], float] = time.time) -> None:
        self.profile = profile
        # replies and progress carry the agent module's path and its node's clock
        self.stamp = Stamper(source or f"{profile.name}/{node or 'agent'}/agent", now)
        self.transport = transport
        self.ks = ks
        self.executor = executor
        self.node = node
        self.log = logging.getLogger(f"contactflow.agent.{profile.name}")
        self._handles: list[Handle] = []
        self._job: _Job | None = None
        self._lock = threading.Lock()
        self.rejected = 0

    @property
    def busy(self) -> bool:
        with self._lock:
            return self._job is not None and self._job.running

    def start(self) -> None:
        """Warm the translation path, then answer on the key space and announce the robot."""
        warm(self.profile)
        r, t = self.profile.name, self.transport
        self._handles = [
            t.queryable(self.ks.robot_service(r, "caps"), self._on_caps),
            t.queryable(self.ks.robot_service(r, "translate"), self._on_translate),
            t.queryable(self.ks.robot_service(r, "run"), self._on_run),
            t.queryable(self.ks.robot_service(r, "cancel"), self._on_cancel),
            t.token(self.ks.alive_robot(r)),
        ]

    def stop(self) -> None:
        with self._lock:
            job = self._job
        if job is not None:
            job.cancel.set()
            job.thread.join(timeout=10)
        for h in self._handles:
            h.close()
        self._handles = []

    def capabilities(self) -> Capabilities:
        p = self.profile
        return Capabilities(robot=p.name, hand=str(p.hand), sensors=sorted(str(s) for s in p.sensors),
                            primitives=sorted(p.capabilities), workspace_center=list(p.workspace.center),
                            workspace_radius=p.workspace.radius, busy=self.busy, node=self.node)

    # -- queryables ------------------------------------------------------------------------
    def _on_caps(self, key: str, payload: bytes) -> bytes:
        return encode(self.stamp(self.capabilities(), key))  # the request carries nothing the answer depends on

    def _on_translate(self, key: str, payload: bytes) -> bytes:
        try:
            req = decode(payload, TranslateRequest, key)
        except WireError as exc:
            self.rejected += 1
            return encode(self.stamp(Bid(robot=self.profile.name, ok=False, reasons=[str(exc)]), key))
        bid, _ = dry_run(self.profile, req.atd, req.file)
        bid.busy = self.busy
        return encode(self.stamp(bid, key, [req.hdr.id]))

    def _on_run(self, key: str, payload: bytes) -> bytes:
        try:
            req = decode(payload, RunRequest, key)
        except WireError as exc:
            self.rejected += 1
            return encode(self.stamp(RunReply(ok=False, robot=self.profile.name, error=str(exc)), key))
        reply = self._run(key, req)
        return encode(self.stamp(reply, key, [req.hdr.id]))

    def _run(self, key: str, req: RunRequest) -> RunReply:
        try:
            tr = received(req.estd, self.profile, f"{key} (task {req.task_id}, {req.file})")
        except EstdError as exc:
            self.rejected += 1
            self.log.warning("%s", exc)
            return RunReply(ok=False, robot=self.profile.name, error=str(exc))
        with self._lock:
            if self._job is not None and self._job.running:
                return RunReply(ok=False, robot=self.profile.name, error=f"busy with task {self._job.task_id}")
            cancel = threading.Event()
            thread = threading.Thread(target=self._execute, args=(req, tr, cancel),
                                      name=f"agent-{self.profile.name}-{req.task_id}", daemon=True)
            self._job = _Job(req.task_id, req.attempt, cancel, thread)
            thread.start()
        return RunReply(ok=True, robot=self.profile.name)

    def _on_cancel(self, key: str, payload: bytes) -> bytes:
        with self._lock:
            job = self._job
        if job is not None:
            job.cancel.set()
        return encode(self.stamp(RunReply(ok=job is not None, robot=self.profile.name,
                                          error="" if job else "no task running"), key))

    # -- execution -------------------------------------------------------------------------
    def _execute(self, req: RunRequest, tr: Translation, cancel: threading.Event) -> None:
        key = self.ks.progress(req.task_id)
        pub = self.transport.publisher(key)
        run = [req.hdr.id]  # every report follows from the run request

        def report(p: AbstractProgress) -> None:
            msg = AbstractProgressMsg(task_id=req.task_id, robot=self.profile.name, kind=str(p.kind),
                                      state=p.state, transition=p.transition,
                                      event=str(p.event) if p.event else "",
                                      concrete=str(p.concrete) if p.concrete else "", detail=p.detail,
                                      attempt=req.attempt)
            pub(encode(self.stamp(msg, key, run)))

        try:
            outcome = self.executor(tr, report, cancel, dict(req.params))
        except Exception as exc:  # the executor failed: report it as the robot's failure
            self.log.exception("task %s failed", req.task_id)
            outcome, detail = Event.HARDWARE_FAILURE, f"executor raised {type(exc).__name__}: {exc}"
        else:
            detail = ""
        final = AbstractProgressMsg(task_id=req.task_id, robot=self.profile.name, kind="finished",
                                    final=True, outcome=str(outcome), detail=detail, attempt=req.attempt)
        with self._lock:
            # free before the report: a broker that hears the end may send the next task at once
            if self._job is not None and self._job.thread is threading.current_thread():
                self._job.ended = True
        pub(encode(self.stamp(final, key, run)))
