"""Task-layer module (thesis §6.1.4): runs a YAML task with the task engine on a node.

The shell is thin: :class:`ControlRunner` starts and stops primitive modules with control
messages (``RUN`` with the node's parameters, ``STOP``) and turns the events arriving on the
``events`` input into runner events; the engine does the rest. Progress goes out on the
``progress`` port; the task's outcome is raised as the module's own event, so a task can
be a node of another task running elsewhere.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import yaml

from contactflow.nodes.keys import ANY, KeySpace
from contactflow.nodes.messages import Command, EventMsg, ParamValue
from contactflow.nodes.module import Layer, Module, ModuleIO, Port
from contactflow.nodes.status import STATUS_EVENT, Event, Status
from contactflow.nodes.taskengine import PrimitiveRunner, Progress, RunnerEvent, TaskEngine
from contactflow.nodes.taskfile import load_tasks
from contactflow.nodes.taskgraph import TaskError, TaskGraph
from contactflow.nodes.wire import Message


class TaskProgressMsg(Message, tag="task_progress"):
    """One progress report of a running task (:class:`~contactflow.nodes.taskengine.Progress`)."""

    kind: str  # started | entered | event | edge | finished
    run: str  # the run's id
    path: list[str]  # task names and nested node ids down to the node concerned
    node: str = ""  # the task graph node entered or left
    label: str = ""  # the caller's name of that node (an ATD state)
    edge: str = ""  # the edge taken
    edge_label: str = ""  # the caller's name of the edge (an ATD transition)
    event: str = ""  # the event that fired the edge or ended the run
    source: str = ""  # the module (instance) that raised the event
    detail: str = ""  # why (the event's detail)
    implicit: bool = False  # a fault exit no edge of the graph declares


def progress_msg(p: Progress) -> TaskProgressMsg:
    return TaskProgressMsg(kind=str(p.kind), run=p.run, path=list(p.path), node=p.node,
                           label=p.label, edge=p.edge, edge_label=p.edge_label,
                           event=str(p.event) if p.event is not None else "", source=p.source,
                           detail=p.detail, implicit=p.implicit)


def _wire_params(params: Mapping[str, Any], where: str) -> dict[str, ParamValue]:
    out: dict[str, ParamValue] = {}
    for k, v in params.items():
        if isinstance(v, bool | int | float | str):
            out[k] = v
        elif isinstance(v, list | tuple) and all(isinstance(x, str) for x in v):
            out[k] = [str(x) for x in v]
        elif isinstance(v, list | tuple) and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v):
            out[k] = [float(x) for x in v]
        else:
            raise TaskError([f"{where}: parameter {k!r}={v!r} cannot travel in a control message"])
    return out


class ControlRunner:
    """A :class:`~contactflow.nodes.taskengine.PrimitiveRunner` over a module's I/O.

    Primitive type ``T`` runs as module ``robot/T``; when that one is busy (two detectors of
    one node, parallel branches) the next free of ``T_2`` ... ``T_<pool>`` is used, so a
    node hosting a pool of modules per type runs them side by side. Events are fed with
    :meth:`feed` from the module's ``events`` input.
    """

    def __init__(self, io: ModuleIO, robot: str = "", pool: int = 3) -> None:
        self.io, self.robot, self.pool = io, robot, max(1, pool)
        self._by_module: dict[str, str] = {}  # module name -> running instance
        self._module_of: dict[str, str] = {}  # instance -> module name
        self._queue: list[RunnerEvent] = []
        self._started: dict[str, float] = {}  # module -> when its current instance started

    def _target(self, module: str) -> str:
        return f"{self.robot}/{module}" if self.robot else module

    def start(self, instance: str, type: str, params: Mapping[str, Any]) -> None:
        names = [type] + [f"{type}_{k}" for k in range(2, self.pool + 1)]
        module = next((n for n in names if n not in self._by_module), None)
        if module is None:
            self._queue.append(RunnerEvent(instance, Event.ERROR, detail=f"all {self.pool} "
                                           f"modules of type {type!r} are busy"))
            return
        try:
            wire = _wire_params(params, instance)
        except TaskError as exc:
            self._queue.append(RunnerEvent(instance, Event.ERROR, detail=str(exc)))
            return
        target = self._target(module)
        self.io.command(target, Command.RESET)  # the configured parameters, then this node's
        if wire:
            reply = self.io.command(target, Command.SET, wire)
            if not reply.ok:
                self._queue.append(RunnerEvent(instance, Event.ERROR, detail=f"{target}: {reply.error}"))
                return
        reply = self.io.command(target, Command.RUN)
        if not reply.ok:
            self._queue.append(RunnerEvent(instance, Event.ERROR, detail=f"{target}: {reply.error}"))
            return
        self._by_module[module] = instance
        self._module_of[instance] = module
        self._started[module] = self.io.now

    def stop(self, instance: str) -> None:
        module = self._module_of.pop(instance, None)
        if module is None:
            return
        del self._by_module[module]
        self.io.command(self._target(module), Command.STOP)

    def feed(self, msgs: list[EventMsg]) -> None:
        for m in msgs:
            module = m.module.rsplit("/", 1)[-1]
            inst = self._by_module.get(module)
            # an event stamped before the instance started belongs to a previous activation
            stale = 0.0 < m.hdr.t_sim < self._started.get(module, 0.0) - 1e-9
            if inst is not None and not stale:
                self._queue.append(RunnerEvent(inst, m.event, dict(m.values), m.detail))

    def poll(self) -> list[RunnerEvent]:
        out, self._queue = self._queue, []
        return out


class TaskModule(Module):
    """Runs the main task of a YAML task file; finishes with the task's outcome.

    A caller in the same process may hand it the task instead (``graph``, its ``library`` and
    ``plan``), and the runner its engine drives (``runner``: the in-process runner, whose
    primitives are hosted beside it); the host then steps it as any module, after the
    primitives of the tick (:meth:`~contactflow.nodes.host.ModuleHost.tick`).
    """

    layer = Layer.TASK
    inputs = (Port("events", EventMsg, "events of the primitives the task runs"),)
    outputs = (Port("progress", TaskProgressMsg, "states entered, edges taken, outcome"),)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT, Event.HARDWARE_FAILURE)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 20.0  # Hz, engine tick rate
        task_file: str = ""  # path of the YAML task file
        task: str = ""  # task to run (default: the file's main task)
        robot: str = ""  # robot whose primitive modules the task commands (default: own)
        plan: str = ""  # YAML mapping binding the task's parameters, e.g. "{x: [0, 0, 1]}"
        pool: int = 3  # modules per primitive type the node hosts (T, T_2, ... T_pool)

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """Without wiring, the events of every module of the robot it commands, wherever they run."""
        return {"events": ks.events(params.robot or robot, ANY, ANY)}

    def __init__(self, name: str, params: Params | None = None, graph: TaskGraph | None = None,
                 library: Mapping[str, TaskGraph] | None = None, plan: Mapping[str, Any] | None = None,
                 runner: PrimitiveRunner | None = None, on_progress: Callable[[Progress], None] | None = None) -> None:
        super().__init__(name, params)
        self._graph, self._library, self._plan = graph, library, dict(plan or {})
        self._runner, self._on_progress = runner, on_progress

    def setup(self, io: ModuleIO) -> None:
        super().setup(io)
        self.runner = self._runner or ControlRunner(io, self.params.robot, self.params.pool)
        self.engine = TaskEngine(self.runner, lambda: io.now, library=self._library, on_progress=self._progress)
        self.run_id = ""

    def _progress(self, p: Progress) -> None:
        assert self.io is not None
        self.io.publish("progress", progress_msg(p))
        if self._on_progress is not None:
            self._on_progress(p)

    def start(self) -> None:
        if self._graph is not None:
            self.run_id = self.engine.launch(self._graph, self._plan)
            return
        tasks, main = load_tasks(self.params.task_file)
        name = self.params.task or main
        if name not in tasks:
            raise TaskError([f"{self.params.task_file}: no task {name!r} (tasks: {sorted(tasks)})"])
        plan = yaml.safe_load(self.params.plan) if self.params.plan.strip() else {}
        if not isinstance(plan, dict):
            raise TaskError([f"{self.name}.params.plan: expected a YAML mapping, got {plan!r}"])
        self.engine.library = tasks
        self.run_id = self.engine.launch(tasks[name], plan)

    def step(self) -> Status:
        assert self.io is not None
        self.runner.feed([m for m in self.io.take("events") if isinstance(m, EventMsg)])
        self.engine.tick()
        res = self.engine.result(self.run_id)
        if res is None:
            return Status.RUNNING
        if res.event is not STATUS_EVENT.get(res.status):  # the host raises the status's own event
            self.io.emit(res.event, detail=f"{res.label}: {res.detail}" if res.detail else res.label)
        return res.status

    def stop(self) -> None:
        if self.run_id and not self.engine.done(self.run_id):
            self.engine.cancel(self.run_id, "task module stopped")
