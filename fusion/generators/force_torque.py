"""Force-torque hypotheses generator (thesis §4.4.3, eq. 4.8-4.9): single-contact, uniform law.

A wrench (f, τ) measured at the sensor is explained by a force f applied anywhere on the line
{d : d × f = τ} (eq. 4.8). Following eq. 4.9, for each axis a with a usable force component
the coordinate d_a is sampled across the hand's bounding box expanded by a margin and the two
other coordinates are solved from two of the equations, giving up to three (ideally equal)
lines. Points away from the robot surface are dropped (App. B distance), and so, optionally,
are points where the force would pull the surface outwards. The n voxels left each get
likelihood 1/n (eq. 4.1), or optionally a share weighted by the distance law of eq. 4.5. Force and torque are in the sensor frame, torque about its origin.

The shell reads the interface layer's ``Wrench`` (world axes, at the origin of
``sensor_frame``) and the posed ``RobotModel``, which carries that frame's pose; with
``links`` set, the hand's bounding box and surface come from those links' bi-spheres.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import RobotModel, Wrench
from contactflow.fusion.generators.base import GeneratorModule, capsules_of, frame_of
from contactflow.fusion.geometry import DistanceFn, distance_fn, gradient
from contactflow.fusion.hypotheses import VOXEL_SIZE, Hypotheses, HypothesisType, voxelize
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
    links: tuple[str, ...] = ()  # name prefixes of the hand links behind the sensor: the box and the
    # surface come from their bi-spheres; empty: box_lo/box_hi and the whole robot model
    link: str = ""  # link (hand) named in the published clouds


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


def hand_box(caps: np.ndarray, T_world_sensor: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Bounding box (lo, hi) in the sensor frame of the bi-spheres ``caps`` (k, 8), world frame."""
    T = np.asarray(T_world_sensor, dtype=float)
    local = (np.concatenate([caps[:, 0:3], caps[:, 4:7]]) - T[:3, 3]) @ T[:3, :3]
    r = np.concatenate([caps[:, 3], caps[:, 7]])[:, None]
    return tuple((local - r).min(axis=0).tolist()), tuple((local + r).max(axis=0).tolist())


class ForceTorqueGenerator(GeneratorModule):
    """Wrist wrench to contact hypotheses along its line of action (eq. 4.8-4.9)."""

    Params = ForceTorqueParams
    inputs = (
        Port("wrench", Wrench, "wrist wrench, world axes, torque about the origin of its sensor_frame"),
        Port("robot_model", RobotModel, "posed bi-spheres and the sensor frame's pose, world"),
    )

    def step(self) -> Status:
        assert self.io is not None
        model = self.io.latest("robot_model")
        wrenches = self.io.take("wrench")
        if model is None or not wrenches:
            return Status.RUNNING
        msg = wrenches[-1]
        assert isinstance(msg, Wrench) and isinstance(model, RobotModel)
        f_w, tau_w = np.asarray(msg.force, dtype=float), np.asarray(msg.torque, dtype=float)
        if f_w.shape != (3,) or tau_w.shape != (3,) or not (np.isfinite(f_w).all() and np.isfinite(tau_w).all()):
            raise ValueError(f"{self.name}: input 'wrench' ({msg.arm}) needs 3 finite force and 3 torque values, "
                             f"got {f_w.size} and {tau_w.size}")
        T = frame_of(model, msg.sensor_frame, self.name)
        caps = capsules_of(model, "robot_model", self.name, self.params.links)
        assert caps is not None
        params = self.params
        if params.links:
            lo, hi = hand_box(caps, T)
            params = dataclasses.replace(params, box_lo=lo, box_hi=hi)
        R = T[:3, :3]
        h = ft_hypotheses(R.T @ f_w, R.T @ tau_w, T, distance_fn(caps), self.stamp_of(msg), params)
        self.publish_cloud(h, link=self.params.link)
        return Status.RUNNING
