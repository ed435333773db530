"""A robot station's contact cues: each arm's tactile pads and wrist F/T as hypothesis clouds (thesis eq. 4.6, 4.8-4.9).

``contact_cues`` modules publish them on ``contacts/<robot>/tactile_<arm>`` and
``contacts/<robot>/force_torque_<arm>`` (empty when the sensor feels nothing) and a
``contact_fusion`` module fuses them into the robot's contacts and events
(``layout.contact_modules``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.fusion.generators.tactile import tactile_hypotheses
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.sim_sources import hand_capsules, taxel_readings, wrist_hypotheses


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
