"""Smoke tests of the fusion benchmarks in their quick form."""

import json

import pytest

from contactflow.fusion import bench_contacts, bench_fusion


def test_bench_fusion_quick(tmp_path):
    s = bench_fusion.run(tmp_path, quick=True)
    assert json.loads((tmp_path / "fusion.json").read_text())["benchmark"] == "fusion"
    assert all(r["same_voxels"] and r["max_abs_diff"] < 1e-9 for r in s["results"])
    assert s["static_3x10k_hz"] > 0 and all(r["integrator_mean_hz"] > 0 for r in s["results"])


def test_bench_contacts_quick(tmp_path):
    s = bench_contacts.run(tmp_path, quick=True, rig="melfa")
    assert (tmp_path / "contacts.md").exists() and (tmp_path / "contacts_melfa.png").exists()
    melfa = s["rigs"]["melfa"]
    assert melfa["touches"] == 3
    touched = melfa["touches"] - melfa["missed_touches"]
    assert touched >= 2
    assert melfa["modalities"]["all"]["detected"] >= 1  # the fused modalities find a touch


def test_the_thesis_s_allegro_hand_touches_the_fixed_box_from_above_and_the_touch_is_fused():
    import numpy as np
    from rich.progress import Progress

    from contactflow.fusion.condensation import CondensationParams

    rig = bench_contacts.RIGS["tombatossals"]
    (d,) = bench_contacts.directions(1, rig.elevations[:1])  # straight ahead, 35 degrees down
    with Progress(transient=True) as progress:
        (touch,) = bench_contacts.run_object("box", bench_contacts.object_specs(rig)["box"], rig, [d],
                                             np.random.default_rng(0), progress, progress.add_task("touch", total=1))
    # the palm meets the fixed box (no finger passes through it): a true contact, and the wrist felt it
    assert touch.truth is not None and len(touch.clouds["force"]) > 0
    rows = bench_contacts.evaluate([touch], CondensationParams())
    # within the 2 cm: the palm's model is slabs hugging its plate (one ball around it: 5.2 cm off, range blind)
    assert rows["all"]["detected"] == rows["force"]["detected"] == rows["range"]["detected"] == 1
    assert 0.0 < rows["force"]["eps_cm"] < 2.0 and 0.0 < rows["all"]["eps_cm"] < 2.0


def test_on_the_runtime_a_planned_rig_plans_its_moves_to_the_start_around_the_object_it_sees():
    import numpy as np

    dirs = bench_contacts.directions(3, (35.0,))
    home, centre = np.eye(4), np.array([0.55, -0.3, 0.82])
    for name, planned in (("tombatossals", True), ("melfa", False)):
        rig = bench_contacts.RIGS[name]
        nodes = bench_contacts.touch_task(rig, home, centre, dirs)["tasks"]["touches"]["nodes"]
        approach = [nodes[f"approach_{i}"] for i in range(len(dirs))]
        assert all(n["params"].get("planning", True) is planned for n in approach)
        assert all(n["params"].get("sense_obstacles", False) is planned for n in approach)
        assert all(nodes[f"home_{i}"]["params"].get("planning", True) is planned for i in range(len(dirs)))
        assert all(nodes[f"back_{i}"]["params"]["planning"] is False for i in range(len(dirs)))  # straight back
        for i, d in enumerate(dirs):  # the start, as in process: 13 cm before the centre, the palm facing d if the rig says
            start = bench_contacts.start_pose(rig, home, centre, d)
            assert approach[i]["params"]["target"][:3] == pytest.approx(list(centre - 0.13 * d))
            assert approach[i]["params"]["target"] == pytest.approx(bench_contacts._target(start))  # and its turn
            if rig.facing:
                assert np.allclose(start[:3, 2], d) and start[2, 1] > 0  # the palm along d, the thumb side up
            else:
                assert np.allclose(start[:3, :3], home[:3, :3])


def test_bench_contacts_runtime_fuses_every_generator_of_the_world_and_judges_them_by_its_true_contacts(tmp_path):
    import math

    s = bench_contacts.run(tmp_path, quick=True, rig="melfa", executor="runtime")
    rt = json.loads((tmp_path / "contacts.json").read_text())["rigs"]["melfa"]["runtime"]
    assert rt["touches"] == 3 and rt["touches"] - rt["missed_touches"] >= 2  # the world's eval/ stream saw the hand touch
    rows = rt["modalities"]
    # the wrist F/T cues of the world's robot state, fused by the fusion node, find the touches within centimetres
    force = rows["force"]
    assert force["detected"] >= 2, rt["per_touch"]
    assert math.isfinite(force["eps_cm"]) and 0.0 < force["eps_cm"] < 5.0 and force["sigma_cm"] > 0.0
    assert rows["tactile + force"]["detected"] >= force["detected"]
    # every generator of the local bench runs on the runtime: the range generator on the vision node reads the
    # world's fixed head camera, the simulator support generator the predictor's hand contacts
    (feeds,) = rt["feeds"].values()
    clouds = feeds["clouds"]
    assert set(clouds) == {"tactile_arm", "force_torque_arm", "range", "simulator"}, clouds
    assert all(n > 0 for n, _ in clouds.values()) and clouds["force_torque_arm"][1] > 0
    assert clouds["range"][1] > 0 and clouds["simulator"][1] > 0  # the camera saw the touch, the predictor too
    assert rows["range"]["detected"] >= 1 and rows["range"]["eps_cm"] < 10.0, rt["per_touch"]
    assert rows["all"]["detected"] >= force["detected"] and rows["all + simulator"]["detected"] >= force["detected"]
    # Algorithm 4.1 waits for every plugged source: with the 10 Hz camera among them a fusion cycles at its pace
    cycles = feeds["cycles_per_s"]
    assert cycles["range"] == pytest.approx(bench_contacts.CAMERA_HZ, rel=0.2)
    assert cycles["tactile"] > 150 and cycles["all"] < 2 * bench_contacts.CAMERA_HZ, cycles
    assert "missing" not in (tmp_path / "contacts.md").read_text()
    assert s["executor"] == "runtime" and "modalities" not in s["rigs"]["melfa"]  # no local figures were computed


def test_bench_contacts_refuses_an_unknown_executor_or_rig(tmp_path):
    from contactflow.nodes.params import ParamError

    with pytest.raises(ParamError, match="--executor 'sim' is not one of"):
        bench_contacts.run(tmp_path, quick=True, executor="sim")
    with pytest.raises(ParamError, match="--rig 'ur5' is not one of"):
        bench_contacts.run(tmp_path, quick=True, rig="ur5")
