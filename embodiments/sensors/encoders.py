"""Joint and finger encoders: joint positions/velocities read from the articulation, with resolution and noise."""

from __future__ import annotations

import numpy as np


class Encoders:
    """Positions and velocities of ``joints`` (names), quantised to ``resolution`` rad."""

    def __init__(self, art, joints: tuple[str, ...] | list[str], resolution: float = 1e-5, noise: float = 0.0,
                 seed: int = 0) -> None:
        self.art = art
        self.joints = tuple(joints)
        self.idx = art.indices(self.joints)
        self.resolution, self.noise = resolution, noise
        self.rng = np.random.default_rng(seed)

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        q = self.art.qpos()[self.idx]
        qd = self.art.qvel()[self.idx]
        if self.noise > 0:
            q = q + self.rng.normal(0, self.noise, q.shape)
        if self.resolution > 0:
            q = np.round(q / self.resolution) * self.resolution
        return q, qd
