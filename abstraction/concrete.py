"""The last step of translation: the factory's parameters in each primitive's own vocabulary.

Factories speak in ATD terms (a target point, an approach direction, a standoff, a motion
type, grasp forces in N); the simulated primitives take poses ``[x, y, z, roll, pitch,
yaw]`` of the hand's grasp frame, an arm name, thresholds named as in thesis ch. 3. This
runner wraps a primitive runner and converts a node's parameters once they are bound (task
parameters such as an object location are only known when the node is entered).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from contactflow.nodes.taskengine import PrimitiveRunner, RunnerEvent

HAND_KEYS = ("target", "approach", "standoff", "waypoints", "motion", "keep_orientation", "obstacles",
             "hand_shape", "stop_force", "stop_sensor", "filter_hz")
DOWN = (0.0, 0.0, -1.0)


def grasp_pose(xyz: np.ndarray, yaw: float = np.pi / 2) -> list[float]:
    """Grasp frame at ``xyz`` with its approach axis (z) pointing down: ``[x, y, z, r, p, y]``."""
    return [float(xyz[0]), float(xyz[1]), float(xyz[2]), float(np.pi), 0.0, float(yaw - np.pi / 2)]


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


def concretize(type_: str, params: Mapping[str, Any], arms: list[str], max_opening: float = 0.1,
               last_arm: str = "", hand_at: Callable[[str], np.ndarray] | None = None) -> dict[str, Any]:
    """Primitive parameters for ``type_`` from a factory's parameter set.

    ``hand_at(arm)`` gives the hand's current position: a push goes from there to the target.
    """
    p = dict(params)
    target = _vec(p.get("target"))
    approach = _vec(p.get("approach"))
    approach = approach / np.linalg.norm(approach) if approach is not None and np.linalg.norm(approach) > 0 else None
    out: dict[str, Any] = {"arm": p.pop("arm", "") or last_arm or choose_arm(arms, target)}
    standoff = float(p.get("standoff", 0.0) or 0.0)
    if type_ in ("move_to", "transport"):
        if target is not None:
            goal = target - standoff * (approach if approach is not None else np.asarray(DOWN))
            out["target"] = grasp_pose(goal)
        waypoints = p.get("waypoints") or []
        if type_ == "transport" and len(waypoints) >= 6:
            pts = np.asarray(waypoints, dtype=np.float64).reshape(-1, 3)[:-1]
            out["waypoints"] = [v for q in pts for v in grasp_pose(q)]
        if type_ == "transport" and p.get("obstacles"):
            boxes = np.asarray(p["obstacles"], dtype=np.float64).reshape(-1, 6)
            out["obstacles"] = [float(v) for b in boxes for v in b[:3]]
        if type_ == "move_to":
            out["planning"] = p.get("motion", "free") == "free"
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
        d = target - hand_at(out["arm"])
        d[2] = 0.0  # pushes slide the object on its support
        if np.linalg.norm(d) > 1e-3:
            out.update(direction=[float(v) for v in d / np.linalg.norm(d)], distance=float(np.linalg.norm(d)))
    elif type_ == "place":
        if "contact_threshold" in p:
            out["force_threshold"] = float(p["contact_threshold"])
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
                 log: Callable[[str], None] | None = None) -> None:
        self.inner = inner
        self.hand_at = hand_at
        self.arms = arms
        self.max_opening = max_opening
        self.log = log
        self._arm = ""  # the arm of the last arm primitive: grasps and releases follow it

    def start(self, instance: str, type: str, params: Mapping[str, Any]) -> None:
        concrete = concretize(type, params, self.arms, self.max_opening, last_arm=self._arm, hand_at=self.hand_at)
        if type in ("move_to", "transport") and "target" in concrete:
            self._arm = concrete["arm"]
        if self.log is not None:
            self.log(f"{instance}: {type} {concrete}")
        self.inner.start(instance, type, concrete)

    def stop(self, instance: str) -> None:
        self.inner.stop(instance)

    def poll(self) -> list[RunnerEvent]:
        return self.inner.poll()
