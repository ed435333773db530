"""ATD parsing: Fig. 7.2 as written, the YAML form, and refusals with file, line and element."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from contactflow.abstraction.atd import AtdError, load_atd, parse_atd
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.examples import path
from contactflow.abstraction.primitives import AbstractPrimitive, Movement, Terminal

FIG = path("fig7_2.xml").read_text()


def refused(text: str, *fragments: str, file: str = "bad.xml") -> str:
    with pytest.raises(AtdError) as info:
        parse_atd(text, file)
    msg = str(info.value)
    for f in fragments:
        assert f in msg, msg
    return msg


def test_fig7_2_parses_as_written():
    atd = load_atd(path("fig7_2.xml"))
    assert [s.name for s in atd.states] == ["approach", "preshape_hand", "grasp_object",
                                            "lift_object", "success_end", "fail_end"]
    assert atd.start == "approach"
    types = [s.type for s in atd.states]
    assert types == [AbstractPrimitive.MOVE, AbstractPrimitive.MOVE, AbstractPrimitive.GRASP,
                     AbstractPrimitive.TRANSPORT, Terminal.SUCCESS, Terminal.FAILURE]
    approach, preshape, grasp, lift = atd.states[:4]
    assert approach.movement is Movement.FREE and approach.hand_shape == "open"
    assert preshape.movement is Movement.GUARDED and preshape.hand_shape == "pinch_grasp_preshape"
    assert grasp.hand_shape == "pinch_grasp"
    assert lift.path == ((0.2, 0.6, 0.25),) and lift.goal == (0.2, 0.6, 0.25)
    assert lift.where.line == 14
    events = [[e.event for e in t.events] for t in atd.transitions]
    assert events == [[AbstractEvent.SUCCESS], [AbstractEvent.SUCCESS],
                      [AbstractEvent.SUCCESS, AbstractEvent.GRASP_STABLE],
                      [AbstractEvent.GRASP_LOST],
                      [AbstractEvent.SUCCESS, AbstractEvent.GRASP_STABLE]]
    assert atd.transitions[3].destination == "fail_end"


def test_yaml_form_equals_xml_form():
    x, y = load_atd(path("fig7_2.xml")), load_atd(path("fig7_2.yaml"))

    def strip(atd):
        return ([(s.name, s.type, s.movement, s.hand_shape, s.path) for s in atd.states],
                [(t.origin, t.destination, tuple(e.event for e in t.events)) for t in atd.transitions])

    assert strip(x) == strip(y)


def test_experiment_atds_carry_objects_and_obstacles():
    push = load_atd(path("push_away.xml"))
    box = push.objects["obstacle_box"]
    assert box.mass == 0.2 and box.approach == (1.0, 0.0, 0.0) and box.location == (0.0, 0.5, 0.03)
    assert [o.name for o in push.obstacles] == ["table"]
    pp = load_atd(path("pick_place_behind.xml"))
    assert len(pp.states) == 9 and pp.state("carry_behind").path[-1] == (-0.15, 0.55, 0.2)
    retry = load_atd(path("grasp_retry.xml"))
    assert any(t.name == "retry" and t.destination == "reopen" for t in retry.transitions)
    assert retry.transitions[-1].events[0].after == 15.0


def test_dangling_transition():
    bad = FIG.replace('destination="fail_end"', 'destination="fail_ending"')
    refused(bad, "bad.xml:39:", "<transition origin='lift_object' destination='fail_ending'>",
            "dangling destination: no state named 'fail_ending'")


def test_unknown_primitive_and_event():
    refused(FIG.replace('type="grasp"', 'type="teleport"'), "bad.xml:10:",
            "<state name='grasp_object'>", "unknown abstract primitive 'teleport'")
    refused(FIG.replace("<grasp_lost/>", "<grasp_slipped/>"), "bad.xml:41:",
            "unknown abstract event 'grasp_slipped'")
    refused(FIG.replace("<hand_shape>open</hand_shape>", "<colour>red</colour>"), "bad.xml:4:",
            "<colour>: property of <state name='approach'> is not accepted by a move state")


def test_no_terminal_unreachable_and_dead_end():
    bad = FIG.replace('type="success"', 'type="move"').replace('type="failure"', 'type="move"')
    msg = refused(bad, "no terminal state")
    assert "dead end" in msg
    refused(FIG.replace("</statemachine>", '<state name="island" type="move"/>\n'
                        '<transition origin="island" destination="fail_end"><error/></transition>\n'
                        "</statemachine>"),
            "<state name='island'>: unreachable from the start state 'approach'")


def test_malformed_values_and_missing_target():
    refused(FIG.replace("0.2 0.6 0.25", "0.2 0.6"), "bad.xml:14:", "path position 1 must be 3 numbers")
    refused(FIG.replace("<movement>free</movement>", "<movement>wild</movement>"),
            "movement 'wild' is not one of free, guarded, constrained")
    no_path = FIG.replace("<path>\n      <position>0.2 0.6 0.25</position>\n    </path>\n", "")
    refused(no_path, "a transport state needs a <target> or a <path>")


def test_truncated_xml():
    refused(FIG[: len(FIG) // 2], "bad.xml:", "not well-formed XML")


def test_billion_laughs_refused():
    bomb = """<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
]>
<statemachine><state name="a" type="move"><hand_shape>&lol4;</hand_shape></state></statemachine>"""
    refused(bomb, "bad.xml: refused", "DTD")


def test_external_entity_refused():
    xxe = """<?xml version="1.0"?>
<!DOCTYPE statemachine [<!ENTITY secret SYSTEM "file:///etc/passwd">]>
<statemachine><state name="a" type="move"><hand_shape>&secret;</hand_shape></state>
<state name="b" type="success"/><transition origin="a" destination="b"><success/></transition>
</statemachine>"""
    msg = refused(xxe, "refused")
    assert "root:" not in msg


def test_yaml_errors_have_lines():
    text = path("fig7_2.yaml").read_text()
    refused(text.replace("events: [grasp_lost]", "events: [grasp_gone]"), "bad.yaml:19:",
            "unknown abstract event 'grasp_gone'", file="bad.yaml")
    refused(text.replace("type: grasp,", "type: squeeze,"), "bad.yaml:7:",
            "unknown abstract primitive 'squeeze'", file="bad.yaml")


def test_yaml_form_with_objects_obstacles_and_timeouts():
    text = """
statemachine:
  name: fetch
  objects:
    cup: {location: [0.1, 0.5, 0.06], mass: 0.2, approach: [0, 0, -2], size: [0.06, 0.06, 0.1]}
  environment:
    obstacles:
      wall: {position: [0.3, 0.6, 0.1], size: [0.02, 0.4, 0.2]}
  states:
    - {name: reach, type: move, movement: free}
    - {name: take, type: grasp}
    - {name: bring, type: transport, target: {object: cup}}
    - {name: done, type: success}
    - {name: lost, type: failure}
  transitions:
    - {origin: reach, destination: take, events: [success]}
    - {origin: take, destination: bring, events: [success, grasp_stable]}
    - {origin: take, destination: lost, timeout: 12}
    - {origin: bring, destination: done, events: success}
"""
    atd = parse_atd(text, "fetch.yaml")
    cup = atd.objects["cup"]
    assert cup.approach == (0.0, 0.0, -1.0), "the approach direction is normalised"
    assert atd.obstacles[0].size == (0.02, 0.4, 0.2)
    assert atd.state("bring").target_object == "cup"
    assert atd.transitions[2].events[0].event is AbstractEvent.TIMEOUT
    assert atd.transitions[2].events[0].after == 12.0
    refused(text.replace("[0, 0, -2]", "[0, 0, 0]"), "fetch.yaml:5:", "approach must be a non-zero direction",
            file="fetch.yaml")
    refused(text.replace("{object: cup}", "{object: mug}"), "fetch.yaml:12:", "unknown object 'mug'",
            file="fetch.yaml")


def test_a_file_that_never_ends_is_read_to_the_limit_and_refused(tmp_path):
    import contextlib
    import os
    import threading

    from contactflow.abstraction.atd import MAX_ATD_BYTES

    fifo = tmp_path / "endless.xml"
    os.mkfifo(fifo)  # reports size 0, as a device does

    def feed() -> None:
        # writes until the reader stops at the limit and closes its end
        with contextlib.suppress(BrokenPipeError), open(fifo, "wb") as f:
            while True:
                f.write(b"<" * 65536)

    writer = threading.Thread(target=feed, daemon=True)
    writer.start()
    with pytest.raises(AtdError, match=f"exceeds the {MAX_ATD_BYTES}-byte limit"):
        load_atd(fifo)
    writer.join(10)
    assert not writer.is_alive()


def test_a_yaml_atd_whose_aliases_expand_past_the_limit_is_refused_quickly():
    import time

    # nine levels of ten aliases each, inside a field the ATD has (an obstacle's properties)
    levels = ["&a0 [x, x, x, x, x, x, x, x, x, x]"]
    levels += [f"&a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    text = ("statemachine:\n  name: bomb\n  start: s\n  environment:\n    obstacles:\n      o: ["
            + ", ".join(levels) + "]\n")
    assert len(text) < 1500  # 10^9 nodes once expanded
    t0 = time.perf_counter()
    with pytest.raises(AtdError, match="expands to more than 100000 YAML nodes"):
        parse_atd(text, "bomb.yaml")
    assert time.perf_counter() - t0 < 5.0


def _mangled(text: str) -> st.SearchStrategy[bytes]:
    """``text`` cut short, with a stretch replaced by arbitrary bytes."""
    raw = text.encode()
    return st.tuples(st.integers(0, len(raw)), st.integers(0, len(raw)), st.binary(max_size=40)).map(
        lambda c: (raw[:min(c[0], c[1])] + c[2] + raw[max(c[0], c[1]):])[: max(c[0], c[1]) + len(c[2])])


@settings(max_examples=400, deadline=None)
@given(st.one_of(st.binary(max_size=200), st.text(max_size=200), _mangled(FIG),
                 _mangled(path("fig7_2.yaml").read_text())))
def test_any_input_is_an_atd_or_an_atd_error(data):
    # a broker answers every dispatch: whatever arrives parses or is refused with AtdError, never anything else
    try:
        parse_atd(data, "fuzz.xml")
    except AtdError as exc:
        assert str(exc).startswith("fuzz.xml")
