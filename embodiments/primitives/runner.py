"""In-process primitive runner for the task engine: primitives and the task hosted as on a node, in lockstep with a co-located world module."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from contactflow.embodiments import registry
from contactflow.embodiments.primitives.base import Primitive, PrimitiveError, Robot
from contactflow.nodes.config import ModuleConfig, parse_source
from contactflow.nodes.keys import ModuleAddr
from contactflow.nodes.messages import Command, EventMsg
from contactflow.nodes.params import replace_params
from contactflow.nodes.registry import resolve
from contactflow.nodes.status import Event, Status
from contactflow.nodes.task_module import TaskModule
from contactflow.nodes.taskengine import Progress, RunnerEvent, RunResult, TaskEngine
from contactflow.nodes.taskgraph import TaskGraph
from contactflow.nodes.wire import decode


@dataclass
class _Active:
    prim: Primitive
    addr: ModuleAddr


class LocalPrimitiveRunner:
    """:class:`~contactflow.nodes.taskengine.PrimitiveRunner` running primitives in this process.

    Primitives are created by registered short name (``contactflow.nodes.registry``) and run
    as on a node: hosted by a :class:`~contactflow.nodes.host.ModuleHost` beside the world
    module of ``robot``'s world, on an in-process bus. The host runs them (RUN, STOP, the
    resource claims, their steps at ``rate_hz`` on the simulated clock, their events); they read
    the states the world sends and command its command port, which checks and applies what
    they send (``facade``, the node's :class:`~contactflow.embodiments.remote.RemoteRobot`).
    Only the bus differs from a node: in-process and synchronous, not zenoh; :meth:`advance`
    ticks the host once per control tick. A task runs as on a node too, a task module on the
    same host (:meth:`host_task`) whose engine the host steps after the tick's primitives.
    ``defaults`` holds per-type parameter overrides
    (default: the overrides of the robot's home, :mod:`~contactflow.embodiments.registry`);
    task parameters override them.
    """

    def __init__(self, robot: Robot, defaults: Mapping[str, Mapping[str, Any]] | None = None,
                 factory: Callable[[str], type[Primitive]] | None = None) -> None:
        self.robot = robot
        self._host, self._world, self.facade = _co_located(robot)
        if defaults is None:
            defaults = registry.home(robot.spec.name).overrides
        self.defaults = {k: dict(v) for k, v in defaults.items()}
        self._factory = factory or _resolve_primitive
        self.active: dict[str, _Active] = {}
        self.started: list[tuple[str, str, dict[str, Any]]] = []
        self._events: list[RunnerEvent] = []
        self._instances: dict[str, str] = {}  # hosted module name -> the engine's instance it runs
        self._host.transport.subscribe(self._host.ks.events(robot.name, self._host.config.node), self._on_event)

    def _on_event(self, key: str, payload: bytes) -> None:
        msg = decode(payload, EventMsg, key)
        instance = self._instances.get(msg.module.rsplit("/", 1)[-1])
        if instance is not None:
            self._events.append(RunnerEvent(instance, Event(msg.event), dict(msg.values), msg.detail))

    def create(self, instance: str, type_name: str, params: Mapping[str, Any]) -> Primitive:
        """The primitive ``instance`` of ``type_name`` with the robot's defaults and ``params``, bound to the robot."""
        cls = self._factory(type_name)
        merged = {**self.defaults.get(type_name, {}), **dict(params)}
        prim = cls(instance, replace_params(cls.Params(), merged, where=f"{instance} ({type_name}).params."))
        prim.bind(self.facade)
        return prim

    def start(self, instance: str, type: str, params: Mapping[str, Any]) -> None:
        self.started.append((instance, type, dict(params)))
        self._sync()
        self.stop(instance)  # a finished run of the same instance
        # the engine's instance names ("run/path/node#activation") are no key segments: the module is numbered
        name = f"{type}_{len(self.started)}"
        addr = ModuleAddr(self.robot.name, self._host.config.node, name)
        try:
            prim = self.create(instance, type, params)
            self._host.add(ModuleConfig(name, type, prim.__class__, prim.params, self.robot.name, autostart=False), prim)
        except (PrimitiveError, ValueError, KeyError) as exc:
            self._events.append(RunnerEvent(instance, Event.ERROR, {}, f"{type}: {exc}"))
            return
        self._instances[name] = instance
        self.active[instance] = _Active(prim, addr)
        reply = self._host.send_control(f"{self.robot.name}/{name}", Command.RUN, {})
        if not reply.ok and not any(e.instance == instance and e.event is Event.ERROR for e in self._events):
            self._events.append(RunnerEvent(instance, Event.ERROR, {}, f"{type}: {reply.error}"))

    def stop(self, instance: str) -> None:
        a = self.active.pop(instance, None)
        if a is not None:
            self._host.remove(a.addr)
            self._instances.pop(a.addr.module, None)

    def poll(self) -> list[RunnerEvent]:
        out, self._events = self._events, []
        return out

    def feed(self, msgs: list[EventMsg]) -> None:
        """Nothing: events reach this runner on its own subscription to the bus (it runs primitives without a task too)."""

    def host_task(self, task: TaskGraph, params: Mapping[str, Any] | None = None,
                  library: Mapping[str, TaskGraph] | None = None, on_progress: Callable[[Progress], None] | None = None,
                  rate_hz: float = 200.0) -> TaskModule:
        """``task`` launched by a task module on this runner's host, its engine driving this runner; ticked by
        :meth:`advance` (at ``rate_hz`` Hz of simulated time) until :meth:`end_task`."""
        self._sync()
        module = TaskModule("task", TaskModule.Params(rate_hz=rate_hz), graph=task, library=library, plan=params,
                            runner=self, on_progress=on_progress)
        self._host.add(ModuleConfig("task", "task", TaskModule, module.params, self.robot.name, autostart=False), module)
        reply = self._host.send_control(f"{self.robot.name}/task", Command.RUN, {})
        if not reply.ok:
            self._host.remove(ModuleAddr(self.robot.name, self._host.config.node, "task"))
            raise RuntimeError(f"task {task.name!r} did not start: {reply.error}")
        return module

    def end_task(self, module: TaskModule) -> RunResult:
        """Stop what the task left running, take the task module off the host; the run's result."""
        for inst in list(self.active):
            self.stop(inst)
        self._host.remove(ModuleAddr(self.robot.name, self._host.config.node, module.name))
        res = module.engine.result(module.run_id)
        if res is None:
            raise RuntimeError(f"run {module.run_id!r} ended without a result")
        return res

    def host_contacts(self) -> None:
        """The robot's contact fusion on this runner's host, as on a control node with ``contacts: true``
        (:func:`~contactflow.embodiments.layout.contact_modules`): what ``wait_event`` with ``sensor: fused`` reads."""
        from contactflow.embodiments.layout import contact_modules

        self._sync()
        for entry in contact_modules(self.robot.name, self.robot.spec.name):
            cls = resolve(entry["type"])
            params = replace_params(cls.Params(), entry["params"], where=f"{entry['name']}.params.")
            inputs = {port: parse_source(src) for port, src in entry.get("inputs", {}).items()}
            self._host.add(ModuleConfig(entry["name"], entry["type"], cls, params, self.robot.name, inputs=inputs,
                                        autostart=False))
            reply = self._host.send_control(f"{self.robot.name}/{entry['name']}", Command.RUN, {})
            if not reply.ok:
                raise RuntimeError(f"{entry['name']} did not start: {reply.error}")

    def advance(self) -> None:
        """Step every primitive whose period has elapsed (call once per control tick)."""
        self._sync()
        self._host.tick()

    @classmethod
    def of(cls, robot: Robot) -> LocalPrimitiveRunner:
        """The robot's in-process node with the robot's defaults, made once: tasks run one after
        another on it, as on a robot's control node (an arm controller still moving when a task
        ends goes on in the next, until a primitive commands the arm)."""
        runner = getattr(robot, "_local_runner", None)
        if runner is None:
            runner = robot._local_runner = cls(robot)
        return runner

    def idle(self, duration: float) -> None:
        """Let ``duration`` s of simulated time pass, the host ticking as a node does between tasks
        (the arm controllers finish what the primitives last commanded)."""
        dt = 1.0 / self.robot.params.control_rate
        end = self.robot.time + duration - 1e-9
        while self.robot.time < end:
            self.advance()
            self.robot.step(dt)

    def _sync(self) -> None:
        """The world's state and clock as they are now (the world may have stepped without the runner)."""
        self._world.publish_state()
        self._host.clock.advance(self.robot.time)


def _co_located(robot: Robot):
    """A host on an in-process bus with the world module around ``robot``'s world, and the facade primitives drive it through.

    Primitives run here as they do on a node: they read the robot's state as the world sends
    it and command it on its command port, which the world checks and applies; only the bus
    differs (in-process and synchronous, not zenoh).
    """
    from contactflow.embodiments.modules.world_module import WorldModule
    from contactflow.embodiments.remote import connect, link
    from contactflow.nodes.config import NodeConfig
    from contactflow.nodes.host import ModuleHost
    from contactflow.nodes.transport import LocalTransport, ZenohSettings

    bus = LocalTransport()
    node = NodeConfig(site="local", node="local", host="local", robot="site", clock="sim", zenoh=ZenohSettings(),
                      modules=())
    host = ModuleHost(node, bus)
    params = WorldModule.Params(control_rate=robot.params.control_rate, ground_truth_hz=0.0)
    world = WorldModule("world", params, world=robot.world, sims=(robot,))
    host.add(ModuleConfig("world", "world", WorldModule, params, "site", autostart=False), world)
    link(bus, host.ks, robot.name, node.node)  # subscribed before the world sends the state the facade waits for
    world.publish_state()
    facade = connect(bus, host.ks, robot.name, node.node)
    host.attach(f"robot/{robot.name}", facade)  # the arm controllers step after each tick's primitives
    return host, world, facade


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

    The task is a task module on the runner's host (:meth:`LocalPrimitiveRunner.host_task`);
    each tick steps the due primitives, then the task's engine, then advances physics by
    ``dt`` s. A run still going after ``max_time`` s of simulated time is cancelled (result ERROR).
    """
    runner = runner or LocalPrimitiveRunner.of(robot)
    module = runner.host_task(task, params, library, on_progress, rate_hz=1.0 / dt)
    engine, run = module.engine, module.run_id
    t_end = robot.time + max_time
    while not engine.done(run):
        runner.advance()
        robot.step(dt)
        if robot.time >= t_end and not engine.done(run):
            engine.cancel(run, f"still running after {max_time:g} s of simulated time")
    return runner.end_task(module), engine


def finished_ok(res: RunResult) -> bool:
    return res.status is Status.SUCCESS


def run_primitive(runner: LocalPrimitiveRunner, type: str, params: Mapping[str, Any], max_time: float = 30.0,
                  dt: float = 0.005, instance: str | None = None, times: list[float] | None = None) -> list[RunnerEvent]:
    """Run one primitive to its outcome in lockstep with the world; returns every event it raised (and appends
    to ``times`` the simulated s from the start at which each came)."""
    inst = instance or f"{type}#{len(runner.started) + 1}"
    runner.start(inst, type, params)
    robot = runner.robot
    t0 = robot.time
    t_end = t0 + max_time
    events: list[RunnerEvent] = []
    while True:
        runner.advance()
        robot.step(dt)
        new = [e for e in runner.poll() if e.instance == inst]
        events += new
        if times is not None:
            times += [robot.time - t0] * len(new)
        if any(e.event in (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT) for e in new):
            break
        if robot.time >= t_end:
            events.append(RunnerEvent(inst, Event.TIMEOUT, {}, f"{type} still running after {max_time:g} s"))
            if times is not None:
                times.append(robot.time - t0)
            break
    runner.stop(inst)
    return events


def outcome(events: list[RunnerEvent]) -> RunnerEvent:
    """The final event of a primitive run (SUCCESS, FAILURE, ERROR or TIMEOUT)."""
    for e in reversed(events):
        if e.event in (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT):
            return e
    raise ValueError("the primitive raised no final event")
