"""The robots on the runtime: a world node and control nodes over zenoh, in one process or in several."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from contactflow.embodiments.layout import CELLS, control_node, world_node
from contactflow.embodiments.primitives.base import pose6, top_grasp_pose
from contactflow.embodiments.tasks import TASKS_DIR
from contactflow.nodes.config import load_node_config
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import EventMsg
from contactflow.nodes.node import Node
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for, write_config
from contactflow.nodes.status import Event
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import decode

ROBOT = "tombatossals"
_T = pose6(top_grasp_pose((0.55, -0.12, 0.93)))
PLAN = {"target": [_T[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]}
FINAL = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT, Event.HARDWARE_FAILURE)


class Observer:
    """A tool session recording every module event of a site (what ``contactflow echo`` would show)."""

    def __init__(self, site: str, endpoint: str) -> None:
        self.ks = KeySpace(site)
        self.t = ZenohTransport(ZenohSettings(connect=(endpoint,))).open()
        self.events: list[EventMsg] = []
        self._lock = threading.Lock()
        self._sub = self.t.subscribe(self.ks.events(), self._on)

    def _on(self, key: str, payload: bytes) -> None:
        with self._lock:
            self.events.append(decode(payload, EventMsg, key))

    def outcome(self, module: str) -> EventMsg | None:
        with self._lock:
            return next((e for e in self.events if e.module.endswith(module) and e.event in FINAL), None)

    def sequence(self) -> list[tuple[float, str, str]]:
        """(sim time, module, event) of every event, in simulated-time order."""
        with self._lock:
            return sorted((round(e.hdr.t_sim, 6), e.module.rsplit("/", 1)[-1], str(e.event)) for e in self.events)

    def close(self) -> None:
        self._sub.close()
        self.t.close()


def configs(tmp: Path, site: str, seed: int = 0) -> tuple[Path, Path, str]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    control = f"control_{ROBOT}"
    w = write_config(tmp / "world.yaml", world_node(site, CELLS / "pick_place.yaml", listen=endpoint,
                                                    wait_for=(control,), seed=seed))
    c = write_config(tmp / "control.yaml", control_node(site, ROBOT, ROBOT, TASKS_DIR / "thesis.yaml", "pick_and_place", PLAN,
                                                        connect=(endpoint,), autostart=True))
    return w, c, endpoint


def run_in_one_process(tmp: Path, site: str, timeout: float = 240.0):
    w, c, endpoint = configs(tmp, site)
    world = Node(load_node_config(w))
    world.start()
    obs = Observer(site, endpoint)
    control = Node(load_node_config(c))
    control.start()
    try:
        assert wait_for(lambda: obs.outcome("/task") is not None, timeout), obs.sequence()[-20:]
        wm = world.host.modules[("site", "world")].module
        cyl = wm.robots[ROBOT].sim.ground_truth().object_poses["cyl"][:3, 3].copy()
        return obs.outcome("/task"), obs.sequence(), cyl, wm
    finally:
        control.stop()
        world.stop()
        obs.close()


def test_pick_and_place_runs_over_the_key_space_and_repeats_exactly_in_one_process_and_in_two(tmp_path):
    one, seq_one, cyl, wm = run_in_one_process(tmp_path / "one", "rt1")
    assert one.event is Event.SUCCESS, seq_one
    assert wm.overruns == 0 and wm.robots[ROBOT].refused == 0
    # the can left its place and stands on the table near the place target
    assert cyl[2] == pytest.approx(0.81, abs=0.015)
    assert np.hypot(cyl[0] - 0.55, cyl[1] + 0.3) > 0.1
    visited = {m for _, m, _ in seq_one}
    assert {"detect_objects", "move_to", "robust_grasp", "lift", "transport", "place", "release"} <= visited

    # the same configuration, each node a process of its own
    w, c, endpoint = configs(tmp_path / "two", "rt1")
    procs = [spawn_node(w, tmp_path / "two" / "world.log")]
    obs = Observer("rt1", endpoint)
    procs.append(spawn_node(c, tmp_path / "two" / "control.log"))
    try:
        assert wait_for(lambda: obs.outcome("/task") is not None, 300), (
            (tmp_path / "two" / "control.log").read_text()[-3000:])
        two = obs.outcome("/task")
        seq_two = obs.sequence()
    finally:
        for p in procs:
            stop_process(p)
        obs.close()
    assert two.event is Event.SUCCESS
    assert two.hdr.t_sim == pytest.approx(one.hdr.t_sim, abs=1e-9)
    assert seq_two == seq_one
