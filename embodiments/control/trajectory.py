"""Joint trajectory following: waypoints timed by a speed bound, with an F/T contact watchdog."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.nodes.status import Status


@dataclass(frozen=True)
class TrajectoryParams:
    max_velocity: float = 1.0  # rad/s, per joint
    min_segment: float = 0.05  # s, shortest segment duration
    abort_force: float = 8.0  # N, F/T force change that counts as an unexpected contact
    settle: float = 0.2  # s after the last waypoint before SUCCESS


class TrajectoryFollower:
    """Samples a piecewise-linear joint path; aborts when the wrist force deviates from its start value."""

    def __init__(self, waypoints: np.ndarray, params: TrajectoryParams | None = None) -> None:
        self.params = params or TrajectoryParams()
        w = np.asarray(waypoints, dtype=np.float64)
        if w.ndim != 2 or len(w) < 1 or not np.all(np.isfinite(w)):
            raise ValueError(f"waypoints must be a finite (K, n) array, got shape {w.shape}")
        self.waypoints = w
        seg = np.abs(np.diff(w, axis=0)).max(axis=1) / self.params.max_velocity if len(w) > 1 else np.zeros(0)
        self.durations = np.maximum(seg, self.params.min_segment)
        self.times = np.concatenate([[0.0], np.cumsum(self.durations)])
        self.t = 0.0
        self.status = Status.RUNNING
        self.abort_reason = ""
        self._f0: np.ndarray | None = None

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at time ``t`` since the start."""
        if len(self.waypoints) == 1 or t >= self.duration:
            return self.waypoints[-1].copy(), np.zeros(self.waypoints.shape[1])
        k = int(np.searchsorted(self.times, t, side="right") - 1)
        s = (t - self.times[k]) / self.durations[k]
        a, b = self.waypoints[k], self.waypoints[k + 1]
        return a + s * (b - a), (b - a) / self.durations[k]

    def step(self, dt: float, force: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Advance by ``dt``; ``force`` is the wrist force (world axes) used by the watchdog."""
        if self.status != Status.RUNNING:
            return self.sample(self.t)[0], np.zeros(self.waypoints.shape[1])
        if force is not None:
            f = np.asarray(force, dtype=np.float64)[:3]
            if self._f0 is None:
                self._f0 = f.copy()
            elif np.linalg.norm(f - self._f0) > self.params.abort_force:
                self.status = Status.FAILURE
                self.abort_reason = "contact"
                return self.sample(self.t)[0], np.zeros(self.waypoints.shape[1])
        self.t += dt
        if self.t >= self.duration + self.params.settle:
            self.status = Status.SUCCESS
        return self.sample(self.t)
