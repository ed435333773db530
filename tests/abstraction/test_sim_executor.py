"""§7.3 in physics through the sim executor: ATD 1 pushes the box away, ATD 2 picks the target and places it."""

import math
import threading
from pathlib import Path

from contactflow.abstraction.agent import dry_run
from contactflow.abstraction.atd import load_atd
from contactflow.abstraction.estd import received
from contactflow.abstraction.frames import to_world
from contactflow.abstraction.profiles import PROFILES
from contactflow.abstraction.sim_executor import SimExecutor
from contactflow.nodes.status import Event

EXAMPLES = Path(__file__).resolve().parents[2] / "abstraction" / "examples"
ROBOT = "baxter"
PLACE_AT = to_world(load_atd(EXAMPLES / "pick_place_behind.xml"), PROFILES[ROBOT].task_frame).state("put_down").target


def run(sim, name):
    """Dry run, then run what the robot would be sent (the ESTD, checked on arrival)."""
    bid, _ = dry_run(PROFILES[ROBOT], (EXAMPLES / name).read_text(), name)
    assert bid.ok, bid.reasons
    tr = received(bid.estd, PROFILES[ROBOT], name)
    seen = []
    outcome = sim(tr, seen.append, threading.Event(), {})
    return outcome, [p.state for p in seen if str(p.kind) == "entered"]


def test_atd2_picks_the_target_and_places_it_behind_the_pushed_box():
    assert PLACE_AT == (0.55, 0.15, 0.81)  # m, world: beside the box's pushed place, 16.5 cm from the target's start
    sim = SimExecutor(ROBOT)
    outcome, states = run(sim, "push_away.xml")
    assert outcome is Event.SUCCESS, states
    box = sim.robot.ground_truth().object_poses["obstacle_box"][:3, 3]
    assert box[1] < -0.1  # pushed out of the way (it stood at y = 0)
    start = sim.robot.ground_truth().object_poses["target"][:3, 3]
    assert math.dist(start[:2], PLACE_AT[:2]) > 0.15

    outcome, states = run(sim, "pick_place_behind.xml")
    assert outcome is Event.SUCCESS, states
    assert states == ["approach", "preshape_hand", "grasp_object", "lift_object", "carry_behind", "put_down",
                      "let_go", "placed"]
    end = sim.robot.ground_truth().object_poses["target"][:3, 3]
    assert math.dist(end[:2], PLACE_AT[:2]) < 0.05, end  # near its place location (top view)
    assert abs(end[2] - PLACE_AT[2]) < 0.02, end  # standing on the table, not fallen over
