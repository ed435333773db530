"""Joint trajectory following: waypoints timed by a speed bound, with an F/T contact watchdog."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.nodes.status import Status


class ForceWatch:
    """Detects an unexpected contact: the low-passed wrist force leaves its baseline by more than ``limit`` N.

    The baseline is the mean over the first ``baseline_time`` s; the filter (time constant
    ``tau``) keeps sensor noise (Baxter's estimated wrench) and motion transients from
    tripping it.
    """

    def __init__(self, limit: float, tau: float = 0.03, baseline_time: float = 0.05) -> None:
        self.limit, self.tau, self.baseline_time = limit, tau, baseline_time
        self.t = 0.0
        self._sum = np.zeros(3)
        self._n = 0
        self.baseline: np.ndarray | None = None
        self.filtered: np.ndarray | None = None

    def update(self, force: np.ndarray, dt: float) -> bool:
        f = np.asarray(force, dtype=np.float64)[:3]
        self.t += dt
        a = min(1.0, dt / self.tau)
        self.filtered = f.copy() if self.filtered is None else (1 - a) * self.filtered + a * f
        if self.baseline is None:
            self._sum += f
            self._n += 1
            if self.t >= self.baseline_time:
                self.baseline = self._sum / self._n
            return False
        return bool(np.linalg.norm(self.filtered - self.baseline) > self.limit)


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
        self.watch = ForceWatch(self.params.abort_force) if np.isfinite(self.params.abort_force) else None

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
        if force is not None and self.watch is not None and self.watch.update(force, dt):
            self.status = Status.FAILURE
            self.abort_reason = "contact"
            return self.sample(self.t)[0], np.zeros(self.waypoints.shape[1])
        self.t += dt
        if self.t >= self.duration + self.params.settle:
            self.status = Status.SUCCESS
        return self.sample(self.t)
