"""Hardware fault detection: physics blow-up (NaN, joint explosion), stuck joint, lost sensor stream.

A detected fault becomes a ``hardware_failure`` condition and the robot is stopped by its
owner; :meth:`FaultMonitor.check` never raises.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FaultParams:
    max_joint_speed: float = 20.0  # rad/s or m/s, faster for ``explosion_time`` means the simulation exploded
    explosion_time: float = 0.02  # s; a light finger phalanx chattering in contact spikes for one tick
    burst_speed: float = 200.0  # rad/s or m/s, faster is an explosion at once
    limit_excess: float = 0.3  # rad, this far beyond a joint limit means an explosion
    stuck_error: float = 0.08  # rad, tracking error of a joint that does not move
    stuck_speed: float = 0.02  # rad/s
    stuck_time: float = 0.4  # s the condition must last
    sensor_timeout: float = 0.25  # s without a new sample


@dataclass(frozen=True)
class Fault:
    kind: str  # nan | explosion | stuck_joint | sensor_loss
    detail: str


class FaultMonitor:
    """Checks one robot's state at the control rate."""

    def __init__(self, joint_names: list[str], lower: np.ndarray, upper: np.ndarray, watched: np.ndarray | None = None,
                 params: FaultParams | None = None) -> None:
        self.names = list(joint_names)
        self.lower, self.upper = np.asarray(lower), np.asarray(upper)
        self.watched = np.ones(len(self.names), bool) if watched is None else np.asarray(watched, bool)
        self.params = params or FaultParams()
        self._stuck_since = np.full(len(self.names), np.nan)
        self._fast_since = np.full(len(self.names), np.nan)
        p = self.params
        self._low, self._high = self.lower - p.limit_excess, self.upper + p.limit_excess

    def check(self, t: float, q: np.ndarray, qd: np.ndarray, target: np.ndarray,
              sensor_stamps: dict[str, float] | None = None) -> Fault | None:
        # runs for every robot at every tick: the common case (nothing over a bound) takes no np.where
        p = self.params
        try:
            finite = np.isfinite(q) & np.isfinite(qd)
            if not finite.all():
                bad = [self.names[i] for i in np.nonzero(~finite)[0]]
                return Fault("nan", f"non-finite joint state in {bad[:4]}")
            speed = np.abs(qd)
            over = speed > p.max_joint_speed
            if over.any():
                self._fast_since = np.where(over, np.where(np.isnan(self._fast_since), t, self._fast_since), np.nan)
                fast = (speed > p.burst_speed) | (over & (t - self._fast_since >= p.explosion_time))
            else:
                self._fast_since.fill(np.nan)
                fast = speed > p.burst_speed
            out = (q < self._low) | (q > self._high)
            if fast.any() or out.any():
                i = int(np.nonzero(fast | out)[0][0])
                return Fault("explosion", f"joint {self.names[i]} q={q[i]:.3f} qd={qd[i]:.2f}")
            err = np.abs(target - q)
            cond = self.watched & (err > p.stuck_error) & (speed < p.stuck_speed)
            if cond.any():
                self._stuck_since = np.where(cond, np.where(np.isnan(self._stuck_since), t, self._stuck_since), np.nan)
                long = cond & (t - self._stuck_since >= p.stuck_time)
                if long.any():
                    i = int(np.nonzero(long)[0][0])
                    return Fault("stuck_joint", f"joint {self.names[i]} does not follow (error {err[i]:.3f})")
            else:
                self._stuck_since.fill(np.nan)
            silent = self.silent_streams(t, sensor_stamps or {})
            if silent is not None:
                return silent
        except (ValueError, FloatingPointError, IndexError) as exc:
            return Fault("nan", f"state check failed: {exc}")
        return None

    def silent_streams(self, t: float, stamps: dict[str, float]) -> Fault | None:
        """A sensor whose latest sample is older than ``sensor_timeout`` has lost its stream."""
        for name, stamp in stamps.items():
            if t - stamp > self.params.sensor_timeout:
                return Fault("sensor_loss", f"sensor {name} silent for {t - stamp:.2f} s")
        return None

    def reset(self) -> None:
        self._stuck_since[:] = np.nan
        self._fast_since[:] = np.nan
