"""Embodiments as data: the spec dataclasses, each robot's home and the registry that finds them.

Each robot has one home, a package under ``embodiments/robots/<name>/``: ``spec.py`` (its
``SPEC``: where the URDF comes from, a composition of example-robot-data parts; arms with
chain, controlled frame, home pose and gains; hands with kind, preshapes, finger joints and
tactile pads; wrist F/T and cameras; head; capabilities; the computers its modules run on,
thesis App. A), ``factory.py`` (its translation factory, thesis Tables 7.3-7.4) and
``__init__.py``, which registers it as ``HOME`` (:class:`RobotHome`: the spec, the primitive
parameter overrides its hardware needs, grasp centre and wall side). A new robot is a new
package; nothing else names it.
"""

from __future__ import annotations

import importlib
import pathlib
import pkgutil
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from types import MappingProxyType
from typing import Any

import numpy as np

from contactflow.embodiments.transforms import xyz_rpy_to_matrix
from contactflow.embodiments.urdf_compose import Composition, write


class RegistryError(KeyError):
    """Unknown robot or inconsistent spec."""

    def __str__(self) -> str:
        return str(self.args[0])


class HandKind(StrEnum):
    """What a hand is, for the primitives and for translation (one vocabulary)."""

    MULTI_FINGER = "multi_finger"  # e.g. Schunk SDH2 / Allegro: preshapes, finger corrections
    PARALLEL = "parallel"  # 1-DOF jaws: width and force only


@dataclass(frozen=True)
class ArmSpec:
    """A kinematic chain controlled as one arm."""

    name: str  # e.g. "left", "right", "arm"
    joints: tuple[str, ...]  # chain joints, base to tip
    base_link: str  # link the chain starts from (Cartesian commands default to it)
    ee_frame: str  # controlled frame (a link or fixed frame of the URDF)
    home: tuple[float, ...]  # rad, home pose of ``joints``
    hand: str = ""  # name of the hand mounted on this arm
    ft: str = ""  # name of the wrist F/T sensor of this arm
    kp: float = 1000.0  # N m/rad, position drive stiffness
    kd: float = 100.0  # N m s/rad, drive damping
    force_limit: float = 500.0  # N m, drive force limit
    max_velocity: float = 1.0  # rad/s, joint speed used by trajectories
    max_acceleration: float = 2.0  # rad/s^2, speed-up and slow-down of planned trajectories


@dataclass(frozen=True)
class PadSpec:
    """A tactile pad: ``rows`` x ``cols`` taxels on a patch of ``link`` (thesis A.1.2: 5x8)."""

    name: str
    link: str
    origin: tuple[float, float, float]  # m, pad centre in the link frame
    normal: tuple[float, float, float]  # outward normal in the link frame
    u_axis: tuple[float, float, float]  # direction of the ``cols`` axis in the link frame
    size: tuple[float, float]  # m, extent along u (cols) and v (rows)
    rows: int = 5
    cols: int = 8
    radius: float = 0.0  # m, curvature of a fingertip pad (0 = flat)
    sigma: float = 0.003  # m, Gaussian spread of one contact over the taxels
    range_: float = 0.004  # m, contacts farther than this from the pad surface are ignored


@dataclass(frozen=True)
class HandSpec:
    """A hand: its actuated joints, preshapes and tactile pads."""

    name: str
    kind: HandKind
    joints: tuple[str, ...]  # actuated finger joints
    preshapes: dict[str, tuple[float, ...]]  # name -> positions of ``joints`` (must hold open/closed)
    mimic: tuple[tuple[str, str, float], ...] = ()  # (joint, master joint, multiplier)
    fingertips: tuple[str, ...] = ()  # fingertip link names
    palm_link: str = ""
    pads: tuple[PadSpec, ...] = ()
    kp: float = 1000.0
    kd: float = 100.0
    force_limit: float = 100.0  # N or N m per finger joint
    friction: float = 2.0  # finger link friction coefficient
    max_velocity: float = 2.0  # rad/s or m/s
    armature: float = 0.0  # kg m^2 (or kg) added to each finger joint: light phalanges chatter in contact without it


@dataclass(frozen=True)
class FTSpec:
    """A wrist force-torque sensor at the incoming joint of ``link`` (expressed in ``link``)."""

    name: str
    link: str
    rate_hz: float = 200.0  # Hz (JR3: up to 200 Hz, App. A.1.2)
    force_noise: float = 0.05  # N, std dev
    torque_noise: float = 0.005  # N m, std dev
    bias: tuple[float, ...] = (0.0,) * 6  # constant offset added to the reading
    estimated: bool = False  # True: estimated from joint efforts (Baxter, App. A.4.2)
    arm: str = ""  # arm whose joint efforts estimate the wrench (when ``estimated``)


@dataclass(frozen=True)
class CameraSpec:
    """An RGBD camera on ``link``; optical frame: x right, y down, z forward."""

    name: str
    link: str
    width: int = 640
    height: int = 480
    fx: float = 525.0  # px, Kinect v1 defaults
    fy: float = 525.0
    cx: float = 319.5
    cy: float = 239.5
    near: float = 0.3  # m
    far: float = 4.0  # m
    rate_hz: float = 30.0
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)  # optical frame in the link frame
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def optical_in_link(self) -> np.ndarray:
        """4x4 pose of the optical frame in the camera link's frame."""
        return xyz_rpy_to_matrix(self.xyz, self.rpy)


GRASP_CORRECTIONS = ("alignment", "sliding", "finger_lost", "force_adaptation")
"""The robust grasp's corrections (§3.3.1): eq. 3.1, eq. 3.2, finger lost (Fig. 3.2 F1/F3), force adaptation."""


@dataclass(frozen=True)
class Capabilities:
    """What the embodiment can do, as translation sees it: its primitives, reach, payload and hand."""

    primitives: frozenset[str]  # concrete primitive types (module types) this robot runs
    workspace_min: tuple[float, float, float]  # m, world frame
    workspace_max: tuple[float, float, float]
    payload: float = 1.0  # kg
    grasp_corrections: tuple[str, ...] = GRASP_CORRECTIONS
    """Robust-grasp corrections the hands allow (thesis Fig. 3.2); ``finger_lost`` needs a multi-finger hand."""
    hand_shapes: Mapping[str, str] = field(default_factory=lambda: {"open": "open", "closed": "closed"})
    """ATD hand shape -> the hand's own preshape."""
    max_opening: float = 0.1  # m, widest object the hand takes
    wrench_noise: float = 0.2  # N, standard deviation of the wrist force reading
    speed: float = 0.1  # m/s, nominal Cartesian speed of the end effector


@dataclass(frozen=True)
class Computer:
    """A computer of the robot and the modules that run there (thesis Fig. A.6)."""

    name: str
    role: str
    modules: tuple[str, ...]


def collision_part(link: str, parts: tuple[str, ...]) -> int:
    """Index of the part of ``parts`` (link-name prefixes) that ``link`` belongs to; ``len(parts)`` for the rest.

    Links of different parts collide with each other, links of one part never: the world sets
    its collision groups and the planners their self-collision pairs by this one rule.
    """
    for k, prefix in enumerate(parts):
        if link.startswith(prefix):
            return k
    return len(parts)


@dataclass(frozen=True)
class RobotSpec:
    """Everything the system knows about one embodiment."""

    name: str
    description: str
    composition: Composition
    arms: tuple[ArmSpec, ...]
    hands: tuple[HandSpec, ...] = ()
    fts: tuple[FTSpec, ...] = ()
    cameras: tuple[CameraSpec, ...] = ()
    head_joints: tuple[str, ...] = ()
    head_home: tuple[float, ...] = ()
    capabilities: Capabilities | None = None
    computers: tuple[Computer, ...] = ()
    base_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m, default placement in the world
    base_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    collision_groups: tuple[str, ...] = ()
    """Link-name prefixes of parts that collide with each other (e.g. the two arms of a torso);
    links inside one part (and all unmatched links) never collide with each other."""
    task_frames: dict[str, tuple[str, tuple[float, ...]]] = field(default_factory=dict)
    """Named task frames: name -> (parent frame, xyz + rpy offset)."""

    def urdf(self, directory: pathlib.Path | None = None) -> pathlib.Path:
        """Path of the composed URDF (written to the cache on first use)."""
        return write(self.composition, directory)

    def arm(self, name: str) -> ArmSpec:
        for a in self.arms:
            if a.name == name:
                return a
        raise RegistryError(f"robot {self.name!r} has no arm {name!r} (arms: {[a.name for a in self.arms]})")

    def hand(self, name: str) -> HandSpec:
        for h in self.hands:
            if h.name == name:
                return h
        raise RegistryError(f"robot {self.name!r} has no hand {name!r} (hands: {[h.name for h in self.hands]})")

    def ft(self, name: str) -> FTSpec:
        for f in self.fts:
            if f.name == name:
                return f
        raise RegistryError(f"robot {self.name!r} has no F/T sensor {name!r} (F/T: {[f.name for f in self.fts]})")

    def camera(self, name: str) -> CameraSpec:
        for c in self.cameras:
            if c.name == name:
                return c
        raise RegistryError(f"robot {self.name!r} has no camera {name!r} (cameras: {[c.name for c in self.cameras]})")

    def validate(self) -> None:
        """Cross-check names; raises RegistryError naming the robot and field."""
        hands = {h.name for h in self.hands}
        fts = {f.name for f in self.fts}
        for a in self.arms:
            if len(a.home) != len(a.joints):
                raise RegistryError(f"{self.name}.arms[{a.name}].home has {len(a.home)} values for {len(a.joints)} joints")
            if a.hand and a.hand not in hands:
                raise RegistryError(f"{self.name}.arms[{a.name}].hand names unknown hand {a.hand!r}")
            if a.ft and a.ft not in fts:
                raise RegistryError(f"{self.name}.arms[{a.name}].ft names unknown sensor {a.ft!r}")
        for h in self.hands:
            for key in ("open", "closed"):
                if key not in h.preshapes:
                    raise RegistryError(f"{self.name}.hands[{h.name}].preshapes lacks {key!r}")
            for key, vals in h.preshapes.items():
                if len(vals) != len(h.joints):
                    raise RegistryError(f"{self.name}.hands[{h.name}].preshapes[{key}] has {len(vals)} values for {len(h.joints)} joints")
        if len(self.head_home) != len(self.head_joints):
            raise RegistryError(f"{self.name}.head_home does not match head_joints")
        if self.capabilities is not None:
            corrections = self.capabilities.grasp_corrections
            unknown = sorted(set(corrections) - set(GRASP_CORRECTIONS))
            if unknown:
                raise RegistryError(f"{self.name}.capabilities.grasp_corrections: unknown {unknown} "
                                    f"(known: {list(GRASP_CORRECTIONS)})")
            if "finger_lost" in corrections and not any(h.kind is HandKind.MULTI_FINGER for h in self.hands):
                raise RegistryError(f"{self.name}.capabilities.grasp_corrections: finger_lost needs a multi-finger "
                                    "hand (a parallel gripper has no external finger to lose)")


@dataclass(frozen=True)
class RobotHome:
    """Everything one robot is, registered in its package: spec, translation factory, primitive overrides."""

    spec: RobotSpec
    overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    """Primitive type -> ``Params`` field -> value: thesis parameters set "depending on" the hardware (§3.3)."""
    grasp_center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """m, where an object sits in a hand closing from its open preshape, in the controlled (grasp) frame."""
    preshape_centers: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    """Preshape -> m, where an object sits in a hand closing from that preshape, if not at ``grasp_center``."""
    wall_side: tuple[float, float] = (1.0, 0.0)
    """Hand-frame (x, y) side put toward a container wall when grasping beside one."""

    @property
    def name(self) -> str:
        return self.spec.name

    def validate(self) -> None:
        """The spec's cross-checks, and every preshape centre names a preshape of the robot's hands."""
        self.spec.validate()
        unknown = sorted(set(self.preshape_centers) - {k for hand in self.spec.hands for k in hand.preshapes})
        if unknown:
            raise RegistryError(f"{self.name}.preshape_centers: {unknown} are no preshape of its hands")

    def center(self, preshape: str = "") -> tuple[float, float, float]:
        """Where an object sits in a hand closing from ``preshape`` ("": the open one), grasp frame (m)."""
        return tuple(self.preshape_centers.get(preshape, self.grasp_center))

    @property
    def factory(self) -> type:
        """The robot's translation factory class (``FACTORY`` of its package's ``factory`` module)."""
        return importlib.import_module(f"{ROBOTS_PACKAGE}.{self.name}.factory").FACTORY


ROBOTS_PACKAGE = "contactflow.embodiments.robots"


def _discover() -> Mapping[str, str]:
    from contactflow.embodiments import robots

    return MappingProxyType({m.name: f"{ROBOTS_PACKAGE}.{m.name}" for m in pkgutil.iter_modules(robots.__path__)
                             if m.ispkg})


_ROBOTS = _discover()


def names() -> list[str]:
    """Names of every registered embodiment."""
    return sorted(_ROBOTS)


def configured(name: str, where: str) -> RobotSpec:
    """The spec of robot ``name`` named in a configuration at ``where``; ValueError naming the place."""
    if name not in _ROBOTS:
        raise ValueError(f"{where}: {name!r} is not a registered embodiment {names()}")
    return get(name)


def home(name: str) -> RobotHome:
    """The home of robot ``name``: its spec (validated), factory and primitive overrides."""
    if name not in _ROBOTS:
        raise RegistryError(f"unknown robot {name!r} (known: {names()})")
    h = importlib.import_module(_ROBOTS[name]).HOME
    if h.name != name:
        raise RegistryError(f"{_ROBOTS[name]}.HOME is robot {h.name!r}, not {name!r}")
    h.validate()
    return h


def get(name: str) -> RobotSpec:
    """The spec of robot ``name`` (validated)."""
    return home(name).spec
