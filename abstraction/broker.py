"""The abstraction broker: dispatch one ATD to whichever robot can translate it, fail over.

The broker answers ``broker/dispatch``. For each request it validates the ATD (an invalid
one is never dispatched), asks every candidate robot for a dry-run translation and a bid
(one wildcard query on ``broker/robots/*/translate``), picks the best (``any``), every
capable robot (``all``) or the named one, and starts the task there by sending each the
ESTD its bid carried (the translation chosen at bid time). Robots stream progress
on ``broker/progress/<task_id>``; the broker adds its own reports there (assigned,
failover, refused, and the task's end). When a running robot's liveliness token vanishes or
it ends with ``hardware_failure``, the task is re-dispatched to the next capable robot.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from contactflow.abstraction.atd import AtdError, parse_atd
from contactflow.abstraction.dispatch import DispatchRefused, TaskRecord, choose
from contactflow.abstraction.messages import (
    AbstractProgressMsg,
    Bid,
    DispatchReply,
    DispatchRequest,
    RunReply,
    RunRequest,
    TranslateRequest,
)
from contactflow.nodes.acl import AccessDenied
from contactflow.nodes.keys import ANY, KeyExprError, KeySpace, segment
from contactflow.nodes.status import Event
from contactflow.nodes.transport import Handle, Transport
from contactflow.nodes.wire import Stamper, WireError, decode, encode

BROKER = "broker"
FAILOVER_OUTCOMES = frozenset({str(Event.HARDWARE_FAILURE)})
MAX_PARALLEL_RUNS = 16  # run requests in flight at once for one dispatch


class Broker:
    """Dispatches abstract tasks to robots over a transport."""

    def __init__(self, transport: Transport, ks: KeySpace, bid_timeout: float = 3.0, source: str = "site/broker/broker",
                 now: Callable[[], float] = time.time) -> None:
        self.stamp = Stamper(source, now)  # requests, replies and reports carry the broker module's path and clock
        self.transport = transport
        self.ks = ks
        self.bid_timeout = bid_timeout
        self.log = logging.getLogger("contactflow.broker")
        self.tasks: dict[str, TaskRecord] = {}
        self._lock = threading.RLock()
        self._work: queue.Queue = queue.Queue()
        self._handles: list[Handle] = []
        self._thread: threading.Thread | None = None
        self.rejected = 0
        self._reports: dict[str, Callable[[bytes], None]] = {}  # task id -> its progress publisher

    def start(self) -> None:
        t = self.transport
        self._handles = [
            t.watch_alive(self.ks.alive_robot(), self._on_alive),
            t.subscribe(self.ks.progress(), self._on_progress),
            t.queryable(self.ks.dispatch(), self._on_dispatch),
        ]
        self._thread = threading.Thread(target=self._worker, name="broker", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        for h in self._handles:
            h.close()
        self._handles = []
        self._work.put(None)
        if self._thread is not None:
            self._thread.join(timeout=5)

    # -- dispatch ----------------------------------------------------------------------------
    def _on_dispatch(self, key: str, payload: bytes) -> bytes:
        try:
            req = decode(payload, DispatchRequest, key)
        except WireError as exc:
            self.rejected += 1
            return encode(self.stamp(DispatchReply(ok=False, task_id="", error=str(exc)), key))
        try:
            reply = self.dispatch(req)
        except Exception as exc:  # a caller is answered whatever went wrong, never left to its timeout
            self.log.exception("dispatch of %r", req.task_id[:100])
            reply = DispatchReply(ok=False, task_id=req.task_id[:100],
                                  error=f"broker: dispatch failed: {type(exc).__name__}: {exc}")
        return encode(self.stamp(reply, key, [req.hdr.id]))

    def dispatch(self, req: DispatchRequest) -> DispatchReply:
        try:  # the id names the task's progress key: refused before anything is reported or kept under it
            if req.task_id == ANY:
                raise KeyExprError(f"task_id={req.task_id!r} is a wildcard, not a task id")
            segment(req.task_id, "task_id")
        except KeyExprError as exc:
            self.rejected += 1
            return DispatchReply(ok=False, task_id=req.task_id[:100], error=str(exc))
        try:
            parse_atd(req.atd, req.file)
        except AtdError as exc:
            self._report(req.task_id, "refused", detail="invalid ATD:\n" + "\n".join(exc.issues), final=True,
                         outcome=str(Event.ERROR))
            return DispatchReply(ok=False, task_id=req.task_id, error="invalid ATD, not dispatched:\n" + str(exc))
        record = TaskRecord(req.task_id, req.atd, req.file, req.target, params=dict(req.params))
        with self._lock:
            if req.task_id in self.tasks:
                return DispatchReply(ok=False, task_id=req.task_id, error=f"task id {req.task_id!r} is in use")
            self.tasks[req.task_id] = record
        try:
            started = self._assign(record)
        except DispatchRefused as exc:
            record.done = True
            self._report(req.task_id, "refused", detail=str(exc), final=True, outcome=str(Event.FAILURE))
            return DispatchReply(ok=False, task_id=req.task_id, refusals=exc.refusals, error=str(exc))
        return DispatchReply(ok=True, task_id=req.task_id, robots=started)

    def bids(self, task_id: str, atd: str, file: str, target: str) -> list[Bid]:
        robot = target if target not in ("any", "all") else "*"
        req = encode(self.stamp(TranslateRequest(task_id=task_id, atd=atd, file=file), "translate"))
        out = []
        for key, payload in self.transport.query(self.ks.robot_service(robot, "translate"), req, self.bid_timeout):
            try:
                out.append(decode(payload, Bid, key))
            except WireError as exc:
                self.log.warning("bad bid on %s: %s", key, exc)
        return out

    def _assign(self, record: TaskRecord) -> list[str]:
        """Pick robots for ``record`` and start them; raises DispatchRefused when none starts."""
        bids = self.bids(record.task_id, record.atd, record.file, record.target)
        refusals: dict[str, list[str]] = {}
        while True:
            try:
                chosen = choose(record.target, bids, exclude=record.failed | set(refusals))
            except DispatchRefused as exc:
                exc.refusals.update(refusals)
                raise DispatchRefused(exc.refusals) from None
            by_robot = {b.robot: b for b in bids}
            started = []
            for robot in chosen:
                # recorded and reported before the run request: a fast robot may finish first
                with self._lock:
                    record.running.add(robot)
                self._report(record.task_id, "assigned", robot_detail=robot,
                             detail=f"running on {robot} (attempt {record.attempt})")
            for robot, reply in zip(chosen, self._run_all(record, [by_robot[r] for r in chosen]), strict=True):
                if reply.ok:
                    started.append(robot)
                else:
                    with self._lock:
                        record.running.discard(robot)
                    refusals[robot] = [reply.error or "refused to run"]
                    self._report(record.task_id, "declined", robot_detail=robot, detail=f"{robot}: {reply.error}")
            if started:
                return started
            if record.target == "all":
                raise DispatchRefused(refusals)

    def _run_all(self, record: TaskRecord, bids: list[Bid]) -> list[RunReply]:
        """Run requests to every chosen robot at once, so none waits for another's answer."""
        if len(bids) == 1:
            return [self._run_on(record, bids[0])]
        with ThreadPoolExecutor(max_workers=min(len(bids), MAX_PARALLEL_RUNS), thread_name_prefix="broker-run") as pool:
            return list(pool.map(lambda b: self._run_on(record, b), bids))

    def _run_on(self, record: TaskRecord, bid: Bid) -> RunReply:
        robot = bid.robot
        if bid.estd is None:
            return RunReply(ok=False, robot=robot, error="its bid carried no ESTD")
        req = encode(self.stamp(RunRequest(task_id=record.task_id, estd=bid.estd, file=record.file,
                                           attempt=record.attempt, params=record.params), "run", [bid.hdr.id]))
        try:
            replies = self.transport.query(self.ks.robot_service(robot, "run"), req, self.bid_timeout)
        except AccessDenied as exc:
            return RunReply(ok=False, robot=robot, error=str(exc))
        if not replies:
            return RunReply(ok=False, robot=robot, error="no answer to run")
        try:
            return decode(replies[0][1], RunReply, replies[0][0])
        except WireError as exc:
            return RunReply(ok=False, robot=robot, error=str(exc))

    # -- monitoring ----------------------------------------------------------------------------
    def _on_alive(self, key: str, alive: bool) -> None:
        robot = key.rsplit("/", 1)[-1]
        if not alive:
            self._work.put(("lost", robot, "its node disappeared (liveliness lost)"))

    def _on_progress(self, key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, AbstractProgressMsg, key)
        except WireError as exc:
            self.rejected += 1
            self.log.warning("%s", exc)
            return
        if msg.robot != BROKER and msg.final:
            self._work.put(("final", msg.task_id, msg.robot, msg.outcome, msg.attempt))

    def _worker(self) -> None:
        while True:
            item = self._work.get()
            if item is None:
                return
            try:
                if item[0] == "lost":
                    self._robot_lost(item[1], item[2])
                else:
                    self._robot_final(*item[1:])
            except Exception:  # keep the broker alive whatever one task does
                self.log.exception("broker worker")

    def _robot_lost(self, robot: str, why: str) -> None:
        with self._lock:
            affected = [r for r in self.tasks.values() if robot in r.running and not r.done]
        for record in affected:
            self._failover(record, robot, why)

    def _robot_final(self, task_id: str, robot: str, outcome: str, attempt: int) -> None:
        with self._lock:
            record = self.tasks.get(task_id)
        if record is None or record.done or robot not in record.running or attempt != record.attempt:
            return
        if outcome in FAILOVER_OUTCOMES:
            self._failover(record, robot, f"ended with {outcome}")
            return
        with self._lock:
            over = record.robot_finished(robot, outcome)
        if over:
            self._finish(record)

    def _failover(self, record: TaskRecord, robot: str, why: str) -> None:
        with self._lock:
            move = record.robot_failed(robot, why)
        if not move:
            if not record.running:
                self._finish(record)
            return
        record.attempt += 1
        self._report(record.task_id, "failover", detail=f"{robot} {why}; re-dispatching")
        try:
            self._assign(record)
        except DispatchRefused as exc:
            self._report(record.task_id, "refused", detail=str(exc))
            self._finish(record)

    def _finish(self, record: TaskRecord) -> None:
        record.done = True
        ok = [r for r, o in record.finished.items() if o == str(Event.SUCCESS)]
        outcome = str(Event.SUCCESS) if ok else str(Event.FAILURE)
        summary = ", ".join(f"{r}: {o}" for r, o in sorted(record.finished.items()))
        self._report(record.task_id, "finished", detail=summary, final=True, outcome=outcome)

    def _report(self, task_id: str, kind: str, detail: str = "", final: bool = False, outcome: str = "",
                robot_detail: str = "") -> None:
        msg = AbstractProgressMsg(task_id=task_id, robot=BROKER, kind=kind, detail=detail, final=final,
                                  outcome=outcome, state=robot_detail)
        key = self.ks.progress(task_id)
        with self._lock:
            put = self._reports.get(task_id)
            if put is None:  # one publisher per task's key, declared at its first report
                put = self._reports[task_id] = self.transport.publisher(key)
            if final:
                del self._reports[task_id]
        put(encode(self.stamp(msg, key)))
