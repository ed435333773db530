"""Transport (thesis §3.3.2, eq. 3.3): Cartesian velocity toward the target with an F/T stop, limits, waypoints, force-field avoidance and OMPL fallback."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, low_pass, matrix6, pose6
from contactflow.embodiments.primitives.motion import planning_cloud, pose_error, target_pose
from contactflow.embodiments.transforms import rotvec_error
from contactflow.nodes.status import Event, Status

DEFAULT_LIMITS = (0.1, 0.1, 0.1, 0.5, 0.5, 0.5)
"""m/s, rad/s: velocity bound used when every VELOCITY LIMIT is zero ("no constraint")."""


def transport_velocity(err: np.ndarray, gain: float, force: np.ndarray, threshold: float) -> np.ndarray:
    """Eq. 3.3: n (x_target - x_current) while ||F|| < F_threshold, else 0 (``err`` is the 6D pose error)."""
    if np.linalg.norm(force) >= threshold:
        return np.zeros(6)
    return gain * err


def limit_velocity(v: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """Scale ``v`` uniformly (the normalisation n) so every component stays inside ``limits``; 0 locks an axis."""
    out = np.where(limits > 0, v, 0.0) if limits.any() else v.copy()
    lim = limits if limits.any() else np.asarray(DEFAULT_LIMITS)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(lim > 0, np.abs(out) / lim, 0.0)
    k = float(ratio.max(initial=0.0))
    return out / k if k > 1.0 else out


def limit_acceleration(v: np.ndarray, v_prev: np.ndarray, limits: np.ndarray, dt: float) -> np.ndarray:
    if not limits.any():
        return v
    dv = v - v_prev
    bound = np.where(limits > 0, limits * dt, np.inf)
    return v_prev + np.clip(dv, -bound, bound)


def force_field(p: np.ndarray, obstacles: np.ndarray, influence: float, gain: float) -> np.ndarray:
    """Khatib's repulsive velocity at ``p`` from obstacle points closer than ``influence`` (m)."""
    if len(obstacles) == 0:
        return np.zeros(3)
    d = p[None, :] - obstacles
    dist = np.linalg.norm(d, axis=1)
    near = (dist < influence) & (dist > 1e-6)
    if not near.any():
        return np.zeros(3)
    dn, dd = d[near], dist[near]
    mag = gain * (1.0 / dd - 1.0 / influence) / dd**2
    return (mag[:, None] * dn / dd[:, None]).sum(axis=0) / max(1, near.sum())


class Transport(Primitive):
    """Move the hand (with or without an object) to ``target`` through optional ``waypoints``."""

    requires = Capability(ft=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT, Event.STUCK)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        target: tuple[float, ...] = ()  # [x, y, z, roll, pitch, yaw] m, rad (world)
        relative: bool = False  # target is an offset of the current pose
        force_threshold: float = 15.0  # N, unexpected contact (eq. 3.3)
        filter_hz: float = 0.0  # Hz, low-pass cut-off on the wrist force of the contact check (0 = none; for noisy estimated wrenches)
        acceleration_limits: tuple[float, ...] = (0.0,) * 6  # m/s^2, rad/s^2 (all 0: unconstrained)
        velocity_limits: tuple[float, ...] = (0.0,) * 6  # m/s, rad/s (all 0: unconstrained; a 0 among others locks that axis)
        obstacles: tuple[float, ...] = ()  # obstacle point cloud, flat [x, y, z, ...] (world): force field and planner
        sense_obstacles: bool = False  # also plan against the camera cloud (robot removed by the spherical model)
        waypoints: tuple[float, ...] = ()  # flat list of [x, y, z, roll, pitch, yaw] poses to pass through
        planning_distance_limit: float = 0.03  # m, farther targets are reached with the OMPL planner
        gain: float = 1.0  # 1/s, n of eq. 3.3 before limiting
        influence: float = 0.1  # m, force-field influence distance
        repulsion: float = 0.0005  # m^3/s, force-field gain
        tolerance: float = 0.005  # m, target reached
        waypoint_tolerance: float = 0.02  # m, a waypoint is passed through, not reached exactly
        settle_tolerance: float = 0.012  # m, a hand that stops this close (e.g. sagging under a load) has arrived
        rot_tolerance: float = 0.05  # rad
        stuck_time: float = 1.0  # s without progress = local minimum
        stuck_progress: float = 0.005  # m of progress expected in stuck_time
        planning_checks: int = 50_000  # state checks per plan search (2-4 s): a count, the same on any machine
        timeout: float = 30.0  # s
        guarded: bool = False  # a contact over force_threshold ends the motion with SUCCESS (a guarded move)
        preshape: str = ""  # hand preshape taken at the start ("" = keep)

    def begin(self) -> None:
        p = self.params
        if p.preshape and self.hand_name:
            self.hand.preshape(p.preshape)
        goal = target_pose(self, p.target, "target", relative=p.relative)
        w = np.asarray(p.waypoints, dtype=np.float64)
        if w.size % 6:
            raise ValueError(f"{self.name}.params.waypoints: expected a multiple of 6 values, got {w.size}")
        self.goals = [matrix6(tuple(w[i:i + 6]), f"{self.name}.params.waypoints[{i // 6}]")
                      for i in range(0, w.size, 6)] + [goal]
        self.obstacles = planning_cloud(self, p.obstacles, "obstacles", False)
        self.vlim = np.asarray(p.velocity_limits, dtype=np.float64)
        self.alim = np.asarray(p.acceleration_limits, dtype=np.float64)
        if self.vlim.shape != (6,) or self.alim.shape != (6,):
            raise ValueError(f"{self.name}: velocity_limits and acceleration_limits need 6 values")
        self.r.tare_ft(self.arm_name)
        self.f: np.ndarray | None = None  # N, the low-passed wrist force
        self.v_prev = np.zeros(6)
        self.k = 0
        self.plans = 0
        self.mode = ""
        self._enter_goal()

    def _enter_goal(self) -> None:
        goal = self.goals[self.k]
        cur = self.r.frame_pose(self.ee_frame)
        dist, _ = pose_error(cur, goal)
        self.progress = (self.r.time, dist)
        constrained = self.vlim.any() or self.alim.any() or len(self.obstacles)
        if dist > self.params.planning_distance_limit and not constrained:
            self._plan(goal)
        else:
            self.mode = "velocity"

    def _plan(self, goal: np.ndarray) -> None:
        self.halt()
        # the planner sees only what this primitive was given or senses, plus the cell's fixtures
        cloud = planning_cloud(self, self.params.obstacles, "obstacles", self.params.sense_obstacles)
        plan = self.arm.plan(goal, checks=self.params.planning_checks, cloud=cloud)
        if plan is None:
            self.mode = "error"
            return
        self.plans += 1
        self.arm.execute(plan, abort_force=self.params.force_threshold)
        self.mode = "planned"

    def update(self) -> None:
        p = self.params
        if self.mode == "error":
            self.fail("planning failed", event=Event.ERROR, plans=self.plans)
            return
        if self.elapsed > p.timeout:
            self.fail(f"target not reached after {p.timeout} s", event=Event.TIMEOUT)
            return
        goal = self.goals[self.k]
        cur = self.r.frame_pose(self.ee_frame)
        self.f = f = low_pass(self.f, self.wrench_in("world")[:3], p.filter_hz, 1.0 / p.rate_hz)
        if self.mode == "planned":
            if not self.arm.done():
                return
            if self.arm.status is Status.FAILURE:
                self.emit_once(Event.CONTACT, "unexpected contact during the planned motion")
                if p.guarded:
                    self.succeed(contact=1.0, force=float(np.linalg.norm(f)), **pose6(cur))
                    return
                self.fail("collision during the planned motion", force=float(np.linalg.norm(f)))
                return
            self.mode = "velocity"
            self.progress = (self.r.time, pose_error(cur, goal)[0])
        err = np.concatenate([goal[:3, 3] - cur[:3, 3], rotvec_error(goal[:3, :3], cur[:3, :3])])
        dp, dr = float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))
        last = self.k + 1 == len(self.goals)
        t0, d0 = self.progress
        settled = self.r.time - t0 >= p.stuck_time and d0 - dp < p.stuck_progress and dp <= p.settle_tolerance
        if (dp <= (p.tolerance if last else p.waypoint_tolerance) or settled) and dr <= p.rot_tolerance:
            if not last:
                self.k += 1
                self._enter_goal()
                return
            self.succeed(position_error=dp, rotation_error=dr, plans=self.plans, **pose6(cur))
            return
        v = transport_velocity(err, p.gain, f, p.force_threshold)
        if not v.any():
            self.emit_once(Event.CONTACT, f"|F| = {np.linalg.norm(f):.1f} N over the threshold")
            if p.guarded:
                self.halt()
                self.succeed(contact=1.0, force=float(np.linalg.norm(f)), **pose6(cur))
                return
            self.fail("stopped by an unexpected contact", force=float(np.linalg.norm(f)))
            return
        v[:3] += force_field(cur[:3, 3], self.obstacles, p.influence, p.repulsion)
        v = limit_velocity(v, self.vlim)
        v = limit_acceleration(v, self.v_prev, self.alim, 1.0 / p.rate_hz)
        # the arm's Cartesian controller restarts on each new twist: re-send only on a real change
        sent = self.v_prev
        if np.linalg.norm(v - sent) > 0.3 * np.linalg.norm(sent) + 1e-3:
            self.v_prev = v
            self.arm.set_twist(v)
        t0, d0 = self.progress
        if self.r.time - t0 >= p.stuck_time:
            if d0 - dp < p.stuck_progress and dp > p.planning_distance_limit:
                self.emit_once(Event.STUCK, f"local minimum {dp:.3f} m from the target: planning")
                self._plan(goal)
                return
            self.progress = (self.r.time, dp)
