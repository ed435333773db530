"""The runtime's share of ``contactflow bench sim``: the full stack's pace, and the command -> sensor round trip.

1. Real-time factor (simulated s per wall s, from tick 1 to the last task's end) of the
   whole runtime in lockstep: a world node and control nodes running their tasks over zenoh
   (tombatossals' pick and place; with two robots, melfa's tap at the same table, one cell).
   Each layout is run with every node in one process (a session each) and with each node a
   process of its own, side by side; every run starts in a fresh process. Lockstep makes the two
   layouts one run: the bench says whether they gave the same events at the same simulated times.
   Each cell runs with the plain lockstep and with the world's pipeline (it steps tick k+1 while
   its nodes step tick k, so world and nodes use both cores).
2. Command -> sensor round trip over loopback: a controller session in lockstep with a world
   node in another process receives tick k's state, sends an arm command, answers the tick,
   and waits for the state that shows the command applied (one physics tick in between).
"""

from __future__ import annotations

import hashlib
import multiprocessing as mp
import shutil
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

LAYOUTS = (("1 robot, pipelined", False, True), ("1 robot", False, False), ("2 robots, one cell", True, False),
           ("2 robots, one cell, pipelined", True, True))
"""(label, melfa too, the world's pipeline): the quick bench runs the first only."""


def _cell_job(args: tuple[bool, bool, str, bool]) -> dict:
    """One run of the reference cell; in-process layouts run here, in a fresh worker process."""
    from contactflow.embodiments.layout import run_cell, table_cell
    from contactflow.nodes.procs import free_port
    from contactflow.nodes.status import Event

    melfa, processes, folder, pipeline = args
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    site = f"bench{free_port()}"
    run = run_cell(Path(folder), *table_cell(site, endpoint, melfa=melfa, pipeline=pipeline), endpoint,
                   processes=processes)
    last = run.poses[-1] if run.poses else None
    return {"rtf": run.rtf, "sim_s": run.sim_s, "wall_s": run.wall_s,
            "outcomes": {r: str(e.event) for r, e in run.outcomes.items()},
            # what says the layouts ran the same run: the event sequence (simulated time, module, event), hashed
            "events": len(run.events), "trace": hashlib.sha1(repr(run.events).encode()).hexdigest()[:16],
            "visited": sorted({m for _, m, _ in run.events}),
            "overruns": sum(m.event is Event.OVERRUN for m in run.messages),
            # where a tick goes: each module's CPU per tick (ms) as its status says, over the wire in either layout
            "cpu_ms_per_tick": run.cpu_per_tick(),
            "objects": {n: [round(float(v), 4) for v in T[:3, 3]] for n, T in zip(last.names, last.poses.numpy(),
                                                                                   strict=True)} if last else {}}


def rtf_runs(folder: Path, advance=lambda: None, layouts=LAYOUTS) -> dict:
    ctx = mp.get_context("spawn")
    out: dict = {}
    for label, melfa, pipeline in layouts:
        row = {}
        slug = label.replace(",", "").replace(" ", "_")
        for layout, processes in (("one_process", False), ("split", True)):
            with ctx.Pool(1) as pool:
                row[layout] = pool.apply(_cell_job, ((melfa, processes, str(folder / f"{slug}_{layout}"), pipeline),))
            advance()
        row["split_vs_one"] = row["split"]["rtf"] / row["one_process"]["rtf"] if row["one_process"]["rtf"] else 0.0
        row["repeated"] = (row["split"]["trace"], row["split"]["sim_s"]) == (row["one_process"]["trace"],
                                                                              row["one_process"]["sim_s"])
        out[label] = row
    return out


def round_trip(ticks: int, folder: Path) -> dict:
    """Round trip of ``ticks`` commands over loopback (a world process, this process as its controller)."""
    from contactflow.embodiments.layout import CELLS, world_node
    from contactflow.embodiments.messages import ArmCommand, ArmCommandKind, RobotState
    from contactflow.nodes.keys import KeySpace
    from contactflow.nodes.messages import LockstepAck
    from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for, write_config
    from contactflow.nodes.transport import ZenohSettings, ZenohTransport
    from contactflow.nodes.wire import NDArray, decode, encode

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    site = f"rtt{free_port()}"
    ks = KeySpace(site)
    world = spawn_node(write_config(folder / "rtt_world.yaml", world_node(site, CELLS / "pick_place.yaml", listen=endpoint,
                                                                          wait_for=("rtt",))), folder / "rtt_world.log")
    t = ZenohTransport(ZenohSettings(connect=(endpoint,))).open()
    cond = threading.Condition()
    latest: list[tuple[RobotState, float]] = []

    def on_state(key: str, payload: bytes) -> None:
        msg = decode(payload, RobotState, key)
        with cond:
            latest.append((msg, time.perf_counter()))
            cond.notify_all()

    handles = [t.subscribe(ks.robot("tombatossals", "state"), on_state), t.token(ks.alive_lockstep("rtt")),
               t.token(ks.alive_controller("tombatossals", "rtt"))]
    cmd = t.publisher(ks.robot("tombatossals", "command"))
    ack = t.publisher(ks.lockstep("rtt"))
    samples: list[float] = []
    try:
        if not wait_for(lambda: bool(latest), 60):
            raise TimeoutError(f"no world state: {(folder / 'rtt_world.log').read_text()[-2000:]}")
        for seq in range(1, ticks + 1):
            with cond:
                state, _ = latest[-1]
                latest.clear()
            arm = state.arms[1] if len(state.arms) > 1 else state.arms[0]
            q = arm.q_cmd.numpy()
            sent = time.perf_counter()
            cmd(encode(ArmCommand(robot="tombatossals", arm=arm.name, kind=ArmCommandKind.TARGET, seq=seq,
                                  values=NDArray.of(np.stack([q, np.zeros_like(q)])))))
            ack(encode(LockstepAck(node="rtt", tick=state.tick)))
            k = [a.name for a in state.arms].index(arm.name)

            def applied(n: int = seq, k: int = k) -> float | None:
                return next((r for s, r in latest if s.arms[k].applied >= n), None)

            with cond:
                if not cond.wait_for(lambda: applied() is not None, 5.0):
                    raise TimeoutError(f"tick {state.tick}: the command never came back applied")
                samples.append(applied() - sent)
    finally:
        for h in handles:
            h.close()
        t.close()
        stop_process(world)
    ms = 1000.0 * np.asarray(samples[10:])  # the first ticks warm the caches
    return {"ticks": len(ms), "p50_ms": float(np.percentile(ms, 50)), "p99_ms": float(np.percentile(ms, 99)),
            "max_ms": float(ms.max())}


def run(quick: bool = False, advance=lambda: None, out_dir: Path | None = None) -> dict:
    """Both measures; ``quick`` runs the one-robot layouts only and fewer round trips. The node logs of a
    layout pair that did not give the same events are kept in ``out_dir``/runtime_logs."""
    with tempfile.TemporaryDirectory(prefix="cf-bench-runtime-") as tmp:
        folder = Path(tmp)
        rtf = rtf_runs(folder, advance, LAYOUTS[:1] if quick else LAYOUTS)
        if out_dir is not None and not all(row["repeated"] for row in rtf.values()):
            shutil.copytree(folder, out_dir / "runtime_logs", dirs_exist_ok=True,
                            ignore=lambda d, names: [n for n in names if not (Path(d, n).is_dir() or n.endswith(".log"))])
        return {"rtf": rtf, "round_trip": round_trip(100 if quick else 2000, folder)}


def steps(quick: bool) -> int:
    """Progress steps of :func:`run` (one per cell run)."""
    return 2 * (1 if quick else len(LAYOUTS))
