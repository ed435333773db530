"""Contact event tracker: made, broken, confirm, hold, association."""

import numpy as np

from contactflow.fusion.condensation import Contact
from contactflow.fusion.events import ContactTracker, TrackerParams
from contactflow.nodes.status import Event


def contact(x, lik=0.9, link="palm"):
    return Contact(np.array([x, 0.0, 0.8]), lik, 0.005, 1.0, np.zeros(3), 5, 1, "r1", link)


def test_made_then_broken_after_hold():
    tr = ContactTracker(TrackerParams(hold=0.1))
    (e,) = tr.update([contact(0.5)], 0.0)
    assert (e.event, e.robot, e.link, e.id, e.sigma) == (Event.CONTACT_MADE, "r1", "palm", 1, 0.005)
    assert tr.update([contact(0.505)], 0.05) == []  # same contact, moved a little
    assert tr.update([], 0.1) == []  # unseen, but within hold
    (b,) = tr.update([], 0.16)
    assert b.event == Event.CONTACT_BROKEN and b.id == 1
    assert np.allclose(b.location, [0.5025, 0, 0.8])
    assert tr.tracks == []


def test_two_contacts_get_two_ids_and_break_independently():
    tr = ContactTracker(TrackerParams(hold=0.0))
    ev = tr.update([contact(0.5), contact(0.6, link="thumb")], 0.0)
    assert sorted(e.id for e in ev) == [1, 2]
    ev = tr.update([contact(0.6, link="thumb")], 0.1)
    assert [(e.event, e.link) for e in ev] == [(Event.CONTACT_BROKEN, "palm")]


def test_confirm_needs_consecutive_cycles():
    tr = ContactTracker(TrackerParams(confirm=2))
    assert tr.update([contact(0.5)], 0.0) == []
    assert tr.update([], 0.05) == []  # flicker: candidate dropped, no event
    assert tr.update([contact(0.5)], 0.1) == []
    (e,) = tr.update([contact(0.5)], 0.15)
    assert e.event == Event.CONTACT_MADE


def test_far_contact_is_a_new_one():
    tr = ContactTracker(TrackerParams(match_radius=0.02, hold=0.0))
    tr.update([contact(0.5)], 0.0)
    ev = tr.update([contact(0.55)], 0.1)
    assert sorted(e.event for e in ev) == sorted([Event.CONTACT_MADE, Event.CONTACT_BROKEN])


def test_reset_reports_made_contacts_broken():
    tr = ContactTracker()
    tr.update([contact(0.5)], 0.0)
    (e,) = tr.reset(now=1.0)
    assert e.event == Event.CONTACT_BROKEN and tr.tracks == []
