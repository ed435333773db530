"""The last step of translation: a node's goal, in task terms, turned into hand poses when it starts.

A factory gives each primitive its typed ``Params`` and a :class:`Goal` in ATD terms (a
target point, an approach direction, a standoff, the object's size, waypoints, obstacles).
Where the hand must go depends on what is only known when the node is entered: the bound
object location, the hand's current pose, where a held object sits in the hand. This runner
wraps a primitive runner and turns the goal into the primitive's pose fields (``[x, y, z,
roll, pitch, yaw]`` of the hand's grasp frame, the arm, a push direction and distance).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from contactflow.nodes.params import ParamError, replace_params
from contactflow.nodes.registry import UnknownModuleType, resolve
from contactflow.nodes.status import Event
from contactflow.nodes.taskengine import PrimitiveRunner, RunnerEvent
from contactflow.nodes.taskgraph import NodeKind, TaskGraph

DOWN = (0.0, 0.0, -1.0)
LINE_SPEED = 0.05  # m/s, guarded straight-line moves
LINE_TURN = 0.5  # rad/s
SIDE_CLEARANCE = 0.03  # m, gap between the hand and an object it approaches from the side
PUSH_HEIGHT = 0.02  # m, the hand's lowest point above the pushed object's bottom
GRASPS = ("robust_grasp", "naive_grasp", "close_until_force", "close_until_stall")
"""Primitives after whose success the hand holds an object (until a release)."""


@dataclass(frozen=True, slots=True)
class Goal:
    """Where a primitive goes, in task terms (the ESTD node's ``goal``; references bound when it starts)."""

    target: str | tuple[float, ...] = ()  # m, world point, or a ${params.X} reference to one
    approach: str | tuple[float, ...] = ()  # unit world direction toward the target, or a reference (): none
    standoff: float = 0.0  # m, the hand stops this far back along ``approach``
    size: tuple[float, ...] = ()  # m, world extents of the object: how close the hand may come
    waypoints: tuple[float, ...] = ()  # m, flat [x, y, z, ...] points passed through before the target
    obstacles: tuple[float, ...] = ()  # m, flat boxes [cx, cy, cz, sx, sy, sz, ...] a free path avoids
    pushes: bool = False  # the hand pushes the object ahead of it to the target

    def to_params(self) -> dict[str, Any]:
        """The fields that differ from the defaults, as plain values."""
        default = Goal()
        return {f.name: list(v) if isinstance(v, tuple) else v for f in fields(self)
                if (v := getattr(self, f.name)) != getattr(default, f.name)}

    @classmethod
    def of(cls, value: Any, where: str) -> Goal:
        """A goal from an ESTD node's bound ``goal`` map; ValueError naming ``where`` and the field."""
        if not isinstance(value, Mapping):
            raise ValueError(f"{where}: goal must be a map, got {type(value).__name__}")
        known = {f.name for f in fields(cls)}
        out: dict[str, Any] = {}
        for k, v in value.items():
            if k not in known:
                raise ValueError(f"{where}: goal.{k}: unknown field (known: {', '.join(sorted(known))})")
            if k == "pushes":
                if not isinstance(v, bool):
                    raise ValueError(f"{where}: goal.pushes: expected a bool, got {v!r}")
                out[k] = v
            elif k == "standoff":
                if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
                    raise ValueError(f"{where}: goal.standoff: expected a finite number, got {v!r}")
                out[k] = float(v)
            elif isinstance(v, str) and k in ("target", "approach"):
                out[k] = v
            elif isinstance(v, list | tuple) and all(isinstance(c, int | float) and not isinstance(c, bool)
                                                     and np.isfinite(c) for c in v):
                out[k] = tuple(float(c) for c in v)
            else:
                raise ValueError(f"{where}: goal.{k}: expected a list of finite numbers, got {v!r}")
        return cls(**out)


def top_down(yaw: float) -> np.ndarray:
    """Rotation of a grasp frame whose approach axis (z) points down, turned by ``yaw`` (see grasp_pose)."""
    c, s = np.cos(yaw - np.pi / 2), np.sin(yaw - np.pi / 2)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def grasp_pose(xyz: np.ndarray, yaw: float = np.pi / 2) -> list[float]:
    """Grasp frame at ``xyz`` with its approach axis (z) pointing down: ``[x, y, z, r, p, y]``."""
    return [float(xyz[0]), float(xyz[1]), float(xyz[2]), float(np.pi), 0.0, float(yaw - np.pi / 2)]


def pose_list(xyz: np.ndarray, R: np.ndarray) -> list[float]:
    """``[x, y, z, roll, pitch, yaw]`` (fixed axes, as URDF) of a position and rotation."""
    with warnings.catch_warnings():
        # a side grasp pitched by 90 degrees is gimbal-locked: scipy sets the third angle to zero and
        # folds the rotation into the first, still exactly R, and warns on every such grasp
        warnings.simplefilter("ignore", UserWarning)
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

def concretize(type_: str, params: Mapping[str, Any], arms: list[str], last_arm: str = "",
               hand_at: Callable[[str], np.ndarray] | None = None,
               hands: Mapping[str, HandGeometry] | None = None) -> dict[str, Any]:
    """A started node's primitive parameters: its ``Params`` fields, and its bound ``goal`` as hand poses.

    ``hand_at(arm)`` gives the controlled frame's current pose (4x4): a push goes from there to
    the target. ``hands`` gives each arm's hand geometry: approach poses keep the hand off the object.
    """
    out = {k: v for k, v in params.items() if k != "goal"}
    goal = Goal.of(params["goal"], type_) if "goal" in params else Goal()
    target = _vec(goal.target)
    approach = _vec(goal.approach)
    approach = approach / np.linalg.norm(approach) if approach is not None and np.linalg.norm(approach) > 0 else None
    size = _vec(goal.size)
    out["arm"] = out.get("arm") or last_arm or choose_arm(arms, target)
    hand = (hands or {}).get(out["arm"])
    if type_ in ("move_to", "transport"):
        current = np.asarray(hand_at(out["arm"]), dtype=np.float64) if hand_at is not None else None
        if target is not None and approach is not None:
            out["target"] = _approach_goal(target, approach, goal.standoff, size, hand, current)
        elif target is not None:
            out["target"] = _explicit_goal(target, size, hand, current, goal.pushes)
        if type_ == "transport" and len(goal.waypoints) >= 6:
            pts = np.asarray(goal.waypoints, dtype=np.float64).reshape(-1, 3)[:-1]
            out["waypoints"] = [v for q in pts for v in grasp_pose(q)]
        if type_ == "transport" and goal.obstacles:
            boxes = np.asarray(goal.obstacles, dtype=np.float64).reshape(-1, 6)
            out["obstacles"] = [float(v) for b in boxes for v in b[:3]]
    elif type_ == "place" and target is not None:
        # where the grasp frame is with the object resting at the target: the place slows down above it
        current = np.asarray(hand_at(out["arm"]), dtype=np.float64) if hand_at is not None else None
        out["target"] = _explicit_goal(target, size, hand, current, False)
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
    elif type_ == "slide" and target is not None:
        out["target"] = [float(v) for v in target]
    return out


def _bound_later(v: Any) -> bool:
    return isinstance(v, str) and "${" in v


def check_params(task: TaskGraph) -> list[str]:
    """Issues with the primitive parameters of ``task``'s nodes and helpers: each key a field of the
    primitive's ``Params`` with a value of its type (``goal`` a :class:`Goal`), naming node and field.

    Values that are ``${...}`` references are bound when the node starts, and checked there.
    """
    issues: list[str] = []
    for node in task.nodes.values():
        if node.kind is not NodeKind.PRIMITIVE:
            continue
        label = node.label or node.id
        for who, type_, params in ((f"state {label!r}", node.type, node.params),
                                   *((f"state {label!r}: helper {h.name!r}", h.type, h.params) for h in node.helpers)):
            where = f"{node.where}: {who}"
            try:
                cls = resolve(type_).Params
                if "goal" in params:
                    Goal.of(params["goal"], f"{where}: {type_}.params")
                replace_params(cls(), {k: v for k, v in params.items() if k != "goal" and not _bound_later(v)},
                               where=f"{where}: {type_}.params.")
            except (UnknownModuleType, ParamError, ValueError) as exc:
                issues.append(str(exc))
    return issues


class ConcreteRunner:
    """A :class:`PrimitiveRunner` that converts bound factory parameters, then delegates."""

    def __init__(self, inner: PrimitiveRunner, arms: list[str],
                 hand_at: Callable[[str], np.ndarray] | None = None,
                 log: Callable[[str], None] | None = None,
                 hands: Mapping[str, HandGeometry] | None = None,
                 held_at: Callable[[str], np.ndarray | None] | None = None) -> None:
        self.inner = inner
        self.hand_at = hand_at
        self.hands = dict(hands or {})
        self.held_at = held_at
        self.arms = arms
        self.log = log
        self._arm = ""  # the arm of the last arm primitive: grasps and releases follow it
        self._started: dict[str, tuple[str, str]] = {}  # instance -> (type, arm)
        self._holding: set[str] = set()  # arms whose last grasp succeeded and that released nothing since
        self._failed: list[RunnerEvent] = []  # nodes whose goal could not be turned into poses

    def start(self, instance: str, type: str, params: Mapping[str, Any]) -> None:
        hands = self.hands
        arm = params.get("arm") or self._arm
        if type in ("transport", "place") and arm in self._holding and arm in hands and self.held_at is not None:
            center = self.held_at(arm)  # where the object sits in this grasp, not where grasps usually put it
            if center is not None:  # across the approach axis; along it the place primitive finds the surface
                xy = (float(center[0]), float(center[1]), float(hands[arm].grasp_center[2]))
                hands = {**hands, arm: replace(hands[arm], grasp_center=xy)}
        try:
            concrete = concretize(type, params, self.arms, last_arm=self._arm, hand_at=self.hand_at, hands=hands)
        except ValueError as exc:
            self._failed.append(RunnerEvent(instance, Event.ERROR, {}, f"{type}: {exc}"))
            return
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
        events, self._failed = [*self._failed, *self.inner.poll()], []
        for e in events:
            type_, arm = self._started.get(e.instance, ("", ""))
            if type_ in GRASPS and e.event is Event.SUCCESS:
                self._holding.add(arm)
        return events
