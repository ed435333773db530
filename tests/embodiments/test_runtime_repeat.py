"""Runs on the runtime that must repeat exactly whatever the process layout or the wall clock: lockstep, the
marks and the idle pause make them repeat beside the suite's other worker as they do alone."""

from __future__ import annotations

import pytest

from contactflow.embodiments.layout import run_cell, table_cell
from contactflow.nodes.procs import free_port
from contactflow.nodes.status import Event

ROBOT = "tombatossals"
pytestmark = pytest.mark.heavy(seconds=70)


def test_world_control_and_vision_pick_and_place_what_the_vision_node_segmented_and_repeat_in_three_processes(tmp_path):
    from contactflow.embodiments.layout import vision_cell

    runs = []
    for processes in (False, True):
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        world, control, vision = vision_cell("rtv", endpoint)
        runs.append(run_cell(tmp_path / str(processes), world, [control], endpoint, processes=processes,
                             services=(vision,), timeout=180))
    one, three = runs
    assert three.outcomes[ROBOT].event is Event.SUCCESS, three.events
    detected = [e for e in three.messages if e.event is Event.OBJECT_DETECTED]
    assert len(detected) == 1, [(e.module, e.event, e.detail) for e in three.messages]
    (detected,) = detected
    # the objects came from the vision node, cut from a frame of the world's depth stream; no frame of its own
    assert "vision chain, depth frame site/world/world/tombatossals/depth#" in detected.detail, detected.detail
    assert (detected.values["cx"], detected.values["cy"]) == pytest.approx((0.55, -0.3), abs=0.025)  # the can (r 3 cm)
    assert (detected.values["tx"], detected.values["ty"]) == pytest.approx((0.55, -0.3), abs=0.01)  # its top, seen whole
    visited = {m for _, m, _ in three.events}
    assert {"robust_grasp", "lift", "transport", "place", "release"} <= visited
    # the vision node in lockstep: the same detection of the same depth frame at the same tick in one process and
    # in three, and the same events at the same simulated times; the detection repeats to a micrometre, not always
    # to the last bit (a full-suite run differed by 2e-8 m)
    (first,) = [e for e in one.messages if e.event is Event.OBJECT_DETECTED]
    assert first.detail == detected.detail and first.hdr.t_sim == detected.hdr.t_sim
    assert first.values == pytest.approx(detected.values, abs=1e-6)
    assert one.events == three.events


def _idle_world_run(tmp_path, site: str, delay: float) -> dict:
    """A paused-when-idle world and its control node; ``move_to`` run by hand ``delay`` s of wall time after the
    world went idle; what the world did meanwhile and when the move ended."""
    import time

    from contactflow.embodiments.layout import SiteWatch
    from contactflow.nodes.config import load_node_config
    from contactflow.nodes.messages import Command
    from contactflow.nodes.node import Node
    from contactflow.nodes.procs import wait_for, write_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    world, (control,) = table_cell(site, endpoint)
    world["modules"][0]["params"]["idle"] = "pause"
    control["modules"][-1]["autostart"] = False  # no task: the node is idle until a primitive is run by hand
    nodes = [Node(load_node_config(write_config(tmp_path / f"{site}_{c['node']}.yaml", c))) for c in (world, control)]
    for n in nodes:
        n.start()
    watch = SiteWatch(site, endpoint)
    wm = nodes[0].host.modules[("site", "world")].module
    try:
        assert wait_for(lambda: wm.paused, 60)
        paused_at = wm.tick_no
        assert wm.status_detail().startswith(f"paused at tick {paused_at} ")  # what `contactflow ls` shows
        time.sleep(delay)
        idle_ticks = wm.tick_no - paused_at
        far = [0.4, -0.4, 1.1, 3.14159, 0.0, 0.0]
        assert nodes[1].host.send_control(f"{ROBOT}/move_to", Command.RUN, {"target": far, "arm": "right"}).ok
        assert wait_for(lambda: watch.outcome("move_to") is not None, 120)
        assert wait_for(lambda: wm.paused, 10)  # idle again once the move ended
        end = wm.tick_no
        time.sleep(0.3)
        return {"paused_at": paused_at, "idle_ticks": idle_ticks, "outcome": watch.outcome("move_to"),
                "end": end, "after_end": wm.tick_no - end, "pauses": wm.pauses}
    finally:
        watch.close()
        for n in reversed(nodes):
            n.stop()


def test_an_idle_world_pauses_and_a_primitive_run_at_any_wall_clock_moment_repeats_to_the_tick(tmp_path):
    early = _idle_world_run(tmp_path, "rti1", 0.1)
    late = _idle_world_run(tmp_path, "rti2", 1.5)
    for run in (early, late):
        # no tick while the node was idle, before the move or after it; paused twice
        assert run["idle_ticks"] == 0 and run["after_end"] == 0 and run["pauses"] == 2, run
        assert run["outcome"].event is Event.SUCCESS, run["outcome"]
    # the world waited at the same tick, and the move ran the same ticks, however long the wait was
    assert early["paused_at"] == late["paused_at"] and early["end"] == late["end"]
    assert early["outcome"].hdr.t_sim == late["outcome"].hdr.t_sim
    assert early["outcome"].values == late["outcome"].values
