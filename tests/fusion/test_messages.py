"""Fusion wire messages: round trips and field-naming errors."""

import numpy as np
import pytest

from contactflow.fusion.condensation import Contact
from contactflow.fusion.hypotheses import Hypotheses, HypothesisType
from contactflow.fusion.messages import ContactEventMsg, ContactInfo, HypothesisCloud
from contactflow.nodes.status import Event
from contactflow.nodes.wire import NDArray, WireError, decode, encode


def test_cloud_roundtrip():
    h = Hypotheses.make(np.array([[0.5, 0.1, 0.8], [0.6, 0, 0.8]]), [0.5, 1.0], HypothesisType.SUPPORT,
                        [1.0, 2.0], [[0, 0, 1], [1, 0, 0]], 3.25)
    msg = decode(encode(HypothesisCloud.of(h, "r1", "tactile", "thumb")), HypothesisCloud)
    assert msg.source == "r1/tactile" and msg.link == "thumb"
    back = msg.hypotheses()
    assert np.allclose(back.location, h.location, atol=1e-6) and back.stamp == 3.25
    assert back.kind.tolist() == [1, 1] and np.allclose(back.force, [1, 2])


def test_cloud_without_force_sends_empty_arrays():
    msg = HypothesisCloud.of(Hypotheses.make(np.zeros((3, 3)), 0.5), "r1", "range")
    assert msg.force.shape == [0] and msg.direction.shape == [0, 3]
    assert np.allclose(msg.hypotheses().force, 0)


def test_bad_cloud_names_the_field():
    msg = HypothesisCloud.of(Hypotheses.make(np.zeros((3, 3)), 0.5), "r1", "range")
    msg.likelihood = NDArray.of(np.zeros(2, np.float32))
    with pytest.raises(WireError, match=r"r1/range\).likelihood"):
        msg.hypotheses()
    msg.likelihood = NDArray.of(np.full(3, 2.0, np.float32))
    with pytest.raises(WireError, match="'likelihood' must lie"):
        msg.hypotheses()
    msg.likelihood = NDArray.of(np.full(3, 0.5, np.float32))
    msg.frame = "hand"
    with pytest.raises(WireError, match="world frame"):
        msg.hypotheses()


def test_contact_messages():
    c = Contact(np.array([0.5, 0, 0.8]), 0.9, 0.01, 2.0, np.array([1.0, 0, 0]), 7, 0b101, "r1", "palm")
    info = ContactInfo.of(c, ["r1/ft", "r1/range", "r1/tactile"])
    assert info.sources == ["r1/ft", "r1/tactile"]
    with pytest.raises(ValueError, match="contact_made or contact_broken"):
        ContactEventMsg(event=Event.SUCCESS, contact_id=1, robot="r", link="", location=[0, 0, 0], likelihood=1, t=0)
