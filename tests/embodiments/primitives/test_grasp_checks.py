"""Pure checks of the grasp primitives: held-open fingers against their command, the contact offset of eq. 3.1."""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.primitives.hands import blocked_fingers, held_fingers
from contactflow.embodiments.primitives.robust_grasp import contact_offset

GROUPS = {"a": np.array([0, 1]), "b": np.array([2, 3])}


def test_a_finger_held_by_its_own_target_is_not_blocked() -> None:
    q = np.array([0.2, 0.3, 0.2, 0.3])
    closed = np.full(4, 1.3)
    # against the closed preshape both fingers look held open ...
    assert blocked_fingers(q, closed, GROUPS) == 2
    # ... but a finger whose target is where it stands (frozen at a touch) holds nothing
    target = np.array([0.2, 0.3, 1.3, 1.3])
    assert blocked_fingers(q, target, GROUPS) == 1
    assert blocked_fingers(q, q.copy(), GROUPS) == 0


def test_held_fingers_join_pads_and_configuration_per_finger() -> None:
    q = np.array([0.2, 0.3, 1.3, 1.3])
    closed = np.full(4, 1.3)
    # one finger by its pad, the other held open: two fingers on the object (each check alone says one)
    assert held_fingers(q, closed, GROUPS, ["b"]) == {"a", "b"}
    assert held_fingers(q, q.copy(), GROUPS, []) == set()
    # a gripper's jaws share their joints: held open counts one jaw, both pads count two
    jaws = {"left": np.array([0]), "right": np.array([0])}
    assert held_fingers(np.array([0.02]), np.zeros(1), jaws, [], margin=0.01) == {"left"}
    assert held_fingers(np.zeros(1), np.zeros(1), jaws, ["left", "right"]) == {"left", "right"}


def test_contact_offset_from_the_wrench() -> None:
    axis = np.array([0.0, 0.0, 1.0])
    f = np.array([0.0, 0.0, -5.0])  # the support pushes the hand back along its axis
    r = np.array([0.03, -0.04, 0.1])  # contact 5 cm off the axis, 10 cm along it
    assert abs(contact_offset(f, np.cross(r, f), axis) - 0.05) < 1e-9
    assert contact_offset(f, np.zeros(3), axis) == 0.0
