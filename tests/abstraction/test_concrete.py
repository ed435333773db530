"""Concrete parameters from factory ones: hand geometry keeps approaches off objects, pushes low and aimed."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.abstraction.concrete import HandGeometry, concretize, top_down
from contactflow.embodiments.transforms import xyz_rpy_to_matrix


def box_points(lo, hi) -> np.ndarray:
    return np.array([[hi[i] if (k >> i) & 1 else lo[i] for i in range(3)] for k in range(8)], dtype=float)


# a parallel gripper: thin fingers reaching 5 cm below a wide body (a panda hand in its grasp frame)
GRIPPER = HandGeometry(np.vstack([
    box_points((-0.01, -0.05, -0.05), (0.01, -0.03, 0.0)),  # finger
    box_points((-0.01, 0.03, -0.05), (0.01, 0.05, 0.0)),  # finger
    box_points((-0.03, -0.10, -0.14), (0.03, 0.10, -0.05)),  # body, above the fingers
]))
BOX = [0.08, 0.08, 0.06]
BOX_AT = [0.5, 0.0, 0.78]


def hand_parts(params: dict, hand: HandGeometry) -> np.ndarray:
    T = xyz_rpy_to_matrix(params["target"][:3], params["target"][3:])
    return hand.points @ T[:3, :3].T + T[:3, 3]


def test_side_approach_keeps_the_hand_off_the_object_and_its_low_parts_in_front_of_it():
    out = concretize("move_to", {"goal": {"target": BOX_AT, "approach": [0.0, -1.0, 0.0], "standoff": 0.1, "size": BOX}},
                     ["arm"], hands={"arm": GRIPPER})
    pts = hand_parts(out, GRIPPER)
    lo, hi = np.array(BOX_AT) - np.array(BOX) / 2, np.array(BOX_AT) + np.array(BOX) / 2
    inside = np.all((pts > lo) & (pts < hi), axis=1)
    assert not inside.any()
    beside = pts[pts[:, 2] < hi[2]]
    assert beside[:, 1].min() > hi[1]  # what is at the object's height is on its near side
    assert pts[:, 2].min() == pytest.approx(lo[2] + 0.02, abs=1e-6)  # lowest part just above the bottom
    assert beside[:, 0].min() < BOX_AT[0] < beside[:, 0].max()  # and it covers the object's middle


def test_without_hand_geometry_the_approach_is_the_plain_standoff():
    out = concretize("move_to", {"goal": {"target": BOX_AT, "approach": [0.0, -1.0, 0.0], "standoff": 0.1}}, ["arm"])
    assert out["target"][:3] == pytest.approx([0.5, 0.1, 0.78])


def test_top_approach_puts_the_grasp_centre_over_the_object():
    hand = HandGeometry(GRIPPER.points, grasp_center=(-0.05, 0.02, 0.0))
    out = concretize("transport", {"goal": {"target": [0.6, 0.0, 0.81], "approach": [0, 0, -1], "standoff": 0.1}},
                     ["left", "right"], hands={"left": hand})
    T = xyz_rpy_to_matrix(out["target"][:3], out["target"][3:])
    centre = T[:3, :3] @ np.array(hand.grasp_center) + T[:3, 3]
    assert centre == pytest.approx([0.6, 0.0, 0.91], abs=1e-9)
    assert T[:3, 2] == pytest.approx([0, 0, -1], abs=1e-9)


def test_push_target_is_where_the_object_ends_not_the_hand():
    R = top_down(0.0)
    current = np.eye(4)
    current[:3, :3] = R
    current[:3, 3] = (0.5, 0.1, 0.8)
    out = concretize("transport", {"goal": {"target": [0.5, -0.15, 0.78], "size": BOX, "pushes": True}},
                     ["arm"], hand_at=lambda arm: current, hands={"arm": GRIPPER})
    reach = GRIPPER.reach(R, np.array([0.0, -1.0, 0.0]), 0.78 + 0.03 - 0.8)
    assert out["target"][1] == pytest.approx(-0.15 + 0.04 + reach)
    assert out["target"][2] == pytest.approx(0.8)  # the hand keeps its height and heading


def test_a_place_s_target_is_where_the_hand_is_with_the_object_resting_there():
    hand = HandGeometry(GRIPPER.points, grasp_center=(0.0, 0.0, 0.03))
    current = np.eye(4)
    current[:3, :3] = top_down(0.3)
    current[:3, 3] = (0.4, 0.2, 1.0)
    out = concretize("place", {"velocity": 0.005, "goal": {"target": [0.4, 0.2, 0.81]}}, ["arm"],
                     hand_at=lambda arm: current, hands={"arm": hand})
    T = xyz_rpy_to_matrix(out["target"][:3], out["target"][3:])
    assert T[:3, :3] == pytest.approx(current[:3, :3], abs=1e-9)  # the hand goes down as it is
    assert T[:3, :3] @ np.array(hand.grasp_center) + T[:3, 3] == pytest.approx([0.4, 0.2, 0.81], abs=1e-9)
    assert "target" not in concretize("place", {"velocity": 0.005}, ["arm"])  # not told: the thesis's place


def test_the_primitive_params_pass_through_and_a_bad_goal_is_refused():
    out = concretize("transport", {"force_threshold": 3.0, "guarded": True, "goal": {"target": BOX_AT}}, ["arm"])
    assert out["force_threshold"] == 3.0 and out["guarded"] is True and len(out["target"]) == 6
    with pytest.raises(ValueError, match=r"goal\.stanoff: unknown field"):
        concretize("transport", {"goal": {"target": BOX_AT, "stanoff": 0.1}}, ["arm"])
    with pytest.raises(ValueError, match=r"goal\.target: expected a list of finite numbers"):
        concretize("transport", {"goal": {"target": [0.5, float("nan"), 0.8]}}, ["arm"])


def test_pusher_refuses_postures_whose_low_parts_miss_the_object():
    # a hand whose only low part is a thumb far off to one side cannot push pointing down
    thumb = HandGeometry(np.vstack([box_points((0.04, 0.13, -0.01), (0.07, 0.16, 0.01)),
                                    box_points((-0.18, -0.09, -0.15), (0.07, 0.09, -0.05))]))
    R, height = thumb.pusher(np.array([0.0, -1.0, 0.0]), np.array(BOX))
    low = thumb.band(R, BOX[2] - height)
    side = low @ np.array([1.0, 0.0, 0.0])
    assert side.min() < 0.0 < side.max()


def test_a_held_object_is_placed_by_where_it_sits_in_that_grasp():
    from contactflow.abstraction.concrete import ConcreteRunner
    from contactflow.nodes.status import Event
    from contactflow.nodes.taskengine import RunnerEvent

    class Inner:
        def __init__(self) -> None:
            self.started: list[tuple[str, str, dict]] = []
            self.events: list[RunnerEvent] = []

        def start(self, instance, type, params):
            self.started.append((instance, type, params))

        def stop(self, instance):
            self.started.append((instance, "stop", {}))

        def poll(self):
            out, self.events = self.events, []
            return out

    hand = HandGeometry(GRIPPER.points, grasp_center=(-0.05, 0.02, 0.0))
    measured = np.array([-0.02, -0.01, 0.03])  # where the object sits in this grasp (z ignored)
    inner = Inner()
    runner = ConcreteRunner(inner, ["left"], hands={"left": hand}, held_at=lambda arm: measured)
    place = {"arm": "left", "goal": {"target": [0.55, 0.15, 0.81]}}

    def centre_at(params: dict, c) -> np.ndarray:
        T = xyz_rpy_to_matrix(params["target"][:3], params["target"][3:])
        return T[:3, :3] @ np.asarray(c) + T[:3, 3]

    runner.start("carry#1", "transport", place)  # nothing held yet: the usual grasp centre
    assert centre_at(inner.started[-1][2], hand.grasp_center) == pytest.approx([0.55, 0.15, 0.81], abs=1e-9)
    runner.start("grasp#2", "robust_grasp", {"arm": "left"})
    inner.events.append(RunnerEvent("grasp#2", Event.SUCCESS))
    runner.poll()
    runner.start("carry#3", "transport", place)
    assert centre_at(inner.started[-1][2], (-0.02, -0.01, 0.0)) == pytest.approx([0.55, 0.15, 0.81], abs=1e-9)
    runner.start("open#4", "release", {"arm": "left"})
    runner.start("carry#5", "transport", place)  # let go: the usual centre again
    assert centre_at(inner.started[-1][2], hand.grasp_center) == pytest.approx([0.55, 0.15, 0.81], abs=1e-9)
    failed = ConcreteRunner(inner, ["left"], hands={"left": hand}, held_at=lambda arm: measured)
    failed.start("grasp#1", "robust_grasp", {"arm": "left"})
    inner.events.append(RunnerEvent("grasp#1", Event.FAILURE))
    failed.poll()
    failed.start("carry#2", "transport", place)  # a failed grasp holds nothing
    assert centre_at(inner.started[-1][2], hand.grasp_center) == pytest.approx([0.55, 0.15, 0.81], abs=1e-9)
