"""Helpers for tests and benchmarks of the embodiments: standard scenes and geometric checks."""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World


def make_robot(name: str, table: bool = True) -> SimRobot:
    """A fresh world (floor, optional table) with one robot at its default placement."""
    w = World()
    if table:
        w.add_table()
    return SimRobot(w, name)


def line_deviation(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance of ``points`` from the segment a-b."""
    d = b - a
    lam = np.clip((points - a) @ d / (d @ d), 0.0, 1.0)
    return float(np.linalg.norm(points - (a + lam[:, None] * d), axis=1).max())
