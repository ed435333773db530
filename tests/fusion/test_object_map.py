"""The object map: touched objects of a region kept after the touch, followed while carried, claimed by the robots."""

import numpy as np
import pytest

from contactflow.fusion.object_map import ObjectMap, ObjectMapParams

REGION = (0.4, -0.5, 0.77, 0.7, -0.2, 0.9)


def test_touches_inside_the_region_become_objects_and_touches_nearby_refine_them():
    m = ObjectMap(ObjectMapParams(region=REGION, merge=0.04, memory=8))
    m.touch([np.array([0.50, -0.30, 0.80]), np.array([0.60, -0.40, 0.80])], ["melfa", "melfa"], 1.0)
    m.touch([np.array([0.52, -0.30, 0.80])], ["melfa"], 2.0)
    m.touch([np.array([0.50, -0.30, 0.76]), np.array([0.2, 0.0, 0.8])], ["melfa", "melfa"], 3.0)  # the bottom, off the box
    assert [o.id for o in m.objects] == [1, 2]
    first, second = m.objects
    assert first.location == pytest.approx([0.51, -0.30, 0.80])
    assert first.sightings == 2 and first.touched == {"melfa": 2.0}
    assert second.location == pytest.approx([0.60, -0.40, 0.80])


def test_a_carried_object_is_followed_out_of_the_region_and_dropped():
    m = ObjectMap(ObjectMapParams(region=REGION, merge=0.04, memory=4))
    at = np.array([0.55, -0.35, 0.80])
    m.touch([at] * 4, ["tombatossals"] * 4, 0.0)
    for k in range(1, 30):  # lifted 1 cm per cycle
        m.touch([at + [0.0, 0.0, 0.01 * k]], ["tombatossals"], 0.05 * k)
        if not m.objects:
            break
        assert m.objects[0].location[2] > at[2]
    assert m.objects == [] and k < 29


def test_two_estimates_that_came_close_are_one_object():
    m = ObjectMap(ObjectMapParams(region=REGION, merge=0.04))
    m.touch([np.array([0.50, -0.30, 0.80])], ["melfa"], 0.0)
    m.touch([np.array([0.545, -0.30, 0.80])], ["tombatossals"], 1.0)  # 4.5 cm away: another object, for now
    assert len(m.objects) == 2
    m.touch([np.array([0.53, -0.30, 0.80])] * 3, ["tombatossals"] * 3, 2.0)  # the second moves toward the first
    (o,) = m.objects
    assert o.id == 1 and o.touched == {"melfa": 0.0, "tombatossals": 2.0}


def test_claims_count_until_a_touch():
    m = ObjectMap(ObjectMapParams(region=REGION))
    m.touch([np.array([0.50, -0.30, 0.80])], ["melfa"], 0.0)
    assert m.claim(1) and m.claim(1) and not m.claim(7)
    assert m.objects[0].claims == 2
    m.touch([np.array([0.50, -0.30, 0.80])], ["tombatossals"], 1.0)
    assert m.objects[0].claims == 0


@pytest.mark.parametrize("bad", [dict(region=(0.0, 0.0, 0.0, 1.0, 1.0)), dict(region=(1, 0, 0, 0, 1, 1)),
                                 dict(region=REGION, merge=0.0), dict(region=REGION, memory=0)])
def test_bad_map_params_are_refused(bad):
    with pytest.raises(ValueError, match="map_"):
        ObjectMap(ObjectMapParams(**bad))
