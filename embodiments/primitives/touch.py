"""Touch (§6.3.6): move the arm forward (hand frame) until a contact is sensed: by the F/T or the pads, or by the fusion."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, pose6
from contactflow.embodiments.primitives.fused import ContactSensorParams, SensesFusedContacts
from contactflow.nodes.status import Event


class Touch(SensesFusedContacts, Primitive):
    """Guarded motion along ``direction`` until contact; reports the contact pose.

    ``sensor: own`` stops on the wrist's force over ``force_threshold`` or a pad in contact;
    ``sensor: fused`` on a contact the robot's fusion places on the hand (of ``region``) that was
    not there when the motion began, and reports where it lies (``contact_x``, ``_y``, ``_z``).
    """

    requires = Capability(ft=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT)

    @dataclass(frozen=True)
    class Params(ContactSensorParams, Primitive.Params):
        direction: tuple[float, ...] = (0.0, 0.0, 1.0)  # unit vector in ``frame``
        frame: str = "hand"  # "hand" (controlled frame) or "world"
        force_threshold: float = 2.0  # N
        velocity: float = 0.03  # m/s
        max_distance: float = 0.2  # m

    def direction_world(self) -> np.ndarray:
        d = np.asarray(self.params.direction, dtype=np.float64)
        if d.shape != (3,) or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"{self.name}: params.direction must be a non-zero 3-vector, got {self.params.direction}")
        d = d / np.linalg.norm(d)
        if self.params.frame == "hand":
            return self.r.frame_pose(self.ee_frame)[:3, :3] @ d
        if self.params.frame != "world":
            raise ValueError(f"{self.name}: params.frame must be 'hand' or 'world', got {self.params.frame!r}")
        return d

    def begin(self) -> None:
        self.d = self.direction_world()
        self.r.tare_ft(self.arm_name)
        self.p0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        if self.params.sensor == "fused":
            self.start_fused()

    def update(self) -> None:
        p = self.params
        T = self.r.frame_pose(self.ee_frame)
        travelled = float((T[:3, 3] - self.p0) @ self.d)
        at = self.sensed_contact("contact", self.d)
        if at is not None:
            self.emit_once(Event.CONTACT, f"touched{self.told_by()}", at)
            self.succeed(travelled=travelled, **pose6(T), **at)
            return
        if self.fusion_silent():
            return
        if travelled >= p.max_distance:
            self.fail(f"no contact within {p.max_distance} m", travelled=travelled)
            return
        self.twist(np.concatenate([self.d * p.velocity, np.zeros(3)]))
