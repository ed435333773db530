"""The world module: scene files, commands and their refusal, the lockstep barrier, holding a robot whose controller died."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import yaml

from contactflow.embodiments.layout import world_node
from contactflow.embodiments.messages import (
    ArmCommand,
    ArmCommandKind,
    CameraFrame,
    CameraRequest,
    DepthImage,
    HandCommand,
    RobotState,
    TrueContacts,
)
from contactflow.embodiments.scene_file import parse_scene
from contactflow.embodiments.world import ScrewBottleSpec
from contactflow.nodes.config import parse_node_config
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Clock, EventMsg, LockstepAck, Mark
from contactflow.nodes.node import Node
from contactflow.nodes.procs import free_port, wait_for
from contactflow.nodes.status import Event
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import NDArray, decode, encode, stamp
from contactflow.nodes.yamldoc import ConfigError, YamlDoc

SCENE = """\
scene: table
robots:
  - {name: melfa}
objects:
  - {name: cube, kind: box, size: [0.05, 0.05, 0.05], xyz: [0.5, 0.2, 0.775]}
"""


@pytest.mark.parametrize("text, where", [
    ("robots:\n  - {name: walle}\n", r"scene.yaml:2: robots\[0\].embodiment: 'walle' is not a robot"),
    ("robots:\n  - {name: melfa, color: red}\n", r"scene.yaml:2: robots\[0\].color: unknown field"),
    ("robots: [{name: melfa}]\nobjects:\n  - {name: c, kind: box, radius: 0.1, size: [1, 1, 1], xyz: [0, 0, 1]}\n",
     r"scene.yaml:3: objects\[0\].radius: a box has no 'radius'"),
    ("robots: [{name: melfa}]\nobjects:\n  - {name: c, kind: sphere, radius: -1, xyz: [0, 0, 1]}\n",
     r"scene.yaml:3: objects\[0\].radius: expected a positive number"),
    ("robots: [{name: melfa, base: [0, 0]}]\n", r"scene.yaml:1: robots\[0\].base: expected 6 numbers"),
    ("robots: [{name: melfa}, {name: melfa}]\n", r"scene.yaml:1: robots\[1\].name: robot 'melfa' is placed twice"),
    ("scene: moon\nrobots: [{name: melfa}]\n", r"scene.yaml:1: scene: 'moon' is not one of"),
    ("robots: [{name: melfa}]\nobjects:\n  - name: c\n    xyz: [0, 0, 1]\n    shapes:\n"
     "      - {kind: box, size: [1, 1, 1], xyz: [0, 0]}\n", r"scene.yaml:6: objects\[0\].shapes\[0\].xyz: expected 3"),
    ("robots: [{name: melfa}]\nobjects:\n  - {name: c, kind: box, size: [1, 1, 1], xyz: [0, 0, 1], shapes: []}\n",
     r"scene.yaml:3: objects\[0\].kind: an object with shapes gives 'kind' per shape"),
    ("robots: [{name: melfa}]\nobjects:\n  - {name: b, kind: screw_bottle, xyz: [0, 0, 1], thread: 2}\n",
     r"scene.yaml:3: objects\[0\].thread: unknown field"),
    ("robots: [{name: melfa}]\nobjects:\n  - {name: b, kind: screw_bottle, xyz: [0, 0, 1], cap_radius: 0}\n",
     r"scene.yaml:3: objects\[0\].cap_radius: expected a positive number"),
    ("robots: [{name: melfa}]\nobjects:\n  - {name: b, kind: screw_bottle, xyz: [0, 0, 1], thread_turns: -1}\n",
     r"scene.yaml:3: objects\[0\].thread_turns: expected a non-negative number"),
    ("robots: [{name: melfa}]\nobjects:\n  - {name: b, kind: sphere, radius: 0.1, xyz: [0, 0, 1]}\n"
     "  - {name: b, kind: screw_bottle, xyz: [0, 0, 1]}\n", r"scene.yaml:4: objects\[1\].name: object 'b' is defined twice"),
    ("robots: [{name: melfa}]\ncameras:\n  - {name: head, eye: [0, 0, 1.5], target: [0.5, 0, 0.8]}\n"
     "  - {name: head, eye: [0, 1, 1.5], target: [0.5, 0, 0.8]}\n", r"scene.yaml:4: cameras\[1\].name: camera 'head' is placed twice"),
    ("robots: [{name: melfa}]\ncameras:\n  - {name: 'a/b', eye: [0, 0, 1.5], target: [0.5, 0, 0.8]}\n",
     r"scene.yaml:3: cameras\[0\].name: camera='a/b' is not a valid key segment"),
    ("robots: [{name: melfa}]\ncameras:\n  - {name: '*', eye: [0, 0, 1.5], target: [0.5, 0, 0.8]}\n",
     r"scene.yaml:3: cameras\[0\].name: a camera needs a name"),
    ("robots: [{name: melfa}]\ncameras:\n  - {name: head, eye: [0, 0], target: [0.5, 0, 0.8]}\n",
     r"scene.yaml:3: cameras\[0\].eye: expected 3 numbers"),
    ("robots: [{name: melfa}]\ncameras:\n  - {name: head, eye: [0, 0, 1], target: [0, 0, 1]}\n",
     r"scene.yaml:3: cameras\[0\].target: the camera looks at its own eye"),
    ("robots: [{name: melfa}]\ncameras:\n  - {name: head, eye: [0, 0, 1], target: [1, 0, 1], width: 4}\n",
     r"scene.yaml:3: cameras\[0\].width: expected a whole number of pixels in 8..4096"),
    ("robots: [{name: melfa}]\ncameras:\n  - {name: head, eye: [0, 0, 1], target: [1, 0, 1], fov: 60}\n",
     r"scene.yaml:3: cameras\[0\].fov: unknown field"),
])
def test_a_bad_scene_file_names_the_line_and_field(text, where):
    with pytest.raises(ConfigError, match=where):
        parse_scene(YamlDoc.parse(text, "scene.yaml"))


def test_objects_of_several_shapes_round_trip_through_a_scene_file():
    from contactflow.embodiments.bench_grasp import objects
    from contactflow.embodiments.scene_file import object_entry

    specs = objects()
    doc = yaml.safe_dump({"scene": "table", "robots": [{"name": "tombatossals"}],
                          "objects": [object_entry(s) for s in specs]})
    parsed = parse_scene(YamlDoc.parse(doc, "bench.yaml")).objects
    assert [(o.name, o.shapes, o.mass, o.xyz) for o in parsed] == [(s.name, s.shapes, s.mass, s.xyz) for s in specs]
    assert sum(len(o.shapes) > 1 for o in parsed) == 4  # car, spray, stapler, weight


def test_a_screw_bottle_in_a_scene_file_stands_free_unless_static():
    doc = ("robots: [{name: tombatossals}]\nobjects:\n"
           "  - {name: b1, kind: screw_bottle, xyz: [0.5, 0.0, 0.75], thread_turns: 0.5, cap_radius: 0.018}\n"
           "  - {name: b2, kind: screw_bottle, xyz: [0.6, 0.1, 0.75], static: true}\n")
    scene = parse_scene(YamlDoc.parse(doc, "scene.yaml"))
    assert scene.objects == ()
    b1, b2 = scene.bottles
    assert (b1.name, b1.xyz, b1.thread_turns, b1.cap_radius, b1.fixed) == ("b1", (0.5, 0.0, 0.75), 0.5, 0.018, False)
    assert b1.body_radius == ScrewBottleSpec("x", (0, 0, 0)).body_radius  # what the entry leaves out: the spec's default
    assert b2.fixed


class Client:
    """A hand-written controller session: state in, commands out (what a node's robot link does)."""

    def __init__(self, site: str, endpoint: str, robot: str = "melfa") -> None:
        self.ks = KeySpace(site)
        self.robot = robot
        self.t = ZenohTransport(ZenohSettings(connect=(endpoint,))).open()
        self.states: list[RobotState] = []
        self.clocks: list[Clock] = []
        self.events: list[EventMsg] = []
        self.frames: list[CameraFrame] = []
        self._lock = threading.Lock()
        self._cmd = self.t.publisher(self.ks.robot(robot, "command"))
        self._ack = self.t.publisher(self.ks.lockstep("tester"))
        self._subs = [
            self.t.subscribe(self.ks.robot(robot, "state"), lambda k, p: self._add(self.states, decode(p, RobotState, k))),
            self.t.subscribe(self.ks.clock(), lambda k, p: self._add(self.clocks, decode(p, Clock, k))),
            self.t.subscribe(self.ks.events(), lambda k, p: self._add(self.events, decode(p, EventMsg, k))),
            self.t.subscribe(self.ks.robot(robot, "camera"), lambda k, p: self._add(self.frames, decode(p, CameraFrame, k))),
        ]

    def _add(self, where: list, msg) -> None:
        with self._lock:
            where.append(msg)

    @property
    def state(self) -> RobotState:
        with self._lock:
            return self.states[-1]

    def send(self, msg) -> None:
        self._cmd(encode(msg))

    def ack(self, tick: int, marks: list[Mark] | None = None, working: bool = False, node: str = "tester") -> None:
        self._ack(encode(LockstepAck(node=node, tick=tick, marks=marks or [], working=working)))

    def close(self) -> None:
        for s in self._subs:
            s.close()
        self.t.close()


def start_world(tmp_path, scene_text: str = SCENE, robot: str = "melfa", **params) -> tuple[Node, Client]:
    """A world node on a free port with ``scene_text``, and a controller session on it that got states."""
    scene = tmp_path / "cell.yaml"
    scene.write_text(scene_text)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    site = f"w{free_port()}"
    node = Node(parse_node_config(YamlDoc.parse(
        yaml.safe_dump(world_node(site, scene, listen=endpoint, **params)), "world.yaml")))
    node.start()
    client = Client(site, endpoint, robot)
    assert wait_for(lambda: len(client.states) > 5, 30)
    return node, client


@pytest.fixture
def world(tmp_path):
    node, client = start_world(tmp_path)
    yield node.host.modules[("site", "world")].module, client
    client.close()
    node.stop()


def arm_cmd(kind: ArmCommandKind, values=None, seq: int = 1, **kw) -> ArmCommand:
    return ArmCommand(robot=kw.pop("robot", "melfa"), arm=kw.pop("arm", "arm"), kind=kind, seq=seq,
                      values=None if values is None else NDArray.of(np.asarray(values, dtype=np.float64)), **kw)


def test_commands_outside_the_robot_are_refused_counted_and_never_applied(world):
    wm, c = world
    q0 = c.state.position.numpy().copy()
    home = np.array(wm.robots["melfa"].sim.spec.arm("arm").home)
    zero = np.zeros(6)
    bad = [
        arm_cmd(ArmCommandKind.TARGET, [home + [10.0, 0, 0, 0, 0, 0], zero]),  # outside the joint limits
        arm_cmd(ArmCommandKind.TARGET, [[np.nan] * 6, zero]),
        arm_cmd(ArmCommandKind.TARGET, [home, [0.0, 0, np.inf, 0, 0, 0]]),
        arm_cmd(ArmCommandKind.TARGET, home),  # wrong shape: a position without its velocity
        arm_cmd(ArmCommandKind.TARGET),  # no values
        arm_cmd(ArmCommandKind.TARGET, [home, zero], arm="left"),  # no such arm
        HandCommand(robot="melfa", hand="gripper", seq=1, preshape="fist"),
        HandCommand(robot="melfa", hand="gripper", seq=2, preshape="open", effort=3.0),
    ]
    for m in bad:
        c.send(m)
    assert wait_for(lambda: c.state.refused == len(bad), 10), c.state.refused
    # a command naming another robot than its key, and a robot the world does not have
    c.send(arm_cmd(ArmCommandKind.TARE, robot="baxter"))
    other = ZenohTransport(ZenohSettings(connect=c.t.settings.connect)).open()
    other.publisher(c.ks.robot("walle", "command"))(encode(arm_cmd(ArmCommandKind.TARE, robot="walle")))
    assert wait_for(lambda: c.state.refused == len(bad) + 1 and wm.refused_unknown == 1, 10)
    other.close()
    assert np.abs(c.state.position.numpy()[:6] - q0[:6]).max() < 0.02  # nothing moved the arm
    assert not c.state.held and not c.state.failed
    # a valid command after all that is applied, and its sequence number comes back
    target = home + [0.2, 0, 0, 0, 0, 0]
    c.send(arm_cmd(ArmCommandKind.TARGET, [target, zero], seq=7))
    names = c.state.names
    idx = [names.index(j) for j in wm.robots["melfa"].sim.spec.arm("arm").joints]
    assert wait_for(lambda: c.state.arms[0].applied == 7, 20)
    assert c.state.arms[0].q_cmd.numpy() == pytest.approx(target)
    assert wait_for(lambda: np.abs(c.state.position.numpy()[idx] - target).max() < 0.01, 20)  # the drives hold it


def test_a_lockstep_node_holds_the_world_at_each_tick_until_it_answers(world):
    wm, c = world
    token = c.t.token(c.ks.alive_lockstep("tester"))
    assert wait_for(lambda: "tester" in wm._lockstep, 10)
    time.sleep(0.3)
    k = wm.tick_no
    time.sleep(0.5)
    assert wm.tick_no == k  # waiting for the tester's answer to tick k
    sent = Mark(key="cf/x/data/out", source="site/tester/m/out", seq=7)
    for i in range(3):
        c.ack(k + i, [sent] if i == 1 else [])
        # a node answers a tick once its clock came (the world counts the tick before it publishes it)
        assert wait_for(lambda i=i: wm.tick_no == k + i + 1 and any(m.tick == k + i + 1 for m in c.clocks), 5)
    time.sleep(0.3)
    assert wm.tick_no == k + 3
    ticks = [m.tick for m in c.clocks if m.tick >= k]
    assert {k + 1, k + 2, k + 3} <= set(ticks)
    # what the node said it sent during tick k+1 comes with tick k+2 (its subscribers wait for it), and only then
    marks = {m.tick: m.marks for m in c.clocks if m.tick > k}
    assert marks[k + 2] == [sent] and marks[k + 1] == [] and marks[k + 3] == []
    # a forged answer for a tick far ahead is refused: the world still waits for the node's real answer
    c.ack(2**62)
    time.sleep(0.5)
    assert wm.tick_no == k + 3 and wm.refused_acks == 1
    c.ack(k + 3)
    assert wait_for(lambda: wm.tick_no == k + 4, 5)
    token.close()  # gone: the world runs on without it
    assert wait_for(lambda: wm.tick_no > k + 50, 10)
    assert wm.overruns == 0


def test_a_pipelined_world_steps_a_tick_ahead_of_its_nodes_and_applies_what_they_sent_during_tick_k_after_tick_k_plus_1(
        tmp_path):
    """``pipeline``: tick k+1 runs once the nodes answered tick k-1 (world and nodes step at once); a command sent
    during tick k applies at the step after tick k+1, whenever it arrives, and what a node sent during tick k
    is marked on the clock of tick k+2. The world's messages say the tick they are inputs from."""
    node, c = start_world(tmp_path, pipeline=True)
    wm = node.host.modules[("site", "world")].module
    try:
        token = c.t.token(c.ks.alive_lockstep("tester"))
        assert wait_for(lambda: "tester" in wm._lockstep, 10)
        time.sleep(0.3)
        k = wm.tick_no
        time.sleep(0.5)
        assert wm.tick_no == k  # waiting for the tester's answer to tick k-1
        c.ack(k - 1)
        assert wait_for(lambda: wm.tick_no == k + 1, 5)
        time.sleep(0.3)
        assert wm.tick_no == k + 1  # ... and now for its answer to tick k
        clock = next(m for m in c.clocks if m.tick == k + 1)
        state = next(s for s in c.states if s.tick == k + 1)
        assert clock.lag == 1 and clock.hdr.tick == state.hdr.tick == k - 1  # inputs of the nodes from tick k+1 on
        home = np.array(wm.robots["melfa"].sim.spec.arm("arm").home)
        early = arm_cmd(ArmCommandKind.TARGET, [home + [0.1, 0, 0, 0, 0, 0], np.zeros(6)], seq=5)
        early.hdr.tick = k + 1  # sent while stepping tick k+1, ahead of the world's wait: not due yet
        c.send(early)
        sent = Mark(key="cf/x/data/out", source="site/tester/m/out", seq=7)
        time.sleep(0.3)
        c.ack(k, [sent])
        assert wait_for(lambda: any(s.tick == k + 2 for s in c.states), 5)
        assert next(s for s in c.states if s.tick == k + 2).arms[0].applied == 0  # tick k+1's command waits
        c.ack(k + 1)
        assert wait_for(lambda: any(s.tick == k + 3 for s in c.states), 5)
        assert next(s for s in c.states if s.tick == k + 3).arms[0].applied == 5
        marks = {m.tick: m.marks for m in c.clocks if m.tick > k}
        assert marks[k + 1] == [] and marks[k + 2] == [sent] and marks[k + 3] == []
        # a command that says a tick the world has not reached is forged: applied (or refused) at once, never kept
        forged = arm_cmd(ArmCommandKind.TARGET, [home, np.zeros(6)], seq=6)
        forged.hdr.tick = 2**62
        c.send(forged)
        c.ack(k + 2)
        assert wait_for(lambda: any(s.tick == k + 4 for s in c.states), 5)
        assert next(s for s in c.states if s.tick == k + 4).arms[0].applied == 6 and not wm._commands
        token.close()
        assert wait_for(lambda: wm.tick_no > k + 50, 10)
        assert wm.overruns == 0
    finally:
        c.close()
        node.stop()


def test_a_lockstep_token_zenoh_drops_and_re_learns_keeps_the_answer_the_node_gave(world):
    """A peer's liveliness tokens can vanish and come back while the peer lives (zenoh re-routing): a node that
    answered the current tick and whose token flickers is not waited for again; the world ticks on once the
    other node answers (it stalled 10 s and held the robot in a demo)."""
    wm, c = world
    tokens = {n: c.t.token(c.ks.alive_lockstep(n)) for n in ("tester", "other")}
    assert wait_for(lambda: {"tester", "other"} <= wm._lockstep, 10)
    time.sleep(0.3)
    k = wm.tick_no
    c.ack(k)  # the tester answered tick k; the world waits for the other node
    time.sleep(0.3)
    assert wm.tick_no == k
    tokens["tester"].close()
    assert wait_for(lambda: "tester" not in wm._lockstep, 5)
    tokens["tester"] = c.t.token(c.ks.alive_lockstep("tester"))
    assert wait_for(lambda: "tester" in wm._lockstep, 5)
    assert wm.tick_no == k  # (its answer alone moved nothing)
    c.ack(k, node="other")
    assert wait_for(lambda: wm.tick_no == k + 1, 5)  # the tester's answer of tick k counts: not asked again
    for t in tokens.values():
        t.close()
    assert wm.overruns == 0


def test_a_controller_token_that_comes_back_within_the_grace_holds_nothing_and_one_that_stays_away_does(world):
    wm, c = world
    token = c.t.token(c.ks.alive_controller("melfa", "tester"))
    assert wait_for(lambda: "tester" in wm.robots["melfa"].controllers, 10)
    token.close()
    assert wait_for(lambda: "tester" not in wm.robots["melfa"].controllers, 5)
    token = c.t.token(c.ks.alive_controller("melfa", "tester"))  # back within gone_grace (1 s)
    assert wait_for(lambda: "tester" in wm.robots["melfa"].controllers, 5)
    time.sleep(wm.params.gone_grace + 0.5)
    assert not wm.robots["melfa"].held and not c.state.held
    assert not any(e.event is Event.HARDWARE_FAILURE for e in c.events)
    t0 = time.monotonic()
    token.close()  # for good: held once the grace has passed
    assert wait_for(lambda: c.state.held, 10)
    assert time.monotonic() - t0 >= wm.params.gone_grace
    assert wait_for(lambda: any(e.event is Event.HARDWARE_FAILURE and "['tester'] gone" in e.detail
                                for e in c.events), 5)


def test_a_lockstep_node_that_says_it_is_still_working_is_waited_for_up_to_max_step_then_held(tmp_path):
    node, c = start_world(tmp_path, deadline=1.0, max_step=4.0)
    try:
        wm = node.host.modules[("site", "world")].module
        tokens = [c.t.token(c.ks.alive_lockstep("tester")), c.t.token(c.ks.alive_controller("melfa", "tester"))]
        assert wait_for(lambda: "tester" in wm._lockstep and "tester" in wm.robots["melfa"].controllers, 10)
        time.sleep(0.3)
        k = wm.tick_no
        # working on tick k for 2.5 s, a note every 0.3 s: past the 1 s deadline, the world waits and holds nothing
        for _ in range(8):
            c.ack(k, working=True)
            time.sleep(0.3)
        assert wm.tick_no == k and wm.overruns == 0 and not wm.robots["melfa"].held
        c.ack(k + 5, working=True)  # a note for a tick not published yet is forged: refused
        assert wait_for(lambda: wm.refused_acks == 1, 5) and wm.tick_no == k
        c.ack(k)
        assert wait_for(lambda: wm.tick_no == k + 1, 5)
        # the notes stop (the node froze): held one deadline after the last
        c.ack(k + 1, working=True)
        t0 = time.monotonic()
        assert wait_for(lambda: wm.overruns == 1, 5) and 0.8 < time.monotonic() - t0 < 2.0
        assert wait_for(lambda: wm.robots["melfa"].held, 5)
        assert wait_for(lambda: any(e.event is Event.OVERRUN and "did not answer within 1 s" in e.detail
                                    for e in c.events), 5)
        # a node that keeps saying it works on one tick (a loop stuck in a module) is held after max_step
        c.send(stamp(arm_cmd(ArmCommandKind.TARE, seq=1), "melfa/tester/m/cmd", 1, 0.0))  # takes the robot back
        assert wait_for(lambda: not wm.robots["melfa"].held, 5)
        k = wm.tick_no  # (the world waits a deadline at each tick the stalled node does not answer)
        c.ack(k)
        assert wait_for(lambda: wm.tick_no == k + 1, 5)
        base, t0 = wm.overruns, time.monotonic()
        while wm.overruns == base and time.monotonic() - t0 < 8.0:
            c.ack(k + 1, working=True)
            time.sleep(0.3)
        assert wm.overruns == base + 1 and 3.5 < time.monotonic() - t0 < 5.0
        assert wait_for(lambda: wm.robots["melfa"].held, 5)
        assert wait_for(lambda: any(e.event is Event.OVERRUN and "still working on it after 4 s" in e.detail
                                    for e in c.events), 5)
        for tok in tokens:
            tok.close()
    finally:
        c.close()
        node.stop()


def test_the_world_holds_a_robot_whose_controller_is_gone_and_raises_hardware_failure(world):
    wm, c = world
    token = c.t.token(c.ks.alive_controller("melfa", "tester"))
    assert wait_for(lambda: "tester" in wm.robots["melfa"].controllers, 10)
    idx = [c.state.names.index(j) for j in wm.robots["melfa"].sim.spec.arm("arm").joints]
    q0 = c.state.position.numpy()[idx].copy()
    far = q0 + [1.5, 0, 0, 0, 0, 0]
    c.send(arm_cmd(ArmCommandKind.TARGET, [far, np.zeros(6)], seq=1))
    assert wait_for(lambda: c.state.arms[0].applied == 1, 10)
    # on its way (the free-running world may already have brought it there: it is held where it is either way)
    assert wait_for(lambda: np.abs(c.state.position.numpy()[idx] - q0).max() > 0.05, 10)
    token.close()  # the controller dies
    assert wait_for(lambda: c.state.held, 10)
    assert wait_for(lambda: any(e.event is Event.HARDWARE_FAILURE and "melfa" in e.detail for e in c.events), 5)
    # the header carries the world node's one clock (wall, as its status does); the values the simulated time
    fault = next(e for e in c.events if e.event is Event.HARDWARE_FAILURE)
    assert fault.values["t"] == pytest.approx(c.state.held_at / wm.params.control_rate + wm._t0_sim, abs=0.05)
    assert fault.values["tick"] == pytest.approx(c.state.held_at, abs=10)
    assert fault.hdr.t_sim == pytest.approx(time.time(), abs=10.0)
    # the arm stops where it was and stays there: it comes to rest, held, within its settling (a free-running world
    # on a loaded machine had not settled 0.5 s of wall time after the hold: 1.3 mrad still to go)
    assert wait_for(lambda: np.abs(c.state.velocity.numpy()[idx]).max() < 0.001, 10)
    q1 = c.state.position.numpy()[idx].copy()
    time.sleep(0.5)
    assert np.abs(c.state.position.numpy()[idx] - q1).max() < 1e-3
    assert np.abs(c.state.velocity.numpy()[idx]).max() < 0.01
    # a command the dead node sent late does not take the robot back (it is refused and counted)
    refused = c.state.refused
    c.send(stamp(arm_cmd(ArmCommandKind.TARGET, [far, np.zeros(6)], seq=2), "melfa/tester/m/cmd", 2, 0.0))
    assert wait_for(lambda: c.state.refused == refused + 1, 10)
    time.sleep(0.3)
    assert c.state.held and np.abs(c.state.velocity.numpy()[idx]).max() < 0.01
    # a new controller's command takes the robot back
    c.send(stamp(arm_cmd(ArmCommandKind.TARE, seq=3), "melfa/newcomer/m/cmd", 1, 0.0))
    assert wait_for(lambda: not c.state.held, 10)


def test_a_node_linked_to_a_robot_becomes_its_controller_with_its_first_command_not_by_reading_it(world):
    from contactflow.embodiments.remote import RobotLink

    wm, c = world
    link = RobotLink(c.t, c.ks, "melfa", "reader")
    try:
        link.wait_state()
        link.send(CameraRequest(robot="melfa", camera="none", request=7))  # asking for a frame reads the robot
        time.sleep(0.5)
        assert "reader" not in wm.robots["melfa"].controllers and not c.state.held
        link.send(arm_cmd(ArmCommandKind.TARE, seq=1))
        assert wait_for(lambda: "reader" in wm.robots["melfa"].controllers, 10)
        # applied before the link goes (a command applied after the hold would take the robot back)
        assert wait_for(lambda: c.state.arms[0].applied == 1, 10)
    finally:
        link.close()
    # the link went, and with it the robot's only controller: the world holds the robot
    assert wait_for(lambda: c.state.held, 10)


def test_a_camera_request_is_answered_with_a_frame_of_that_tick(tmp_path):
    node, c = start_world(tmp_path, SCENE.replace("{name: melfa}", "{name: tombatossals}"), "tombatossals",
                          camera_backend="raycast")
    try:
        c.send(CameraRequest(robot="tombatossals", camera="kinect", request=42))
        c.send(CameraRequest(robot="tombatossals", camera="eye", request=43))  # no such camera: refused
        assert wait_for(lambda: len(c.frames) == 2, 30)
        f, eye = sorted(c.frames, key=lambda m: m.request)
        assert f.request == 42 and not f.error and len(f.points.numpy()) > 1000
        pts = f.points.numpy()
        # the cube is in the frame: points on its top face
        top = pts[(np.abs(pts[:, 0] - 0.5) < 0.02) & (np.abs(pts[:, 1] - 0.2) < 0.02)]
        assert len(top) and top[:, 2].max() == pytest.approx(0.80, abs=0.01)
        assert wait_for(lambda: c.state.refused == 1, 10)
        # the refused request is answered too, with why: its requester does not wait out a timeout
        assert eye.request == 43 and "eye" in eye.error and eye.t == -1.0 and len(eye.points.numpy()) == 0, eye.error
    finally:
        c.close()
        node.stop()


def test_the_depth_stream_keeps_its_rate_between_ticks(tmp_path):
    # 30 Hz is not a whole number of 200 Hz ticks: the frames alternate 6 and 7 ticks apart, 30 a second
    node, c = start_world(tmp_path, SCENE.replace("{name: melfa}", "{name: tombatossals}"), "tombatossals",
                          camera_backend="raycast", camera_hz=30.0)
    stamps: list[float] = []
    sub = c.t.subscribe(c.ks.robot("tombatossals", "depth"), lambda k, p: stamps.append(decode(p, DepthImage, k).hdr.t_sim))
    try:
        assert wait_for(lambda: len(stamps) >= 40, 60)
        t = np.array(stamps[:40])
        assert np.count_nonzero((t >= t[0]) & (t < t[0] + 1.0 - 1e-9)) == 30
        assert set(np.round(np.diff(t) * 200).astype(int)) <= {6, 7}
    finally:
        sub.close()
        c.close()
        node.stop()


def test_a_fixed_camera_of_the_scene_streams_depth_of_the_cell_on_its_own_key(tmp_path):
    """A camera no robot carries (a scene file's ``cameras``): its frames on ``camera/<name>/depth``, at camera_hz,
    seeing the cube from where the scene file puts it."""
    scene = SCENE + "cameras:\n  - {name: head, eye: [-0.1, 0.2, 1.45], target: [0.5, 0.2, 0.775], width: 160, height: 120}\n"
    node, c = start_world(tmp_path, scene, "melfa", camera_backend="raycast", camera_hz=10.0)
    frames: list[DepthImage] = []
    sub = c.t.subscribe(c.ks.camera("head"), lambda k, p: frames.append(decode(p, DepthImage, k)))
    try:
        assert wait_for(lambda: len(frames) >= 5, 60)
        from contactflow.recognition.geometry import depth_to_points
        from contactflow.recognition.messages import depth_arrays

        f = frames[-1]
        depth, K, T = depth_arrays(f)
        assert f.camera == "head" and depth.shape == (120, 160) and np.allclose(T[:3, 3], [-0.1, 0.2, 1.45])
        t = np.array([m.hdr.t_sim for m in frames[:5]])
        assert np.allclose(np.diff(t), 0.1, atol=1e-6)  # 10 Hz of simulated time
        pts = depth_to_points(depth, K, T)
        top = pts[(np.abs(pts[:, 0] - 0.5) < 0.015) & (np.abs(pts[:, 1] - 0.2) < 0.015)]
        assert len(top) and top[:, 2].max() == pytest.approx(0.80, abs=0.01)  # the cube's top face
    finally:
        sub.close()
        c.close()
        node.stop()


def test_each_robots_true_contacts_with_the_objects_go_to_eval_only_with_contacts_hz(tmp_path):
    # a fixed block around melfa's open fingers at home: they press on it from the first tick
    block = "  - {name: block, kind: box, size: [0.12, 0.12, 0.06], xyz: [0.388, 0.109, 1.01], static: true}\n"
    node, c = start_world(tmp_path, SCENE + block, contacts_hz=50.0)
    truths: list[TrueContacts] = []
    sub = c.t.subscribe(c.ks.evaluation("melfa", "true_contacts"), lambda k, p: truths.append(decode(p, TrueContacts, k)))
    try:
        assert wait_for(lambda: len(truths) >= 3, 30)
        msg = truths[-1]
        pts, normals, forces = msg.positions.numpy(), msg.normals.numpy(), msg.forces.numpy()
        assert len(forces) >= 1 and np.all(forces > 0)
        assert all(b.startswith("melfa/") for b in msg.body_a) and set(msg.body_b) == {"block"}  # not the far cube
        lo, hi = np.array([0.328, 0.049, 0.98]), np.array([0.448, 0.169, 1.04])
        assert np.all((pts > lo - 0.01) & (pts < hi + 0.01)), pts
        assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-3)
        assert msg.hdr.source.endswith("/melfa/true_contacts") and msg.hdr.t_sim > 0
    finally:
        sub.close()
        c.close()
        node.stop()
    node, c = start_world(tmp_path, SCENE + block)  # off by default
    quiet: list[bytes] = []
    sub = c.t.subscribe(c.ks.evaluation("melfa", "true_contacts"), lambda k, p: quiet.append(p))
    try:
        n = len(c.states)
        assert wait_for(lambda: len(c.states) > n + 20, 30)
        assert not quiet
    finally:
        sub.close()
        c.close()
        node.stop()


def test_a_realtime_world_follows_the_wall_clock_and_counts_late_commands(tmp_path):
    node, c = start_world(tmp_path, clock="realtime")
    try:
        t0, w0 = c.state.t, time.monotonic()
        time.sleep(1.5)
        rate = (c.state.t - t0) / (time.monotonic() - w0)
        assert rate == pytest.approx(1.0, abs=0.15)
        # a command answering a state a second old arrives long after the tick it was meant for
        assert c.state.late == 0
        late = arm_cmd(ArmCommandKind.TARE, seq=1)
        late.hdr.t_sim = c.state.t - 1.0
        c.send(late)
        assert wait_for(lambda: c.state.arms[0].applied == 1, 5)
        assert c.state.late == 1
    finally:
        c.close()
        node.stop()


def test_a_remote_robot_clips_joint_targets_to_the_limits_as_the_simulated_robot_does(world):
    """A target just past a limit (holding the measured joints of an arm resting there: encoders read past
    it) goes to the limit, as on the simulated robot; the world never refuses what the facade sends."""
    from contactflow.embodiments.remote import connect

    wm, c = world
    r = connect(c.t, c.ks, "melfa", "tester")
    arm, hand = r.arm("arm"), r.hand("gripper")
    hand.set_fingers(hand.upper + 1e-3)
    past = np.asarray(wm.robots["melfa"].sim.arm("arm").q_cmd, dtype=np.float64).copy()
    past[5] = arm.upper[5] + 1e-3
    arm.move_joints(past, speed=4.0)  # the wrist turns a whole turn to its limit
    # no node hosts this facade: the test steps its arm controller, as a node's tick hook would
    assert wait_for(lambda: r.after_tick() or (c.state.arms[0].applied >= 1 and c.state.hands[0].applied >= 1), 10, 0.005)
    assert c.state.refused == 0
    assert wait_for(lambda: r.after_tick() or abs(c.state.arms[0].q_cmd.numpy()[5] - arm.upper[5]) < 1e-4, 30, 0.005), c.state.arms[0]
    # what the facade clips is still refused from a client that sends it raw (the world's own check)
    c.send(arm_cmd(ArmCommandKind.TARGET, [past, np.zeros(6)], seq=9))
    assert wait_for(lambda: c.state.refused == 1, 10)


def test_each_tick_the_joints_come_on_their_own_stream_too(world):
    """A subscriber that needs only the joints (the vision node's self filter) reads them without the robot's state."""
    from contactflow.embodiments.messages import JointState, RobotState

    wm, c = world
    got: dict[str, dict[int, object]] = {"joints": {}, "state": {}}
    subs = [c.t.subscribe(c.ks.robot("melfa", s), lambda k, p, s=s, t=t: got[s].setdefault((m := decode(p, t, k)).hdr.seq, m))
            for s, t in (("joints", JointState), ("state", RobotState))]
    try:
        assert wait_for(lambda: len(set(got["joints"]) & set(got["state"])) >= 5, 10)
    finally:
        for s in subs:
            s.close()
    for seq in sorted(set(got["joints"]) & set(got["state"]))[:5]:
        j, s = got["joints"][seq], got["state"][seq]
        assert j.robot == "melfa" and j.names == s.names and j.hdr.t_sim == s.hdr.t_sim
        assert np.array_equal(j.position.numpy(), s.position.numpy())
        assert j.effort.numpy().shape == (len(s.names),) and np.all(np.isfinite(j.effort.numpy()))


def test_a_remote_arm_runs_its_controller_on_the_node_and_streams_joint_targets_the_world_holds(world):
    """The world takes joint targets only: the pose move is computed by the facade's controller, one target per
    step of the node; when the node stops stepping, the arm rests where the last target put it."""
    from contactflow.embodiments.remote import connect

    wm, c = world
    r = connect(c.t, c.ks, "melfa", "tester")
    arm = r.arm("arm")
    kinds: list[str] = []
    sub = c.t.subscribe(c.ks.robot("melfa", "command"), lambda k, p: kinds.append(decode(p, ArmCommand, k).kind))
    try:
        start = arm.ee_pose()
        goal = start.copy()
        goal[:3, 3] += [0.0, 0.03, -0.02]
        arm.move_pose(goal, speed=0.1)
        time.sleep(0.5)  # the world runs on, the node does not step: nothing moves the arm
        assert kinds == [] and arm.status.value == "running"
        assert np.linalg.norm(arm.ee_pose()[:3, 3] - start[:3, 3]) < 1e-3
        assert wait_for(lambda: r.after_tick() or arm.done(), 30, 0.005)
        assert arm.status.value == "success", arm.abort_reason
        assert wait_for(lambda: len(kinds) == c.state.arms[0].applied, 5)
        assert set(kinds) == {ArmCommandKind.TARGET} and len(kinds) > 20  # one per step while the move ran
        time.sleep(0.5)  # no more targets: the arm rests at the goal, its last velocity target not held
        assert np.linalg.norm(arm.ee_pose()[:3, 3] - goal[:3, 3]) < 0.004
        idx = [c.state.names.index(j) for j in arm.joints]
        assert np.abs(c.state.velocity.numpy()[idx]).max() < 0.01
    finally:
        sub.close()
