"""The last step of translation: the factory's parameters in each primitive's own vocabulary.

Factories speak in ATD terms (a target point, an approach direction, a standoff, a motion
type, grasp forces in N); the simulated primitives take poses ``[x, y, z, roll, pitch,
yaw]`` of the hand's grasp frame, an arm name, thresholds named as in thesis ch. 3. This
runner wraps a primitive runner and converts a node's parameters once they are bound (task
parameters such as an object location are only known when the node is entered).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from contactflow.nodes.status import Event
from contactflow.nodes.taskengine import PrimitiveRunner, RunnerEvent

DOWN = (0.0, 0.0, -1.0)
LINE_SPEED = 0.05  # m/s, guarded straight-line moves
LINE_TURN = 0.5  # rad/s
CARRY_FORCE = 10.0  # N, least unexpected-contact threshold of a guarded path
SIDE_CLEARANCE = 0.03  # m, gap between the hand and an object it approaches from the side
PUSH_HEIGHT = 0.02  # m, the hand's lowest point above the pushed object's bottom
GRASPS = ("robust_grasp", "naive_grasp", "close_until_force", "close_until_stall")
"""Primitives after whose success the hand holds an object (until a release)."""


def top_down(yaw: float) -> np.ndarray:
    """Rotation of a grasp frame whose approach axis (z) points down, turned by ``yaw`` (see grasp_pose)."""
    c, s = np.cos(yaw - np.pi / 2), np.sin(yaw - np.pi / 2)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def grasp_pose(xyz: np.ndarray, yaw: float = np.pi / 2) -> list[float]:
    """Grasp frame at ``xyz`` with its approach axis (z) pointing down: ``[x, y, z, r, p, y]``."""
    return [float(xyz[0]), float(xyz[1]), float(xyz[2]), float(np.pi), 0.0, float(yaw - np.pi / 2)]


def pose_list(xyz: np.ndarray, R: np.ndarray) -> list[float]:
    """``[x, y, z, roll, pitch, yaw]`` (fixed axes, as URDF) of a position and rotation."""
    rpy = Rotation.from_matrix(R).as_euler("xyz")
    return [float(v) for v in xyz[:3]] + [float(v) for v in rpy]


def side_orientations(d: np.ndarray) -> list[np.ndarray]:
    """Hand orientations for meeting an object along horizontal ``d``: pointing down, or pointing along ``d``."""
    base = float(np.arctan2(d[1], d[0]))
    down = [top_down(base + k * np.pi / 2) for k in range(4)]
    side = np.array([-d[1], d[0], 0.0])
    along = [np.column_stack([x, np.cross(d, x), d])
             for x in (np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0]), side, -side)]
    return down + along


@dataclass(frozen=True, eq=False)
class HandGeometry:
    """Where a hand is around its controlled frame: points of its surface and its grasp centre (m)."""

    points: np.ndarray  # (N, 3) m, wrist, sensor and open hand in the controlled frame
    grasp_center: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m, where a grasped object sits

    def offsets(self, R: np.ndarray) -> np.ndarray:
        """The points as world offsets from the frame origin for frame rotation ``R``."""
        return np.asarray(self.points, dtype=np.float64) @ np.asarray(R).T

    def band(self, R: np.ndarray, below: float | None = None) -> np.ndarray:
        """Offsets of the parts lower than ``below`` m (relative to the frame; all when None)."""
        o = self.offsets(R)
        if below is None:
            return o
        low = o[o[:, 2] <= below]
        return low if len(low) else o[[int(np.argmin(o[:, 2]))]]

    def reach(self, R: np.ndarray, direction: np.ndarray, below: float | None = None) -> float:
        """How far the hand extends along horizontal ``direction``."""
        return float(np.max(self.band(R, below) @ direction))

    def lateral(self, R: np.ndarray, direction: np.ndarray, below: float | None = None) -> tuple[float, float]:
        """The hand's extent to the right and left of a motion along ``direction`` (min, max)."""
        side = self.band(R, below) @ np.array([-direction[1], direction[0], 0.0])
        return float(side.min()), float(side.max())

    def lowest(self, R: np.ndarray) -> float:
        """Depth of the hand's lowest point below its frame origin (m)."""
        return float(-np.min(self.offsets(R)[:, 2]))

    def frame_for_center(self, center: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Frame position that puts the grasp centre at ``center``."""
        return np.asarray(center, dtype=np.float64) - np.asarray(R) @ np.asarray(self.grasp_center)

    def pusher(self, d: np.ndarray, size: np.ndarray, toward: np.ndarray | None = None) -> tuple[np.ndarray, float]:
        """Orientation and frame height (above the object's bottom) to push an object of ``size`` along ``d``.

        The parts of the hand at the object's height must cover its middle; among those, the
        narrowest swept path wins, then the side that keeps the hand's bulk toward ``toward``.
        """
        width = float(np.abs(np.array([-d[1], d[0], 0.0])) @ size)
        best: tuple[tuple, np.ndarray, float] | None = None
        for R in side_orientations(d):
            height = PUSH_HEIGHT + self.lowest(R)
            lo, hi = self.lateral(R, d, size[2] - height)
            if lo > -width / 4 or hi < width / 4:
                continue  # the low parts would miss the object
            bulk = 0.0
            if toward is not None:
                t = np.asarray(toward, dtype=np.float64)
                t = t - (t @ d) * d
                bulk = -float(np.mean(self.offsets(R)[:, :2] @ t[:2]))
            score = (round(max(-lo, hi), 2), round(bulk, 2), round(self.reach(R, d, size[2] - height), 3))
            if best is None or score < best[0]:
                best = (score, R, height)
        if best is None:
            R = top_down(float(np.arctan2(d[1], d[0])))
            return R, PUSH_HEIGHT + self.lowest(R)
        return best[1], best[2]

def _vec(v: Any, n: int = 3) -> np.ndarray | None:
    if isinstance(v, list | tuple) and len(v) >= n and all(isinstance(a, int | float) for a in v[:n]):
        return np.asarray(v[:n], dtype=np.float64)
    return None


def choose_arm(arms: list[str], target: np.ndarray | None) -> str:
    """The arm on the target's side (left arms at +y, right at -y); the only arm otherwise."""
    if target is None or len(arms) == 1:
        return arms[0]
    side = "left" if target[1] >= 0 else "right"
    return next((a for a in arms if a.startswith(side)), arms[0])


def _approach_goal(target: np.ndarray, approach: np.ndarray, standoff: float, size: np.ndarray | None,
                   hand: HandGeometry | None, current: np.ndarray | None) -> list[float]:
    """Grasp-frame pose from which the hand reaches the object at ``target`` along ``approach``.

    From above: ``standoff`` over the object with the grasp centre on its axis. From the side
    (a horizontal approach): a pushing posture (see :meth:`HandGeometry.pusher`), a clearance
    away from the object's face, its lowest point just above the object's bottom.
    """
    horizontal = np.array([approach[0], approach[1], 0.0])
    if hand is None:
        return grasp_pose(target - standoff * approach)
    if abs(approach[2]) >= 0.7 or np.linalg.norm(horizontal) < 1e-6:
        R = top_down(np.pi / 2)
        return pose_list(hand.frame_for_center(target - standoff * approach, R), R)
    d = horizontal / np.linalg.norm(horizontal)
    if size is None:
        R = top_down(float(np.arctan2(d[1], d[0])))
        return pose_list(target - max(standoff, SIDE_CLEARANCE + hand.reach(R, d)) * d, R)
    toward = current[:3, 3] - target if current is not None else None
    R, height = hand.pusher(d, size, toward)
    goal = target - (float(np.abs(d) @ size) / 2 + SIDE_CLEARANCE + hand.reach(R, d, size[2] - height)) * d
    goal[2] = target[2] - size[2] / 2 + height
    return pose_list(goal, R)


def _explicit_goal(target: np.ndarray, size: np.ndarray | None, hand: HandGeometry | None,
                   current: np.ndarray | None, pushing: bool) -> list[float]:
    """Grasp-frame pose for an explicit target: where a held object goes, or where a pushed one ends.

    The hand keeps its orientation. Holding, the grasp centre goes to the target; pushing, the
    hand stops where its leading face has brought the object's centre to the target.
    """
    R = current[:3, :3] if current is not None else top_down(np.pi / 2)
    if hand is None:
        return pose_list(target, R)
    if pushing and current is not None:
        d = target - current[:3, 3]
        d[2] = 0.0
        if np.linalg.norm(d) > 1e-6:
            d /= np.linalg.norm(d)
            half, below = 0.0, None
            if size is not None:
                half = float(np.abs(d) @ size) / 2
                below = target[2] + size[2] / 2 - current[2, 3]
            goal = target - (hand.reach(R, d, below) + half) * d
            goal[2] = current[2, 3]
            return pose_list(goal, R)
    return pose_list(hand.frame_for_center(target, R), R)

def concretize(type_: str, params: Mapping[str, Any], arms: list[str], max_opening: float = 0.1,
               last_arm: str = "", hand_at: Callable[[str], np.ndarray] | None = None,
               hands: Mapping[str, HandGeometry] | None = None) -> dict[str, Any]:
    """Primitive parameters for ``type_`` from a factory's parameter set.

    ``hand_at(arm)`` gives the controlled frame's current pose (4x4): a push goes from there to
    the target. ``hands`` gives each arm's hand geometry: approach poses keep the hand off the object.
    """
    p = dict(params)
    target = _vec(p.get("target"))
    approach = _vec(p.get("approach"))
    approach = approach / np.linalg.norm(approach) if approach is not None and np.linalg.norm(approach) > 0 else None
    size = _vec(p.get("size"))
    out: dict[str, Any] = {"arm": p.pop("arm", "") or last_arm or choose_arm(arms, target)}
    hand = (hands or {}).get(out["arm"])
    standoff = float(p.get("standoff", 0.0) or 0.0)
    line = p.get("motion") == "line"
    if type_ in ("move_to", "transport"):
        current = np.asarray(hand_at(out["arm"]), dtype=np.float64) if hand_at is not None else None
        if target is not None and approach is not None:
            out["target"] = _approach_goal(target, approach, standoff, size, hand, current)
        elif target is not None:
            out["target"] = _explicit_goal(target, size, hand, current, bool(p.get("pushes")))
        waypoints = p.get("waypoints") or []
        if type_ == "transport" and len(waypoints) >= 6:
            pts = np.asarray(waypoints, dtype=np.float64).reshape(-1, 3)[:-1]
            out["waypoints"] = [v for q in pts for v in grasp_pose(q)]
        if type_ == "transport" and p.get("obstacles"):
            boxes = np.asarray(p["obstacles"], dtype=np.float64).reshape(-1, 6)
            out["obstacles"] = [float(v) for b in boxes for v in b[:3]]
        if type_ == "transport" and line:
            out["velocity_limits"] = [LINE_SPEED] * 3 + [LINE_TURN] * 3  # straight and slow: no planner
        if type_ == "move_to":
            out["planning"] = p.get("motion", "free") == "free"
        if line and "stop_force" in p and not p.get("pushes"):
            # a guarded move stops on contact (the wrist F/T tells it; tactile stops use it too). Going to
            # an object or down onto a surface, the contact is the goal; on a free path it is a fault,
            # judged above the jolts a carried load gives
            until_contact = approach is not None or bool(p.get("until_contact"))
            force = float(p["stop_force"]) if p.get("stop_sensor") == "wrist_ft" else max(3.0, float(p["stop_force"]))
            out["guarded"] = until_contact
            out["force_threshold" if type_ == "transport" else "abort_force"] = (
                force if until_contact else max(force, CARRY_FORCE))
        if p.get("hand_shape"):
            out["preshape"] = str(p["hand_shape"])
    elif type_ in ("robust_grasp", "naive_grasp"):
        corrections = set(p.get("corrections") or [])
        out["pregrasp_type"] = "open"
        if type_ == "robust_grasp" and "pregrasp_size" in p:
            out["pregrasp_size"] = float(min(1.0, max(0.0, float(p["pregrasp_size"]) / max_opening)))
        if type_ == "robust_grasp" and corrections:
            out.update(alignment="alignment" in corrections, sliding="sliding" in corrections,
                       finger_lost="finger_lost" in corrections)
    elif type_ == "close_until_force":
        if "grasp_force" in p:
            out["grip_force"] = float(p["grasp_force"]) / 2.0  # the factory's force is the total of two pads
    elif type_ == "push" and target is not None and hand_at is not None:
        T = np.asarray(hand_at(out["arm"]), dtype=np.float64)
        d = target - T[:3, 3]
        d[2] = 0.0  # pushes slide the object on its support
        if np.linalg.norm(d) > 1e-3:
            dist = float(np.linalg.norm(d))
            d = d / dist
            if hand is not None and size is not None:
                # the hand's face meets the object after its reach and the object's half size
                below = target[2] + size[2] / 2 - T[2, 3]
                dist -= hand.reach(T[:3, :3], d, below) + float(np.abs(d) @ size) / 2
            out.update(direction=[float(v) for v in d], distance=max(dist, 0.01))
    elif type_ == "place":
        if "contact_threshold" in p:
            out["force_threshold"] = float(p["contact_threshold"])
        if "filter_hz" in p:
            out["filter_hz"] = float(p["filter_hz"])
    elif type_ == "slide":
        if target is not None:
            out["target"] = [float(v) for v in target]
    elif type_ == "release":
        out["hand_target"] = 1.0
    elif type_ == "wait_event":
        out.update({k: p[k] for k in ("event",) if k in p})
        out["finish"] = False
    elif type_ == "hold":
        out["effort"] = 1.0
    return out


class ConcreteRunner:
    """A :class:`PrimitiveRunner` that converts bound factory parameters, then delegates."""

    def __init__(self, inner: PrimitiveRunner, arms: list[str], max_opening: float = 0.1,
                 hand_at: Callable[[str], np.ndarray] | None = None,
                 log: Callable[[str], None] | None = None,
                 hands: Mapping[str, HandGeometry] | None = None,
                 held_at: Callable[[str], np.ndarray | None] | None = None) -> None:
        self.inner = inner
        self.hand_at = hand_at
        self.hands = dict(hands or {})
        self.held_at = held_at
        self.arms = arms
        self.max_opening = max_opening
        self.log = log
        self._arm = ""  # the arm of the last arm primitive: grasps and releases follow it
        self._started: dict[str, tuple[str, str]] = {}  # instance -> (type, arm)
        self._holding: set[str] = set()  # arms whose last grasp succeeded and that released nothing since

    def start(self, instance: str, type: str, params: Mapping[str, Any]) -> None:
        hands = self.hands
        arm = params.get("arm") or self._arm
        if type in ("transport", "place") and arm in self._holding and arm in hands and self.held_at is not None:
            center = self.held_at(arm)  # where the object sits in this grasp, not where grasps usually put it
            if center is not None:  # across the approach axis; along it the place primitive finds the surface
                xy = (float(center[0]), float(center[1]), float(hands[arm].grasp_center[2]))
                hands = {**hands, arm: replace(hands[arm], grasp_center=xy)}
        concrete = concretize(type, params, self.arms, self.max_opening, last_arm=self._arm, hand_at=self.hand_at,
                              hands=hands)
        if type in ("move_to", "transport") and "target" in concrete:
            self._arm = concrete["arm"]
        if type in ("release", *GRASPS):
            self._holding.discard(concrete["arm"])
        self._started[instance] = (type, concrete["arm"])
        if self.log is not None:
            self.log(f"{instance}: {type} {concrete}")
        self.inner.start(instance, type, concrete)

    def stop(self, instance: str) -> None:
        self.inner.stop(instance)

    def poll(self) -> list[RunnerEvent]:
        events = self.inner.poll()
        for e in events:
            type_, arm = self._started.get(e.instance, ("", ""))
            if type_ in GRASPS and e.event is Event.SUCCESS:
                self._holding.add(arm)
        return events
