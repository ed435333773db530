"""Task files: YAML loading with file:line, validation refusals, dump/load round trip."""

from __future__ import annotations

import pytest

from contactflow.nodes.taskfile import dump_tasks, load_tasks, parse_tasks
from contactflow.nodes.taskgraph import TaskError, validate

GOOD = """\
nodes:
  move: {primitive: move_to}
  grasp:
    primitive: robust_grasp
    helpers: {watch: {primitive: wait_event}}
  done: {terminal: success}
edges:
  - {from: move, to: grasp, on: success}
  - {from: grasp, to: done, on: [success, watch.grasp_stable]}
  - {from: grasp, to: move, on: [[failure, error]]}
"""


def refused(text: str, *fragments: str) -> str:
    with pytest.raises(TaskError) as info:
        load_tasks("bad.yaml", text)
    msg = str(info.value)
    for f in fragments:
        assert f in msg, msg
    return msg


def test_good_file_loads_and_round_trips():
    tasks, main = load_tasks("good.yaml", GOOD)
    assert main == "good"
    t = tasks[main]
    assert t.start == "move" and t.nodes["grasp"].where.line == 3
    again, main2 = load_tasks("again.yaml", dump_tasks(tasks))
    a, b = again[main2], t
    assert a.nodes.keys() == b.nodes.keys()
    assert [(e.origin, e.dest, e.when) for e in a.edges] == [(e.origin, e.dest, e.when) for e in b.edges]
    assert a.nodes["grasp"].helpers[0].type == "wait_event"


def test_dangling_edge_with_line():
    refused(GOOD + "  - {from: grasp, to: nowhere, on: success}\n",
            "bad.yaml:11:", "dangling destination 'nowhere'")


def test_unknown_primitive_and_event_with_line():
    refused(GOOD.replace("move_to", "teleport"), "bad.yaml:2:", "unknown primitive type 'teleport'")
    refused(GOOD.replace("[success, watch", "[succes, watch"), "bad.yaml:9:", "unknown event 'succes'")
    refused(GOOD.replace("watch.grasp_stable", "eye.grasp_stable"), "bad.yaml:9:",
            "names no helper of node 'grasp'")


def test_unreachable_dead_end_and_no_terminal():
    msg = refused(GOOD.replace("edges:", "  orphan: {primitive: hold}\nedges:"),
                  "bad.yaml:7:", "'orphan' is unreachable")
    assert "dead end" in msg
    refused(GOOD.replace("done: {terminal: success}", "done: {primitive: hold}"),
            "bad.yaml:1: task 'bad' has no terminal state")


def test_primitive_types_come_from_the_module_registry():
    # a primitive registered by another area than the embodiments' is as good as theirs
    tasks, _ = load_tasks("watch.yaml", GOOD.replace("wait_event", "threshold_watch"))
    assert tasks["watch"].nodes["grasp"].helpers[0].type == "threshold_watch"
    # a registered module type of another layer is no primitive
    refused(GOOD.replace("move_to", "lowpass"), "bad.yaml:2:", "unknown primitive type 'lowpass'")
    assert load_tasks("any.yaml", GOOD.replace("move_to", "teleport"), primitives=None)[1] == "any"


def test_yaml_errors_and_structure_errors_have_lines():
    refused("nodes:\n  a: {primitive: hold\n", "bad.yaml:3:", "not valid YAML")
    refused(GOOD.replace("  done: {terminal: success}", "  done: {terminal: success}\n  move: {primitive: hold}"),
            "bad.yaml:7:", "duplicate key 'move'")
    refused(GOOD.replace("{primitive: move_to}", "{primitive: move_to, task: pick}"),
            "bad.yaml:2:", "exactly one of")
    refused(GOOD.replace("{primitive: move_to}", "{primitive: move_to, timout: 3}"),
            "bad.yaml:2:", "unknown key 'timout'")


def test_nested_task_references_are_checked():
    text = """
tasks:
  a:
    nodes:
      sub: {task: b}
      ok: {terminal: success}
    edges: [{from: sub, to: ok, on: success}]
  b:
    nodes:
      sub: {task: a}
      ok: {terminal: success}
    edges: [{from: sub, to: ok, on: success}]
"""
    with pytest.raises(TaskError, match="recursive: a -> b -> a"):
        load_tasks("nest.yaml", text)
    tasks, _ = parse_tasks(text.replace("task: a}", "task: c}"), "nest.yaml")
    with pytest.raises(TaskError, match="nest.yaml:10: .*unknown task 'c'"):
        validate(tasks["b"], tasks=tasks)
