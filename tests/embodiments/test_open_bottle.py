"""Bimanual unscrew on the runtime (thesis §3.4.2, Fig. 3.18): one hand holds a free bottle, the other opens it."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.layout import control_node, run_cell, world_node
from contactflow.embodiments.scene_file import load_scene
from contactflow.embodiments.tasks import TASKS_DIR
from contactflow.nodes.procs import free_port

ROBOT = "tombatossals"


@pytest.mark.heavy(seconds=50)
def test_the_left_hand_holds_the_free_bottle_up_while_the_right_hand_unscrews_its_cap(tmp_path) -> None:
    endpoint, site = f"tcp/127.0.0.1:{free_port()}", f"bottle{free_port()}"
    control = control_node(site, ROBOT, ROBOT, TASKS_DIR / "unscrew.yaml", connect=(endpoint,), autostart=True)
    world = world_node(site, load_scene("open_bottle").file, listen=endpoint, wait_for=(control["node"],),
                       ground_truth_hz=10.0)
    run = run_cell(tmp_path, world, [control], endpoint, timeout=600.0)
    assert run.outcomes[ROBOT].event == "success", run.outcomes[ROBOT]
    ends = {e.module.rsplit("/", 1)[-1]: e for e in run.messages if e.event in ("success", "failure", "error")}
    # both arms ran pooled modules of the same types: the right hand's move went to the right arm, over the cap
    assert ends["move_to"].values["z"] > 1.1 and ends["move_to"].values["y"] < -0.05, ends["move_to"]
    assert "camera kinect" in ends["detect_objects"].detail  # the cap found in a depth frame, not from the scene
    unscrew = ends["unscrew"].values
    assert unscrew["twists"] >= 2 and unscrew["pulled"] >= 0.04, unscrew
    held = [e for e in run.messages if e.module.endswith("/hold")]
    assert [str(e.event) for e in held] == ["grasp_stable"], held  # held with force control, never lost
    poses = [dict(zip(m.names, m.poses.numpy(), strict=True)) for m in run.poses if "bottle" in m.names]
    start, end = poses[0], poses[-1]
    assert start["bottle"][2, 3] == pytest.approx(0.75, abs=0.005)  # it stood on the table
    body, cap = end["bottle"], end["bottle_cap"]
    tilts = [np.degrees(np.arccos(min(1.0, p["bottle"][2, 2]))) for p in poses]
    assert max(tilts) < 10.0, max(tilts)  # never toppled, upright in the left hand to the end
    assert body[2, 3] > 0.78  # held up off the table at the vantage pose
    screwed = start["bottle"][:3, :3].T @ (start["bottle_cap"][:3, 3] - start["bottle"][:3, 3])
    lifted = body[:3, :3].T @ (cap[:3, 3] - body[:3, 3]) - screwed
    assert lifted[2] >= 0.03, lifted  # the cap came off the neck, along the bottle's axis, in the right hand
