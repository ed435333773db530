"""Robot model publisher: the spherical model (App. B), sensor frames and taxels posed from each joint state."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from contactflow.embodiments.control.kinematics import Kinematics, KinematicsError
from contactflow.embodiments.messages import JointState, RobotModel, TaxelPoses
from contactflow.embodiments.registry import PadSpec, RobotSpec
from contactflow.embodiments.spherical import SphericalModel
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.nodes.wire import NDArray


@functools.lru_cache(maxsize=256)
def pad_taxels(pad: PadSpec) -> tuple[np.ndarray, np.ndarray]:
    """Taxel centres and outward unit normals of ``pad`` in its link frame, each (rows, cols, 3), read-only
    (computed once per pad: every cue cycle poses them)."""
    from contactflow.embodiments.sensors.tactile import _pad_axes, taxel_positions

    local = taxel_positions(pad)
    n, _, _ = _pad_axes(pad)
    if pad.radius > 0:
        c = np.asarray(pad.origin, dtype=np.float64) - pad.radius * n
        normals = (local - c) / np.linalg.norm(local - c, axis=-1, keepdims=True)
    else:
        normals = np.broadcast_to(n, local.shape).copy()
    local.setflags(write=False)
    normals.setflags(write=False)
    return local, normals


def hand_regions(kin: Kinematics, spec: RobotSpec, links: tuple[str, ...] | list[str]) -> list[str]:
    """Per link of ``links``, the hand part it is: ``finger`` (moved by a hand joint), ``palm`` (the palm link or a
    link fixed to it), else ``""`` (fusion.regions reads these to tell where on the hand a contact lies)."""
    from contactflow.fusion.regions import Region

    model = kin.model
    moved = {n for h in spec.hands for n in (*h.joints, *(m[0] for m in h.mimic))}
    palms = {kin.frame_id(h.palm_link) for h in spec.hands if h.palm_link}

    def region(link: str) -> str:
        i = kin.frame_id(link)
        if model.names[model.frames[i].parentJoint] in moved:
            return str(Region.FINGER)
        joint = model.frames[i].parentJoint
        while True:  # up the fixed joints to the palm, or to a frame moved by another joint
            if i in palms:
                return str(Region.PALM)
            parent = model.frames[i].parentFrame
            if parent == i or model.frames[parent].parentJoint != joint:
                return ""
            i = parent

    return [region(link) for link in links]


def sensor_frames(spec: RobotSpec) -> tuple[str, ...]:
    """Links carrying a sensor of ``spec``: every wrist F/T link and every tactile pad link."""
    out = [f.link for f in spec.fts] + [p.link for h in spec.hands for p in h.pads]
    return tuple(dict.fromkeys(out))


class RobotModelPublisher(Module):
    """Subscribes the joint state and publishes the posed spherical model with the sensor frames, and each hand's taxel poses.

    Given no ``spec`` (hosted from a node's configuration) it models the robot it is hosted for,
    as the world built it (embodiment and base), and reads that robot's ``robot/<robot>/joints``.
    """

    layer = Layer.INTERFACE
    inputs = (Port("joint_state", JointState, "joint positions of the robot"),)
    outputs = (
        Port("robot_model", RobotModel, "posed bi-spheres and sensor frame poses, world"),
        Port("taxels", TaxelPoses, "world taxel positions and normals, one message per hand"),
    )

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz, at most once per new joint state
        frames: tuple[str, ...] = ()  # extra frames to pose besides the sensor links

    def __init__(self, name: str, params: Params | None = None, spec: RobotSpec | None = None,
                 base: np.ndarray | None = None, robot: str = "") -> None:
        super().__init__(name, params)
        self.spec = spec
        self.base = None if base is None else np.asarray(base, dtype=np.float64)
        self.robot = robot or (spec.name if spec is not None else "")
        self.kin: Kinematics | None = None
        self.model: SphericalModel | None = None

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """The joints the world publishes of the robot the module is hosted for."""
        return {"joint_state": ks.robot(robot, "joints")}

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        self._last = None
        if self.spec is None:
            from contactflow.embodiments.remote import link

            link(io.transport, io.keyspace, io.robot, io.node)  # the world's description, asked at the first step
        else:
            self._build(self.spec, self.base if self.base is not None else np.eye(4))

    def _build(self, spec: RobotSpec, base: np.ndarray) -> None:
        self.spec, self.base = spec, base
        self.kin = Kinematics(spec.urdf(), base)
        self.model = SphericalModel.from_urdf(self.kin, str(spec.urdf()))
        self.regions = hand_regions(self.kin, spec, self.model.links)
        self.frames = tuple(dict.fromkeys((*sensor_frames(spec), *self.params.frames)))
        for f in self.frames:
            self.kin.frame_id(f)
        self.hands = [(h.name, [p.name for p in h.pads], [p.link for p in h.pads],
                       np.stack([pad_taxels(p)[0] for p in h.pads]), np.stack([pad_taxels(p)[1] for p in h.pads]))
                      for h in spec.hands if h.pads]

    def step(self) -> Status:
        assert self.io is not None
        if self.kin is None:
            from contactflow.embodiments.remote import connect

            robot = connect(self.io.transport, self.io.keyspace, self.io.robot, self.io.node)
            self.robot = self.robot or robot.name
            self._build(robot.spec, robot.base)
        assert self.kin is not None and self.model is not None
        msg = self.io.latest("joint_state")
        if msg is None or msg is self._last:
            return Status.RUNNING
        self._last = msg
        q_in = msg.position.numpy().astype(np.float64).ravel()
        if q_in.shape[0] != len(msg.names) or not np.isfinite(q_in).all():
            raise ValueError(f"{self.name}: input 'joint_state' has {q_in.shape[0]} positions for "
                             f"{len(msg.names)} names or non-finite values")
        try:
            idx = self.kin.q_index(msg.names)
        except KinematicsError as exc:
            raise ValueError(f"{self.name}: input 'joint_state': {exc}") from None
        q = self.kin.q.copy()
        q[idx] = q_in
        self.kin.update(q)
        self.model.update(self.kin)
        t = msg.hdr.t_sim if msg.hdr.t_sim > 0 else self.io.now
        poses = np.stack([self.kin.frame_pose(f) for f in self.frames]) if self.frames else np.zeros((0, 4, 4))
        self.io.publish("robot_model", RobotModel(
            robot=self.robot, t=t, links=list(self.model.links), c1=NDArray.of(self.model.C1),
            r1=NDArray.of(self.model.r1), c2=NDArray.of(self.model.C2), r2=NDArray.of(self.model.r2),
            regions=self.regions, frames=list(self.frames), poses=NDArray.of(poses) if self.frames else None))
        for hand, pads, links, local, normals in self.hands:
            T = np.stack([self.kin.frame_pose(link) for link in links])
            pos = np.einsum("kij,kabj->kabi", T[:, :3, :3], local) + T[:, None, None, :3, 3]
            nrm = np.einsum("kij,kabj->kabi", T[:, :3, :3], normals)
            self.io.publish("taxels", TaxelPoses(robot=self.robot, hand=hand, t=t, pads=pads,
                                                 positions=NDArray.of(np.ascontiguousarray(pos)),
                                                 normals=NDArray.of(np.ascontiguousarray(nrm))))
        return Status.RUNNING
