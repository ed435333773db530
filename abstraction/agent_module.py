"""A robot's broker agent as a module on the robot's control node (``type: robot_agent``)."""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass, field
from typing import Any

from contactflow.abstraction.agent import RobotAgent
from contactflow.abstraction.profiles import PROFILES
from contactflow.nodes.keys import ANY, KeySpace
from contactflow.nodes.messages import EventMsg
from contactflow.nodes.module import Layer, Module, ModuleIO, Port
from contactflow.nodes.params import ParamError
from contactflow.nodes.status import Event, Status


@dataclass
class _Job:
    """A task the agent's broker thread hands to the module's step loop, and its outcome."""

    translation: Any
    report: Any
    cancel: threading.Event
    params: dict
    outcome: Event = Event.ERROR
    done: threading.Event = field(default_factory=threading.Event)


@dataclass
class _Running:
    """The task under way in the module's step: its engine and run, the runner fed with events.

    Objects the ATD asks to detect are found first (``detect``: parameter -> its detect_objects
    instance, or "" before it started); the engine launches once every one is bound.
    """

    job: _Job
    engine: Any  # TaskEngine
    inner: Any  # ControlRunner
    t0: float  # s on the node's clock when it started
    params: dict  # the run's bound parameters (world frame)
    detect: dict[str, str] = field(default_factory=dict)
    run_id: str = ""


class RobotAgentModule(Module):
    """Advertises the robot, bids on ATDs and runs the ESTDs it is given.

    The task engine runs in this module's step on the robot's control node, in lockstep with
    the world: it starts and stops the node's primitive modules with control messages and
    follows their events, and the primitives drive the world's robot over the key space. The
    robot's contact fusion runs beside it, as modules of the node (a manifest node's ``contacts: true``).
    """

    layer = Layer.TASK
    autostart = True
    inputs = (Port("events", EventMsg, "events of the primitive modules of this robot"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 20.0  # Hz, task engine ticks
        robot: str = "tombatossals"  # embodiment name
        pool: int = 2  # modules per primitive type on the node (T, T_2, ...)
        max_time: float = 120.0  # s of simulated time a task may run

        def validate(self) -> None:
            if self.robot not in PROFILES:
                raise ValueError(f"robot: {self.robot!r} is not one of {sorted(PROFILES)}")

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """Without wiring, the events of every module of the robot (its primitives, wherever they run)."""
        return {"events": ks.events(robot, ANY, ANY)}

    def setup(self, io: ModuleIO) -> None:
        super().setup(io)
        self._agent: RobotAgent | None = None
        self._jobs: queue.Queue[_Job] = queue.Queue()
        self._run: _Running | None = None  # the task under way

    def start(self) -> None:
        try:
            self.params.validate()
        except ValueError as exc:
            raise ParamError(str(exc)) from None
        self._agent = RobotAgent(PROFILES[self.params.robot], self.io.transport, self.io.keyspace,
                                 self._executor, node=self.io.node, source=f"{self.io.robot}/{self.io.node}/{self.name}",
                                 now=lambda: self.io.now)
        self._agent.start()

    # -- the executor: the broker thread hands a task to the step loop and waits ------------
    def _executor(self, translation, report, cancel, params) -> Event:
        job = _Job(translation, report, cancel, dict(params or {}))
        self._jobs.put(job)
        self.io.wake()  # picked up at the node's next tick, not at the next 20 Hz step; a paused world resumes
        while not job.done.wait(0.2):
            if self.state is not Status.RUNNING:  # the module was stopped: nobody steps the task
                return Event.ERROR
        return job.outcome

    def busy(self) -> bool:
        """Busy with a task under way or handed over, not merely for running (the agent always runs)."""
        return self.state is Status.RUNNING and (self._run is not None or not self._jobs.empty())

    def _begin(self, job: _Job) -> _Running:
        from contactflow.abstraction.execution import bound_params, robot_runner, to_detect
        from contactflow.embodiments.remote import connect
        from contactflow.nodes.task_module import ControlRunner
        from contactflow.nodes.taskengine import TaskEngine

        io, p = self.io, self.params
        robot = connect(io.transport, io.keyspace, io.robot, io.node)
        inner = ControlRunner(io, io.robot, p.pool)
        tr = job.translation
        engine = TaskEngine(robot_runner(inner, robot, p.robot, robot.hand_points), lambda: io.now,
                            on_progress=lambda pr: job.report(tr.abstract(pr)))
        params = bound_params(tr, job.params)
        detect = dict.fromkeys(to_detect(tr, params), "")
        r = _Running(job, engine, inner, io.now, params, detect)
        if not detect:
            r.run_id = engine.launch(tr.estd, params)
        return r

    def _detect(self, r: _Running) -> None:
        """Find the next object the ATD asks to detect with the node's detect_objects; launch when all are bound.

        Its location is the centre of its top face across (the camera sees an object's top whole
        but only its near side, which pulls the centroid of all its points toward the camera) and
        half the seen height below its top.
        """
        key = next(iter(r.detect))
        if not r.detect[key]:
            r.detect[key] = f"detect_{key}"
            r.inner.start(r.detect[key], "detect_objects", {})
        instance = r.detect[key]
        for e in r.inner.poll():
            if e.instance != instance or e.event not in (Event.SUCCESS, Event.FAILURE, Event.ERROR):
                continue
            r.inner.stop(e.instance)
            if e.event is not Event.SUCCESS:
                self.io.log(f"task not started: {key} was not detected: {e.detail}")
                r.job.outcome = Event.FAILURE
                self._run = None
                r.job.done.set()
                return
            v = e.values
            r.params[key] = [float(v["tx"]), float(v["ty"]), float(v["top"]) - 0.5 * float(v["size_z"])]
            self.io.log(f"{key} detected at {[round(c, 3) for c in r.params[key]]} ({e.detail})")
            del r.detect[key]
            break  # its first outcome carries the values; the module's status event that follows is the same outcome
        if not r.detect:
            r.run_id = r.engine.launch(r.job.translation.estd, r.params)

    def _advance(self, r: _Running) -> None:
        r.inner.feed([m for m in self.io.take("events") if isinstance(m, EventMsg)])
        if r.detect:
            self._detect(r)
            return
        r.engine.tick()
        if not r.engine.done(r.run_id):
            if r.job.cancel.is_set():
                r.engine.cancel(r.run_id, "cancelled")
            elif self.io.now - r.t0 >= self.params.max_time:
                r.engine.cancel(r.run_id, f"gave up after {self.params.max_time:g} s")
        if r.engine.done(r.run_id):
            result = r.engine.result(r.run_id)
            r.job.outcome = result.event if result is not None else Event.ERROR
            self._run = None
            r.job.done.set()

    def step(self) -> Status:
        if self._run is None:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                self.io.take("events")  # nothing runs: old events belong to nobody
                return Status.RUNNING
            try:
                self._run = self._begin(job)
            except Exception as exc:  # the robot does not answer, a hand was not measured...
                self.io.log(f"task not started: {type(exc).__name__}: {exc}")
                job.outcome = Event.HARDWARE_FAILURE
                job.done.set()
                return Status.RUNNING
        self._advance(self._run)
        return Status.RUNNING

    def stop(self) -> None:
        if self._run is not None:
            r, self._run = self._run, None
            if r.run_id:
                r.engine.cancel(r.run_id, "agent stopped")
            r.job.outcome = Event.ERROR
            r.job.done.set()
        if self._agent is not None:
            self._agent.stop()
            self._agent = None
