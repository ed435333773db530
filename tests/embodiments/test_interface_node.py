"""The simulated interface and the Cartesian controller service hosted from a node configuration."""

from __future__ import annotations

import time

import numpy as np
import pytest

from contactflow.embodiments import registry
from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.control.planning import CoalChecker
from contactflow.embodiments.messages import (
    CartesianTarget,
    JointCommand,
    JointState,
    ObjectPoses,
    PointCloud,
    RobotModel,
    Wrench,
)
from contactflow.embodiments.transforms import xyz_rpy_to_matrix
from contactflow.nodes.clock import SimClock
from contactflow.nodes.config import load_node_config, parse_node_config
from contactflow.nodes.host import ModuleHost
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Clock, Command, EventMsg
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for, write_config
from contactflow.nodes.registry import resolve
from contactflow.nodes.status import Event, Status
from contactflow.nodes.testing import FakeIO
from contactflow.nodes.transport import LocalTransport, ZenohSettings, ZenohTransport
from contactflow.nodes.wire import NDArray, decode, decode_any, encode, stamp
from contactflow.nodes.yamldoc import YamlDoc

CONFIG = """
site: t
node: sim
clock: sim
robot: melfa
modules:
  - {name: station, type: sim_interface, params: {robot: melfa, scene: table, camera_hz: 0}}
  - name: cart
    type: cartesian_controller_arm
    inputs: {joint_state: station.joint_state, target: commander.target, wrench: station.wrench}
  - name: cart2
    type: cartesian_controller_arm
    autostart: false
    inputs: {joint_state: station.joint_state, target: commander.target}
"""


class Station:
    """One in-process node: the host on a local bus, stepped tick by tick on the sim clock the world publishes."""

    def __init__(self, config: str = CONFIG) -> None:
        self.cfg = parse_node_config(YamlDoc.parse(config, "station.yaml"))
        self.bus = LocalTransport()
        self.seen: list[tuple[str, object]] = []
        self.bus.subscribe("cf/**", lambda k, p: self.seen.append((k, decode_any(p))))
        self.clock = SimClock(self.bus, self.cfg.keyspace)
        self.host = ModuleHost(self.cfg, self.bus, self.clock)
        for m in self.cfg.modules:
            self.host.add(m)
        self.host.start_autostart()
        self.station = self.host.modules[("melfa", "station")].module
        self.cart = self.host.modules[("melfa", "cart")].module if ("melfa", "cart") in self.host.modules else None
        self.target_pub = self.bus.publisher(self.cfg.keyspace.output("melfa", "test", "commander", "target"))

    def run(self, seconds: float) -> None:
        t_end = self.station.robot.time + seconds
        for _ in range(round(2 * seconds * 200) + 10):
            if self.station.robot.time >= t_end - 1e-9:
                return
            self.host.tick()
        raise AssertionError(f"the node stopped stepping the world at t = {self.station.robot.time}")

    def send(self, msg: CartesianTarget) -> None:
        self.target_pub(encode(stamp(msg, "melfa/test/commander/target", 1, self.clock.now())))

    def of(self, type_, suffix: str = "") -> list:
        return [m for k, m in self.seen if isinstance(m, type_) and k.endswith(suffix)]


@pytest.fixture(scope="module")
def node() -> Station:
    s = Station()
    s.run(0.3)
    return s


def test_joint_states_follow_the_sim_clock_at_200_hz(node):
    t0 = node.station.robot.time
    start = len(node.of(JointState))
    node.run(0.5)
    states = node.of(JointState)[start:]
    assert len(states) == pytest.approx(100, abs=1)
    assert states[-1].names == node.station.robot.art.joint_names
    assert node.station.robot.time == pytest.approx(t0 + 0.5, abs=1e-6)
    assert node.clock.now() == pytest.approx(node.station.robot.time, abs=1e-6), "the node steps on the world's clock"
    stamps = np.array([m.hdr.t_sim for m in states])
    assert np.allclose(np.diff(stamps), 0.005, atol=1e-6)
    assert node.of(Clock, "/t/clock"), "the sim clock is on the site's clock key"
    assert node.of(ObjectPoses, "/eval/melfa/object_poses"), "ground truth goes to the evaluation key"
    assert {m.arm for m in node.of(Wrench)} == {"arm"}
    assert node.of(RobotModel)[-1].robot == "melfa"


def test_a_cartesian_target_5_cm_away_is_reached_within_5_mm(node):
    robot = node.station.robot
    T0 = robot.arm("arm").ee_pose()
    goal = T0.copy()
    goal[:3, 3] += (0.03, 0.04, 0.0)
    node.send(CartesianTarget(arm="arm", mode="pose", values=[float(x) for x in goal.ravel()], speed=0.1))
    node.run(1.5)
    assert node.cart.status == Status.SUCCESS
    assert np.linalg.norm(robot.arm("arm").ee_pose()[:3, 3] - goal[:3, 3]) < 0.005
    spec = registry.get("melfa")
    kin = Kinematics(spec.urdf(), xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))
    js = node.of(JointState)[-1]
    q = kin.q.copy()
    q[kin.q_index(js.names)] = js.position.numpy()
    kin.update(q)
    assert np.linalg.norm(kin.frame_pose(spec.arm("arm").ee_frame)[:3, 3] - goal[:3, 3]) < 0.005
    commands = node.of(JointCommand, "/cart/out/joint_command")
    assert commands and commands[-1].names == list(spec.arm("arm").joints)
    assert node.of(JointCommand, "/station/out/mixed"), "the interface mixed the controller's commands"


def test_a_malformed_target_is_rejected_and_the_controller_goes_on(node):
    before = node.cart.rejected
    node.send(CartesianTarget(arm="arm", mode="pose", values=[1.0, 2.0]))
    node.run(0.05)
    assert node.cart.rejected == before + 1
    assert node.host.modules[("melfa", "cart")].module.state == Status.RUNNING


def test_a_second_commander_of_the_arm_without_mix_is_refused(node):
    reply = node.host.send_control("melfa/cart2", Command.RUN, {})
    assert not reply.ok
    assert "resource 'arm_arm'" in reply.error and "already commanded by sim/cart" in reply.error


def test_a_sensor_that_raises_is_a_lost_stream_not_a_crash(node, monkeypatch):
    def broken():
        raise RuntimeError("ray casting failed")

    monkeypatch.setattr(node.station.robot, "ground_truth", broken)
    n = len(node.of(JointState))
    node.run(0.1)
    lost = [m for m in node.of(EventMsg) if m.event == Event.HARDWARE_FAILURE]
    assert len(lost) == 1 and "ground_truth: RuntimeError: ray casting failed" in lost[0].detail
    assert node.station.state == Status.RUNNING and len(node.of(JointState)) == n + 20


def test_a_physics_fault_becomes_hardware_failure_and_the_node_lives_on(node):
    node.station.robot.inject_fault("explode", joint="shoulder_pan_joint")
    node.run(0.1)
    events = [m for m in node.of(EventMsg) if m.event == Event.HARDWARE_FAILURE and "explosion" in m.detail]
    assert events and events[0].module == "melfa/sim/station"
    assert node.station.state == Status.RUNNING
    n = len(node.of(JointState))
    node.run(0.05)
    assert len(node.of(JointState)) > n, "the stopped robot keeps publishing its state"


MIXED = """
site: t
node: sim
clock: sim
robot: melfa
modules:
  - {name: station, type: sim_interface, params: {robot: melfa, model_hz: 0, ground_truth_hz: 0}}
  - {name: cart, type: cartesian_controller_arm, mix: {arm_arm: 0.75},
     inputs: {joint_state: station.joint_state, target: commander.target}}
  - {name: cart2, type: cartesian_controller_arm, mix: {arm_arm: 0.25},
     inputs: {joint_state: station.joint_state, target: other.target}}
"""


def test_two_commanders_that_declare_mix_drive_the_arm_by_their_weights():
    node = Station(MIXED)
    assert all(hm.module.state == Status.RUNNING for hm in node.host.modules.values())
    node.run(0.1)
    other = node.bus.publisher(node.cfg.keyspace.output("melfa", "test", "other", "target"))
    y0 = node.station.robot.arm("arm").ee_pose()[1, 3]
    node.send(CartesianTarget(arm="arm", mode="twist", values=[0.0, 0.05, 0.0, 0.0, 0.0, 0.0]))
    other(encode(stamp(CartesianTarget(arm="arm", mode="twist", values=[0.0, -0.05, 0.0, 0.0, 0.0, 0.0]),
                       "melfa/test/other/target", 1, node.clock.now())))
    node.run(0.5)
    moved = node.station.robot.arm("arm").ee_pose()[1, 3] - y0
    assert moved == pytest.approx((0.75 - 0.25) * 0.05 * 0.45, rel=0.3), "weighted mean of +5 and -5 cm/s is +2.5 cm/s"
    weights = {m.hdr.source.split("/")[-2]: m.weight for m in node.of(JointCommand, "/out/joint_command")}
    assert weights == {"cart": 0.75, "cart2": 0.25}


def test_the_interface_in_a_node_process_is_driven_by_a_controller_in_another(tmp_path):
    """Two real nodes over zenoh: the sim interface paced by its wall-clock host, the controller on the sim clock."""
    site, port = "pif", free_port()
    ks = KeySpace(site)
    zenoh = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port}"], "multicast_scouting": False}
    station = write_config(tmp_path / "station.yaml", {
        "site": site, "node": "station", "robot": "melfa", "clock": "wall", "zenoh": zenoh,
        "modules": [{"name": "sim", "type": "sim_interface", "params": {"robot": "melfa", "camera_hz": 0}}]})
    proc = spawn_node(station, tmp_path / "station.log")
    control = write_config(tmp_path / "control.yaml", {
        "site": site, "node": "control", "robot": "melfa", "clock": "sim",
        "modules": [{"name": "cart", "type": "cartesian_controller_arm",
                     "inputs": {"joint_state": "sim.joint_state", "target": "commander.target"}}]})
    bus = ZenohTransport(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",))).open()
    host = None
    states: list[JointState] = []
    sub = bus.subscribe(ks.output("melfa", "station", "sim", "joint_state"),
                        lambda k, p: states.append(decode(p, JointState, k)))
    spec = registry.get("melfa")
    kin = Kinematics(spec.urdf(), xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))

    def tcp(js: JointState) -> np.ndarray:
        q = kin.q.copy()
        q[kin.q_index(js.names)] = js.position.numpy()
        kin.update(q)
        return kin.frame_pose(spec.arm("arm").ee_frame)

    try:
        assert wait_for(lambda: len(states) > 20, timeout=60), (tmp_path / "station.log").read_text()[-3000:]
        host = ModuleHost(load_node_config(control), bus)
        for m in host.config.modules:
            host.add(m)
        host.start()
        goal = tcp(states[-1])
        goal[:3, 3] += (0.0, 0.05, 0.0)
        put = bus.publisher(ks.output("melfa", "control", "commander", "target"))
        put(encode(stamp(CartesianTarget(arm="arm", mode="pose", values=[float(x) for x in goal.ravel()]),
                         "melfa/control/commander/target", 1, host.clock.now())))
        assert wait_for(lambda: np.linalg.norm(tcp(states[-1])[:3, 3] - goal[:3, 3]) < 0.005, timeout=15), \
            (tcp(states[-1])[:3, 3], goal[:3, 3])
        assert host.modules[("melfa", "cart")].module.status in (Status.RUNNING, Status.SUCCESS)
    finally:
        sub.close()
        if host is not None:
            host.shutdown()
        bus.close()
        assert stop_process(proc) == 0


PLANNED = """
site: t
node: sim
clock: sim
robot: melfa
modules:
  - {name: station, type: sim_interface, params: {robot: melfa, model_hz: 0, ground_truth_hz: 0}}
  - name: planner
    type: planner_arm
    params: {planner: RRTConnect, timeout: 5.0, speed: 1.0}
    inputs: {joint_state: station.joint_state, goal: commander.target, cloud: commander.cloud, wrench: station.wrench}
"""


def run_until(node, done, step: float, wall_timeout: float = 120.0) -> None:
    """Step the simulation until ``done()``: the planner thinks in wall time, on its own thread."""
    deadline = time.monotonic() + wall_timeout
    while not done() and time.monotonic() < deadline:
        node.run(step)


def test_the_planner_service_goes_around_a_sensed_wall_and_refuses_an_unreachable_goal():
    node = Station(PLANNED)
    node.run(0.1)
    spec = registry.get("melfa")
    kin = Kinematics(spec.urdf(), xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))
    xs, zs = np.meshgrid(np.arange(0.28, 0.52, 0.01), np.arange(0.90, 1.12, 0.01))
    wall = np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], 1).astype(np.float32)  # the plane y = 0
    cloud = node.bus.publisher(node.cfg.keyspace.output("melfa", "test", "commander", "cloud"))
    cloud(encode(stamp(PointCloud(points=NDArray.of(wall)), "melfa/test/commander/cloud", 1, node.clock.now())))
    goal = node.station.robot.arm("arm").ee_pose()
    assert goal[1, 3] > 0.05, "the tcp starts on the +y side of the wall"
    goal[1, 3] = -0.09
    start = len(node.of(JointState))
    node.send(CartesianTarget(arm="arm", mode="pose", values=[float(x) for x in goal.ravel()]))

    def outcome():
        return [m for m in node.of(EventMsg) if m.module.endswith("/planner") and m.event in (Event.SUCCESS, Event.FAILURE)]

    run_until(node, outcome, 0.1)
    assert [m.event for m in outcome()] == [Event.SUCCESS], [m.detail for m in outcome()]
    assert np.linalg.norm(node.station.robot.arm("arm").ee_pose()[:3, 3] - goal[:3, 3]) < 0.005
    # the executed motion, with the robot's collision meshes, against the wall as solid 1 cm cells: the
    # tcp goes to the other side over the wall or around it (OMPL's route depends on the CPU time it
    # gets), and no state of the way there puts any part of the arm or gripper into the wall
    wall_cells = CoalChecker(kin, str(spec.urdf()), [], cloud=wall, resolution=0.01)
    path, inside = [], []
    for js in node.of(JointState)[start:]:
        q = kin.q.copy()
        q[kin.q_index(js.names)] = js.position.numpy()
        kin.update(q)
        path.append(kin.frame_pose(spec.arm("arm").ee_frame)[:3, 3])
        if not wall_cells.valid(q):
            inside.append(path[-1])
    path = np.array(path)
    assert (path[:, 1] > 0.02).any() and (path[:, 1] < -0.02).any(), "the tcp never reached the other side of the wall"
    assert not inside, f"the arm went through the wall with the tcp at {np.array(inside)}"

    far = np.eye(4)
    far[:3, 3] = (3.0, 0.0, 1.0)
    node.send(CartesianTarget(arm="arm", mode="pose", values=[float(x) for x in far.ravel()]))
    run_until(node, lambda: len(outcome()) > 1, 0.05)
    assert outcome()[-1].event == Event.FAILURE and "no collision-free IK" in outcome()[-1].detail


@pytest.mark.parametrize(("module", "params", "message"), [
    ("sim_interface", {"robot": "nope"}, r"station\.params\.robot: 'nope' is not a registered embodiment"),
    ("cartesian_controller_left", {"robot": "melfa"}, r"station: robot 'melfa' has no arm 'left'"),
    ("planner_arm", {"robot": "nope"}, r"station\.params\.robot: 'nope' is not a registered embodiment"),
    ("planner_arm", {"robot": "melfa", "tries": 0}, r"station\.params\.tries: 0"),
])
def test_a_misconfigured_robot_or_arm_is_refused_naming_the_module(module, params, message):
    m = resolve(module)("station", resolve(module).Params(**params))
    with pytest.raises(ValueError, match=message):
        m.setup(FakeIO())
