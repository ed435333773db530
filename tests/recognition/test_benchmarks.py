"""Smoke tests of the recognition benchmarks in quick mode (outputs exist and are consistent)."""

from __future__ import annotations

import json

from contactflow.recognition import bench_recognition, bench_vision
from contactflow.recognition.features import FEATURE_SETS


def test_bench_vision_quick(tmp_path):
    out = bench_vision.run(tmp_path, quick=True)
    saved = json.loads((tmp_path / "vision.json").read_text())
    assert saved["frames"] == out["frames"] == 15
    for r in saved["scenes"].values():
        assert r["points"]["clusters"] >= 3
        assert r["total"]["mean_ms"] > 0
    assert (tmp_path / "vision.md").read_text().startswith("# 3D vision pipeline")


def test_bench_recognition_quick(tmp_path):
    out = bench_recognition.run(tmp_path, quick=True)
    for name in ("recognition.json", "recognition.md", "recognition_sos_aos.png", "recognition_knowledge.json"):
        assert (tmp_path / name).stat().st_size > 0
    rec = out["recognition"]
    assert set(rec["table_8_3"]) == set(FEATURE_SETS)
    for r in rec["table_8_2"].values():
        for o in r.values():
            assert abs(o["correct"] + o["wrong"] + o["uncertain"] - 100.0) < 1e-6
    assert all(len(rec["incremental"][m]) == 4 for m in ("unsupervised", "supervisor labels unknowns"))
    assert len(out["shape"]["rows"]) == 18
    assert all(len(r["cells"]) == 4 for r in out["shape"]["rows"])
