"""Smoke tests of the fusion benchmarks in their quick form."""

import json

from contactflow.fusion import bench_contacts, bench_fusion


def test_bench_fusion_quick(tmp_path):
    s = bench_fusion.run(tmp_path, quick=True)
    assert json.loads((tmp_path / "fusion.json").read_text())["benchmark"] == "fusion"
    assert all(r["same_voxels"] and r["max_abs_diff"] < 1e-9 for r in s["results"])
    assert s["static_3x10k_hz"] > 0


def test_bench_contacts_quick(tmp_path):
    s = bench_contacts.run(tmp_path, quick=True)
    assert (tmp_path / "contacts.md").exists() and (tmp_path / "contacts.png").exists()
    assert s["touches"] == 3
    touched = s["touches"] - s["missed_touches"]
    assert touched >= 2
    assert s["modalities"]["all"]["detected"] >= 1  # the fused modalities find a touch


def test_bench_contacts_runtime_fuses_the_worlds_robot_cues_and_judges_them_by_its_true_contacts(tmp_path):
    import math

    s = bench_contacts.run(tmp_path, quick=True, executor="runtime")
    rt = json.loads((tmp_path / "contacts.json").read_text())["runtime"]
    assert rt["touches"] == 3 and rt["touches"] - rt["missed_touches"] >= 2  # the world's eval/ stream saw the hand touch
    rows = rt["modalities"]
    # the wrist F/T cues of the world's robot state, fused by the fusion node, find the touches within centimetres
    force = rows["force"]
    assert force["detected"] >= 2, rt["per_touch"]
    assert math.isfinite(force["eps_cm"]) and 0.0 < force["eps_cm"] < 5.0 and force["sigma_cm"] > 0.0
    assert rows["tactile + force"]["detected"] >= force["detected"]
    # what the runtime has no generator for is reported missing, not faked
    assert {m for m, r in rows.items() if "missing" in r} == {"range", "all", "all + simulator"}
    assert "missing" in (tmp_path / "contacts.md").read_text()
    assert s["executor"] == "runtime" and "modalities" not in s  # no local figures were computed


def test_bench_contacts_refuses_an_unknown_executor(tmp_path):
    import pytest

    from contactflow.nodes.params import ParamError

    with pytest.raises(ParamError, match="--executor 'sim' is not one of"):
        bench_contacts.run(tmp_path, quick=True, executor="sim")
