"""Smoke test of the deploy benchmark (quick mode)."""

import json

from contactflow.deploy.bench_deploy import run


def test_bench_deploy_quick_writes_bring_up_and_latencies(tmp_path):
    summary = run(tmp_path, quick=True)
    saved = json.loads((tmp_path / "deploy.json").read_text())
    assert saved["bring_up"][0]["nodes"] == 5 and saved["bring_up"][0]["modules"] == 9
    assert summary["bring_up_median_s"] > 0
    for key in ("latency_loopback", "latency_netns"):
        assert saved[key]["n"] >= 100 and 0 < saved[key]["p50_ms"] <= saved[key]["p99_ms"], saved[key]
