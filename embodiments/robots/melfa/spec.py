"""Melfa stand-in (App. A.3): a 6-DoF UR5 arm carrying the panda parallel gripper with tactile pads.

Composition: ``ur_description/urdf/ur5_robot.urdf`` without its ``world`` link, and the panda
gripper (``panda.urdf`` minus the arm links) mounted on ``tool0`` by a fixed joint; the wrist
F/T sits at that joint (JR3 between gripper and arm on the real setup).
"""

from __future__ import annotations

from contactflow.embodiments.registry import ArmSpec, Capabilities, Computer, FTSpec, RobotSpec
from contactflow.embodiments.robots.parts import panda_gripper, panda_gripper_part
from contactflow.embodiments.urdf_compose import Composition, Mount, Part

UR5_JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")

_comp = Composition(
    name="melfa",
    parts=(
        Part("ur_description/urdf/ur5_robot.urdf", drop_root="world"),
        panda_gripper_part("", Mount(parent="tool0")),
    ),
)

SPEC = RobotSpec(
    name="melfa",
    description="6-DoF industrial arm with a parallel gripper with tactile pads and a wrist F/T",
    composition=_comp,
    arms=(ArmSpec(name="arm", joints=UR5_JOINTS, base_link="base_link", ee_frame="panda_hand_tcp",
                  home=(0.0, -1.8, 1.9, -1.671, -1.5707963267948966, 0.0), hand="gripper", ft="wrist_ft",
                  kp=2000.0, kd=200.0, force_limit=1000.0),),
    hands=(panda_gripper("gripper", ""),),
    fts=(FTSpec(name="wrist_ft", link="panda_hand"),),
    capabilities=Capabilities(
        primitives=frozenset({"transport", "move_to", "release", "hold", "lift", "wait_event", "watch_prediction", "detect_objects",
                              "place_location", "close_until_force", "robust_grasp",
                              "poke", "choose_mapped"}),
        workspace_min=(0.2, -0.5, 0.75),
        workspace_max=(0.75, 0.5, 1.3),
        payload=3.0,
        max_opening=0.08,
        wrench_noise=0.05,
        speed=0.25,
        grasp_corrections=("alignment", "sliding", "force_adaptation"),  # parallel gripper: no finger to lose
    ),
    computers=(Computer("control", "arm, gripper, F/T, tactile", ("joint_state_publisher", "joint_command_subscriber", "ft", "tactile")),),
    base_xyz=(0.0, 0.0, 0.75),
)
