"""Fakes for the abstraction layer: an executor that plays primitives from scripts."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from contactflow.abstraction.execution import EngineExecutor, SimTime
from contactflow.nodes.status import Event
from contactflow.nodes.testing_tasks import FakeClock, FakeRunner, Step


def succeeding_runner(clock: SimTime, duration: float = 0.2, fail_type: str = "",
                      fail_event: Event = Event.HARDWARE_FAILURE) -> FakeRunner:
    """Every primitive succeeds after ``duration`` s, except ``fail_type`` which raises ``fail_event``."""
    runner = FakeRunner(clock)  # FakeRunner only calls its clock

    def rule(instance: str, type_: str, params: Mapping[str, Any]) -> list[Step] | None:
        if "." in instance.rsplit("/", 1)[-1]:
            # event watchers: a nominal run sees the grasp become stable and never lost
            stable = params.get("event") == str(Event.GRASP_STABLE)
            return [Step(duration / 2, Event.GRASP_STABLE)] if stable else []
        if type_ == fail_type:
            return [Step(duration, fail_event)]
        return [Step(duration, Event.SUCCESS)]

    return runner.rule(rule)


def fake_executor(duration: float = 0.2, fail_type: str = "", realtime: float = 0.0,
                  on_start: Callable[[], None] | None = None) -> EngineExecutor:
    """An executor whose primitives all succeed (or ``fail_type`` fails), optionally paced."""

    def make(clock: SimTime):
        if on_start is not None:
            on_start()
        return succeeding_runner(clock, duration, fail_type), lambda dt: None

    return EngineExecutor(make, dt=0.05, realtime=realtime)


__all__ = ["FakeClock", "fake_executor", "succeeding_runner"]
