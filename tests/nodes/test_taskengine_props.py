"""Property test: on random graphs and random primitive behaviour the engine keeps its books."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from contactflow.nodes.status import Event
from contactflow.nodes.taskengine import ProgressKind, TaskEngine
from contactflow.nodes.taskgraph import Edge, Node, NodeKind, TaskGraph, Trigger, validate
from contactflow.nodes.testing_tasks import FakeClock, FakeRunner, Step

EVENTS = [Event.SUCCESS, Event.FAILURE, Event.CONTACT, Event.ERROR, Event.GRASP_LOST]


@st.composite
def graphs(draw):
    n = draw(st.integers(1, 5))
    ids = [f"p{i}" for i in range(n)]
    nodes = {i: Node(i, NodeKind.PRIMITIVE, type="hold", timeout=draw(st.sampled_from([1.0, 2.5, None])))
             for i in ids}
    nodes["ok"] = Node("ok", NodeKind.SUCCESS)
    nodes["ko"] = Node("ko", NodeKind.FAILURE)
    edges = []
    # a chain keeps every node reachable, random extra edges add cycles
    for k, i in enumerate(ids):
        nxt = ids[k + 1] if k + 1 < n else "ok"
        edges.append(Edge(f"c{k}", i, nxt, (frozenset({Trigger(Event.SUCCESS)}),)))
    for k in range(draw(st.integers(0, 6))):
        a = draw(st.sampled_from(ids))
        b = draw(st.sampled_from(ids + ["ok", "ko"]))
        ev = draw(st.sampled_from(EVENTS))
        edges.append(Edge(f"x{k}", a, b, (frozenset({Trigger(ev)}),)))
    return TaskGraph("random", nodes, tuple(edges), start="p0", timeout=3.0)


scripts = st.lists(st.tuples(st.floats(0.0, 2.0), st.sampled_from(EVENTS)), max_size=3)


@settings(max_examples=60, deadline=None)
@given(graphs(), st.lists(scripts, min_size=1, max_size=4))
def test_engine_books_balance_on_random_graphs(task, runs):
    validate(task)
    clock = FakeClock()
    runner = FakeRunner(clock)
    runner.script("hold", *[[Step(t, e) for t, e in r] for r in runs])
    log = []
    eng = TaskEngine(runner, clock, on_progress=log.append)
    run = eng.launch(task)
    for _ in range(200):
        if eng.done(run):
            break
        clock.advance(0.1)
        eng.tick()
        # only the current node's primitive runs
        assert len(runner.active) <= 1
    stopped = set(runner.stops)
    started = {i for i, _, _ in runner.starts}
    assert stopped <= started
    if eng.done(run):
        assert runner.active == {} and stopped == started
        assert log[-1].kind is ProgressKind.FINISHED
        assert eng.result(run).terminal in ("ok", "ko")
    entered = [p.node for p in log if p.kind is ProgressKind.ENTERED]
    edges = [p for p in log if p.kind is ProgressKind.EDGE]
    assert len(entered) == len(edges) + 1
