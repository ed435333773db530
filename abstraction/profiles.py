"""What a factory knows about a robot: hand kind, sensors, primitive types and workspace.

The lead connects these to ``contactflow.embodiments.registry``; until then the three
thesis robots are described here with the values the factories need.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum


class HandKind(StrEnum):
    MULTI_FINGER = "multi_finger"  # e.g. Schunk SDH2 / Barrett: preshapes, finger corrections
    PARALLEL_GRIPPER = "parallel_gripper"  # 1-DOF jaws: width and force only


class Sensor(StrEnum):
    WRIST_FT = "wrist_ft"  # 6-axis force-torque sensor at the wrist
    TACTILE = "tactile"  # tactile arrays on the fingers
    GRIPPER_EFFORT = "gripper_effort"  # motor effort / position of a gripper
    JOINT_STATE = "joint_state"
    CAMERA = "camera"
    DEPTH = "depth"


@dataclass(frozen=True, slots=True)
class Workspace:
    """Reachable region: a sphere around ``center`` (m, world frame) above ``z_min``."""

    center: tuple[float, float, float]
    radius: float  # m
    z_min: float = 0.0  # m, lowest reachable height (table surface)

    def reaches(self, p: Sequence[float]) -> bool:
        return math.dist(self.center, p) <= self.radius and p[2] >= self.z_min

    def describe(self, p: Sequence[float]) -> str:
        d = math.dist(self.center, p)
        if p[2] < self.z_min:
            return f"z={p[2]:.3f} m is below the workspace floor {self.z_min:.3f} m"
        return f"{d:.3f} m from the workspace centre, reach is {self.radius:.3f} m"


@dataclass(frozen=True, slots=True)
class RobotProfile:
    """Capabilities of one robot as the translation factory sees them."""

    name: str
    hand: HandKind
    sensors: frozenset[Sensor]
    capabilities: frozenset[str]  # concrete primitive types this robot runs
    workspace: Workspace
    hand_shapes: frozenset[str] = frozenset({"open"})
    max_payload: float = 1.0  # kg
    max_opening: float = 0.1  # m, widest object the hand takes
    wrench_noise: float = 0.2  # N, standard deviation of the wrist force reading
    speed: float = 0.1  # m/s, nominal Cartesian speed of the end effector
    factory: str = ""  # name of the factory to use (default: the robot's name)

    def has(self, *sensors: Sensor) -> bool:
        return all(s in self.sensors for s in sensors)


_ARM = frozenset({"transport", "move_to", "release", "hold", "lift", "wait_event",
                  "detect_objects", "place_location"})

TOMBATOSSALS = RobotProfile(
    name="tombatossals",
    hand=HandKind.MULTI_FINGER,
    sensors=frozenset({Sensor.WRIST_FT, Sensor.TACTILE, Sensor.JOINT_STATE, Sensor.CAMERA,
                       Sensor.DEPTH}),
    capabilities=_ARM | {"robust_grasp", "naive_grasp", "place", "slide", "explore", "unscrew",
                         "push", "pull", "touch"},
    workspace=Workspace((0.0, 0.3, 0.6), 1.0, 0.0),
    hand_shapes=frozenset({"open", "pinch_grasp_preshape", "pinch_grasp", "cylindrical",
                           "cylindrical_preshape", "spherical", "spherical_preshape"}),
    max_payload=2.0,
    max_opening=0.14,
    wrench_noise=0.2,
    speed=0.1,
)

MELFA = RobotProfile(
    name="melfa",
    hand=HandKind.PARALLEL_GRIPPER,
    sensors=frozenset({Sensor.TACTILE, Sensor.GRIPPER_EFFORT, Sensor.JOINT_STATE}),
    capabilities=_ARM | {"close_until_force"},
    workspace=Workspace((0.0, 0.4, 0.4), 0.85, 0.0),
    hand_shapes=frozenset({"open", "closed"}),
    max_payload=3.0,
    max_opening=0.068,  # PG-70 stroke
    wrench_noise=0.0,
    speed=0.25,
)

BAXTER = RobotProfile(
    name="baxter",
    hand=HandKind.PARALLEL_GRIPPER,
    sensors=frozenset({Sensor.WRIST_FT, Sensor.GRIPPER_EFFORT, Sensor.JOINT_STATE,
                       Sensor.CAMERA}),
    capabilities=_ARM | {"close_until_force", "naive_grasp", "place", "slide", "push", "pull",
                         "touch", "explore"},
    workspace=Workspace((0.0, 0.35, 0.5), 1.1, 0.0),
    hand_shapes=frozenset({"open", "closed"}),
    max_payload=2.2,
    max_opening=0.09,
    wrench_noise=2.0,  # the wrist wrench is estimated from joint torques: noisy
    speed=0.2,
)

PROFILES = {p.name: p for p in (TOMBATOSSALS, MELFA, BAXTER)}
