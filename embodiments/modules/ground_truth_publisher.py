"""Ground-truth publisher: object poses and true contacts, for evaluation only.

The node routes these ports to ``KeySpace.evaluation(robot, stream)``; primitives and
fusion never subscribe there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from contactflow.embodiments.messages import ObjectPoses, TrueContacts
from contactflow.embodiments.modules.backend import RobotBackend
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.nodes.wire import NDArray


class GroundTruthPublisher(Module):
    """Publishes the simulator's object poses and contact points."""

    layer = Layer.INTERFACE
    outputs = (Port("object_poses", ObjectPoses, "object poses (evaluation)"),
               Port("true_contacts", TrueContacts, "physics contacts (evaluation)"))

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz

    def __init__(self, name: str, robot: RobotBackend, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.robot = robot

    @classmethod
    def default_output_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """Ground truth lives under ``eval/``, a part of the key space no primitive reads."""
        return {port.name: ks.evaluation(robot, port.name) for port in cls.outputs}

    def step(self) -> Status:
        gt = self.robot.ground_truth()
        names = list(gt.object_poses)
        poses = np.stack([gt.object_poses[n] for n in names]) if names else np.zeros((0, 4, 4))
        self.io.publish("object_poses", ObjectPoses(names=names, poses=NDArray.of(poses)))
        c = gt.contacts
        self.io.publish("true_contacts", TrueContacts(
            body_a=[x.body_a for x in c], body_b=[x.body_b for x in c],
            positions=NDArray.of(np.array([x.position for x in c]).reshape(-1, 3)),
            normals=NDArray.of(np.array([x.normal for x in c]).reshape(-1, 3)),
            forces=NDArray.of(np.array([x.force for x in c], dtype=np.float64))))
        return Status.RUNNING
