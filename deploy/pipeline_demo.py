"""A small real deployment: two node processes, a service pipeline across them, live events."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console

from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Command, ControlReply, ControlRequest, EventMsg, Vector
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for, write_config
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import WireError, decode, encode


def pipeline_configs(site: str, port_a: int, port_b: int) -> tuple[dict, dict]:
    """Node A senses and filters; node B scales and watches; the pipeline spans both."""
    zen_a = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port_a}"], "multicast_scouting": False}
    zen_b = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port_b}"], "connect": [f"tcp/127.0.0.1:{port_a}"],
             "multicast_scouting": False}
    a = {"site": site, "node": "sense", "host": "control", "robot": "demo", "zenoh": zen_a, "modules": [
        {"name": "source", "type": "signal_source", "params": {"rate_hz": 50, "frequency": 0.5, "noise": 0.05}},
        {"name": "filter", "type": "lowpass", "inputs": {"in": "source.signal"}, "params": {"cutoff_hz": 3.0}},
    ]}
    b = {"site": site, "node": "watch", "host": "vision3d", "robot": "demo", "zenoh": zen_b, "modules": [
        {"name": "gain", "type": "scale", "inputs": {"in": "filter.out"}, "params": {"gain": 2.0}},
        {"name": "watch", "type": "threshold_watch", "inputs": {"in": "gain.out"},
         "params": {"threshold": 1.5, "timeout": 20.0}},
    ]}
    return a, b


@dataclass
class Recorder:
    events: list[dict] = field(default_factory=list)
    outputs: int = 0
    last_trace: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)


def run(out: Path, quick: bool = False, console: Console | None = None) -> int:
    console = console or Console()
    out.mkdir(parents=True, exist_ok=True)
    site = f"demo{int(time.time()) % 100000}"
    ks = KeySpace(site)
    port_a, port_b = free_port(), free_port()
    cfg_a, cfg_b = pipeline_configs(site, port_a, port_b)
    procs = [spawn_node(write_config(out / "sense.yaml", cfg_a), out / "sense.log"),
             spawn_node(write_config(out / "watch.yaml", cfg_b), out / "watch.log")]
    tool = ZenohTransport(ZenohSettings(connect=(f"tcp/127.0.0.1:{port_a}",))).open()
    rec = Recorder()
    t0 = time.time()

    def on_event(key: str, payload: bytes) -> None:
        try:
            ev = decode(payload, EventMsg, key)
        except WireError as exc:
            console.print(f"[red]{exc}[/]")
            return
        with rec.lock:
            rec.events.append({"t": round(time.time() - t0, 3), "module": ev.module, "event": str(ev.event),
                               "detail": ev.detail})
        console.print(f"[bold magenta]event[/] {ev.module}: [yellow]{ev.event}[/] {ev.detail}")

    def on_output(key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, Vector, key)
        except WireError:
            return
        with rec.lock:
            rec.outputs += 1
            rec.last_trace = [f"{i.source}#{i.seq}" for i in msg.hdr.inputs]

    subs = [tool.subscribe(ks.events("demo"), on_event),
            tool.subscribe(ks.output("demo", "*", "gain", "out"), on_output)]
    code = 1
    try:
        up = wait_for(lambda: len(tool.alive(ks.alive_module("demo"), timeout=0.5)) >= 4, timeout=30)
        console.print(f"[green]2 nodes, {len(tool.alive(ks.alive_module('demo')))} modules up[/]" if up
                      else "[red]nodes did not come up[/]")
        rounds = 1 if quick else 3
        for i in range(rounds):
            req = ControlRequest(cmd=Command.RUN, issuer="demo")
            replies = tool.query(ks.control("demo", "*", "watch"), encode(req))
            ok = bool(replies) and decode(replies[0][1], ControlReply).ok
            console.print(f"round {i + 1}: run watch -> {'ok' if ok else 'refused'}")
            wait_for(lambda n=i: sum(e["event"] == "success" for e in rec.events) > n, timeout=25)
        with rec.lock:
            successes = sum(e["event"] == "success" for e in rec.events)
            console.print(f"pipeline delivered {rec.outputs} traced outputs; last came from {rec.last_trace}")
        code = 0 if successes >= rounds and rec.outputs > 0 else 1
    finally:
        for s in subs:
            s.close()
        tool.close()
        for p in procs:
            stop_process(p)
    summary = {"site": site, "events": rec.events, "outputs": rec.outputs, "trace": rec.last_trace, "ok": code == 0}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return code
