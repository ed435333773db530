"""Task engine on pure fakes: cycles, nesting, timeouts, parallel tasks, online binding."""

from __future__ import annotations

import pytest

from contactflow.nodes.status import Event, Status
from contactflow.nodes.taskengine import ProgressKind, TaskEngine
from contactflow.nodes.taskfile import parse_tasks
from contactflow.nodes.taskgraph import TaskError
from contactflow.nodes.testing_tasks import FakeClock, FakeRunner, Step, run_until_done

S, F = Event.SUCCESS, Event.FAILURE

LIB = """
main: clear_table
tasks:
  pick:
    params: {approach: null}
    timeout: 20
    nodes:
      move: {primitive: move_to, params: {target: "${params.approach}"}}
      grasp:
        primitive: robust_grasp
        helpers: {watch: {primitive: wait_event, params: {event: grasp_stable}}}
      lift: {primitive: lift}
      picked: {terminal: success}
      dropped: {terminal: failure}
    edges:
      - {from: move, to: grasp, on: success}
      - {from: grasp, to: lift, on: [success, watch.grasp_stable]}
      - {from: grasp, to: move, on: failure, name: regrasp}
      - {from: lift, to: picked, on: success}
      - {from: lift, to: dropped, on: grasp_lost}
  place:
    nodes:
      where: {primitive: place_location}
      put: {primitive: place, params: {target: "${where.location}"}}
      rel: {primitive: release}
      ok: {terminal: success}
    edges:
      - {from: where, to: put, on: success}
      - {from: put, to: rel, on: success}
      - {from: rel, to: ok, on: success}
  clear_table:
    nodes:
      detect: {primitive: detect_objects, params: {region: table}}
      pick: {task: pick, params: {approach: "${detect.approach_vector}"}}
      place: {task: place}
      cleared: {terminal: success, event: object_not_found}
      failed: {terminal: failure}
    edges:
      - {from: detect, to: pick, on: object_detected}
      - {from: detect, to: cleared, on: object_not_found}
      - {from: pick, to: place, on: success}
      - {from: place, to: detect, on: success}
"""


def engine_for(text: str = LIB):
    tasks, main = parse_tasks(text, "lib.yaml")
    clock = FakeClock()
    runner = FakeRunner(clock)
    log = []
    eng = TaskEngine(runner, clock, library=tasks, on_progress=log.append)
    return eng, runner, clock, tasks, main, log


def test_cycle_nested_tasks_and_online_binding():
    eng, runner, clock, tasks, main, log = engine_for()
    # two objects on the table, then none: the top-level cycle runs twice
    runner.script(
        "detect",
        [Step(0.1, Event.OBJECT_DETECTED, {"approach_vector": [0.1, 0.2, 0.3]})],
        [Step(0.1, Event.OBJECT_DETECTED, {"approach_vector": [0.4, 0.5, 0.6]})],
        [Step(0.1, Event.OBJECT_NOT_FOUND)],
    )
    for t in ("move_to", "robust_grasp", "lift", "release"):
        runner.script(t, [Step(0.2, S)])
    runner.script("pick/grasp.watch", [Step(0.3, Event.GRASP_STABLE)])
    runner.script("place_location", [Step(0.1, S, {"location": [1.0, 0.0, 0.8]})])
    runner.script("place", [Step(0.2, S)])
    run = eng.launch(tasks[main])
    res = run_until_done(eng, clock, run)
    assert res.status is Status.SUCCESS and res.event is Event.OBJECT_NOT_FOUND
    assert res.terminal == "cleared"
    moves = [p for _, t, p in runner.starts if t == "move_to"]
    assert moves == [{"target": [0.1, 0.2, 0.3]}, {"target": [0.4, 0.5, 0.6]}]
    places = [p for _, t, p in runner.starts if t == "place"]
    assert places == [{"target": [1.0, 0.0, 0.8]}] * 2
    # the grasp waited for the watcher's stable grasp (conjunction), then lifted
    grasp_edges = [p for p in log if p.kind is ProgressKind.EDGE and p.node == "grasp"]
    assert all(p.t >= 0.3 for p in grasp_edges)
    assert runner.active == {}, "every instance stopped"
    assert sorted(i for i, _, _ in runner.starts) == sorted(runner.stops)
    entered = [p.path + (p.node,) for p in log if p.kind is ProgressKind.ENTERED]
    assert ("clear_table", "pick", "grasp") in entered
    assert ("clear_table", "place", "put") in entered


def test_inner_cycle_regrasp_then_grasp_lost_fails_parent():
    eng, runner, clock, tasks, main, log = engine_for()
    runner.script("move_to", [Step(0.1, S)])
    runner.script("robust_grasp", [Step(0.1, F)], [Step(0.1, S)])
    runner.script("grasp.watch", [Step(0.05, Event.GRASP_STABLE)])
    runner.script("lift", [Step(0.5, Event.GRASP_LOST)])
    run = eng.launch(tasks["pick"], {"approach": [0, 0, 1]})
    res = run_until_done(eng, clock, run)
    assert res.status is Status.FAILURE and res.terminal == "dropped"
    assert res.event is Event.FAILURE and res.t < 2.0, "dropped on grasp_lost, not by timeout"
    assert runner.started_types().count("robust_grasp") == 2
    assert [p.edge for p in log if p.kind is ProgressKind.EDGE][:3] == [
        "move->grasp#0", "regrasp", "move->grasp#0"]


def test_timeout_takes_implicit_fault_exit_and_propagates():
    eng, runner, clock, tasks, main, log = engine_for()
    runner.script("detect", [Step(0.1, Event.OBJECT_DETECTED, {"approach_vector": [0, 0, 1]})])
    runner.script("move_to", [])  # never finishes
    run = eng.launch(tasks[main])
    res = run_until_done(eng, clock, run)
    # pick's node timeout (20 s) fails pick through its failure terminal with TIMEOUT;
    # clear_table has no edge for timeout, so it fails too and reports the timeout
    assert res.status is Status.FAILURE and res.event is Event.TIMEOUT
    assert res.terminal == "failed"
    assert 20.0 <= res.t < 20.2
    implicit = [p for p in log if p.kind is ProgressKind.EDGE and p.implicit]
    assert [(p.path, p.node, p.event) for p in implicit] == [
        (("clear_table", "pick"), "move", Event.TIMEOUT),
        (("clear_table",), "pick", Event.TIMEOUT)]
    assert runner.active == {}


def test_explicit_timeout_edge_is_followed():
    text = """
nodes:
  wait: {primitive: wait_event, timeout: 2.5}
  search: {primitive: explore}
  found: {terminal: success}
edges:
  - {from: wait, to: found, on: motion_detected}
  - {from: wait, to: search, on: timeout}
  - {from: search, to: found, on: contact}
"""
    eng, runner, clock, tasks, main, log = engine_for(text)
    runner.script("explore", [Step(1.0, Event.CONTACT)])
    res = run_until_done(eng, clock, eng.launch(tasks[main]))
    assert res.status is Status.SUCCESS
    assert 3.5 <= res.t <= 3.7
    assert runner.started_types() == ["wait_event", "explore"]


def test_parallel_node_track_while_picking():
    text = """
main: look_and_pick
tasks:
  track:
    nodes:
      follow: {primitive: move_to, params: {head: true}}
      lost: {terminal: failure, event: object_lost}
    edges: [{from: follow, to: lost, on: object_lost}]
  look_and_pick:
    nodes:
      both:
        parallel: [{name: look, task: track}, {name: grab, primitive: robust_grasp}]
      done: {terminal: success}
      bad: {terminal: failure}
    edges:
      - {from: both, to: done, on: success}
      - {from: both, to: bad, on: object_lost}
"""
    eng, runner, clock, tasks, main, log = engine_for(text)
    runner.script("robust_grasp", [Step(1.0, S)])
    res = run_until_done(eng, clock, eng.launch(tasks[main]))
    assert res.status is Status.SUCCESS
    assert set(runner.started_types()) == {"move_to", "robust_grasp"}
    assert runner.active == {}, "the tracking branch is stopped when the grab finishes"

    eng, runner, clock, tasks, main, log = engine_for(text)
    runner.script("robust_grasp", [Step(5.0, S)])
    runner.script("move_to", [Step(1.0, Event.OBJECT_LOST)])
    res = run_until_done(eng, clock, eng.launch(tasks[main]))
    assert res.terminal == "bad" and res.t < 1.2


def test_parallel_until_all_and_two_top_level_runs():
    text = """
nodes:
  both:
    parallel: [{name: a, primitive: hold}, {name: b, primitive: lift}]
    until: all
  done: {terminal: success}
  bad: {terminal: failure}
edges:
  - {from: both, to: done, on: success}
  - {from: both, to: bad, on: failure}
"""
    eng, runner, clock, tasks, main, log = engine_for(text)
    runner.script("hold", [Step(1.0, S)])
    runner.script("lift", [Step(2.0, S)])
    r1 = eng.launch(tasks[main], run_id="left")
    clock.advance(0.5)
    r2 = eng.launch(tasks[main], run_id="right")
    assert eng.running == ["left", "right"]
    res1 = run_until_done(eng, clock, r1)
    assert res1.status is Status.SUCCESS and 1.99 <= res1.t < 2.1
    res2 = run_until_done(eng, clock, r2)
    assert res2.status is Status.SUCCESS and 2.49 <= res2.t < 2.6
    runs = {p.run for p in log}
    assert runs == {"left", "right"}


def test_unbound_runtime_reference_fails_node_with_error():
    text = """
nodes:
  detect: {primitive: detect_objects}
  move: {primitive: move_to, params: {target: "${detect.approach_vector}"}}
  ok: {terminal: success}
  bad: {terminal: failure}
edges:
  - {from: detect, to: move, on: success}
  - {from: move, to: ok, on: success}
"""
    eng, runner, clock, tasks, main, log = engine_for(text)
    runner.script("detect_objects", [Step(0.1, S, {"count": 0})])
    res = run_until_done(eng, clock, eng.launch(tasks[main]))
    assert res.event is Event.ERROR and res.terminal == "bad"
    assert "move_to" not in runner.started_types()
    errs = [p.detail for p in log if p.kind is ProgressKind.EVENT and p.event is Event.ERROR]
    assert any("approach_vector" in d for d in errs)


def test_plan_binding_refuses_missing_and_unknown_parameters():
    eng, runner, clock, tasks, main, log = engine_for()
    with pytest.raises(TaskError, match="needs parameter 'approach'"):
        eng.launch(tasks["pick"])
    with pytest.raises(TaskError, match="no parameter 'speed'"):
        eng.launch(tasks["pick"], {"approach": [0, 0, 1], "speed": 2})


def test_hardware_failure_propagates_from_helper_and_cancel_stops_all():
    eng, runner, clock, tasks, main, log = engine_for()
    runner.script("move_to", [Step(0.1, S)])
    runner.script("grasp.watch", [Step(0.2, Event.HARDWARE_FAILURE)])
    res = run_until_done(eng, clock, eng.launch(tasks["pick"], {"approach": [0, 0, 1]}))
    assert res.event is Event.HARDWARE_FAILURE and res.status is Status.FAILURE

    eng, runner, clock, tasks, main, log = engine_for()
    run = eng.launch(tasks["pick"], {"approach": [0, 0, 1]})
    clock.advance(1.0)
    eng.tick()
    assert runner.active
    eng.cancel(run)
    assert runner.active == {} and eng.result(run).event is Event.ERROR


def test_invalid_graph_is_refused_at_launch_and_spinning_cycle_is_stopped():
    bad = """
nodes:
  a: {primitive: hold, params: {x: "${nothing.value}"}}
  b: {terminal: success}
edges:
  - {from: a, to: b, on: success}
"""
    eng, runner, clock, tasks, main, log = engine_for(bad)
    with pytest.raises(TaskError, match="names no node"):
        eng.launch(tasks[main])
    assert runner.starts == []
    spin = """
nodes:
  w: {primitive: touch}
  a: {primitive: hold, params: {x: "${c.value}"}}
  c: {primitive: touch}
  b: {terminal: success}
edges:
  - {from: w, to: a, on: success}
  - {from: a, to: a, on: error}
  - {from: a, to: c, on: contact}
  - {from: c, to: b, on: success}
"""
    calm_text = "nodes:\n  t: {primitive: touch}\n  b: {terminal: success}\nedges: [{from: t, to: b, on: success}]\n"
    eng, runner, clock, tasks, main, log = engine_for(spin)
    runner.script("touch", [Step(0.1, S)])
    spinning = eng.launch(tasks[main], run_id="spinning")
    calm = eng.launch(parse_tasks(calm_text)[0]["task"], run_id="calm")
    clock.advance(0.1)
    eng.tick()  # both touches succeed in this tick; the spinning run starts its cycle first
    res = eng.result(spinning)
    assert res is not None and res.event is Event.ERROR and "never waits" in res.detail
    assert eng.result(calm).status is Status.SUCCESS, "the spin does not use up another run's budget"
    assert runner.active == {}
