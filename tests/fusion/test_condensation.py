"""Contact condensation: cluster separates two contacts (Fig. 4.12), centroid, threshold."""

import numpy as np
import pytest

from contactflow.fusion.condensation import CondensationParams, Method, condense
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.integrator import Integrator

A = np.array([0.50, 0.00, 0.80])
B = np.array([0.50, 0.06, 0.80])


def blob(center, n, spread, rng, lik):
    return Hypotheses.make(center + rng.normal(0, spread, (n, 3)), lik)


def fused_two_contacts():
    """Fig. 4.12: two touches, F/T-like broad noise plus two tight tactile blobs."""
    rng = np.random.default_rng(0)
    integ = Integrator()
    integ.offer("tactile", Hypotheses.concat([blob(A, 40, 0.003, rng, 0.8), blob(B, 40, 0.003, rng, 0.8)]), 0.0)
    integ.offer("ft", Hypotheses.make(rng.uniform([0.45, -0.05, 0.75], [0.55, 0.11, 0.85], (300, 3)), 0.01), 0.0)
    return integ.cycle(0.0)


def test_cluster_method_separates_two_contacts():
    contacts = condense(fused_two_contacts(), CondensationParams(method=Method.CLUSTER))
    assert len(contacts) == 2
    found = sorted(contacts, key=lambda c: c.location[1])
    assert np.linalg.norm(found[0].location - A) < 0.005
    assert np.linalg.norm(found[1].location - B) < 0.005
    for c in found:
        assert 0 < c.sigma < 0.01 and c.voxels > 3


def test_centroid_method_merges_them_in_between():
    contacts = condense(fused_two_contacts(), CondensationParams(method=Method.CENTROID))
    assert len(contacts) == 1
    assert abs(contacts[0].location[1] - 0.03) < 0.01
    assert contacts[0].sigma > 0.02


def test_threshold_method_keeps_only_likely_voxels():
    f = fused_two_contacts()
    c = condense(f, CondensationParams(method=Method.THRESHOLD, threshold=0.6))
    assert len(c) == 1 and c[0].voxels == int(np.count_nonzero(f.likelihood >= 0.6))


def test_weak_cloud_is_no_contact_and_empty_cloud_is_fine():
    integ = Integrator()
    integ.offer("ft", Hypotheses.make(np.array([[0.5, 0, 0.8], [0.6, 0, 0.8]]), 0.05), 0.0)
    assert condense(integ.cycle(0.0), CondensationParams(min_mass=0.3)) == []
    assert condense(Integrator().fuse(0.0)) == []


def test_contact_gets_robot_and_link_of_main_source():
    integ = Integrator()
    integ.offer("r1/tactile", Hypotheses.make(A[None], 0.9), 0.0, robot="r1", link="thumb")
    integ.offer("r2/camera", Hypotheses.make(A[None], 0.1), 0.0, robot="r1", link="")
    (c,) = condense(integ.cycle(0.0))
    assert (c.robot, c.link) == ("r1", "thumb")
    assert c.likelihood == pytest.approx(1 - 0.1 * 0.9)


def test_a_support_cloud_naming_no_link_does_not_take_the_contact_off_its_link():
    # motion support spans both hands and names no link; it outweighs a thin F/T line on the voxel it
    # supports, and the contact stays on the hand the F/T names
    from contactflow.fusion.hypotheses import HypothesisType

    integ = Integrator()
    integ.offer("r1/force_torque", Hypotheses.make(A[None], 0.05), 0.0, robot="r1", link="right_hand")
    integ.offer("r1/motion", Hypotheses.make(A[None], 0.3, HypothesisType.SUPPORT), 0.0, robot="r1", link="")
    (c,) = condense(integ.cycle(0.0), CondensationParams(threshold=0.01, min_mass=0.0))
    assert (c.robot, c.link) == ("r1", "right_hand")


def test_bad_params_are_refused():
    with pytest.raises(ValueError, match="cluster_eps"):
        CondensationParams(cluster_eps=0).validate()
