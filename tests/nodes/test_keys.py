"""Key expressions of claims and benchmarks: one wildcard addresses them all, bad parts are refused."""

import pytest
import zenoh

from contactflow.nodes.keys import KeyExprError, KeySpace

KS = KeySpace("lab")


def matches(pattern, key):
    return zenoh.KeyExpr(pattern).intersects(zenoh.KeyExpr(key))


def test_claim_keys_carry_the_mode_and_parse_back():
    key = KS.claim("tom", "arm_left", "control", "push", "mix")
    assert KS.parse_claim(key) == ("control", "push", "mix")
    assert matches(KS.claim("tom", "arm_left"), key) and matches(KS.claim("*", "*"), key)
    assert not matches(KS.claim("tom", "arm_right"), key)
    with pytest.raises(KeyExprError, match="excl or mix"):
        KS.claim("tom", "arm_left", "control", "push", "shared")
    with pytest.raises(KeyExprError, match="not a resource claim"):
        KS.parse_claim(KS.alive_module("tom", "control", "push"))


def test_benchmark_keys_live_under_the_site_and_one_pattern_covers_a_stack():
    key = KS.bench("raw", "64B", "tput", "0")
    assert key.startswith("cf/lab/") and matches(KS.bench("raw"), key)
    assert not matches(KS.bench("contactflow"), key) and not matches(KS.bench(), KS.bench_signal("done"))
    with pytest.raises(KeyExprError, match="size"):
        KS.bench("raw", "64/B", "tput", "0")
    with pytest.raises(KeyExprError, match="ready, done"):
        KS.bench_signal("go")
