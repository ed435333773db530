"""Finger pose feedback hypotheses generator (thesis §4.4.5): single-contact per finger, uniform law.

On compliant hands a contact bends a finger that is not being driven. The encoder values of
each finger are compared with a reference taken while the hand was still; a finger whose
joints moved more than ``joint_threshold`` gets hypotheses over its whole surface, each with
likelihood 1/n. While the hand is driven the generator is disabled, and it takes a new
reference once the hand stops (its joints move less than ``still`` between two readings). The shell reads the encoders from the robot's joint state and
samples each finger's surface from the bi-spheres of its links in the posed robot model.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import JointState, RobotModel
from contactflow.fusion.generators.base import GeneratorModule, capsules_of
from contactflow.fusion.geometry import capsule_surface
from contactflow.fusion.hypotheses import VOXEL_SIZE, Hypotheses, HypothesisType, voxelize
from contactflow.nodes.messages import Vector
from contactflow.nodes.module import Port
from contactflow.nodes.status import Status

FingerSurface = Callable[[int], np.ndarray]
"""Points (k, 3) sampled on finger ``i``'s surface at the current joint values, world frame."""


@dataclass(frozen=True)
class FingerParams:
    rate_hz: float = 30.0  # Hz
    robot: str = "robot"
    joint_threshold: float = 0.03  # rad, involuntary joint deflection that means contact
    still: float = 0.005  # rad, the largest joint change between two readings of a hand at rest (a reference is taken)
    finger_of_joint: tuple[float, ...] = ()  # finger index of each encoder joint (-1: none); () = one finger per joint
    voxel_size: float = VOXEL_SIZE  # m
    joints: tuple[str, ...] = ()  # encoder joints of the hand in the joint state; () = every joint
    finger_links: tuple[str, ...] = ()  # link name prefix of each finger (index = finger)


def fingers_of(finger_of_joint: Sequence[float], n_joints: int) -> list[list[int]]:
    """Joint indices per finger from a finger index per joint (-1 for joints of no finger)."""
    if not finger_of_joint:
        return [[j] for j in range(n_joints)]
    if len(finger_of_joint) != n_joints:
        raise ValueError(f"finger_pose: finger_of_joint has {len(finger_of_joint)} entries for {n_joints} joints")
    ids = sorted({int(f) for f in finger_of_joint if f >= 0})
    return [[j for j, f in enumerate(finger_of_joint) if int(f) == i] for i in ids]


class FingerPoseGenerator:
    """Pure core: ``fingers`` lists the joint indices of each finger in the encoder vector."""

    def __init__(self, fingers: Sequence[Sequence[int]], params: FingerParams | None = None) -> None:
        if not fingers or any(len(f) == 0 for f in fingers):
            raise ValueError("finger_pose: every finger needs at least one joint index")
        self.fingers = [np.asarray(f, dtype=int) for f in fingers]
        self.params = params or FingerParams()
        self.reference: np.ndarray | None = None
        self._last: np.ndarray | None = None  # the previous reading: whether the fingers still move

    def deflected(self, q: np.ndarray) -> list[int]:
        """Fingers whose joints moved away from the reference."""
        if self.reference is None:
            return []
        dq = np.abs(np.asarray(q, dtype=float) - self.reference)
        return [i for i, idx in enumerate(self.fingers) if dq[idx].max() > self.params.joint_threshold]

    def update(self, q: np.ndarray, surface: FingerSurface, stamp: float, actuated: bool = False) -> Hypotheses:
        q = np.asarray(q, dtype=float).ravel()
        top = max(int(f.max()) for f in self.fingers)
        if q.size <= top:
            raise ValueError(f"finger_pose: {q.size} joint values, finger joint index {top} needs more")
        still = self._last is None or float(np.abs(q - self._last).max()) <= self.params.still
        self._last = q.copy()
        if actuated:
            self.reference = None
            return Hypotheses.empty(stamp)
        if self.reference is None:
            # a hand whose command ended still settles onto its goal: the reference waits until it is at rest
            if still:
                self.reference = q.copy()
            return Hypotheses.empty(stamp)
        clouds = []
        for i in self.deflected(q):
            pts = np.asarray(surface(i), dtype=float).reshape(-1, 3)
            if pts.shape[0] == 0:
                continue
            h = voxelize(Hypotheses.make(pts, 1.0, HypothesisType.REGULAR, stamp=stamp, where="finger_pose"),
                         self.params.voxel_size, reduce="max")
            clouds.append(Hypotheses(h.location, np.full(len(h), 1.0 / len(h)), h.kind, h.force, h.direction, stamp))
        return Hypotheses.concat(clouds, stamp)


class FingerPoseHypothesesGenerator(GeneratorModule):
    """Compliant finger deflection to hypotheses on the deflected finger (§4.4.5)."""

    Params = FingerParams
    inputs = (
        Port("joint_state", JointState, "joint state of the robot, holding the hand encoders"),
        Port("robot_model", RobotModel, "posed bi-spheres; each finger's surface from its links"),
        Port("actuated", Vector, "[1] while the hand is driven, [0] otherwise"),
    )

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        self.core: FingerPoseGenerator | None = None

    def reset(self) -> None:
        self.core = None

    def encoders(self, msg: JointState) -> np.ndarray:
        q = msg.position.numpy().astype(np.float64).ravel()
        if q.shape[0] != len(msg.names):
            raise ValueError(f"{self.name}: input 'joint_state' has {q.shape[0]} positions for {len(msg.names)} names")
        if not self.params.joints:
            return q
        missing = [j for j in self.params.joints if j not in msg.names]
        if missing:
            raise ValueError(f"{self.name}: input 'joint_state' lacks joints {missing} (params.joints)")
        return q[[msg.names.index(j) for j in self.params.joints]]

    def surface(self, model: RobotModel, finger: int) -> np.ndarray:
        links = self.params.finger_links
        if finger >= len(links):
            raise ValueError(f"{self.name}: finger {finger} has no entry in params.finger_links {list(links)}")
        caps = capsules_of(model, "robot_model", self.name, (links[finger],))
        assert caps is not None
        return capsule_surface(caps, self.params.voxel_size)

    def step(self) -> Status:
        assert self.io is not None
        frames = self.io.take("joint_state")
        model = self.io.latest("robot_model")
        if not frames or model is None:
            return Status.RUNNING
        act = self.io.latest("actuated")
        actuated = bool(act is not None and act.values and act.values[0] > 0.5)  # type: ignore[attr-defined]
        msg = frames[-1]
        assert isinstance(msg, JointState) and isinstance(model, RobotModel)
        q = self.encoders(msg)
        if self.core is None:
            self.core = FingerPoseGenerator(fingers_of(self.params.finger_of_joint, q.size), self.params)
        h = self.core.update(q, lambda i: self.surface(model, i), self.stamp_of(msg), actuated)
        self.publish_cloud(h)
        return Status.RUNNING
