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


def test_a_mean_carries_its_runs_and_t_interval():
    from contactflow.nodes.stats import mean, mean_interval, mean_text

    # [1, 2, 3]: sd 1, t(0.975, 2 dof) = 4.3027, so 2 -/+ 4.3027 / sqrt(3)
    assert mean_interval([1.0, 2.0, 3.0]) == pytest.approx((2 - 2.48414, 2 + 2.48414), abs=1e-5)
    # a lower level narrows it; identical runs have no spread
    lo90, hi90 = mean_interval([1.0, 2.0, 3.0], 0.9)
    assert 2 - 2.48414 < lo90 < 2 < hi90 < 2 + 2.48414
    assert mean_interval([4.0, 4.0, 4.0]) == (4.0, 4.0)
    assert mean_interval([7.0]) is None and mean_interval([]) is None
    for values in ([1.0, 2.0], [1.0]):  # a bad level is refused even where there is no interval to give
        with pytest.raises(ValueError, match="level 1.0 is not in"):
            mean_interval(values, 1.0)
    # ten boxes of the vision strategy (attempts per box): the thesis's goal of 11 lies inside the interval
    boxes = [22, 8, 8, 15, 7, 14, 13, 53, 16, 13]
    m = mean(boxes)
    assert m["mean"] == pytest.approx(16.9) and m["runs"] == 10
    assert m["ci95"][0] < 11 < m["ci95"][1]
    assert mean_text(m["mean"], m["ci95"]) == "16.9 [7.3-26.5]"
    assert mean([3.0]) == {"mean": 3.0, "runs": 1, "ci95": None}
    assert mean_text(3.0, None) == "3.0" and mean_text(3.14159, None, 0) == "3"
