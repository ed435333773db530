"""A robot's predictor on the runtime (thesis ch. 5): its own simulation, fed the robot's commands over the key space, beside the world."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from contactflow.embodiments.layout import CELLS, control_node, run_cell, table_cell, world_node
from contactflow.embodiments.messages import PredictedState, PredictionMismatch
from contactflow.embodiments.tasks import TASKS_DIR
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port
from contactflow.nodes.status import Event
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import decode

ROBOT = "tombatossals"
BELIEF = CELLS / "pick_place.yaml"  # what the robot believes: the can of 0.2 kg where the cell file puts it

pytestmark = pytest.mark.heavy


class Listener:
    """A tool session on the predictor's streams (``predict/<robot>/...``), joined once the world is up."""

    def __init__(self, site: str, endpoint: str) -> None:
        self.states: list[PredictedState] = []
        self.mismatches: list[PredictionMismatch] = []
        self._lock = threading.Lock()
        self.ks = KeySpace(site)
        self.endpoint = endpoint
        self.t = None

    def __call__(self, _world) -> None:
        """``run_cell``'s keep hook: nothing to read from the world (the listener already heard everything)."""

    def open(self) -> None:
        self.t = ZenohTransport(ZenohSettings(connect=(self.endpoint,))).open()
        self.t.subscribe(self.ks.predict(ROBOT, "state"), lambda k, p: self._add(self.states, decode(p, PredictedState, k)))
        self.t.subscribe(self.ks.predict(ROBOT, "mismatch"),
                         lambda k, p: self._add(self.mismatches, decode(p, PredictionMismatch, k)))

    def _add(self, where: list, msg) -> None:
        with self._lock:
            where.append(msg)


def run(tmp_path, site: str, world_scene, task_file=None, task: str = ""):
    """The reference cell's pick and place (or ``task`` of ``task_file``), the robot's predictor believing ``BELIEF``,
    in a world built from ``world_scene``."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    predictor = {"belief": str(BELIEF)}
    if task_file is None:
        _, (control,) = table_cell(site, endpoint, predictor=predictor)
    else:
        control = control_node(site, ROBOT, ROBOT, task_file, task, {}, connect=(endpoint,), autostart=True,
                               contacts=True, predictor=predictor)
    world = world_node(site, world_scene, listen=endpoint, wait_for=(control["node"],), ground_truth_hz=20.0)
    listener = Listener(site, endpoint)
    opener = threading.Timer(0.5, listener.open)  # the world listens once its node started
    opener.start()
    try:
        return run_cell(tmp_path, world, [control], endpoint), listener
    finally:
        opener.cancel()
        if listener.t is not None:
            listener.t.close()


def test_the_predictor_follows_an_undisturbed_pick_and_place_and_reports_no_mismatch(tmp_path):
    """Fig. 5.16: predicted joints within 0.1 rad and the predicted can within 2.5 cm of the world's, all along."""
    cell, heard = run(tmp_path, "pr1", BELIEF)
    assert cell.outcomes[ROBOT].event is Event.SUCCESS, cell.events
    assert not [e for e in cell.events if e[2] == "prediction_mismatch"], cell.events
    assert heard.mismatches == []
    states = heard.states
    assert len(states) > 300 and states[-1].t > cell.outcomes[ROBOT].hdr.t_sim - 0.1  # 20 Hz over the whole run
    assert max(s.joint_error for s in states) < 0.1
    truth = sorted(cell.poses, key=lambda m: m.hdr.t_sim)
    errors, carried = [], False
    for s in states:
        gt = next((m for m in reversed(truth) if m.hdr.t_sim <= s.t + 1e-6), None)
        if gt is None:
            continue
        can = s.poses.numpy()[s.objects.index("cyl")][:3, 3]
        errors.append(float(np.linalg.norm(can - gt.poses.numpy()[gt.names.index("cyl")][:3, 3])))
        carried |= can[2] > 0.88  # the predicted can was lifted with the hand
    assert carried and max(errors) < 0.025, max(errors)
    # the predictor predicted the grasp's contacts on the hand, as fusion sensed them
    assert any(s.contact_hands and set(s.contact_hands) == {"right_hand"} for s in states)


def test_an_object_heavier_than_believed_is_a_surprise_on_which_the_careful_pick_puts_it_back(tmp_path):
    """The world's can weighs 0.8 kg, the robot believes 0.2 kg: the lift feels 6 N more than predicted; the task's
    watch_prediction helper takes the prediction_mismatch edge, and the can is put back on the table."""
    heavy = tmp_path / "heavy.yaml"
    heavy.write_text(BELIEF.read_text().replace("mass: 0.2", "mass: 0.8"))
    cell, heard = run(tmp_path, "pr2", heavy, TASKS_DIR / "careful.yaml", "careful_pick")
    final = cell.outcomes[ROBOT]
    assert final.event is Event.FAILURE, cell.events
    seq = [(m, e) for _, m, e in cell.events]
    assert ("task", "prediction_mismatch") in seq and ("watch_prediction", "prediction_mismatch") in seq, seq
    assert ("lift", "success") not in seq and ("place", "success") in seq and ("release", "success") in seq
    fired = next(t for t, m, e in cell.events if (m, e) == ("watch_prediction", "prediction_mismatch"))
    lifted = next(t for t, m, e in cell.events if (m, e) == ("robust_grasp", "success"))
    force = [m for m in heard.mismatches if m.kind == "force"]
    assert force and force[0].part == "right" and force[0].value > 5.0
    assert fired - lifted < 1.1  # the lift had not gone far: the predictor says it again every second while it lasts
    watched = next(m for m in cell.messages if m.event is Event.PREDICTION_MISMATCH and m.module.endswith("/watch_prediction"))
    assert watched.detail.startswith("force")
    # the predictor's own event carries what differed and when
    msg = next(m for m in cell.messages if m.event is Event.PREDICTION_MISMATCH and m.module.endswith("/predictor"))
    assert "force" in msg.detail and "since" in msg.values
    can = cell.poses[-1].poses.numpy()[cell.poses[-1].names.index("cyl")][:3, 3]
    assert can[2] == pytest.approx(0.81, abs=0.01)  # back on the table, standing
