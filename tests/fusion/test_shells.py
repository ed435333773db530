"""The generator Module shells on FakeIO: inputs as runtime messages in, hypothesis clouds out."""

import numpy as np
import pytest

from contactflow.fusion.generators.finger import (
    FingerParams,
    FingerPoseHypothesesGenerator,
    fingers_of,
)
from contactflow.fusion.generators.force_torque import ForceTorqueGenerator, ForceTorqueParams
from contactflow.fusion.generators.motion import MotionSupportHypothesesGenerator
from contactflow.fusion.generators.null import NullHypothesesGenerator
from contactflow.fusion.generators.range import RangeHypothesesGenerator
from contactflow.fusion.generators.simulator import SimulatorSupportGenerator
from contactflow.fusion.hypotheses import HypothesisType
from contactflow.nodes.messages import Array, Vector
from contactflow.nodes.testing import FakeIO
from contactflow.nodes.wire import NDArray

HAND = np.array([[0.5, 0.2, 0.95, 0.04, 0.5, 0.2, 1.05, 0.04]])  # bi-sphere, world


def arr(a):
    return Array(array=NDArray.of(np.asarray(a, dtype=np.float64)))


def started(module):
    io = FakeIO()
    io.module = module
    module.setup(io)
    module.start()
    return io


def clouds(io):
    return [m.hypotheses() for m in io.published["hypotheses"]]


def test_force_torque_shell():
    gen = ForceTorqueGenerator("ft", ForceTorqueParams(robot="r1", box_lo=(-0.05, -0.05, 0.0),
                                                        box_hi=(0.05, 0.05, 0.2)))
    io = started(gen)
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.2, 0.9]
    p_local = np.array([0.04, 0.0, 0.1])
    f = np.array([-3.0, 0.5, 1.0])
    gen.step()
    assert io.published["hypotheses"] == []  # waits for all inputs
    io.feed("sensor_pose", arr(T))
    io.feed("robot_model", arr(HAND))
    io.feed("wrench", Vector(values=[float(v) for v in (*f, *np.cross(p_local, f))]))
    gen.step()
    (h,) = clouds(io)
    assert np.linalg.norm(h.location - (p_local + T[:3, 3]), axis=1).min() < 0.006
    io.feed("wrench", Vector(values=[1.0, 2.0]))
    with pytest.raises(ValueError, match="expected 6"):
        gen.step()


def test_range_shell_initialises_then_stays_quiet_without_contact():
    gen = RangeHypothesesGenerator("range")
    io = started(gen)
    g = np.arange(-0.03, 0.031, 0.005)
    top = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pts = np.column_stack([top[:, 0] + 0.55, top[:, 1], np.full(len(top), 0.87)])
    io.feed("robot_model", arr(HAND))
    io.feed("camera", Vector(values=[0.0, 0.0, 1.4]))
    for _ in range(2):
        io.feed("points", arr(pts))
        gen.step()
    assert [len(h) for h in clouds(io)] == [0, 0]
    assert gen.core.grid is not None
    io.feed("points", arr(np.zeros((3, 2))))
    with pytest.raises(ValueError, match="expected \\(n, 3\\)"):
        gen.step()


def test_finger_shell():
    assert fingers_of((0, 0, 1, -1), 4) == [[0, 1], [2]]
    gen = FingerPoseHypothesesGenerator("finger", FingerParams(finger_of_joint=(0, 0, 1, 1)))
    io = started(gen)
    surf = np.array([[0.5, 0, 0.9, 0], [0.5, 0.05, 0.9, 1], [0.5, 0.06, 0.9, 1]])
    io.feed("finger_surfaces", arr(surf))
    io.feed("fingers", Vector(values=[0, 0, 0, 0]))
    gen.step()
    io.feed("fingers", Vector(values=[0, 0, 0, 0.3]))
    gen.step()
    h = clouds(io)[-1]
    assert len(h) == 2 and np.allclose(h.likelihood, 0.5)


def test_motion_shell_extrapolates_surface():
    gen = MotionSupportHypothesesGenerator("motion")
    io = started(gen)
    io.feed("surface", arr([[0.50, 0, 0.9]]))
    gen.step()
    io.feed("surface", arr([[0.51, 0, 0.9]]))
    gen.step()
    (h,) = clouds(io)
    assert h.kind[0] == HypothesisType.SUPPORT and abs(h.location[0, 0] - 0.52) <= 0.0026


def test_simulator_and_null_shells():
    sim = SimulatorSupportGenerator("sim")
    io = started(sim)
    io.feed("predicted_contacts", arr([[0.5, 0, 0.9]]))
    sim.step()
    assert clouds(io)[0].likelihood.tolist() == [0.5]
    null = NullHypothesesGenerator("null")
    io = started(null)
    io.feed("robot_model", arr(HAND))
    null.step()
    (h,) = clouds(io)
    assert len(h) > 10 and (h.kind == HypothesisType.NULL).all()
