"""Broker, robot agents and a client in separate node processes: dispatch, failover on kill, detection.

Each robot is a world node and a control node (its agent and primitive modules) in lockstep;
the robot the broker picks first is paced at real time so that it is still mid-task when its
control node is killed.
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from contactflow.abstraction.agent import EXAMPLES, dry_run
from contactflow.abstraction.client import close, dispatch
from contactflow.abstraction.dispatch import choose
from contactflow.abstraction.profiles import PROFILES
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for, write_config
from contactflow.nodes.transport import ZenohSettings, ZenohTransport

SITE = "brokerproc"
KS = KeySpace(SITE)
ROBOTS = ("tombatossals", "melfa")
PUSH = (EXAMPLES / "push_away.xml").read_text()
# the broker's own choice for `any`, from the robots' (pure) dry runs
FIRST = choose("any", [dry_run(PROFILES[r], PUSH, "push_away.xml")[0] for r in ROBOTS])[0]


def spawn_site(folder: Path, site: str, paced: str = "") -> tuple[dict, ZenohTransport, int]:
    """A broker node, and for each robot a world node and a lockstep control node (agent + primitive modules);
    the ``paced`` robot's cell runs at real time (still mid-task when it is killed). Returns once both robots are up."""
    from contactflow.embodiments.layout import primitive_modules, world_node

    hub = free_port()
    procs = {"broker": spawn_node(write_config(folder / "broker.yaml", {
        "site": site, "node": "broker_node", "zenoh": {"mode": "peer", "listen": [f"tcp/127.0.0.1:{hub}"]},
        "modules": [{"name": "broker", "type": "broker"}]}), folder / "broker.log")}
    connect = (f"tcp/127.0.0.1:{hub}",)
    for robot in ROBOTS:
        world = world_node(site, f"fig7_4_{robot}", node=f"{robot}_world", connect=connect, cell=robot,
                           wait_for=(f"{robot}_control",), max_rtf=1.0 if robot == paced else 0.0)
        control = {"site": site, "node": f"{robot}_control", "clock": "lockstep", "cell": robot,
                   "zenoh": {"mode": "peer", "connect": list(connect)},
                   "modules": [{"name": "agent", "type": "robot_agent", "robot": robot, "params": {"robot": robot}},
                               *primitive_modules(robot)]}
        for name, cfg in ((f"{robot}_world", world), (robot, control)):
            procs[name] = spawn_node(write_config(folder / f"{name}.yaml", cfg), folder / f"{name}.log")
    tool = ZenohTransport(ZenohSettings(connect=connect)).open()
    ks = KeySpace(site)
    ready = wait_for(lambda: len(tool.alive(ks.alive_robot(), timeout=0.5)) == 2
                     and len(tool.alive(ks.alive_module("site", "broker_node", "broker"), timeout=0.5)) == 1, timeout=90)
    if not ready:
        tool.close()
        for proc in procs.values():
            stop_process(proc)
        pytest.fail("\n".join(log.read_text()[-1500:] for log in folder.glob("*.log")))
    return procs, tool, hub


@pytest.fixture
def site(tmp_path):
    # per test: a site left up would run its idle worlds as fast as the CPUs allow beside the next test's
    procs, tool, hub = spawn_site(tmp_path / "site", SITE)
    try:
        yield procs, tool, hub
    finally:
        tool.close()
        for p in procs.values():
            stop_process(p)


def test_robots_cli_lists_capabilities(site):
    _, _, hub = site
    out = subprocess.run([sys.executable, "-m", "contactflow.deploy.cli", "robots", "--site", SITE,
                          "--connect", f"tcp/127.0.0.1:{hub}"], capture_output=True, text=True, timeout=60,
                         env={"COLUMNS": "250", "PATH": ""})
    assert out.returncode == 0, out.stderr
    assert "tombatossals" in out.stdout and "melfa" in out.stdout and "2 robots" in out.stdout


def test_cli_run_refuses_an_invalid_atd_without_dispatching(site, tmp_path):
    _, _, hub = site
    bad = tmp_path / "bad.xml"
    bad.write_text((EXAMPLES / "push_away.xml").read_text().replace('destination="retreat"', 'destination="x"'))
    out = subprocess.run([sys.executable, "-m", "contactflow.deploy.cli", "run", str(bad), "--site", SITE,
                          "--connect", f"tcp/127.0.0.1:{hub}"], capture_output=True, text=True, timeout=60,
                         env={"COLUMNS": "250", "PATH": ""})
    assert out.returncode == 2
    assert "not dispatched" in out.stdout and "bad.xml:" in out.stdout


def test_a_killed_control_node_leaves_its_robot_held_and_the_task_fails_over(tmp_path):
    """Each robot a world node and a lockstep control node (agent + primitive modules); kill one mid-push."""
    from contactflow.nodes.messages import EventMsg
    from contactflow.nodes.wire import decode

    site = "brokerrt"
    ks = KeySpace(site)
    procs, tool, _ = spawn_site(tmp_path, site, paced=FIRST)
    held: list[EventMsg] = []
    sub = tool.subscribe(ks.events("site", f"{FIRST}_world", "world"), lambda k, p: held.append(decode(p, EventMsg, k)))
    try:
        follow = dispatch(tool, ks, PUSH, "push_away.xml", target="any")
        assert follow.reply.ok and follow.reply.robots[0] == FIRST, follow.reply
        assert wait_for(lambda: any(m.kind == "edge" and m.robot == FIRST for m in follow.progress), timeout=60)
        assert not any(m.final and m.robot == FIRST for m in follow.progress)  # still mid-task
        procs[FIRST].kill()
        assert follow.done.wait(120), [(m.robot, m.kind, m.state, m.detail) for m in follow.progress]
        assert follow.outcome == "success"
        failover = [m for m in follow.progress if m.kind == "failover"]
        assert failover and FIRST in failover[0].detail
        other = next(r for r in ROBOTS if r != FIRST)
        assert wait_for(lambda: any(m.final and m.robot == other for m in follow.progress), timeout=10)
        close(follow)
        # the dead node's robot stands held in its world, which raised the fault naming it
        assert wait_for(lambda: any(e.event.value == "hardware_failure" and e.detail.startswith(f"{FIRST}: held")
                                    for e in held), timeout=10), held
    finally:
        sub.close()
        tool.close()
        for p in procs.values():
            stop_process(p)


def test_an_object_the_atd_asks_to_detect_is_found_by_the_vision_node_and_picked(tmp_path):
    """World, vision3d and control (agent + primitive modules) in three processes: the agent binds the
    object's location from detect_objects, which reads the vision node's clusters, then runs the task."""
    from contactflow.embodiments.layout import (
        VISION_INPUTS,
        primitive_modules,
        vision_node,
        world_node,
    )
    from contactflow.embodiments.scene_file import load_scene

    site, robot = "detectrt", "tombatossals"
    ks = KeySpace(site)
    hub = free_port()
    connect = (f"tcp/127.0.0.1:{hub}",)
    modules = primitive_modules(robot)
    for m in modules:
        m.update({"inputs": dict(VISION_INPUTS[m["type"]])} if m["type"] in VISION_INPUTS else {})
    configs = {
        "broker": {"site": site, "node": "broker_node", "zenoh": {"mode": "peer", "listen": [connect[0]]},
                   "modules": [{"name": "broker", "type": "broker"}]},
        # paused while idle: the task starts at the same tick however long the dispatch takes, so the run repeats
        "world": world_node(site, "pick_place", connect=connect, wait_for=("control", f"vision3d_{robot}"), camera_hz=2.0,
                            idle="pause"),
        "vision": vision_node(site, robot, connect=connect),
        "control": {"site": site, "node": "control", "clock": "lockstep", "zenoh": {"mode": "peer", "connect": list(connect)},
                    "modules": [{"name": "agent", "type": "robot_agent", "robot": robot, "params": {"robot": robot}},
                                *modules]},
    }
    procs = {name: spawn_node(write_config(tmp_path / f"{name}.yaml", cfg), tmp_path / f"{name}.log")
             for name, cfg in configs.items()}
    tool = ZenohTransport(ZenohSettings(connect=connect)).open()
    try:
        assert wait_for(lambda: len(tool.alive(ks.alive_robot(), timeout=0.5)) == 1, timeout=60), \
            "\n".join(p.read_text()[-1500:] for p in tmp_path.glob("*.log"))
        follow = dispatch(tool, ks, (EXAMPLES / "pick_detected.xml").read_text(), "pick_detected.xml", target=robot)
        assert follow.reply.ok, follow.reply
        assert follow.done.wait(180), [(m.robot, m.kind, m.state, m.detail) for m in follow.progress]
        assert follow.outcome == "success", [(m.kind, m.state, m.event, m.detail) for m in follow.progress]
        close(follow)
        log = " ".join((tmp_path / "control.log").read_text().split())  # the console wraps long lines
        found = re.search(r"can_location detected at \[([^\]]+)\] \(1 objects \(([a-z ]+),", log)
        assert found is not None, log[-3000:]
        assert found.group(2) == "vision chain"  # the vision node's clusters, not a camera frame of its own
        xyz = [float(c) for c in found.group(1).split(",")]
        can = next(o for o in load_scene("pick_place").objects if o.name == "cyl")
        # the centre of the can's top face, seen whole (the centroid of all the seen points was 1.7 cm toward the camera)
        assert sum((a - b) ** 2 for a, b in zip(xyz, can.xyz, strict=True)) ** 0.5 < 0.01, (xyz, can.xyz)
    finally:
        tool.close()
        for p in procs.values():
            stop_process(p)
