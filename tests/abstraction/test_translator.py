"""Translation ATD -> ESTD per robot: the three rules, factory choices, refusals, execution."""

from __future__ import annotations

import dataclasses

import pytest

from contactflow.abstraction.atd import load_atd, parse_atd
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.examples import path
from contactflow.abstraction.factory import EventChoice, factory_for
from contactflow.abstraction.profiles import PROFILES, Sensor
from contactflow.abstraction.translator import TranslationError, translate
from contactflow.embodiments.robots.tombatossals.factory import TombatossalsFactory
from contactflow.nodes.status import Event, Status
from contactflow.nodes.taskengine import ProgressKind, TaskEngine
from contactflow.nodes.taskfile import load_tasks
from contactflow.nodes.taskgraph import REQUIRED, NodeKind, Trigger
from contactflow.nodes.testing_tasks import FakeClock, FakeRunner, Step, run_until_done

EXAMPLES = ["fig7_2.xml", "fig7_2.yaml", "push_away.xml", "pick_place_behind.xml", "grasp_retry.xml"]
ROBOTS = sorted(PROFILES)
TOMBATOSSALS, MELFA, BAXTER = (PROFILES[r] for r in ("tombatossals", "melfa", "baxter"))


@pytest.mark.parametrize("robot", ROBOTS)
@pytest.mark.parametrize("example", EXAMPLES)
def test_examples_translate_on_every_robot_obeying_the_three_rules(example, robot):
    atd = load_atd(path(example))
    tr = translate(atd, factory_for(PROFILES[robot]))
    estd = tr.estd
    # rule 1: one node per state; rule 2: one edge per transition
    assert sorted(tr.states.values()) == sorted(s.name for s in atd.states)
    assert len(estd.nodes) == len(atd.states) and len(estd.edges) == len(atd.transitions)
    assert [e.label for e in estd.edges] == [t.name for t in atd.transitions]
    # rule 3: every abstract label maps to one or more concrete labels
    for t, e in zip(atd.transitions, estd.edges, strict=True):
        assert set(tr.labels[e.id]) == {ev.event for ev in t.events}
        assert all(len(g) >= 1 for groups in tr.labels[e.id].values() for g in groups)
    # only the robot's primitives; the ESTD survives its YAML form
    types = {n.type for n in estd.nodes.values() if n.kind is NodeKind.PRIMITIVE}
    types |= {h.type for n in estd.nodes.values() for h in n.helpers}
    assert types <= PROFILES[robot].capabilities
    again, main = load_tasks("estd.yaml", tr.to_yaml(), primitives=PROFILES[robot].capabilities)
    assert [(e.origin, e.dest, e.when) for e in again[main].edges] == \
        [(e.origin, e.dest, e.when) for e in estd.edges]


def test_factories_choose_their_own_primitives_and_parameters():
    atd = load_atd(path("pick_place_behind.xml"))
    tomb = translate(atd, factory_for(TOMBATOSSALS)).estd.nodes
    melfa = translate(atd, factory_for(MELFA)).estd.nodes
    baxter = translate(atd, factory_for(BAXTER)).estd.nodes
    # Table 7.3 / 7.4 mappings
    assert tomb["grasp_object"].type == "robust_grasp"
    # the corrections the hand's capabilities allow (a parallel gripper has no finger to lose), as the
    # robust grasp's own typed parameters: an ATD's grasp turns on every one its hand allows
    assert factory_for(MELFA).corrections() == factory_for(BAXTER).corrections() == (
        "alignment", "sliding", "force_adaptation")
    assert tomb["grasp_object"].params["finger_lost"] is True and tomb["grasp_object"].params["alignment"] is True
    assert tomb["approach"].type == "transport" and tomb["put_down"].type == "place"
    assert melfa["grasp_object"].type == "close_until_force"
    assert melfa["approach"].type == "move_to" and melfa["put_down"].type == "transport"
    assert [h.type for h in melfa["carry_behind"].helpers if h.name == "grip"] == ["hold"]
    # baxter's grippers have no pads to close until a force on: they close until the jaws stall
    assert baxter["grasp_object"].type == "close_until_stall" and baxter["put_down"].type == "place"
    # the noisy wrist wrench raises baxter's contact thresholds and lowers its filter
    assert baxter["put_down"].params["force_threshold"] > tomb["put_down"].params["force_threshold"]
    assert baxter["put_down"].params["filter_hz"] < tomb["put_down"].params["filter_hz"]
    # the place knows where the object goes down (the ATD's target, in the world): it slows down above it
    assert tomb["put_down"].params["goal"]["target"] == pytest.approx([0.55, 0.15, 0.81])
    assert baxter["preshape_hand"].params["abort_force"] > melfa["preshape_hand"].params["abort_force"]
    # grasp force from the object's mass (0.15 kg) on the grippers: per pad on melfa's, held while carrying
    assert 2.5 <= melfa["grasp_object"].params["grip_force"] <= 20.0
    grip = {h.name: h for h in melfa["carry_behind"].helpers}["grip"]
    assert grip.params == {"force": 2.0 * melfa["grasp_object"].params["grip_force"]}
    # hand shapes: mapped to the multi-finger hand's own preshapes, approximated on grippers
    assert tomb["preshape_hand"].params["preshape"] == "open"
    assert melfa["preshape_hand"].params["preshape"] == "open"
    assert tomb["grasp_object"].params["pregrasp_type"] == "open"


def test_baxter_needs_gripper_and_wrist_for_stable_grasp_of_a_heavy_object():
    text = path("pick_place_behind.xml").read_text().replace("<mass>0.15</mass>", "<mass>1.0</mass>")
    tr = translate(parse_atd(text, "heavy.xml"), factory_for(BAXTER))
    edge = next(e for e in tr.estd.edges if e.id == "grasp_object__lift_object")
    assert edge.when == (frozenset({Trigger(Event.SUCCESS)}),
                         frozenset({Trigger(Event.GRASP_STABLE, "grasp_stable_grip")}),
                         frozenset({Trigger(Event.GRASP_STABLE, "grasp_stable_load")}))
    lost = next(e for e in tr.estd.edges if e.id == "lift_object__failed")
    assert lost.when == (frozenset({Trigger(Event.GRASP_LOST, "grasp_lost_grip"),
                                    Trigger(Event.GRASP_LOST, "grasp_lost_load")}),)


SLIDE = """<statemachine name="wipe">
  <state name="go" type="move"><target>0.1 0.5 0.2</target></state>
  <state name="wipe" type="slide"><target>0.3 0.5 0.02</target></state>
  <state name="done" type="success"/>
  <transition origin="go" destination="wipe"><success/></transition>
  <transition origin="wipe" destination="done"><success/></transition>
</statemachine>"""


def test_refusals_name_the_robot_state_and_reason():
    atd = parse_atd(SLIDE, "wipe.xml")
    with pytest.raises(TranslationError) as info:
        translate(atd, factory_for(MELFA))
    assert info.value.robot == "melfa"
    assert "wipe.xml:3: state 'wipe' (slide): melfa cannot slide" in str(info.value)
    assert translate(atd, factory_for(TOMBATOSSALS)).estd.nodes["wipe"].type == "slide"

    far = SLIDE.replace("0.1 0.5 0.2", "3.0 0.5 0.2")
    with pytest.raises(TranslationError, match=r"wipe.xml:2: state 'go' .*out of tombatossals's reach"):
        translate(parse_atd(far, "wipe.xml"), factory_for(TOMBATOSSALS))

    heavy = path("grasp_retry.xml").read_text().replace("<mass>0.25</mass>", "<mass>2.5</mass>")
    for robot, ok in (("tombatossals", False), ("melfa", True), ("baxter", False)):
        if ok:
            translate(parse_atd(heavy, "heavy.xml"), factory_for(PROFILES[robot]))
        else:
            with pytest.raises(TranslationError, match="exceeds .* payload"):
                translate(parse_atd(heavy, "heavy.xml"), factory_for(PROFILES[robot]))

    wide = path("grasp_retry.xml").read_text().replace("0.05 0.05 0.12", "0.09 0.09 0.12")
    with pytest.raises(TranslationError, match="melfa's hand opens to 0.080 m"):
        translate(parse_atd(wide, "wide.xml"), factory_for(MELFA))


def test_missing_sensors_fall_back_or_refuse_grasp_events():
    blind = dataclasses.replace(TOMBATOSSALS, sensors=TOMBATOSSALS.sensors - {Sensor.TACTILE})
    with pytest.raises(TranslationError) as info:
        translate(load_atd(path("fig7_2.xml")), factory_for(blind))
    msg = str(info.value)
    assert "event grasp_stable: tombatossals cannot detect grasp_stable" in msg
    push = translate(load_atd(path("push_away.xml")), factory_for(blind))  # no grasp involved
    assert push.estd.nodes["push_object"].type == "transport"
    no_ft = dataclasses.replace(TOMBATOSSALS, sensors=TOMBATOSSALS.sensors - {Sensor.WRIST_FT})
    tr = translate(load_atd(path("fig7_2.xml")), factory_for(no_ft))
    assert tr.estd.nodes["grasp_object"].type == "naive_grasp"


def test_translator_enforces_rule_three_against_a_broken_factory():
    class Broken(TombatossalsFactory):
        def event(self, ev, state, node, atd):
            if ev.event is AbstractEvent.GRASP_LOST:
                return EventChoice(())
            return super().event(ev, state, node, atd)

    with pytest.raises(TranslationError, match="mapped grasp_lost to no concrete label"):
        translate(load_atd(path("fig7_2.xml")), Broken(TOMBATOSSALS))


def _world(runner: FakeRunner, lose_first_lift: bool = False) -> None:
    """Every primitive succeeds; watchers report what the fake world does."""
    lifts = {"n": 0}

    def rule(instance, type_, params):
        if type_ == "wait_event":
            if params["event"] == "grasp_stable":
                return [Step(0.05, Event.GRASP_STABLE)]
            if params["event"] == "grasp_lost" and "lift_object" in instance:
                lifts["n"] += 1
                if lose_first_lift and lifts["n"] == 1:
                    return [Step(0.1, Event.GRASP_LOST)]
            return []
        if type_ == "hold":
            return []
        return [Step(0.2, Event.SUCCESS)]

    runner.rule(rule)


@pytest.mark.parametrize("robot", ROBOTS)
def test_fig7_2_estd_runs_and_reports_in_atd_names(robot):
    atd = load_atd(path("fig7_2.xml"))
    tr = translate(atd, factory_for(PROFILES[robot]))
    assert tr.estd.params["object_location"] is REQUIRED  # Fig. 7.2 leaves the object out
    clock = FakeClock()
    runner = FakeRunner(clock)
    _world(runner)
    reports = []
    eng = TaskEngine(runner, clock, on_progress=lambda p: reports.append(tr.abstract(p)))
    run = eng.launch(tr.estd, {"object_location": [0.2, 0.6, 0.1]})
    res = run_until_done(eng, clock, run)
    assert res.status is Status.SUCCESS and res.label == "success_end"
    entered = [r.state for r in reports if r.kind is ProgressKind.ENTERED]
    assert entered == ["approach", "preshape_hand", "grasp_object", "lift_object", "success_end"]
    edges = [(r.transition, r.event) for r in reports if r.kind is ProgressKind.EDGE]
    assert [t for t, _ in edges] == [t.name for t in atd.transitions if t.destination != "fail_end"]
    assert edges[2][1] in (AbstractEvent.SUCCESS, AbstractEvent.GRASP_STABLE)
    first_move = runner.starts[0]
    assert first_move[2]["goal"]["target"] == [0.2, 0.6, 0.1] and first_move[2]["goal"]["standoff"] == 0.1
    assert runner.active == {}


@pytest.mark.parametrize("robot", ROBOTS)
def test_cyclic_atd_retries_after_grasp_lost(robot):
    atd = load_atd(path("grasp_retry.xml"))
    tr = translate(atd, factory_for(PROFILES[robot]))
    clock = FakeClock()
    runner = FakeRunner(clock)
    _world(runner, lose_first_lift=True)
    reports = []
    eng = TaskEngine(runner, clock, on_progress=lambda p: reports.append(tr.abstract(p)))
    res = run_until_done(eng, clock, eng.launch(tr.estd))
    assert res.status is Status.SUCCESS and res.label == "lifted"
    entered = [r.state for r in reports if r.kind is ProgressKind.ENTERED]
    assert entered.count("approach") == 2 and entered.count("reopen") == 1
    retry = [r for r in reports if r.kind is ProgressKind.EDGE and r.transition == "retry"]
    assert len(retry) == 1 and retry[0].event is AbstractEvent.GRASP_LOST


def test_a_place_onto_another_object_is_not_told_that_object_s_location_as_its_rest():
    text = """
statemachine:
  name: stack
  objects:
    cup: {location: [0.1, 0.5, 0.06], size: [0.06, 0.06, 0.1]}
    box: {location: [0.0, 0.6, 0.03], size: [0.1, 0.1, 0.06]}
  states:
    - {name: take, type: grasp, object: cup}
    - {name: put, type: place, target: {object: box}}
    - {name: done, type: success}
  transitions:
    - {origin: take, destination: put, events: [success]}
    - {origin: put, destination: done, events: [success]}
"""
    nodes = translate(parse_atd(text, "stack.yaml"), factory_for(TOMBATOSSALS)).estd.nodes
    assert nodes["put"].type == "place" and "target" not in nodes["put"].params.get("goal", {})


CORRECTED = """<statemachine name="corrected" start="grasp_object">
  <object name="can"><location>0.0 0.6 0.06</location><mass>0.15</mass><size>0.05 0.05 0.12</size></object>
  <state name="grasp_object" type="grasp"/>
  <state name="set_back" type="place"><target>0.0 0.6 0.06</target></state>
  <state name="reopen" type="release"/>
  <state name="lift_object" type="transport"><path><position>0.0 0.6 0.25</position></path></state>
  <state name="lifted" type="success"/>
  <state name="failed" type="failure"/>
  <transition origin="grasp_object" destination="lift_object"><success/></transition>
  <transition origin="grasp_object" destination="failed"><error/></transition>
  <transition origin="grasp_object" destination="set_back"><prediction_mismatch/></transition>
  <transition origin="set_back" destination="reopen"><success/></transition>
  <transition origin="reopen" destination="grasp_object"><success/></transition>
  <transition origin="lift_object" destination="lifted"><success/></transition>
</statemachine>"""


@pytest.mark.parametrize("robot", ROBOTS)
def test_a_prediction_mismatch_transition_watches_the_robot_s_predictor_and_takes_the_correction(robot):
    """§5.7: every factory maps prediction_mismatch to a watch_prediction helper of its state; the first grasp's
    surprise takes the correction (set back, reopen, grasp again), reported in the ATD's terms."""
    tr = translate(parse_atd(CORRECTED, "corrected.xml"), factory_for(PROFILES[robot]))
    helpers = {h.name: h for h in tr.estd.nodes["grasp_object"].helpers}
    assert helpers["prediction_mismatch"].type == "watch_prediction"
    clock = FakeClock()
    runner = FakeRunner(clock)
    grasps = {"n": 0}

    def rule(instance, type_, params):
        if type_ == "watch_prediction":
            grasps["n"] += 1
            return [Step(0.1, Event.PREDICTION_MISMATCH)] if grasps["n"] == 1 else []
        if type_ in ("wait_event", "hold"):
            return []
        return [Step(0.2 if "grasp_object" not in instance else 0.3, Event.SUCCESS)]

    runner.rule(rule)
    reports = []
    eng = TaskEngine(runner, clock, on_progress=lambda p: reports.append(tr.abstract(p)))
    res = run_until_done(eng, clock, eng.launch(tr.estd))
    assert res.status is Status.SUCCESS and res.label == "lifted", reports
    edges = [(r.transition, r.event) for r in reports if r.kind is ProgressKind.EDGE]
    assert edges[0] == ("grasp_object->set_back", AbstractEvent.PREDICTION_MISMATCH), edges
    assert [t for t, _ in edges[1:]] == ["set_back->reopen", "reopen->grasp_object", "grasp_object->lift_object",
                                        "lift_object->lifted"]


def test_timeout_transition_of_the_atd_fires():
    atd = load_atd(path("grasp_retry.xml"))
    tr = translate(atd, factory_for(MELFA))
    assert tr.estd.nodes["grasp_object"].timeout == 15.0
    clock = FakeClock()
    runner = FakeRunner(clock)
    runner.script("move_to", [Step(0.2, Event.SUCCESS)])  # the grasp never closes
    reports = []
    eng = TaskEngine(runner, clock, on_progress=lambda p: reports.append(tr.abstract(p)))
    res = run_until_done(eng, clock, eng.launch(tr.estd))
    assert res.label == "failed" and res.status is Status.FAILURE and 15.2 <= res.t < 15.4
    last = [r for r in reports if r.kind is ProgressKind.EDGE][-1]
    assert last.transition == "grasp_object->failed" and last.event is AbstractEvent.TIMEOUT


def test_hardware_failure_is_reported_as_an_abstract_fault_exit():
    atd = load_atd(path("fig7_2.xml"))
    tr = translate(atd, factory_for(BAXTER))
    clock = FakeClock()
    runner = FakeRunner(clock)
    runner.script("move_to", [Step(0.3, Event.HARDWARE_FAILURE)])
    reports = []
    eng = TaskEngine(runner, clock, on_progress=lambda p: reports.append(tr.abstract(p)))
    res = run_until_done(eng, clock, eng.launch(tr.estd, {"object_location": [0.2, 0.6, 0.1]}))
    assert res.event is Event.HARDWARE_FAILURE and res.label == "fail_end"
    fault = [r for r in reports if r.kind is ProgressKind.EDGE]
    assert [(r.transition, r.event, r.implicit) for r in fault] == [
        ("approach!hardware_failure", AbstractEvent.HARDWARE_FAILURE, True)]


def test_atd_names_with_spaces_keep_their_names_in_progress():
    text = path("fig7_2.xml").read_text().replace("preshape_hand", "preshape hand")
    tr = translate(parse_atd(text, "spaces.xml"), factory_for(MELFA))
    assert "preshape_hand" in tr.estd.nodes and tr.states["preshape_hand"] == "preshape hand"
    clock = FakeClock()
    runner = FakeRunner(clock)
    _world(runner)
    seen = []
    eng = TaskEngine(runner, clock, on_progress=lambda p: seen.append(tr.abstract(p)))
    run_until_done(eng, clock, eng.launch(tr.estd, {"object_location": [0.2, 0.6, 0.1]}))
    assert "preshape hand" in [r.state for r in seen if r.kind is ProgressKind.ENTERED]
    assert "approach->preshape hand" in [r.transition for r in seen if r.kind is ProgressKind.EDGE]


def test_the_factory_hands_typed_params_and_a_bad_one_is_an_error_naming_the_state():
    """Nothing is dropped on the way: per-robot detectors reach the primitive as its own fields (Tables 7.3-7.4)."""
    from contactflow.abstraction.factory import MappingRefused

    atd = load_atd(path("pick_place_behind.xml"))
    melfa = translate(atd, factory_for(MELFA)).estd.nodes
    watch = {h.name: h for h in melfa["lift_object"].helpers}["grasp_stable"]
    assert watch.params == {"event": "grasp_stable", "finish": False, "sensor": "tactile",
                            "threshold": melfa["grasp_object"].params["grip_force"]}
    tomb = translate(atd, factory_for(TOMBATOSSALS)).estd.nodes
    watch = {h.name: h for h in tomb["lift_object"].helpers}["grasp_stable"]
    assert watch.params["min_contacts"] == 2 and watch.params["sensor"] == "hand"
    baxter = translate(atd, factory_for(BAXTER)).estd.nodes
    assert {h.params["sensor"] for h in baxter["lift_object"].helpers} == {"gripper_effort"}
    # the robot's overrides are part of the typed Params the ESTD carries
    assert tomb["grasp_object"].params["torque_threshold"] == 0.1
    # the ATD's hand position (6 cm, Table 7.3) opens a gripper that far, as a fraction of its opening;
    # a multi-finger hand's joints give no aperture in metres: it opens fully
    assert melfa["let_go"].params == {"hand_target": 0.75}  # 6 of the gripper's 8 cm
    assert tomb["let_go"].params == {}

    class Misspelt(TombatossalsFactory):
        def grasp(self, kind, concrete, state, atd, notes):
            p, goal, helpers = super().grasp(kind, concrete, state, atd, notes)
            return {**p, "pregrasp_sise": 0.5}, goal, helpers

    class Mistyped(TombatossalsFactory):
        def release(self, kind, concrete, state, atd, notes):
            return {"hand_target": "wide"}, None, []

    with pytest.raises(TranslationError, match=r"state 'grasp_object' \(grasp\): robust_grasp\.params\."
                                                r"pregrasp_sise: unknown parameter"):
        translate(atd, Misspelt(TOMBATOSSALS))
    with pytest.raises(TranslationError, match=r"state 'let_go' \(release\): release\.params\.hand_target"):
        translate(atd, Mistyped(TOMBATOSSALS))
    with pytest.raises(MappingRefused, match=r"wait_event\.params\.sensr: unknown parameter"):
        factory_for(TOMBATOSSALS).helper("w", "wait_event", "state 'x'", sensr="tactile")


def test_a_received_estd_with_a_bad_primitive_param_is_refused_naming_node_and_field():
    from contactflow.abstraction.estd import EstdError, estd_message, received

    tr = translate(load_atd(path("pick_place_behind.xml")), factory_for(MELFA))
    msg = estd_message(tr)
    assert received(msg, MELFA, "run").estd.nodes["grasp_object"].params["grip_force"] > 0
    bad = msg.task.replace("grip_force:", "grip_forse:")
    with pytest.raises(EstdError, match=r"state 'grasp_object': close_until_force\.params\.grip_forse"):
        received(type(msg)(**{**{f: getattr(msg, f) for f in msg.__struct_fields__}, "task": bad}), MELFA, "run")
    bad = msg.task.replace("threshold: 2.5", "threshold: lots", 1)
    with pytest.raises(EstdError, match=r"helper 'grasp_stable': wait_event\.params\.threshold"):
        received(type(msg)(**{**{f: getattr(msg, f) for f in msg.__struct_fields__}, "task": bad}), MELFA, "run")


def test_an_object_to_detect_is_a_parameter_its_robot_binds_and_only_a_robot_with_vision_takes_it():
    from contactflow.abstraction.atd import DETECT
    from contactflow.abstraction.execution import EngineExecutor

    atd = load_atd(path("pick_detected.xml"))
    assert atd.objects["can"].detect and atd.objects["can"].location is None
    yaml_form = parse_atd("statemachine:\n  name: p\n  objects:\n    can: {location: detect}\n  states:\n"
                          "    - {name: g, type: grasp}\n    - {name: ok, type: success}\n  transitions:\n"
                          "    - {origin: g, destination: ok, events: [success]}\n", "p.yaml")
    assert yaml_form.objects["can"].detect
    tr = translate(atd, factory_for(TOMBATOSSALS))
    assert tr.estd.params["can_location"] == DETECT
    for robot in (MELFA, BAXTER):  # no camera: the broker does not send it there
        with pytest.raises(TranslationError, match=f"object 'can' is to be detected and {robot.name} cannot find it"):
            translate(atd, factory_for(robot))
    # an executor without the runtime's vision refuses it rather than run towards a word
    with pytest.raises(ValueError, match="can_location: the ATD asks to detect it"):
        EngineExecutor(lambda clock: (None, None))(tr, lambda p: None, None)
