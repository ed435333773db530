"""Reusable example-robot-data parts: the panda arm, the allegro hand, the panda gripper.

Composition documented here (the tombatossals and melfa robots use it):
- ``panda_arm_with_allegro``: ``panda_description/urdf/panda.urdf`` minus ``panda_hand``,
  ``panda_hand_tcp`` and the two fingers; ``allegro_hand_description/urdf/allegro_right_hand.urdf``
  mounted by a fixed joint ``panda_link8 -> palm_link`` with the palm normal along the
  flange axis (like the Barrett/SDH hands of the real robot, App. A.1.2): the back of the
  palm on the flange, the palm centre on the flange axis, fingers perpendicular to it.
  At the panda home pose the palm faces down and the fingers point forward. A fixed
  ``grasp`` frame sits where the closed fingertips meet (6 cm in front of the palm, z =
  approach = palm normal, x = from the fingertips toward the wrist side of the palm).
- ``panda_gripper``: ``panda.urdf`` minus ``panda_link0..8``, so its root is ``panda_hand``.
"""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.registry import HandKind, HandSpec, PadSpec
from contactflow.embodiments.urdf_compose import ExtraLink, Mount, Part

PANDA = "panda_description/urdf/panda.urdf"
ALLEGRO = "allegro_hand_description/urdf/allegro_right_hand.urdf"
PANDA_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
PANDA_HOME = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)
PANDA_HAND_LINKS = ("panda_hand", "panda_hand_tcp", "panda_leftfinger", "panda_rightfinger")
PANDA_ARM_LINKS = tuple(f"panda_link{i}" for i in range(9))
ALLEGRO_JOINTS = tuple(f"joint_{i}.0" for i in range(16))
ALLEGRO_TIPS = ("link_3.0_tip", "link_7.0_tip", "link_11.0_tip", "link_15.0_tip")


def panda_arm_with_allegro(prefix: str, mount: Mount | None) -> tuple[tuple[Part, ...], tuple[ExtraLink, ...]]:
    """Parts and extra links of one panda arm carrying an allegro right hand."""
    arm = Part(PANDA, prefix=prefix, drop_links=PANDA_HAND_LINKS, mount=mount)
    # palm x (normal) -> flange z, palm z (fingers) -> flange -x, yawed so the fingers point forward at home
    c = 0.0475 * np.cos(np.pi / 4)
    hand = Part(ALLEGRO, prefix=prefix, mount=Mount(parent=f"{prefix}panda_link8", xyz=(c, -c, 0.03),
                                                    rpy=(0.0, -np.pi / 2, 3 * np.pi / 4)))
    grasp = ExtraLink(name=f"{prefix}grasp", parent=f"{prefix}palm_link", joint=f"{prefix}grasp_joint",
                      xyz=(0.06, 0.0, -0.03), rpy=(0.0, np.pi / 2, 0.0), mass=0.001)
    return (arm, hand), (grasp,)


def allegro_hand(name: str, prefix: str) -> HandSpec:
    """An allegro hand with one 5x8 tactile pad on the palmar side (+x) of each fingertip."""
    pads = tuple(
        PadSpec(name=f"{finger}", link=f"{prefix}{tip}", origin=(0.012, 0.0, 0.0), normal=(1.0, 0.0, 0.0),
                u_axis=(0.0, 0.0, 1.0), size=(0.032, 0.023), radius=0.012, sigma=0.003)
        for finger, tip in zip(("index", "middle", "ring", "thumb"), ALLEGRO_TIPS, strict=True)
    )
    finger_open = (0.0, 0.0, 0.0, 0.0)
    return HandSpec(
        name=name,
        kind=HandKind.MULTI_FINGER,
        joints=tuple(prefix + j for j in ALLEGRO_JOINTS),
        preshapes={
            "open": finger_open * 3 + (0.5, 0.0, 0.0, 0.0),
            "closed": (0.0, 1.3, 1.3, 1.0) * 3 + (1.3, 0.9, 0.9, 0.9),
            "pinch": (0.0, 0.9, 0.8, 0.6) + finger_open * 2 + (1.3, 0.5, 0.6, 0.8),
            "cylindrical": (0.0, 0.6, 0.6, 0.4) * 3 + (1.2, 0.3, 0.4, 0.4),
            # the thesis's Barrett hand opened for a top grasp: fingers and thumb bent toward the approach (fingertips
            # 2.7 cm, thumb tip 6.8 cm past the grasp frame, 14.6 cm apart), so a descent meets the table or the
            # object with the fingertips, around the object, and the close wraps it (from "open", a flat paddle, it
            # meets the top, and the fingers curl into the table beside anything lower than 7 cm)
            "claw": (0.0, 0.7, 0.2, 0.1) * 3 + (1.3, 0.5, 0.2, 0.2),
            "spherical": (-0.2, 0.5, 0.6, 0.4, 0.0, 0.5, 0.6, 0.4, 0.2, 0.5, 0.6, 0.4, 1.0, 0.4, 0.5, 0.5),
        },
        fingertips=tuple(prefix + t for t in ALLEGRO_TIPS),
        palm_link=f"{prefix}palm_link",
        pads=pads,
        kp=20.0,
        kd=1.0,
        force_limit=15.0,
        friction=1.5,
        max_velocity=3.0,
        armature=0.01,
    )


def panda_gripper_part(prefix: str, mount: Mount) -> Part:
    """The panda parallel gripper alone, mounted on ``mount``."""
    return Part(PANDA, prefix=prefix, drop_links=PANDA_ARM_LINKS, mount=mount)


def panda_gripper(name: str, prefix: str) -> HandSpec:
    """The panda gripper with a 5x8 tactile pad on the inner face of each finger."""
    pads = (
        PadSpec(name="left", link=f"{prefix}panda_leftfinger", origin=(0.0, 0.0, 0.045), normal=(0.0, -1.0, 0.0),
                u_axis=(0.0, 0.0, 1.0), size=(0.0185, 0.0175), sigma=0.002),
        PadSpec(name="right", link=f"{prefix}panda_rightfinger", origin=(0.0, 0.0, 0.045), normal=(0.0, 1.0, 0.0),
                u_axis=(0.0, 0.0, 1.0), size=(0.0185, 0.0175), sigma=0.002),
    )
    return HandSpec(
        name=name,
        kind=HandKind.PARALLEL,
        joints=(f"{prefix}panda_finger_joint1",),
        mimic=((f"{prefix}panda_finger_joint2", f"{prefix}panda_finger_joint1", 1.0),),
        preshapes={"open": (0.04,), "closed": (0.0,)},
        fingertips=(f"{prefix}panda_leftfinger", f"{prefix}panda_rightfinger"),
        palm_link=f"{prefix}panda_hand",
        pads=pads,
        kp=1000.0,
        kd=100.0,
        force_limit=100.0,
        friction=2.0,
        max_velocity=0.2,
    )
