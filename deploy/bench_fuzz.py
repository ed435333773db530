"""Benchmark: hostile input against the deployed default manifest (eight node processes on loopback).

Every key the nodes read is sent ``per_key`` payloads (``deploy/fuzz.py``: random bytes,
random MessagePack, and a message seen live on the key with one field made hostile); every
queryable gets as many queries. Measured: node processes that died, modules whose step loop
stopped, the rejects the nodes counted themselves (``rejected`` in module status, ``refused``
in the world's robot states) and the queries answered. Goal: no death, no stalled loop.
"""

from __future__ import annotations

import json
import random
import threading
import time
from collections import defaultdict
from pathlib import Path

import msgpack
import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from contactflow.deploy.demo import QUICK_CAMERA_HZ, ROBOTS, deployment
from contactflow.deploy.fuzz import payloads
from contactflow.deploy.launcher import render, tool_endpoints
from contactflow.embodiments import registry
from contactflow.embodiments.messages import ArmCommand, ArmCommandKind
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import spawn_node, stop_process, wait_for
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import NDArray, encode, stamp

console = Console()
QUERY_WAIT = 10.0  # s a hostile query waits for its answer before it counts as unanswered (an answer is a reply
# at all, not a latency: a node's queryable thread on two cores shared with another deployment took over 0.5 s (CI:
# 4 of 236), and beside two busy processes and a second deployment over 2 s (7 of 252); a node that answers takes
# no longer for it)
RESUME_WAIT = 30.0  # s after the fuzz a module that stepped before it has to be heard stepping again
"""A loop that stopped never steps again; a lockstep node whose world crawls under load steps again late (CI:
the logs of tombatossals' world showed it at ticks 201-202 through a fuzz beside the demo test, and a fixed 4 s wait
took its 14 modules for stalled). The seconds the slowest one took are reported (``resume_s``), with each world's
ticks."""


def _kind(ks: KeySpace, key: str) -> str:
    """The class of a key for the table (``robot/state``, ``m/out``, ``ctl``, ...)."""
    rest = key.removeprefix(ks.prefix + "/").split("/")
    if rest[0] == "m":
        return "m/" + rest[-1] if rest[-2] != "out" else "m/out"
    if rest[0] == "robot":
        return "robot/" + rest[-1]
    if rest[0] == "broker":
        return "broker/" + (rest[-1] if rest[1] == "robots" else rest[1])
    return rest[0]


class _Counters:
    """The nodes' own counts, read from their status and robot states."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.heard = _Counts()  # the last counts heard of each module and robot
        self.since_fuzz: _Counts | None = None  # ... and of those heard since the fuzz ended
        self.samples: dict[str, bytes] = {}

    def on_sample(self, key: str, payload: bytes) -> None:
        with self.lock:
            self.samples.setdefault(key, payload)
        try:
            msg = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        except Exception:  # noqa: BLE001 - our own fuzz traffic is seen here too
            return
        if not isinstance(msg, dict):
            return
        with self.lock:
            for counts in (self.heard, self.since_fuzz):
                if counts is not None:
                    counts.take(msg)

    def fuzz_ended(self) -> None:
        """From now on only the nodes publish counts: what comes is real."""
        with self.lock:
            self.since_fuzz = _Counts()

    def snapshot(self, known: tuple[dict, dict, dict] | None = None) -> tuple[dict[str, int], dict[str, int], dict[str, int]]:
        """The counts per module and robot; with ``known`` (the counts before the fuzz), of those names only.

        Counts as each module or robot said them since the fuzz ended, or as before the fuzz when it said nothing
        since: a forged status (a fuzzed payload on a module's status key) stays the last word of a module that
        publishes nothing meanwhile (a lockstep node whose world crawls), and summed into the rejects it made them
        -9.2e18 (CI); as its steps, it would make a module look stalled or stepping."""
        with self.lock:
            heard = self.heard.dicts()
            fresh = self.since_fuzz.dicts() if self.since_fuzz is not None else ({}, {}, {})
        if known is None:
            return heard
        return tuple({k: now.get(k, v) for k, v in then.items()} for then, now in zip(known, fresh, strict=True))

    def ticks(self) -> dict[str, int]:
        """The last tick each robot's world published a state at; once the fuzz ended, the ticks published since."""
        with self.lock:
            return dict((self.since_fuzz if self.since_fuzz is not None else self.heard).ticks)


class _Counts:
    """Counts by module (rejected, steps) and by robot (refused, tick), from status and robot state maps."""

    def __init__(self) -> None:
        self.rejected: dict[str, int] = {}
        self.steps: dict[str, int] = {}
        self.refused: dict[str, int] = {}
        self.ticks: dict[str, int] = {}

    def take(self, msg: dict) -> None:
        counts = {k: v for k, v in msg.items() if isinstance(v, int) and not isinstance(v, bool)}
        if msg.get("type") == "status" and isinstance(msg.get("module"), str):
            self.rejected[msg["module"]] = counts.get("rejected", 0)
            self.steps[msg["module"]] = counts.get("steps", 0)
        elif msg.get("type") == "robot_state" and isinstance(msg.get("robot"), str):
            self.refused[msg["robot"]] = counts.get("refused", 0)
            self.ticks[msg["robot"]] = counts.get("tick", 0)

    def dicts(self) -> tuple[dict[str, int], dict[str, int], dict[str, int]]:
        return dict(self.rejected), dict(self.steps), dict(self.refused)


def _command(robot: str) -> bytes:
    """A valid command for ``robot``'s first arm (hold where the joints are zero), as a mutation template."""
    spec = registry.get(robot)
    arm = spec.arms[0]
    return encode(stamp(ArmCommand(robot=robot, arm=arm.name, kind=ArmCommandKind.TARGET, seq=1,
                                   values=NDArray.of(np.zeros((2, len(arm.joints))))), "site/fuzz/fuzz/cmd", 1, 0.0))


def run(out: Path, quick: bool = False, per_key: int | None = None) -> dict:
    n = per_key or (10 if quick else 60)
    site = f"fuzz{int(time.time()) % 100000}"
    ks = KeySpace(site)
    # the worlds run while idle: every stream live (the templates) and every loop stepping (what a stall is seen by)
    m = deployment(site, out / "fuzz-config", camera_hz=QUICK_CAMERA_HZ, idle="run")
    launches = render(m, out / "fuzz-config", local=True)
    procs = {ln.node.name: spawn_node(ln.config, out / "fuzz-logs" / f"{ln.node.name}.log") for ln in launches}
    tool = ZenohTransport(ZenohSettings(connect=tuple(tool_endpoints(m, local=True)))).open()
    counters = _Counters()
    sub = tool.subscribe(f"{ks.prefix}/**", counters.on_sample)
    rng = random.Random(7)
    sent: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    t0 = time.time()
    try:
        # every node announced (a busy machine brings the vision nodes up after the robots) and every robot
        up = wait_for(lambda: len(tool.alive(ks.alive_node(), timeout=0.5)) >= len(launches)
                      and len(tool.alive(ks.alive_robot(), timeout=0.5)) >= len(ROBOTS), timeout=120)
        if not up:
            raise RuntimeError(f"the deployment did not come up; see {out / 'fuzz-logs'}")
        time.sleep(1.5)
        _, steps_idle, _ = counters.snapshot()
        time.sleep(3.0)  # live samples of every stream, as templates
        nodes_before = set(tool.alive(ks.alive_node(), timeout=1.0))
        modules = sorted(tool.alive(ks.alive_module(), timeout=1.0))
        before = counters.snapshot()
        rejected0, steps0, refused0 = before
        ticks0 = counters.ticks()
        with counters.lock:
            streams = {k: p for k, p in counters.samples.items() if "/alive/" not in k}
        for r in ROBOTS:  # commands are only sent while a task runs: a valid one is the template
            streams.setdefault(ks.robot(r, "command"), _command(r))
        queries = [ks.dispatch(), *(ks.robot(r, "info") for r in ROBOTS),
                   *(ks.robot_service(r, v) for r in ROBOTS for v in ("caps", "translate", "run", "cancel")),
                   *(ks.control(*k.split("/")[-3:]) for k in modules)]
        pubs = {k: tool.publisher(k) for k in streams}
        with Progress(console=console, transient=True) as bar:
            task = bar.add_task(f"fuzzing {len(streams)} streams and {len(queries)} queryables", total=len(pubs) + len(queries))
            for key, pub in pubs.items():
                for kind, payload in payloads(rng, streams[key] or None, n):
                    pub(payload)
                    sent[_kind(ks, key)][kind] += 1
                    time.sleep(0.001)  # a flood is the messaging bench's; here every payload is read
                bar.advance(task)
            for key in queries:
                for kind, payload in payloads(rng, None, max(2, n // 5)):
                    answered = tool.query(key, payload, timeout=QUERY_WAIT)
                    sent[_kind(ks, key)][kind] += 1
                    sent[_kind(ks, key)]["answered"] += int(bool(answered))
                bar.advance(task)
        counters.fuzz_ended()
        ended = time.time()
        running = {mod for mod, s in steps0.items() if s > steps_idle.get(mod, s)}  # stepping before the fuzz
        time.sleep(4.0)  # the modules report their counts every second while their loops run
        while True:
            rejected1, steps1, refused1 = counters.snapshot(before)
            stalled = sorted(mod for mod in running if steps1.get(mod, 0) <= steps0[mod])
            if not stalled or time.time() - ended >= RESUME_WAIT:
                break
            time.sleep(0.5)
        resume_s = time.time() - ended
        ticks1 = counters.ticks()
        nodes_after = set(tool.alive(ks.alive_node(), timeout=1.0))
        exited = {name: p.poll() for name, p in procs.items() if p.poll() is not None}
    finally:
        sub.close()
        tool.close()
        for p in procs.values():
            stop_process(p)
    result = {
        "per_key": n, "seconds": round(time.time() - t0, 1), "streams": len(streams), "queryables": len(queries),
        "payloads": sum(v for c in sent.values() for k, v in c.items() if k != "answered"),
        "nodes": len(nodes_before), "node_deaths": len(nodes_before - nodes_after) + len(exited), "exited": exited,
        "stalled_modules": stalled, "resume_s": round(resume_s, 1),
        "world_ticks": {r: ticks1.get(r, t) - t for r, t in ticks0.items()},
        "rejected": sum(rejected1.get(k, 0) - rejected0.get(k, 0) for k in rejected1),
        "refused_commands": sum(refused1.get(r, 0) - refused0.get(r, 0) for r in refused1),
        "by_key": {k: dict(v) for k, v in sorted(sent.items())},
    }
    table = Table(title=f"bench fuzz: {result['payloads']} hostile payloads, {n} per stream key")
    for col in ("keys", "bytes", "msgpack", "mutated", "queries answered"):
        table.add_column(col, justify="right" if col != "keys" else "left")
    for k, c in result["by_key"].items():
        table.add_row(k, str(c.get("bytes", 0)), str(c.get("msgpack", 0)), str(c.get("mutated", 0)),
                      str(c.get("answered", "")))
    console.print(table)
    console.print(f"node deaths: {result['node_deaths']} of {result['nodes']} (goal 0); stalled modules: "
                  f"{len(stalled)} (goal 0; every other one stepped again {result['resume_s']:g} s after the fuzz); "
                  f"world ticks from the fuzz's start to then: {result['world_ticks']}; "
                  f"rejects counted by the modules: {result['rejected']}; "
                  f"commands refused by the worlds: {result['refused_commands']}")
    (out / "fuzz.json").write_text(json.dumps(result, indent=2))
    return result
