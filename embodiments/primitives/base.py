"""Primitive base: a reactive controller (thesis §3.3) bound to a robot facade, stepped at its rate."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from contactflow.nodes.module import Layer, Module
from contactflow.nodes.status import Event, Status


class ArmLike(Protocol):
    name: str
    spec: Any

    def ee_pose(self, frame: str = "world") -> np.ndarray: ...
    def q(self) -> np.ndarray: ...
    def qd(self) -> np.ndarray: ...
    def move_pose(self, T: np.ndarray, frame: str = "world", speed: float = 0.1) -> None: ...
    def move_joints(self, q: np.ndarray, speed: float | None = None) -> None: ...
    def set_twist(self, twist: np.ndarray, frame: str = "world", duration: float | None = None) -> None: ...
    def set_wrench(self, wrench: np.ndarray, frame: str = "world") -> None: ...
    def guarded_move(self, twist: np.ndarray, frame: str = "world", max_force: float = 5.0,
                     duration: float | None = None) -> None: ...
    def plan(self, goal: np.ndarray, planner: str = "KPIECE1", timeout: float = 2.0, checker: str = "coal",
             obstacles: tuple = (), cloud: np.ndarray | None = None, checks: int = 0) -> Any: ...
    def execute(self, plan: Any, abort_force: float = 8.0, speed: float | None = None) -> None: ...
    def stop(self) -> None: ...
    def done(self) -> bool: ...

    @property
    def status(self) -> Status: ...


class HandLike(Protocol):
    name: str
    kind: str
    joints: tuple[str, ...]
    spec: Any

    def open(self) -> None: ...
    def close(self, effort: float = 1.0) -> None: ...
    def preshape(self, name: str, effort: float = 1.0) -> None: ...
    def set_fingers(self, q: np.ndarray, effort: float = 1.0) -> None: ...
    def positions(self) -> np.ndarray: ...
    def done(self) -> bool: ...

    @property
    def effort(self) -> float: ...


class Robot(Protocol):
    """What primitives use of a robot; :class:`~contactflow.embodiments.sim_robot.SimRobot` satisfies it."""

    spec: Any
    failed: bool
    failure: str  # what stopped a failed robot (a fault, or the world holding it)
    head: Any  # HeadHandle of a robot with a pan-tilt head, else None

    @property
    def time(self) -> float: ...
    @property
    def arms(self) -> list[str]: ...
    def arm(self, name: str) -> ArmLike: ...
    def hand(self, name: str) -> HandLike: ...
    def ft(self, arm: str) -> Any: ...
    def tare_ft(self, arm: str) -> None: ...
    def tactile(self, hand: str) -> dict[str, np.ndarray]: ...
    def camera(self, name: str = "kinect") -> Any: ...
    def camera_pose(self, name: str = "kinect") -> np.ndarray: ...
    def frame_pose(self, frame: str, relative_to: str = "world") -> np.ndarray: ...
    def fixtures(self) -> list: ...


class PrimitiveError(ValueError):
    """A primitive was misconfigured or bound to a robot that lacks what it needs."""


@dataclass(frozen=True)
class Capability:
    """What a primitive requires of the embodiment (Table 3.2 "control and sensor requirements")."""

    ft: bool = False  # wrist force-torque sensor
    tactile: bool = False  # tactile pads on the hand
    hand: bool = False  # a hand on the arm
    camera: bool = False  # an RGBD camera


TACTILE_CONTACT = 0.05
"""N per taxel: a pad with a taxel above this is in contact (above the simulated noise floor)."""


class Primitive(Module):
    """Base of every manipulation primitive: arm/hand selection, timing, result events.

    Subclasses implement :meth:`begin` (first command) and :meth:`update` (one control
    step) and finish with :meth:`succeed` / :meth:`fail`, which emit the outcome event with
    numeric result ``values`` that later task nodes can bind.
    """

    abstract = True
    layer = Layer.PRIMITIVE
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR)
    requires: ClassVar[Capability] = Capability()
    commands_arm: ClassVar[bool] = True
    """False for watchers and perception: they never stop an arm another primitive drives."""
    hand_kinds: ClassVar[tuple[str, ...]] = ("multi_finger", "parallel")
    """Hand kinds the primitive supports; per-embodiment differences (§3.3) are declared here."""

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz, control loop rate
        arm: str = ""  # arm to command ("" = the robot's first arm)

    def __init__(self, name: str, params: Any = None) -> None:
        super().__init__(name, params)
        self.robot: Robot | None = None
        self.arm_name = ""
        self.hand_name = ""
        self.t0 = 0.0
        self._outcome: Status = Status.RUNNING
        self._twist_cmd: tuple[tuple[float, ...], str] | None = None

    # -- binding -------------------------------------------------------------------------
    def bind(self, robot: Robot) -> Primitive:
        """Attach the robot facade; checks the embodiment has what the primitive requires."""
        self.robot = robot
        arm = getattr(self.params, "arm", "")
        arms = list(robot.arms)
        if arm and arm not in arms:
            raise PrimitiveError(f"{self.name}: params.arm={arm!r} is not an arm of {robot.spec.name} ({arms})")
        self.arm_name = arm or arms[0]
        spec = robot.spec.arm(self.arm_name)
        self.hand_name = spec.hand
        req = self.requires
        if req.ft and not spec.ft:
            raise PrimitiveError(f"{self.name}: {type(self).__name__} needs a wrist F/T on arm {self.arm_name!r}")
        if (req.hand or req.tactile) and not self.hand_name:
            raise PrimitiveError(f"{self.name}: {type(self).__name__} needs a hand on arm {self.arm_name!r}")
        if self.hand_name:
            kind = robot.hand(self.hand_name).kind
            if (req.hand or req.tactile) and kind not in self.hand_kinds:
                raise PrimitiveError(f"{self.name}: {type(self).__name__} does not support {kind} hands "
                                     f"(supports {list(self.hand_kinds)})")
        if req.tactile and self.hand_name and not robot.spec.hand(self.hand_name).pads:
            raise PrimitiveError(f"{self.name}: {type(self).__name__} needs tactile pads on {self.hand_name!r}")
        if req.camera and not robot.spec.cameras:
            raise PrimitiveError(f"{self.name}: {type(self).__name__} needs a camera on {robot.spec.name}")
        return self

    @property
    def r(self) -> Robot:
        if self.robot is None:
            raise PrimitiveError(f"{self.name}: primitive is not bound to a robot (call bind first)")
        return self.robot

    def _hosted_robot(self) -> str:
        """The robot of a module hosted on a node ("" elsewhere: in-process runs bind a robot themselves)."""
        from contactflow.nodes.keys import SITE_ROBOT

        robot = getattr(self.io, "robot", SITE_ROBOT)
        return "" if robot == SITE_ROBOT or not hasattr(self.io, "transport") else robot

    def setup(self, io) -> None:
        super().setup(io)
        robot = self._hosted_robot()
        if robot and self.robot is None:
            from contactflow.embodiments.remote import link

            link(io.transport, io.keyspace, robot, io.node)

    def claimed_resources(self) -> tuple[str, ...]:
        """On a node, the arm a commanding primitive drives (``arm_<name>``): one primitive per arm."""
        robot = self._hosted_robot()
        if not robot or not self.commands_arm:
            return ()
        arm = getattr(self.params, "arm", "")
        if not arm:
            from contactflow.embodiments import registry
            from contactflow.embodiments.remote import link

            info = link(self.io.transport, self.io.keyspace, robot, self.io.node).info()
            arm = registry.get(info.embodiment).arms[0].name
        return (f"arm_{arm}",)

    def _bind_hosted(self) -> None:
        """On a node: bind the world's robot this module belongs to, over the key space."""
        from contactflow.embodiments.remote import RemoteError, connect

        io = self.io
        robot = self._hosted_robot()
        if io is None or not robot:
            raise PrimitiveError(f"{self.name}: primitive is not bound to a robot (host it with robot: <name>)")
        try:
            facade = connect(io.transport, io.keyspace, robot, io.node)
        except RemoteError as exc:
            raise PrimitiveError(f"{self.name}: {exc}") from None
        io.attach(f"robot/{robot}", facade)  # the node steps the robot's arm controllers after each tick
        self.bind(facade)

    @property
    def arm(self) -> ArmLike:
        return self.r.arm(self.arm_name)

    @property
    def hand(self) -> HandLike:
        return self.r.hand(self.hand_name)

    @property
    def ee_frame(self) -> str:
        return self.r.spec.arm(self.arm_name).ee_frame

    @property
    def elapsed(self) -> float:
        return self.r.time - self.t0

    # -- commands ------------------------------------------------------------------------
    def twist(self, v6: np.ndarray, frame: str = "world") -> None:
        """Cartesian velocity of the controlled frame; re-sent only when it changes.

        Re-issuing a twist restarts the arm's Cartesian controller from rest, so a loop that
        sends the same velocity every step would crawl.
        """
        key = (tuple(np.round(np.asarray(v6, dtype=np.float64), 6)), frame)
        if key == self._twist_cmd:
            return
        moving = self._twist_cmd is not None and any(self._twist_cmd[0])
        self._twist_cmd = key
        self._trace = []
        if not np.any(key[0]):
            if moving:
                self._hold_measured()
            return
        self.arm.set_twist(np.asarray(v6, dtype=np.float64), frame=frame)

    def blocked(self, window: float = 0.4, ratio: float = 0.25) -> bool:
        """The arm does not follow the current twist: over ``window`` s it moved less than ``ratio`` of it.

        A blocked Cartesian command winds up the joint targets until the fault monitor stops
        the robot, so the primitives treat it as a contact.
        """
        if self._twist_cmd is None or not any(self._twist_cmd[0][:3]):
            return False
        speed = float(np.linalg.norm(self._twist_cmd[0][:3]))
        now = self.r.time
        pos = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        trace = getattr(self, "_trace", [])
        trace.append((now, pos))
        while len(trace) > 1 and now - trace[1][0] >= window:
            trace.pop(0)
        self._trace = trace
        t0, p0 = trace[0]
        if now - t0 < window:
            return False
        return float(np.linalg.norm(pos - p0)) < ratio * speed * (now - t0)

    def _wound_up(self, error: float = 0.05, speed: float = 0.02, duration: float = 0.15) -> bool:
        """Joint targets running away from joints that do not move (the fault monitor's stuck
        condition, caught earlier): the arm pushes against something it cannot move."""
        if not self.commands_arm:
            return False
        q_cmd = getattr(self.arm, "q_cmd", None)
        if q_cmd is None:
            return False
        lag = np.abs(np.asarray(q_cmd) - self.arm.q())
        stuck = bool(np.any((lag > error) & (np.abs(self.arm.qd()) < speed)))
        now = self.r.time
        if not stuck:
            self._stuck_since = None
            return False
        if self._stuck_since is None:
            self._stuck_since = now
        return now - self._stuck_since >= duration

    def _hold_measured(self) -> None:
        # holding the commanded joints would keep pressing whatever blocked the arm
        if self.commands_arm and not self.r.failed:
            self.arm.move_joints(self.arm.q(), speed=1000.0)

    def relax(self) -> None:
        """Stop and hold the measured joints (unwinds a blocked or pressing command)."""
        self._twist_cmd = None
        self._hold_measured()

    def halt(self) -> None:
        """Stop a twist this primitive commanded (other arm commands are left alone)."""
        if self._twist_cmd is not None and any(self._twist_cmd[0]):
            self._hold_measured()
        self._twist_cmd = None

    # -- sensing helpers -----------------------------------------------------------------
    def wrench_in(self, frame: str) -> np.ndarray:
        """Wrist wrench (reaction of the environment on the hand, at the sensor origin) in ``frame`` axes.

        The F/T reading comes in world axes (``sensors/ft.py``); it is rotated, not moved.
        """
        w = np.asarray(self.r.ft(self.arm_name).vector, dtype=np.float64)
        if frame == "world":
            return w
        R = self.r.frame_pose(frame)[:3, :3].T
        return np.concatenate([R @ w[:3], R @ w[3:]])

    def pad_forces(self) -> dict[str, float]:
        """Total pressure per tactile pad of the hand (0 for a hand without pads)."""
        if not self.hand_name:
            return {}
        return {k: float(v.sum()) for k, v in self.r.tactile(self.hand_name).items()}

    def pads_in_contact(self) -> list[str]:
        if not self.hand_name:
            return []
        return [k for k, v in self.r.tactile(self.hand_name).items() if float(v.max(initial=0.0)) > TACTILE_CONTACT]

    def grip_force(self) -> float:
        """N, the gripper's motor effort sensing: held open by an object, the jaws push with their effort limit.

        A stalled drive gives its force limit (effort x the finger joint's limit); jaws that
        closed on nothing push on nothing.
        """
        if not self.hand_name or not self.holding():
            return 0.0
        return float(self.hand.effort) * self.r.spec.hand(self.hand_name).force_limit

    def holding(self, min_fingers: int = 2, min_pads: int = 1) -> bool:
        """Something is in the hand: ``min_pads`` pads touch, or ``min_fingers`` fingers are held open by an object.

        The pads cover the fingertips only, so a power grasp on the inner phalanxes is told
        by the joint configuration (thesis §3.3.1: "joint configuration or contact information").
        """
        from contactflow.embodiments.primitives.hands import blocked_fingers, finger_groups

        if not self.hand_name:
            return False
        if len(self.pads_in_contact()) >= max(min_pads, 1):
            return True
        spec = self.r.spec.hand(self.hand_name)
        groups = finger_groups(spec)
        closed = np.asarray(spec.preshapes["closed"], dtype=np.float64)
        travel = float(np.abs(np.asarray(spec.preshapes["open"], dtype=np.float64) - closed).max())
        # a gripper's jaws travel centimetres, not radians: held open means a fifth of their travel
        margin = min(0.15, 0.2 * travel)
        return blocked_fingers(self.hand.positions(), closed, groups, margin) >= min(min_fingers, len(groups))

    # -- lifecycle -----------------------------------------------------------------------
    def start(self) -> None:
        if self.robot is None:
            self._bind_hosted()
        else:
            self.bind(self.robot)  # a pooled module runs again with new params: they may name another arm
        self.t0 = self.r.time
        self.result = {}
        self._outcome = Status.RUNNING
        self.state = Status.RUNNING
        self._stuck_since: float | None = None
        self.begin()

    def step(self) -> Status:
        if self._outcome is not Status.RUNNING:
            return self._outcome
        if self.r.failed:
            why = self.r.failure or "hardware fault"
            self.emit_once(Event.HARDWARE_FAILURE, f"robot stopped: {why}")
            return self.fail(f"hardware failure: {why}")
        if self._wound_up():
            self.relax()
            self.emit_once(Event.CONTACT, "the arm is blocked")
            return self.fail("arm blocked: its joints stopped short of their targets")
        self.update()
        return self._outcome

    def stop(self) -> None:
        """Hold the arm where it is measured; the hand keeps its last command (a grasp stays closed)."""
        if self.robot is not None:
            self.relax()
        self.state = Status.STOPPED

    def begin(self) -> None:
        """First command of the primitive (override)."""

    def update(self) -> None:
        """One control step (override); call :meth:`succeed` or :meth:`fail` to finish."""

    # -- outcome -------------------------------------------------------------------------
    def emit_once(self, event: Event, detail: str = "", values: dict[str, float] | None = None) -> None:
        if self.io is not None:
            self.io.emit(event, detail, values)

    def succeed(self, detail: str = "", **values: float) -> Status:
        return self._finish(Status.SUCCESS, Event.SUCCESS, detail, values)

    def fail(self, detail: str = "", event: Event = Event.FAILURE, **values: float) -> Status:
        return self._finish(Status.FAILURE, event, detail, values)

    def _finish(self, status: Status, event: Event, detail: str, values: dict[str, float]) -> Status:
        if self._outcome is not Status.RUNNING:
            return self._outcome
        self.result.update({k: float(v) for k, v in values.items()})
        self.result.setdefault("duration", float(self.elapsed))
        self.relax()
        self._outcome = status
        self.state = status
        self.emit_once(event, detail, dict(self.result))
        return status


def pose6(T: np.ndarray) -> dict[str, float]:
    """A 4x4 pose as result values ``x, y, z, roll, pitch, yaw`` (m, rad; fixed-axis xyz)."""
    from scipy.spatial.transform import Rotation

    r, p, y = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
    return {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3]),
            "roll": float(r), "pitch": float(p), "yaw": float(y)}


def matrix6(v: tuple[float, ...] | list[float], where: str) -> np.ndarray:
    """``[x, y, z, roll, pitch, yaw]`` (m, rad) as a 4x4 pose; ``where`` names the parameter."""
    from scipy.spatial.transform import Rotation

    a = np.asarray(v, dtype=np.float64)
    if a.shape != (6,) or not np.all(np.isfinite(a)):
        raise PrimitiveError(f"{where}: expected [x, y, z, roll, pitch, yaw], got {list(v)!r}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", a[3:]).as_matrix()
    T[:3, 3] = a[:3]
    return T


def low_pass(prev: np.ndarray | float | None, x: np.ndarray | float, cutoff_hz: float, dt: float):
    """One step of a first-order low-pass of cut-off ``cutoff_hz`` (0: none) over samples ``dt`` s apart."""
    if prev is None or cutoff_hz <= 0:
        return x
    a = dt / (dt + 1.0 / (2 * np.pi * cutoff_hz))
    return prev + a * (x - prev)


def hand_pose_for(robot: str, T_center: np.ndarray, preshape: str = "") -> np.ndarray:
    """The controlled-frame pose that puts robot ``robot``'s grasp centre for ``preshape`` (its home's) at ``T_center`` (4x4, world)."""
    from contactflow.embodiments import registry

    off = np.eye(4)
    off[:3, 3] = registry.home(robot).center(preshape)
    return T_center @ np.linalg.inv(off)


def top_grasp_pose(xyz: np.ndarray | tuple[float, ...], yaw: float = np.pi / 2) -> np.ndarray:
    """Grasp-frame pose above ``xyz`` with the approach axis (z) pointing down, rotated ``yaw`` about world z."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = xyz
    return T


def wall_yaws(yaws: list[float], xy, walls: tuple[float, ...], margin: float,
              wall_side: tuple[float, ...]) -> list[float]:
    """``yaws`` (of top grasps) for an object at ``xy`` within ``margin`` of a wall of ``walls`` [xmin, ymin, xmax, ymax]:
    the quarter turn of ``yaws[0]`` that puts the hand's ``wall_side`` toward the nearest wall comes first.

    Which side of a hand can face a wall while it grasps an object beside it depends on the
    hand (where its fingers and thumb land, which of them push the object); it is measured
    per hand. Without walls, or far from them, ``yaws`` is returned unchanged.
    """
    if len(walls) != 4 or margin <= 0.0 or not yaws:
        return yaws
    x, y = float(xy[0]), float(xy[1])
    gaps = np.array([x - walls[0], walls[2] - x, y - walls[1], walls[3] - y])
    side = int(np.argmin(gaps))
    if gaps[side] >= margin:
        return yaws
    out = np.array([(-1.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.0, 1.0)][side])
    sx, sy = np.asarray(wall_side, dtype=np.float64)[:2] / np.linalg.norm(wall_side[:2])

    def facing(yaw: float) -> float:  # the hand's ``wall_side`` in world xy (top grasp: hand z down) . the wall's outward normal
        return float((sx * np.array([np.cos(yaw), np.sin(yaw)]) + sy * np.array([np.sin(yaw), -np.cos(yaw)])) @ out)

    best = max((yaws[0] + k * np.pi / 2 for k in range(4)), key=facing)
    return [best] + [a for a in yaws if abs(np.angle(np.exp(1j * (a - best)))) > 1e-6]
