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
