"""Recording the key space to MCAP, reading it back, re-fusion, replay into a fusion node, the live Foxglove view."""

import json
import socket
import threading
import time
from collections import Counter

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from contactflow.deploy.recorder import Recorder
from contactflow.deploy.recording import Recording, RecordingError
from contactflow.deploy.replayer import Replayer, ReplayError
from contactflow.deploy.testing import TAP_PAD
from contactflow.fusion.messages import ContactEventMsg, ContactList, HypothesisCloud
from contactflow.fusion.refusion import EventRecord, compare, refuse
from contactflow.fusion.service import FusionParams
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.params import replace_params
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for, write_config
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import decode_any

SITE = "rec"
KS = KeySpace(SITE)
FUSION = {"robot": "r1", "sources": "r1/*", "rate_hz": 50, "timeout": 0.1, "hold": 0.05}
# a pad pressed and released every 0.4 s, turned into hypotheses by the tactile generator and fused:
# ~5 contact events per second on the fused events key
SENSING = [
    {"name": "pad", "type": TAP_PAD, "params": {"robot": "r1", "press_s": 0.2, "release_s": 0.2}},
    {"name": "tactile", "type": "tactile_hypotheses", "inputs": {"tactile": "pad.tactile", "taxels": "pad.taxels"},
     "params": {"robot": "r1"}},
]
FUSING = [{"name": "fusion", "type": "contact_fusion", "params": FUSION}]
EDGE = 0.5  # s, one press-and-release cycle plus the fusion timeout


def _node(tmp, site, modules, name, clock="wall"):
    port = free_port()
    cfg = {"site": site, "node": name, "host": "box", "clock": clock,
           "zenoh": {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port}"], "multicast_scouting": False},
           "modules": modules}
    proc = spawn_node(write_config(tmp / f"{name}.yaml", cfg), tmp / f"{name}.log")
    tool = ZenohTransport(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",))).open()
    if not wait_for(lambda: len(tool.alive(KeySpace(site).alive_module(), timeout=0.5)) == len(modules), timeout=30):
        tool.close()
        stop_process(proc)
        raise AssertionError((tmp / f"{name}.log").read_text()[-3000:])
    return proc, tool


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """At least 3 s and 15 contact events (~5/s) of a sensing-and-fusion node recorded, with what an independent
    subscriber counted per key."""
    tmp = tmp_path_factory.mktemp("recording")
    proc, tool = _node(tmp, SITE, SENSING + FUSING, "sense")
    seen: Counter = Counter()
    lock = threading.Lock()

    def count(key, payload):
        decode_any(payload, key)
        with lock:
            seen[key] += 1
    try:
        rec = Recorder(tool, [f"{KS.prefix}/contacts/**"], tmp / "run.mcap", SITE).start()
        sub = tool.subscribe(f"{KS.prefix}/contacts/**", count)
        t0, events = time.monotonic(), KS.fused("r1", "events")

        def enough() -> bool:
            with lock:
                return time.monotonic() - t0 >= 3.0 and seen[events] >= 15

        # a span of press cycles, not of wall time: beside a busy worker the node's events came late and 3 s held
        # less than a second of clouds (the replay test had no interior left to compare)
        wait_for(enough, timeout=60.0)
        sub.close()
        stats = rec.stop()
        with lock:
            counted = dict(seen)
        yield tmp, tmp / "run.mcap", stats, counted
    finally:
        tool.close()
        stop_process(proc)


def test_a_recording_reads_back_with_a_channel_and_schema_per_key(recorded):
    tmp, path, stats, counted = recorded
    assert stats.dropped == 0 and stats.rejected == 0 and stats.lost == 0, stats
    rec = Recording.open(path)
    assert rec.site == SITE
    events_key, cloud_key = KS.fused("r1", "events"), KS.hypotheses("r1", "tactile")
    assert rec.channels[events_key] == {"contact_event"} and rec.channels[cloud_key] == {"hypothesis_cloud"}
    assert rec.counts[events_key] >= 8, rec.counts  # ~5 events/s for 3 s
    # the recorder and an independent subscriber started a moment apart: every key's count within a few
    for key, n in counted.items():
        assert abs(rec.counts.get(key, 0) - n) <= 3, (key, rec.counts.get(key), n)
    assert sum(rec.counts.values()) == stats.recorded
    assert {"/contacts/events", "/contacts/hypotheses", "/contacts/fused"} <= set(rec.view_topics)

    # the plain mcap reader: JSON schema per key, JSON messages, sequence per channel from 1
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        by_topic = {c.topic: c for c in summary.channels.values()}
        ch = by_topic[events_key]
        schema = summary.schemas[ch.schema_id]
        assert (schema.name, schema.encoding, ch.message_encoding) == ("contactflow.contact_event", "jsonschema", "json")
        assert json.loads(schema.data)["type"] == "object" and "location" in json.loads(schema.data)["properties"]
        assert summary.schemas[by_topic["/contacts/hypotheses"].schema_id].name == "foxglove.PointCloud"
        f.seek(0)
        msgs = [(m.sequence, json.loads(m.data)) for _, c, m in make_reader(f).iter_messages(topics=[events_key])]
    assert [s for s, _ in msgs] == list(range(1, len(msgs) + 1))
    assert {m["event"] for _, m in msgs} == {"contact_made", "contact_broken"}

    samples = list(rec.samples({events_key}))
    assert len(samples) == rec.counts[events_key] and all(isinstance(s.msg, ContactEventMsg) for s in samples)
    assert [s.log_ns for s in samples] == sorted(s.log_ns for s in samples)


def _events_and_clouds(rec):
    clouds, events = [], []
    for s in rec.samples():
        if isinstance(s.msg, HypothesisCloud):
            clouds.append(s.msg)
        elif isinstance(s.msg, ContactEventMsg):
            events.append(EventRecord.of(s.msg))
    return clouds, events


def test_refusion_with_the_recorded_parameters_on_the_recorded_cycles_reproduces_the_recorded_events(recorded):
    _, path, _, _ = recorded
    rec = Recording.open(path)
    clouds, events = _events_and_clouds(rec)
    cycles = [s.msg for s in rec.samples() if isinstance(s.msg, ContactList)]
    params = replace_params(FusionParams(), FUSION)
    again = refuse(clouds, params, cycles=cycles)
    cmp = compare(events, again, window=0.05, radius=0.005)
    # the first and last recorded events may lack their cloud (the recording starts and stops mid-press); the
    # others come on the very cycle they came on, whatever delays the loaded machine put between clouds and cycles
    # (on a grid from the clouds' stamps, CI once matched 12 of 15: a cycle late by more than the window)
    assert cmp.matched >= len(events) - 2 and len(cmp.unmatched_refused) <= 2, cmp.as_dict()
    assert cmp.dt_max == 0.0 and cmp.dist_max <= 0.005
    # a cluster must now weigh more than the whole pad: the same clouds make no contact
    assert refuse(clouds, replace_params(params, {"min_mass": 1e6}), cycles=cycles) == []
    # halving the tactile likelihoods below the floor, too
    assert refuse(clouds, replace_params(params, {"threshold": 0.9}), {"tactile": 0.5}, cycles) == []
    # on a grid (another rate): still the pad's presses, a made and a broken per press
    grid = refuse(clouds, params)
    assert abs(len(grid) - len(events)) <= 2 and {e.event.value for e in grid} == {"contact_made", "contact_broken"}


def test_replaying_the_clouds_into_a_fusion_node_makes_the_events_of_their_re_fusion(recorded):
    tmp, path, _, _ = recorded
    rec = Recording.open(path)
    _, recorded_events = _events_and_clouds(rec)
    site = "rep"
    proc, tool = _node(tmp, site, FUSING, "refuse", clock="sim")  # on the replay's clock: the recorded time
    got = []

    def on_event(key, payload):
        got.append(EventRecord.of(decode_any(payload, key)))
    try:
        sub = tool.subscribe(KeySpace(site).fused("r1", "events"), on_event)
        cloud_keys = {k for k, tags in rec.channels.items() if "hypothesis_cloud" in tags}
        # at a quarter of real time: the node's fusion times a source out after 0.1 s of the replay's clock, which
        # is then 0.4 s of wall time for a cloud to travel in on a loaded machine (at full speed one came too late)
        player = Replayer(tool, rec, site=site, keys=cloud_keys, rate=0.25)
        assert player.check() == []  # nobody publishes clouds on the new site
        assert player.makes_clock  # the recording has none: its nodes ran on the wall clock
        stats = player.run()
        time.sleep(0.5)
        sub.close()
    finally:
        tool.close()
        stop_process(proc)
    assert stats.messages == sum(rec.counts[k] for k in cloud_keys)
    assert 0.2 < stats.speed < 0.3 and stats.clock_ticks > 100, stats.as_dict()
    # The replayed node fuses on the recorded clock, so it makes the events the offline re-fusion of the same
    # clouds makes (the recorded live node ran on a loaded machine's wall clock: a cloud late by more than the
    # 0.1 s timeout broke a contact there that the clouds' stamps do not, so the recording is not the reference;
    # its events against the re-fusion are the test above). Every event of the interior has its partner on the
    # other side. At the edges a cloud may be missing (the recording starts and stops mid-press, the replayed
    # node starts on its first clock message), so events within a press cycle plus the fusion timeout of either
    # end are left out.
    clouds = _events_and_clouds(rec)[0]
    refused = refuse(clouds, replace_params(FusionParams(), FUSION))
    clouds_t = [c.stamp for c in clouds]
    lo, hi = min(clouds_t) + EDGE, max(clouds_t) - EDGE
    inner_ref = [e for e in refused if lo <= e.t <= hi]
    inner_got = [e for e in got if lo <= e.t <= hi]
    assert len(inner_ref) >= 6 and len(recorded_events) >= 8, (lo, hi, len(refused), len(recorded_events))
    there = compare(inner_ref, got, window=0.1, radius=0.005)
    back = compare(inner_got, refused, window=0.1, radius=0.005)
    assert there.matched == len(inner_ref) and back.matched == len(inner_got), (there.as_dict(), back.as_dict())
    assert there.dist_max <= 0.005


def test_replay_onto_a_site_with_live_publishers_on_the_recorded_keys_is_refused_unless_forced(recorded, tmp_path):
    _, path, _, _ = recorded
    rec = Recording.open(path)
    proc, tool = _node(tmp_path, SITE, SENSING, "live")
    try:
        player = Replayer(tool, rec, rate=0)
        with pytest.raises(ReplayError, match=r"live publishers on \d+ recorded keys.*--force"):
            player.check()
        assert KS.hypotheses("r1", "tactile") in player.check(force=True)
    finally:
        tool.close()
        stop_process(proc)


def test_truncated_foreign_and_non_mcap_files_are_refused_naming_the_file(recorded, tmp_path):
    _, path, _, _ = recorded
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match=r"cut\.mcap: truncated"):
        Recording.open(cut)
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel("/x", "json", sid)
        w.add_message(cid, 1, b"{}", 1)
        w.finish()
    with pytest.raises(RecordingError, match=r"foreign\.mcap: not a contactflow recording"):
        Recording.open(foreign)
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(RecordingError, match=r"notes\.txt: not an MCAP file"):
        Recording.open(text)
    with pytest.raises(RecordingError, match=r"absent\.mcap"):
        Recording.open(tmp_path / "absent.mcap")


def test_the_live_view_serves_the_advertised_channels_to_a_websocket_client(tmp_path):
    from websockets.sync.client import connect

    port = free_port()
    view = {"name": "view", "type": "foxglove_view", "params": {"port": port}}
    proc, tool = _node(tmp_path, "viewsite", [*SENSING, {**FUSING[0], "params": {**FUSION}}, view], "view")

    def listening() -> bool:  # a module is alive once set up; its server starts when it runs, just after
        with socket.socket() as sock:
            return sock.connect_ex(("127.0.0.1", port)) == 0

    try:
        assert wait_for(listening, timeout=30), (tmp_path / "view.log").read_text()[-3000:]
        topics: set[str] = set()
        with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], open_timeout=10) as ws:
            assert ws.subprotocol == "foxglove.sdk.v1"
            info = json.loads(ws.recv(timeout=5))
            assert info["op"] == "serverInfo"
            end = time.monotonic() + 10
            wanted = {"/contacts/events", "/contacts/hypotheses", "/contacts/fused"}
            subscribed = set()
            binary = 0
            while time.monotonic() < end and (not wanted <= topics or binary < 3):
                msg = ws.recv(timeout=max(0.1, end - time.monotonic()))
                if isinstance(msg, bytes):
                    binary += 1  # a message data frame of a subscribed channel
                    continue
                m = json.loads(msg)
                if m["op"] == "advertise":
                    new = [c for c in m["channels"] if c["topic"] in wanted and c["topic"] not in subscribed]
                    topics |= {c["topic"] for c in m["channels"]}
                    if new:
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": len(subscribed) + i, "channelId": c["id"]} for i, c in enumerate(new)]}))
                        subscribed |= {c["topic"] for c in new}
        assert wanted <= topics, topics
        assert binary >= 3, "no message data reached the subscribed client"
    finally:
        tool.close()
        stop_process(proc)


def test_the_command_line_refuses_bad_files_and_parameters_and_re_fuses_a_recording(recorded, tmp_path, monkeypatch):
    from rich.console import Console
    from typer.testing import CliRunner

    from contactflow.deploy import cli
    from contactflow.fusion import cli as fusion_cli

    _, path, _, _ = recorded
    monkeypatch.setattr(cli, "console", Console(width=300))
    monkeypatch.setattr(fusion_cli, "console", Console(width=300))
    runner = CliRunner()
    (tmp_path / "x.mcap").write_text("not mcap")
    r = runner.invoke(cli.app, ["replay", str(tmp_path / "x.mcap")])
    assert r.exit_code == 2 and "x.mcap: not an MCAP file" in r.output
    r = runner.invoke(cli.app, ["replay", str(path), "--key", "cf/rec/nothing"])
    assert r.exit_code == 2 and "no channel for key 'cf/rec/nothing'" in r.output
    r = runner.invoke(fusion_cli.app, ["refuse", str(path), "--set", "voxel=0.01"])
    assert r.exit_code == 2 and "--set voxel: unknown parameter" in r.output
    r = runner.invoke(fusion_cli.app, ["refuse", str(path), "--set", f"rate_hz={FUSION['rate_hz']}",
                                "--set", f"timeout={FUSION['timeout']}", "--set", f"hold={FUSION['hold']}",
                                "--robot", "r1", "--out", str(tmp_path / "cmp.json")])
    assert r.exit_code == 0, r.output
    cmp = json.loads((tmp_path / "cmp.json").read_text())
    assert cmp["params"]["hold"] == FUSION["hold"] and cmp["matched"] >= sum(cmp["recorded"].values()) - 2, cmp
    assert cmp["timing"].startswith("the recorded loop's") and cmp["dt_max"] == 0.0, cmp
    assert "contact_made" in r.output and "matched" in r.output
    r = runner.invoke(fusion_cli.app, ["refuse", str(path), "--grid", "--robot", "r1", "--out", str(tmp_path / "g.json")])
    assert r.exit_code == 0 and json.loads((tmp_path / "g.json").read_text())["timing"] == "a grid", r.output


def test_re_fusion_of_two_fusion_loops_cycles_asks_for_one_or_a_grid(tmp_path, monkeypatch):
    from rich.console import Console
    from typer.testing import CliRunner

    from contactflow.deploy.recording import RecordingWriter
    from contactflow.fusion import cli as fusion_cli
    from contactflow.nodes.wire import stamp

    w = RecordingWriter(tmp_path / "two.mcap", SITE).open()
    for i, robot in enumerate(("r1", "r2")):
        w.write(KS.fused(robot, "contacts"), stamp(ContactList(stamp=0.1), f"{robot}/n/fusion/contacts", 1, 0.1), 1_000 + i)
    w.close()
    monkeypatch.setattr(fusion_cli, "console", Console(width=300))
    r = CliRunner().invoke(fusion_cli.app, ["refuse", str(tmp_path / "two.mcap")])
    assert r.exit_code == 2 and "the cycles of 2 fusion loops (r1/n/fusion/contacts, r2/n/fusion/contacts)" in r.output
    assert "--robot" in r.output and "--grid" in r.output
    r = CliRunner().invoke(fusion_cli.app, ["refuse", str(tmp_path / "two.mcap"), "--robot", "r2", "--out",
                                            str(tmp_path / "r2.json")])
    assert r.exit_code == 0 and json.loads((tmp_path / "r2.json").read_text())["timing"] == "the recorded loop's 1 cycle"


def test_a_key_that_carries_several_message_types_gets_a_channel_per_type(tmp_path):
    from contactflow.deploy.recording import RecordingWriter
    from contactflow.embodiments.messages import CameraRequest, HandCommand
    from contactflow.nodes.wire import stamp

    key = KS.robot("r1", "command")
    sent = [HandCommand(robot="r1", hand="left", seq=1, preshape="closed"), CameraRequest(robot="r1", camera="head", request=1),
            HandCommand(robot="r1", hand="left", seq=2, preshape="open")]
    w = RecordingWriter(tmp_path / "cmd.mcap", SITE).open()
    for i, m in enumerate(sent):
        w.write(key, stamp(m, "r1/ctl/x", i + 1, 0.5 * i), 1_000 + i)
    w.close()
    rec = Recording.open(tmp_path / "cmd.mcap")
    assert rec.channels == {key: {"hand_command", "camera_request"}} and rec.counts == {key: 3}
    got = [s.msg for s in rec.samples()]
    assert [type(m) for m in got] == [type(m) for m in sent] and got[2].preshape == "open" and got[1].request == 1


def test_a_world_too_busy_to_describe_its_robot_is_asked_again_and_the_view_gets_the_robot(tmp_path):
    """The recorder's view asks a robot's world for its description on the robot's first state; a world that does
    not answer in time (a loaded machine) is asked again a second later, and its robot's URDF is in the recording."""
    import numpy as np

    from contactflow.embodiments.messages import RobotInfo, RobotState
    from contactflow.nodes.transport import LocalTransport
    from contactflow.nodes.wire import NDArray, encode, stamp

    t = LocalTransport()
    ks = KeySpace("busy")
    rec = Recorder(t, [ks.robot("m1", "state")], tmp_path / "busy.mcap", "busy").start()
    put = t.publisher(ks.robot("m1", "state"))
    asked: list[float] = []
    answering: list = []

    def state(seq: int) -> bytes:
        msg = RobotState(robot="m1", tick=seq, t=0.005 * seq, names=[], position=NDArray.of(np.zeros(0)),
                         velocity=NDArray.of(np.zeros(0)), arms=[], hands=[])
        return encode(stamp(msg, "m1/world/state", seq, 0.005 * seq))

    def info(key: str, payload: bytes) -> bytes:
        asked.append(time.monotonic())
        return encode(stamp(RobotInfo(robot="m1", embodiment="melfa", base=np.eye(4).ravel().tolist()), "w", 1, 0.0))

    try:
        put(state(1))  # no world answers yet
        assert wait_for(lambda: rec.stats.recorded == 1, 5)
        answering.append(t.queryable(ks.robot("m1", "info"), info))
        start = time.monotonic()
        for seq in range(2, 40):  # states keep coming, as they do every tick
            put(state(seq))
            time.sleep(0.05)
        assert len(asked) == 1 and asked[0] - start >= 0.9  # asked again once the second had passed, then known
    finally:
        for h in answering:
            h.close()
        rec.stop()
    assert "/m1/robot_description" in Recording.open(tmp_path / "busy.mcap").view_topics


def test_the_live_view_asks_a_world_that_did_not_answer_again_on_a_later_state():
    """As the recorder: a robot whose world gave no description is asked again (here on the next call), and its URDF
    goes to the viewers once it answers."""
    from types import SimpleNamespace

    import numpy as np

    from contactflow.deploy.view_module import FoxgloveView
    from contactflow.embodiments.messages import RobotInfo
    from contactflow.nodes.transport import LocalTransport
    from contactflow.nodes.wire import encode, stamp

    t, ks = LocalTransport(), KeySpace("viewbusy")
    view = FoxgloveView("view")
    logs: list[str] = []
    view.setup(SimpleNamespace(transport=t, keyspace=ks, node="n", log=logs.append))  # no server: not started
    view._asking.add("m1")  # a state of m1 came and its world was asked: no world answers (5 s)
    view._learn("m1")
    assert "m1" not in view._asking and not view._learned and "no frames for robot m1 yet" in logs[0]
    reply = encode(stamp(RobotInfo(robot="m1", embodiment="melfa", base=np.eye(4).ravel().tolist()), "w", 1, 0.0))
    handle = t.queryable(ks.robot("m1", "info"), lambda key, payload: reply)
    try:
        view._asking.add("m1")  # the next state asks again
        view._learn("m1")
    finally:
        handle.close()
    assert [topic for topic, _ in view._learned] == ["/m1/robot_description"] and "m1" in view._asking
