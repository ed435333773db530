"""The robots on the runtime: a world node and control nodes over zenoh, in one process or in several."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.layout import TAP_ABOVE, run_cell, table_cell
from contactflow.nodes.procs import free_port
from contactflow.nodes.status import Event

pytestmark = pytest.mark.heavy(seconds=120)

ROBOT = "tombatossals"


def test_two_robots_in_one_cell_each_run_a_task_without_disturbing_the_other(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    kept = {}

    def keep(wm) -> None:
        gt = wm.robots[ROBOT].sim.ground_truth()
        kept.update(can=gt.object_poses["cyl"][:3, 3].copy(), cube=gt.object_poses["cube"][:3, 3].copy(),
                    contacts=gt.contacts, refused=[r.refused for r in wm.robots.values()],
                    failed=[r.sim.failed for r in wm.robots.values()])

    world, controls = table_cell("rt2", endpoint, melfa=True, cell_map=True)
    # tombatossals' carry watcher (wait_event, sensor fused) reads its grasp from the cell's map, not its own fusion
    watchers = [m for m in controls[0]["modules"] if m["type"] == "wait_event"]
    assert watchers and all(m["inputs"] == {"contacts": "cf/rt2/contacts/fused/shared_table/contacts"} for m in watchers)
    run = run_cell(tmp_path, world, controls, endpoint, keep=keep)
    # ... and held it through the carry: a watcher that hears no contact list for 1 s fails the task, one that sees
    # no contact on the hand reports the grasp lost
    assert all(o.event is Event.SUCCESS for o in run.outcomes.values()), run.events
    assert ("transport", "success") in {(m, e) for _, m, e in run.events} and "grasp_lost" not in {
        e for _, _, e in run.events}, run.events
    # every cue of both robots (each hand's tactile and F/T, an allegro's finger pose, motion support, null) in the one
    # map, nothing refused
    # (its status, as contactflow ls shows it, at the end)
    assert run.statuses["site/control_tombatossals/cell_map"].detail == "sources: tombatossals 8, melfa 4; refused: none"
    cell = [c for c in run.contacts if c.hdr.source == "site/control_tombatossals/cell_map/events"]
    assert [(c.robot, c.link, str(c.event)) for c in cell][:1] == [(ROBOT, "right_hand", "contact_made")], cell
    own = [c for c in run.contacts if c.hdr.source.startswith(f"{ROBOT}/")]  # tombatossals' own fusion
    assert {(c.robot, str(c.event)) for c in own} == {(c.robot, str(c.event)) for c in cell if c.robot == ROBOT}
    # ... and melfa's touch on the cube, made and broken, is in the cell's map too
    assert {("melfa", "contact_made"), ("melfa", "contact_broken")} <= {(c.robot, str(c.event)) for c in cell}
    assert ("touch", "success") in {(m, e) for _, m, e in run.events}
    # melfa's touch stopped on its own fused contacts (its gripper's pads and wrist fused), not the wrist alone
    touched = [m for m in run.messages if m.module.endswith("melfa/touch") and m.event is Event.CONTACT]
    assert len(touched) == 1 and "fused contacts melfa/" in touched[0].detail, touched
    # the can was moved by tombatossals; melfa touched down at the cube and left it standing there
    cyl = kept["can"]
    assert np.hypot(cyl[0] - 0.55, cyl[1] + 0.3) > 0.1 and cyl[2] == pytest.approx(0.81, abs=0.015)
    assert kept["cube"] == pytest.approx([TAP_ABOVE[0], TAP_ABOVE[1], 0.775], abs=0.01)
    end = max(o.hdr.t_sim for o in run.outcomes.values())
    assert not [e for t, _, e in run.events if t <= end and e == "hardware_failure"]  # no robot held or failed
    assert kept["refused"] == [0, 0] and kept["failed"] == [False, False]
    # the robots do not touch each other
    assert not any({c.body_a.split("/")[0], c.body_b.split("/")[0]} == {ROBOT, "melfa"} for c in kept["contacts"])


def test_killing_the_control_node_mid_grasp_holds_the_robot_and_a_new_control_node_finishes_the_task(tmp_path):
    import signal
    import time

    from contactflow.embodiments.layout import SiteWatch
    from contactflow.nodes.procs import spawn_node, stop_process, wait_for, write_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    world, (control,) = table_cell("rt3", endpoint)
    w = spawn_node(write_config(tmp_path / "world.yaml", world), tmp_path / "world.log")
    watch = SiteWatch("rt3", endpoint)
    c1 = spawn_node(write_config(tmp_path / "control.yaml", control), tmp_path / "control1.log")
    c2 = None
    try:
        assert wait_for(lambda: ("robust_grasp", "contact") in {(m, e) for _, m, e in watch.sequence()}, 120), (
            watch.sequence())
        c1.send_signal(signal.SIGKILL)  # dies mid-grasp: no goodbye, its session just drops
        c1.wait(10)
        held = lambda: next((e for e in watch.events if e.event is Event.HARDWARE_FAILURE  # noqa: E731
                             and e.detail.startswith(f"{ROBOT}: held by the world")), None)
        assert wait_for(lambda: held() is not None, 10), watch.sequence()[-5:]
        t_held = watch.last_tick[0]
        time.sleep(1.0)
        assert watch.last_tick[0] > t_held + 0.5  # the world runs on without the dead node
        # the deployment starts the control node again: the task runs from the start and ends
        c2 = spawn_node(tmp_path / "control.yaml", tmp_path / "control2.log")
        assert wait_for(lambda: watch.outcome(f"{ROBOT}/control_{ROBOT}/task") is not None, 240), (
            (tmp_path / "control2.log").read_text()[-3000:])
        assert watch.outcome(f"{ROBOT}/control_{ROBOT}/task").event is Event.SUCCESS, [(round(e.hdr.t_sim, 2), e.module.rsplit("/", 1)[-1], str(e.event), e.detail[:80]) for e in watch.events]
    finally:
        for p in (c2, c1, w):
            if p is not None:
                stop_process(p)
        watch.close()


def test_a_second_primitive_on_a_busy_arm_is_refused_naming_the_one_that_drives_it(tmp_path):
    from contactflow.nodes.config import load_node_config
    from contactflow.nodes.messages import Command
    from contactflow.nodes.node import Node
    from contactflow.nodes.procs import write_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    world, (control,) = table_cell("rt4", endpoint)
    control["modules"][-1]["autostart"] = False  # the task stays idle: primitives are run by hand
    nodes = [Node(load_node_config(write_config(tmp_path / f"{c['node']}.yaml", c))) for c in (world, control)]
    for n in nodes:
        n.start()
    try:
        host = nodes[1].host
        far = [0.4, -0.4, 1.1, 3.14159, 0.0, 0.0]
        assert host.send_control(f"{ROBOT}/move_to", Command.RUN, {"target": far, "arm": "right"}).ok
        reply = host.send_control(f"{ROBOT}/move_to_2", Command.RUN, {"target": far, "arm": "right"})
        assert not reply.ok
        assert "resource 'arm_right' of robot 'tombatossals' is already commanded by control_tombatossals/move_to" in reply.error
        # the other arm is free, and a watcher that commands no arm runs beside the mover
        assert host.send_control(f"{ROBOT}/move_to_2", Command.RUN, {"target": far, "arm": "left"}).ok
        assert host.send_control(f"{ROBOT}/wait_event", Command.RUN, {"arm": "right", "event": "grasp_lost"}).ok
        assert host.send_control(f"{ROBOT}/move_to", Command.STOP, {}).ok
        assert host.send_control(f"{ROBOT}/move_to", Command.RUN, {"target": far, "arm": "right"}).ok
    finally:
        for n in reversed(nodes):
            n.stop()


def test_the_readme_world_and_control_nodes_work_as_written(tmp_path, monkeypatch):
    """The README's two node configurations and its two ``contactflow ctl`` lines, on a free port."""
    import re
    import shlex
    from pathlib import Path

    from rich.console import Console
    from typer.testing import CliRunner

    from contactflow.deploy import cli
    from contactflow.embodiments.layout import SiteWatch
    from contactflow.nodes.procs import spawn_node, stop_process, wait_for

    readme = (Path(__file__).parents[2] / "README.md").read_text()
    blocks = dict(re.findall(r"```yaml\n# (world\.yaml|control\.yaml)\n(.*?)```", readme, re.S))
    commands = [c for c in re.findall(r"^contactflow ctl (.*?)(?:\s+#.*)?$", readme, re.M) if "7447" in c]
    assert set(blocks) == {"world.yaml", "control.yaml"} and len(commands) == 2
    port = str(free_port())
    procs = []
    for name in ("world.yaml", "control.yaml"):
        (tmp_path / name).write_text(blocks[name].replace("7447", port).replace("site: lab", "site: readme"))
        procs.append(spawn_node(tmp_path / name, tmp_path / f"{name}.log"))
    endpoint = f"tcp/127.0.0.1:{port}"
    watch = SiteWatch("readme", endpoint)
    monkeypatch.setattr(cli, "console", Console(width=400, soft_wrap=True))
    try:
        assert wait_for(lambda: len(watch.t.alive(watch.ks.alive_module(), timeout=0.5)) == 3, 60)
        for line in commands:
            args = shlex.split(line.replace("7447", port).replace("--site lab", "--site readme"))
            out = CliRunner().invoke(cli.app, ["ctl", *args], catch_exceptions=False)
            assert out.exit_code == 0 and ": ok" in out.output, out.output
        assert wait_for(lambda: watch.outcome("tombatossals/control/move_to") is not None, 120), (
            (tmp_path / "control.yaml.log").read_text()[-3000:])
        done = watch.outcome("tombatossals/control/move_to")
        assert done.event is Event.SUCCESS, done
        assert [done.values[k] for k in ("x", "y", "z")] == pytest.approx([0.55, -0.3, 0.95], abs=0.01)
    finally:
        for p in reversed(procs):
            stop_process(p)
        watch.close()


FEEL = """
main: feel
tasks:
  feel:
    params: {arm: right, region: [0.3, -0.6, 0.74, 1.0, 0.1, 1.2]}
    timeout: 80
    nodes:
      detect: {primitive: detect_objects, params: {arm: "${params.arm}", region: "${params.region}", standoff: 0.04}}
      approach:
        primitive: move_to
        params:
          arm: "${params.arm}"
          target: ["${detect.x}", "${detect.y}", "${detect.z}", "${detect.roll}", "${detect.pitch}", "${detect.yaw}"]
      grasp: {primitive: robust_grasp, params: {arm: "${params.arm}", pregrasp_type: open}}
      lift: {primitive: lift, params: {arm: "${params.arm}", distance: 0.05}}
      held: {primitive: wait_event, params: {arm: "${params.arm}", event: grasp_stable, sensor: fused, min_contacts: 2, region: finger}}
      open: {primitive: release, params: {arm: "${params.arm}", velocity: 0.005}}
      retreat: {primitive: transport, params: {arm: "${params.arm}", target: [0, 0, 0.08, 0, 0, 0], relative: true}}
      gone: {primitive: wait_event, params: {arm: "${params.arm}", event: grasp_lost, sensor: fused}}
      done: {terminal: success}
      failed: {terminal: failure}
    edges:
      - {from: detect, to: approach, on: success}
      - {from: approach, to: grasp, on: success}
      - {from: grasp, to: lift, on: success}
      - {from: lift, to: held, on: success}
      - {from: held, to: open, on: grasp_stable}
      - {from: open, to: retreat, on: success}
      - {from: retreat, to: gone, on: success}
      - {from: gone, to: done, on: grasp_lost}
      - {from: detect, to: failed, on: [[failure, error]]}
      - {from: approach, to: failed, on: [[failure, error]]}
      - {from: grasp, to: failed, on: [[failure, error]]}
      - {from: lift, to: failed, on: [[failure, error]]}
      - {from: held, to: failed, on: [[failure, error]]}
      - {from: open, to: failed, on: [[failure, error]]}
      - {from: retreat, to: failed, on: [[failure, error]]}
      - {from: gone, to: failed, on: [[failure, error]]}
"""


def test_a_task_transitions_on_the_robots_fused_contacts(tmp_path):
    """Grasp held and grasp lost come from the control node's contact fusion (tactile and wrist F/T
    clouds fused into contacts on the hand), not from a primitive's own reading of the sensors."""
    from contactflow.embodiments.layout import CELLS, control_node, world_node

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    (tmp_path / "feel.yaml").write_text(FEEL)
    control = control_node("rt4", ROBOT, ROBOT, tmp_path / "feel.yaml", connect=(endpoint,), autostart=True,
                           contacts=True)
    world = world_node("rt4", CELLS / "pick_place.yaml", listen=endpoint, wait_for=(control["node"],))
    run = run_cell(tmp_path, world, [control], endpoint)
    assert run.outcomes[ROBOT].event is Event.SUCCESS, run.events
    seq = [(m, e) for _, m, e in run.events]
    stable = seq.index(("wait_event", "grasp_stable"))
    lost = seq.index(("wait_event", "grasp_lost"))
    assert ("release", "success") in seq[stable:lost]
    # the fusion module's own events: contacts made on the hand before the grasp held, broken after the release,
    # none made once the hand is away
    made = [i for i, s in enumerate(seq) if s == ("contacts", "contact_made")]
    broken = [i for i, s in enumerate(seq) if s == ("contacts", "contact_broken")]
    assert made and made[0] < stable and any(i > stable for i in broken) and made[-1] < lost
    fired = [m for m in run.messages if m.module.endswith("/wait_event") and m.event is Event.GRASP_STABLE]
    assert fired and "fused contacts" in fired[0].detail and "/contacts/" in fired[0].detail
    # on the key space, every fused event names the clouds it came from: the hand's cues, and the motion support
    # of the hands where they moved
    assert run.contacts and all(c.robot == ROBOT and c.link.endswith("_hand") for c in run.contacts)
    # each says where on the hand it lies (the fusion reads the posed model): the grasp held on the fingers'
    # contacts (the wait counts only region finger), and the palm and the can were touched too
    assert {c.region for c in run.contacts} == {"finger", "palm", "held_object"}, run.contacts
    assert all(c.part.startswith("right_") for c in run.contacts)
    fingers = [i for i, c in enumerate(run.contacts) if c.event is Event.CONTACT_MADE and c.region == "finger"]
    assert fingers and all(c.part.startswith("right_link_") for c in run.contacts if c.region == "finger")
    for c in run.contacts:
        assert c.sources and len(c.hdr.inputs) == len(c.sources), c
        cues, motion = f"/control_{ROBOT}/cues_", f"/control_{ROBOT}/motion/"
        assert all(cues in i.source or motion in i.source for i in c.hdr.inputs), c.hdr.inputs
        assert any(cues in i.source for i in c.hdr.inputs), c.hdr.inputs  # support alone makes no contact


def test_the_vision_node_s_range_generator_is_fused_with_the_control_node_s_cues(tmp_path):
    """Thesis §4.4.4 on the runtime: the vision3d node's range generator (the occupancy grid of what it sees above
    the table, the control node's posed model as the virtual contact sensor) publishes on contacts/<robot>/range,
    and the robot's own fusion on the control node fuses it with the hand's cues: contacts the range evidence took
    part in lie on the grasping hand, the first where it came down on the can."""
    from contactflow.embodiments.layout import vision_cell

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    world, control, vision = vision_cell("rt6", endpoint, contacts=True)
    assert [m["inputs"] for m in vision["modules"] if m["type"] == "range_hypotheses"] == [
        {"depth": "cf/rt6/robot/tombatossals/depth", "robot_model": "tombatossals/model.robot_model", "roi": "plane.roi"}]
    run = run_cell(tmp_path, world, [control], endpoint, services=(vision,), timeout=180)
    assert run.outcomes[ROBOT].event is Event.SUCCESS, run.events
    ranged = [c for c in run.contacts if f"{ROBOT}/range" in c.sources]
    assert ranged, {s for c in run.contacts for s in c.sources}
    assert all(c.part.startswith("right_") and c.region in ("finger", "palm", "held_object") for c in ranged), [
        (c.part, c.region) for c in ranged]
    # the first where the hand came down on the can (at 0.55, -0.30; 12 cm tall on the table at 0.75 m)
    first = min((c for c in ranged if c.event is Event.CONTACT_MADE), key=lambda c: c.t)
    assert np.linalg.norm(np.subtract(first.location[:2], (0.55, -0.3))) < 0.06 and 0.75 < first.location[2] < 0.9, first
