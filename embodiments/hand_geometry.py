"""The space a robot's hand occupies around its controlled frame, measured on its collision geometry."""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.sensors.camera import shape_mesh
from contactflow.embodiments.transforms import pose_to_matrix


def _subtree(root) -> list:
    out, todo = [], [root]
    while todo:
        link = todo.pop()
        out.append(link)
        todo.extend(link.get_children())
    return out


def hand_points(robot, arm: str) -> np.ndarray:
    """Surface points (N, 3) in ``arm``'s controlled frame of everything past the arm's last joint.

    That is the wrist link, the F/T sensor and the hand in its current preshape: the part of
    the robot that goes closest to an object. Measured on the PhysX collision shapes.
    """
    spec = robot.spec.arm(arm)
    links = robot.art.links
    last = spec.joints[-1]
    root = next((lk for lk in links.values() if lk.get_joint() is not None and lk.get_joint().get_name() == last), None)
    if root is None:
        raise ValueError(f"{robot.name}: arm {arm!r} has no link driven by its last joint {last!r}")
    T_ee_inv = np.linalg.inv(robot.frame_pose(spec.ee_frame))
    points = []
    for link in _subtree(root):
        T = pose_to_matrix(link.get_entity_pose())
        for shape in link.get_collision_shapes():
            mesh = shape_mesh(shape)
            if mesh is None:
                continue
            M = T_ee_inv @ T @ pose_to_matrix(shape.get_local_pose())
            points.append(mesh[0] @ M[:3, :3].T + M[:3, 3])
    if not points:
        raise ValueError(f"{robot.name}: arm {arm!r} has no collision geometry past {last!r}")
    return np.unique(np.round(np.concatenate(points), 4), axis=0)
