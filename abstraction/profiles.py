"""What a factory knows about a robot: hand kind, sensors, primitive types and workspace.

Sensors, hand kind, payload and the workspace box come from the embodiment registry
(``contactflow.embodiments.registry``); the primitive set, hand shapes and speeds the
factories choose between are the translation extras of each robot below.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from contactflow.abstraction.frames import WORKCELL, TaskFrame
from contactflow.embodiments import registry
from contactflow.embodiments.registry import RobotSpec


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
    """Reachable region: an axis-aligned box (m, world frame) from the embodiment registry."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    @property
    def center(self) -> tuple[float, float, float]:
        return tuple((a + b) / 2 for a, b in zip(self.lo, self.hi, strict=True))  # type: ignore[return-value]

    @property
    def radius(self) -> float:
        """Half the box diagonal (m): the reach a bid may assume."""
        return math.dist(self.lo, self.hi) / 2

    def reaches(self, p: Sequence[float]) -> bool:
        return all(lo - 1e-9 <= v <= hi + 1e-9 for lo, v, hi in zip(self.lo, p, self.hi, strict=True))

    def describe(self, p: Sequence[float]) -> str:
        axes = [f"{n}={v:.3f} m outside [{lo:.2f}, {hi:.2f}]"
                for n, lo, v, hi in zip("xyz", self.lo, p, self.hi, strict=True) if not lo <= v <= hi]
        return "; ".join(axes) or "inside the workspace"


@dataclass(frozen=True, slots=True)
class RobotProfile:
    """Capabilities of one robot as the translation factory sees them."""

    name: str
    hand: HandKind
    sensors: frozenset[Sensor]
    capabilities: frozenset[str]  # concrete primitive types this robot runs
    workspace: Workspace
    hand_shapes: Mapping[str, str] = field(default_factory=lambda: {"open": "open"})  # ATD shape -> preshape
    max_payload: float = 1.0  # kg
    max_opening: float = 0.1  # m, widest object the hand takes
    wrench_noise: float = 0.2  # N, standard deviation of the wrist force reading
    speed: float = 0.1  # m/s, nominal Cartesian speed of the end effector
    factory: str = ""  # name of the factory to use (default: the robot's name)
    grasp_corrections: tuple[str, ...] = ()  # robust-grasp corrections the hand allows (registry capabilities)
    task_frame: TaskFrame = WORKCELL  # where the ATD's coordinates sit in this robot's world

    def has(self, *sensors: Sensor) -> bool:
        return all(s in self.sensors for s in sensors)


_ARM = frozenset({"transport", "move_to", "release", "hold", "lift", "wait_event",
                  "detect_objects", "place_location"})


@dataclass(frozen=True, slots=True)
class _Extras:
    """What translation needs beyond the embodiment registry (thesis Tables 7.3-7.4)."""

    capabilities: frozenset[str]
    hand_shapes: Mapping[str, str]  # ATD hand shape -> the hand's own preshape
    max_opening: float  # m
    wrench_noise: float  # N
    speed: float  # m/s


_EXTRAS = {
    "tombatossals": _Extras(
        _ARM | {"robust_grasp", "naive_grasp", "place", "slide", "explore", "unscrew", "push", "pull", "touch"},
        {"open": "open", "closed": "closed", "pinch_grasp_preshape": "open", "pinch_grasp": "pinch",
         "cylindrical_preshape": "open", "cylindrical": "cylindrical", "spherical_preshape": "open",
         "spherical": "spherical"},
        max_opening=0.14, wrench_noise=0.2, speed=0.1),
    "melfa": _Extras(_ARM | {"close_until_force"}, {"open": "open", "closed": "closed"},
                     max_opening=0.08, wrench_noise=0.05, speed=0.25),
    "baxter": _Extras(
        _ARM | {"close_until_force", "close_until_stall", "naive_grasp", "place", "slide", "push", "pull", "touch",
                "explore"},
        {"open": "open", "closed": "closed"},
        max_opening=0.055, wrench_noise=2.0, speed=0.2),  # wrist wrench estimated from efforts: noisy
}


def profile_of(spec: RobotSpec) -> RobotProfile:
    """The translation profile of an embodiment: sensors and workspace from its registry entry."""
    extras = _EXTRAS.get(spec.name)
    if extras is None:
        raise KeyError(f"no translation profile for embodiment {spec.name!r} (known: {sorted(_EXTRAS)})")
    sensors = {Sensor.JOINT_STATE}
    if spec.fts:
        sensors.add(Sensor.WRIST_FT)
    if any(h.pads for h in spec.hands):
        sensors.add(Sensor.TACTILE)
    if spec.cameras:
        sensors |= {Sensor.CAMERA, Sensor.DEPTH}
    multi = any(h.kind == "multi_finger" for h in spec.hands)
    if not multi:
        sensors.add(Sensor.GRIPPER_EFFORT)
    caps = spec.capabilities
    if caps is None:
        raise KeyError(f"embodiment {spec.name!r} declares no capabilities")
    return RobotProfile(
        name=spec.name, hand=HandKind.MULTI_FINGER if multi else HandKind.PARALLEL_GRIPPER,
        sensors=frozenset(sensors), capabilities=extras.capabilities,
        workspace=Workspace(caps.workspace_min, caps.workspace_max), hand_shapes=extras.hand_shapes,
        max_payload=caps.payload, max_opening=extras.max_opening, wrench_noise=extras.wrench_noise,
        speed=extras.speed, grasp_corrections=caps.grasp_corrections,
    )


PROFILES = {name: profile_of(registry.get(name)) for name in registry.names() if name in _EXTRAS}
TOMBATOSSALS, MELFA, BAXTER = PROFILES["tombatossals"], PROFILES["melfa"], PROFILES["baxter"]
