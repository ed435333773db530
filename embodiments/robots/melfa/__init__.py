"""Melfa's home (App. A.3): its spec, translation factory and the primitive overrides its hardware needs."""

from __future__ import annotations

from contactflow.embodiments.registry import RobotHome
from contactflow.embodiments.robots.melfa.spec import SPEC

HOME = RobotHome(
    spec=SPEC,
    overrides={
        # simulated wrist F/T of a panda-sized gripper: contact torques are tenths of N m, not the JR3's N m.
        # A parallel gripper has no finger-lost correction (two fingers, no external finger to lose)
        "robust_grasp": {"torque_threshold": 0.1, "finger_lost": False},
    },
)
