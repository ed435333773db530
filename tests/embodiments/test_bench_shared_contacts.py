"""Smoke run of the shared-contacts benchmark: a robot takes objects from the cell's map of another robot's touches."""

from __future__ import annotations

import json

import pytest

from contactflow.embodiments import bench_shared_contacts as bench
from contactflow.nodes.params import ParamError


@pytest.mark.heavy(seconds=135)
def test_the_taker_empties_the_box_from_the_cell_map_of_the_explorers_touches_and_alone_from_its_own(tmp_path) -> None:
    # one object, each variant in a worker process of its own: melfa pokes the box and tombatossals takes from the
    # cell's map; tombatossals pokes the box itself and takes from the map its own touches made
    summary = bench.run(tmp_path, quick=True, jobs=2)
    runs = {r["variant"]: r for r in summary["runs"]}
    assert set(runs) == set(bench.VARIANTS) and all(r["seed"] == 100 for r in runs.values())
    for r in runs.values():
        assert r["success"] and r["left"] == 0, r  # taken out of the box by the map's approach
        assert 1 <= r["attempts"] <= 2, r
        assert sum(r["outcomes"].values()) == r["attempts"], r  # each attempt's end, told by the taker's progress
        assert r["map"]["localised"] == 1 and r["map"]["error"] <= bench.LOCALISED, r["map"]
    mapped, alone = runs["with_map"], runs["alone"]
    assert mapped["explored"] > 30.0 and alone["explored"] == 0.0  # melfa explored before tombatossals began
    assert mapped["time"] < alone["time"] - 20.0  # the taker did not explore: its own pokes take longer than that
    saved = json.loads((tmp_path / "shared_contacts.json").read_text())
    assert saved["benchmark"] == "shared_contacts" and [r["variant"] for r in saved["rows"]] == list(bench.VARIANTS)
    assert (tmp_path / "shared_contacts.png").stat().st_size > 0


def test_the_poke_grid_keeps_each_hand_inside_the_box_and_the_map_region_is_inside_its_walls(tmp_path) -> None:
    cx, cy = bench.box.BOX_CENTER
    for robot, arm in ((bench.EXPLORER, bench.EXPLORER_ARM), (bench.TAKER, bench.box.ARM)):
        plan = bench.poke_plan(robot, arm)
        xs, ys = plan["spots"][0::2], plan["spots"][1::2]
        assert abs(max(xs) - cx) < bench.box.INNER[0] / 2 and abs(min(ys) - cy) < bench.box.INNER[1] / 2
        assert plan["floor"] < plan["height"] and max(abs(x - y) for x, y in zip(xs, xs[1:], strict=False)) <= bench.PITCH + 1e-9
        coarse = bench.poke_plan(robot, arm, pitch=bench.QUICK_PITCH)["spots"]  # a quick run's: fewer, as far out
        assert len(coarse) < len(plan["spots"]) and max(coarse[0::2]) == pytest.approx(max(xs))
        assert max(abs(x - y) for x, y in zip(coarse[0::2], coarse[2::2], strict=False)) <= bench.QUICK_PITCH + 1e-9
    x0, y0, z0, x1, y1, z1 = bench.map_region()
    assert x1 - x0 < bench.box.INNER[0] and y1 - y0 < bench.box.INNER[1] and z0 > bench.box.BOTTOM
    got = bench.localisation([(1, cx, cy, 0.8)], {"cube": [cx + 0.01, cy, 0.78], "ball": [cx + 0.2, cy, 0.78]})
    assert got["nearest"] == pytest.approx({"cube": 0.01, "ball": 0.2})
    assert (got["estimates"], got["localised"], got["objects"], got["spurious"]) == (1, 1, 2, 0)
    assert got["error"] == pytest.approx(0.01)
    with pytest.raises(ParamError, match="--objects 7 is not 1 to 6"):
        bench.run(tmp_path, objects=7)
