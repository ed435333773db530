"""Hostile payloads: reproducible, of every kind, and never anything but a clean refusal or a valid message."""

import random

import msgpack
import numpy as np
import pytest

from contactflow.abstraction.messages import DispatchRequest
from contactflow.deploy.fuzz import mutate, payloads
from contactflow.embodiments.messages import ArmCommand, ArmCommandKind
from contactflow.nodes.messages import Clock, ControlRequest, EventMsg
from contactflow.nodes.status import Event
from contactflow.nodes.wire import NDArray, WireError, decode, encode, stamp

TEMPLATES = [
    stamp(Clock(t=1.5, tick=300), "site/w/world/clock", 3, 1.5),
    stamp(EventMsg(event=Event.SUCCESS, module="r/n/m", values={"x": 1.0}), "r/n/m", 4, 2.0),
    stamp(ArmCommand(robot="r", arm="right", kind=ArmCommandKind.TARGET, seq=2, values=NDArray.of(np.zeros((2, 7)))),
          "r/n/move_to/cmd", 9, 3.0),
    ControlRequest(cmd="stop", params={"gain": 0.5}),
    DispatchRequest(task_id="t1", atd="<atd/>", target="all"),
]


def test_payloads_repeat_with_the_seed_and_cover_every_kind():
    t = encode(TEMPLATES[0])
    a = list(payloads(random.Random(3), t, 30))
    assert a == list(payloads(random.Random(3), t, 30))
    assert {k for k, _ in a} == {"bytes", "msgpack", "mutated"}
    assert {k for k, _ in payloads(random.Random(3), None, 30)} == {"bytes", "msgpack"}


def test_a_mutation_changes_one_value_of_the_template():
    t = encode(TEMPLATES[0])
    rng = random.Random(5)
    changed = 0
    for _ in range(50):
        m = mutate(t, rng)
        if m == t[: len(m)] and len(m) < len(t):
            continue  # cut short
        before, after = msgpack.unpackb(t), msgpack.unpackb(m, strict_map_key=False)
        assert set(after) == set(before)  # the same fields, one of them hostile
        changed += after != before
    assert changed > 30


@pytest.mark.parametrize("template", TEMPLATES, ids=lambda m: type(m).__name__)
def test_every_hostile_payload_decodes_or_is_refused_cleanly(template):
    t = encode(template)
    kinds = {"valid": 0, "refused": 0}
    for _, p in payloads(random.Random(11), t, 600):
        try:
            decode(p, type(template), "cf/fuzz/key")
        except WireError as exc:
            assert str(exc).startswith("cf/fuzz/key: ")  # the place is named
            kinds["refused"] += 1
        else:
            kinds["valid"] += 1
    assert kinds["refused"] > 300
