"""Fakes for the task engine: a settable clock and a scripted primitive runner."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from contactflow.nodes.status import Event
from contactflow.nodes.taskengine import RunnerEvent, RunResult, TaskEngine


@dataclass
class FakeClock:
    """A clock the test advances by hand (s)."""

    t: float = 0.0

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


@dataclass(frozen=True, slots=True)
class Step:
    """Emit ``event`` (with result ``values``) ``after`` s from the primitive's start."""

    after: float
    event: Event
    values: Mapping[str, Any] = field(default_factory=dict)


def node_of(instance: str) -> str:
    """The node path of an instance id: ``run1/pick/grasp.watch#3`` -> ``pick/grasp.watch``."""
    return instance.split("/", 1)[1].rsplit("#", 1)[0]


class FakeRunner:
    """A :class:`~contactflow.nodes.taskengine.PrimitiveRunner` that plays scripts.

    ``script(key, run1, run2, ...)`` gives the steps a primitive plays on its first, second,
    ... start (the last one repeats). ``key`` is a node path as :func:`node_of` returns it
    (most specific) or a primitive type. ``rule(fn)`` adds a fallback that computes the
    steps from ``(instance, type, params)`` (None: no opinion). Unscripted primitives run
    silently until stopped.
    The runner records every start (with its parameters) and stop.
    """

    def __init__(self, clock: FakeClock) -> None:
        self.clock = clock
        self.scripts: dict[str, list[list[Step]]] = {}
        self.starts: list[tuple[str, str, dict[str, Any]]] = []
        self.stops: list[str] = []
        self.active: dict[str, tuple[float, list[Step]]] = {}
        self._count: dict[str, int] = defaultdict(int)
        self._manual: list[RunnerEvent] = []
        self._rules: list[Callable[[str, str, Mapping[str, Any]], Sequence[Step] | None]] = []

    def rule(self, fn: Callable[[str, str, Mapping[str, Any]], Sequence[Step] | None]) -> FakeRunner:
        self._rules.append(fn)
        return self

    def script(self, key: str, *runs: Sequence[Step]) -> FakeRunner:
        self.scripts[key] = [list(r) for r in runs]
        return self

    def start(self, instance: str, type: str, params: Mapping[str, Any]) -> None:
        if instance in self.active:
            raise AssertionError(f"instance {instance!r} started twice")
        self.starts.append((instance, type, dict(params)))
        key = node_of(instance) if node_of(instance) in self.scripts else type
        n = self._count[key]
        self._count[key] += 1
        if key in self.scripts:
            runs = self.scripts[key]
            steps = list(runs[min(n, len(runs) - 1)])
        else:
            found = (fn(instance, type, params) for fn in self._rules)
            steps = list(next((s for s in found if s is not None), []))
        self.active[instance] = (self.clock(), sorted(steps, key=lambda s: s.after))

    def stop(self, instance: str) -> None:
        if instance not in self.active:
            raise AssertionError(f"instance {instance!r} stopped but not running")
        self.stops.append(instance)
        del self.active[instance]

    def emit(self, instance: str, event: Event, **values: Any) -> None:
        """Queue an event by hand for a running instance."""
        self._manual.append(RunnerEvent(instance, event, values))

    def poll(self) -> list[RunnerEvent]:
        now = self.clock()
        due: list[tuple[float, int, RunnerEvent]] = []
        for i, (inst, (t0, steps)) in enumerate(self.active.items()):
            while steps and t0 + steps[0].after <= now + 1e-12:
                s = steps.pop(0)
                due.append((t0 + s.after, i, RunnerEvent(inst, s.event, dict(s.values))))
        out, self._manual = self._manual, []
        return out + [ev for _, _, ev in sorted(due, key=lambda d: (d[0], d[1]))]

    def started_types(self) -> list[str]:
        return [t for _, t, _ in self.starts]

    def started_nodes(self) -> list[str]:
        return [node_of(i) for i, _, _ in self.starts]


def run_until_done(engine: TaskEngine, clock: FakeClock, run: str, dt: float = 0.05,
                   max_time: float = 600.0) -> RunResult:
    """Tick ``engine`` every ``dt`` s of fake time until ``run`` finishes."""
    while not engine.done(run):
        if clock.t > max_time:
            raise AssertionError(f"run {run!r} still running after {max_time} s: at {engine.state(run)}")
        clock.advance(dt)
        engine.tick()
    res = engine.result(run)
    assert res is not None
    return res
