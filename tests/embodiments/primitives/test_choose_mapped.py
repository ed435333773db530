"""Choose mapped: which object of a contact map a robot goes for next."""

from contactflow.embodiments.primitives.choose_mapped import ChooseMapped, choose
from contactflow.fusion.messages import MappedObjectInfo
from contactflow.nodes.keys import KeySpace


def obj(i: int, x: float, sightings: int = 5, claims: int = 0, **touched: float) -> MappedObjectInfo:
    return MappedObjectInfo(id=i, location=[x, -0.3, 0.8], sightings=sightings, touched=touched, claims=claims)


def test_untouched_by_me_first_then_the_one_i_touched_longest_ago_and_the_most_seen():
    objs = [obj(1, 0.50, 3, melfa=1.0), obj(2, 0.55, 9, melfa=1.0), obj(3, 0.60, 20, melfa=1.0, tombatossals=5.0)]
    assert choose(objs, "tombatossals", (), 3).id == 2  # never touched by it, seen most
    objs[0] = obj(1, 0.50, 3, melfa=1.0, tombatossals=2.0)
    objs[1] = obj(2, 0.55, 9, melfa=1.0, tombatossals=9.0)  # it could not take 2: 1 and 3 before it
    assert choose(objs, "tombatossals", (), 3).id == 1
    assert choose(objs[1:], "tombatossals", (), 3).id == 3


def test_objects_hands_found_nothing_at_wait_and_are_given_up_after_forget_claims():
    objs = [obj(1, 0.50, 30, claims=1), obj(2, 0.55, 2)]
    assert choose(objs, "melfa", (), 3).id == 2
    assert choose([obj(1, 0.50, claims=3)], "melfa", (), 3) is None


def test_only_objects_over_the_region():
    objs = [obj(1, 0.30), obj(2, 0.55)]
    assert choose(objs, "melfa", (0.4, -0.5, 0.7, -0.1), 3).id == 2
    assert choose(objs, "melfa", (0.6, -0.5, 0.7, -0.1), 3) is None


def test_it_reads_its_robots_own_map_unless_wired_and_claims_on_its_robots_key():
    ks, p = KeySpace("lab"), ChooseMapped.Params()
    assert ChooseMapped.default_input_keys(ks, "melfa", "choose", p) == {"objects": "cf/lab/contacts/fused/melfa/objects"}
    assert ChooseMapped.default_output_keys(ks, "melfa", "choose", p) == {"claim": "cf/lab/contacts/fused/melfa/claims"}
