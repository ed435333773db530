"""Weight W from the wrist F/T: the core averages, the primitive on a simulated robot lifting a known mass."""

from __future__ import annotations

import math

import numpy as np
import pytest

from contactflow.embodiments.messages import Wrench
from contactflow.embodiments.testing import melfa_around_plate
from contactflow.nodes.module import Layer
from contactflow.nodes.status import Event, Status
from contactflow.nodes.testing import FakeIO, run_module
from contactflow.recognition.primitives.measure_weight import MeasureWeight
from contactflow.recognition.primitives.recognize_object import RecognizeObject
from contactflow.recognition.weighing import GRAVITY, ForceAverage, average_force_z, lifted_weight

MASS = 0.3  # kg


def test_average_drops_bad_rows_and_rejects_bad_shapes():
    f = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -3.0], [np.nan, 0.0, 5.0]])
    avg = average_force_z(f)
    assert avg.samples == 2 and avg.force_z == pytest.approx(-2.0) and avg.sem == pytest.approx(1.0)
    assert average_force_z(np.zeros((0, 3))).samples == 0
    with pytest.raises(ValueError, match="where"):
        average_force_z(np.zeros((4, 2)), "where")
    w, s = lifted_weight(ForceAverage(0.5, 0.03, 10), ForceAverage(-2.5, 0.04, 10))
    assert w == pytest.approx(3.0) and s == pytest.approx(0.05)


def test_no_wrench_fails_and_other_arms_are_ignored():
    d = MeasureWeight.describe()
    assert d["outputs"] and d["doc"] and MeasureWeight.layer is Layer.PRIMITIVE
    with pytest.raises(ValueError, match="params.mode"):
        run_module(MeasureWeight("w", MeasureWeight.Params(mode="guess")), FakeIO(), steps=1)
    io = FakeIO()
    assert run_module(MeasureWeight("w", MeasureWeight.Params(timeout=0.5)), io, steps=100) is Status.FAILURE
    assert io.event_labels() == [Event.FAILURE] and not io.published["weight"]
    mod = MeasureWeight("w", MeasureWeight.Params(arm="right", baseline=0.0, timeout=1.0))
    io = FakeIO()
    io.module = mod
    mod.setup(io)
    mod.start()
    status = Status.RUNNING
    while not status.finished:
        io.feed("wrench", Wrench(arm="left", sensor_frame="l", force=[0.0, 0.0, -50.0], torque=[0.0] * 3))
        io.feed("wrench", Wrench(arm="right", sensor_frame="r", force=[0.0, 0.0, -2.0], torque=[0.0] * 3))
        status = mod.step()
        io.t += 0.02
    assert status is Status.SUCCESS and io.published["weight"][0].weight == pytest.approx(2.0)


def _weigh(robot, params: MeasureWeight.Params) -> tuple[Status, FakeIO]:
    """Run the primitive on the simulated wrist F/T, fed as Wrench messages at its rate."""
    mod = MeasureWeight("weigh", params)
    io = FakeIO(t=robot.time)
    io.module = mod
    mod.setup(io)
    mod.start()
    while True:
        robot.step(1.0 / params.rate_hz)
        io.t = robot.time
        r = robot.ft("arm")
        io.feed("wrench", Wrench(arm="arm", sensor_frame=r.frame, force=[float(x) for x in r.force],
                                 torque=[float(x) for x in r.torque]))
        status = mod.step()
        if status.finished:
            return status, io


def test_weight_of_a_lifted_mass_from_the_simulated_wrist_ft():
    robot = melfa_around_plate(MASS)
    arm, hand = robot.arm("arm"), robot.hand("gripper")
    # the baseline is taken with the hand free around the object: once the jaws squeeze it
    # on the table they already carry part of its weight
    status, before = _weigh(robot, MeasureWeight.Params(mode="baseline"))
    assert status is Status.SUCCESS and not before.published["weight"]
    base = before.events[-1].values
    hand.close()
    assert hand.wait(3.0) == Status.SUCCESS
    up = arm.ee_pose()
    up[2, 3] = 0.90
    arm.move_pose(up, speed=0.25)
    assert arm.wait(5.0) == Status.SUCCESS
    assert robot.world.objects["obj"].pose()[2, 3] > 0.85  # lifted
    status, after = _weigh(robot, MeasureWeight.Params(baseline=base["force_z"], baseline_std=base["std"], window=0.3))
    assert status is Status.SUCCESS
    w = after.published["weight"][-1]
    consumer = {port.name: port.type for port in RecognizeObject.inputs}["weight"]
    assert isinstance(w, consumer)  # what RecognizeObject waits for when its features have W
    assert w.weight == pytest.approx(MASS * GRAVITY, rel=0.10)
    assert 0.0 < w.std < 0.1 * MASS * GRAVITY
    assert after.events[-1].values["mass"] == pytest.approx(MASS, rel=0.10)
    assert math.isfinite(after.events[-1].values["samples"]) and after.events[-1].values["samples"] >= 5
