"""Explore (Table 3.1): move the hand along a direction or a sweep of waypoints and stop at the first contact."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, hand_pose_for, pose6
from contactflow.embodiments.primitives.fused import ContactSensorParams, SensesFusedContacts
from contactflow.nodes.status import Event


class Explore(SensesFusedContacts, Primitive):
    """Guarded sweep: straight along ``direction`` (world) or through ``sweep`` points until a contact.

    With ``alternate`` points, a coin flip (``seed`` and the start time) picks which of the two
    sweeps this pass runs, so a task that sweeps again after a failed grasp does not always meet
    the same object first.

    A contact above ``floor_z`` (a known support such as a box bottom, told apart by
    proprioception, §3.4.3) is an object: SUCCESS with the approach pose that puts the hand's
    grasp centre over the contact, moved ``lead`` m further along the horizontal motion (where
    the object is). The contact is located on the wrist wrench's line of action (eq. 4.8):
    where it leaves the hand's ``footprint`` through the side leading the motion, or without a
    footprint its point nearest the controlled frame; a contact sensed by the pads alone is at
    the touching pads. A contact on the support or a finished sweep ends with OBJECT_NOT_FOUND
    (FAILURE). With ``sensor: fused`` the sweep stops on a new contact the robot's fusion places on
    the hand instead of on its own reading of the wrist and pads (and reports where the fusion puts
    it, ``fused_x``, ``_y``, ``_z``); the contact is located as above.
    """

    requires = Capability(ft=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT, Event.OBJECT_DETECTED, Event.OBJECT_NOT_FOUND)

    @dataclass(frozen=True)
    class Params(ContactSensorParams, Primitive.Params):
        direction: tuple[float, ...] = (0.0, 0.0, -1.0)  # world, used when no sweep is given
        sweep: tuple[float, ...] = ()  # flat [x, y, z, ...] points (world) to visit in order
        force_threshold: float = 2.0  # N, contact threshold
        velocity: float = 0.03  # m/s
        max_distance: float = 0.3  # m, along ``direction``
        floor_z: float = -1.0  # m, contacts at or below this height are on the known support
        floor_margin: float = 0.015  # m
        lead: float = 0.03  # m, the object's centre is this far beyond the contact along the horizontal motion
        footprint: tuple[float, ...] = ()  # m, [lo x, y, z, hi x, y, z] box of the hand in the controlled frame
        locate_force: float = 1.0  # N, weaker wrenches do not locate the contact (the pads do)
        preshape: str = ""  # hand preshape while exploring ("" = keep; Fig. 3.26a uses a compact one)
        alternate: tuple[float, ...] = ()  # flat [x, y, z, ...] (world): a second sweep, run instead of ``sweep`` on a coin flip
        seed: int = 0  # the coin flip's seed (with the start time): a repeated search does not always meet the same contact first

    def begin(self) -> None:
        p = self.params
        for field in ("sweep", "alternate"):
            if len(getattr(p, field)) % 3:
                raise ValueError(f"{self.name}.params.{field}: expected a multiple of 3 values, got {len(getattr(p, field))}")
        self.flipped = bool(p.alternate) and np.random.default_rng((p.seed, round(self.r.time * 1000))).random() < 0.5
        pts = np.asarray(p.alternate if self.flipped else p.sweep, dtype=np.float64)
        self.points = list(pts.reshape(-1, 3))
        if p.footprint and len(p.footprint) != 6:
            raise ValueError(f"{self.name}.params.footprint: expected [lo x, y, z, hi x, y, z], got {list(p.footprint)}")
        d = np.asarray(p.direction, dtype=np.float64)
        if not self.points and (d.shape != (3,) or np.linalg.norm(d) < 1e-9):
            raise ValueError(f"{self.name}: params.direction must be a non-zero 3-vector, got {p.direction}")
        self.d = d / max(np.linalg.norm(d), 1e-9)
        self.r.tare_ft(self.arm_name)
        self.p0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        if p.preshape and self.hand_name:
            self.hand.preshape(p.preshape)
        self._ready = not (p.preshape and self.hand_name)
        self.k = 0
        self._dir: np.ndarray | None = None
        if p.sensor == "fused":
            self.start_fused()

    def update(self) -> None:
        p = self.params
        if not self._ready:
            if not (self.hand.done() or self.elapsed > 1.0):
                return
            self._ready = True
            self.r.tare_ft(self.arm_name)
            self.p0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        T = self.r.frame_pose(self.ee_frame)
        pos = T[:3, 3]
        moving = self._dir if self._dir is not None else self.d
        told = self.sensed_contact("fused", moving)
        if told is not None:
            self.halt()
            on_floor = bool(pos[2] <= p.floor_z + p.floor_margin) and abs(float(moving[2])) > 0.7
            self.emit_once(Event.CONTACT, f"explored into a contact{self.told_by()}", {"on_floor": float(on_floor)})
            at = self.locate(T, moving)
            # approach pose: the hand's grasp centre over the object, ``lead`` beyond the contact
            there = T.copy()
            there[:3, 3] = at
            ahead = np.array([moving[0], moving[1], 0.0])
            if np.linalg.norm(ahead) > 0.3:
                there[:3, 3] += ahead / np.linalg.norm(ahead) * p.lead
            vals = pose6(hand_pose_for(self.r.spec.name, there))
            vals.update(contact_x=float(at[0]), contact_y=float(at[1]), contact_z=float(at[2]),
                        object_x=float(there[0, 3]), object_y=float(there[1, 3]),  # the grasp centre's spot
                        on_floor=float(on_floor), waypoint=float(self.k), alternate=float(self.flipped), **told)
            if on_floor:
                self.fail("touched the support, no object here", event=Event.OBJECT_NOT_FOUND, **vals)
            else:
                self.emit_once(Event.OBJECT_DETECTED, "contact above the support", vals)
                self.succeed(**vals)
            return
        if self.fusion_silent():  # ends the sweep: finishing holds the arm where it is
            return
        if self.points:
            goal = self.points[self.k]
            err = goal - pos
            if np.linalg.norm(err) < 0.005:
                self.k += 1
                if self.k >= len(self.points):
                    self.fail("sweep finished without a contact", event=Event.OBJECT_NOT_FOUND, waypoint=float(self.k),
                              alternate=float(self.flipped))
                    return
                goal = self.points[self.k]
                err = goal - pos
            d = err / max(np.linalg.norm(err), 1e-9)
            speed = min(p.velocity, 2.0 * float(np.linalg.norm(err)) + 0.005)
        else:
            if float((pos - self.p0) @ self.d) >= p.max_distance:
                self.fail(f"no contact within {p.max_distance} m", event=Event.OBJECT_NOT_FOUND)
                return
            d, speed = self.d, p.velocity
        if self._dir is None or float(d @ self._dir) < 0.95 or abs(speed - self._speed) > 0.3 * self._speed:
            self._dir, self._speed = d, speed
            self.twist(np.concatenate([d * speed, np.zeros(3)]))

    def locate(self, T: np.ndarray, moving: np.ndarray) -> np.ndarray:
        """Where the hand touched (world): on the wrench's line of action, else at the touching pads."""
        p = self.params
        w = self.r.ft(self.arm_name)
        f, tau = np.asarray(w.force, dtype=np.float64), np.asarray(w.torque, dtype=np.float64)
        fn = float(np.linalg.norm(f))
        if fn < p.locate_force:
            pads = set(self.pads_in_contact())
            links = [pad.link for pad in self.r.spec.hand(self.hand_name).pads if pad.name in pads] if pads else []
            if not links:
                return T[:3, 3].copy()
            return np.mean([self.r.frame_pose(k)[:3, 3] for k in links], axis=0)
        return wrench_contact(f, tau, self.r.frame_pose(w.frame)[:3, 3], T, moving, p.footprint)


def wrench_contact(force: np.ndarray, torque: np.ndarray, origin: np.ndarray, T_hand: np.ndarray,
                   moving: np.ndarray, footprint: tuple[float, ...] = ()) -> np.ndarray:
    """A single contact's point (world) from the wrench on the hand (world axes, torque about ``origin``).

    The force acts somewhere on the line {x : (x - origin) x f = torque}. With the hand's
    ``footprint`` box (controlled frame ``T_hand``) the point is where the line crosses the
    box face leading ``moving``; otherwise, or when the line runs along that face, it is the
    line's point nearest the controlled frame's origin.
    """
    f = np.asarray(force, dtype=np.float64)
    u = f / np.linalg.norm(f)
    p0 = np.asarray(origin, dtype=np.float64) + np.cross(f, np.asarray(torque, dtype=np.float64)) / float(f @ f)
    R, c = T_hand[:3, :3], T_hand[:3, 3]
    nearest = p0 + float((c - p0) @ u) * u
    if len(footprint) != 6:
        return nearest
    lo, hi = np.asarray(footprint[:3], dtype=np.float64), np.asarray(footprint[3:], dtype=np.float64)
    a, d, m = R.T @ (p0 - c), R.T @ u, R.T @ np.asarray(moving, dtype=np.float64)
    k = int(np.argmax(np.abs(m)))
    if abs(d[k]) < 0.3:
        return nearest
    face = hi[k] if m[k] > 0 else lo[k]
    local = np.clip(a + (face - a[k]) / d[k] * d, lo, hi)
    return c + R @ local
