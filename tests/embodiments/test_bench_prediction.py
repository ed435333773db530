"""The prediction benchmark's worlds and its summary (the runs themselves: tests/embodiments/test_predictor.py)."""

from __future__ import annotations

import json

import pytest
import yaml

from contactflow.embodiments import bench_prediction as bp
from contactflow.embodiments.scene_file import parse_scene
from contactflow.nodes.yamldoc import YamlDoc


def can(text: str):
    return next(o for o in parse_scene(YamlDoc.parse(text, "world.yaml")).objects if o.name == bp.CAN)


def test_each_case_differs_from_the_belief_as_it_says_and_a_seed_repeats():
    believed = can(bp.BELIEF.read_text())
    gaps = []
    for seed in range(20):
        world = can(bp.world_scene("undisturbed", seed))
        offset = ((world.xyz[0] - believed.xyz[0]) ** 2 + (world.xyz[1] - believed.xyz[1]) ** 2) ** 0.5
        assert offset <= 0.01 + 1e-4 and 0.8 <= world.mass / believed.mass <= 1.25
        assert 0.8 <= world.friction / believed.friction <= 1.25
        gaps.append(offset)
    assert max(gaps) > 0.007 and len(set(gaps)) == 20  # the gap is drawn per seed
    assert bp.world_scene("heavy", 3) == bp.world_scene("heavy", 3)
    assert can(bp.world_scene("heavy", 3)).mass == pytest.approx(4 * can(bp.world_scene("undisturbed", 3)).mass, rel=0.01)
    obstacle = yaml.safe_load(bp.world_scene("obstacle", 3))["objects"]
    assert [o["name"] for o in obstacle] == [bp.CAN, bp.CRATE]
    with pytest.raises(ValueError, match="case 'storm'"):
        bp.world_scene("storm", 0)


def run_of(case: str, mismatches: list[tuple[float, str]], event_t: float | None, outcome: str = "success") -> dict:
    first = min((t for t, _ in mismatches), default=None)
    return {"case": case, "seed": 0, "outcome": outcome, "sim_s": 20.0, "wall_s": 25.0, "event_t": event_t,
            "first_mismatch_t": first, "latency": None if first is None or event_t is None else first - event_t,
            "mismatches": [{"t": t, "since": t, "kind": k, "part": "right", "value": 6.0} for t, k in mismatches],
            "times": [1.0, 2.0], "joint_error": [0.0, 0.01], "object_error": [0.004, 0.012], "predictor_rtf": 3.0}


def test_the_summary_counts_detections_false_alarms_and_latencies_per_case(tmp_path):
    runs = [run_of("undisturbed", [], None), run_of("undisturbed", [(9.0, "force")], None),
            run_of("heavy", [(12.5, "force"), (13.5, "force")], 12.3), run_of("heavy", [], 12.4),
            run_of("slip", [(14.2, "force"), (14.4, "missing_contact")], 14.0, outcome="failure")]
    rows = {r["case"]: r for r in bp.summarize(runs)}
    assert set(rows) == {"undisturbed", "heavy", "slip"}
    assert rows["undisturbed"]["rate"] == 0.5 and rows["undisturbed"]["latency_median"] is None
    assert rows["heavy"]["flagged"] == 1 and rows["heavy"]["first_kinds"] == {"force": 1}
    assert rows["heavy"]["latency_median"] == pytest.approx(0.2)
    assert rows["slip"]["latency_max"] == pytest.approx(0.2) and rows["slip"]["task_success"] == 0
    assert rows["slip"]["object_error_max"] == pytest.approx(0.012) and rows["slip"]["object_within"] == 1
    bp._plot(runs, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 10_000
    json.dumps(rows)  # the JSON summary takes them as they are
