"""Injected faults become hardware_failure and a stopped robot, never an exception."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.faults import FaultMonitor
from contactflow.embodiments.testing import make_robot
from contactflow.nodes.status import Event, Status


def _moving_melfa():
    robot = make_robot("melfa", table=False)
    arm = robot.arm("arm")
    arm.move_joints(np.asarray(arm.home) + np.array([0.0, 0.5, -0.5, 0.0, 0.0, 0.0]), speed=0.5)
    robot.step(0.2)
    return robot, arm


@pytest.mark.parametrize("kind,kw", [("nan", {}), ("explode", {"joint": "elbow_joint"}),
                                     ("stuck_joint", {"joint": "shoulder_lift_joint"}),
                                     ("sensor_loss", {"sensor": "arm"})])
def test_injected_fault_gives_hardware_failure(kind, kw):
    robot, arm = _moving_melfa()
    robot.inject_fault(kind, **kw)
    robot.step(1.5)
    assert robot.failed, kind
    assert [e for _, e, _ in robot.events] == [Event.HARDWARE_FAILURE]
    assert arm.status == Status.FAILURE and arm.abort_reason == "hardware_failure"
    q = arm.q()
    robot.step(0.5)
    assert np.all(np.isfinite(arm.q()))
    assert np.abs(arm.q() - q).max() < 0.02  # stopped
    arm.move_pose(arm.ee_pose(), speed=0.1)  # further commands are refused, not raised
    assert arm.status == Status.FAILURE


def test_monitor_is_quiet_on_a_healthy_robot(melfa):
    melfa.step(1.0)
    assert not melfa.failed


def test_monitor_unit_rules():
    m = FaultMonitor(["a", "b"], np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    ok = np.zeros(2)
    assert m.check(0.0, ok, ok, ok) is None
    assert m.check(0.0, np.array([np.nan, 0.0]), ok, ok).kind == "nan"
    assert m.check(0.0, ok, np.array([0.0, 1000.0]), ok).kind == "explosion"
    assert m.check(0.0, np.array([2.0, 0.0]), ok, ok).kind == "explosion"
    target = np.array([0.5, 0.0])
    assert m.check(0.0, ok, ok, target) is None
    assert m.check(1.0, ok, ok, target).kind == "stuck_joint"
    assert m.check(2.0, ok, ok, ok, {"ft": 1.0}).kind == "sensor_loss"


@pytest.mark.parametrize("sensor", ["arm", "gripper"])
def test_a_silent_stream_is_noticed_by_the_watchdog(sensor):
    robot, arm = _moving_melfa()
    stream = robot._ft_of_arm[sensor] if sensor == "arm" else robot._tactile[sensor]
    robot.step(0.05)
    assert stream.stamp == pytest.approx(robot.time, abs=0.006)  # a live stream: fresh samples
    robot.inject_fault("sensor_loss", sensor=sensor)
    stamp = stream.stamp
    robot.step(0.15)
    assert not robot.failed  # a gap shorter than the watchdog timeout is tolerated
    assert stream.stamp == stamp  # the sensor produces no new sample
    if sensor == "arm":
        assert robot.ft("arm").t == stamp  # readers get the last sample, not a fresh one
    robot.step(0.2)
    assert robot.failed and robot.failure.startswith("sensor_loss")
    assert [e for _, e, _ in robot.events] == [Event.HARDWARE_FAILURE]


def test_a_robot_that_does_not_watch_its_streams_samples_them_only_when_read_and_still_watches_its_joints():
    """A predictor's robot (SimRobotParams.watch_streams=False) reads its sensors only when it compares."""
    from contactflow.embodiments.sim_robot import SimRobot, SimRobotParams
    from contactflow.embodiments.world import World

    robot = SimRobot(World(), "melfa", params=SimRobotParams(watch_streams=False))
    ft, tactile = robot._ft_of_arm["arm"], robot._tactile["gripper"]
    robot.step(0.5)
    assert ft.stamp == tactile.stamp == -np.inf and not robot.failed  # never sampled, and no sensor_loss for it
    assert robot.ft("arm").t == pytest.approx(robot.time) and ft.stamp == pytest.approx(robot.time)  # read on demand
    robot.inject_fault("nan")
    robot.step(0.1)
    assert robot.failed and robot.failure.startswith("nan")  # the joint rules still run


def test_a_lost_camera_gives_hardware_failure_when_read():
    robot = make_robot("tombatossals")
    first = robot.camera()
    assert len(first.points) > 1000 and not robot.failed
    robot.inject_fault("sensor_loss", sensor="kinect")
    robot.step(0.4)
    frame = robot.camera()
    assert frame.t == first.t  # no new frame came
    assert robot.failed and "camera kinect" in robot.failure
    assert [e for _, e, _ in robot.events] == [Event.HARDWARE_FAILURE]


def test_sensor_loss_names_the_known_sensors():
    robot = make_robot("melfa", table=False)
    with pytest.raises(ValueError, match=r"no sensor 'nose' \(F/T by arm: \['arm'\], tactile by hand: \['gripper'\]"):
        robot.inject_fault("sensor_loss", sensor="nose")


def test_a_one_tick_speed_spike_is_chatter_a_sustained_one_an_explosion():
    """A light finger phalanx chattering in contact spikes past the speed limit for one control tick."""
    m = FaultMonitor(["finger"], np.array([-0.2]), np.array([1.6]))
    q, spike = np.array([0.7]), np.array([-38.0])
    assert m.check(0.0, q, spike, q) is None
    assert m.check(0.005, q, np.array([0.5]), q) is None  # back to normal: no fault
    assert m.check(0.010, q, spike, q) is None
    assert m.check(0.015, q, spike, q) is None
    fault = m.check(0.035, q, spike, q)  # still that fast after explosion_time
    assert fault is not None and fault.kind == "explosion" and "finger" in fault.detail


def test_a_primitive_running_when_the_robot_faults_fails_naming_the_fault():
    from contactflow.embodiments.primitives.base import pose6
    from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome

    robot = make_robot("melfa", table=False)
    runner = LocalPrimitiveRunner(robot)
    T = robot.arm("arm").ee_pose()
    T[2, 3] -= 0.15
    runner.start("m", "move_to", {"arm": "arm", "target": list(pose6(T).values())})
    events: list = []
    for tick in range(400):
        if tick == 40:
            robot.inject_fault("explode", joint="elbow_joint")
        runner.advance()
        robot.step(0.005)
        events += runner.poll()
        if any(e.event in (Event.SUCCESS, Event.FAILURE) for e in events):
            break
    # what a task's progress and the demo's report show: which joint, not only "a hardware fault"
    fault = [e.detail for e in events if e.event is Event.HARDWARE_FAILURE]
    assert fault and "explosion: joint elbow_joint" in fault[0], events
    end = outcome(events)
    assert end.event is Event.FAILURE and "explosion: joint elbow_joint" in end.detail, end
