"""Helpers for tests and benchmarks of the embodiments: standard scenes and geometric checks."""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, box
from contactflow.nodes.status import Status


def gaze_deg(robot: SimRobot, obj: str, camera: str = "kinect") -> float:
    """Angle (deg) between a camera's optical axis and an object's true centre (evaluation only)."""
    T = robot.camera_pose(camera)
    d = robot.ground_truth().object_poses[obj][:3, 3] - T[:3, 3]
    return float(np.degrees(np.arccos(np.clip(T[:3, 2] @ d / np.linalg.norm(d), -1.0, 1.0))))


def make_robot(name: str, table: bool = True) -> SimRobot:
    """A fresh world (floor, optional table) with one robot at its default placement."""
    w = World()
    if table:
        w.add_table()
    return SimRobot(w, name)


def melfa_around_plate(mass: float) -> SimRobot:
    """melfa with its open gripper lowered around a thin plate of ``mass`` kg standing on the table.

    The plate is 8 mm across the pads' rows (narrower than the 17.5 mm pads), 4 cm wide, 6 cm tall.
    """
    robot = make_robot("melfa")
    arm = robot.arm("arm")
    T0 = arm.ee_pose()
    robot.world.add_object(box("obj", (0.04, 0.008, 0.06), (T0[0, 3], T0[1, 3], 0.78), mass=mass, friction=0.8))
    robot.step(0.2)
    down = T0.copy()
    down[2, 3] = 0.80
    arm.move_pose(down, speed=0.15)
    if arm.wait(5.0) != Status.SUCCESS:
        raise RuntimeError(f"melfa did not reach the plate: {arm.status}")
    return robot


def line_deviation(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance of ``points`` from the segment a-b."""
    d = b - a
    lam = np.clip((points - a) @ d / (d @ d), 0.0, 1.0)
    return float(np.linalg.norm(points - (a + lam[:, None] * d), axis=1).max())
