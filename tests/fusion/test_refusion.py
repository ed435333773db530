"""Re-fusion on the recorded loop's cycles: each cloud in the cycle that took it, late or replaced."""

import numpy as np

from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.messages import ContactList, HypothesisCloud
from contactflow.fusion.refusion import _recorded_steps, refuse
from contactflow.fusion.service import FusionParams
from contactflow.nodes.wire import MsgId, stamp

PARAMS = FusionParams(rate_hz=50, timeout=0.1, hold=0.05)
SOURCE = "r1/tactile/pad"


def _cloud(seq: int, t: float, pressed: bool) -> HypothesisCloud:
    n = 4 if pressed else 0
    h = Hypotheses(np.tile([0.5, 0.0, 0.8], (n, 1)) + 0.002 * np.arange(n)[:, None], np.full(n, 0.9),
                   np.zeros(n, np.uint8), np.zeros(n), np.zeros((n, 3)), t)
    return stamp(HypothesisCloud.of(h, "r1", "tactile"), SOURCE, seq, t)


def _cycle(t: float, *seqs: int) -> ContactList:
    return stamp(ContactList(stamp=t), "r1/fuse/fusion/contacts", 1, t, [MsgId(source=SOURCE, seq=s) for s in seqs])


def test_a_cloud_a_loaded_loop_took_late_makes_its_event_on_that_cycle_not_at_its_stamp():
    clouds = [_cloud(1, 0.00, False), _cloud(2, 0.02, True), _cloud(3, 0.04, True)]
    # the loop stepped at 0.00, then not before 0.11 (busy), where it took clouds 2 and 3 at once
    cycles = [_cycle(0.00, 1), _cycle(0.11, 3), _cycle(0.13, 3)]
    made = refuse(clouds, PARAMS, cycles=cycles)
    assert [(e.event.value, e.t) for e in made] == [("contact_made", 0.11)]
    grid = refuse(clouds, PARAMS)  # from the stamps: made on the grid's step at 0.02
    assert (grid[0].event.value, grid[0].t) == ("contact_made", 0.02)


def test_each_cloud_goes_to_the_cycle_that_took_it_or_with_the_cloud_that_replaced_it():
    clouds = [_cloud(1, 0.00, False), _cloud(2, 0.02, True), _cloud(3, 0.04, True), _cloud(4, 0.05, True),
              _cloud(5, 0.30, True)]
    cycles = [_cycle(0.01, 1), _cycle(0.11, 3), _cycle(0.12, 4), _cycle(0.20, 4)]
    steps = _recorded_steps(sorted(clouds, key=lambda c: c.stamp), cycles)
    assert [t for t, _ in steps] == [0.01, 0.11, 0.12, 0.20]
    # 2 was replaced by 3 before a cycle ran; 5 came after the last cycle, never fused
    assert [[c.hdr.seq for c in taken] for _, taken in steps] == [[1], [2, 3], [4], []]
