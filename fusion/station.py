"""A robot station's contact cues: each arm's tactile pads, wrist F/T and finger pose as hypothesis clouds (thesis eq. 4.6, 4.8-4.9, §4.4.5).

``contact_cues`` modules publish them on ``contacts/<robot>/tactile_<arm>``,
``contacts/<robot>/force_torque_<arm>`` and, for a multi-finger hand,
``contacts/<robot>/finger_pose_<arm>`` (empty when the sensor feels nothing) and a
``contact_fusion`` module fuses them into the robot's contacts and events
(``layout.contact_modules``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.fusion.generators.finger import FingerParams, FingerPoseGenerator
from contactflow.fusion.generators.tactile import tactile_hypotheses
from contactflow.fusion.geometry import capsule_surface
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.sim_sources import (
    hand_capsules,
    stope_capsules,
    taxel_readings,
    wrist_hypotheses,
)
from contactflow.nodes.status import Status


@dataclass
class Cue:
    """One arm's contact cues: its hand's pads and its wrist F/T."""

    name: str
    arm: str
    hand: str
    ft_link: str
    links: tuple[str, ...]
    min_force: float  # N, below this the wrist reading is noise


def hand_links(spec, arm: str) -> tuple[str, ...]:
    """Name prefixes of the links of ``arm``'s hand in the robot's model: its palm and fingertips (where
    pads and contacts are), else the wrist sensor's link; () for an arm without a hand."""
    a = spec.arm(arm)
    if not a.hand:
        return ()
    hand = spec.hand(a.hand)
    return tuple(p for p in (hand.palm_link, *hand.fingertips) if p) or ((spec.ft(a.ft).link,) if a.ft else ())


def robot_cues(robot: object, min_force: float) -> list[Cue]:
    """The cues of every arm of ``robot`` with a hand (a SimRobot, or a world's robot over the key space)."""
    spec = robot.spec
    cues = []
    for arm in spec.arms:
        if not arm.hand:
            continue
        ft = spec.ft(arm.ft) if arm.ft else None
        ft_link = ft.link if ft is not None else ""
        hand = spec.hand(arm.hand)
        prefixes = hand_links(spec, arm.name)
        # 4 sigma above the sensor noise: an estimated wrench (Baxter) is far noisier
        floor = max(min_force, 4.0 * ft.force_noise) if ft is not None else min_force
        cues.append(Cue(arm.name, arm.name, hand.name, ft_link, prefixes, floor))
    return cues


def cue_clouds(robot: object, cue: Cue, now: float) -> list[tuple[str, Hypotheses]]:
    """``(generator, cloud)`` of the cue's pads (``tactile_<arm>``) and wrist F/T (``force_torque_<arm>``) now;
    a cloud is empty when its sensor feels nothing."""
    pressure, taxels, normals = taxel_readings(robot, cue.hand)
    cloud = Hypotheses.empty(now)
    if pressure.size and float(pressure.max()) > 0:
        cloud = tactile_hypotheses(pressure, taxels, now, normals)
    out = [(f"tactile_{cue.name}", cloud)]
    if cue.ft_link:
        force = np.linalg.norm(robot.ft(cue.arm).external[:3])
        cloud = Hypotheses.empty(now)
        if force >= cue.min_force:
            cloud, _ = wrist_hypotheses(robot, cue.arm, cue.ft_link, hand_capsules(robot, cue.links), now)
        out.append((f"force_torque_{cue.name}", cloud))
    return out


class FingerCue:
    """Finger pose feedback (thesis §4.4.5) of one cue's multi-finger hand: a finger its drive does not move
    that the hand's encoders show moved since the hand came to rest is bent by a contact, somewhere on its
    surface (:class:`~contactflow.fusion.generators.finger.FingerPoseGenerator`, which takes its reference once
    the fingers are still). The hand is driven while its last command runs; each finger's surface is the
    bi-spheres of its joints' links in the posed model.
    """

    def __init__(self, robot: object, cue: Cue, params: FingerParams | None = None) -> None:
        from contactflow.embodiments.primitives.hands import finger_groups

        spec = robot.spec.hand(cue.hand)
        model, sph = robot.kin.model, robot.spherical
        fingers = list(finger_groups(spec).values())
        self.hand = cue.hand
        # the s-topes of each finger: those hung on its joints (pinocchio joint ids, as the model's s-topes)
        joints = [{model.getJointId(spec.joints[int(j)]) for j in f} for f in fingers]
        hung = np.array([st.joint for st in sph.stopes])
        self.stopes = [np.flatnonzero(np.isin(hung, sorted(ids))) for ids in joints]
        self.core = FingerPoseGenerator(fingers, params or FingerParams(robot=robot.name))

    @staticmethod
    def applies(robot: object, cue: Cue) -> bool:
        """True for a hand of several fingers, each with joints of its own (a gripper's jaws share theirs)."""
        from contactflow.embodiments.primitives.hands import finger_groups

        return len({tuple(j) for j in finger_groups(robot.spec.hand(cue.hand)).values()}) > 1

    def cloud(self, robot: object, now: float) -> Hypotheses:
        """This reading's hypotheses: on the fingers bent since the hand last came to rest (empty while it is driven)."""
        hand = robot.hand(self.hand)

        def surface(finger: int) -> np.ndarray:
            return capsule_surface(stope_capsules(robot.spherical, self.stopes[finger]), self.core.params.voxel_size)

        return self.core.update(hand.positions(), surface, now, actuated=hand.status is Status.RUNNING)
