"""Joint trajectory following: waypoints timed by speed and acceleration bounds, with an F/T contact watchdog."""

from __future__ import annotations

import math
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
    max_acceleration: float = math.inf  # rad/s^2, of the path length (largest joint change) (inf: each segment timed alone)
    corner_jump: float = 0.1  # rad/s, largest change of a joint's velocity where the path turns at a waypoint
    min_segment: float = 0.05  # s, shortest segment duration when each segment is timed alone
    abort_force: float = 8.0  # N, F/T force change that counts as an unexpected contact
    settle: float = 0.2  # s after the last waypoint before SUCCESS


class TrajectoryFollower:
    """Samples a piecewise-linear joint path; aborts when the wrist force deviates from its start value.

    With a finite ``max_acceleration`` the path is timed along its length (the largest joint
    change per segment): the arm speeds up and slows down at that bound over the whole path,
    whatever the planner's waypoint spacing, and slows at a waypoint where the path turns so
    that no joint's velocity jumps by more than ``corner_jump``. Otherwise each segment runs at
    ``max_velocity`` for at least ``min_segment`` s (a joint target reached in one step), except
    at a waypoint where the path turns back on itself (over 90 degrees): the arm comes to rest
    there, slowing down over the segment before and speeding up over the one after, each taking
    twice as long. A reversal at full speed jolts the wrist: 29 N on tombatossals' F/T from an arm
    turning back at 0.4 rad/s, enough for the watchdog to abort the path on a contact that is not there.
    """

    def __init__(self, waypoints: np.ndarray, params: TrajectoryParams | None = None) -> None:
        self.params = params or TrajectoryParams()
        w = np.asarray(waypoints, dtype=np.float64)
        if w.ndim != 2 or len(w) < 1 or not np.all(np.isfinite(w)):
            raise ValueError(f"waypoints must be a finite (K, n) array, got shape {w.shape}")
        p = self.params
        if not (p.max_velocity > 0 and p.max_acceleration > 0 and p.corner_jump > 0):
            raise ValueError("max_velocity, max_acceleration and corner_jump must be > 0, got "
                             f"{p.max_velocity}, {p.max_acceleration}, {p.corner_jump}")
        self.profiled = math.isfinite(p.max_acceleration)
        if self.profiled and len(w) > 1:  # a repeated waypoint has no direction to time
            moved = np.abs(np.diff(w, axis=0)).max(axis=1) > 1e-12
            w = w[np.concatenate([[True], moved])]
        self.waypoints = w
        self.lengths = np.abs(np.diff(w, axis=0)).max(axis=1) if len(w) > 1 else np.zeros(0)
        if self.profiled:
            self._time_profile()
        else:
            self.durations = np.maximum(self.lengths / p.max_velocity, p.min_segment)
            self._rest_at_turnbacks()
        self.times = np.concatenate([[0.0], np.cumsum(self.durations)])
        self.t = 0.0
        self.status = Status.RUNNING
        self.abort_reason = ""
        self.watch = ForceWatch(p.abort_force) if np.isfinite(p.abort_force) else None

    def _rest_at_turnbacks(self) -> None:
        """Segments into (out of) a waypoint where the path turns back slow down to (speed up from) rest."""
        d = np.diff(self.waypoints, axis=0)
        back = np.zeros(len(d) + 1, dtype=bool)  # at waypoint k
        if len(d) > 1:
            back[1:-1] = (d[1:] * d[:-1]).sum(axis=1) < 0.0
        self.rest_in, self.rest_out = back[1:], back[:-1]  # per segment: rests at its end, at its start
        self.durations = self.durations * np.where(self.rest_in | self.rest_out, 2.0, 1.0)

    def _time_profile(self) -> None:
        """Speeds at the waypoints (forward and backward acceleration passes), then per segment a
        speed-up, cruise and slow-down between them."""
        p, L = self.params, self.lengths
        a, vmax = p.max_acceleration, p.max_velocity
        v = np.full(len(L) + 1, vmax)
        v[0] = v[-1] = 0.0
        if len(L) > 1:
            u = np.diff(self.waypoints, axis=0) / L[:, None]
            turn = np.abs(np.diff(u, axis=0)).max(axis=1)
            v[1:-1] = np.minimum(vmax, p.corner_jump / np.maximum(turn, 1e-12))
        for k in range(len(L)):
            v[k + 1] = min(v[k + 1], math.sqrt(v[k] ** 2 + 2 * a * L[k]))
        for k in reversed(range(len(L))):
            v[k] = min(v[k], math.sqrt(v[k + 1] ** 2 + 2 * a * L[k]))
        self.v_start, self.v_end = v[:-1], v[1:]
        self.v_peak = np.minimum(vmax, np.sqrt(a * L + 0.5 * (self.v_start ** 2 + self.v_end ** 2)))
        self.v_peak = np.maximum(self.v_peak, np.maximum(self.v_start, self.v_end))
        self.t_up = (self.v_peak - self.v_start) / a
        self.t_down = (self.v_peak - self.v_end) / a
        ramps = (2 * self.v_peak ** 2 - self.v_start ** 2 - self.v_end ** 2) / (2 * a)
        self.t_cruise = np.maximum(L - ramps, 0.0) / np.maximum(self.v_peak, 1e-12)
        self.durations = self.t_up + self.t_cruise + self.t_down

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def _progress(self, k: int, tau: float) -> tuple[float, float]:
        """Length covered along segment ``k`` and its rate, ``tau`` s into the segment."""
        a, v0, vp = self.params.max_acceleration, self.v_start[k], self.v_peak[k]
        tu, tc = self.t_up[k], self.t_cruise[k]
        if tau < tu:
            return v0 * tau + 0.5 * a * tau * tau, v0 + a * tau
        up = v0 * tu + 0.5 * a * tu * tu
        if tau < tu + tc:
            return up + vp * (tau - tu), vp
        td = min(tau - tu - tc, self.t_down[k])
        return up + vp * tc + vp * td - 0.5 * a * td * td, vp - a * td

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at time ``t`` since the start."""
        n = self.waypoints.shape[1]
        if len(self.waypoints) == 1 or t >= self.duration:
            return self.waypoints[-1].copy(), np.zeros(n)
        k = int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.lengths) - 1))
        a, b = self.waypoints[k], self.waypoints[k + 1]
        if self.profiled:
            s, rate = self._progress(k, max(t - self.times[k], 0.0))
            u = min(1.0, s / self.lengths[k])
            return a + u * (b - a), (b - a) / self.lengths[k] * rate
        u, T = (t - self.times[k]) / self.durations[k], self.durations[k]
        if self.rest_in[k] and self.rest_out[k]:  # rests at both ends
            return a + (3 - 2 * u) * u * u * (b - a), 6 * u * (1 - u) * (b - a) / T
        if self.rest_in[k]:  # from the neighbours' speed down to rest: that speed at the start, as twice as long
            return a + (2 - u) * u * (b - a), 2 * (1 - u) * (b - a) / T
        if self.rest_out[k]:
            return a + u * u * (b - a), 2 * u * (b - a) / T
        return a + u * (b - a), (b - a) / T

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
