"""Parameter coercion: online changes and YAML values become the declared field types."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from contactflow.nodes.params import ParamError, params_dict, replace_params


@dataclass(frozen=True)
class P:
    rate_hz: float = 10.0
    count: int = 3
    on: bool = False
    gains: tuple[float, ...] = (1.0, 2.0)
    links: tuple[str, ...] = ("hand",)


def test_numbers_lists_and_strings_take_their_declared_types():
    p = replace_params(P(), {"rate_hz": "20", "count": 4.0, "on": "yes", "gains": "[1, 2.5]",
                             "links": ["pad_left", "pad_right"]})
    assert p == P(20.0, 4, True, (1.0, 2.5), ("pad_left", "pad_right"))
    assert replace_params(P(), {"links": "a, b"}).links == ("a", "b")
    assert params_dict(p)["links"] == ["pad_left", "pad_right"]


@pytest.mark.parametrize(("change", "message"), [
    ({"rate_hz": "fast"}, "rate_hz: expected a number"),
    ({"count": 1.5}, "count: expected an integer"),
    ({"gains": ["a"]}, "gains: expected a list of numbers"),
    ({"links": [1, 2]}, "links: expected a list of strings"),
    ({"nope": 1}, "nope: unknown parameter"),
    ({"gains": [1.0, "nan"]}, "gains: expected a list of numbers"),
    ({"rate_hz": "nan"}, "rate_hz: expected a number"),
    ({"rate_hz": 0}, "rate_hz: expected a positive finite rate in Hz, got 0"),
    ({"rate_hz": "-inf"}, "rate_hz: expected a positive finite rate in Hz"),
])
def test_bad_values_name_the_field(change, message):
    with pytest.raises(ParamError, match=message):
        replace_params(P(), change, where="m.")


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_a_rate_is_taken_only_when_it_is_a_positive_finite_number(rate):
    ok = math.isfinite(rate) and rate > 0.0
    try:
        p = replace_params(P(), {"rate_hz": rate})
    except ParamError as exc:
        assert not ok and "rate_hz" in str(exc)
    else:
        assert ok and p.rate_hz == rate
