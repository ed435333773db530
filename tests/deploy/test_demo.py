"""`contactflow demo` (quick): five node processes, both §7.3 ATDs on all three robots, checked on ground truth."""

import json

import msgpack
import pytest
import zenoh
from rich.console import Console

from contactflow.abstraction.atd import load_atd, parse_atd
from contactflow.abstraction.frames import WORKCELL
from contactflow.deploy import demo
from contactflow.deploy.recording import Recording
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port

ROBOTS = ["baxter", "melfa", "tombatossals"]


def _outside_client(endpoint: str, site: str, heard: list):
    """A client written from docs/protocol.md alone: zenoh and msgpack, no contactflow import."""
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    session.declare_subscriber(f"cf/{site}/broker/progress/*",
                               lambda s: heard.append(msgpack.unpackb(s.payload.to_bytes())))
    return session


@pytest.mark.heavy(seconds=115)
@pytest.mark.timeout(600)  # 260 s beside the suite's other worker on a machine half as fast as most: 300 s is too close
def test_quick_demo_succeeds_on_every_robot_with_the_expected_physical_result(tmp_path):
    site, endpoint = "demotest", f"tcp/127.0.0.1:{free_port()}"
    heard: list = []
    client = _outside_client(endpoint, site, heard)  # it waits for the demo's session to listen
    console = Console(record=True, width=200)
    try:
        code = demo.run(tmp_path, quick=True, console=console, site=site, listen=(endpoint,), record=True)
    finally:
        client.close()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert code == 0 and summary["ok"], summary["tasks"]
    assert f"site {site}; nodes listen on tcp/127.0.0.1:" in console.export_text()
    # the outside client attached through the demo's listen endpoint and followed both tasks to their ends
    ends = [m for m in heard if m["type"] == "abstract_progress" and m["robot"] == "broker" and m["final"]]
    assert sorted(m["outcome"] for m in ends) == ["success", "success"], ends
    # real headers: each source numbers its messages on a task's key from 1 and stamps them with its node's
    # clock (simulated: 0 while a world still waits for its nodes, so only the ends are surely later)
    streams: dict = {}
    for m in heard:
        streams.setdefault((m["hdr"]["source"], m["task_id"]), []).append(m["hdr"])
    assert {s for s, _ in streams} >= {"site/control/broker", "tombatossals/control/agent", "melfa/melfa_control/agent"}
    for (source, task), hdrs in streams.items():
        assert source and sorted(h["seq"] for h in hdrs) == list(range(1, len(hdrs) + 1)), (source, task)
        assert all(h["t_wall"] > 0 and h["t_sim"] >= 0 for h in hdrs), (source, task)
    assert all(m["hdr"]["t_sim"] > 0 for m in ends)
    # --record: the key space in an MCAP file beside the report, with the view a Foxglove layout shows
    rec = Recording.open(tmp_path / "demo.mcap")
    assert summary["recording"]["dropped"] == 0 and summary["recording"]["recorded"] == sum(rec.counts.values())
    assert rec.channels[KeySpace(site).fused("tombatossals", "events")] == {"contact_event"}
    assert all(rec.channels[KeySpace(site).robot(r, "state")] == {"robot_state"} for r in ROBOTS)
    # a robot's command port carries arm and hand commands and camera requests: a channel per type
    assert {"arm_command", "hand_command"} <= rec.channels[KeySpace(site).robot("tombatossals", "command")]
    assert {"/tf", "/contacts/events", "/task/progress", "/tombatossals/depth", "/vision/objects",
            "/contacts/tombatossals/tactile_left", "/contacts/melfa/force_torque_arm"} <= set(rec.view_topics)
    assert {f"/{r}/robot_description" for r in ROBOTS} <= set(rec.view_topics)
    assert len(summary["nodes"]) == 8  # per robot a world and a control node; tombatossals vision2d and vision3d
    assert [t["atd"] for t in summary["tasks"]] == ["push_away.xml", "pick_place_behind.xml"]
    for task in summary["tasks"]:
        assert task["dispatched"] and task["finished"] and task["ok"], task
        assert sorted(task["robots"]) == ROBOTS
        assert task["outcomes"] == {r: "success" for r in ROBOTS}
        assert sorted(task["physical"]) == ROBOTS
        for robot, checks in task["physical"].items():
            assert len(checks) == 1 and checks[0]["ok"], (robot, checks)
    push, place = ([c for checks in t["physical"].values() for c in checks] for t in summary["tasks"])
    assert all(c["object"] == "obstacle_box" and c["distance_after"] < c["distance_before"] - 0.02 for c in push)
    assert all(c["object"] == "target" and c["distance_after"] <= demo.PLACE_TOLERANCE for c in place)
    entered = {(p["robot"], p["state"]) for p in summary["progress"] if p["kind"] == "entered"}
    assert {r for r, s in entered if s == "let_go"} == set(ROBOTS)
    # tombatossals' predictor followed both tasks in a cell that is as it believes: no mismatch, no correction
    assert summary["mismatches"] == [] and all(t["corrections"] == [] for t in summary["tasks"])
    # every fused contact event names the hypothesis clouds it came from
    assert summary["contacts"]
    # tombatossals' predictor is a cue of its fusion: its predicted hand contacts support the sensed ones
    assert any("/simulator/" in i for c in summary["contacts"] if c["robot"] == "tombatossals" for i in c["inputs"])
    for c in summary["contacts"]:
        assert c["sources"] and len(c["inputs"]) == len(c["sources"]), c
        # the sensed cues, the vision3d node's range, and the support of where the hands move (motion) and of what
        # the predictor predicts
        assert all(i.startswith(f"{c['robot']}/") and any(g in i for g in ("/cues_", "/range/", "/motion/",
                                                                           "/simulator/"))
                   for i in c["inputs"]), c
        assert any(g in i for i in c["inputs"] for g in ("/cues_", "/range/")), c  # support alone makes no contact
    for name in ("timeline.png", "contacts.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_physical_checks_fail_when_the_objects_did_not_go_where_the_atd_says():
    push = load_atd(demo.EXAMPLES / "push_away.xml")
    start = {"obstacle_box": [0.50, 0.0, 0.78]}
    (stayed,) = demo.physical_checks(push, WORKCELL, start, start)
    assert not stayed["ok"] and stayed["goal"] == [0.5, -0.15, 0.78]
    (pushed,) = demo.physical_checks(push, WORKCELL, start, {"obstacle_box": [0.5, -0.12, 0.78]})
    assert pushed["ok"] and pushed["distance_after"] == 0.03
    place = load_atd(demo.EXAMPLES / "pick_place_behind.xml")
    before = {"target": [0.62, 0.0, 0.81]}
    (near,) = demo.physical_checks(place, WORKCELL, before, {"target": [0.56, 0.16, 0.81]})
    assert near["ok"]
    (fallen,) = demo.physical_checks(place, WORKCELL, before, {"target": [0.56, 0.16, 0.775]})
    assert not fallen["ok"]
    (missing,) = demo.physical_checks(place, WORKCELL, before, {})
    assert not missing["ok"] and "no ground truth" in missing["why"]


def test_a_correction_branch_taken_on_a_prediction_mismatch_is_not_checked_as_the_task_s_place():
    """An ATD whose correction sets the target back where it stood (§5.7): the place checked is the nominal run's."""
    text = (demo.EXAMPLES / "pick_place_behind.xml").read_text()
    text = text.replace('<state name="placed" type="success"/>',
                        '<state name="set_back" type="place"><target>0.0 0.62 0.06</target></state>\n'
                        '  <state name="reopen" type="release"><hand_opening>0.06</hand_opening></state>\n'
                        '  <state name="placed" type="success"/>')
    text = text.replace('<transition origin="let_go" destination="placed"><success/></transition>',
                        '<transition origin="let_go" destination="placed"><success/></transition>\n'
                        '  <transition origin="grasp_object" destination="set_back"><prediction_mismatch/></transition>\n'
                        '  <transition origin="set_back" destination="reopen"><success/></transition>\n'
                        '  <transition origin="reopen" destination="preshape_hand"><success/></transition>')
    atd = parse_atd(text, "corrected.xml")
    assert {"set_back", "reopen"} <= {s.name for s in atd.states}
    assert demo.nominal(atd) >= {"grasp_object", "put_down", "placed"} and not demo.nominal(atd) & {"set_back", "reopen"}
    (check,) = demo.physical_checks(atd, WORKCELL, {"target": [0.62, 0.0, 0.81]}, {"target": [0.56, 0.16, 0.81]})
    assert check["state"] == "put_down" and check["ok"]
