"""Contact cues of a world's robot on a node: one arm's tactile pads, wrist F/T and finger pose as generator clouds on the key space."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from contactflow.fusion.messages import HypothesisCloud
from contactflow.fusion.station import FingerCue, cue_clouds, robot_cues
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status


class ContactCues(Module):
    """The tactile (eq. 4.6), wrist F/T (eq. 4.8-4.9) and finger pose (§4.4.5) generators of one arm of the robot the
    module is hosted for.

    It reads what the robot's station would give, over the key space: the world's
    ``robot/<robot>/state`` (pressures, the wrench, the hand's encoders and whether its command
    still runs) and the robot's own model at the measured joints (taxel poses, the hand's
    bi-spheres). Each cycle it publishes one cloud per generator on
    ``contacts/<robot>/tactile_<arm>``, ``contacts/<robot>/force_torque_<arm>`` and, for a
    multi-finger hand, ``contacts/<robot>/finger_pose_<arm>``, empty when the sensor feels
    nothing, so a fusion service waiting for all its sources is never kept waiting;
    ``contact_fusion`` fuses them.
    """

    layer = Layer.SERVICE
    outputs = (Port("tactile", HypothesisCloud, "tactile hypotheses of the arm's hand, world frame"),
               Port("force_torque", HypothesisCloud, "wrist F/T hypotheses on the arm's hand, world frame"),
               Port("finger_pose", HypothesisCloud, "finger pose hypotheses on the fingers a contact bent (a multi-finger "
                                                    "hand), world frame"))

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz of the node's clock (simulated time on a lockstep node)
        arm: str = ""  # the arm whose hand and wrist sensor feel (required)
        min_force: float = 1.5  # N, wrist forces below this feed no F/T cloud (noise, the hand's own weight)

    @classmethod
    def default_output_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        if not params.arm:
            raise ValueError(f"{name}.params.arm: name the arm whose cues the module publishes")
        return {port.name: ks.hypotheses(robot, f"{port.name}_{params.arm}") for port in cls.outputs}

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        from contactflow.embodiments.remote import link

        # subscribed now, so the robot's state is there when the module first steps
        link(io.transport, io.keyspace, io.robot, io.node)
        self.robot: Any = None

    def step(self) -> Status:
        from contactflow.embodiments.remote import connect

        io = self.io
        if self.robot is None:
            self.robot = connect(io.transport, io.keyspace, io.robot, io.node)
            cues = {c.arm: c for c in robot_cues(self.robot, self.params.min_force)}
            if self.params.arm not in cues:
                raise ValueError(f"{self.name}.params.arm: {self.params.arm!r} is no arm with a hand of {io.robot} "
                                 f"({sorted(cues)})")
            self.cue = cues[self.params.arm]
            self.fingers = FingerCue(self.robot, self.cue) if FingerCue.applies(self.robot, self.cue) else None
        r = self.robot
        state = r.link.state  # the sensor message the clouds are computed from: their provenance
        read = [state.hdr.id] if state is not None and state.hdr.source else []
        for generator, cloud in cue_clouds(r, self.cue, r.time):
            port = generator.removesuffix(f"_{self.cue.name}")
            io.publish(port, HypothesisCloud.of(cloud, r.name, generator, self.cue.hand), inputs=read)
        if self.fingers is not None:
            io.publish("finger_pose", HypothesisCloud.of(self.fingers.cloud(r, r.time), r.name,
                                                         f"finger_pose_{self.cue.name}", self.cue.hand), inputs=read)
        return Status.RUNNING
