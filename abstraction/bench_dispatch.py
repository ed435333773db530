"""Benchmark: dispatch latency, from an ATD sent to the broker to each robot's first task state, cold and warm.

Two set-ups in one run. ``deployed``: the default manifest's three robots as node processes
(worlds, control nodes with the agents and the broker, vision), as ``contactflow demo`` runs
them; a robot's first state is a primitive module started on its control node against its
world. ``stand-ins``: 50 robot agents (the three embodiments' profiles under new names) in a
few processes, each running the task engine on fake primitives (no physics), with the broker
and the client in sessions of their own. A trial dispatches ATD 1 of §7.3 (push the box away)
``--on all`` and times, per robot, the broker's reply (every robot's dry-run translation and
bid, then the run requests) and the robot's first ``entered`` progress report; then each
robot's task is cancelled and the task's end awaited before the next trial. Cold: the first
dispatch after the robots came up (each bring-up gives one); warm: the next ones.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing as mp
import platform
import statistics
import threading
import time
from pathlib import Path

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from contactflow.abstraction.agent import EXAMPLES
from contactflow.abstraction.client import TaskFollow, close, dispatch
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for
from contactflow.nodes.transport import ZenohSettings, ZenohTransport

ATD = "push_away.xml"
BASES = ("tombatossals", "melfa", "baxter")
GOALS = {"deployed": {"warm_p95_s": 0.2, "cold_max_s": 1.0}, "stand-ins": {"warm_p95_s": 1.0, "cold_max_s": 1.0}}
console = Console()


def _pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(round(q * (len(s) - 1))))]


def trial(tool: ZenohTransport, ks: KeySpace, robots: list[str], timeout: float = 60.0) -> dict:
    """One dispatch ``--on all``: seconds to the broker's reply and to each robot's first state."""
    text = (EXAMPLES / ATD).read_text()
    first: dict[str, float] = {}
    lock = threading.Lock()
    every = threading.Event()

    def on_progress(m) -> None:
        t = time.monotonic()
        with lock:
            if m.kind == "entered" and m.robot in robots and m.robot not in first:
                first[m.robot] = t - t0
                if len(first) == len(robots):
                    every.set()

    t0 = time.monotonic()
    follow: TaskFollow = dispatch(tool, ks, text, ATD, target="all", on_progress=on_progress, timeout=timeout)
    reply_s = time.monotonic() - t0
    try:
        if follow.reply is None or not follow.reply.ok:
            raise RuntimeError(f"not dispatched: {follow.reply.error if follow.reply else 'no reply'}")
        if sorted(follow.reply.robots) != sorted(robots):
            raise RuntimeError(f"dispatched to {follow.reply.robots}, expected {robots}")
        every.wait(timeout)
        for r in robots:  # end the task on every robot before the next trial
            tool.query(ks.robot_service(r, "cancel"), b"", timeout=5.0)
        if not follow.done.wait(timeout):
            raise RuntimeError(f"task {follow.task_id} did not end within {timeout} s of its cancel")
    finally:
        close(follow)
    with lock:
        missing = sorted(set(robots) - set(first))
        if missing:
            raise RuntimeError(f"no first state from {missing} within {timeout} s")
        return {"reply_s": reply_s, "first_state_s": dict(first)}


def _deployed(out: Path, bring_ups: int, warm: int, bar: Progress) -> list[dict]:
    from contactflow.deploy.demo import ROBOTS, deployment
    from contactflow.deploy.launcher import render, tool_endpoints

    rows = []
    task = bar.add_task("deployed: 3 robots", total=bring_ups * (1 + warm))
    for b in range(bring_ups):
        site = f"bdisp{int(time.time()) % 100000}{b}"
        run_dir = (out / "dispatch" / site).resolve()
        m = deployment(site, run_dir / "config")
        launches = render(m, run_dir / "config", local=True)
        procs = [spawn_node(ln.config, run_dir / "logs" / f"{ln.node.name}.log") for ln in launches]
        tool = ZenohTransport(ZenohSettings(connect=tuple(tool_endpoints(m, local=True)))).open()
        ks = KeySpace(site)
        try:
            if not wait_for(lambda t=tool, k=ks: len(t.alive(k.alive_robot(), timeout=0.5)) >= len(ROBOTS), timeout=120):
                raise RuntimeError(f"the default manifest's robots did not come up; logs in {run_dir / 'logs'}")
            for i in range(1 + warm):
                r = trial(tool, ks, list(ROBOTS))
                rows.append({"setup": "deployed", "phase": "cold" if i == 0 else "warm", "bring_up": b, **r})
                bar.advance(task)
        finally:
            tool.close()
            for p in procs:
                stop_process(p)
    return rows


def _standin_main(names: list[str], bases: list[str], endpoint: str, site: str, ready, stop) -> None:
    """A process of stand-in robots: one session, one agent per name, fake primitives."""
    from contactflow.abstraction.agent import RobotAgent
    from contactflow.abstraction.profiles import PROFILES
    from contactflow.abstraction.testing import fake_executor

    t = ZenohTransport(ZenohSettings(connect=(endpoint,))).open()
    ks = KeySpace(site)
    agents = []
    for name, base in zip(names, bases, strict=True):
        p = PROFILES[base]
        profile = dataclasses.replace(p, name=name, factory=p.factory or base)
        # primitives last long enough to be cancelled, paced to the wall clock as a robot would be
        agents.append(RobotAgent(profile, t, ks, fake_executor(duration=5.0, realtime=1.0), node=f"{name}_control"))
    for a in agents:
        a.start()
    ready.put(len(agents))
    stop.get()
    for a in agents:
        a.stop()
    t.close()


def _standins(n: int, procs: int, bring_ups: int, warm: int, bar: Progress) -> list[dict]:
    from contactflow.abstraction.broker import Broker

    rows = []
    task = bar.add_task(f"stand-ins: {n} robots in {procs} processes", total=bring_ups * (1 + warm))
    ctx = mp.get_context("spawn")
    names = [f"standin{i:02d}" for i in range(n)]
    bases = [BASES[i % len(BASES)] for i in range(n)]
    for b in range(bring_ups):
        site = f"bstand{int(time.time()) % 100000}{b}"
        ks = KeySpace(site)
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        hub = ZenohTransport(ZenohSettings(listen=(endpoint,))).open()
        broker = Broker(hub, ks, source=f"{site}/broker/broker")
        broker.start()
        tool = ZenohTransport(ZenohSettings(connect=(endpoint,))).open()
        # a queue, not an Event: setting a multiprocessing Event waits for every process asleep on it to wake,
        # for ever when one died asleep (CI: the bench hung there past the test's timeout)
        ready, stop = ctx.Queue(), ctx.Queue()
        workers = [ctx.Process(target=_standin_main, args=(names[i::procs], bases[i::procs], endpoint, site, ready, stop),
                               daemon=True) for i in range(procs)]
        for w in workers:
            w.start()
        try:
            started = sum(ready.get(timeout=120) for _ in workers)
            if not wait_for(lambda t=tool, k=ks: len(t.alive(k.alive_robot(), timeout=0.5)) >= n, timeout=60):
                raise RuntimeError(f"only {len(tool.alive(ks.alive_robot()))} of {started} stand-ins are seen alive")
            for i in range(1 + warm):
                r = trial(tool, ks, names)
                rows.append({"setup": "stand-ins", "phase": "cold" if i == 0 else "warm", "bring_up": b, **r})
                bar.advance(task)
        finally:
            for _ in workers:
                stop.put(None)
            for w in workers:
                w.join(30)
                if w.is_alive():
                    w.kill()
            broker.stop()
            tool.close()
            hub.close()
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    """p50 / p95 / max per set-up and phase, over every robot's start in every trial."""
    out = []
    for setup in ("deployed", "stand-ins"):
        for phase in ("cold", "warm"):
            sel = [r for r in rows if r["setup"] == setup and r["phase"] == phase]
            if not sel:
                continue
            starts = [s for r in sel for s in r["first_state_s"].values()]
            replies = [r["reply_s"] for r in sel]
            out.append({"setup": setup, "phase": phase, "robots": len(sel[0]["first_state_s"]), "trials": len(sel),
                        "reply_p50_s": statistics.median(replies), "reply_p95_s": _pct(replies, 0.95),
                        "start_p50_s": statistics.median(starts), "start_p95_s": _pct(starts, 0.95),
                        "start_max_s": max(starts)})
    return out


def run(out_dir: Path, quick: bool = False) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    bring_ups, warm = (1, 3) if quick else (3, 10)
    n, procs = (12, 2) if quick else (50, 5)
    with Progress(console=console, transient=True) as bar:
        rows = _deployed(out_dir, bring_ups, warm, bar) + _standins(n, procs, bring_ups, warm, bar)
    summary = summarise(rows)
    table = Table(title=f"Dispatch of {ATD} --on all: seconds to the broker's reply and to each robot's first state")
    for col in ("set-up", "robots", "phase", "trials", "reply p50", "p95", "start p50", "p95", "max", "goal"):
        table.add_column(col, justify="right")
    for s in summary:
        g = GOALS[s["setup"]]
        goal = f"p95 < {g['warm_p95_s']:g}" if s["phase"] == "warm" else f"max < {g['cold_max_s']:g}"
        table.add_row(s["setup"], str(s["robots"]), s["phase"], str(s["trials"]),
                      *(f"{s[k]:.3f}" for k in ("reply_p50_s", "reply_p95_s", "start_p50_s", "start_p95_s", "start_max_s")),
                      goal)
    console.print(table)
    result = {"benchmark": "dispatch", "quick": quick, "atd": ATD, "goals": GOALS,
              "machine": {"python": platform.python_version(), "cpus": mp.cpu_count()},
              "summary": summary, "trials": rows}
    (out_dir / "dispatch.json").write_text(json.dumps(result, indent=2))
    return result
