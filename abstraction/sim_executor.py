"""Run an ESTD on a simulated embodiment: the station's world, primitives reading physics sensors.

The station keeps one world for its whole life (what ATD 1 pushed away stays pushed for
ATD 2). Each task runs the task engine in lockstep with the physics; a contact monitor may
watch the robot's sensors meanwhile (the station's fusion, publishing contact events).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from contactflow.abstraction.execution import EngineExecutor, SimTime, robot_runner
from contactflow.abstraction.translator import AbstractProgress, Translation
from contactflow.nodes.status import Event


class ContactMonitor(Protocol):
    """Called after every control tick with the robot; does its own rate limiting."""

    def __call__(self, robot: Any) -> None: ...


class SimExecutor:
    """An :class:`~contactflow.abstraction.agent.Executor` on a simulated robot."""

    def __init__(self, robot: str, scene: str = "thesis_7_3", realtime: float = 0.0, dt: float = 0.005,
                 max_time: float = 120.0, monitor_factory: Callable[[Any], ContactMonitor] | None = None) -> None:
        self.robot_name = robot
        self.scene = scene
        self.realtime = realtime
        self.dt = dt
        self.max_time = max_time
        self.monitor_factory = monitor_factory
        self.robot: Any = None
        self.hand_points: dict[str, Any] = {}  # arm -> its hand's points, measured as the robot was built
        self.monitor: ContactMonitor | None = None
        self._lock = threading.Lock()

    def build(self) -> Any:
        """Create the world, its scene and the robot (once; SAPIEN is imported only here)."""
        from contactflow.embodiments.hand_geometry import hand_points
        from contactflow.embodiments.scenes import SCENES
        from contactflow.embodiments.sim_robot import SimRobot
        from contactflow.embodiments.world import World, WorldParams

        if self.robot is None:
            if self.scene not in SCENES:
                raise ValueError(f"scene {self.scene!r} is not one of {sorted(SCENES)}")
            world = World(WorldParams())
            SCENES[self.scene](world)
            self.robot = SimRobot(world, self.robot_name)
            self.hand_points = {arm: hand_points(self.robot, arm) for arm in self.robot.arms}
            self.robot.step(0.3)  # let objects settle on the table
            if self.monitor_factory is not None:
                self.monitor = self.monitor_factory(self.robot)
        return self.robot

    def __call__(self, translation: Translation, report: Callable[[AbstractProgress], None],
                 cancel: threading.Event, params: Mapping[str, Any] | None = None) -> Event:
        from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner

        with self._lock:
            robot = self.build()
            runner = LocalPrimitiveRunner(robot)
            concrete = robot_runner(runner, robot, self.robot_name, self.hand_points.__getitem__)

            def advance(dt: float) -> None:
                runner.advance()
                robot.step(dt)
                if self.monitor is not None:
                    self.monitor(robot)

            def make(_clock: SimTime):
                return concrete, advance

            engine = EngineExecutor(make, dt=self.dt, max_time=self.max_time, realtime=self.realtime)
            try:
                outcome = engine(translation, report, cancel, params)
            finally:
                for inst in list(runner.active):
                    runner.stop(inst)
            if robot.failed:
                return Event.HARDWARE_FAILURE
            return outcome
