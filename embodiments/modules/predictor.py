"""A robot's predictor (thesis ch. 5): its own SAPIEN scene beside the robot, fed the robot's commands, compared with what it senses.

The module builds a simulation of what the robot believes: its embodiment at its base (the
world's description of the robot), the cell's fixtures and the objects of a *belief* scene
file (where the task thinks they are: the ATD's locations, not the world's truth), posed at
the robot's first measured joints. It subscribes the robot's command port, as the world does,
and the robot's state: for every world tick it applies the commands the world applied before
that tick (the state's ``applied`` sequence numbers say which), steps its scene by one tick
and, ``compare_hz`` times a simulated second, compares:

- its hands' contact points with the robot's fused contacts (``contacts/fused/<robot>/contacts``),
- its arm joints with the measured ones, its wrist loads with the measured external wrench,

through :class:`~contactflow.embodiments.prediction.MismatchDetector`. Each mismatch goes out
on ``predict/<robot>/mismatch`` and as a ``prediction_mismatch`` event, and the predictor
resynchronises its robot to the measured joints (also every ``resync`` s). What it predicts
goes out on ``predict/<robot>/state`` at ``publish_hz``. A look-ahead question on
``predict/<robot>/ask`` (a primitive and its parameters) is answered on ``predict/<robot>/ahead``
with what the primitive did in a copy of the predicted world (§5.5,
:mod:`~contactflow.embodiments.lookahead`). Nothing here reads ``eval/``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

import msgspec
import numpy as np

from contactflow.embodiments.messages import (
    ArmCommand,
    CameraRequest,
    HandCommand,
    HeadCommand,
    LookAheadEvent,
    LookAheadReply,
    LookAheadRequest,
    MismatchKind,
    PredictedState,
    PredictionMismatch,
    RobotInfo,
    RobotState,
)
from contactflow.embodiments.modules.world_module import (
    CommandError,
    apply_arm,
    apply_hand,
    apply_head,
)
from contactflow.embodiments.prediction import Mismatch, MismatchDetector, MismatchParams, held_mass
from contactflow.embodiments.primitives.base import TACTILE_CONTACT
from contactflow.fusion.messages import ContactList
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import EventMsg
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import NDArray
from contactflow.recognition.messages import SegmentedObjects

_commands = msgspec.msgpack.Decoder(ArmCommand | HandCommand | HeadCommand | CameraRequest)
MAX_PENDING = 4096  # commands kept while waiting for the states that apply them
MAX_HORIZON = 120.0  # s of simulated time a look-ahead may run
MAX_BACKLOG = 2000  # world ticks (10 s at 200 Hz) kept while the predictor is behind
NEAR_HAND = 0.12  # m, a seen object whose top centre is this close to a hand link (the robot's, as predicted) is left
SEEN_SETTLE = 0.01  # m, a seen object this close to its prediction is left (a frame's noise, a few mm, moves no grasp)


class Predictor(Module):
    """Simulates the robot from its commands and reports where prediction and sensing disagree."""

    layer = Layer.SERVICE
    inputs = (
        Port("state", RobotState, "the robot's state after each world tick"),
        Port("sensed", ContactList, "the robot's fused contacts, every cycle"),
        Port("perceived", EventMsg, "the robot's module events: object_detected places a believed object"),
        Port("ask", LookAheadRequest, "look-ahead questions: a primitive to run from the predicted state"),
        Port("seen", SegmentedObjects, "a vision node's segmented objects (wired: inputs: {seen: objects.objects}): "
             "each places the believed object it shows"),
    )
    outputs = (
        Port("predicted", PredictedState, "what the predictor holds after a world tick"),
        Port("mismatch", PredictionMismatch, "where prediction and sensing disagree"),
        Port("ahead", LookAheadReply, "look-ahead answers"),
    )
    events = (Event.PREDICTION_MISMATCH,)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz; each step predicts every world tick that came since the last
        belief: str = ""  # a scene file of what the robot believes: fixtures and objects (its robots are not read); "": the world's fixtures only
        window: float = 0.1  # s, how far in time a sensed and a predicted contact may lie apart
        radius: float = 0.08  # m, how far in space, for a sensed contact that names no hand
        hold: float = 0.3  # s the robot's fusion keeps a contact after its last sight (its tracker's hold)
        absent: float = 0.15  # s the robot's pads must feel nothing while the prediction presses them before a contact is missing
        sustain: float = 0.1  # s a predicted contact or a joint or load difference lasts before it counts
        joint_bound: float = 0.1  # rad, arm joints (thesis Fig. 5.16)
        object_bound: float = 0.025  # m, a detected object this far from its prediction is a mismatch (Fig. 5.16: 2.5 cm)
        force_bound: float = 5.0  # N, external wrist force where the hand is steady (free, or holding aloft): an object 0.5 kg heavier than believed
        quiet: float = 1.0  # s before the same kind at the same place is reported again
        resync: float = 1.0  # s between checks that resynchronise to the measured joints (0: only on a mismatch)
        resync_tol: float = 0.02  # rad: arm joints this close to the measured are left alone
        publish_hz: float = 20.0  # Hz of simulated time, predicted states on predict/<robot>/state
        compare_hz: float = 100.0  # Hz of simulated time the prediction is compared with the robot (contacts, loads, joints), every other 200 Hz tick: the scene still steps every tick
        command_wait: float = 0.5  # s of wall time a state waits for a command it says was applied
        reach: float = 0.1  # m, a detected object this close to a believed one (top centre, in the plane) is that one

    def __init__(self, name: str, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.robot = ""
        self._names: list[str] = []
        self.sim: Any = None  # the predictor's SimRobot
        self.world: Any = None
        self.detector: MismatchDetector | None = None
        self.mismatches: list[PredictionMismatch] = []
        self.tick = -1
        self.t = 0.0
        self.joint_error = 0.0
        self.force_error: dict[str, float] = {}
        self.missed = 0  # commands a state said were applied that never came
        self.ignored = 0  # commands the predictor could not apply (refused by the world too)
        self.refused = 0  # states of other joints than the robot's first state
        self.skipped = 0  # states dropped while the predictor was behind the world
        self.compute = 0.0  # s of wall time spent predicting ticks and deciding what differs
        self.resynced_objects = 0  # believed objects moved to where perception saw them
        self.resyncs = 0  # times the arms were put back at the measured joints
        self._touching = False  # the predicted hands touch something (no resynchronisation then)
        self._held: dict[str, str] = {}  # hand -> the one object it holds aloft in the prediction
        self._looking = False  # a look-ahead is under way, until its answer is queued
        self._asked_request = -1  # its request number
        self._answers: deque[LookAheadReply] = deque()  # look-ahead answers to publish (appended by its thread)
        self._pending: deque = deque()
        self._seen: dict[str, int] = {}  # part (arm or hand) -> highest command seq received
        self._lock = threading.Lock()
        self._states: deque[RobotState] = deque()
        self._last: RobotState | None = None  # the newest state predicted
        self._waiting_since: float | None = None
        self._published_at = -np.inf
        self._compared_at = -np.inf
        self._resynced_at = 0.0
        self._handles: list[Any] = []
        self._own_bodies: set[int] = set()
        self._hand_bodies: dict[int, tuple[str, str]] = {}
        self.log = logging.getLogger(f"contactflow.predictor.{name}")

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """The state the world publishes of the robot the module is hosted for, and the robot's fused contacts."""
        return {"state": ks.robot(robot, "state"), "sensed": ks.fused(robot, "contacts"),
                "perceived": ks.events(robot, "*", "*"), "ask": ks.predict(robot, "ask")}

    @classmethod
    def default_output_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        return {"predicted": ks.predict(robot, "state"), "mismatch": ks.predict(robot, "mismatch"),
                "ahead": ks.predict(robot, "ahead")}

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        p = self.params
        self._mismatch_params().validate(f"{self.name}.params")
        if p.publish_hz <= 0 or p.compare_hz <= 0 or p.resync < 0 or p.command_wait < 0 or p.reach <= 0 \
                or p.resync_tol < 0:
            raise ValueError(f"{self.name}.params: publish_hz, compare_hz and reach must be > 0, resync, resync_tol "
                             f"and command_wait >= 0")
        if p.belief:
            from contactflow.embodiments.scene_file import load_scene

            load_scene(p.belief)  # a bad belief file is refused now, naming its line, not at the first tick
        self.robot = io.robot
        self._handles.append(io.transport.subscribe(io.keyspace.robot(self.robot, "command"), self._on_command))

    def _mismatch_params(self) -> MismatchParams:
        p = self.params
        return MismatchParams(window=p.window, radius=p.radius, hold=p.hold, absent=p.absent, sustain=p.sustain,
                              joint_bound=p.joint_bound, force_bound=p.force_bound, object_bound=p.object_bound,
                              quiet=p.quiet)

    def stop(self) -> None:
        for h in self._handles:
            h.close()
        self._handles.clear()

    # -- zenoh callback: decode and queue -------------------------------------------------------
    def _on_command(self, key: str, payload: bytes) -> None:
        try:
            msg = _commands.decode(payload)
        except (msgspec.ValidationError, msgspec.DecodeError):
            return  # the world refuses and counts it; it never reaches the robot, nor the prediction
        if isinstance(msg, CameraRequest) or msg.robot != self.robot:
            return
        part = msg.arm if isinstance(msg, ArmCommand) else msg.hand if isinstance(msg, HandCommand) else "head"
        with self._lock:
            if len(self._pending) < MAX_PENDING:
                self._pending.append((part, getattr(msg, "seq", 0), msg))
                self._seen[part] = max(self._seen.get(part, 0), getattr(msg, "seq", 0))

    # -- the loop -------------------------------------------------------------------------------
    def step(self) -> Status:
        assert self.io is not None
        self._states.extend(self.io.take("state"))
        while len(self._states) > MAX_BACKLOG:  # behind the world: the oldest ticks are predicted in one go
            self._states.popleft()
            self.skipped += 1
        for msg in self.io.take("sensed"):
            if self.detector is not None:
                mine = [c for c in msg.contacts if c.robot in ("", self.robot)]
                self.detector.sense(msg.stamp, np.array([c.location for c in mine], dtype=np.float64).reshape(-1, 3),
                                    [c.link if c.link in self._hand_names else "" for c in mine])
        while self._states:
            state = self._states[0]
            if self.sim is None:
                self._build(state)
            elif state.tick <= self.tick or state.names != self._names or not np.isfinite(state.t):
                # a repeat of a tick (the world republishes while it waits), or not the robot this predictor models
                self.refused += state.tick > self.tick
                self._states.popleft()
                continue
            elif not self._commands_in(state):
                break
            else:
                began = time.perf_counter()
                self._predict(state)
                self.compute += time.perf_counter() - began
            self._states.popleft()
        if self.detector is not None:
            began = time.perf_counter()
            found = self.detector.check()
            self.compute += time.perf_counter() - began
            for m in found:
                self._report(m)
        for e in self.io.take("perceived"):
            if e.event is Event.OBJECT_DETECTED and self.sim is not None:
                self._perceived(e)
        for seen in self.io.take("seen"):
            if self.sim is not None:
                self._seen_objects(seen)
        for req in self.io.take("ask"):
            if req.robot == self.robot:
                self._ask(req)
        while self._answers:
            self.io.publish("ahead", self._answers.popleft())
        return Status.RUNNING

    # -- look-ahead (§5.5) ----------------------------------------------------------------------
    def _ask(self, req: LookAheadRequest) -> None:
        """Start a look-ahead from the predicted state on a thread of its own (it takes seconds: the node's
        ticks go on meanwhile); one at a time, and a request asked again while it runs is answered once."""
        from contactflow.embodiments.lookahead import Snapshot

        def refuse(why: str) -> None:
            self._answers.append(LookAheadReply(robot=self.robot, request=req.request, primitive=req.primitive,
                                                outcome="", duration=0.0, wall=0.0, error=why))

        if self.sim is None:
            return refuse("the predictor has no state of the robot yet")
        if self._looking:
            if req.request == self._asked_request:
                return None  # asked again while it runs: the one answer comes when it is done
            return refuse("busy with another look-ahead")
        if not (np.isfinite(req.horizon) and 0.0 < req.horizon <= MAX_HORIZON):
            return refuse(f"horizon {req.horizon!r} s is not in (0, {MAX_HORIZON:g}]")
        sim = self.sim
        snap = Snapshot(self.robot, sim.spec.name, sim.art.base.copy(), self._rate, sim.art.qpos(),
                        {a: np.asarray(sim.arm(a).q_cmd, dtype=np.float64).copy() for a in sim.arms},
                        tuple((o.spec if o.spec.static else replace(o.spec, mass=o.mass()), o.pose())
                              for o in self.world.objects.values()))  # what a load taught of a mass too
        self._asked_request = req.request
        self._looking = True
        threading.Thread(target=self._look, args=(snap, req), name=f"{self.name}-ahead", daemon=True).start()

    def _look(self, snap, req: LookAheadRequest) -> None:  # type: ignore[no-untyped-def]
        from contactflow.embodiments.lookahead import look_ahead

        try:
            out = look_ahead(snap, req.primitive, req.params, req.horizon)
        except Exception as exc:  # a bad primitive or parameter, or a world that failed to build: said, not raised
            self._looking = False
            self._answers.append(LookAheadReply(robot=self.robot, request=req.request, primitive=req.primitive,
                                                outcome="", duration=0.0, wall=0.0,
                                                error=f"{type(exc).__name__}: {exc}"[:500]))
            return
        # done before the answer goes out: a question asked on hearing it is not refused as "busy" by a thread
        # that has only its return left
        self._looking = False
        self._answers.append(LookAheadReply(
            robot=self.robot, request=req.request, primitive=req.primitive, outcome=out.outcome,
            duration=out.duration, wall=out.wall,
            events=[LookAheadEvent(t=t, event=e, detail=d[:300]) for t, e, d in out.events],
            objects=list(out.objects), moved=list(out.moved), tilted=list(out.tilted), touched=list(out.touched)))

    def _perceived(self, e: EventMsg) -> None:
        """§5.6, resynchronisation from perception: a detected object's top centre places the believed object."""
        v = e.values
        if {"tx", "ty", "top"} <= set(v):
            self._place(np.array([v["tx"], v["ty"]], dtype=np.float64), float(v["top"]), e.module, self._touched())

    def _seen_objects(self, msg: SegmentedObjects) -> None:
        """§5.7, the simulator synchronised with what the robot perceives: each segmented object's top centre (its
        top face, which the camera sees whole) places the believed object; but not one the robot's hand is at
        (within ``NEAR_HAND``): the hand hides part of it and the self filter cuts more, so its top centre is off,
        and the object is the task's, followed by the contacts."""
        from contactflow.embodiments.primitives.detect_objects import TOP_BAND

        hands = np.array([self.sim.art.link_pose(k.split("/", 1)[1])[:3, 3] for k in self._hand]).reshape(-1, 3)
        touched = self._touched()  # once per frame, not per object
        for obj in msg.objects:
            try:
                pts = obj.points.numpy().astype(np.float64).reshape(-1, 3)
            except (TypeError, ValueError):
                continue  # no points (a malformed message): nothing to place
            if len(pts) == 0 or not np.isfinite(pts).all():
                continue
            top = float(pts[:, 2].max())
            at = pts[pts[:, 2] >= top - TOP_BAND][:, :2].mean(axis=0)
            if len(hands) and float(np.linalg.norm(hands - np.array([*at, top]), axis=1).min()) < NEAR_HAND:
                continue
            self._place(at, top, msg.hdr.source, touched, SEEN_SETTLE)

    def _touched(self) -> set[str]:
        """The bodies the predicted robot touches now."""
        from contactflow.embodiments.sensors.ground_truth import body_name

        own = f"{self.robot}/"
        return {body_name(b) for c in self.world.contacts() for b in c.bodies
                if any(body_name(o).startswith(own) for o in c.bodies)}

    def _place(self, at: np.ndarray, top: float, source: str, touched: set[str], settle: float = 0.0) -> None:
        """Move the believed object nearest to ``at`` (within ``reach``, in the plane) there: it stands where it
        stood; unless it is in ``touched`` (the predicted robot touches it) or lies within ``settle`` m. More than
        ``object_bound`` away it is a mismatch too."""
        best, gap = None, self.params.reach
        for obj in self.world.objects.values():
            if obj.spec.static or obj.name in touched:
                continue
            d = float(np.linalg.norm(obj.pose()[:2, 3] - at))
            if d <= gap:
                best, gap = obj, d
        if best is None or gap < settle:
            return
        assert self.detector is not None
        found = self.detector.object(self.t, best.name, np.array([*at, top]), gap)
        if found is not None:
            self._report(found)
        T = best.pose()
        T[:2, 3] = at
        best.set_pose(T)
        self.resynced_objects += 1
        self.log.info("%s: %s moved %.1f mm to where %s saw it", self.robot, best.name, 1000 * gap, source)

    def status_detail(self) -> str:
        if self.sim is None:
            return "waiting for the robot's first state"
        return (f"tick {self.tick}: joint error {self.joint_error:.3f} rad, "
                f"{len(self.mismatches)} mismatch(es), {self.missed} command(s) missed")

    # -- building the prediction scene ----------------------------------------------------------
    def _build(self, state: RobotState) -> None:
        from contactflow.embodiments.remote import link
        from contactflow.embodiments.sim_robot import SimRobot, SimRobotParams
        from contactflow.embodiments.world import World, WorldParams

        assert self.io is not None
        info: RobotInfo = link(self.io.transport, self.io.keyspace, self.robot, self.io.node).info()
        self.world = world = World(WorldParams(camera_backend="raycast"))
        self._furnish(world, info)
        self.sim = sim = SimRobot(world, info.embodiment, name=self.robot,
                                  base=np.asarray(info.base, dtype=np.float64).reshape(4, 4),
                                  params=SimRobotParams(control_rate=info.control_rate, seed=info.seed + 7919,
                                                        watch_streams=False))
        self._every = max(1, int(round(1.0 / (info.control_rate * world.params.timestep))))
        self._rate = info.control_rate
        self._names = list(state.names)
        self._index = sim.art.indices(tuple(self._names))
        # each arm's joints among the state's, and all arms' (looked up every tick)
        self._arm_sel = [np.isin(self._index, sim.art.indices(a.joints)) for a in sim.spec.arms]
        self._arms_sel = np.logical_or.reduce(self._arm_sel) if self._arm_sel else np.zeros(len(self._index), bool)
        self._ft_arms = [a.name for a in sim.spec.arms if a.ft]
        self._arm_hand = {a.name: a.hand for a in sim.spec.arms}
        self._hand = self._hand_links(sim)
        self._hand_names = set(self._hand.values())
        # the robot's bodies, and its hands' (id of the physx component -> link, hand): what contacts are read by
        self._own_bodies = {id(lk) for lk in sim.art.links.values()}
        self._hand_bodies = {id(sim.art.links[k.split("/", 1)[1]]): (k.split("/", 1)[1], h) for k, h in self._hand.items()}
        self._payload = sim.spec.capabilities.payload if sim.spec.capabilities is not None else 0.0
        from contactflow.fusion.station import robot_cues

        self._cues = robot_cues(sim, 0.0)
        self._resync(state, commanded=True)
        self.detector = MismatchDetector(self._mismatch_params())
        self.tick, self.t, self._last = state.tick, state.t, state
        self.log.info("%s: predicting from tick %d (t=%.3f s) with objects %s", self.robot, state.tick, state.t,
                      sorted(n for n, o in world.objects.items() if not o.spec.static))

    def _furnish(self, world: Any, info: RobotInfo) -> None:
        """The believed cell: a belief scene file's fixtures and objects, else the world's fixtures."""
        from contactflow.embodiments.world import ObjectSpec, ShapeSpec

        if self.params.belief:
            from contactflow.embodiments.scene_file import load_scene
            from contactflow.embodiments.scenes import SCENES

            scene = load_scene(self.params.belief)
            if scene.scene:
                SCENES[scene.scene](world)
            for obj in scene.objects:
                world.add_object(obj)
            return
        for f in info.fixtures:
            if f.name == "floor":
                continue  # the world's ground
            obj = world.add_object(ObjectSpec(f.name, (ShapeSpec(f.kind, tuple(f.size)),), static=True, category="table"))
            obj.set_pose(np.asarray(f.pose, dtype=np.float64).reshape(4, 4))

    def _hand_links(self, sim: Any) -> dict[str, str]:
        """``robot/link`` -> hand of every link past the last joint of an arm with a hand: where fusion places contacts."""
        from contactflow.embodiments.hand_geometry import link_subtree

        out = {}
        for a in sim.spec.arms:
            if not a.hand:
                continue
            root = next(lk for lk in sim.art.links.values()
                        if lk.get_joint() is not None and lk.get_joint().get_name() == a.joints[-1])
            out |= {f"{self.robot}/{lk.get_name()}": a.hand for lk in link_subtree(root)}
        return out

    def _resync(self, state: RobotState, commanded: bool = False) -> None:
        """Put the predictor's robot at the measured joints: its arms only, only when they are ``resync_tol`` away
        and the predicted hands touch nothing (at the start: every joint, the arms at their commanded targets)."""
        art = self.sim.art
        q, qd = art.qpos(), art.qvel()
        measured, velocity = state.position.numpy(), state.velocity.numpy()
        self._resynced_at = state.t
        if not commanded:  # on a mismatch, or periodically
            if self._touching:
                return  # a hand teleported into what it touches would launch it: resynchronise once free
            arms = self._arms_sel
            if float(np.abs(q[self._index[arms]] - measured[arms]).max(initial=0.0)) <= self.params.resync_tol:
                return
            q[self._index[arms]], qd[self._index[arms]] = measured[arms], velocity[arms]
            art.articulation.set_qpos(q)
            art.articulation.set_qvel(qd)
            self.resyncs += 1
            return
        q[self._index] = measured
        art.set_state(q)
        self.sim.mixer.hold(q)
        for a in state.arms:
            self.sim.arm(a.name).stream(a.q_cmd.numpy(), np.zeros(len(a.q_cmd.numpy())))

    # -- one world tick -------------------------------------------------------------------------
    def _commands_in(self, state: RobotState) -> bool:
        """Whether every command ``state`` says the world applied has come (or waiting for it is over)."""
        applied = {a.name: a.applied for a in state.arms} | {h.name: h.applied for h in state.hands}
        with self._lock:
            short = [part for part, seq in applied.items() if seq > self._seen.get(part, 0)]
        if not short:
            self._waiting_since = None
            return True
        now = time.monotonic()
        self._waiting_since = self._waiting_since or now
        if now - self._waiting_since < self.params.command_wait:
            return False
        self.missed += len(short)
        self.log.warning("%s: tick %d: commands for %s the world applied never came", self.robot, state.tick, short)
        with self._lock:
            for part in short:
                self._seen[part] = applied[part]
        self._waiting_since = None
        return True

    def _predict(self, state: RobotState) -> None:
        applied = {a.name: a.applied for a in state.arms} | {h.name: h.applied for h in state.hands}
        with self._lock:
            due = [c for c in self._pending if c[1] <= applied.get(c[0], 0) or c[0] == "head"]
            self._pending = deque(c for c in self._pending if not (c[1] <= applied.get(c[0], 0) or c[0] == "head"))
        for _, _, msg in due:
            try:
                if isinstance(msg, ArmCommand):
                    apply_arm(self.sim, msg)
                elif isinstance(msg, HandCommand):
                    apply_hand(self.sim, msg)
                else:
                    apply_head(self.sim, msg)
            except (CommandError, ValueError, KeyError):
                self.ignored += 1
        self.world.step(self._every * max(1, state.tick - self.tick))
        self.tick, self.t, self._last = state.tick, state.t, state
        if state.t - self._compared_at >= 1.0 / self.params.compare_hz - 1e-9:
            self._compared_at = state.t
            self._compare(state)

    def _compare(self, state: RobotState) -> None:
        det = self.detector
        assert det is not None
        t = state.t
        q = self.sim.art.qpos()
        measured = state.position.numpy()
        worst, joint = 0.0, ""
        for sel in self._arm_sel:
            err = np.abs(q[self._index[sel]] - measured[sel])
            if err.size and float(err.max()) > worst:
                worst, joint = float(err.max()), state.names[int(np.flatnonzero(sel)[int(err.argmax())])]
        self.joint_error = worst
        found = det.joints(t, worst, joint)
        points, links, hands, felt, steady = self._contacts()
        det.touch(t, {s.hand for s in state.tactile if float(np.max(s.pressure.numpy(), initial=0.0)) > TACTILE_CONTACT})
        sensed = {w.arm: np.asarray(w.external_force, dtype=np.float64) for w in state.wrenches}
        forces = []
        for arm in self._ft_arms:
            f = np.asarray(self.sim.ft(arm).external[:3], dtype=np.float64)
            forces.append(f)
            if arm in sensed:
                self.force_error[arm] = float(np.linalg.norm(f - sensed[arm]))
                det.force(t, arm, f, sensed[arm], self._arm_hand[arm] in steady)
        det.predict(t, points, hands, felt)
        self._touching = len(points) > 0
        if found is not None:
            self._report(found)
        if self.params.resync > 0 and t - self._resynced_at >= self.params.resync:
            self._resync(state)
        if t - self._published_at >= 1.0 / self.params.publish_hz - 1e-9:
            self._published_at = t
            self._publish(state, points, links, hands, forces)

    def _felt(self) -> set[str]:
        """The hands whose predicted contact presses a pad of the predictor's own tactile sensors: a contact the
        robot's pads are expected to feel (what the wrist alone would feel is the load comparison's part)."""
        return {cue.hand for cue in self._cues
                if any(float(np.max(v)) > TACTILE_CONTACT for v in self.sim.tactile(cue.hand).values())}

    def _contacts(self) -> tuple[np.ndarray, list[str], list[str], set[str], set[str]]:
        """Contact points of the robot's hands with anything but the robot (with a force), their links and hands;
        the hands whose contact the robot would feel; and the *steady* hands: touching nothing, or only objects
        that touch nothing but the robot (held aloft). A hand pushing an object over the table, or setting it
        down, is not steady: there the load follows friction and timing the belief does not know.

        Only the hands' contacts are read, and those of what they touch (the step's contacts by body,
        ``World.contacts_of``), not every contact of the scene: this runs at every comparison (``compare_hz``)."""
        from contactflow.embodiments.sensors.ground_truth import body_name

        pts, links, hands = [], [], []
        own = self._own_bodies
        touching: dict[str, dict[int, Any]] = {}  # hand -> the bodies it touches, by id
        for c in self.world.contacts_of(self._hand_bodies):
            a, b = c.bodies
            if (id(a) in own) == (id(b) in own):
                continue  # the robot with itself
            link, other = (a, b) if id(a) in own else (b, a)
            pressed = [p.position for p in c.points if p.impulse.any()]
            if not pressed:
                continue
            name, hand = self._hand_bodies[id(link)]
            touching.setdefault(hand, {})[id(other)] = other
            pts += pressed
            links += [name] * len(pressed)
            hands += [hand] * len(pressed)
        touched = {i: o for bodies in touching.values() for i, o in bodies.items()}
        crowded: set[int] = set()  # touched bodies that touch another body than the robot
        for c in self.world.contacts_of(touched) if touched else ():
            a, b = c.bodies
            if id(a) not in own and id(b) not in own and any(p.impulse.any() for p in c.points):
                crowded |= {id(a), id(b)}
        static = {n for n, o in self.world.objects.items() if o.spec.static}
        steady = {h for h in self._hand_names
                  if not any(i in crowded or body_name(o) in static for i, o in touching.get(h, {}).items())}
        self._held = {h: body_name(next(iter(touching[h].values()))) for h in steady if len(touching.get(h, ())) == 1}
        return (np.array(pts, dtype=np.float64).reshape(-1, 3), links, hands, self._felt() if pts else set(),
                steady)

    def _publish(self, state: RobotState, points: np.ndarray, links: list[str], hands: list[str],
                 forces: list[np.ndarray]) -> None:
        assert self.io is not None
        objs = {n: o for n, o in self.world.objects.items() if not o.spec.static}
        q = self.sim.art.qpos()
        self.io.publish("predicted", PredictedState(
            robot=self.robot, tick=state.tick, t=state.t, names=list(state.names),
            position=NDArray.of(np.ascontiguousarray(q[self._index])), joint_error=self.joint_error,
            objects=list(objs), poses=NDArray.of(np.stack([o.pose() for o in objs.values()])) if objs else None,
            contacts=NDArray.of(points) if len(points) else None, contact_links=links, contact_hands=hands,
            arms=list(self._ft_arms),
            force=[float(v) for f in forces for v in f],
            force_error=[self.force_error.get(a, 0.0) for a in self._ft_arms], compute=self.compute))

    def _learn(self, m: Mismatch) -> str:
        """§5.7, the model follows the robot: a load that differs where a hand holds one object aloft is that
        object's weight, and its believed mass becomes what the wrist measures. Returns what changed ("": nothing;
        a difference that is no weight, a push or a pull beyond the arm's payload, teaches nothing)."""
        name = self._held.get(self._arm_hand.get(m.part, ""))
        obj = self.world.objects.get(name) if name else None
        if obj is None or obj.spec.static:
            return ""
        before = obj.mass()
        mass = held_mass(before, np.asarray(m.delta), self._payload)
        if mass is None:
            return ""
        obj.set_mass(mass)
        return f"{obj.name} weighs {mass:.3f} kg, not {before:.3f} kg"

    def _report(self, m: Mismatch) -> None:
        assert self.io is not None
        update = self._learn(m) if m.kind is MismatchKind.FORCE and m.delta else ""
        msg = PredictionMismatch(robot=self.robot, kind=m.kind, t=self.t, since=m.since, location=list(m.location),
                                 part=m.part, value=m.value if np.isfinite(m.value) else -1.0, bound=m.bound,
                                 detail=m.detail, update=update)
        self.mismatches.append(msg)
        self.io.publish("mismatch", msg)
        self.io.emit(Event.PREDICTION_MISMATCH, f"{self.robot}: {m.kind}: {m.detail}"[:500],
                     {"t": self.t, "since": m.since})
        self.log.info("%s: t=%.3f s: %s: %s%s", self.robot, self.t, m.kind, m.detail, f"; {update}" if update else "")
        if self._last is not None:
            self._resync(self._last)  # §5.6: back to what the robot measures, then predict on from there
