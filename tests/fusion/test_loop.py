"""The one fusion loop: Algorithm 4.1's wait-all, late and silent sources, contacts that break when nobody talks."""

import numpy as np

from contactflow.fusion.events import TrackerParams
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.integrator import IntegratorParams
from contactflow.fusion.loop import FusionLoop
from contactflow.nodes.status import Event

A = np.array([[0.50, 0.30, 0.80]])
B = np.array([[0.50, -0.30, 0.80]])


def loop(**kw) -> FusionLoop:
    return FusionLoop(IntegratorParams(timeout=0.3, wait_timeout=0.1, source_timeout=1.0),
                      tracker_params=TrackerParams(hold=0.05), **kw)


def test_a_cycle_waits_for_every_active_source_or_the_wait_timeout():
    f = loop()
    f.offer("r/tactile", Hypotheses.make(A, 0.9, stamp=0.0), 0.0, "r", "thumb")
    f.offer("r/ft", Hypotheses.make(B, 0.8, stamp=0.0), 0.0, "r", "hand")
    first = f.step(0.0)
    assert first is not None and [e.event for e in first.events] == [Event.CONTACT_MADE] * 2
    f.offer("r/tactile", Hypotheses.make(A, 0.9, stamp=0.02), 0.02, "r", "thumb")
    assert f.step(0.02) is None  # r/ft has not spoken this cycle: wait for it
    assert f.step(0.08) is None
    late = f.step(0.13)  # the wait for the late source timed out
    assert late is not None and late.events == []
    f.offer("r/tactile", Hypotheses.make(A, 0.9, stamp=0.14), 0.14, "r", "thumb")
    f.offer("r/ft", Hypotheses.empty(0.14), 0.14, "r", "hand")  # feels nothing: a reading, not silence
    both = f.step(0.14)
    assert both is not None and len(both.contacts) == 2  # B's hypothesis lives until its timeout


def test_when_nobody_talks_the_contacts_break_and_silent_sources_are_unplugged():
    f = loop(drop_after=2.0)
    f.offer("r/tactile", Hypotheses.make(A, 0.9, stamp=0.0), 0.0, "r", "thumb")
    assert [e.event for e in f.step(0.0).events] == [Event.CONTACT_MADE]
    broken = f.step(1.5)  # r/tactile silent past source_timeout: the hypotheses expire
    assert broken is not None and [e.event for e in broken.events] == [Event.CONTACT_BROKEN]
    assert f.step(1.6) is None  # no contacts left, nobody talks: no cycle
    f.step(2.5)
    assert f.integrator.sources == {}
