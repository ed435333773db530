"""Bids: dry-run translations with a nominal duration, refusals with reasons."""

from __future__ import annotations

import math

from contactflow.abstraction.atd import load_atd, parse_atd
from contactflow.abstraction.bid import bid
from contactflow.abstraction.examples import path
from contactflow.abstraction.profiles import PROFILES

MELFA, TOMBATOSSALS = PROFILES["melfa"], PROFILES["tombatossals"]


def test_bids_for_pick_and_place():
    atd = load_atd(path("pick_place_behind.xml"))
    bids = {name: bid(atd, p) for name, p in PROFILES.items()}
    assert all(b.ok for b in bids.values())
    assert all(0 < b.duration < math.inf for b in bids.values())
    # the slow tombatossals arm with its robust grasp bids longer than the fast melfa
    assert bids["tombatossals"].duration > bids["melfa"].duration


def test_refused_bid_lists_reasons():
    text = path("push_away.xml").read_text()
    assert "0.15 0.50 0.03</target>" in text
    text = text.replace("0.15 0.50 0.03</target>", "2.5 0.50 0.03</target>")
    atd = parse_atd(text, "far.xml")
    b = bid(atd, MELFA)
    assert not b.ok and b.duration == math.inf
    assert any("out of melfa's reach" in r for r in b.reasons)
    assert not bid(atd, TOMBATOSSALS).ok
