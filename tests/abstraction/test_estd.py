"""The ESTD on the wire: the broker sends the bid's translation, the robot checks it and never re-translates."""


import time

import pytest

from contactflow.abstraction.agent import EXAMPLES, RobotAgent, dry_run
from contactflow.abstraction.broker import Broker
from contactflow.abstraction.client import close, dispatch
from contactflow.abstraction.estd import EstdError, estd_message, received
from contactflow.abstraction.messages import (
    Bid,
    EdgeEvents,
    Estd,
    RunReply,
    RunRequest,
    TranslateRequest,
)
from contactflow.abstraction.profiles import PROFILES
from contactflow.abstraction.testing import fake_executor
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.status import Event
from contactflow.nodes.taskfile import task_dict
from contactflow.nodes.transport import LocalTransport
from contactflow.nodes.wire import decode, encode

KS = KeySpace("estdtest")


def translation(robot, name="pick_place_behind.xml"):
    bid, tr = dry_run(PROFILES[robot], (EXAMPLES / name).read_text(), name)
    assert bid.ok and tr is not None and bid.estd == estd_message(tr)
    return tr


@pytest.mark.parametrize("robot", sorted(PROFILES))
def test_a_received_estd_is_the_translation_with_its_atd_names_and_events(robot):
    tr = translation(robot)
    got = received(estd_message(tr), PROFILES[robot], "run")
    assert got.atd is None
    assert task_dict(got.estd) == task_dict(tr.estd)
    assert dict(got.states) == dict(tr.states) and dict(got.transitions) == dict(tr.transitions)
    assert {e: dict(m) for e, m in got.labels.items()} == {e: dict(m) for e, m in tr.labels.items()}
    assert dict(got.node_ids) == dict(tr.node_ids)


def refusal(msg, robot="baxter"):
    with pytest.raises(EstdError) as exc:
        received(msg, PROFILES[robot], "robots/baxter/run")
    return str(exc.value)


def test_a_malformed_estd_is_refused_with_its_reason():
    good = estd_message(translation("baxter"))
    assert "translated for 'baxter', not for 'melfa'" in refusal(good, robot="melfa")
    assert "not valid YAML" in refusal(Estd(robot="baxter", task="tasks: {a: [1,"))
    first = good.task.index("primitive: ") + len("primitive: ")
    alien = good.task[:first] + "fly_away" + good.task[good.task.index("\n", first):]
    assert "fly_away" in refusal(Estd(robot="baxter", task=alien, events=good.events))
    no_edge = [*good.events, EdgeEvents(edge="nowhere", event="success", groups=[["success"]])]
    assert "'nowhere'" in refusal(Estd(robot="baxter", task=good.task, events=no_edge))
    edge = good.events[0].edge
    stray = [EdgeEvents(edge=edge, event="success", groups=[["grasp_lost"]])]
    assert "not on that edge" in refusal(Estd(robot="baxter", task=good.task, events=stray))
    unknown = [EdgeEvents(edge=edge, event="teleported", groups=[["success"]])]
    assert "teleported" in refusal(Estd(robot="baxter", task=good.task, events=unknown))


def test_the_agent_refuses_a_malformed_estd_and_never_runs_it():
    t = LocalTransport()
    runs = []

    def executor(*args):
        runs.append(args)
        return Event.SUCCESS

    agent = RobotAgent(PROFILES["melfa"], t, KS, executor)
    agent.start()
    try:
        bad = Estd(robot="melfa", task="main: x\ntasks: {x: {nodes: {a: {primitive: fly_away}}}}")
        ((key, payload),) = t.query(KS.robot_service("melfa", "run"), encode(RunRequest(task_id="t1", estd=bad)))
        reply = decode(payload, RunReply, key)
        assert not reply.ok and "ESTD refused" in reply.error and "fly_away" in reply.error
        assert agent.rejected == 1 and runs == [] and not agent.busy
    finally:
        agent.stop()


class FakeRobot:
    """A robot answering the dry run with a given ESTD and recording what it is asked to run."""

    def __init__(self, t, robot, estd):
        self.robot, self.estd, self.runs = robot, estd, []
        self.handles = [t.queryable(KS.robot_service(robot, "translate"), self.on_translate),
                        t.queryable(KS.robot_service(robot, "run"), self.on_run), t.token(KS.alive_robot(robot))]

    def on_translate(self, key, payload):
        decode(payload, TranslateRequest, key)
        return encode(Bid(robot=self.robot, ok=True, estimated_duration=1.0, estd=self.estd))

    def on_run(self, key, payload):
        self.runs.append(decode(payload, RunRequest, key))
        return encode(RunReply(ok=True, robot=self.robot))


def test_the_broker_sends_the_estd_the_bid_carried():
    t = LocalTransport()
    broker = Broker(t, KS, bid_timeout=0.5)
    broker.start()
    chosen = estd_message(translation("melfa", "push_away.xml"))
    # not what melfa would translate now: the broker must not translate or alter anything itself
    marked = Estd(robot="melfa", task=chosen.task.replace("label: approach", "label: approach_marked", 1),
                  events=chosen.events)
    assert marked.task != chosen.task
    robot = FakeRobot(t, "melfa", marked)
    try:
        follow = dispatch(t, KS, (EXAMPLES / "push_away.xml").read_text(), "push_away.xml", target="melfa")
        close(follow)
        assert follow.reply.ok, follow.reply.error
        (run,) = robot.runs
        assert run.estd == marked and run.file == "push_away.xml" and run.task_id == follow.task_id
        assert not hasattr(run, "atd")
    finally:
        for h in robot.handles:
            h.close()
        broker.stop()


def test_the_robot_runs_the_bid_time_translation():
    t = LocalTransport()
    broker = Broker(t, KS, bid_timeout=0.5)
    broker.start()
    seen = []
    inner = fake_executor(duration=0.05)

    def executor(tr, report, cancel, params):
        seen.append(tr)
        return inner(tr, report, cancel, params)

    agent = RobotAgent(PROFILES["tombatossals"], t, KS, executor)
    agent.start()
    try:
        follow = dispatch(t, KS, (EXAMPLES / "push_away.xml").read_text(), "push_away.xml")
        assert follow.done.wait(10)
        close(follow)
        assert follow.outcome == "success"
        (tr,) = seen
        assert tr.atd is None  # rebuilt from the ESTD it was sent, not translated from the ATD again
        assert task_dict(tr.estd) == task_dict(translation("tombatossals", "push_away.xml").estd)
        entered = [m.state for m in follow.progress if m.kind == "entered" and m.robot == "tombatossals"]
        assert entered[:3] == ["approach", "push_object", "retreat"]
    finally:
        agent.stop()
        broker.stop()


def test_a_robot_that_reported_its_task_finished_takes_the_next_one_at_once():
    # the broker hears the final report and may send the next task before the job's thread has returned: the
    # robot is free from its final report on (it answered "busy" while the thread only had its return left)
    from contactflow.abstraction.messages import AbstractProgressMsg

    t = LocalTransport()
    agent = RobotAgent(PROFILES["melfa"], t, KS, fake_executor(duration=0.05))
    estd = estd_message(translation("melfa"))
    at_end: list[tuple[bool, RunReply]] = []
    second: list[str] = []

    def on_progress(key, payload):
        msg = decode(payload, AbstractProgressMsg, key)
        if msg.final and msg.task_id == "t2":
            second.append(msg.outcome)
        if msg.final and msg.task_id == "t1":  # delivered in the job's thread, as its report goes out
            busy = agent.busy
            ((k, p),) = t.query(KS.robot_service("melfa", "run"), encode(RunRequest(task_id="t2", estd=estd)))
            at_end.append((busy, decode(p, RunReply, k)))

    subs = [t.subscribe(KS.progress(task), on_progress) for task in ("t1", "t2")]
    agent.start()
    try:
        ((key, payload),) = t.query(KS.robot_service("melfa", "run"), encode(RunRequest(task_id="t1", estd=estd)))
        assert decode(payload, RunReply, key).ok
        deadline = time.monotonic() + 30.0
        while not second and not (at_end and not at_end[0][1].ok) and time.monotonic() < deadline:
            time.sleep(0.01)
        ((busy, reply),) = at_end
        assert not busy and reply.ok, reply.error
        assert second == ["success"]  # and it ran the next task to its end
    finally:
        for sub in subs:
            sub.close()
        agent.stop()
