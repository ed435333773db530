"""Robust grasp (thesis §3.3.1, Fig. 3.2): alignment by wrist torque (eq. 3.1), sliding grasp (eq. 3.2), finger-lost correction, force adaptation; optional levelling and search."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from scipy.spatial.transform import Rotation

from contactflow.embodiments import registry
from contactflow.embodiments.primitives.base import Capability, Primitive, PrimitiveError
from contactflow.embodiments.primitives.hands import ClosingRamp, finger_groups, held_fingers
from contactflow.embodiments.registry import GRASP_CORRECTIONS
from contactflow.embodiments.remote import RemoteError
from contactflow.nodes.status import Event


class Phase(StrEnum):
    PRESHAPE = "preshape"
    SETTLE = "settle"
    ALIGN = "align"
    SLIDE = "slide"
    REOPEN = "reopen"
    SHIFT = "shift"
    ADAPT = "adapt"


def alignment_velocity(torque_y: float, contact: bool, torque_threshold: float, vx: float, vz: float,
                       v_approach: float) -> tuple[np.ndarray, bool]:
    """Eq. 3.1 in the hand frame: (velocity, aligned). Before a contact the hand approaches at ``v_approach``."""
    if not contact:
        return np.array([0.0, 0.0, v_approach]), False
    if torque_y > torque_threshold:
        return np.array([vx, 0.0, -vz]), False
    if torque_y < -torque_threshold:
        return np.array([-vx, 0.0, -vz]), False
    return np.zeros(3), True


def contact_offset(force: np.ndarray, torque: np.ndarray, axis: np.ndarray) -> float:
    """Distance of the contact from the sensor axis ``axis`` (unit), estimated from the wrench: |tau_perp| / |F|."""
    tau = torque - (torque @ axis) * axis
    return float(np.linalg.norm(tau) / max(float(np.linalg.norm(force)), 1e-9))


def sliding_velocity(fz: float, force_threshold: float, vz: float) -> float:
    """Eq. 3.2: velocity along the hand z axis from the sensed z force (reaction on the hand)."""
    if fz <= -force_threshold:
        return -vz
    if fz >= force_threshold:
        return vz
    return 0.0


def levelled_pose(T: np.ndarray, direction: np.ndarray, pivot: np.ndarray,
                  tolerance: float) -> tuple[np.ndarray, float] | None:
    """(pose, turn in rad): ``T`` turned so the hand-frame ``direction`` points straight down (world -z), about the
    hand-frame point ``pivot``; None when it is already down or more than ``tolerance`` rad away (not a top grasp).

    A top grasp tilted by the approach error lands one side of the hand first: the fingers on
    that side press the support while the others close above the object and squeeze it out.
    The turn is the smallest one, so the yaw about the vertical is kept.
    """
    d = T[:3, :3] @ direction
    down = np.array([0.0, 0.0, -1.0])
    angle = float(np.arccos(np.clip(d @ down, -1.0, 1.0)))
    if tolerance <= 0.0 or angle < 1e-3 or angle > tolerance:
        return None
    axis = np.cross(d, down)
    R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    c = T[:3, :3] @ pivot
    goal = T.copy()
    goal[:3, :3] = R @ T[:3, :3]
    goal[:3, 3] += c - R @ c
    return goal, angle


def search_poses(T_start: np.ndarray, T_now: np.ndarray, direction: np.ndarray, xdir: np.ndarray,
                 offset: tuple[float, float]) -> list[np.ndarray]:
    """Where the hand goes to search after closing on nothing: back out along the approach to the height
    where it began (no sideways drag through what it missed), then over ``T_start`` shifted by ``offset``
    (hand-frame x, y, across the approach)."""
    R0 = T_start[:3, :3]
    d = R0 @ direction
    back = T_now.copy()
    back[:3, 3] -= ((back[:3, 3] - T_start[:3, 3]) @ d) * d
    over = T_start.copy()
    over[:3, 3] += R0 @ (offset[0] * xdir + offset[1] * np.cross(direction, xdir))
    return [back, over]


LOOK_DEPTH = 0.3
"""m below where the grasp began that a look takes in (the support and what stands on it)."""


def look_pose(points: np.ndarray, T_start: np.ndarray, pivot: np.ndarray, radius: float,
              min_size: int = 30) -> tuple[np.ndarray, float] | None:
    """(pose, distance in m): ``T_start`` shifted across (in world x, y) so its hand-frame ``pivot`` is over the top
    centre of the object nearest to where that pivot was, among the objects of the world-frame cloud ``points``
    within ``radius`` of it; None when the cloud shows none there.

    The region reaches from ``LOOK_DEPTH`` below the pivot (to take in the support under an
    approach that began well above it) to ``radius`` above it; the support is the cloud's
    dominant plane in it, the objects the clusters standing on it.
    """
    from contactflow.embodiments.primitives.detect_objects import TOP_BAND, segment_scene

    g = T_start[:3, :3] @ pivot + T_start[:3, 3]
    region = np.concatenate([g - (radius, radius, LOOK_DEPTH), g + radius])
    _, clusters = segment_scene(points, region, min_size=min_size)
    if not clusters:
        return None
    tops = []
    for c in clusters:
        top = c.points[c.points[:, 2] >= c.points[:, 2].max() - TOP_BAND]
        tops.append(top[:, :2].mean(axis=0))
    d = [float(np.linalg.norm(t - g[:2])) for t in tops]
    k = int(np.argmin(d))
    if d[k] > radius:
        return None
    goal = T_start.copy()
    goal[:2, 3] += tops[k] - g[:2]
    return goal, d[k]


class RobustGrasp(Primitive):
    """Reactive grasp: approach along the grasp direction, centre on the object, close while sliding, adapt force.

    Per embodiment: the finger-lost correction needs a multi-finger hand with tactile pads
    on its two external fingers (F1, F3 of Fig. 3.2); a parallel gripper skips it. Three
    corrections the thesis does not have are off by default: levelling a tilted top grasp
    before the descent, and, after a close that holds nothing, looking for the object with a
    camera and searching beside the start.
    """

    requires = Capability(ft=True, hand=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT, Event.GRASP_STABLE)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        pregrasp_type: str = ""  # hand preshape before the grasp ("" = current configuration)
        pregrasp_size: float = -1.0  # 0..1 hand opening before the grasp (< 0: not set)
        force_threshold: float = 2.0  # N, contact detection with the F/T
        torque_threshold: float = 5.0  # N m, alignment torque threshold (sensor dependent, §3.3.1)
        grasp_direction: tuple[float, ...] = (0.0, 0.0, 1.0)  # hand frame, approach direction
        max_distance: float = 0.2  # m, travel along the grasp direction looking for a contact
        correction_velocity: float = 0.005  # m/s, alignment and sliding corrections (Vx, Vz)
        approach_velocity: float = 0.04  # m/s, forward motion before the first contact (not given in the thesis)
        max_alignment: float = 0.04  # m, lateral travel of the alignment before giving up on it
        alignment_probe: float = 0.01  # m, lateral travel after which the contact must have come closer to the hand axis (else it is the support: slide)
        closing_velocity: float = 0.8  # rad/s (m/s for a gripper), finger closing during the sliding grasp
        pressing_closing_velocity: float = -1.0  # rad/s (m/s), finger closing while eq. 3.2 backs off the support (< 0: closing_velocity)
        grasp_effort: float = 0.5  # 0..1 finger force limit while closing
        final_effort: float = 1.0  # 0..1 finger force limit after force adaptation
        finger_lost_shift: float = 0.025  # m, shift toward the contacts (Fig. 3.2 uses 5 cm on the SDH2; half the allegro finger spacing here)
        max_regrasps: int = 2  # finger-lost corrections before accepting the grasp
        min_contacts: int = 2  # pads in contact for a grasp to count as holding the object
        alignment: bool = True  # enable the alignment phase (eq. 3.1)
        alignment_axes: str = "x"  # "x": eq. 3.1 (torque about hand y moves along x); "xy": also torque about x moves along y
        sliding: bool = True  # enable the sliding correction (eq. 3.2)
        finger_lost: bool = True  # finger-lost correction: part of the primitive in the thesis (Fig. 3.2); needs a multi-finger hand
        level_tolerance: float = 0.0  # rad, a grasp direction within this angle of straight down is turned straight down before the approach (objects rest on level supports; 0: off, as in the thesis)
        level_pivot: tuple[float, ...] = ()  # m, hand-frame point kept in place while levelling (where the hand holds an object; empty: the robot's grasp centre for pregrasp_type)
        search_offsets: tuple[float, ...] = ()  # m, hand-frame (x, y) pairs: after a close that holds nothing, descend again shifted by the next pair (none in the thesis)
        search_camera: str = ""  # camera that looks for the object after a close that holds nothing, before the search_offsets ("": none; not in the thesis)
        search_radius: float = 0.2  # m, how far from where the grasp began a look finds the object
        max_looks: int = 2  # looks after closes on nothing (each followed by a descent over the object it saw)
        self_margin: float = 0.02  # m, a look ignores points this close to the robot's own spherical model
        settle_speed: float = 0.02  # rad/s, the arm's joints move slower than this for settle_time before the F/T is tared (0: tare at once)
        settle_time: float = 0.1  # s of stillness before the tare
        settle_timeout: float = 2.0  # s the arm may take to come to rest before the tare is taken anyway

    def begin(self) -> None:
        p = self.params
        d = np.asarray(p.grasp_direction, dtype=np.float64)
        if d.shape != (3,) or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"{self.name}: params.grasp_direction must be a non-zero 3-vector, got {p.grasp_direction}")
        self.dir = d / np.linalg.norm(d)
        # x of eq. 3.1: the hand x axis made orthogonal to the grasp direction
        x = np.array([1.0, 0.0, 0.0]) - self.dir[0] * self.dir
        self.xdir = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-6 else np.array([0.0, 1.0, 0.0])
        self.spec = self.r.spec.hand(self.hand_name)
        self._check_corrections()
        self.groups = finger_groups(self.spec)
        self.closed = np.asarray(self.spec.preshapes["closed"], dtype=np.float64)
        pivot = p.level_pivot or registry.home(self.r.spec.name).center(p.pregrasp_type)
        if len(pivot) != 3:
            raise ValueError(f"{self.name}: params.level_pivot must be a 3-vector (or empty), got {p.level_pivot}")
        self.pivot = np.asarray(pivot, dtype=np.float64)
        if len(p.search_offsets) % 2:
            raise ValueError(f"{self.name}: params.search_offsets must hold (x, y) pairs, got {len(p.search_offsets)} numbers")
        self.T_start: np.ndarray | None = None
        self.levelled = 0.0
        self._goals: list[np.ndarray] = []
        self._shift_time = 0.0
        self.searches = 0
        self.looks = 0
        self._offsets_used = 0
        self._look_next = False
        self.regrasps = 0
        self.aligns = 0
        self.slides = 0
        self.slides_back = 0
        self.lateral = 0.0
        self.support_contacts = 0
        self._probe: tuple[float, float] | None = None
        self._ramp: ClosingRamp | None = None
        self._contact_seen = False
        self._t_phase = self.r.time
        if p.pregrasp_type:
            self.hand.preshape(p.pregrasp_type)
        elif p.pregrasp_size >= 0.0:
            opened = np.asarray(self.spec.preshapes["open"], dtype=np.float64)
            s = float(np.clip(p.pregrasp_size, 0.0, 1.0))
            self.hand.set_fingers(self.closed + s * (opened - self.closed))
        self._levelling = self._level()
        self.phase = Phase.PRESHAPE

    # -- helpers -------------------------------------------------------------------------
    def _level(self) -> bool:
        """Start turning a nearly downward grasp direction straight down; False when there is nothing to turn."""
        p = self.params
        T = self.r.frame_pose(self.ee_frame)
        levelled = levelled_pose(T, self.dir, self.pivot, p.level_tolerance)
        if levelled is None:
            return False
        goal, self.levelled = levelled
        self.arm.move_pose(goal, speed=0.05)
        return True

    def _to(self, phase: Phase) -> None:
        self.phase, self._t_phase = phase, self.r.time

    def _twist(self, v_hand: np.ndarray) -> None:
        self.twist(np.concatenate([v_hand, np.zeros(3)]), frame=self.ee_frame)

    def _wound_up(self, *args, **kwargs) -> bool:
        stuck = super()._wound_up(*args, **kwargs)
        if stuck and self.phase in (Phase.PRESHAPE, Phase.SETTLE):
            # the levelling turn pressed a finger on the object: stop the turn where the arm is and go on
            # (waiting for rest made this a failure: 4 of 100 trials with error, grasp bench trials 3-12)
            self.relax()
            self._stuck_since = None
            return False
        return stuck

    def _settle(self) -> None:
        """Wait for the arm to come to rest before the tare: a sensor tared while the hand still swings
        from the last move keeps the swing's inertial force as an offset (after a levelling turn, ~2 N:
        the contact threshold, so the grasp closed on air 5-12 cm above the object)."""
        self._still_since: float | None = None
        self._to(Phase.SETTLE)

    def _still(self) -> bool:
        p = self.params
        if p.settle_speed <= 0.0:
            return True
        if float(np.abs(self.arm.qd()).max()) >= p.settle_speed:
            self._still_since = None
            return False
        if self._still_since is None:
            self._still_since = self.r.time
        return self.r.time - self._still_since >= p.settle_time

    def _start_align(self) -> None:
        self.r.tare_ft(self.arm_name)
        if self.T_start is None:
            self.T_start = self.r.frame_pose(self.ee_frame).copy()
        self.p0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        self.x0 = self.p0.copy()
        self._probe = None
        self._to(Phase.ALIGN)

    def _start_slide(self) -> None:
        self.halt()
        q = self.hand.positions()
        self._ramp = ClosingRamp(q, self.closed, self.params.closing_velocity)
        self._to(Phase.SLIDE)

    # -- control -------------------------------------------------------------------------
    def update(self) -> None:
        p = self.params
        dt = 1.0 / p.rate_hz
        if self.phase is Phase.PRESHAPE:
            if (self.hand.done() and (not self._levelling or self.arm.done())) or self.r.time - self._t_phase > 2.0:
                self._settle()
            return
        if self.phase is Phase.SETTLE:
            if self._still() or self.r.time - self._t_phase > p.settle_timeout:
                self._start_align()
            return
        if self.phase is Phase.ALIGN:
            w = self.wrench_in(self.ee_frame)
            f = w[:3]
            contact = bool(np.linalg.norm(f) > p.force_threshold) or bool(self.pads_in_contact())
            if contact and not self._contact_seen:
                self._contact_seen = True
                self.emit_once(Event.CONTACT, "grasp approach touched")
            pos = self.r.frame_pose(self.ee_frame)[:3, 3]
            R = self.r.frame_pose(self.ee_frame)[:3, :3]
            travelled = float((pos - self.p0) @ (R @ self.dir))
            self.lateral = float(np.linalg.norm((pos - self.x0) - ((pos - self.x0) @ (R @ self.dir)) * (R @ self.dir)))
            ydir = np.cross(self.dir, self.xdir)
            ty = float(w[3:] @ ydir)
            tx = float(w[3:] @ self.xdir)
            if not p.alignment:
                stuck = self.blocked()
                if stuck:
                    self.relax()
                if contact or travelled >= p.max_distance or stuck:
                    self._start_slide()
                else:
                    self._twist(self.dir * p.approach_velocity)
                return
            v, aligned = alignment_velocity(ty, contact, p.torque_threshold, p.correction_velocity,
                                            p.correction_velocity, p.approach_velocity)
            vy = 0.0
            if "y" in p.alignment_axes:
                # same law about the other axis: a contact at +y gives a negative torque about x
                u, aligned_y = alignment_velocity(-tx, contact, p.torque_threshold, p.correction_velocity,
                                                  p.correction_velocity, p.approach_velocity)
                vy = u[0]
                aligned = aligned and aligned_y
                if v[0] == 0.0 and vy != 0.0:
                    v = u * np.array([0.0, 0.0, 1.0])
            if self.blocked():
                self.relax()
                self._start_slide()
                return
            if aligned or travelled >= p.max_distance or self.lateral >= p.max_alignment:
                self._start_slide()
                return
            if v[0] != 0.0 or vy != 0.0:
                self.aligns += 1
                if self._support_contact(f, w[3:]):
                    self.support_contacts += 1
                    self._start_slide()
                    return
            self._twist(v[0] * self.xdir + vy * ydir + v[2] * self.dir)
            return
        if self.phase is Phase.SLIDE:
            assert self._ramp is not None
            fz = float(self.wrench_in(self.ee_frame)[:3] @ self.dir)
            vz = sliding_velocity(fz, p.force_threshold, p.correction_velocity) if p.sliding else 0.0
            # "light contact with the supporting plane": fingers closing faster than the hand backs off press it
            self._ramp.speed = p.pressing_closing_velocity if vz < 0.0 and p.pressing_closing_velocity >= 0.0 \
                else p.closing_velocity
            target = self._ramp.advance(dt)
            self.hand.set_fingers(target, effort=p.grasp_effort)
            if p.sliding:
                if vz != 0.0:
                    self.slides += 1
                    self.slides_back += int(vz < 0.0)
                if self.blocked():
                    vz = 0.0
                    self.relax()
                self._twist(self.dir * vz)
            stalled = self._ramp.observe(self.r.time, self.hand.positions())
            if (stalled and self.r.time - self._t_phase > 0.3) or self.r.time - self._t_phase > 6.0:
                self.halt()
                if self._finger_lost():
                    return
                self.hand.close(effort=p.final_effort)
                self._to(Phase.ADAPT)
            return
        if self.phase is Phase.REOPEN:
            if self.hand.done() or self.r.time - self._t_phase > 1.0:
                self._next_goal()
            return
        if self.phase is Phase.SHIFT:
            if self.arm.done() or self.r.time - self._t_phase > self._shift_time:
                if self._look_next:
                    self._look_next = False
                    self._look()
                    return
                if self._goals:
                    self._next_goal()
                    return
                self._contact_seen = False
                self._settle()
            return
        if self.phase is Phase.ADAPT and (self.hand.done() or self.r.time - self._t_phase > 1.0):
            pads = self.pads_in_contact()
            need = min(p.min_contacts, len(self.groups))
            held = len(held_fingers(self.hand.positions(), self.closed, self.groups, pads)) >= need
            vals = dict(contacts=len(pads), alignments=self.aligns, slides=self.slides, slides_back=self.slides_back,
                        regrasps=self.regrasps, lateral=self.lateral, support_contacts=self.support_contacts)
            vals.update(searches=self.searches, looks=self.looks, levelled=self.levelled)
            if held:
                self.emit_once(Event.GRASP_STABLE, f"pads in contact: {pads}", vals)
                self.succeed(f"grasped with {pads}", **vals)
            elif not self._search():
                self.fail(f"hand closed without holding (pads in contact: {pads})", **vals)

    def _support_contact(self, f: np.ndarray, tau: np.ndarray) -> bool:
        """True when eq. 3.1 cannot centre the contact: its estimated offset from the hand axis did not shrink
        by half the lateral travel of the last ``alignment_probe``.

        An object edge off the axis comes closer as the hand moves toward it; the table under the hanging
        thumb stays under the thumb, so the alignment would creep ``max_alignment`` away from the object.
        The sliding grasp (Fig. 3.5a: the hand touching the support) takes over. An object lying along a
        finger link looks the same and also goes to the sliding grasp.
        """
        p = self.params
        if np.linalg.norm(f) <= p.force_threshold:
            return False
        offset = contact_offset(f, tau, self.dir)
        if self._probe is None:
            self._probe = (self.lateral, offset)
            return False
        moved = self.lateral - self._probe[0]
        if moved < p.alignment_probe:
            return False
        if self._probe[1] - offset < 0.5 * moved:
            return True
        self._probe = (self.lateral, offset)
        return False

    def _check_corrections(self) -> None:
        """Refuse a correction the embodiment does not allow (its ``capabilities.grasp_corrections``)."""
        p = self.params
        caps = getattr(self.r.spec, "capabilities", None)
        allowed = set(caps.grasp_corrections if caps is not None else GRASP_CORRECTIONS)
        if self.spec.kind != "multi_finger":
            allowed.discard("finger_lost")
        for name in ("alignment", "sliding", "finger_lost"):
            if getattr(p, name) and name not in allowed:
                raise PrimitiveError(f"{self.name}: params.{name}: {self.r.spec.name}'s {self.spec.kind} hand "
                                     f"{self.hand_name!r} allows only {sorted(allowed)} (capabilities.grasp_corrections)")

    def _finger_lost(self) -> bool:
        """Fig. 3.2 F1/F3: one external finger without contact → open, shift toward the contacts, retry."""
        p = self.params
        pads = [pd.name for pd in self.spec.pads]
        if not (p.finger_lost and len(pads) >= 3
                and self.regrasps < p.max_regrasps):
            return False
        # a finger touches when its pad senses or the object holds it open (joint configuration)
        q = self.hand.positions()
        touching = set(self.pads_in_contact()) | {
            f for f, idx in self.groups.items() if np.abs(q[idx] - self.closed[idx]).max() > 0.15}
        f1, f2, f3 = pads[0], pads[1], pads[2]
        # the object sits under one external finger only: the middle finger missed it too
        if (f1 in touching) == (f3 in touching) or f2 in touching:
            return False
        lost, kept = (f1, f3) if f3 in touching else (f3, f1)
        tips = dict(zip(pads, self.spec.fingertips, strict=False))
        a = self.r.frame_pose(tips[kept])[:3, 3]
        b = self.r.frame_pose(tips[lost])[:3, 3]
        T = self.r.frame_pose(self.ee_frame)
        d = T[:3, :3].T @ (a - b)
        d -= (d @ self.dir) * self.dir
        if np.linalg.norm(d) < 1e-6:
            return False
        shift = T[:3, :3] @ (d / np.linalg.norm(d) * p.finger_lost_shift - self.dir * 0.02)
        goal = T.copy()
        goal[:3, 3] += shift
        self.regrasps += 1
        if self.io is not None:
            self.io.log(f"finger lost: {lost} without contact, shifting toward {kept}")
        self._reopen([goal])
        return True

    def _search(self) -> bool:
        """The hand closed on nothing: reopen, back out, and descend again over the object a look finds
        (``search_camera``, up to ``max_looks``) or else over the start shifted by the next of
        ``search_offsets``; False when neither is left."""
        p = self.params
        if self.T_start is None:
            return False
        back, _ = search_poses(self.T_start, self.r.frame_pose(self.ee_frame), self.dir, self.xdir, (0.0, 0.0))
        if p.search_camera and self.looks < p.max_looks:
            self.looks += 1
            self.searches += 1
            self._look_next = True  # once backed out, clear of the object
            self._reopen([back])
            return True
        over = self._offset_goal()
        if over is None:
            return False
        self.searches += 1
        self._reopen([back, over])
        return True

    def _offset_goal(self) -> np.ndarray | None:
        """Over the start shifted by the next unused pair of ``search_offsets``; None when none is left."""
        p = self.params
        k = 2 * self._offsets_used
        if k + 1 >= len(p.search_offsets) or self.T_start is None:
            return None
        self._offsets_used += 1
        offset = (p.search_offsets[k], p.search_offsets[k + 1])
        if self.io is not None:
            self.io.log(f"closed on nothing: search at {offset[0]:+.3f}, {offset[1]:+.3f} m")
        return search_poses(self.T_start, self.r.frame_pose(self.ee_frame), self.dir, self.xdir, offset)[1]

    def _look(self) -> None:
        """Backed out after a close on nothing: look for the object with ``search_camera`` and go over it
        (the closing fingers push objects 5-15 cm); over the next search offset when the look shows nothing."""
        p = self.params
        assert self.T_start is not None
        try:
            frame = self.r.camera(p.search_camera)
        except RemoteError as exc:  # no frame came: the look sees nothing, the offsets remain
            if self.io is not None:
                self.io.log(f"closed on nothing: look {self.looks} failed ({exc})")
            self.looks = p.max_looks  # a camera that did not answer is not asked again this grasp
            frame = None
        pts = np.asarray(frame.points) if frame is not None else np.zeros((0, 3))
        model = getattr(self.r, "spherical", None)
        if model is not None and len(pts):
            pts = pts[model.clear_of(pts, p.self_margin)]  # the arm and hand are not the object
        found = look_pose(pts, self.T_start, self.pivot, p.search_radius)
        if found is not None:
            goal, d = found
            if self.io is not None:
                self.io.log(f"closed on nothing: look {self.looks} sees an object {100 * d:.1f} cm from the start")
            self._goals = [goal]
        else:
            over = self._offset_goal()
            if over is None:
                self.fail(f"hand closed without holding; look {self.looks} sees no object within "
                          f"{p.search_radius:g} m of the start", searches=self.searches, looks=self.looks)
                return
            self._goals = [over]
        self._next_goal()

    def _reopen(self, goals: list[np.ndarray]) -> None:
        """Open to the preshape, then visit ``goals`` (controlled-frame poses) before approaching again."""
        self._goals = list(goals)
        if self.params.pregrasp_type:
            self.hand.preshape(self.params.pregrasp_type)
        else:
            self.hand.open()
        self._to(Phase.REOPEN)

    def _next_goal(self) -> None:
        goal = self._goals.pop(0)
        speed = 0.05
        dist = float(np.linalg.norm(goal[:3, 3] - self.r.frame_pose(self.ee_frame)[:3, 3]))
        self._shift_time = dist / speed + 1.5
        self.arm.move_pose(goal, speed=speed)
        self._to(Phase.SHIFT)
