"""Sensors from the physics: F/T reads m·g, tactile only under contact, camera cloud of a known box, encoders."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.registry import PadSpec
from contactflow.embodiments.sensors.camera import depth_to_points
from contactflow.embodiments.sensors.tactile import pressure, taxel_positions
from contactflow.embodiments.testing import make_robot
from contactflow.embodiments.world import box
from contactflow.nodes.status import Event, Status

MASS = 0.5


@pytest.fixture(scope="module")
def grasp():
    """melfa picks a 0.5 kg box: (robot, tactile while open, tactile while holding)."""
    robot = make_robot("melfa")
    arm, hand = robot.arm("arm"), robot.hand("gripper")
    T0 = arm.ee_pose()
    # a thin plate (8 mm across the pads' rows, narrower than the 17.5 mm pads)
    robot.world.add_object(box("obj", (0.04, 0.008, 0.06), (T0[0, 3], T0[1, 3], 0.78), mass=MASS, friction=0.8))
    robot.step(0.2)
    down = T0.copy()
    down[2, 3] = 0.80
    arm.move_pose(down, speed=0.15)
    assert arm.wait(5.0) == Status.SUCCESS
    open_tactile = robot.tactile("gripper")
    hand.close()
    assert hand.wait(3.0) == Status.SUCCESS
    up = down.copy()
    up[2, 3] = 0.95
    arm.move_pose(up, speed=0.15)
    assert arm.wait(5.0) == Status.SUCCESS
    robot.step(0.3)
    return robot, open_tactile, robot.tactile("gripper")


def test_ft_reads_the_held_weight(grasp):
    robot, _, _ = grasp
    assert robot.world.objects["obj"].pose()[2, 3] > 0.85  # lifted
    f = np.mean([robot.ft("arm").force for _ in range(1) if robot.step(0.01) is None], axis=0)
    assert f[2] == pytest.approx(-MASS * 9.81, rel=0.05)
    assert np.linalg.norm(f[:2]) < 0.05 * MASS * 9.81


def test_tactile_shows_pressure_only_under_contact(grasp):
    _, open_tactile, held = grasp
    assert all(np.all(v == 0) for v in open_tactile.values())
    for pad in ("left", "right"):
        img = held[pad]
        assert img.shape == (5, 8)
        assert np.all(img >= 0)
        rows = img.sum(axis=1)
        assert rows[2] > 1.0  # the plate presses on the middle rows
        assert rows[0] == 0 and rows[4] == 0  # the outer rows, beside the plate, read nothing
    # the pads carry the grip force: equal and opposite on the two fingers
    assert held["left"].sum() == pytest.approx(held["right"].sum(), rel=0.1)


def test_pressure_model_on_flat_and_curved_pads():
    flat = PadSpec("p", "l", origin=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), u_axis=(1.0, 0.0, 0.0), size=(0.016, 0.01))
    img = pressure(flat, np.array([[0.0, 0.0, 0.0]]), np.array([2.0]))
    r, c = np.unravel_index(img.argmax(), img.shape)
    assert r == 2 and c in (3, 4)
    assert img.sum() == pytest.approx(2.0, rel=0.1)
    assert np.all(pressure(flat, np.array([[0.05, 0.0, 0.0]]), np.array([2.0])) == 0)  # beside the pad
    assert np.all(pressure(flat, np.array([[0.0, 0.0, 0.02]]), np.array([2.0])) == 0)  # above it
    tip = PadSpec("t", "l", origin=(0.012, 0.0, 0.0), normal=(1.0, 0.0, 0.0), u_axis=(0.0, 0.0, 1.0), size=(0.022, 0.016),
                  radius=0.012)
    taxels = taxel_positions(tip)
    assert np.allclose(np.linalg.norm(taxels, axis=2), 0.012)
    front = pressure(tip, np.array([[0.012, 0.0, 0.0]]), np.array([1.0]))
    back = pressure(tip, np.array([[-0.012, 0.0, 0.0]]), np.array([1.0]))
    assert front.max() > 0 and np.all(back == 0)


def test_camera_cloud_of_a_known_box():
    robot = make_robot("tombatossals")
    size, centre = (0.1, 0.06, 0.08), np.array([0.55, 0.0, 0.79])
    robot.world.add_object(box("target", size, tuple(centre), mass=0.3))
    robot.step(0.1)
    frame = robot.camera("kinect")
    assert frame.depth.shape == (480, 640)
    assert np.allclose(depth_to_points(frame.depth, frame.K, frame.T_world_cam), frame.points, atol=1e-4)
    P = frame.points
    near = P[(np.abs(P[:, 0] - centre[0]) < 0.08) & (np.abs(P[:, 1] - centre[1]) < 0.06) & (P[:, 2] > 0.755) & (P[:, 2] < 0.9)]
    top = near[near[:, 2] > near[:, 2].max() - 0.003]
    assert len(top) > 200
    assert top[:, 2].mean() == pytest.approx(centre[2] + size[2] / 2, abs=5e-3)
    assert top[:, 0].min() == pytest.approx(centre[0] - size[0] / 2, abs=5e-3)
    assert top[:, 0].max() == pytest.approx(centre[0] + size[0] / 2, abs=5e-3)
    assert top[:, 1].min() == pytest.approx(centre[1] - size[1] / 2, abs=5e-3)
    assert top[:, 1].max() == pytest.approx(centre[1] + size[1] / 2, abs=5e-3)
    gt = robot.ground_truth()
    assert np.allclose(gt.object_poses["target"][:3, 3], centre, atol=2e-3)
    assert any({c.body_a, c.body_b} == {"target", "table"} for c in gt.contacts)


def test_encoders_follow_the_fingers(melfa):
    hand = melfa.hand("gripper")
    hand.set_fingers(np.array([0.02]))
    assert hand.wait(2.0) == Status.SUCCESS
    assert melfa.finger_positions("gripper")[0] == pytest.approx(0.02, abs=1e-3)
    hand.open()
    assert hand.wait(2.0) == Status.SUCCESS


def test_baxter_estimated_wrench_detects_table_contact():
    robot = make_robot("baxter")
    arm = robot.arm("left")
    quiet = np.array([robot.ft("left").force for _ in range(20) if robot.step(0.01) is None])
    assert quiet.std(axis=0).max() > 0.3  # noisy, as the real virtual sensor
    arm.guarded_move(np.array([0.0, 0.0, -0.05, 0.0, 0.0, 0.0]), max_force=8.0, duration=6.0)
    assert arm.wait(7.0) == Status.SUCCESS
    assert any(e == Event.CONTACT for _, e, _ in robot.events)
    assert arm.ee_pose()[2, 3] < 0.80  # stopped at the table (top at 0.75), not before


def test_allegro_fingertip_pad_feels_only_its_own_contact():
    robot = make_robot("tombatossals")
    arm = robot.arm("left")
    tip = robot.frame_pose("left_link_3.0_tip")[:3, 3]  # index fingertip, pad facing down at home
    robot.world.add_object(box("post", (0.03, 0.03, 0.1), (tip[0], tip[1], tip[2] - 0.07), static=True))
    arm.guarded_move(np.array([0.0, 0.0, -0.03, 0.0, 0.0, 0.0]), max_force=2.0, duration=5.0)
    assert arm.wait(6.0) == Status.SUCCESS
    robot.step(0.1)
    pads = robot.tactile("left_hand")
    index = pads["index"]
    assert index.max() > 0.05
    r, c = np.unravel_index(index.argmax(), index.shape)
    assert 1 <= r <= 3 and 2 <= c <= 5  # centred under the fingertip
    assert all(np.all(pads[p] == 0) for p in ("middle", "ring", "thumb"))
    assert all(np.all(v == 0) for v in robot.tactile("right_hand").values())


def test_wrench_control_presses_and_ft_matches_the_contact_force(melfa):
    arm = melfa.arm("arm")
    arm.guarded_move(np.array([0.0, 0.0, -0.05, 0.0, 0.0, 0.0]), max_force=3.0, duration=8.0)
    assert arm.wait(9.0) == Status.SUCCESS
    arm.set_wrench(np.array([0.0, 0.0, -10.0, 0.0, 0.0, 0.0]))  # press down with 10 N
    melfa.step(1.5)
    ft, table = [], []
    for _ in range(40):
        melfa.step(0.01)
        ft.append(melfa.ft("arm").force)
        table.append(sum(c.force * c.normal[2] for c in melfa.ground_truth().contacts if "table" in (c.body_a, c.body_b)))
    f = np.mean(ft, axis=0)
    assert f[2] == pytest.approx(10.0, rel=0.1)  # the F/T reads the table pushing up (+z)
    assert f[2] == pytest.approx(abs(np.mean(table)), rel=0.05)
    arm.move_joints(np.asarray(arm.home))
    assert arm.wait(6.0) == Status.SUCCESS
