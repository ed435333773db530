"""Tombatossals (UJI humanoid torso, App. A.1) rebuilt from example-robot-data parts.

Composition: a fixed ``torso`` root; two panda arms (prefixes ``left_``/``right_``) standing
on the torso 0.3 m either side of its centre, each carrying an allegro right hand (see
``robots/parts.py``); a pan-tilt head (``head_pan`` about z, ``head_tilt`` about y) on a
column behind the arms, carrying a Kinect-like RGBD camera (640x480, f = 525 px) looking
forward. Wrist F/T sensors sit at the fixed joint between ``panda_link8`` and the hand palm.
The two arms (with their hands) collide with each other and with the head; links within
one arm do not (self-collision inside an arm is off, as for every simulated robot).
"""

from __future__ import annotations

from contactflow.embodiments.registry import (
    ArmSpec,
    CameraSpec,
    Capabilities,
    Computer,
    FTSpec,
    RobotSpec,
)
from contactflow.embodiments.robots.parts import (
    PANDA_HOME,
    PANDA_JOINTS,
    allegro_hand,
    panda_arm_with_allegro,
)
from contactflow.embodiments.urdf_compose import Composition, ExtraLink, Mount

_left_parts, _left_extra = panda_arm_with_allegro("left_", Mount("torso", xyz=(0.0, 0.3, 0.0)))
_right_parts, _right_extra = panda_arm_with_allegro("right_", Mount("torso", xyz=(0.0, -0.3, 0.0)))

_head = (
    ExtraLink(name="head_column", parent="torso", joint="head_column_joint", xyz=(-0.25, 0.0, 0.0),
              box=(0.08, 0.08, 0.7), box_xyz=(0.0, 0.0, 0.35), mass=2.0),
    ExtraLink(name="head_pan_link", parent="head_column", joint="head_pan", joint_type="revolute",
              xyz=(0.0, 0.0, 0.75), axis=(0.0, 0.0, 1.0), limits=(-1.2, 1.2), mass=0.5),
    ExtraLink(name="head_tilt_link", parent="head_pan_link", joint="head_tilt", joint_type="revolute",
              xyz=(0.0, 0.0, 0.05), axis=(0.0, 1.0, 0.0), limits=(-0.3, 1.2),
              box=(0.06, 0.28, 0.05), mass=0.5),
    ExtraLink(name="kinect_link", parent="head_tilt_link", joint="kinect_joint", xyz=(0.05, 0.0, 0.0), mass=0.05),
)

_comp = Composition(
    name="tombatossals",
    root="torso",
    parts=_left_parts + _right_parts,
    extras=_left_extra + _right_extra + _head,
)

_hands = (allegro_hand("left_hand", "left_"), allegro_hand("right_hand", "right_"))

SPEC = RobotSpec(
    name="tombatossals",
    description="UJI humanoid torso: two 7-DoF arms with 16-DoF hands, fingertip tactile pads, wrist F/T, pan-tilt RGBD head",
    composition=_comp,
    arms=(
        ArmSpec(name="left", joints=tuple("left_" + j for j in PANDA_JOINTS), base_link="left_panda_link0",
                ee_frame="left_grasp", home=PANDA_HOME, hand="left_hand", ft="left_ft"),
        ArmSpec(name="right", joints=tuple("right_" + j for j in PANDA_JOINTS), base_link="right_panda_link0",
                ee_frame="right_grasp", home=PANDA_HOME, hand="right_hand", ft="right_ft"),
    ),
    hands=_hands,
    fts=(FTSpec(name="left_ft", link="left_palm_link"), FTSpec(name="right_ft", link="right_palm_link")),
    cameras=(CameraSpec(name="kinect", link="kinect_link", rpy=(-1.5707963267948966, 0.0, -1.5707963267948966)),),
    head_joints=("head_pan", "head_tilt"),
    head_home=(0.0, 0.7),
    capabilities=Capabilities(
        primitives=frozenset({"transport", "move_to", "release", "hold", "lift", "wait_event", "watch_prediction", "detect_objects", "place_location",
                              "robust_grasp", "naive_grasp", "place", "slide", "explore", "unscrew", "push", "pull",
                              "touch", "poke", "choose_mapped"}),
        workspace_min=(0.2, -0.8, 0.75),
        workspace_max=(0.85, 0.8, 1.35),
        payload=2.0,
        hand_shapes={"open": "open", "closed": "closed", "pinch_grasp_preshape": "open", "pinch_grasp": "pinch",
                     "cylindrical_preshape": "open", "cylindrical": "cylindrical", "spherical_preshape": "open",
                     "spherical": "spherical"},
        max_opening=0.14,
        wrench_noise=0.2,
        speed=0.1,
    ),
    computers=(
        Computer("control", "arms, hands, F/T, tactile, joint states", ("joint_state_publisher", "joint_command_subscriber", "ft", "tactile")),
        Computer("vision", "2D vision", ("camera",)),
        Computer("depth", "3D vision and fusion", ("camera", "ground_truth")),
    ),
    base_xyz=(0.0, 0.0, 0.75),
    collision_groups=("left_", "right_"),
)
