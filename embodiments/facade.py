"""What every robot facade shares (in-process ``SimRobot``, ``RemoteRobot`` over the key space): parts by name, frames, arm commands."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from contactflow.nodes.status import Status


class RobotFacade(ABC):
    """Arm and hand handles by name, and frames at the measured joints of the facade's ``kin`` model.

    A subclass sets ``name``, ``spec``, ``kin``, ``_arms`` and ``_hands`` and brings ``kin`` to
    the measured joints in ``_sync_kin``.
    """

    name: str
    spec: Any
    kin: Any
    _arms: dict[str, Any]
    _hands: dict[str, Any]

    @abstractmethod
    def _sync_kin(self) -> None:
        """Bring ``kin`` to the measured joints."""

    @abstractmethod
    def kin_q_cmd(self) -> np.ndarray:
        """The model's joints: measured, with each arm at its commanded joints (where plans and their goal IK start,
        and the grasp filters' reachability with them)."""

    def arm(self, name: str):
        try:
            return self._arms[name]
        except KeyError:
            raise KeyError(f"robot {self.name}: no arm {name!r} (arms: {list(self._arms)})") from None

    def hand(self, name: str):
        try:
            return self._hands[name]
        except KeyError:
            raise KeyError(f"robot {self.name}: no hand {name!r} (hands: {list(self._hands)})") from None

    @property
    def arms(self) -> list[str]:
        return list(self._arms)

    @property
    def hands(self) -> list[str]:
        return list(self._hands)

    def finger_positions(self, hand: str) -> np.ndarray:
        return self.hand(hand).positions()

    def frame_pose(self, frame: str, relative_to: str = "world") -> np.ndarray:
        """Pose of any link, fixed frame or task frame at the measured joint state."""
        self._sync_kin()
        return self.kin.frame_pose(frame, relative_to)

    def camera_pose(self, name: str = "kinect") -> np.ndarray:
        """World pose of a camera's optical frame at the measured joint state."""
        spec = self.spec.camera(name)
        return self.frame_pose(spec.link) @ spec.optical_in_link()

    @property
    def spherical(self):
        """The posed spherical model (App. B) at the measured joints."""
        from contactflow.embodiments.spherical import SphericalModel

        if not hasattr(self, "_spherical"):
            self._spherical = SphericalModel.from_urdf(self.kin, str(self.spec.urdf()))
        self._sync_kin()
        self._spherical.update(self.kin)
        return self._spherical


class ArmFacade(ABC):
    """An arm of a facade: its commands go to the arm's controllers (``ctl``, an
    :class:`~contactflow.embodiments.control.arm.ArmController`), which the facade's robot steps.

    A subclass sets ``robot``, ``spec``, ``name``, ``joints`` and ``ctl``, and says whether the
    robot has failed (a command to a failed robot fails at once).
    """

    robot: Any
    spec: Any
    name: str
    joints: tuple[str, ...]
    ctl: Any

    @property
    @abstractmethod
    def _failed(self) -> bool:
        """The robot has failed."""

    def _path(self, waypoints: np.ndarray) -> np.ndarray:
        """The joint path a move follows (a subclass may clip it to the joint limits)."""
        return np.atleast_2d(np.asarray(waypoints, dtype=np.float64))

    @property
    def status(self) -> Status:
        return self.ctl.status

    @property
    def abort_reason(self) -> str:
        return self.ctl.abort_reason

    def done(self) -> bool:
        return self.status in (Status.SUCCESS, Status.FAILURE)

    def ee_pose(self, frame: str = "world") -> np.ndarray:
        return self.robot.frame_pose(self.spec.ee_frame, frame)

    def stop(self) -> None:
        """Hold the current commanded position."""
        self.ctl.stop()

    def set_joint_target(self, q: np.ndarray) -> None:
        """Immediate joint position target (no interpolation)."""
        self.move_joints(q, speed=1e6)

    def move_joints(self, q: np.ndarray, speed: float | None = None) -> None:
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (len(self.joints),):
            raise ValueError(f"arm {self.name}: move_joints needs {len(self.joints)} values, got shape {q.shape}")
        self.execute_waypoints(q[None], speed=speed, abort_force=np.inf)

    def execute_waypoints(self, waypoints: np.ndarray, speed: float | None = None, abort_force: float = 8.0) -> None:
        """Follow joint waypoints; abort when the F/T force changes by more than ``abort_force`` N."""
        w = self._path(waypoints)
        if w.ndim != 2 or w.shape[1] != len(self.joints) or not len(w):
            raise ValueError(f"arm {self.name}: waypoints need shape (k, {len(self.joints)}), got {w.shape}")
        self.ctl.execute_waypoints(w, speed, abort_force, self._failed)

    def execute(self, plan: Any, abort_force: float = 8.0, speed: float | None = None) -> None:
        """Execute a :class:`~contactflow.embodiments.control.planning.Plan` (or a waypoint array)."""
        self.execute_waypoints(getattr(plan, "waypoints", plan), speed=speed, abort_force=abort_force)

    def move_pose(self, T: np.ndarray, frame: str = "world", speed: float = 0.1) -> None:
        self.ctl.move_pose(np.asarray(T, dtype=np.float64), frame, speed, self._failed)

    def set_twist(self, twist: np.ndarray, frame: str = "world", duration: float | None = None) -> None:
        self.ctl.set_twist(np.asarray(twist, dtype=np.float64), frame, duration, self._failed)

    def set_wrench(self, wrench: np.ndarray, frame: str = "world") -> None:
        self.ctl.set_wrench(np.asarray(wrench, dtype=np.float64), frame, self._failed)

    def guarded_move(self, twist: np.ndarray, frame: str = "world", max_force: float = 5.0,
                     duration: float | None = None) -> None:
        """Move at ``twist`` until the wrist force changes by ``max_force`` N (SUCCESS + CONTACT)."""
        self.ctl.guarded_move(np.asarray(twist, dtype=np.float64), frame, max_force, duration, self._failed)

    def plan(self, goal: np.ndarray, planner: str = "KPIECE1", timeout: float = 2.0, checker: str = "coal",
             obstacles: tuple = (), cloud: np.ndarray | None = None, rest: bool = False, checks: int = 0):
        """OMPL plan from the current commanded joints to a joint goal or a 4x4 pose of the controlled frame.

        Collision-checked against the given ``obstacles`` (planning ``Obstacle`` records) and
        point ``cloud`` (N, 3) plus the cell's fixtures (the table): what the caller sensed.
        With ``rest`` a pose goal's joints are solved from the home posture; a search ends at ``timeout`` s or,
        with ``checks``, after that many state checks (see ``plan_arm``).
        """
        from contactflow.embodiments.control.planning import plan_arm

        return plan_arm(self.robot, self, goal, planner=planner, timeout=timeout, checker=checker,
                        obstacles=obstacles, cloud=cloud, rest=rest, checks=checks)
