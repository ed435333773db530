"""Success rates with their 95 % Wilson intervals."""

from __future__ import annotations

import pytest

from contactflow.nodes.stats import rate, rate_text, wilson


def test_wilson_matches_the_published_values_and_stays_inside_zero_and_one():
    # Newcombe (1998), Table I: 81/263 -> 0.2553-0.3662; 15/148 -> 0.0624-0.1605; 0/20 -> 0-0.1611; 1/29 -> 0.0061-0.1718
    assert wilson(81, 263) == pytest.approx((0.2553, 0.3662), abs=1e-4)
    assert wilson(15, 148) == pytest.approx((0.0624, 0.1605), abs=1e-4)
    assert wilson(0, 20) == pytest.approx((0.0, 0.1611), abs=1e-4)
    assert wilson(1, 29) == pytest.approx((0.0061, 0.1718), abs=1e-4)
    lo, hi = wilson(10, 10)
    assert hi == 1.0 and lo == pytest.approx(0.7225, abs=1e-4)  # 10 of 10 does not prove a rate above 73 %
    assert wilson(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError, match="11 successes in 10 trials"):
        wilson(11, 10)


def test_a_rate_carries_its_trials_and_interval():
    r = rate(27, 30)
    assert r["successes"] == 27 and r["trials"] == 30 and r["rate"] == pytest.approx(0.9)
    assert r["ci95"] == pytest.approx(list(wilson(27, 30)))
    assert rate_text(27, 30) == "27/30 = 90 % [74-97 %]"
