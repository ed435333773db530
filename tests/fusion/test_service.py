"""The ContactFusion service and a generator shell on FakeIO."""

import numpy as np

from contactflow.fusion.generators.tactile import TactileGenerator, TactileParams
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.messages import ContactEventMsg, ContactList, HypothesisCloud
from contactflow.fusion.service import ContactFusion, FusionParams
from contactflow.fusion.testing import one_pad_hand
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.status import Event
from contactflow.nodes.testing import FakeIO

A = np.array([[0.50, 0.30, 0.80]])
B = np.array([[0.50, -0.30, 0.80]])


def start(module, io):
    io.module = module
    module.setup(io)
    module.start()


def test_keys_of_the_fusion_service():
    ks = KeySpace("lab")
    p = FusionParams(robot="site", sources="*/*")
    assert ContactFusion.default_input_keys(ks, "site", "fusion", p) == {"hypotheses": "cf/lab/contacts/*/*"}
    # with an object map, the claims of every robot on any map: the fusion counts those on its own
    mapping = FusionParams(robot="site", sources="*/*", map_region=(0.0, 0.0, 0.0, 1.0, 1.0, 1.0))
    assert ContactFusion.default_input_keys(ks, "site", "fusion", mapping) == {
        "hypotheses": "cf/lab/contacts/*/*", "claims": "cf/lab/contacts/fused/*/claims"}
    assert ContactFusion.default_output_keys(ks, "site", "fusion", p)["events"] == "cf/lab/contacts/fused/site/events"
    assert ContactFusion.default_output_keys(ks, "site", "fusion", p)["objects"] == "cf/lab/contacts/fused/site/objects"


def test_two_robots_fused_by_one_integrator():
    fusion = ContactFusion("fusion", FusionParams(hold=0.05))
    io = FakeIO()
    start(fusion, io)
    io.feed("hypotheses", HypothesisCloud.of(Hypotheses.make(A, 0.9, stamp=0.0), "r1", "tactile", "thumb"))
    io.feed("hypotheses", HypothesisCloud.of(Hypotheses.make(B, 0.8, stamp=0.0), "r2", "ft", "hand"))
    fusion.step()
    (contacts,) = io.published["contacts"]
    assert isinstance(contacts, ContactList)
    assert sorted((c.robot, c.link) for c in contacts.contacts) == [("r1", "thumb"), ("r2", "hand")]
    made = io.published["events"]
    assert all(isinstance(e, ContactEventMsg) and e.event == Event.CONTACT_MADE for e in made) and len(made) == 2
    assert io.event_labels() == [Event.CONTACT_MADE, Event.CONTACT_MADE]
    # r2's generator keeps talking without a contact; r1 goes silent: its contact breaks.
    for k in range(1, 20):
        io.t = 0.05 * k
        io.feed("hypotheses", HypothesisCloud.of(Hypotheses.empty(io.t), "r2", "ft"))
        fusion.step()
    broken = [e for e in io.published["events"] if e.event == Event.CONTACT_BROKEN]
    assert sorted(e.robot for e in broken) == ["r1", "r2"]


def test_a_fusion_of_some_generators_fuses_only_theirs_and_never_waits_for_the_others():
    import pytest

    fusion = ContactFusion("fusion", FusionParams(sources="r1/*", generators=("tactile", "range")))
    io = FakeIO()
    start(fusion, io)
    for gen, at in (("tactile", A), ("range", A + [0.0, 0.0, 0.01]), ("simulator", B)):
        io.feed("hypotheses", HypothesisCloud.of(Hypotheses.make(at, 0.9, stamp=0.0), "r1", gen))
    fusion.step()
    assert sorted(fusion.integrator.sources) == ["r1/range", "r1/tactile"]  # the simulator's is not one of them
    (contacts,) = io.published["contacts"]
    assert len(contacts.contacts) == 1 and np.linalg.norm(np.asarray(contacts.contacts[0].location) - A[0]) < 0.02
    with pytest.raises(ValueError, match="give them with sources '<robot>/.'"):
        FusionParams(sources="r1/tactile", generators=("tactile",)).validate()


def test_silent_sources_are_unplugged_and_bad_clouds_rejected():
    fusion = ContactFusion("fusion", FusionParams(drop_after=1.0))
    io = FakeIO()
    start(fusion, io)
    io.feed("hypotheses", HypothesisCloud.of(Hypotheses.make(A, 0.9), "r1", "tactile"))
    fusion.step()
    assert "r1/tactile" in fusion.integrator.sources
    bad = HypothesisCloud.of(Hypotheses.make(A, 0.9), "r1", "ft")
    bad.frame = "hand"
    io.t = 2.0
    io.feed("hypotheses", bad)
    fusion.step()
    assert fusion.rejected == 1 and fusion.integrator.sources == {}
    assert any("world frame" in line for line in io.logs)


def test_tactile_shell_publishes_cloud():
    gen = TactileGenerator("tactile", TactileParams(robot="r1"))
    io = FakeIO()
    start(gen, io)
    tactile, poses = one_pad_hand([[0.5, 0, 0.8], [0.52, 0, 0.8]], [0.0, 2.0])
    io.feed("taxels", poses)
    io.feed("tactile", tactile)
    gen.step()
    (msg,) = io.published["hypotheses"]
    assert (msg.robot, msg.generator) == ("r1", "tactile")
    h = msg.hypotheses()
    assert len(h) == 1 and h.likelihood[0] == 1.0


def test_contacts_and_events_say_where_on_the_hand_they_lie_by_the_robots_posed_model():
    from contactflow.embodiments.messages import RobotModel
    from contactflow.nodes.wire import NDArray

    def model(regions: list[str], robot: str = "r1") -> RobotModel:
        # a palm sphere at A and a fingertip capsule 6-10 cm along +x from it
        c1 = np.array([A[0], A[0] + [0.06, 0.0, 0.0]])
        c2 = np.array([A[0], A[0] + [0.10, 0.0, 0.0]])
        return RobotModel(robot=robot, t=0.0, links=["palm_link", "tip"], c1=NDArray.of(c1), r1=NDArray.of(np.array([0.04, 0.01])),
                          c2=NDArray.of(c2), r2=NDArray.of(np.array([0.04, 0.01])), regions=regions)

    fusion = ContactFusion("fusion", FusionParams(sources="r1/*", hold=0.05))
    io = FakeIO()
    start(fusion, io)
    on_tip, under = A[0] + [0.08, 0.0, 0.012], A[0] + [0.08, 0.0, -0.08]
    io.feed("robot_model", model(["palm", "finger"]))
    io.feed("hypotheses", HypothesisCloud.of(Hypotheses.make(np.array([on_tip, under]), 0.9, stamp=0.0), "r1", "tactile", "hand"))
    fusion.step()
    (contacts,) = io.published["contacts"]
    told = sorted((c.region, c.part, c.link) for c in contacts.contacts)
    assert told == [("finger", "tip", "hand"), ("held_object", "tip", "hand")]
    assert sorted((e.region, e.part) for e in io.published["events"]) == [("finger", "tip"), ("held_object", "tip")]
    assert any("finger (tip)" in e.detail for e in io.events)
    # a model that does not match its links, one of another robot, or one naming no hand parts tells nothing (the
    # first is logged)
    for bad in (model(["palm"]), model(["palm", "finger"], robot="r2"), model([])):
        io.published.clear()
        io.t += 0.05
        io.feed("robot_model", bad)
        io.feed("hypotheses", HypothesisCloud.of(Hypotheses.make(np.array([on_tip]), 0.9, stamp=io.t), "r1", "tactile", "hand"))
        fusion.step()
        told = {(c.region, c.part) for c in io.published["contacts"][-1].contacts}
        assert told == {("", "")}
    assert sum("no contact regions: fusion: input 'robot_model' (r1): 1 regions for 2 links" in m for m in io.logs) == 1
