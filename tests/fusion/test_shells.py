"""The generator Module shells on FakeIO: inputs as runtime messages in, hypothesis clouds out."""

import numpy as np
import pytest

from contactflow.embodiments.messages import JointState, PointCloud, Wrench
from contactflow.fusion.generators.finger import (
    FingerParams,
    FingerPoseHypothesesGenerator,
    fingers_of,
)
from contactflow.fusion.generators.force_torque import ForceTorqueGenerator, ForceTorqueParams
from contactflow.fusion.generators.motion import MotionSupportHypothesesGenerator
from contactflow.fusion.generators.null import NullHypothesesGenerator
from contactflow.fusion.generators.range import RangeHypothesesGenerator, RangeParams
from contactflow.fusion.generators.simulator import SimulatorSupportGenerator
from contactflow.fusion.generators.tactile import TactileGenerator, TactileParams
from contactflow.fusion.hypotheses import HypothesisType
from contactflow.fusion.testing import one_pad_hand, point_cloud, robot_model
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Array
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


def test_force_torque_shell_reads_a_world_wrench_and_the_sensor_pose_from_the_model():
    gen = ForceTorqueGenerator("ft", ForceTorqueParams(robot="r1", box_lo=(-0.05, -0.05, 0.0),
                                                        box_hi=(0.05, 0.05, 0.2), link="hand"))
    io = started(gen)
    T = np.eye(4)
    T[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # sensor turned 90 deg about z
    T[:3, 3] = [0.5, 0.2, 0.9]
    p_local = np.array([0.0, -0.04, 0.1])
    f_local = np.array([0.5, 3.0, 1.0])
    R = T[:3, :3]
    f_w, tau_w = R @ f_local, R @ np.cross(p_local, f_local)  # world axes, about the sensor origin
    gen.step()
    assert io.published["hypotheses"] == []  # waits for all inputs
    io.feed("robot_model", robot_model(HAND, {"wrist": T}))
    io.feed("wrench", Wrench(arm="arm", sensor_frame="wrist", force=f_w.tolist(), torque=tau_w.tolist()))
    gen.step()
    (msg,) = io.published["hypotheses"]
    h = msg.hypotheses()
    assert msg.link == "hand" and msg.robot == "r1"
    true = R @ p_local + T[:3, 3]
    assert np.linalg.norm(h.location - true, axis=1).min() < 0.006
    assert np.allclose(h.direction[0], f_w / np.linalg.norm(f_w), atol=1e-5)
    io.feed("wrench", Wrench(arm="arm", sensor_frame="elbow", force=f_w.tolist(), torque=tau_w.tolist()))
    with pytest.raises(ValueError, match="no pose of frame 'elbow'"):
        gen.step()
    io.feed("wrench", Wrench(arm="arm", sensor_frame="wrist", force=[1.0, 2.0], torque=[0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="3 finite force"):
        gen.step()


def test_force_torque_shell_takes_the_box_from_the_hand_links():
    gen = ForceTorqueGenerator("ft", ForceTorqueParams(robot="r1", links=("link0",)))
    io = started(gen)
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.2, 0.9]
    far = [1.5, 0.2, 0.95, 0.04, 1.5, 0.2, 1.05, 0.04]  # another link, outside the hand box
    io.feed("robot_model", robot_model(np.vstack([HAND, far]), {"wrist": T}))
    p_local, f = np.array([0.04, 0.0, 0.1]), np.array([-3.0, 0.5, 1.0])
    io.feed("wrench", Wrench(arm="arm", sensor_frame="wrist", force=f.tolist(), torque=np.cross(p_local, f).tolist()))
    gen.step()
    h = clouds(io)[-1]
    assert len(h) and np.linalg.norm(h.location - (p_local + T[:3, 3]), axis=1).min() < 0.006
    assert h.location[:, 0].max() < 0.6
    bad = ForceTorqueGenerator("ft", ForceTorqueParams(links=("nothing",)))
    io = started(bad)
    io.feed("robot_model", robot_model(HAND, {"wrist": T}))
    io.feed("wrench", Wrench(arm="arm", sensor_frame="wrist", force=f.tolist(), torque=[0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="no link starts with"):
        bad.step()


def test_tactile_shell_places_the_hand_reading_with_its_taxel_poses():
    gen = TactileGenerator("tactile", TactileParams(robot="r1"))
    io = started(gen)
    tactile, poses = one_pad_hand([[0.5, 0, 0.8], [0.52, 0, 0.8], [0.54, 0, 0.8]], [0.0, 2.0, 1.0])
    io.feed("tactile", tactile)
    gen.step()
    assert io.published["hypotheses"] == []  # taxels not placed yet
    io.feed("taxels", poses)
    io.feed("tactile", tactile)
    gen.step()
    (msg,) = io.published["hypotheses"]
    h = msg.hypotheses()
    assert msg.link == "hand"
    best = h.location[np.argmax(h.likelihood)]
    assert np.linalg.norm(best - [0.52, 0, 0.8]) < 0.005 and len(h) == 2
    assert np.allclose(h.direction, [0, 0, -1])
    _, other = one_pad_hand([[0.5, 0, 0.8]], [1.0])
    io.feed("taxels", other)
    io.feed("tactile", tactile)
    with pytest.raises(ValueError, match="do not match"):
        gen.step()


def test_range_shell_initialises_then_stays_quiet_without_contact():
    gen = RangeHypothesesGenerator("range")
    io = started(gen)
    g = np.arange(-0.03, 0.031, 0.005)
    top = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pts = np.column_stack([top[:, 0] + 0.55, top[:, 1], np.full(len(top), 0.87)])
    io.feed("robot_model", robot_model(HAND))
    for _ in range(2):
        io.feed("points", point_cloud(pts))
        gen.step()
    assert [len(h) for h in clouds(io)] == [0, 0]
    assert gen.core.grid is not None
    io.feed("points", PointCloud(points=NDArray.of(pts.astype(np.float32))))
    with pytest.raises(ValueError, match="expected the camera position"):
        gen.step()


def test_one_robots_head_camera_publishes_range_hypotheses_about_another_robots_contact():
    params = RangeParams(robot="melfa", require_motion=False)  # a box fixed to the table
    keys = RangeHypothesesGenerator.default_output_keys(KeySpace("lab"), "tombatossals", "head_range", params)
    assert keys == {"hypotheses": KeySpace("lab").hypotheses("melfa", "head_range")}
    gen = RangeHypothesesGenerator("head_range", params)
    io = started(gen)
    g = np.arange(-0.03, 0.031, 0.005)
    top = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    box_top = np.column_stack([top[:, 0] + 0.55, top[:, 1], np.full(len(top), 0.87)])
    head = (0.1, 0.0, 1.6)  # tombatossals' Kinect, not melfa's
    away = np.array([[0.9, 0.4, 1.2, 0.01, 0.9, 0.4, 1.25, 0.01]])
    on_top = np.array([[0.55, 0.0, 0.885, 0.015, 0.55, 0.0, 0.95, 0.015]])  # melfa's fingertip on the box
    io.feed("robot_model", robot_model(away, robot="melfa"))
    io.feed("points", point_cloud(box_top, origin=head))
    gen.step()
    io.feed("robot_model", robot_model(on_top, robot="melfa"))
    io.feed("points", point_cloud(box_top, origin=head))
    gen.step()
    first, touched = io.published["hypotheses"]
    assert first.robot == touched.robot == "melfa" and len(first.hypotheses()) == 0
    h = touched.hypotheses()
    assert len(h) > 0
    assert np.linalg.norm(h.location.mean(axis=0) - [0.55, 0.0, 0.87]) < 0.01


def depth_frame(eye, box_top_z=0.87, half=0.03, table_z=0.75, size=120):
    """A camera at ``eye`` looking straight down: a box top (+-``half`` about x 0.55, y 0) on the table."""
    from contactflow.embodiments.messages import DepthImage
    from contactflow.recognition.geometry import intrinsics, look_at

    K = intrinsics(size, size, 60.0)
    T = look_at(np.asarray(eye, float), np.array([eye[0], eye[1], 0.0]))
    v, u = np.mgrid[0:size, 0:size]
    rays = (np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1)
            @ T[:3, :3].T)  # world direction of each pixel, unit optical z
    depth = (eye[2] - table_z) / -rays[..., 2]
    hit = eye[:2] + rays[..., :2] * ((eye[2] - box_top_z) / -rays[..., 2])[..., None]
    on_box = (np.abs(hit[..., 0] - 0.55) <= half) & (np.abs(hit[..., 1]) <= half)
    depth[on_box] = ((eye[2] - box_top_z) / -rays[..., 2])[on_box]
    return DepthImage.of(depth, K, T, "head")


def test_a_range_generator_reads_a_worlds_depth_stream_within_its_roi():
    from contactflow.recognition.geometry import Box
    from contactflow.recognition.messages import RoiMsg

    on_top = np.array([[0.55, 0.0, 0.885, 0.015, 0.55, 0.0, 0.95, 0.015]])  # a fingertip on the box
    away = np.array([[0.9, 0.4, 1.2, 0.01, 0.9, 0.4, 1.25, 0.01]])
    box, beside = (0.45, -0.1, 0.76, 0.65, 0.1, 1.0), (0.7, 0.2, 0.76, 0.9, 0.4, 1.0)
    found = {}
    for name, roi, region in (("box", box, None), ("beside", beside, None), ("input beside", box, beside)):
        gen = RangeHypothesesGenerator("range", RangeParams(robot="melfa", require_motion=False, roi=roi))
        io = started(gen)
        if region is not None:  # a vision chain's region above its plane (roi input) overrides params.roi
            lo, hi = np.array(region[:3]), np.array(region[3:])
            io.feed("roi", RoiMsg.of(Box((lo + hi) / 2, np.eye(3), hi - lo)))
        io.feed("robot_model", robot_model(away, robot="melfa"))
        io.feed("depth", depth_frame((0.55, 0.0, 1.45)))
        gen.step()
        io.feed("robot_model", robot_model(np.vstack([on_top, away]), robot="melfa"))
        io.feed("depth", depth_frame((0.55, 0.0, 1.45)))
        gen.step()
        found[name] = gen.core.camera, clouds(io)[-1]
        if name == "box":  # the link far from the roi and the grid is left out of the distances: it changes no voxel
            assert np.array_equal(gen.near(np.vstack([on_top, away]), np.array(roi[:3]), np.array(roi[3:])), on_top)
    for name in ("beside", "input beside"):
        assert found[name][0] is None and len(found[name][1]) == 0, name  # nothing in that roi: no grid, no contact
    camera, h = found["box"]
    assert np.allclose(camera, [0.55, 0.0, 1.45])  # the grid's rays start at the frame's camera
    assert len(h) > 0 and np.linalg.norm(h.location.mean(axis=0) - [0.55, 0.0, 0.87]) < 0.01
    from contactflow.nodes.params import ParamError, replace_params

    with pytest.raises(ParamError, match=r"range.params.roi: \[0.5, 0.0, 0.8\] is not"):
        replace_params(RangeParams(), {"roi": [0.5, 0.0, 0.8]}, "range.params.")


def joint_state(names, q):
    z = NDArray.of(np.zeros(len(q)))
    return JointState(robot="r1", names=list(names), position=NDArray.of(np.asarray(q, dtype=float)), velocity=z,
                      effort=z)


def test_finger_shell_reads_the_joint_state_and_the_fingers_links():
    assert fingers_of((0, 0, 1, -1), 4) == [[0, 1], [2]]
    gen = FingerPoseHypothesesGenerator("finger", FingerParams(
        finger_of_joint=(0, 0, 1, 1), joints=("f0a", "f0b", "f1a", "f1b"), finger_links=("link0", "link1")))
    io = started(gen)
    fingers = np.array([[0.5, 0.0, 0.9, 0.01, 0.5, 0.0, 0.95, 0.01],    # link0: finger 0
                        [0.5, 0.05, 0.9, 0.01, 0.5, 0.05, 0.95, 0.01]])  # link1: finger 1
    io.feed("robot_model", robot_model(fingers))
    names = ["arm", "f0a", "f0b", "f1a", "f1b"]
    io.feed("joint_state", joint_state(names, [0.3, 0, 0, 0, 0]))
    gen.step()
    io.feed("joint_state", joint_state(names, [0.9, 0, 0, 0, 0.3]))  # the arm moved, finger 1 bent
    gen.step()
    h = clouds(io)[-1]
    assert len(h) > 10 and np.allclose(h.likelihood, 1.0 / len(h))
    assert (np.abs(h.location[:, 1] - 0.05) < 0.02).all()  # on finger 1 only
    io.feed("joint_state", joint_state(["arm"], [0.0]))
    with pytest.raises(ValueError, match="lacks joints"):
        gen.step()


def test_motion_shell_extrapolates_the_model():
    gen = MotionSupportHypothesesGenerator("motion")
    io = started(gen)
    ball = np.array([0.50, 0, 0.9, 0.02, 0.50, 0, 0.9, 0.02])
    io.feed("robot_model", robot_model(ball))
    gen.step()
    io.feed("robot_model", robot_model(ball + [0.01, 0, 0, 0, 0.01, 0, 0, 0]))
    gen.step()
    (h,) = clouds(io)
    assert (h.kind == HypothesisType.SUPPORT).all() and np.allclose(h.likelihood, 0.3)
    d = np.linalg.norm(h.location - [0.52, 0, 0.9], axis=1)
    assert np.abs(d - 0.02).max() < 0.006  # on the sphere moved one more step


def predicted(contacts):
    from contactflow.embodiments.messages import PredictedState

    return PredictedState(robot="r1", tick=3, t=0.015, names=["j"], position=NDArray.of(np.zeros(1)), joint_error=0.0,
                          contacts=None if contacts is None else NDArray.of(np.asarray(contacts, dtype=np.float64)))


def test_simulator_and_null_shells():
    sim = SimulatorSupportGenerator("sim", SimulatorSupportGenerator.Params(robot="r1"))
    assert sim.default_input_keys(KeySpace("lab"), "r1", "sim", sim.params) == {"predicted": "cf/lab/predict/r1/state"}
    io = started(sim)
    io.feed("predicted", predicted([[0.5, 0, 0.9]]))
    sim.step()
    io.feed("predicted", predicted(None))  # the predicted hands touch nothing: an empty cloud, the source stays plugged
    sim.step()
    (touch, free) = clouds(io)
    assert touch.likelihood.tolist() == [0.5] and (touch.kind == HypothesisType.SUPPORT).all() and len(free) == 0
    io.feed("predicted", predicted([0.5, 0, 0.9]))  # a flat array (non-finite numbers the wire refuses already)
    with pytest.raises(ValueError, match="input 'predicted' .r1. has contacts of shape"):
        sim.step()
    null = NullHypothesesGenerator("null")
    io = started(null)
    io.feed("robot_model", robot_model(HAND))
    null.step()
    (h,) = clouds(io)
    assert len(h) > 10 and (h.kind == HypothesisType.NULL).all()


def test_a_robot_model_with_a_part_metres_wide_is_refused_by_the_shape_generators_naming_the_link():
    # a corrupted or hostile model: gridding a 1.9 m bi-sphere at 5 mm would stall the node's loop for minutes
    from contactflow.fusion.geometry import capsule_surface, interior_points

    for gen in (NullHypothesesGenerator("null"), MotionSupportHypothesesGenerator("motion")):
        io = started(gen)
        io.feed("robot_model", robot_model([[0.5, 0, 0.8, 3.0, 0.5, 0, 0.9, 0.02], [0.5, 0.2, 0.8, 0.02, 0.5, 0.2, 0.9, 0.02]]))
        with pytest.raises(ValueError, match=r"link 'link0' has a bi-sphere of radius 3 m .* at most 2 m"):
            gen.step()
    wide = np.array([[0.0, 0, 0, 1.9, 0, 0, 0.5, 1.9]])
    for shape in (lambda: capsule_surface(wide, 0.005), lambda: interior_points(wide, 0.005, 0.01)):
        with pytest.raises(ValueError, match="cells of 0.005 m: not a robot's parts"):
            shape()
