"""The world (thesis §6.1 interface layer): one SAPIEN cell with its robots, driven only over the key space.

The module builds the cell of a scene file (robots at their base poses, table, objects) and
is its robots' hardware: it takes arm, hand, head and camera commands on
``robot/<robot>/command``, runs each robot's joint controllers at the control rate, and
publishes every tick each robot's :class:`RobotState` on ``robot/<robot>/state``, then the
clock. With ``camera_hz`` it streams depth frames of each robot's first camera (``robot/<robot>/depth``) and of
the scene file's fixed cameras (``camera/<name>/depth``). Object poses and each robot's true contacts with the
objects go only to ``eval/``.
Nothing else in the system touches the scene.

Two clocks (``params.clock``):

- ``lockstep``: tick k+1 runs only when every node announced on ``alive/lockstep/*`` has
  acknowledged tick k, or after ``deadline`` s of wall time (an OVERRUN event; a node that
  misses it has its robots held). A node still stepping the tick says so every second (a
  ``working`` note) and is waited for up to ``max_step``: slow is not dead. A seeded run
  repeats exactly whatever the process layout.
  With ``idle: pause`` the world also stops while every lockstep node is idle (no primitive
  or task running, :meth:`Module.busy`) and resumes when one gets work: a task dispatched at
  any wall-clock moment starts at the tick its robot went idle, so a seeded run repeats even
  when a person or a broker starts its tasks (CARLA's synchronous mode: the client ticks).
  With ``pipeline`` the world steps tick k+1 once the nodes answered tick k-1: it simulates
  while they step tick k, and what they send during tick k takes effect a tick later than
  without it (docs/protocol.md), the same in any process layout.
- ``realtime``: the ticks follow the wall clock, as on the thesis robot; a command that
  arrives after the tick it was meant for is counted late.

Commands are validated before they reach a controller: an unknown robot, arm, hand or
camera, a non-finite value or a joint target outside the limits is refused and counted.
When the last controller node of a robot goes away (its liveliness token drops) the world
holds that robot where it is and raises HARDWARE_FAILURE; the other robots keep running.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import msgspec
import numpy as np

from contactflow.embodiments.messages import (
    ArmCommand,
    ArmCommandKind,
    ArmState,
    CameraFrame,
    CameraRequest,
    DepthImage,
    HandCommand,
    HandPoints,
    HandState,
    HeadCommand,
    JointState,
    ObjectPoses,
    ObstacleMsg,
    RobotInfo,
    RobotState,
    TactileSample,
    TrueContacts,
    WrenchSample,
)
from contactflow.nodes.messages import Clock, LockstepAck, Mark
from contactflow.nodes.module import Layer, Module, ModuleIO
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import Message, NDArray, WireError, decode, encode, stamp

RobotCommand = ArmCommand | HandCommand | HeadCommand | CameraRequest
_command_decoder = msgspec.msgpack.Decoder(RobotCommand)
MAX_COMMAND_BYTES = 1 << 20
MAX_QUEUED = 4096  # commands kept between two ticks; a flood beyond it is refused, not buffered


class CommandError(ValueError):
    """A command the world refuses (never applied)."""


def _finite(a: np.ndarray, what: str) -> np.ndarray:
    if not np.all(np.isfinite(a)):
        raise CommandError(f"{what}: non-finite value")
    return a


def _joint_values(sim: Any, joints: tuple[str, ...], values: np.ndarray, what: str) -> np.ndarray:
    idx = sim.art.indices(joints)
    lo, hi = sim.art.lower[idx], sim.art.upper[idx]
    tol = 1e-6
    bad = (values < lo - tol) | (values > hi + tol)
    if bad.any():
        j = int(np.argmax(bad))
        raise CommandError(f"{what}: joint {joints[j]!r} target {values[j]:.4f} "
                           f"outside its limits [{lo[j]:.4f}, {hi[j]:.4f}]")
    return values


def apply_arm(sim: Any, msg: ArmCommand) -> None:
    """Validate an arm command and hand it to the arm's drives of ``sim`` (a SimRobot); CommandError if refused."""
    arm = sim.arm(msg.arm)
    what = f"arm {msg.arm}"
    if msg.kind is ArmCommandKind.TARGET:
        n = len(arm.joints)
        v = None if msg.values is None else _finite(msg.values.numpy().astype(np.float64), what)
        if v is None or v.shape != (2, n):
            raise CommandError(f"{what}: a target needs values of shape (2, {n}), got {None if v is None else v.shape}")
        arm.stream(_joint_values(sim, arm.joints, v[0], what), v[1])
    else:
        sim.tare_ft(msg.arm)


def apply_hand(sim: Any, msg: HandCommand) -> None:
    """Validate a hand command and start it on the hand of ``sim``; CommandError if refused."""
    hand = sim.hand(msg.hand)
    if not 0.0 < msg.effort <= 1.0:
        raise CommandError(f"hand {msg.hand}: effort {msg.effort} is not in (0, 1]")
    if msg.preshape:
        hand.preshape(msg.preshape, msg.effort)
        return
    if msg.values is None:
        raise CommandError(f"hand {msg.hand}: a command needs values or a preshape")
    v = _finite(msg.values.numpy().astype(np.float64), f"hand {msg.hand}")
    if v.shape != (len(hand.joints),):
        raise CommandError(f"hand {msg.hand}: needs {len(hand.joints)} values, got shape {v.shape}")
    hand.set_fingers(_joint_values(sim, hand.joints, v, f"hand {msg.hand}"), msg.effort)


def _push(text: str, where: str, objects: dict) -> tuple[str, float, float, list[float]]:
    """``object@t0-t1:fx,fy,fz`` as (object, t0, t1, force); a ValueError naming ``where`` otherwise."""
    try:
        name, rest = text.split("@", 1)
        span, force = rest.split(":", 1)
        t0, t1 = (float(v) for v in span.split("-", 1))
        f = [float(v) for v in force.split(",")]
    except ValueError:
        raise ValueError(f"{where}: {text!r} is not object@t0-t1:fx,fy,fz") from None
    if name not in objects or objects[name].spec.static:
        raise ValueError(f"{where}: {name!r} is no movable object of the scene ({sorted(objects)})")
    if len(f) != 3 or not np.all(np.isfinite(f)) or not 0.0 <= t0 < t1:
        raise ValueError(f"{where}: {text!r} needs 0 <= t0 < t1 and three finite force components")
    return name, t0, t1, f


def apply_head(sim: Any, msg: HeadCommand) -> None:
    """Validate a head command and move the head of ``sim``; CommandError if refused."""
    if sim.head is None:
        raise CommandError(f"robot {sim.name} has no head")
    sim.head.move_joints(_finite(np.asarray(msg.values, dtype=np.float64), "head"))


@dataclass
class _Robot:
    sim: Any  # SimRobot
    info: bytes
    state_pub: Any
    camera_pub: Any
    depth_pub: Any
    joints_pub: Any
    arm_seq: dict[str, int] = field(default_factory=dict)
    hand_seq: dict[str, int] = field(default_factory=dict)
    controllers: set[str] = field(default_factory=set)  # nodes holding alive/controller/<robot>/<node>
    gone: set[str] = field(default_factory=set)  # controller nodes whose token dropped (until it is back)
    orphaned: float | None = None  # wall time the last controller's token dropped (held after gone_grace)
    held: bool = False
    held_at: int = -1
    refused: int = 0
    late: int = 0
    seq: int = 0
    depth_seq: int = 0
    contacts_seq: int = 0
    last: RobotState | None = None  # the state of the current tick
    joints: JointState | None = None  # its joints, on their own for the subscribers that need only them (self filter)


@dataclass
class _FixedCamera:
    camera: Any  # DepthCamera fixed in the world
    pub: Any
    seq: int = 0


def fixed_camera(world: Any, c: Any) -> Any:
    """The DepthCamera of a scene file's camera ``c`` (CameraPlacement) in ``world``: Kinect intrinsics scaled to
    its image, streaming as fast as it is read."""
    from contactflow.embodiments.registry import CameraSpec
    from contactflow.embodiments.sensors.camera import DepthCamera
    from contactflow.recognition.geometry import look_at

    f = 525.0 * c.width / 640.0
    spec = CameraSpec(name=c.name, link="", width=c.width, height=c.height, fx=f, fy=f, cx=(c.width - 1) / 2,
                      cy=(c.height - 1) / 2, rate_hz=1e9)
    return DepthCamera(world, spec, T_world_cam=look_at(np.asarray(c.eye, float), np.asarray(c.target, float)))


class WorldModule(Module):
    """A SAPIEN cell from a scene file; its robots commanded and sensed over ``robot/<robot>/...``."""

    layer = Layer.INTERFACE
    events = (Event.HARDWARE_FAILURE, Event.OVERRUN)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 1000.0  # Hz the host calls step; each call runs the ticks that are due
        scene_file: str = ""  # path of the scene file (YAML: robots with base poses, objects)
        clock: str = "lockstep"  # lockstep | realtime
        idle: str = "run"  # lockstep: run | pause (no tick while every lockstep node is idle; the task that wakes one starts at the next)
        max_rtf: float = 0.0  # lockstep: never faster than this many times real time (0: as fast as the nodes answer)
        pipeline: bool = False  # lockstep: step tick k+1 while the nodes step tick k (world and nodes at once on two
        # cores); a command and a message between nodes take effect a tick later, the same in any process layout
        control_rate: float = 200.0  # Hz, one tick: joint control, state messages, the clock (§6.3.1)
        settle: float = 0.3  # s of physics before the first tick (objects come to rest)
        deadline: float = 10.0  # s of wall time a lockstep node has to answer a tick, or to say it is still working on it
        max_step: float = 120.0  # s of wall time a lockstep node that keeps saying it is working may take over one tick
        gone_grace: float = 1.0  # s of wall time a robot may be without a controller token before it is held (zenoh drops and re-learns a live peer's tokens when it re-routes)
        slice: float = 0.05  # s of wall time one step may spend on lockstep ticks
        ground_truth_hz: float = 20.0  # Hz of object poses on eval/
        contacts_hz: float = 0.0  # Hz of simulated time, each robot's true contacts with the objects on eval/<r>/true_contacts
        camera_hz: float = 0.0  # Hz of simulated time, depth frames of each robot's first camera on robot/<r>/depth and of the scene's fixed cameras on camera/<name>/depth
        camera_backend: str = "auto"  # auto | render | raycast
        seed: int = 0  # sensor noise seed of every robot
        cell: str = ""  # the cell's name when a site runs several worlds (its clock and lockstep keys)
        wait_for: tuple[str, ...] = ()  # lockstep nodes tick 1 waits for (a seeded run starts at a known tick)
        republish: float = 0.2  # s of wall time between repeats of the current tick while waiting (late joiners)
        start_timeout: float = 60.0  # s of wall time tick 1 waits for the nodes of wait_for to come up
        pushes: tuple[str, ...] = ()  # forces on objects from an agent no robot knows of (tests, benchmarks): "object@t0-t1:fx,fy,fz" (s of simulated time, N, world)

    def __init__(self, name: str, params: Params | None = None, world: Any = None, sims: tuple = ()) -> None:
        """``world`` and its ``sims`` (SimRobots): a world built by the caller, co-located with its controllers
        (the in-process runner): commands apply as they arrive and :meth:`publish_state` sends the state."""
        super().__init__(name, params)
        self.world: Any = world
        self._given = tuple(sims) if world is not None else None
        self._published_at = -1  # co-located: the world step of the last state sent
        self.robots: dict[str, _Robot] = {}
        self.tick_no = 0
        self.overruns = 0
        self.refused_acks = 0  # acks for ticks the world had not published (forged)
        self.refused_unknown = 0
        self._commands: deque[ArmCommand | HandCommand | HeadCommand] = deque()
        self._requests: deque[CameraRequest] = deque()
        self._holds: deque[tuple[str, str]] = deque()
        self._acks: dict[str, int] = {}
        self._marks: dict[int, dict[tuple[str, str], int]] = {}  # tick -> what the lockstep nodes published during it
        self._lag = 0  # ticks the world runs ahead of its nodes' answers (params.pipeline)
        self._tick_marks: list[Mark] = []  # ... passed on with the current tick's clock
        self._lockstep: set[str] = set()
        self._busy: dict[str, bool] = {}  # lockstep node -> busy at its last ack
        self._working: dict[str, tuple[int, float]] = {}  # lockstep node -> (tick, wall time) of its last working note
        self.paused = False  # idle: pause, and every lockstep node acked the current tick idle
        self.pauses = 0
        self._cond = threading.Condition()
        self._handles: list[Any] = []
        self._gt_due = 0.0
        self._depth_due = 0.0
        self._contacts_due = 0.0
        self._contacts_pubs: dict[str, Any] = {}
        self._clock_seq = 0
        self._t0_wall = 0.0
        self._t0_sim = 0.0
        self.log = logging.getLogger(f"contactflow.world.{name}")

    # -- set up ------------------------------------------------------------------------------
    def setup(self, io: ModuleIO) -> None:
        super().setup(io)
        from contactflow.embodiments.control.planning import fixtures_from_world
        from contactflow.embodiments.hand_geometry import hand_points
        from contactflow.embodiments.scene_file import load_scene
        from contactflow.embodiments.scenes import SCENES
        from contactflow.embodiments.sim_robot import SimRobot, SimRobotParams
        from contactflow.embodiments.transforms import xyz_rpy_to_matrix
        from contactflow.embodiments.world import World, WorldParams

        p = self.params
        where = f"{self.name}.params"
        if p.clock not in ("lockstep", "realtime"):
            raise ValueError(f"{where}.clock: {p.clock!r} is not lockstep or realtime")
        if p.idle not in ("run", "pause") or (p.idle == "pause" and p.clock != "lockstep"):
            raise ValueError(f"{where}.idle: {p.idle!r} is not run, or pause with the lockstep clock")
        if not p.scene_file and self._given is None:
            raise ValueError(f"{where}.scene_file: a world needs a scene file")
        if p.pipeline and (p.clock != "lockstep" or p.idle != "run" or self._given is not None):
            raise ValueError(f"{where}.pipeline: needs the lockstep clock, idle: run and a world of its own")
        self._lag = int(p.pipeline)
        if p.control_rate <= 0 or p.deadline <= 0 or p.slice <= 0 or p.max_rtf < 0 or p.max_step < p.deadline:
            raise ValueError(f"{where}: control_rate, deadline and slice must be positive, max_rtf not negative, "
                             f"max_step at least the deadline")
        transport = io.transport  # the world is infrastructure: its streams are per robot, not per port
        self.ks = ks = io.keyspace
        addr = f"{io.robot}/{io.node}/{self.name}" if hasattr(io, "robot") else self.name
        self.source = addr
        cameras: tuple = ()
        if self._given is not None:
            world, sims = self.world, [(sim.name, sim) for sim in self._given]
        else:
            scene = load_scene(p.scene_file)
            self.world = world = World(WorldParams(camera_backend=p.camera_backend))
            if scene.scene:
                SCENES[scene.scene](world)
            for obj in scene.objects:
                world.add_object(obj)
            for bottle in scene.bottles:
                world.add_screw_bottle(bottle)
            cameras = scene.cameras
            sims = []
            for k, rp in enumerate(scene.robots):
                base = None if rp.base is None else xyz_rpy_to_matrix(rp.base[:3], rp.base[3:])
                sims.append((rp.name, SimRobot(world, rp.embodiment, name=rp.name, base=base,
                                               params=SimRobotParams(control_rate=p.control_rate, seed=p.seed + 101 * k))))
        fixtures = [ObstacleMsg(name=o.name, kind=o.kind, size=[float(v) for v in o.size],
                                pose=[float(v) for v in np.asarray(o.pose).ravel()])
                    for o in fixtures_from_world(world)]
        for rname, sim in sims:
            hands = [HandPoints(arm=a.name, points=NDArray.of(hand_points(sim, a.name))) for a in sim.spec.arms if a.hand]
            info = RobotInfo(robot=rname, embodiment=sim.spec.name, base=[float(v) for v in sim.art.base.ravel()],
                             fixtures=fixtures, hands=hands, world=addr, clock=p.clock, control_rate=p.control_rate,
                             seed=p.seed)
            self.robots[rname] = _Robot(sim, encode(stamp(info, f"{addr}/info", 1, 0.0)),
                                          transport.publisher(ks.robot(rname, "state")),
                                          transport.publisher(ks.robot(rname, "camera")),
                                          transport.publisher(ks.robot(rname, "depth")),
                                          transport.publisher(ks.robot(rname, "joints")))
        self._fixed = [_FixedCamera(fixed_camera(world, c), transport.publisher(ks.camera(c.name))) for c in cameras]
        for k, text in enumerate(p.pushes):
            name, t0, t1, force = _push(text, f"{where}.pushes[{k}]", world.objects)
            world.add_hook(lambda w, obj=world.objects[name], a=t0, b=t1, f=force:
                           obj.body.add_force_torque(f, [0.0, 0.0, 0.0]) if a <= w.time < b else None)
        if self._given is None:
            world.step(max(1, int(round(p.settle / world.params.timestep))))
        self._every = max(1, int(round(1.0 / (p.control_rate * world.params.timestep))))
        self._clock_pub = transport.publisher(ks.clock(p.cell))
        self._gt_pub = transport.publisher(ks.evaluation(p.cell or self.name, "object_poses"))
        if p.contacts_hz > 0:
            self._contacts_pubs = {name: transport.publisher(ks.evaluation(name, "true_contacts")) for name in self.robots}
        for name, r in self.robots.items():
            self._handles.append(transport.queryable(ks.robot(name, "info"), lambda _k, _p, b=r.info: b))
        self._handles.append(transport.subscribe(ks.robot("*", "command"), self._on_command))
        self._handles.append(transport.subscribe(ks.lockstep("*", p.cell), self._on_ack))
        self._handles.append(transport.watch_alive(ks.alive_lockstep("*", p.cell), self._on_lockstep_node))
        self._handles.append(transport.watch_alive(ks.alive_controller("*", "*"), self._on_controller))

    # -- zenoh callbacks: decode and queue, never block ---------------------------------------
    def _on_command(self, key: str, payload: bytes) -> None:
        robot = key.split("/")[-2]
        with self._cond:
            if len(self._commands) + len(self._requests) >= MAX_QUEUED or len(payload) > MAX_COMMAND_BYTES:
                self._refuse(robot, f"{key}: command queue full or payload of {len(payload)} bytes")
                return
            try:
                msg = _command_decoder.decode(payload)
            except (msgspec.ValidationError, msgspec.DecodeError) as exc:
                self._refuse(robot, f"{key}: invalid command: {exc}")
                return
            if msg.robot != robot:
                self._refuse(robot, f"{key}: the command names robot {msg.robot!r}")
                return
            if self._given is None:
                (self._requests if isinstance(msg, CameraRequest) else self._commands).append(msg)
                self._cond.notify_all()
                return
        self._apply(msg)  # co-located: the caller steps the world, the command applies as on the robot itself

    def publish_state(self) -> None:
        """Co-located: send each robot's state as it is now, if the world stepped since the last one."""
        if self.world.steps == self._published_at:
            return
        self._published_at = self.world.steps
        self.tick_no += 1
        self._publish_tick()

    def _on_ack(self, key: str, payload: bytes) -> None:
        try:
            ack = decode(payload, LockstepAck, key)
        except WireError:
            return
        with self._cond:
            if ack.tick > self.tick_no:  # no node can answer a tick not published yet: forged
                self.refused_acks += 1
                if self.refused_acks <= 10:
                    self.log.warning("%s: refused an ack of node %r for tick %d (the world is at tick %d)",
                                     key, ack.node, ack.tick, self.tick_no)
                return
            if ack.working:  # not an answer: the node's loop is alive and still stepping that tick
                if ack.tick >= self.tick_no - self._lag:
                    self._working[ack.node] = (ack.tick, time.monotonic())
                return
            marks = self._marks.setdefault(ack.tick, {})
            for m in ack.marks:
                if m.seq > marks.get((m.key, m.source), 0):
                    marks[(m.key, m.source)] = m.seq
            if ack.tick > self._acks.get(ack.node, -1):
                self._acks[ack.node] = ack.tick
                self._busy[ack.node] = ack.busy
                self._cond.notify_all()
            elif ack.tick == self._acks.get(ack.node) and ack.busy:  # idle at its ack, busy since: resume
                self._busy[ack.node] = True
                self._cond.notify_all()

    def _on_lockstep_node(self, key: str, alive: bool) -> None:
        node = key.rsplit("/", 1)[-1]
        with self._cond:
            if alive:
                self._lockstep.add(node)
            else:
                # not waited for while its token is gone; its last answer and busy state stay: a token that
                # zenoh drops and re-learns (the node never left) must not have the world wait for an answer the
                # node already gave, or stay paused on a busy node it took for idle (a demo stalled 10 s so)
                self._lockstep.discard(node)
                self._working.pop(node, None)
            self._cond.notify_all()

    def _on_controller(self, key: str, alive: bool) -> None:
        robot, node = key.split("/")[-2:]
        with self._cond:
            r = self.robots.get(robot)
            if r is None:
                return
            if alive:
                r.controllers.add(node)
                r.gone.discard(node)
                r.orphaned = None
            elif node in r.controllers:
                r.controllers.discard(node)
                r.gone.add(node)
                if not r.controllers:
                    r.orphaned = time.monotonic()  # held once gone_grace passed without a controller back
            self._cond.notify_all()

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        self._t0_wall = time.monotonic()
        self._t0_sim = self.world.time
        self._publish_tick()

    def step(self) -> Status:
        p = self.params
        end = time.monotonic() + p.slice
        if p.clock == "realtime":
            target = self._t0_sim + (time.monotonic() - self._t0_wall)
            dt = 1.0 / p.control_rate
            while self.world.time + dt <= target + 1e-9 and time.monotonic() < end:
                self._tick()
            self._serve_requests()
            return Status.RUNNING
        while time.monotonic() < end:
            if p.max_rtf > 0 and self.world.time - self._t0_sim > p.max_rtf * (time.monotonic() - self._t0_wall):
                break  # ahead of the pace: the host calls again within a millisecond
            if not self._await_acks():
                # paused: frames are still served and a gone controller's robot held (its event raised now,
                # not at the resume); the host calls again, and the module's control queries get their turn
                self._serve_requests()
                self._apply_holds()
                break
            self._tick()
        return Status.RUNNING

    def stop(self) -> None:
        for h in self._handles:
            h.close()
        self._handles.clear()

    def status_detail(self) -> str:
        if self.paused:
            return f"paused at tick {self.tick_no} (t={self.world.time:.3f} s): every lockstep node idle"
        return ""

    def _when(self) -> dict[str, float]:
        """The simulated time and tick of an event: its header carries the node's (wall) clock, as its status does."""
        return {"t": self.world.time, "tick": float(self.tick_no)}

    # -- the tick -----------------------------------------------------------------------------
    def _await_acks(self) -> bool:
        """Wait until every lockstep node answered the current tick (with a pipeline, the one before), serving
        camera requests meanwhile; False while the world is paused (``idle: pause`` and every node idle)."""
        k = self.tick_no
        want = k - self._lag if k > 0 else 0  # the answer this tick waits for (tick 0: every node is up)
        now = time.monotonic()
        deadline, repeat = now + self.params.deadline, now + self.params.republish
        start_by, give_up = now + self.params.start_timeout, now + self.params.max_step
        while True:
            with self._cond:
                expected = self._lockstep | (set(self.params.wait_for) if k == 0 else set())
                missing = [n for n in expected if self._acks.get(n, -1) < want]
                if not missing:
                    return self._run_on(expected)
                now = time.monotonic()
                absent = k == 0 and bool(set(missing) - self._lockstep)  # a node tick 1 waits for is not up yet
                if absent and now >= start_by:
                    break
                if not absent and now >= deadline and (now >= give_up or not self._all_working(missing, want, now)):
                    break
                if not any(self._due(m) for m in self._requests):
                    self._cond.wait(max(0.0, min(repeat - now, 0.05)))
            if self._serve_requests():  # the time the world spent rendering is not the nodes' delay
                deadline = time.monotonic() + self.params.deadline
            if time.monotonic() >= repeat:  # a node that joined after the tick was published gets it now
                self._publish_tick(repeat=True)
                repeat = time.monotonic() + self.params.republish
        self.overruns += 1
        detail = f"tick {want}: lockstep node(s) {sorted(missing)} did not answer within {self.params.deadline:g} s"
        if now >= give_up:
            detail = f"tick {want}: lockstep node(s) {sorted(missing)} still working on it after {self.params.max_step:g} s"
        self.log.warning(detail)
        self.io.emit(Event.OVERRUN, detail, self._when())
        with self._cond:
            for n in missing:  # a stalled node is treated as gone until it answers again
                self._acks[n] = want
            stalled = [name for name, r in self.robots.items() if r.controllers & set(missing)]
        for name in stalled:
            self._hold(name, f"its controller node(s) {sorted(missing)} stalled")
        return True

    def _all_working(self, nodes: list[str], tick: int, now: float) -> bool:
        """Whether every one of ``nodes`` said within the deadline that it is still working on ``tick`` (under the lock)."""
        return all((w := self._working.get(n)) is not None and w[0] == tick and now - w[1] < self.params.deadline
                   for n in nodes)

    def _run_on(self, nodes: set[str]) -> bool:
        """Whether the next tick may run now that ``nodes`` answered (under the lock): always, unless
        ``idle: pause`` and none of them is busy; then wait a little (a busy ack wakes it) and say no."""
        if self.params.idle != "pause" or any(self._busy.get(n, False) for n in nodes):
            if self.paused:  # the pace restarts at the resume, it does not catch up on the pause
                self.paused = False
                self._t0_wall, self._t0_sim = time.monotonic(), self.world.time
            return True
        if not self.paused:
            self.paused = True
            self.pauses += 1
            self.log.info("tick %d: every lockstep node is idle; paused until one has work", self.tick_no)
        if not self._requests:
            self._cond.wait(0.05)
        return False

    def _due(self, msg: RobotCommand) -> bool:
        """Whether a command or request applies at the current tick: a pipelined world takes those of the tick
        its nodes answered, not those a node already sent while stepping the current one (under the lock). A tick
        ahead of the world's is forged: it is applied (or refused) at once, never queued for good."""
        return not self.tick_no - self._lag < msg.hdr.tick <= self.tick_no

    def _take_due(self, queue: deque) -> tuple[deque, deque]:
        """(the due messages of ``queue``, the others), each in arrival order (under the lock)."""
        due: deque = deque()
        later: deque = deque()
        for m in queue:
            (due if self._due(m) else later).append(m)
        return due, later

    def _serve_requests(self) -> int:
        """Answer the due camera requests with a frame of the current state (commands wait for the tick)."""
        with self._cond:
            todo, self._requests = self._take_due(self._requests)
        for msg in todo:
            self._apply(msg)
        return len(todo)

    def _tick(self) -> None:
        self._serve_requests()
        self._apply_holds()
        with self._cond:
            batch, self._commands = self._take_due(self._commands)
        for msg in batch:
            # in real time a command stamped before the previous tick missed the tick it was meant for
            if self.world.time - msg.hdr.t_sim > 1.5 / self.params.control_rate and msg.robot in self.robots:
                self.robots[msg.robot].late += 1
            self._apply(msg)
        try:
            self.world.step(self._every)
        except Exception as exc:  # a physics blow-up stops the robots, not the node
            for name, r in self.robots.items():
                if not r.sim.failed:
                    r.sim.failed, r.sim.failure = True, f"physics: {type(exc).__name__}: {exc}"
                    self.io.emit(Event.HARDWARE_FAILURE, f"{name}: {r.sim.failure}"[:500], self._when())
        self.tick_no += 1
        self._publish_tick()

    def _apply_holds(self) -> None:
        with self._cond:
            now = time.monotonic()
            for name, r in self.robots.items():
                if r.orphaned is not None and now - r.orphaned >= self.params.gone_grace:
                    r.orphaned = None
                    self._holds.append((name, f"its controller node(s) {sorted(r.gone)} gone"))
            holds, self._holds = self._holds, deque()
        for robot, why in holds:
            self._hold(robot, why)

    def _publish_tick(self, repeat: bool = False) -> None:
        t = self.world.time
        for name, r in self.robots.items():
            if not repeat or r.last is None:
                r.last = self._state(name, r)
            r.seq += 1
            r.state_pub(self._encode(r.last, f"{name}/state", r.seq, t))
            r.joints_pub(self._encode(r.joints, f"{name}/joints", r.seq, t))
        if not repeat and self.params.camera_hz > 0 and t >= self._depth_due - 1e-9:
            period = 1.0 / self.params.camera_hz
            # keep the phase: counted from the tick, 30 Hz at 200 Hz ticks would be every 7th tick (28.6 Hz)
            self._depth_due = self._depth_due + period if self._depth_due > t - period else t + period
            for r in self.robots.values():
                if r.sim.spec.cameras:
                    self._stream_depth(r)
            for c in self._fixed:
                self._stream_fixed(c, t)
        if not repeat and self.params.ground_truth_hz > 0 and t >= self._gt_due - 1e-9:
            self._gt_due = t + 1.0 / self.params.ground_truth_hz
            objs = {n: o.pose() for n, o in self.world.objects.items()} | self.world.bottle_poses()
            poses = np.stack(list(objs.values())) if objs else np.zeros((0, 4, 4))
            self._gt_pub(self._encode(ObjectPoses(names=list(objs), poses=NDArray.of(poses)), "object_poses",
                                      self.tick_no + 1, t))
        if not repeat and self.params.contacts_hz > 0 and t >= self._contacts_due - 1e-9:
            self._contacts_due = t + 1.0 / self.params.contacts_hz
            self._publish_contacts(t)
        if not repeat:
            with self._cond:  # what the nodes sent during the ticks whose answers this tick waited for
                done = [k for k in self._marks if k <= self.tick_no - 1 - self._lag]
                marks: dict[tuple[str, str], int] = {}
                for k in sorted(done):
                    marks.update(self._marks.pop(k))
            self._tick_marks = [Mark(key=k, source=src, seq=seq) for (k, src), seq in marks.items()]
        self._clock_seq += 1
        self._clock_pub(self._encode(Clock(t=t, tick=self.tick_no, marks=self._tick_marks, lag=self._lag), "clock",
                                     self._clock_seq, t))

    def _encode(self, msg: Message, stream: str, seq: int, t: float, clock: int | None = None) -> bytes:
        """``msg`` stamped as sent on ``<source>/<stream>``, encoded. A pipelined world's message sent before the clock
        of tick ``clock`` (the current one's unless given) is an input of its nodes from that tick on, as what the
        nodes sent during tick clock - 1 - lag: its header says that tick. Without a pipeline it says none (-1): the
        nodes have stepped the tick before when it arrives."""
        stamp(msg, f"{self.source}/{stream}", seq, t)
        if self._lag:
            msg.hdr.tick = (self.tick_no if clock is None else clock) - 1 - self._lag
        return encode(msg)

    def _publish_contacts(self, t: float) -> None:
        """Each robot's physics contact points with the cell's objects, the table included (its link first, the normal from it)."""
        from contactflow.embodiments.sensors.ground_truth import read_ground_truth

        objects = set(self.world.objects)
        per: dict[str, list] = {name: [] for name in self.robots}
        for c in read_ground_truth(self.world).contacts:
            for link, other, sign in ((c.body_a, c.body_b, 1.0), (c.body_b, c.body_a, -1.0)):
                robot = link.split("/", 1)[0]
                if robot in per and other in objects:
                    per[robot].append((link, other, c.position, sign * c.normal, c.force))
                    break
        for name, found in per.items():
            msg = TrueContacts(body_a=[f[0] for f in found], body_b=[f[1] for f in found],
                               positions=NDArray.of(np.array([f[2] for f in found], dtype=np.float64).reshape(-1, 3)),
                               normals=NDArray.of(np.array([f[3] for f in found], dtype=np.float64).reshape(-1, 3)),
                               forces=NDArray.of(np.array([f[4] for f in found], dtype=np.float64)))
            self.robots[name].contacts_seq += 1
            self._contacts_pubs[name](self._encode(msg, f"{name}/true_contacts", self.robots[name].contacts_seq, t))

    def _state(self, name: str, r: _Robot) -> RobotState:
        sim = r.sim
        names, q, qd, effort = sim.joint_state()
        position, velocity = NDArray.of(q), NDArray.of(qd)  # one copy each, shared by the state and the joints
        r.joints = JointState(robot=name, names=names, position=position, velocity=velocity,
                              effort=NDArray.of(np.asarray(effort, dtype=np.float64)))
        arms = [ArmState(name=a, q_cmd=NDArray.of(np.asarray(sim.arm(a).q_cmd, dtype=np.float64)),
                         applied=r.arm_seq.get(a, 0)) for a in sim.arms]
        hands = [HandState(name=h, positions=NDArray.of(sim.hand(h).positions()), status=str(sim.hand(h).status),
                           effort=sim.hand(h).effort, applied=r.hand_seq.get(h, 0)) for h in sim.hands]
        wrenches = []
        for a in sim.spec.arms:
            if a.ft:
                w = sim.ft(a.name)
                wrenches.append(WrenchSample(arm=a.name, force=w.force.tolist(), torque=w.torque.tolist(),
                                             frame=w.frame, rotation=w.R_world_sensor.ravel().tolist(),
                                             estimated=w.estimated, external_force=w.external[:3].tolist(),
                                             external_torque=w.external[3:].tolist()))
        tactile = []
        for h in sim.spec.hands:
            if h.pads:
                pads = sim.tactile(h.name)
                tactile.append(TactileSample(hand=h.name, pads=list(pads), pressure=NDArray.of(
                    np.stack([np.asarray(v, dtype=np.float32) for v in pads.values()]))))
        return RobotState(robot=name, tick=self.tick_no, t=sim.time, names=names, position=position,
                          velocity=velocity, arms=arms, hands=hands, wrenches=wrenches, tactile=tactile,
                          failed=sim.failed, failure=sim.failure, held=r.held,
                          held_at=r.held_at if r.held else -1, refused=r.refused, late=r.late)

    # -- commands -----------------------------------------------------------------------------
    def _refuse(self, robot: str, why: str) -> None:
        r = self.robots.get(robot)
        if r is None:
            # a site of several cells: every world hears the others' robots' commands, which is not a fault
            self.refused_unknown += 1
            self.log.debug("refused: %s", why)
            return
        r.refused += 1
        self.log.warning("refused: %s", why)

    def _apply(self, msg: RobotCommand) -> None:
        r = self.robots.get(msg.robot)
        if r is None:
            self._refuse(msg.robot, f"{type(msg).__name__}: no robot {msg.robot!r} in this world ({sorted(self.robots)})")
            return
        sender = msg.hdr.source.split("/")[1] if msg.hdr.source.count("/") >= 1 else ""
        if r.held and sender in r.gone and not isinstance(msg, CameraRequest):
            # sent before its node died and delivered after: it must not take the held robot back
            self._refuse(msg.robot, f"{msg.robot}: {type(msg).__name__} from node {sender!r}, whose controller "
                                    f"token is gone: the robot stays held")
            return
        try:
            if isinstance(msg, CameraRequest):
                self._camera(r, msg)
            elif isinstance(msg, ArmCommand):
                self._arm(r, msg)
            elif isinstance(msg, HandCommand):
                self._hand(r, msg)
            else:
                self._head(r, msg)
        except (CommandError, ValueError, KeyError) as exc:
            self._refuse(msg.robot, f"{msg.robot}: {type(msg).__name__}: {exc}")
            return
        if not isinstance(msg, CameraRequest):
            r.held = False

    def _hold(self, robot: str, why: str) -> None:
        r = self.robots.get(robot)
        if r is None or r.held or r.sim.failed:
            return
        r.held, r.held_at = True, self.tick_no
        for a in r.sim.arms:
            arm = r.sim.arm(a)
            arm.stream(arm.q(), np.zeros(len(arm.joints)))  # stop where it is; the hands keep their grip
        detail = f"{robot}: held by the world: {why}"
        self.log.warning(detail)
        self.io.emit(Event.HARDWARE_FAILURE, detail[:500], self._when())

    def _arm(self, r: _Robot, msg: ArmCommand) -> None:
        apply_arm(r.sim, msg)
        r.arm_seq[msg.arm] = max(r.arm_seq.get(msg.arm, 0), msg.seq)

    def _hand(self, r: _Robot, msg: HandCommand) -> None:
        apply_hand(r.sim, msg)
        r.hand_seq[msg.hand] = max(r.hand_seq.get(msg.hand, 0), msg.seq)

    def _head(self, r: _Robot, msg: HeadCommand) -> None:
        apply_head(r.sim, msg)

    def _stream_depth(self, r: _Robot) -> None:
        camera = r.sim.spec.cameras[0].name
        try:
            depth, K, Twc = r.sim.depth(camera)
        except Exception as exc:  # a camera that cannot render is a lost stream, not a dead world
            self.log.warning("%s: camera %s: %s", r.sim.name, camera, exc)
            return
        r.depth_seq += 1
        msg = DepthImage.of(depth, K, Twc, camera)
        r.depth_pub(self._encode(msg, f"{r.sim.name}/depth", r.depth_seq, self.world.time))

    def _stream_fixed(self, c: _FixedCamera, t: float) -> None:
        name = c.camera.spec.name
        try:
            depth, Twc = c.camera.read_depth(t)
        except Exception as exc:  # as a robot's camera: a lost stream, not a dead world
            self.log.warning("camera %s: %s", name, exc)
            return
        c.seq += 1
        c.pub(self._encode(DepthImage.of(depth, c.camera.K, Twc, name), f"camera/{name}", c.seq, t))

    def _camera(self, r: _Robot, msg: CameraRequest) -> None:
        """Answer ``msg`` with a frame, or with why there is none: a requester waits for its answer (in lockstep
        with the whole cell), so a camera that cannot render says so at once rather than by a timeout."""
        try:
            frame = r.sim.camera(msg.camera, labels=False)  # a CameraFrame carries no labels (they are evaluation's)
        except Exception as exc:  # as a streamed camera's: a lost frame, not a dead world
            error = f"{type(exc).__name__}: {exc}"[:500]
            self._answer(r, msg, CameraFrame(
                robot=r.sim.name, camera=msg.camera, request=msg.request, t=-1.0,
                depth=NDArray.of(np.zeros((0, 0), dtype=np.float32)), points=NDArray.of(np.zeros((0, 3))),
                pixels=NDArray.of(np.zeros((0, 2), dtype=np.int32)), K=[], pose=[], error=error))
            if isinstance(exc, (ValueError, KeyError)):
                raise  # a request the robot cannot take (an unknown camera) is refused as well, and logged there
            self.log.warning("%s: camera %s: %s", r.sim.name, msg.camera, error)
            return
        t = frame.t if np.isfinite(frame.t) else -1.0  # a lost stream that never delivered: stamped -inf here
        self._answer(r, msg, CameraFrame(robot=r.sim.name, camera=msg.camera, request=msg.request, t=t,
                                         depth=NDArray.of(np.asarray(frame.depth, dtype=np.float32)),
                                         points=NDArray.of(np.asarray(frame.points, dtype=np.float64)),
                                         pixels=NDArray.of(np.asarray(frame.pixels, dtype=np.int32)),
                                         K=[float(v) for v in np.asarray(frame.K).ravel()],
                                         pose=[float(v) for v in np.asarray(frame.T_world_cam).ravel()]))

    def _answer(self, r: _Robot, msg: CameraRequest, out: CameraFrame) -> None:
        # answered before the next tick's clock: the nodes may read it from that tick on
        r.camera_pub(self._encode(out, f"{r.sim.name}/camera", msg.request, self.world.time, clock=self.tick_no + 1))
