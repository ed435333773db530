"""Interface-layer modules over a SimRobot, run with the in-memory FakeIO."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.messages import JointCommand, JointState, TactileArray, Wrench
from contactflow.embodiments.modules.camera_publisher import CameraPublisher
from contactflow.embodiments.modules.ft_publisher import FTPublisher
from contactflow.embodiments.modules.ground_truth_publisher import GroundTruthPublisher
from contactflow.embodiments.modules.joint_command_subscriber import JointCommandSubscriber
from contactflow.embodiments.modules.joint_state_publisher import JointStatePublisher
from contactflow.embodiments.modules.tactile_publisher import TactilePublisher
from contactflow.embodiments.modules.world_clock import WorldClock
from contactflow.embodiments.testing import make_robot
from contactflow.embodiments.world import box
from contactflow.nodes.messages import Clock
from contactflow.nodes.status import Event
from contactflow.nodes.testing import FakeIO, run_module
from contactflow.nodes.wire import NDArray


@pytest.fixture(scope="module")
def robot():
    r = make_robot("melfa")
    r.world.add_object(box("cube", (0.05, 0.05, 0.05), (0.6, 0.2, 0.775)))
    return r


def test_joint_state_publisher(robot):
    io = FakeIO()
    run_module(JointStatePublisher("js", robot), io, steps=3)
    msgs = io.published["joint_state"]
    assert len(msgs) == 3 and isinstance(msgs[0], JointState)
    assert msgs[0].names == robot.art.joint_names
    assert np.allclose(msgs[-1].position.numpy(), robot.art.qpos(), atol=1e-6)


def test_joint_command_subscriber_mixes_weighted_sources(robot):
    sub = JointCommandSubscriber("jcs", robot)
    io = FakeIO(module=sub)
    sub.setup(io)
    sub.start()
    clock = WorldClock("clock", robot.world)
    cio = FakeIO(module=clock)
    clock.setup(cio)
    q0 = robot.arm("arm").q()
    j = ["wrist_3_joint"]
    for _ in range(200):
        io.feed("command", JointCommand(names=j, position=NDArray.of(np.array([q0[5] + 0.3])), weight=3.0, source="a"))
        io.feed("command", JointCommand(names=j, position=NDArray.of(np.array([q0[5] - 0.1])), weight=1.0, source="b"))
        sub.step()
        clock.step()
        io.t = cio.t = robot.time
    assert robot.arm("arm").q()[5] == pytest.approx(q0[5] + 0.2, abs=5e-3)
    assert io.published["mixed"][-1].position.numpy()[0] == pytest.approx(q0[5] + 0.2)
    assert isinstance(cio.published["clock"][-1], Clock)
    bad = JointCommand(names=["nope"], position=NDArray.of(np.zeros(1)))
    io.feed("command", bad)
    sub.step()
    assert sub.rejected == 1


def test_sensor_publishers(robot):
    io = FakeIO()
    run_module(FTPublisher("ft", robot, FTPublisher.Params(arm="arm")), io, steps=2)
    w = io.published["wrench"][-1]
    assert isinstance(w, Wrench) and len(w.force) == 3
    io = FakeIO()
    run_module(TactilePublisher("tac", robot, TactilePublisher.Params(hand="gripper")), io, steps=1)
    t = io.published["tactile"][-1]
    assert isinstance(t, TactileArray) and t.pressure.numpy().shape == (2, 5, 8)


def test_camera_and_ground_truth_publishers():
    r = make_robot("tombatossals")
    r.world.add_object(box("cube", (0.05, 0.05, 0.05), (0.6, 0.0, 0.775)))
    r.step(0.1)
    io = FakeIO()
    run_module(CameraPublisher("cam", r), io, steps=1)
    assert io.published["depth"][-1].depth.numpy().shape == (480, 640)
    cloud = io.published["cloud"][-1]
    assert cloud.points.numpy().shape[1] == 3
    T_cam = np.array(io.published["depth"][-1].T_world_cam).reshape(4, 4)
    assert cloud.sensor == "kinect" and np.allclose(cloud.origin, T_cam[:3, 3])
    io = FakeIO()
    run_module(GroundTruthPublisher("gt", r), io, steps=1)
    poses = io.published["object_poses"][-1]
    assert poses.names == ["cube"]
    assert np.allclose(poses.poses.numpy()[0][:3, 3], [0.6, 0.0, 0.775], atol=2e-3)
    contacts = io.published["true_contacts"][-1]
    assert "cube" in contacts.body_a + contacts.body_b


def test_hardware_failure_is_published_as_an_event():
    r = make_robot("melfa", table=False)
    pub = JointStatePublisher("js", r)
    io = FakeIO()
    run_module(pub, io, steps=1)
    r.inject_fault("nan")
    r.step(0.05)
    pub.step()
    pub.step()
    assert io.event_labels() == [Event.HARDWARE_FAILURE]
    assert "nan" in io.events[0].detail


def test_robot_model_publisher_poses_the_spherical_model_sensor_frames_and_taxels(robot):
    from contactflow.embodiments.messages import RobotModel, TaxelPoses
    from contactflow.embodiments.modules.model_publisher import RobotModelPublisher
    from contactflow.embodiments.sensors.tactile import taxel_positions
    from contactflow.embodiments.transforms import pose_to_matrix

    js = FakeIO()
    run_module(JointStatePublisher("js", robot), js, steps=1)
    pub = RobotModelPublisher("model", spec=robot.spec, base=robot.art.base)
    io = FakeIO()
    run_module(pub, io, steps=1)
    assert io.published["robot_model"] == []  # nothing before the first joint state
    io.feed("joint_state", js.published["joint_state"][-1])
    pub.step()
    pub.step()  # the same joint state is not posed twice
    (model,) = io.published["robot_model"]
    assert isinstance(model, RobotModel) and model.robot == "melfa"
    sph = robot.spherical
    assert model.links == sph.links
    assert np.allclose(model.c1.numpy(), sph.C1, atol=1e-6) and np.allclose(model.r2.numpy(), sph.r2)
    # the hand's parts: its palm and the fingers its joints move; the arm's links are none
    parts = dict(zip(model.links, model.regions, strict=True))
    assert parts["panda_hand"] == "palm" and parts["panda_leftfinger"] == parts["panda_rightfinger"] == "finger"
    assert {k for k, r in parts.items() if r} == {"panda_hand", "panda_leftfinger", "panda_rightfinger"}
    ft_link = robot.spec.ft(robot.spec.arm("arm").ft).link
    T_ft = model.poses.numpy()[model.frames.index(ft_link)]
    assert np.allclose(T_ft, pose_to_matrix(robot.art.links[ft_link].get_entity_pose()), atol=1e-4)
    (taxels,) = io.published["taxels"]
    assert isinstance(taxels, TaxelPoses) and taxels.hand == "gripper"
    pads = robot.spec.hand("gripper").pads
    assert taxels.pads == [p.name for p in pads] and taxels.positions.numpy().shape == (2, 5, 8, 3)
    for k, pad in enumerate(pads):
        T = pose_to_matrix(robot.art.links[pad.link].get_entity_pose())  # the simulator's pose, not pinocchio's
        expected = taxel_positions(pad) @ T[:3, :3].T + T[:3, 3]
        assert np.allclose(taxels.positions.numpy()[k], expected, atol=1e-4)
    moved = js.published["joint_state"][-1]
    q = moved.position.numpy().copy()
    q[0] += 0.5
    io.feed("joint_state", JointState(robot="melfa", names=moved.names, position=NDArray.of(q),
                                      velocity=moved.velocity, effort=moved.effort))
    pub.step()
    assert not np.allclose(io.published["robot_model"][-1].c1.numpy(), sph.C1, atol=1e-3)
    io.feed("joint_state", JointState(robot="melfa", names=["nope"], position=NDArray.of(np.zeros(1)),
                                      velocity=NDArray.of(np.zeros(1)), effort=NDArray.of(np.zeros(1))))
    with pytest.raises(ValueError, match="input 'joint_state'.*nope"):
        pub.step()


@pytest.mark.parametrize("name", ["tombatossals", "baxter"])
def test_every_hand_link_is_a_finger_or_the_palm_and_no_arm_link_is(name):
    from contactflow.embodiments import registry
    from contactflow.embodiments.control.kinematics import Kinematics
    from contactflow.embodiments.modules.model_publisher import hand_regions
    from contactflow.embodiments.spherical import SphericalModel

    spec = registry.home(name).spec
    kin = Kinematics(spec.urdf())
    links = SphericalModel.from_urdf(kin, str(spec.urdf())).links
    parts = dict(zip(links, hand_regions(kin, spec, links), strict=True))
    palms = {k for k, r in parts.items() if r == "palm"}
    assert palms == {h.palm_link for h in spec.hands}
    for hand in spec.hands:  # every fingertip is a finger link
        assert all(parts[t] == "finger" for t in hand.fingertips)
    fingers = {k for k, r in parts.items() if r == "finger"}
    # allegro: 4 fingers of 4 links and a tip, twice; baxter: 2 fingers and their tips, twice
    assert len(fingers) == (40 if name == "tombatossals" else 8), sorted(fingers)
    assert not any("panda_link" in k or "forearm" in k or "wrist" in k for k in fingers | palms)
