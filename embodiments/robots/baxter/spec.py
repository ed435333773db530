"""Baxter (App. A.4) from example-robot-data: dual 7-DoF arms with parallel grippers.

Its wrist wrench is not measured by a sensor but estimated from the arm joint efforts, so
it is noisy and biased, as the virtual F/T of the real robot (App. A.4.2).
"""

from __future__ import annotations

from contactflow.embodiments.registry import (
    ArmSpec,
    Capabilities,
    Computer,
    FTSpec,
    HandKind,
    HandSpec,
    RobotSpec,
)
from contactflow.embodiments.urdf_compose import Composition, Part


def _arm(side: str, home: tuple[float, ...]) -> ArmSpec:
    joints = tuple(f"{side}_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2"))
    return ArmSpec(name=side, joints=joints, base_link=f"{side}_arm_mount", ee_frame=f"{side}_gripper", home=home,
                   hand=f"{side}_gripper", ft=f"{side}_ft", kp=800.0, kd=80.0, force_limit=300.0)


def _gripper(side: str) -> HandSpec:
    s = side[0]
    return HandSpec(
        name=f"{side}_gripper",
        kind=HandKind.PARALLEL,
        joints=(f"{s}_gripper_l_finger_joint",),
        mimic=((f"{s}_gripper_r_finger_joint", f"{s}_gripper_l_finger_joint", -1.0),),
        preshapes={"open": (0.020833,), "closed": (0.0,)},
        fingertips=(f"{s}_gripper_l_finger_tip", f"{s}_gripper_r_finger_tip"),
        palm_link=f"{side}_gripper_base_link",
        kp=1000.0, kd=100.0, force_limit=40.0, friction=2.0, max_velocity=0.1,
    )


SPEC = RobotSpec(
    name="baxter",
    description="Rethink Baxter: compliant dual 7-DoF arms, parallel grippers, wrist wrench estimated from joint efforts",
    composition=Composition(name="baxter", parts=(Part("baxter_description/urdf/baxter.urdf"),)),
    arms=(
        _arm("left", (0.08, -1.0, -1.19, 1.94, 0.67, 1.03, -0.5)),
        _arm("right", (-0.08, -1.0, 1.19, 1.94, -0.67, 1.03, 0.5)),
    ),
    hands=(_gripper("left"), _gripper("right")),
    fts=(
        FTSpec(name="left_ft", link="left_hand_link", estimated=True, arm="left", force_noise=1.5, torque_noise=0.15,
               bias=(0.8, -0.5, 1.2, 0.05, -0.03, 0.02), rate_hz=100.0),
        FTSpec(name="right_ft", link="right_hand_link", estimated=True, arm="right", force_noise=1.5, torque_noise=0.15,
               bias=(-0.6, 0.4, 1.0, -0.04, 0.03, 0.02), rate_hz=100.0),
    ),
    head_joints=("head_pan",),
    head_home=(0.0,),
    capabilities=Capabilities(
        primitives=frozenset({"transport", "move_to", "release", "hold", "lift", "wait_event", "watch_prediction", "detect_objects", "place_location",
                              "close_until_force", "close_until_stall", "naive_grasp", "place", "slide", "push", "pull",
                              "touch", "explore"}),
        workspace_min=(0.4, -0.9, 0.75),
        workspace_max=(1.1, 0.9, 1.4),
        payload=2.2,
        max_opening=0.055,
        wrench_noise=2.0,  # the wrist wrench is estimated from joint efforts: noisy
        speed=0.2,
        grasp_corrections=("alignment", "sliding", "force_adaptation"),  # parallel grippers: no finger to lose
    ),
    computers=(Computer("baxter_pc", "arm controller, virtual F/T", ("joint_state_publisher", "joint_command_subscriber", "ft")),
               Computer("workstation", "vision, fusion, tasks", ("camera", "ground_truth"))),
    base_xyz=(0.0, 0.0, 0.85),
)
