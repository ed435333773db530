"""What a factory knows about a robot: hand kind, sensors, primitive types, workspace and overrides.

Everything comes from the robot's home (``contactflow.embodiments.registry``): sensors and
hand kind from its spec, the primitive set, workspace, payload, hand shapes and speed from
its capabilities, the primitive parameter overrides from its registration.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from contactflow.abstraction.frames import WORKCELL, TaskFrame
from contactflow.embodiments import registry
from contactflow.embodiments.registry import HandKind, RobotHome


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
    overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)  # primitive type -> Params overrides

    def has(self, *sensors: Sensor) -> bool:
        return all(s in self.sensors for s in sensors)


def profile_of(home: RobotHome) -> RobotProfile:
    """The translation profile of a robot: sensors from its spec, the rest from its capabilities."""
    spec = home.spec
    sensors = {Sensor.JOINT_STATE}
    if spec.fts:
        sensors.add(Sensor.WRIST_FT)
    if any(h.pads for h in spec.hands):
        sensors.add(Sensor.TACTILE)
    if spec.cameras:
        sensors |= {Sensor.CAMERA, Sensor.DEPTH}
    multi = any(h.kind is HandKind.MULTI_FINGER for h in spec.hands)
    if not multi:
        sensors.add(Sensor.GRIPPER_EFFORT)
    caps = spec.capabilities
    if caps is None:
        raise KeyError(f"embodiment {spec.name!r} declares no capabilities")
    return RobotProfile(
        name=spec.name, hand=HandKind.MULTI_FINGER if multi else HandKind.PARALLEL,
        sensors=frozenset(sensors), capabilities=caps.primitives,
        workspace=Workspace(caps.workspace_min, caps.workspace_max), hand_shapes=caps.hand_shapes,
        max_payload=caps.payload, max_opening=caps.max_opening, wrench_noise=caps.wrench_noise,
        speed=caps.speed, grasp_corrections=caps.grasp_corrections, overrides=home.overrides,
    )


class _Profiles(Mapping[str, RobotProfile]):
    """Robot name -> translation profile, built from each registered home on first use."""

    def __init__(self) -> None:
        self._built: dict[str, RobotProfile] = {}

    def __getitem__(self, name: str) -> RobotProfile:
        if name not in self._built:
            if name not in registry.names():
                raise KeyError(name)
            self._built[name] = profile_of(registry.home(name))
        return self._built[name]

    def __iter__(self) -> Iterator[str]:
        return iter(registry.names())

    def __len__(self) -> int:
        return len(registry.names())


PROFILES: Mapping[str, RobotProfile] = _Profiles()
"""Every registered robot's translation profile."""
