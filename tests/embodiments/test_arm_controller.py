"""The arm controllers as a pure core: joint paths, Cartesian moves, guarded moves and failure, fed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments import registry
from contactflow.embodiments.control.arm import ArmController, ArmMode
from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.nodes.status import Status

DT = 0.005


@pytest.fixture
def melfa():
    """A controller of melfa's arm whose measured joints are exactly its commands (a perfect arm)."""
    spec = registry.get("melfa")
    arm = spec.arms[0]
    kin = Kinematics(spec.urdf(), np.eye(4))
    idx = kin.q_index(arm.joints)
    q = kin.q.copy()
    q[idx] = arm.home
    state = {"q": q, "contacts": []}

    def measured():
        return state["q"].copy()

    ctl = ArmController(kin, arm, measured=measured, target=lambda: state["q"][idx], on_contact=state["contacts"].append)
    return ctl, state, idx


def _run(ctl, state, idx, force=lambda k: np.zeros(3), ticks=2000):
    """Tick until the controller is idle; the arm follows its targets exactly. Returns the targets sent."""
    sent = []
    for k in range(ticks):
        f = force(k)
        out = ctl.update(state["q"][idx], DT, f, np.concatenate([f, np.zeros(3)]))
        if out is None:
            break
        sent.append(out)
        state["q"][idx] = out[0]
    return sent


def test_a_joint_move_starts_from_the_target_and_ends_there_at_its_speed(melfa):
    ctl, state, idx = melfa
    assert ctl.update(state["q"][idx], DT, None, None) is None  # idle: nothing to send
    goal = state["q"][idx] + [0.3, 0, 0, 0, 0, 0]
    ctl.execute_waypoints(goal[None], speed=0.5, abort_force=np.inf, failed=False)
    assert ctl.status == Status.RUNNING and ctl.mode == ArmMode.JOINT
    sent = _run(ctl, state, idx)
    assert ctl.status == Status.SUCCESS and ctl.mode == ArmMode.IDLE
    assert sent[-1][0] == pytest.approx(goal)
    speeds = np.array([np.abs(qd).max() for _, qd in sent])
    assert speeds.max() == pytest.approx(0.5, rel=0.05)  # 0.3 rad at 0.5 rad/s: 0.6 s, then the settle time
    assert 0.6 / DT <= len(sent) <= (0.6 + 0.3) / DT


def test_a_pose_move_reaches_its_goal_along_a_line(melfa):
    ctl, state, idx = melfa
    ctl.kin.update(state["q"])
    start = ctl.kin.frame_pose(ctl.spec.ee_frame)
    goal = start.copy()
    goal[:3, 3] += [0.05, 0.0, -0.05]
    ctl.move_pose(goal, "world", 0.1, failed=False)
    _run(ctl, state, idx)
    assert ctl.status == Status.SUCCESS
    ctl.kin.update(state["q"])
    assert np.linalg.norm(ctl.kin.frame_pose(ctl.spec.ee_frame)[:3, 3] - goal[:3, 3]) < 0.003


def test_a_guarded_move_stops_where_the_arm_is_when_the_wrist_force_changes(melfa):
    ctl, state, idx = melfa
    ctl.guarded_move(np.array([0.0, 0.0, -0.03, 0, 0, 0]), "world", max_force=5.0, duration=None, failed=False)
    sent = _run(ctl, state, idx, force=lambda k: np.array([0.0, 0.0, 0.0 if k < 100 else 8.0]))
    assert ctl.status == Status.SUCCESS and state["contacts"] == ["arm arm: guarded move stopped on contact"]
    assert 100 < len(sent) < 120  # the filtered force passes 5 N within a few ticks of the 8 N step
    assert not sent[-1][1].any()  # stopped: zero velocity at the measured joints
    # without a contact the move fails when its duration ends
    ctl.guarded_move(np.array([0.0, 0.0, -0.03, 0, 0, 0]), "world", max_force=5.0, duration=0.2, failed=False)
    _run(ctl, state, idx)
    assert ctl.status == Status.FAILURE and ctl.abort_reason == "no contact"


def test_a_failed_robot_fails_the_running_command_and_refuses_new_ones(melfa):
    ctl, state, idx = melfa
    ctl.set_twist(np.array([0.0, 0.0, -0.01, 0, 0, 0]), "world", None, failed=False)
    _run(ctl, state, idx, ticks=10)
    ctl.fail()
    assert (ctl.status, ctl.abort_reason, ctl.mode) == (Status.FAILURE, "hardware_failure", ArmMode.IDLE)
    assert ctl.update(state["q"][idx], DT, None, None) is None
    ctl.stop()
    ctl.execute_waypoints(state["q"][idx][None], speed=None, abort_force=np.inf, failed=True)
    assert (ctl.status, ctl.abort_reason, ctl.mode) == (Status.FAILURE, "hardware_failure", ArmMode.IDLE)
    # an idle controller that fails stays idle, with no reason to report
    ctl.stop()
    ctl.status, ctl.abort_reason = Status.SUCCESS, ""
    ctl.fail()
    assert (ctl.status, ctl.abort_reason) == (Status.SUCCESS, "")
