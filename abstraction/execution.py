"""Run a translated task (ESTD) on the task engine, in lockstep with a robot or a fake."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from contactflow.abstraction.atd import DETECT
from contactflow.abstraction.concrete import ConcreteRunner, HandGeometry
from contactflow.abstraction.frames import TaskFrame, params_to_world
from contactflow.abstraction.translator import AbstractProgress, Translation
from contactflow.nodes.status import Event
from contactflow.nodes.taskengine import PrimitiveRunner, TaskEngine


def frame_of(translation: Translation) -> TaskFrame:
    from contactflow.abstraction.profiles import PROFILES

    profile = PROFILES.get(translation.robot)
    return profile.task_frame if profile is not None else TaskFrame()


def bound_params(translation: Translation, params: Mapping[str, Any] | None) -> dict[str, Any]:
    """The dispatch's parameters the ESTD declares, in world coordinates."""
    declared = translation.estd.params
    return params_to_world({k: v for k, v in (params or {}).items() if k in declared}, frame_of(translation))


def to_detect(translation: Translation, bound: Mapping[str, Any]) -> list[str]:
    """The object locations the ATD asks the robot to detect that the dispatch did not bind."""
    return sorted(k for k, v in translation.estd.params.items() if v == DETECT and k not in bound)


def robot_runner(inner: PrimitiveRunner, robot: Any, embodiment: str,
                 hand_points: Callable[[str], Any]) -> ConcreteRunner:
    """The factory's last step for ``robot`` (a simulated or remote facade) over ``inner``.

    Each hand's geometry comes from ``hand_points(arm)`` with the embodiment's usual grasp
    centre; while a hand holds what a grasp took, objects are placed by where they sit in it.
    """
    from contactflow.embodiments import registry
    from contactflow.embodiments.primitives.hands import held_center

    centre = registry.home(embodiment).grasp_center
    hands = {arm: HandGeometry(hand_points(arm), grasp_center=centre) for arm in robot.arms if robot.spec.arm(arm).hand}
    return ConcreteRunner(inner, robot.arms, hand_at=lambda arm: robot.arm(arm).ee_pose(), hands=hands,
                          held_at=lambda arm: held_center(robot, arm))


@dataclass
class SimTime:
    """Simulated seconds, advanced by the executor loop."""

    t: float = 0.0

    def __call__(self) -> float:
        return self.t


class EngineExecutor:
    """An :class:`~contactflow.abstraction.agent.Executor` over a :class:`TaskEngine`.

    ``make`` builds, per run, the primitive runner and the function that advances the
    robot (a simulated world steps ``dt`` s; a fake does nothing). ``realtime`` > 0 paces
    the loop against the wall clock (1 = real time), so a deployment looks like a robot.
    """

    def __init__(self, make: Callable[[SimTime], tuple[PrimitiveRunner, Callable[[float], None]]],
                 dt: float = 0.02, max_time: float = 600.0, realtime: float = 0.0) -> None:
        self.make = make
        self.dt = dt
        self.max_time = max_time
        self.realtime = realtime

    def __call__(self, translation: Translation, report: Callable[[AbstractProgress], None],
                 cancel: threading.Event, params: Mapping[str, Any] | None = None) -> Event:
        bound = bound_params(translation, params)
        detect = to_detect(translation, bound)
        if detect:
            raise ValueError(f"{', '.join(detect)}: the ATD asks to detect it, which the runtime executor's vision "
                             "does (this executor runs a world of its own)")
        clock = SimTime()
        runner, advance = self.make(clock)
        engine = TaskEngine(runner, clock, on_progress=lambda p: report(translation.abstract(p)))
        run = engine.launch(translation.estd, bound)
        wall0 = time.monotonic()
        while not engine.done(run):
            if cancel.is_set():
                engine.cancel(run, "cancelled")
                break
            if clock.t >= self.max_time:
                engine.cancel(run, f"gave up after {self.max_time:g} s")
                break
            advance(self.dt)
            clock.t += self.dt
            engine.tick()
            if self.realtime > 0:
                lag = clock.t / self.realtime - (time.monotonic() - wall0)
                if lag > 0:
                    cancel.wait(lag)
        result = engine.result(run)
        return result.event if result is not None else Event.ERROR
