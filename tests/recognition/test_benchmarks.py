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


def test_bench_vision_runtime_segments_the_worlds_depth_stream_on_the_vision_node(tmp_path):
    import math

    import pytest

    out = bench_vision.run(tmp_path, quick=True, executor="runtime")
    rt = json.loads((tmp_path / "vision.json").read_text())["runtime"]
    assert rt == json.loads(json.dumps(out["runtime"]))
    # fresh frames of the world's depth stream went through the vision3d node over zenoh
    # (a loaded machine slows the world's pace, and with it the camera's rate in wall time)
    assert rt["frames"] >= 3 and 0 < rt["processed"] <= rt["frames"]
    assert rt["dropped"] == rt["frames"] - rt["processed"]
    assert rt["processed_hz"] == pytest.approx(rt["processed"] / rt["seconds"]) and 0 < rt["world_rtf"] <= 1.2
    lat = rt["latency"]
    assert 0.0 < lat["min_ms"] <= lat["median_ms"] <= lat["p95_ms"] <= lat["max_ms"] < 5000.0
    assert all(math.isfinite(v) for v in lat.values())
    # every hop of the chain was heard for every frame that came through, each took time (a stage publishes
    # after its input was published), and together they are the whole latency: their means add up to its mean
    hops = rt["hops_ms"]
    assert list(hops) == ["frame->cloud", "cloud->roi", "roi->self", "self->objects", "objects->bench"]
    assert rt["hops_frames"] == rt["processed"]
    assert all(0.0 < h["median"] < 5000.0 and 0.0 < h["mean"] < 5000.0 for h in hops.values()), hops
    assert sum(h["mean"] for h in hops.values()) == pytest.approx(lat["mean_ms"], rel=1e-9)
    # the five objects on the table are five clusters
    assert rt["objects"] == 5 and rt["clusters_right"] >= 0.9 * rt["processed"], rt
    assert "runtime" in (tmp_path / "vision.md").read_text()


def test_bench_vision_refuses_an_unknown_executor(tmp_path):
    import pytest

    from contactflow.nodes.params import ParamError

    with pytest.raises(ParamError, match="--executor 'sim' is not one of"):
        bench_vision.run(tmp_path, executor="sim")


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
