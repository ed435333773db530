"""Finger bookkeeping shared by the grasp primitives: joint groups per finger, closing ramps, stall detection."""

from __future__ import annotations

import numpy as np


def finger_groups(spec) -> dict[str, np.ndarray]:
    """Indices of the actuated joints of each finger, keyed by its tactile pad name.

    A multi-finger hand with four joints per pad (allegro: index, middle, ring, thumb) maps
    each pad to its four joints; otherwise every pad shares all joints (parallel gripper).
    """
    n = len(spec.joints)
    pads = [p.name for p in spec.pads]
    if spec.kind == "multi_finger" and pads and n % len(pads) == 0:
        k = n // len(pads)
        return {p: np.arange(i * k, (i + 1) * k) for i, p in enumerate(pads)}
    return {p: np.arange(n) for p in pads} or {"all": np.arange(n)}


class ClosingRamp:
    """Finger targets moving from their start toward ``goal`` at ``speed`` (rad/s or m/s).

    Fingers can be frozen (naive grasp: stop each finger that touches); stall detection tells
    when the measured fingers stopped moving although their targets still lead.
    """

    def __init__(self, start: np.ndarray, goal: np.ndarray, speed: float, stall_window: float = 0.2,
                 stall_motion: float = 0.01) -> None:
        self.target = np.asarray(start, dtype=np.float64).copy()
        self.goal = np.asarray(goal, dtype=np.float64)
        self.speed = speed
        self.frozen = np.zeros(len(self.target), bool)
        self._window, self._motion = stall_window, stall_motion
        self._ref: tuple[float, np.ndarray] | None = None
        self.stalled = False

    def freeze(self, idx: np.ndarray, at: np.ndarray) -> None:
        self.target[idx] = at[idx]
        self.frozen[idx] = True

    def advance(self, dt: float) -> np.ndarray:
        step = self.speed * dt
        move = np.clip(self.goal - self.target, -step, step)
        move[self.frozen] = 0.0
        self.target = self.target + move
        return self.target

    @property
    def reached(self) -> bool:
        return bool(np.all(self.frozen | (np.abs(self.goal - self.target) < 1e-6)))

    def observe(self, t: float, q: np.ndarray) -> bool:
        """Feed measured positions; True once they moved less than ``stall_motion`` over the window."""
        if self._ref is None:
            self._ref = (t, q.copy())
            return False
        t0, q0 = self._ref
        if t - t0 >= self._window:
            self.stalled = bool(np.abs(q - q0).max() < self._motion)
            self._ref = (t, q.copy())
        return self.stalled


def blocked_fingers(q: np.ndarray, target: np.ndarray, groups: dict[str, np.ndarray], margin: float = 0.15) -> int:
    """Fingers held open by an object: some joint stays ``margin`` short of its commanded ``target`` (joint-configuration check).

    ``target`` must be what the fingers are driven to (the closed preshape after a full close);
    a finger whose own target holds it open is not blocked by anything.
    """
    seen: set[tuple[int, ...]] = set()
    n = 0
    for idx in groups.values():
        key = tuple(int(i) for i in idx)
        if key in seen:
            continue
        seen.add(key)
        n += int(np.abs(q[idx] - target[idx]).max() > margin)
    return n


def held_fingers(q: np.ndarray, target: np.ndarray, groups: dict[str, np.ndarray], pads: list[str],
                 margin: float = 0.15) -> set[str]:
    """Fingers on the object: the pad senses a contact, or the finger is held ``margin`` short of its ``target``.

    The thesis's "joint configuration or contact information" per finger, so a grasp with the
    thumb pad on the object and the index wrapped around it counts two fingers. Fingers sharing
    their joints (a gripper's jaws) count once by configuration.
    """
    held = set(pads)
    seen: set[tuple[int, ...]] = set()
    for name, idx in groups.items():
        key = tuple(int(i) for i in idx)
        if key in seen:
            continue
        seen.add(key)
        if np.abs(q[idx] - target[idx]).max() > margin:
            held.add(name)
    return held


def held_center(robot, arm: str, margin: float = 0.15, contact: float = 0.05) -> np.ndarray | None:
    """Where the object held by ``arm``'s closed multi-finger hand sits, in the arm's controlled frame (m).

    Told by the joint configuration or contact information (thesis §3.3.1): the object is
    between the thumb and the fingers on it (a pad senses it, or it holds the finger open,
    short of the closed preshape), so its centre is taken midway between the thumb's tip and
    the mean tip of those fingers. Ask it while the hand holds what a grasp closed on; None for
    a hand without a thumb, or when no finger is on the object.
    """
    spec = robot.spec.hand(robot.spec.arm(arm).hand)
    pads = [p.name for p in spec.pads]
    if spec.kind != "multi_finger" or "thumb" not in pads or len(spec.fingertips) != len(pads):
        return None
    groups = finger_groups(spec)
    q = robot.hand(spec.name).positions()
    closed = np.asarray(spec.preshapes["closed"], dtype=np.float64)
    tip = dict(zip(pads, spec.fingertips, strict=True))
    touching = [p for p, v in robot.tactile(spec.name).items() if float(v.max(initial=0.0)) > contact]
    held = sorted(held_fingers(q, closed, groups, touching, margin) - {"thumb"})
    if not held:
        return None
    T_inv = np.linalg.inv(robot.frame_pose(robot.spec.arm(arm).ee_frame))
    at = {p: (T_inv @ robot.frame_pose(tip[p]))[:3, 3] for p in [*held, "thumb"]}
    return 0.5 * (at["thumb"] + np.mean([at[p] for p in held], axis=0))
