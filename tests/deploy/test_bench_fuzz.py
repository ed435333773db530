"""The fuzz benchmark against the deployed default manifest: hostile payloads on every key kill no node."""

import json

import pytest

from contactflow.deploy.bench_fuzz import run


@pytest.mark.heavy(seconds=40)
def test_hostile_payloads_on_every_key_kill_no_node_and_stall_no_loop(tmp_path):
    result = run(tmp_path, quick=True, per_key=3)
    assert json.loads((tmp_path / "fuzz.json").read_text()) == result
    assert result["nodes"] == 8 and result["node_deaths"] == 0, result["exited"]
    assert result["stalled_modules"] == []
    kinds = result["by_key"]
    assert {"robot/command", "robot/state", "clock", "lockstep", "m/ctl", "m/status", "broker/dispatch"} <= set(kinds)
    assert result["rejected"] > 20  # the nodes counted what they refused
    assert kinds["m/ctl"]["answered"] == kinds["m/ctl"]["bytes"] + kinds["m/ctl"]["msgpack"]  # every query answered
