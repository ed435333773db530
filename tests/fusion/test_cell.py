"""A cell's contact map: every robot of the cell in one fusion, foreign, skewed and flooding clouds refused."""

import numpy as np
import pytest

from contactflow.fusion.cell import CellFusion, CellFusionParams
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.messages import ContactList, HypothesisCloud
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.registry import resolve
from contactflow.nodes.status import Event
from contactflow.nodes.testing import FakeIO

A = np.array([[0.50, 0.30, 0.80]])
B = np.array([[0.50, -0.30, 0.80]])


def cell(**params) -> tuple[CellFusion, FakeIO]:
    fusion = CellFusion("cell_map", CellFusionParams(**{"robot": "table", "robots": ("baxter", "melfa"), **params}))
    io = FakeIO()
    io.module = fusion
    fusion.setup(io)
    fusion.start()
    return fusion, io


def cloud(at: np.ndarray, robot: str, generator: str = "tactile", t: float = 0.0, likelihood: float = 0.9):
    return HypothesisCloud.of(Hypotheses.make(at, likelihood, stamp=t), robot, generator, "hand")


def test_the_cell_map_fuses_every_robot_of_the_cell_and_goes_out_under_the_cells_name():
    assert resolve("cell_fusion") is CellFusion
    ks = KeySpace("lab")
    p = CellFusionParams(robot="table", robots=("baxter", "melfa"))
    assert CellFusion.default_input_keys(ks, "site", "cell_map", p)["hypotheses"] == "cf/lab/contacts/*/*"
    assert CellFusion.default_output_keys(ks, "site", "cell_map", p)["events"] == "cf/lab/contacts/fused/table/events"
    fusion, io = cell()
    io.feed("hypotheses", cloud(A, "baxter"))
    io.feed("hypotheses", cloud(B, "melfa", "ft"))
    fusion.step()
    (contacts,) = io.published["contacts"]
    assert isinstance(contacts, ContactList)
    assert sorted(c.robot for c in contacts.contacts) == ["baxter", "melfa"]
    assert io.event_labels() == [Event.CONTACT_MADE, Event.CONTACT_MADE]
    assert sum(fusion.refused.values()) == 0
    io.feed("hypotheses", cloud(A, "tombatossals"))
    fusion.step()
    assert fusion.status_detail() == "sources: baxter 1, melfa 1; refused: robot 1"


def test_a_less_reliable_source_weighs_less_in_the_map():
    fusion, io = cell(reliability=("melfa=0.5", "baxter/ft=0.25"))
    io.feed("hypotheses", cloud(A, "baxter"))  # baxter's tactile: no entry, fully trusted
    io.feed("hypotheses", cloud(B, "melfa", "ft"))
    fusion.step()
    by_robot = {c.robot: c.likelihood for c in io.published["contacts"][0].contacts}
    assert by_robot["melfa"] == pytest.approx(0.5 * by_robot["baxter"], rel=1e-6)
    assert fusion.weights == {"melfa": 0.5, "baxter/ft": 0.25}


def test_clouds_of_another_cells_robot_or_far_from_the_clock_are_refused_and_counted():
    fusion, io = cell(max_skew=0.5)
    io.t = 10.0
    io.feed("hypotheses", cloud(A, "tombatossals", t=10.0))  # a robot of another cell (or of another site)
    io.feed("hypotheses", cloud(A, "baxter", t=9.2))  # 0.8 s old: another clock, or a link that held it
    io.feed("hypotheses", cloud(B, "melfa", t=10.6))  # from the future
    fusion.step()
    assert dict(fusion.refused) == {"robot": 1, "skew": 2}
    assert fusion.integrator.sources == {} and "contacts" not in io.published
    assert any("robot 'tombatossals', not of this cell" in line for line in io.logs)
    assert any("baxter/tactile: stamped 9.200 s, -0.800 s from the clock" in line for line in io.logs)


def test_a_flooding_robot_is_throttled_and_the_others_clouds_come_through():
    fusion, io = cell(max_rate=20.0)
    offered: list[str] = []
    real_offer = fusion.loop.offer
    fusion.loop.offer = lambda source, *a, **kw: (offered.append(source), real_offer(source, *a, **kw))[1]
    for k in range(100):  # one second: baxter sends 2 kHz... of which 20 a second are taken, melfa its 10
        io.t = 0.01 * k
        for _ in range(20):
            io.feed("hypotheses", cloud(A, "baxter", t=io.t))
        if k % 10 == 0:
            io.feed("hypotheses", cloud(B, "melfa", "ft", t=io.t))
        fusion.step()
    assert offered.count("melfa/ft") == 10
    assert 20 <= offered.count("baxter/tactile") <= 20 + 20 + 1  # a second's burst, then the rate
    assert fusion.refused["rate"] == 2000 - offered.count("baxter/tactile")
    assert sum(1 for line in io.logs if "(rate)" in line) == 4  # the first three, then every thousandth


@pytest.mark.parametrize(("params", "match"), [
    ({"robots": ()}, "a cell fusion needs the cell's robots"),
    ({"reliability": ("ur5=0.5",)}, "robot 'ur5' is not one of robots"),
    ({"reliability": ("melfa:0.5",)}, "expected '<robot>\\[/<generator>\\]=w'"),
    ({"reliability": ("melfa=1.5",)}, "with w in \\(0, 1\\]"),
    ({"max_rate": 0.0}, "must be > 0"),
])
def test_bad_parameters_are_named(params, match):
    with pytest.raises(ValueError, match=match):
        cell(**params)


def test_a_cell_map_with_a_region_keeps_the_objects_any_robot_touched_and_counts_the_claims_on_them():
    from contactflow.fusion.messages import MapClaim, ObjectMapMsg

    ks = KeySpace("lab")
    p = CellFusionParams(robot="table", robots=("baxter", "melfa"), map_region=(0.4, 0.2, 0.75, 0.6, 0.4, 0.9))
    assert CellFusion.default_input_keys(ks, "site", "cell_map", p)["claims"] == "cf/lab/contacts/fused/*/claims"
    assert CellFusion.default_output_keys(ks, "site", "cell_map", p)["objects"] == "cf/lab/contacts/fused/table/objects"
    fusion, io = cell(map_region=(0.4, 0.2, 0.75, 0.6, 0.4, 0.9))
    io.feed("hypotheses", cloud(A, "baxter"))  # in the region
    io.feed("hypotheses", cloud(B, "melfa"))  # outside it
    fusion.step()
    (objects,) = io.published["objects"]
    assert isinstance(objects, ObjectMapMsg) and objects.map == "table"
    (o,) = objects.objects
    assert o.location == pytest.approx(A[0], abs=0.01) and o.touched == {"baxter": 0.0} and o.claims == 0
    for m in ("table", "table", "elsewhere"):  # a claim on another map is not this map's
        io.feed("claims", MapClaim(map=m, robot="melfa", object_id=o.id, location=o.location))
    io.feed("claims", MapClaim(map="table", robot="melfa", object_id=99, location=o.location))
    io.t = 1.0  # the touch is over: the next cycle, of melfa's cloud alone, counts the claims and keeps the object
    io.feed("hypotheses", cloud(B, "melfa", t=1.0))
    fusion.step()
    io.t = 1.3  # baxter's source was waited for (wait_timeout) and is late
    fusion.step()
    assert len(io.published["objects"]) == 2
    assert io.published["objects"][-1].objects[0].claims == 2
    assert any("object 99" in line for line in io.logs)


def test_without_a_region_the_fusion_keeps_no_object_map():
    fusion, io = cell()
    io.feed("hypotheses", cloud(A, "baxter"))
    fusion.step()
    assert "objects" not in io.published and fusion.objects is None
