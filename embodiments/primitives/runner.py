"""In-process primitive runner for the task engine: primitives stepped in lockstep with a co-located world module."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from contactflow.embodiments import registry
from contactflow.embodiments.primitives.base import Primitive, PrimitiveError, Robot
from contactflow.nodes.messages import Command, ControlReply, ParamValue
from contactflow.nodes.params import replace_params
from contactflow.nodes.registry import resolve
from contactflow.nodes.status import STATUS_EVENT, Event, Status
from contactflow.nodes.taskengine import Progress, RunnerEvent, RunResult, TaskEngine
from contactflow.nodes.taskgraph import TaskGraph
from contactflow.nodes.wire import Message, MsgId


@dataclass
class LocalIO:
    """A ModuleIO for one primitive instance: events go to the runner's queue, time is the robot's."""

    instance: str
    runner: LocalPrimitiveRunner
    logs: list[str] = field(default_factory=list)
    _latest: dict[str, Message] = field(default_factory=dict)

    @property
    def now(self) -> float:
        return self.runner.robot.time

    def latest(self, port: str) -> Message | None:
        return self._latest.get(port)

    def take(self, port: str) -> list[Message]:
        msg = self._latest.pop(port, None)
        return [msg] if msg is not None else []

    def wired(self, port: str) -> bool:
        return False  # in-process primitives read the robot, not the key space

    def publish(self, port: str, msg: Message, inputs: list[MsgId] | None = None) -> None:
        self._latest[port] = msg

    def emit(self, event: Event, detail: str = "", values: dict[str, float] | None = None,
             t_sim: float | None = None) -> None:
        self.runner._events.append(RunnerEvent(self.instance, Event(event), dict(values or {}), detail))

    def command(self, target: str, cmd: Command, params: dict[str, ParamValue] | None = None) -> ControlReply:
        return ControlReply(ok=False, error=f"{self.instance}: in-process primitives command the robot's world, "
                                             f"not module {target!r}")

    def log(self, text: str) -> None:
        self.logs.append(text)


@dataclass
class _Active:
    prim: Primitive
    next_t: float
    finished: bool = False


class LocalPrimitiveRunner:
    """:class:`~contactflow.nodes.taskengine.PrimitiveRunner` running primitives in this process.

    Primitives are created by registered short name (``contactflow.nodes.registry``), set up
    with a :class:`LocalIO` and stepped at their ``rate_hz`` by :meth:`advance` as the world
    advances. They drive ``robot`` (a simulated robot) as on a node: through the world module
    of its world, co-located on an in-process bus, whose states they read and whose command
    port checks and applies what they send (``facade``, the node's
    :class:`~contactflow.embodiments.remote.RemoteRobot`). ``defaults`` holds per-type
    parameter overrides (default: the overrides of the robot's home,
    :mod:`~contactflow.embodiments.registry`); task parameters override them.
    """

    def __init__(self, robot: Robot, defaults: Mapping[str, Mapping[str, Any]] | None = None,
                 factory: Callable[[str], type[Primitive]] | None = None) -> None:
        self.robot = robot
        self._world, self.facade = _co_located(robot)
        if defaults is None:
            defaults = registry.home(robot.spec.name).overrides
        self.defaults = {k: dict(v) for k, v in defaults.items()}
        self._factory = factory or _resolve_primitive
        self.active: dict[str, _Active] = {}
        self.started: list[tuple[str, str, dict[str, Any]]] = []
        self._events: list[RunnerEvent] = []

    def create(self, instance: str, type: str, params: Mapping[str, Any]) -> Primitive:
        cls = self._factory(type)
        merged = {**self.defaults.get(type, {}), **dict(params)}
        prim = cls(instance, replace_params(cls.Params(), merged, where=f"{instance} ({type}).params."))
        prim.bind(self.facade)
        prim.setup(LocalIO(instance, self))
        return prim

    def start(self, instance: str, type: str, params: Mapping[str, Any]) -> None:
        self.started.append((instance, type, dict(params)))
        self._world.publish_state()  # the world may have stepped without the runner since its last tick
        try:
            prim = self.create(instance, type, params)
            prim.start()
        except (PrimitiveError, ValueError, KeyError) as exc:
            self._events.append(RunnerEvent(instance, Event.ERROR, {}, f"{type}: {exc}"))
            return
        self.active[instance] = _Active(prim, self.robot.time)

    def stop(self, instance: str) -> None:
        a = self.active.pop(instance, None)
        if a is not None:
            a.prim.stop()

    def poll(self) -> list[RunnerEvent]:
        out, self._events = self._events, []
        return out

    def advance(self) -> None:
        """Step every primitive whose period has elapsed (call once per control tick)."""
        self._world.publish_state()
        now = self.robot.time
        for a in list(self.active.values()):
            if a.finished or now + 1e-9 < a.next_t:
                continue
            a.next_t += 1.0 / a.prim.params.rate_hz
            if a.next_t < now:
                a.next_t = now
            try:
                status = a.prim.step()
            except (PrimitiveError, ValueError) as exc:
                a.finished = True
                self._events.append(RunnerEvent(a.prim.name, Event.ERROR, {}, str(exc)))
                continue
            if status.finished:
                a.finished = True
                if not any(e.instance == a.prim.name and e.event is STATUS_EVENT[status] for e in self._events):
                    self._events.append(RunnerEvent(a.prim.name, STATUS_EVENT[status], dict(a.prim.result)))


def _co_located(robot: Robot):
    """The world module around ``robot``'s world on an in-process bus, and the facade primitives drive it through.

    Primitives run here as they do on a node: they read the robot's state as the world sends
    it and command it on its command port, which the world checks and applies; only the bus
    differs (in-process and synchronous, not zenoh).
    """
    from contactflow.embodiments.modules.world_module import WorldModule
    from contactflow.embodiments.remote import RemoteRobot, RobotLink
    from contactflow.nodes.config import ModuleConfig, NodeConfig
    from contactflow.nodes.host import ModuleHost
    from contactflow.nodes.transport import LocalTransport, ZenohSettings

    bus = LocalTransport()
    node = NodeConfig(site="local", node="local", host="local", robot="site", clock="wall", zenoh=ZenohSettings(),
                      modules=())
    host = ModuleHost(node, bus)
    params = WorldModule.Params(control_rate=robot.params.control_rate, ground_truth_hz=0.0)
    world = WorldModule("world", params, world=robot.world, sims=(robot,))
    host.add(ModuleConfig("world", "world", WorldModule, params, "site"), world)
    link = RobotLink(bus, host.ks, robot.name, "local")
    world.publish_state()
    return world, RemoteRobot(link)


def _resolve_primitive(type_name: str) -> type[Primitive]:
    cls = resolve(type_name)
    if not issubclass(cls, Primitive):
        raise PrimitiveError(f"module type {type_name!r} is not a manipulation primitive")
    return cls


def run_task(task: TaskGraph, robot: Robot, params: Mapping[str, Any] | None = None,
             library: Mapping[str, TaskGraph] | None = None, max_time: float = 120.0, dt: float = 0.005,
             runner: LocalPrimitiveRunner | None = None,
             on_progress: Callable[[Progress], None] | None = None) -> tuple[RunResult, TaskEngine]:
    """Run ``task`` to completion in lockstep with the world; returns the result and the engine.

    Each tick steps the due primitives, advances physics by ``dt`` s and ticks the engine.
    A run still going after ``max_time`` s of simulated time is cancelled (result ERROR).
    """
    runner = runner or LocalPrimitiveRunner(robot)
    engine = TaskEngine(runner, lambda: robot.time, library=library, on_progress=on_progress)
    run = engine.launch(task, params)
    t_end = robot.time + max_time
    while not engine.done(run):
        runner.advance()
        robot.step(dt)
        engine.tick()
        if robot.time >= t_end:
            engine.cancel(run, f"still running after {max_time:g} s of simulated time")
    for inst in list(runner.active):
        runner.stop(inst)
    res = engine.result(run)
    if res is None:
        raise RuntimeError(f"run {run!r} ended without a result")
    return res, engine


def finished_ok(res: RunResult) -> bool:
    return res.status is Status.SUCCESS


def run_primitive(runner: LocalPrimitiveRunner, type: str, params: Mapping[str, Any], max_time: float = 30.0,
                  dt: float = 0.005, instance: str | None = None) -> list[RunnerEvent]:
    """Run one primitive to its outcome in lockstep with the world; returns every event it raised."""
    inst = instance or f"{type}#{len(runner.started) + 1}"
    runner.start(inst, type, params)
    robot = runner.robot
    t_end = robot.time + max_time
    events: list[RunnerEvent] = []
    while True:
        runner.advance()
        robot.step(dt)
        new = [e for e in runner.poll() if e.instance == inst]
        events += new
        if any(e.event in (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT) for e in new):
            break
        if robot.time >= t_end:
            events.append(RunnerEvent(inst, Event.TIMEOUT, {}, f"{type} still running after {max_time:g} s"))
            break
    runner.stop(inst)
    return events


def outcome(events: list[RunnerEvent]) -> RunnerEvent:
    """The final event of a primitive run (SUCCESS, FAILURE, ERROR or TIMEOUT)."""
    for e in reversed(events):
        if e.event in (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT):
            return e
    raise ValueError("the primitive raised no final event")
