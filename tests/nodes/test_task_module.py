"""The task module shell: primitives commanded by control messages, events fed back."""

from __future__ import annotations

from contactflow.nodes.messages import Command, EventMsg
from contactflow.nodes.status import Event, Status
from contactflow.nodes.task_module import TaskModule
from contactflow.nodes.testing import FakeIO

TASK = """
nodes:
  move: {primitive: move_to, params: {target: [0.1, 0.2, 0.3], motion: line}}
  grasp: {primitive: close_until_force, params: {grasp_force: 5.0}}
  done: {terminal: success}
edges:
  - {from: move, to: grasp, on: success}
  - {from: grasp, to: done, on: success}
"""


def test_task_module_commands_primitives_and_finishes(tmp_path):
    f = tmp_path / "pick.yaml"
    f.write_text(TASK)
    mod = TaskModule("pick", TaskModule.Params(task_file=str(f), robot="melfa"))
    io = FakeIO(module=mod)
    mod.setup(io)
    mod.start()
    assert io.commands[:3] == [
        ("melfa/move_to", Command.RESET, {}),
        ("melfa/move_to", Command.SET, {"target": [0.1, 0.2, 0.3], "motion": "line"}),
        ("melfa/move_to", Command.RUN, {}),
    ]
    assert mod.step() is Status.RUNNING
    io.feed("events", EventMsg(event=Event.CONTACT, module="melfa/ctl/move_to"))
    io.feed("events", EventMsg(event=Event.SUCCESS, module="melfa/ctl/move_to"))
    assert mod.step() is Status.RUNNING
    assert ("melfa/move_to", Command.STOP, {}) in io.commands
    assert io.commands[-1] == ("melfa/close_until_force", Command.RUN, {})
    io.t = 1.0
    io.feed("events", EventMsg(event=Event.SUCCESS, module="melfa/ctl/close_until_force"))
    assert mod.step() is Status.SUCCESS
    assert io.event_labels() == []  # the host raises SUCCESS for the status (once: a real node's test counts them)
    kinds = [(m.kind, m.node) for m in io.published["progress"]]
    assert ("edge", "move") in kinds and ("finished", "done") in kinds


def test_task_module_refused_start_becomes_error_exit(tmp_path):
    f = tmp_path / "pick.yaml"
    f.write_text(TASK)
    mod = TaskModule("pick", TaskModule.Params(task_file=str(f)))
    io = FakeIO(module=mod)
    from contactflow.nodes.messages import ControlReply
    io.replies["move_to"] = ControlReply(ok=False, error="no such module", state=Status.ERROR)
    mod.setup(io)
    mod.start()
    assert mod.step() is Status.FAILURE
    assert io.event_labels() == [Event.ERROR]


def test_task_module_binds_plan_and_pools_modules_of_one_type(tmp_path):
    f = tmp_path / "watch.yaml"
    f.write_text("""
params: {force: null}
nodes:
  grasp:
    primitive: close_until_force
    params: {grasp_force: "${params.force}"}
    helpers:
      stable: {primitive: wait_event, params: {event: grasp_stable}}
      lost: {primitive: wait_event, params: {event: grasp_lost}}
  ok: {terminal: success}
  ko: {terminal: failure}
edges:
  - {from: grasp, to: ok, on: [success, stable.grasp_stable]}
  - {from: grasp, to: ko, on: lost.grasp_lost}
""")
    mod = TaskModule("t", TaskModule.Params(task_file=str(f), plan="{force: 7.5}"))
    io = FakeIO(module=mod)
    mod.setup(io)
    mod.start()
    runs = [(t, p) for t, c, p in io.commands if c is Command.SET]
    assert runs == [("wait_event", {"event": "grasp_stable"}), ("wait_event_2", {"event": "grasp_lost"}),
                    ("close_until_force", {"grasp_force": 7.5})]
    io.feed("events", EventMsg(event=Event.GRASP_LOST, module="r/n/wait_event_2"))
    assert mod.step() is Status.FAILURE
    stops = {t for t, c, _ in io.commands if c is Command.STOP}
    assert stops == {"wait_event", "wait_event_2", "close_until_force"}


def test_events_of_a_previous_activation_are_ignored(tmp_path):
    f = tmp_path / "loop.yaml"
    f.write_text("""
nodes:
  touch: {primitive: touch}
  ok: {terminal: success}
edges:
  - {from: touch, to: touch, on: contact}
  - {from: touch, to: ok, on: success}
""")
    mod = TaskModule("t", TaskModule.Params(task_file=str(f)))
    io = FakeIO(module=mod)
    mod.setup(io)
    io.t = 1.0
    mod.start()
    io.feed("events", EventMsg(event=Event.CONTACT, module="r/n/touch"))
    io.t = 2.0
    assert mod.step() is Status.RUNNING  # re-entered touch at t=2
    late = EventMsg(event=Event.SUCCESS, module="r/n/touch")
    late.hdr.t_sim = 1.5  # raised by the first activation, delivered late
    io.feed("events", late)
    assert mod.step() is Status.RUNNING
    fresh = EventMsg(event=Event.SUCCESS, module="r/n/touch")
    fresh.hdr.t_sim = 2.1
    io.feed("events", fresh)
    assert mod.step() is Status.SUCCESS


def test_task_module_refuses_a_task_naming_an_unregistered_primitive(tmp_path):
    import pytest

    from contactflow.nodes.taskgraph import TaskError

    f = tmp_path / "typo.yaml"
    f.write_text(TASK.replace("close_until_force", "close_untill_force"))
    mod = TaskModule("t", TaskModule.Params(task_file=str(f)))
    io = FakeIO(module=mod)
    mod.setup(io)
    with pytest.raises(TaskError, match=r"typo.yaml:4: node 'grasp': unknown primitive type 'close_untill_force'"):
        mod.start()
    assert io.commands == []  # nothing was commanded
