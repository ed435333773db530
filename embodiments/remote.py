"""A world's robot seen from a node: the primitives' robot facade over the key space.

:class:`RemoteRobot` satisfies :class:`~contactflow.embodiments.primitives.base.Robot`, as
:class:`~contactflow.embodiments.sim_robot.SimRobot` does, but everything crosses zenoh:
it reads the newest :class:`RobotState` the world published on ``robot/<robot>/state``,
computes frames at the measured joints with its own pinocchio model, and sends hand, head
and camera commands on ``robot/<robot>/command``; a hand command is pending until a state
shows the world applied it, as it would be on the robot itself. The arms' controllers run
here: the node's tick hook (:meth:`RemoteRobot.after_tick`) steps them after the tick's
primitives and streams each moving arm's joint target to the world.

One :class:`RobotLink` per node and robot (:func:`connect`) carries the subscriptions and
announces the node as a controller of the robot (``alive/controller/<robot>/<node>``): when
the last one drops, the world holds the robot.
"""

from __future__ import annotations

import logging
import secrets
import threading
import time
import weakref
from collections import deque
from typing import Any

import numpy as np

from contactflow.embodiments.control.arm import ArmController, ArmMode
from contactflow.embodiments.facade import ArmFacade, RobotFacade
from contactflow.embodiments.messages import (
    ArmCommand,
    ArmCommandKind,
    ArmState,
    CameraFrame,
    CameraRequest,
    HandCommand,
    HandState,
    HeadCommand,
    InfoRequest,
    RobotInfo,
    RobotState,
    WrenchSample,
)
from contactflow.embodiments.sensors.camera import DepthFrame
from contactflow.embodiments.sensors.ft import WrenchReading
from contactflow.nodes.host import tick_of
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.status import Status
from contactflow.nodes.transport import Transport
from contactflow.nodes.wire import NDArray, WireError, decode, encode, stamp

log = logging.getLogger("contactflow.remote")
MAX_TICKS = 5  # world ticks one step of the arm controllers may cover (as the Cartesian controller service)
CAMERA_TIMEOUT = 30.0  # s of wall time a camera frame may take (the first render compiles shaders)
INFO_RETRY = 0.05  # s of wall time between asks of a world that did not answer for its robot yet


class RemoteError(RuntimeError):
    """The world does not answer for a robot."""


class RobotLink:
    """One node's subscriptions to a world's robot, and its command publisher."""

    def __init__(self, transport: Transport, ks: KeySpace, robot: str, node: str) -> None:
        # weakly: the registry of links is keyed by the transport, which a strong reference would keep alive
        self._transport = weakref.ref(transport)
        self.ks, self.robot, self.node = ks, robot, node
        self._lock = threading.Condition()
        self._states: deque[RobotState] = deque(maxlen=4)  # the newest states, oldest first
        self.first_tick = 0  # the tick of the first state this node received
        self.rejected = 0
        self._frames: dict[int, CameraFrame | None] = {}  # the requests this node waits for
        self._seq = 0
        self._info: RobotInfo | None = None
        self.facade: RemoteRobot | None = None
        self._requests = 0
        self._request_base = secrets.randbits(40) << 20
        self._cmd = transport.publisher(ks.robot(robot, "command"))
        self._handles = [transport.subscribe(ks.robot(robot, "state"), self._on_state),
                         transport.subscribe(ks.robot(robot, "camera"), self._on_frame)]
        self.controller = False  # this node has commanded the robot (and holds alive/controller/<robot>/<node>)

    def _on_state(self, key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, RobotState, key)
        except WireError:
            self.rejected += 1
            return
        with self._lock:
            last = self._states[-1] if self._states else None
            if last is None or msg.tick >= last.tick or msg.tick == 0:
                if last is None:
                    self.first_tick = msg.tick
                if last is not None and msg.tick < last.tick:  # the world started again
                    self._states.clear()
                self._states.append(msg)
                self._lock.notify_all()

    @property
    def state(self) -> RobotState | None:
        """The state of the tick the node steps (a pipelined world sends the next one meanwhile); the newest
        outside lockstep, or when the node has stepped no tick it has a state of."""
        with self._lock:
            if not self._states:
                return None
            transport = self._transport()
            tick = tick_of(transport) if transport is not None else -1
            if tick >= 0:
                for s in reversed(self._states):
                    if s.tick <= tick:
                        return s
            return self._states[-1]

    def _on_frame(self, key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, CameraFrame, key)
        except WireError:
            self.rejected += 1
            return
        with self._lock:
            if msg.request in self._frames:  # another node's frame, or one given up on, is not kept
                self._frames[msg.request] = msg
                self._lock.notify_all()

    def info(self, timeout: float = 5.0) -> RobotInfo:
        """The robot's description, asked once of its world."""
        if self._info is None:
            key = self.ks.robot(self.robot, "info")
            end = time.monotonic() + timeout
            transport = self._transport()
            while self._info is None and transport is not None:
                replies = transport.query(key, encode(InfoRequest()), timeout=min(1.0, timeout))
                for rkey, payload in replies:
                    self._info = decode(payload, RobotInfo, rkey)
                if self._info is None and time.monotonic() > end:
                    break
                if self._info is None:
                    # no world's queryable yet: zenoh answers such a query at once, and asking again
                    # straight away burnt a core (and zenoh's network thread) until the world came up
                    time.sleep(INFO_RETRY)
            if self._info is None:
                raise RemoteError(f"no world answers for robot {self.robot!r} on {key}")
        return self._info

    def wait_state(self, timeout: float = 5.0) -> RobotState:
        with self._lock:
            self._lock.wait_for(lambda: bool(self._states), timeout)
            if not self._states:
                raise RemoteError(f"no state of robot {self.robot!r} on {self.ks.robot(self.robot, 'state')} "
                                  f"within {timeout:g} s")
            return self.state

    def send(self, msg: ArmCommand | HandCommand | HeadCommand | CameraRequest) -> None:
        if not self.controller and not isinstance(msg, CameraRequest):
            # a node becomes the robot's controller with its first command: the world holds the robot when the
            # last controller goes, and a node that only reads the robot (contact cues, a camera) must not count
            transport = self._transport()
            if transport is not None:
                self._handles.append(transport.token(self.ks.alive_controller(self.robot, self.node)))
            self.controller = True
        self._seq += 1
        state = self.state
        t = state.t if state is not None else 0.0
        stamp(msg, f"{self.robot}/{self.node}/controller", self._seq, t)
        transport = self._transport()
        msg.hdr.tick = tick_of(transport) if transport is not None else -1  # a pipelined world applies it by this
        self._cmd(encode(msg))

    def frame(self, camera: str, timeout: float = CAMERA_TIMEOUT) -> CameraFrame:
        """Ask the world for a frame now and wait for it (the world answers within the current tick)."""
        self._requests += 1
        request = self._request_base + self._requests  # unique across the nodes asking one world
        with self._lock:
            self._frames[request] = None
        self.send(CameraRequest(robot=self.robot, camera=camera, request=request))
        with self._lock:
            self._lock.wait_for(lambda: self._frames[request] is not None, timeout)
            msg = self._frames.pop(request)
        if msg is None:
            raise RemoteError(f"robot {self.robot}: no frame of camera {camera!r} within {timeout:g} s")
        if msg.error:
            raise RemoteError(f"robot {self.robot}: camera {camera!r} gave no frame: {msg.error}")
        return msg

    def close(self) -> None:
        for h in self._handles:
            h.close()
        self._handles.clear()


_links: weakref.WeakKeyDictionary[Any, dict[str, RobotLink]] = weakref.WeakKeyDictionary()
_links_lock = threading.Lock()


def link(transport: Transport, ks: KeySpace, robot: str, node: str) -> RobotLink:
    """The node's link to ``robot``: one per transport and robot, shared by the node's modules.

    Subscribing is all it does; a module makes it in ``setup`` so the robot's state is there
    when it starts (in lockstep the world publishes a new state only after the node's answer).
    """
    with _links_lock:
        per = _links.setdefault(transport, {})
        lk = per.get(robot)
        if lk is None:
            lk = per[robot] = RobotLink(transport, ks, robot, node)
        return lk


def connect(transport: Transport, ks: KeySpace, robot: str, node: str) -> RemoteRobot:
    """The facade of ``robot`` for a node, shared by its modules (as one robot is shared by the
    primitives that run on it)."""
    lk = link(transport, ks, robot, node)
    with _links_lock:
        if lk.facade is None:
            lk.facade = RemoteRobot(lk)
        return lk.facade


def _pending(sent: int, applied: int, status: str) -> Status:
    return Status.RUNNING if sent > applied else Status(status)


def _limits(robot: RemoteRobot, joints: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) position limits of ``joints`` from the robot's model."""
    kin = robot.kin
    idx = kin.q_index(tuple(joints))
    return (np.asarray(kin.model.lowerPositionLimit)[idx].copy(), np.asarray(kin.model.upperPositionLimit)[idx].copy())


class RemoteArm(ArmFacade):
    """An arm of a :class:`RemoteRobot` (the :class:`~contactflow.embodiments.primitives.base.ArmLike` of a primitive).

    Its controllers run here, on the node (thesis §6.3.2: the Cartesian controller, the IK
    solver and the trajectory service are services of the control computer): the node's tick
    hook (:meth:`RemoteRobot.after_tick`) steps them once per world tick, after the tick's
    primitives, and sends the arm's joint target to the world. Targets are clipped to the joint
    limits, as the simulated robot's drives would stop there: a primitive holding the measured
    joints of an arm resting at a limit (encoders read past it) must hold it, not have the
    world refuse the target.
    """

    def __init__(self, robot: RemoteRobot, spec: Any) -> None:
        self.robot, self.spec = robot, spec
        self.name, self.joints, self.home = spec.name, spec.joints, spec.home
        self.lower, self.upper = _limits(robot, spec.joints)
        self._sent = 0
        self._streamed: tuple[int, np.ndarray] | None = None  # the last target sent, with its seq
        self.ctl = ArmController(robot._ctl_kin, spec, measured=robot._kin_q, target=self._target,
                                 on_contact=lambda detail: log.debug("%s: %s", robot.name, detail))

    def _state(self) -> ArmState:
        for a in self.robot.state.arms:
            if a.name == self.name:
                return a
        raise RemoteError(f"robot {self.robot.name}: the world reports no arm {self.name!r}")

    def _target(self) -> np.ndarray:
        """The arm's joint target now: the one in flight if this node sent one the world has not applied yet."""
        s = self._state()
        if self._streamed is not None and self._streamed[0] > s.applied:
            return self._streamed[1].copy()
        return s.q_cmd.numpy().copy()

    @property
    def _failed(self) -> bool:
        return self.robot.state.failed

    def _path(self, waypoints: np.ndarray) -> np.ndarray:
        return np.clip(super()._path(waypoints), self.lower, self.upper)

    def q(self) -> np.ndarray:
        return self.robot._q()[self.robot._index(self.joints)].copy()

    def qd(self) -> np.ndarray:
        return self.robot.state.velocity.numpy()[self.robot._index(self.joints)].copy()

    @property
    def q_cmd(self) -> np.ndarray:
        return self.ctl.q_cmd.copy() if self.ctl.mode != ArmMode.IDLE else self._target()

    def _send(self, kind: ArmCommandKind, values: np.ndarray | None = None) -> None:
        self._sent += 1
        arr = None if values is None else NDArray.of(np.ascontiguousarray(values, dtype=np.float64))
        self.robot.link.send(ArmCommand(robot=self.robot.name, arm=self.name, kind=kind, seq=self._sent, values=arr))

    def tare(self) -> None:
        self._send(ArmCommandKind.TARE)

    def _control(self, dt: float, failed: bool) -> None:
        """One control tick of the arm's controllers; the target goes to the world."""
        if self.ctl.mode == ArmMode.IDLE:
            return
        if failed:
            self.ctl.fail()
            return
        reading = self.robot.ft(self.name) if self.spec.ft else None
        out = self.ctl.update(self.q(), dt, None if reading is None else reading.force,
                              None if reading is None else reading.vector)
        if out is not None:
            q = np.clip(out[0], self.lower, self.upper)
            self._send(ArmCommandKind.TARGET, np.stack([q, out[1]]))
            self._streamed = (self._sent, q)


class RemoteHand:
    """A hand of a :class:`RemoteRobot`; finger targets are clipped to the joint limits, as the simulated hand does."""

    def __init__(self, robot: RemoteRobot, spec: Any) -> None:
        self.robot, self.spec = robot, spec
        self.name, self.kind, self.joints = spec.name, spec.kind, spec.joints
        self.lower, self.upper = _limits(robot, spec.joints)
        self.preshapes = tuple(spec.preshapes)
        self._sent = 0

    def _state(self) -> HandState:
        for h in self.robot.state.hands:
            if h.name == self.name:
                return h
        raise RemoteError(f"robot {self.robot.name}: the world reports no hand {self.name!r}")

    def positions(self) -> np.ndarray:
        return self._state().positions.numpy().copy()

    @property
    def effort(self) -> float:
        """0..1, the finger drives' force limit in force (the last effort the world applied)."""
        return self._state().effort

    @property
    def status(self) -> Status:
        s = self._state()
        return _pending(self._sent, s.applied, s.status)

    def done(self) -> bool:
        return self.status in (Status.SUCCESS, Status.FAILURE)

    def set_fingers(self, q: np.ndarray, effort: float = 1.0) -> None:
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (len(self.joints),):
            raise ValueError(f"hand {self.name}: set_fingers needs {len(self.joints)} values, got shape {q.shape}")
        if not 0.0 < effort <= 1.0:
            raise ValueError(f"hand {self.name}: effort must be in (0, 1], got {effort}")
        self._sent += 1
        self.robot.link.send(HandCommand(robot=self.robot.name, hand=self.name, seq=self._sent,
                                         values=NDArray.of(np.clip(q, self.lower, self.upper)), effort=float(effort)))

    def preshape(self, name: str, effort: float = 1.0) -> None:
        if name not in self.spec.preshapes:
            raise ValueError(f"hand {self.name}: unknown preshape {name!r} (known: {list(self.preshapes)})")
        self._sent += 1
        self.robot.link.send(HandCommand(robot=self.robot.name, hand=self.name, seq=self._sent, preshape=name,
                                         effort=float(effort)))

    def open(self) -> None:
        self.preshape("open")

    def close(self, effort: float = 1.0) -> None:
        self.preshape("closed", effort)


class RemoteHead:
    """The pan-tilt head of a :class:`RemoteRobot`: joint state, gaze Jacobians, joint targets."""

    def __init__(self, robot: RemoteRobot, joints: tuple[str, ...]) -> None:
        self.robot, self.joints = robot, tuple(joints)
        self.lower, self.upper = _limits(robot, self.joints)

    def q(self) -> np.ndarray:
        return self.robot._q()[self.robot._index(self.joints)].copy()

    def jacobian(self, frame: str) -> np.ndarray:
        self.robot._sync_kin()
        return self.robot.kin.jacobian(frame)[:, self.robot.kin.q_index(self.joints)]

    def move_joints(self, q: np.ndarray) -> None:
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (len(self.joints),):
            raise ValueError(f"head: move_joints needs {len(self.joints)} values, got shape {q.shape}")
        self.robot.link.send(HeadCommand(robot=self.robot.name, values=[float(v) for v in np.clip(q, self.lower, self.upper)]))


class RemoteRobot(RobotFacade):
    """A robot of a world, driven and sensed over the key space (what primitives bind to on a node)."""

    def __init__(self, link: RobotLink) -> None:
        from contactflow.embodiments import registry
        from contactflow.embodiments.control.kinematics import Kinematics
        from contactflow.embodiments.control.planning import seed_ompl

        self.link = link
        self.name = link.robot
        self.info = link.info()
        seed_ompl(self.info.seed + 1)  # the process's planners draw from the run's seed (OMPL refuses 0)
        self.spec = registry.get(self.info.embodiment)
        self.base = np.asarray(self.info.base, dtype=np.float64).reshape(4, 4)
        self.kin = Kinematics(self.spec.urdf(), self.base)
        self._ctl_kin = Kinematics(self.spec.urdf(), self.base)  # the arm controllers' model, at commanded joints
        self._ctl_tick = -1  # the state tick the controllers last stepped on
        self._ctl_t = 0.0  # s, its time
        self._kin_tick = -1
        self._names: list[str] = []
        self._seen: RobotState | None = None  # the last state whose joint order was checked
        self._index_of: dict[tuple[str, ...], np.ndarray] = {}
        link.wait_state()  # the arm controllers start from the commanded joints the world reports
        self._arms = {a.name: RemoteArm(self, a) for a in self.spec.arms}
        self._hands = {h.name: RemoteHand(self, h) for h in self.spec.hands}
        self.head = RemoteHead(self, self.spec.head_joints) if self.spec.head_joints else None
        self._tare: dict[str, tuple[int, np.ndarray]] = {}

    # -- state --------------------------------------------------------------------------------
    @property
    def state(self) -> RobotState:
        s = self.link.state
        if s is None:
            raise RemoteError(f"robot {self.name}: no state received yet")
        if s is not self._seen:  # the joint order compared once per state, not at every read
            self._seen = s
            if s.names != self._names:
                self._names = list(s.names)
                self._index_of.clear()
                self._s2k = self.kin.q_index(self._names)
        return s

    def _index(self, joints: tuple[str, ...]) -> np.ndarray:
        self.state  # noqa: B018 (refreshes the joint order)
        idx = self._index_of.get(joints)
        if idx is None:
            pos = {n: i for i, n in enumerate(self._names)}
            idx = self._index_of[joints] = np.array([pos[j] for j in joints], dtype=np.intp)
        return idx

    def _q(self) -> np.ndarray:
        return self.state.position.numpy()

    @property
    def time(self) -> float:
        return self.state.t

    @property
    def failed(self) -> bool:
        """Stopped by a fault, or held by the world while this node commanded it (a node that
        connects to a held robot takes it over with its first command)."""
        s = self.state
        return s.failed or (s.held and s.held_at >= self.link.first_tick)

    @property
    def failure(self) -> str:
        s = self.state
        return s.failure or ("held by the world" if s.held else "")

    # -- sensors ------------------------------------------------------------------------------
    def _wrench(self, arm: str) -> tuple[WrenchSample, np.ndarray]:
        """The arm's wrist sample as the world sent it, and its force and torque as one vector."""
        for w in self.state.wrenches:
            if w.arm == arm:
                return w, np.asarray([*w.force, *w.torque], dtype=np.float64)
        raise KeyError(f"robot {self.name}: arm {arm!r} has no F/T sensor")

    def ft(self, arm: str) -> WrenchReading:
        w, v = self._wrench(arm)
        pending = self._tare.get(arm)
        if pending is not None:
            seq, at_tare = pending
            if self.arm(arm)._state().applied >= seq:
                del self._tare[arm]
            else:  # the world tares at its next tick: read as if it had
                v = v - at_tare
        return WrenchReading(self.time, v[:3], v[3:], w.frame, np.asarray(w.rotation).reshape(3, 3), w.estimated,
                             np.asarray([*w.external_force, *w.external_torque], dtype=np.float64))

    def tare_ft(self, arm: str) -> None:
        a = self.arm(arm)
        a.tare()
        self._tare[arm] = (a._sent, self._wrench(arm)[1])  # what the world will subtract

    def tactile(self, hand: str) -> dict[str, np.ndarray]:
        for t in self.state.tactile:
            if t.hand == hand:
                p = t.pressure.numpy()
                return {pad: p[k].astype(np.float64) for k, pad in enumerate(t.pads)}
        if hand not in self._hands:
            raise KeyError(f"robot {self.name}: no hand {hand!r}")
        return {}

    def camera(self, name: str = "kinect") -> DepthFrame:
        self.spec.camera(name)
        f = self.link.frame(name)
        depth = f.depth.numpy()
        return DepthFrame(t=f.t, depth=depth, points=f.points.numpy(), pixels=f.pixels.numpy(),
                          K=np.asarray(f.K).reshape(3, 3), T_world_cam=np.asarray(f.pose).reshape(4, 4),
                          labels=np.full(depth.shape, -1, np.int32), label_names=())

    # -- kinematics ---------------------------------------------------------------------------
    def _kin_q(self) -> np.ndarray:
        q = self.kin.q.copy()
        q[self._s2k] = self._q()
        return q

    def _sync_kin(self) -> None:
        s = self.state
        if self._kin_tick != s.tick:
            self.kin.update(self._kin_q())
            self._kin_tick = s.tick

    def kin_q_cmd(self) -> np.ndarray:
        """The model's joints: measured, with each arm at its commanded joints (where plans start)."""
        q = self._kin_q()
        for a in self._arms.values():
            q[self.kin.q_index(a.joints)] = a.q_cmd
        return q

    def add_task_frame(self, name: str, parent: str, T: np.ndarray) -> None:
        self.kin.add_task_frame(name, parent, T)
        self._ctl_kin.add_task_frame(name, parent, T)

    # -- the arm controllers: the node's tick hook ---------------------------------------------
    def after_tick(self) -> None:
        """Step every running arm controller once per world tick, after the tick's primitives."""
        s = self.link.state
        if s is None or s.tick == self._ctl_tick:
            return
        rate = self.info.control_rate
        # the ticks since the last step, counted in simulated time: a real-time node may miss a few; a node
        # far behind a free-running world moves its arms at most MAX_TICKS' worth per step, never in jumps
        ticks = min(max(1, round((s.t - self._ctl_t) * rate)), MAX_TICKS) if self._ctl_tick >= 0 else 1
        self._ctl_tick, self._ctl_t = s.tick, s.t
        dt = ticks / rate
        for a in self._arms.values():
            a._control(dt, s.failed)

    @property
    def rate_hz(self) -> float:
        """Hz, the world's control rate: the arm controllers' rate."""
        return self.info.control_rate

    def active(self) -> bool:
        """An arm controller is moving the arm (its node then ticks at the control rate on the wall clock)."""
        return any(a.ctl.mode != ArmMode.IDLE for a in self._arms.values())

    def hand_points(self, arm: str) -> np.ndarray:
        """Where ``arm``'s hand is around its controlled frame, as the world measured it (N, 3)."""
        for h in self.info.hands:
            if h.arm == arm:
                return h.points.numpy().copy()
        raise KeyError(f"robot {self.name}: the world measured no hand on arm {arm!r}")

    def fixtures(self) -> list:
        """The cell's fixtures as the world declared them (planning obstacles)."""
        from contactflow.embodiments.control.planning import Obstacle

        return [Obstacle(o.name, o.kind, tuple(o.size), np.asarray(o.pose).reshape(4, 4)) for o in self.info.fixtures]
