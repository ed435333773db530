"""Smoke test of the deploy benchmark (quick mode)."""

import json

import pytest

from contactflow.deploy.bench_deploy import run
from contactflow.deploy.manifest import DEFAULT_MANIFEST, load_manifest


@pytest.mark.heavy(seconds=50)
def test_bench_deploy_quick_writes_bring_up_and_fused_event_latencies(tmp_path):
    summary = run(tmp_path, quick=True)
    saved = json.loads((tmp_path / "deploy.json").read_text())
    m = load_manifest(DEFAULT_MANIFEST)  # every node and module of the default manifest came up
    assert saved["bring_up"][0]["nodes"] == len(m.nodes()) == 8
    assert saved["bring_up"][0]["modules"] == sum(len(n.modules) for n in m.nodes()) > 8
    assert summary["bring_up_median_s"] > 0
    for key in ("latency_loopback", "latency_netns"):
        # every fused contact event was traced back to the tactile reading it came from, and that
        # cue latency holds the event's own transport
        lat = saved[key]
        assert lat["n"] >= 100 and lat["untraced"] == 0 and 0 < lat["p50_ms"] <= lat["p99_ms"], lat
        assert lat["transport"]["n"] == lat["n"] and 0 < lat["transport"]["p50_ms"] < lat["p50_ms"], lat
