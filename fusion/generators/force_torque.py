"""Force-torque hypotheses generator (thesis §4.4.3, eq. 4.8-4.9): single-contact, uniform law.

A wrench (f, τ) measured at the sensor is explained by a force f applied anywhere on the line
{d : d × f = τ} (eq. 4.8). Following eq. 4.9, for each axis a with a usable force component
the coordinate d_a is sampled across the hand's bounding box expanded by a margin and the two
other coordinates are solved from two of the equations, giving up to three (ideally equal)
lines. Points away from the robot surface are dropped (App. B distance), and so, optionally,
are points where the force would pull the surface outwards. The n voxels left each get
likelihood 1/n (eq. 4.1), or optionally a share weighted by the distance law of eq. 4.5. Force and torque are in the sensor frame, torque about its origin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.fusion.generators.base import GeneratorModule, array_of
from contactflow.fusion.geometry import DistanceFn, distance_fn, gradient
from contactflow.fusion.hypotheses import VOXEL_SIZE, Hypotheses, HypothesisType, voxelize
from contactflow.nodes.messages import Array, Vector
from contactflow.nodes.module import Port
from contactflow.nodes.status import Status


@dataclass(frozen=True)
class ForceTorqueParams:
    rate_hz: float = 100.0  # Hz
    robot: str = "robot"
    min_force: float = 1.0  # N, smaller wrenches are no contact (sensor noise)
    min_axis_force: float = 0.3  # N, eq. 4.9 divides by f_a: smaller components are not used
    box_lo: tuple[float, ...] = (-0.06, -0.06, 0.0)  # m, hand bounding box in the sensor frame
    box_hi: tuple[float, ...] = (0.06, 0.06, 0.2)  # m
    box_margin: float = 0.02  # m, expansion of the bounding box
    surface_band: float = 0.01  # m, keep points this close to the robot surface
    inward_only: bool = True  # drop points where f would pull the surface outwards
    surface_lambda: float = 0.0  # m, > 0: weight points by eq. 4.5 on their distance to the
    # surface (likelihood 0.5 at this distance), normalised to 1; 0: uniform 1/n (thesis)
    step: float = 0.0025  # m, sampling step of d_a (half a voxel)
    voxel_size: float = VOXEL_SIZE  # m


def wrench_lines(force: np.ndarray, torque: np.ndarray, lo: np.ndarray, hi: np.ndarray, step: float,
                 min_axis_force: float) -> np.ndarray:
    """Points (sensor frame) of the eq. 4.9 lines inside the box [lo, hi]."""
    f, tau = np.asarray(force, dtype=float), np.asarray(torque, dtype=float)
    out = []
    for a in range(3):
        if abs(f[a]) < min_axis_force:
            continue
        b, c = (a + 1) % 3, (a + 2) % 3
        s = np.arange(lo[a], hi[a] + step / 2, step)
        d = np.empty((s.size, 3))
        d[:, a] = s
        d[:, b] = (f[b] * s - tau[c]) / f[a]  # from tau_c = d_a f_b - d_b f_a
        d[:, c] = (tau[b] + f[c] * s) / f[a]  # from tau_b = d_c f_a - d_a f_c
        out.append(d)
    if not out:
        return np.zeros((0, 3))
    pts = np.concatenate(out)
    inside = np.all((pts >= lo) & (pts <= hi), axis=1)
    return pts[inside]


def ft_hypotheses(force: np.ndarray, torque: np.ndarray, T_world_sensor: np.ndarray, distance: DistanceFn,
                  stamp: float, params: ForceTorqueParams | None = None) -> Hypotheses:
    """Hypotheses from one wrench (sensor frame); ``distance`` is the posed robot model."""
    p = params or ForceTorqueParams()
    f = np.asarray(force, dtype=float).reshape(3)
    tau = np.asarray(torque, dtype=float).reshape(3)
    T = np.asarray(T_world_sensor, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"force_torque: T_world_sensor has shape {T.shape}, expected (4, 4)")
    fn = float(np.linalg.norm(f))
    if fn < p.min_force:
        return Hypotheses.empty(stamp)
    lo = np.asarray(p.box_lo, dtype=float) - p.box_margin
    hi = np.asarray(p.box_hi, dtype=float) + p.box_margin
    d = wrench_lines(f, tau, lo, hi, p.step, p.min_axis_force)
    if d.shape[0] == 0:
        return Hypotheses.empty(stamp)
    R, t = T[:3, :3], T[:3, 3]
    pts = d @ R.T + t
    dist = distance(pts)
    near = np.abs(dist) <= p.surface_band
    pts, dist = pts[near], dist[near]
    f_world = R @ f
    if p.inward_only and pts.shape[0]:
        inward = gradient(distance, pts) @ f_world < 0.0
        pts, dist = pts[inward], dist[inward]
    if pts.shape[0] == 0:
        return Hypotheses.empty(stamp)
    lam = p.surface_lambda
    weight = lam * lam / (lam * lam + dist * dist) if lam > 0 else np.ones(pts.shape[0])
    h = voxelize(Hypotheses.make(pts, weight, HypothesisType.REGULAR, fn, f_world / fn, stamp, where="force_torque"),
                 p.voxel_size, reduce="max")
    return Hypotheses(h.location, h.likelihood / h.likelihood.sum(), h.kind, h.force, h.direction, stamp)


class ForceTorqueGenerator(GeneratorModule):
    """Wrist wrench to contact hypotheses along its line of action (eq. 4.8-4.9)."""

    Params = ForceTorqueParams
    inputs = (
        Port("wrench", Vector, "[fx, fy, fz, tx, ty, tz], N and N·m, sensor frame, torque about its origin"),
        Port("sensor_pose", Array, "(4, 4) world pose of the sensor frame"),
        Port("robot_model", Array, "(m, 8) posed bi-spheres [c1, r1, c2, r2], world"),
    )

    def step(self) -> Status:
        assert self.io is not None
        pose = self.io.latest("sensor_pose")
        model = array_of(self.io.latest("robot_model"), "robot_model", 8, self.name)
        wrenches = self.io.take("wrench")
        if pose is None or model is None or not wrenches:
            return Status.RUNNING
        T = pose.array.numpy().astype(float)  # type: ignore[attr-defined]
        msg = wrenches[-1]
        w = np.asarray(msg.values, dtype=float)  # type: ignore[attr-defined]
        if w.shape != (6,):
            raise ValueError(f"{self.name}: input 'wrench' has {w.size} values, expected 6")
        h = ft_hypotheses(w[:3], w[3:], T, distance_fn(model), self.stamp_of(msg), self.params)
        self.publish_cloud(h)
        return Status.RUNNING
