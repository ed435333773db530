"""Where on the hand a fused contact lies: finger, palm or held object, from the robot's posed model."""

import numpy as np
import pytest

from contactflow.fusion.geometry import part_distances
from contactflow.fusion.regions import Region, RegionParams, classify

# a palm sphere of 4 cm at the origin and one finger capsule of 1 cm from (0.06, 0, 0) to (0.10, 0, 0)
CAPS = np.array([[0.0, 0.0, 0.0, 0.04, 0.0, 0.0, 0.0, 0.04],
                 [0.06, 0.0, 0.0, 0.01, 0.10, 0.0, 0.0, 0.01],
                 [0.0, 0.5, 0.0, 0.05, 0.0, 0.6, 0.0, 0.05]])
LINKS = ["palm_link", "link_3.0_tip", "forearm"]
REGIONS = ["palm", "finger", ""]


def test_the_distance_to_a_bi_sphere_is_to_its_surface_with_the_radius_along_it() -> None:
    d = part_distances(np.array([[0.08, 0.02, 0.0], [0.0, 0.0, 0.05], [0.2, 0.0, 0.0]]), CAPS[:2])
    assert d[0, 1] == pytest.approx(0.01) and d[1, 0] == pytest.approx(0.01)
    assert d[2, 1] == pytest.approx(0.09)  # past the segment's end: from the end sphere
    tapered = np.array([[0.0, 0.0, 0.0, 0.02, 0.1, 0.0, 0.0, 0.0]])
    assert part_distances(np.array([[0.05, 0.03, 0.0]]), tapered)[0, 0] == pytest.approx(0.02)


def test_a_contact_is_told_on_the_finger_the_palm_what_the_hand_holds_or_nothing() -> None:
    points = np.array([[0.08, 0.015, 0.0],   # on the finger's surface
                       [0.0, -0.045, 0.0],   # on the palm
                       [0.08, 0.0, -0.07],   # 6 cm under the finger: on what the hand holds
                       [0.0, 0.3, 0.0],      # far from the hand (the forearm is no hand part)
                       [0.0, 0.45, 0.0]])    # on the forearm: no region
    told = classify(points, CAPS, LINKS, REGIONS)
    assert told == [("finger", "link_3.0_tip"), ("palm", "palm_link"), ("held_object", "link_3.0_tip"), ("", ""),
                    ("", "")]
    assert {r for r, _ in told if r} <= set(Region)
    # a model without hand parts tells nothing
    assert classify(points, CAPS, LINKS, ["", "", ""]) == [("", "")] * 5
    assert classify(np.zeros((0, 3)), CAPS, LINKS, REGIONS) == []
    # a tighter reach: the contact under the finger is on no part of the hand
    assert classify(points[2:3], CAPS, LINKS, REGIONS, RegionParams(reach=0.05)) == [("", "")]


def test_a_contact_spread_between_two_fingers_is_on_a_finger_not_on_what_the_hand_holds() -> None:
    # two fingertips 6 cm apart: a cluster over both has its centroid midway, 2 cm off either surface
    caps = np.array([[0.0, 0.03, 0.0, 0.01, 0.0, 0.03, 0.0, 0.01], [0.0, -0.03, 0.0, 0.01, 0.0, -0.03, 0.0, 0.01]])
    links, regions = ["index_tip", "thumb_tip"], ["finger", "finger"]
    mid = np.array([[0.0, 0.0, 0.0]])
    assert classify(mid, caps, links, regions)[0][0] == "held_object"  # a point there, told alone
    assert classify(mid, caps, links, regions, spread=np.array([0.03]))[0][0] == "finger"  # voxels over both tips
    # a tight cluster 4 cm under the fingers (a held object set down) stays on the held object
    assert classify(np.array([[0.0, 0.0, -0.05]]), caps, links, regions, spread=np.array([0.005]))[0][0] == "held_object"


@pytest.mark.parametrize("margin, reach", [(0.0, 0.1), (0.02, 0.01), (-0.01, 0.1)])
def test_region_params_need_a_margin_inside_the_reach(margin, reach) -> None:
    with pytest.raises(ValueError, match="need 0 < margin < reach"):
        RegionParams(margin, reach).validate()
