"""The broker on the in-process transport: choice, refusal, `all`, failover."""

import threading

import pytest

from contactflow.abstraction.agent import EXAMPLES, RobotAgent
from contactflow.abstraction.broker import Broker
from contactflow.abstraction.client import close, dispatch, robots
from contactflow.abstraction.messages import DispatchRequest
from contactflow.abstraction.profiles import PROFILES
from contactflow.abstraction.testing import fake_executor
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.status import Event
from contactflow.nodes.transport import LocalTransport

KS = KeySpace("btest")
PUSH = (EXAMPLES / "push_away.xml").read_text()


class Site:
    def __init__(self, executors):
        self.t = LocalTransport()
        self.broker = Broker(self.t, KS, bid_timeout=1.0)
        self.broker.start()
        self.agents = {}
        self.started: dict[str, int] = {}
        for name, ex in executors.items():
            self.agents[name] = RobotAgent(PROFILES[name], self.t, KS, ex, node=f"{name}_control")
            self.agents[name].start()

    def run(self, atd, target="any", file="push_away.xml", params=None, wait=20.0):
        follow = dispatch(self.t, KS, atd, file, target=target, params=params)
        follow.done.wait(wait)
        close(follow)
        return follow

    def close(self):
        for a in self.agents.values():
            a.stop()
        self.broker.stop()


@pytest.fixture
def site_factory():
    made = []

    def make(executors):
        s = Site(executors)
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


def counting(counter, name, **kw):
    def on_start():
        counter[name] = counter.get(name, 0) + 1
    return fake_executor(on_start=on_start, **kw)


def test_any_picks_one_capable_robot_and_reports_in_atd_names(site_factory):
    starts = {}
    site = site_factory({n: counting(starts, n) for n in ("tombatossals", "melfa", "baxter")})
    follow = site.run(PUSH)
    assert follow.reply.ok and len(follow.reply.robots) == 1
    assert follow.outcome == "success"
    assert sum(starts.values()) == 1
    states = [m.state for m in follow.progress if m.kind == "entered" and m.robot != "broker"]
    assert states[:3] == ["approach", "push_object", "retreat"]
    assert states[-1] == "pushed"


def test_all_runs_on_every_capable_robot(site_factory):
    starts = {}
    site = site_factory({n: counting(starts, n) for n in ("tombatossals", "melfa", "baxter")})
    follow = site.run(PUSH, target="all")
    assert sorted(follow.reply.robots) == ["baxter", "melfa", "tombatossals"]
    assert follow.outcome == "success"
    assert starts == {"tombatossals": 1, "melfa": 1, "baxter": 1}
    finals = {m.robot: m.outcome for m in follow.progress if m.final and m.robot != "broker"}
    assert finals == {"tombatossals": "success", "melfa": "success", "baxter": "success"}


def test_named_robot_and_capabilities(site_factory):
    site = site_factory({n: fake_executor() for n in ("tombatossals", "melfa")})
    follow = site.run(PUSH, target="melfa")
    assert follow.reply.robots == ["melfa"] and follow.outcome == "success"
    caps = robots(site.t, KS)
    assert [c.robot for c in caps] == ["melfa", "tombatossals"]
    assert "robust_grasp" in caps[1].primitives and caps[0].hand == "parallel"


def test_refused_with_reasons_per_robot_when_none_can_translate(site_factory):
    site = site_factory({n: fake_executor() for n in ("tombatossals", "melfa", "baxter")})
    assert "<location>0.0 0.50 0.03</location>" in PUSH
    far = PUSH.replace("<location>0.0 0.50 0.03</location>", "<location>9.0 9.0 0.03</location>")
    follow = site.run(far)
    assert not follow.reply.ok
    assert set(follow.reply.refusals) == {"tombatossals", "melfa", "baxter"}
    assert all("obstacle_box" in " ".join(r) or "reach" in " ".join(r) for r in follow.reply.refusals.values())
    assert follow.final.kind == "refused" and follow.outcome == "failure"
    assert "melfa" in follow.final.detail


def test_invalid_atd_is_never_dispatched(site_factory):
    starts = {}
    site = site_factory({"tombatossals": counting(starts, "tombatossals")})
    bad = PUSH.replace('destination="retreat"', 'destination="nowhere"')
    follow = site.run(bad)
    assert not follow.reply.ok and "invalid ATD" in follow.reply.error and "nowhere" in follow.reply.error
    assert starts == {}
    unknown = site.run("a: [1,", file="bad.yaml")
    assert not unknown.reply.ok and "bad.yaml" in unknown.reply.error


def test_an_invalid_task_id_is_refused_with_a_reply_and_leaves_no_id_in_use(site_factory):
    starts = {}
    site = site_factory({"tombatossals": counting(starts, "tombatossals")})
    for bad in ("a/b", "*", "", "x#1"):
        reply = site.broker.dispatch(DispatchRequest(task_id=bad, atd=PUSH, file="push_away.xml"))
        assert not reply.ok and "task_id" in reply.error, bad
        assert bad not in site.broker.tasks
    assert starts == {} and site.broker.rejected == 4
    ok = site.broker.dispatch(DispatchRequest(task_id="push-1", atd=PUSH, file="push_away.xml"))
    assert ok.ok, ok.error


def test_a_dispatch_that_fails_inside_the_broker_is_still_answered(site_factory, monkeypatch):
    from contactflow.abstraction.messages import DispatchReply
    from contactflow.nodes.wire import decode, encode

    site = site_factory({"tombatossals": counting({}, "tombatossals")})

    def broken(record):
        raise RuntimeError("assignment exploded")

    monkeypatch.setattr(site.broker, "_assign", broken)
    payload = encode(DispatchRequest(task_id="t-1", atd=PUSH, file="push_away.xml"))
    reply = decode(site.broker._on_dispatch("k", payload), DispatchReply)
    assert not reply.ok and "assignment exploded" in reply.error


def test_hardware_failure_fails_over_to_the_next_robot(site_factory):
    calls = []

    def first_fails(name):
        failing, fine = fake_executor(fail_type="move_to"), fake_executor()

        def run(*args):
            calls.append(name)
            return (failing if len(calls) == 1 else fine)(*args)
        return run

    site = site_factory({n: first_fails(n) for n in ("tombatossals", "melfa")})
    follow = site.run(PUSH, target="any")
    assert follow.outcome == "success", [(m.robot, m.kind, m.detail) for m in follow.progress]
    kinds = [m.kind for m in follow.progress if m.robot == "broker"]
    assert kinds == ["assigned", "failover", "assigned", "finished"]
    assert len(calls) == 2 and calls[0] != calls[1]
    finals = [(m.robot, m.outcome) for m in follow.progress if m.final and m.robot != "broker"]
    assert finals == [(calls[0], "hardware_failure"), (calls[1], "success")]


def test_lost_robot_liveliness_fails_over(site_factory):
    started = threading.Event()

    def hangs_until_cancelled(translation, report, cancel, params):
        started.set()
        cancel.wait(30)
        return Event.ERROR

    site = site_factory({"tombatossals": hangs_until_cancelled})
    follow = dispatch(site.t, KS, PUSH, "push_away.xml", target="any")
    assert started.wait(5)
    assert follow.reply.robots == ["tombatossals"]
    melfa = RobotAgent(PROFILES["melfa"], site.t, KS, fake_executor(duration=0.1))
    melfa.start()
    site.agents["melfa"] = melfa
    # the robot's process dies: its liveliness token and queryables vanish, no final report
    for handle in site.agents["tombatossals"]._handles:
        handle.close()
    assert follow.done.wait(20)
    close(follow)
    assert follow.outcome == "success"
    assert any(m.kind == "failover" and "liveliness" in m.detail for m in follow.progress)
    assert [m.robot for m in follow.progress if m.final and m.robot != "broker"] == ["melfa"]


def test_replies_and_progress_carry_real_headers(site_factory):
    site = site_factory({"melfa": fake_executor()})
    follow = site.run(PUSH, target="melfa")
    assert follow.outcome == "success"
    reply = follow.reply
    assert reply.hdr.source == "site/broker/broker" and reply.hdr.seq >= 1 and reply.hdr.t_sim > 0
    assert len(reply.hdr.inputs) == 1 and reply.hdr.inputs[0].source == "site/tool/dispatch"
    by_source = {}
    for m in follow.progress:
        by_source.setdefault(m.hdr.source, []).append(m)
        assert m.hdr.t_sim > 0 and m.hdr.t_wall > 0
    assert set(by_source) == {"site/broker/broker", "melfa/melfa_control/agent"}
    for msgs in by_source.values():  # counted per source on the task's key, from 1, without gaps
        assert [m.hdr.seq for m in msgs] == list(range(1, len(msgs) + 1))
    robot = by_source["melfa/melfa_control/agent"]
    assert all(m.hdr.inputs and m.hdr.inputs[0].source == "site/broker/broker" for m in robot)  # the run request
    caps = robots(site.t, KS)
    assert caps and caps[0].hdr.source == "melfa/melfa_control/agent" and caps[0].hdr.seq >= 1
