"""Benchmark: bring-up time of the default manifest on this machine, and the latency of fused
contact events between network namespaces against loopback in the same run.

Bring-up counts a module once its liveliness token is up, which it declares after its
``setup`` ran. The latency source is a tactile pad pressed and released every 0.1 s (200 readings/s), read by
the real tactile hypotheses generator and fused by the contact fusion service on one host; an
observer on another host follows each contact event's ``inputs`` back to the hypothesis cloud
and the tactile reading it came from: cue latency is the event's arrival minus the reading's
stamp (generator, fusion and the network), transport latency its arrival minus its own stamp.
"""

from __future__ import annotations

import dataclasses
import json
import statistics
import threading
import time
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from contactflow.deploy.launcher import render, tool_endpoints
from contactflow.deploy.manifest import DEFAULT_MANIFEST, Manifest, load_manifest, on_loopback
from contactflow.deploy.netns import NetLab, NetnsUnavailable
from contactflow.deploy.security import write_json5, zenoh_config
from contactflow.deploy.supervisor import Supervisor
from contactflow.deploy.testing import TAP_PAD, LabDeployment, ProbeClient, lab_manifest
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port_block
from contactflow.nodes.transport import ZenohSettings, ZenohTransport

console = Console()
PROBE_MESSAGES = ("contactflow.fusion.messages", "contactflow.embodiments.messages")  # clouds, events, tactile readings


def bring_up_once(m: Manifest, run_dir: Path, timeout: float = 120.0) -> dict[str, float]:
    """Start every node locally under a supervisor; seconds until all nodes / modules are alive."""
    m = dataclasses.replace(on_loopback(m), topology=dataclasses.replace(m.topology, port=free_port_block(len(m.nodes()) + 1)))
    ks = KeySpace(m.site)
    n_nodes = len(m.nodes())
    n_modules = sum(len(n.modules) for n in m.nodes())
    # the observer retries its connections every 0.1 s so that it adds at most that to the time
    cfg = zenoh_config(m, m.nodes()[0])
    cfg["connect"]["retry"] = {"period_init_ms": 100, "period_max_ms": 100, "period_increase_factor": 1}
    zfile = write_json5(run_dir / "observer.json5", cfg)
    obs = ZenohTransport(ZenohSettings(connect=tuple(tool_endpoints(m, local=True)), config_file=str(zfile))).open()
    nodes: set[str] = set()
    modules: set[str] = set()
    lock = threading.Lock()
    done = threading.Event()
    marks: dict[str, float] = {}

    def on(kind: set[str], total: int, label: str):
        def cb(key: str, up: bool) -> None:
            with lock:
                (kind.add if up else kind.discard)(key)
                if len(kind) >= total and label not in marks:
                    marks[label] = time.monotonic()
                if len(marks) == 2:
                    done.set()
        return cb

    handles = [obs.watch_alive(ks.alive_node(), on(nodes, n_nodes, "nodes")),
               obs.watch_alive(ks.alive_module(), on(modules, n_modules, "modules"))]
    stop = threading.Event()
    t0 = time.monotonic()
    sup = Supervisor(render(m, run_dir, local=True), run_dir / "local", str(m.file))
    sup.start()
    runner = threading.Thread(target=sup.run, args=(stop,), daemon=True)
    runner.start()
    try:
        done.wait(timeout)
    finally:
        t_stop = time.monotonic()
        stop.set()
        runner.join(30)
        stopped = time.monotonic() - t_stop
        for h in handles:
            h.close()
        obs.close()
    if len(marks) < 2:
        raise RuntimeError(f"default manifest not healthy within {timeout} s: {len(nodes)}/{n_nodes} nodes, "
                           f"{len(modules)}/{n_modules} modules alive")
    return {"nodes_alive_s": marks["nodes"] - t0, "modules_alive_s": marks["modules"] - t0, "stop_s": stopped,
            "nodes": n_nodes, "modules": n_modules}


def _stats(lat: list[float]) -> dict[str, float]:
    if not lat:
        return {"n": 0}
    lat = sorted(lat)
    return {"n": len(lat), "p50_ms": statistics.median(lat), "p99_ms": lat[min(len(lat) - 1, int(0.99 * len(lat)))],
            "mean_ms": statistics.fmean(lat), "max_ms": lat[-1]}


def _latency(events: list[dict[str, Any]], clouds: list[dict[str, Any]], readings: list[dict[str, Any]]) -> dict[str, Any]:
    """Cue latency (event arrival - the stamp of the newest tactile reading it came from, through its
    clouds) and transport latency (event arrival - its own stamp), ms."""
    if not events:
        return {"n": 0}
    by_id = {f"{m['source']}#{m['seq']}": m for m in clouds + readings if "source" in m}
    cue, transport, untraced = [], [], 0
    for e in events:
        transport.append((e["recv"] - e["t_wall"]) * 1e3)
        stamps = [by_id[r]["t_wall"] for c in e.get("inputs", []) if c in by_id
                  for r in by_id[c].get("inputs", []) if r in by_id and by_id[r]["type"] == "tactile_array"]
        if stamps:
            cue.append((e["recv"] - max(stamps)) * 1e3)
        else:
            untraced += 1
    return {**_stats(cue), "untraced": untraced, "transport": _stats(transport)}


SOURCE = "bench"
HOSTS = {"src": {"nodes": {"tactile": {"robot": SOURCE, "modules": [
    {"name": "pad", "type": TAP_PAD, "params": {"robot": SOURCE, "rate_hz": 200, "press_s": 0.05, "release_s": 0.05}},
    {"name": "tactile", "type": "tactile_hypotheses", "inputs": {"tactile": "pad.tactile", "taxels": "pad.taxels"},
     "params": {"robot": SOURCE, "rate_hz": 200}},
    {"name": "fusion", "type": "contact_fusion",
     "params": {"robot": SOURCE, "sources": f"{SOURCE}/*", "rate_hz": 200, "timeout": 0.03, "hold": 0.02}}]}}},
    "obs": {}}


def _collect(probe: ProbeClient, site: str, n: int, timeout: float) -> dict[str, Any]:
    ks = KeySpace(site)
    ids = {"events": probe.send("sub", key=ks.fused(SOURCE, "events")),
           "clouds": probe.send("sub", key=ks.hypotheses(SOURCE, "*")),
           "readings": probe.send("sub", key=ks.output(SOURCE, "*", "pad", "tactile"))}
    end = time.monotonic() + timeout
    while time.monotonic() < end and probe.count(ids["events"]) < n + 4:
        time.sleep(0.05)
    got = {k: probe.events(i) for k, i in ids.items()}
    return _latency(got["events"][4:], got["clouds"], got["readings"])  # the first events include connection set-up


def latency_loopback(tmp: Path, n: int) -> dict[str, float]:
    port = free_port_block(3)
    doc = {"site": "benchlo", "zenoh": {"port": port},
           "hosts": {h: {"address": "127.0.0.1", **spec} for h, spec in HOSTS.items()}}
    (tmp / "lo.yaml").write_text(yaml.safe_dump(doc))
    m = load_manifest(tmp / "lo.yaml")
    stop = threading.Event()
    sup = Supervisor(render(m, tmp / "lo-run", local=True), tmp / "lo-run" / "local", str(m.file))
    sup.start()
    runner = threading.Thread(target=sup.run, args=(stop,), daemon=True)
    runner.start()
    probe = ProbeClient([], tool_endpoints(m, local=True), name="obs", messages=PROBE_MESSAGES)
    try:
        return _collect(probe, m.site, n, 60 + n / 10)
    finally:
        probe.close()
        stop.set()
        runner.join(30)


def latency_netns(tmp: Path, n: int) -> dict[str, float]:
    lab = NetLab(["src", "obs"]).open()
    dep = None
    probe = None
    try:
        # plain tcp, as the loopback run it is compared with (the lab's namespaces are isolated)
        m = lab_manifest(tmp / "ns.yaml", lab, HOSTS, site="benchns", security={"transport": "tcp", "insecure": True})
        (tmp / "ns-run").mkdir(exist_ok=True)
        dep = LabDeployment(lab, m, tmp / "ns-run")
        dep.up("src")
        probe = ProbeClient(lab.wrap("obs", []), tool_endpoints(m, local=False), name="obs", messages=PROBE_MESSAGES)
        return _collect(probe, m.site, n, 60 + n / 10)
    finally:
        if probe is not None:
            probe.close()
        if dep is not None:
            dep.down()
        lab.close()


def run(out_dir: Path, quick: bool = False) -> dict:
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = out_dir / "deploy-work"
    tmp.mkdir(exist_ok=True)
    m = load_manifest(DEFAULT_MANIFEST)
    repeats = 1 if quick else 3
    n_events = 100 if quick else 500
    summary: dict[str, Any] = {"manifest": str(DEFAULT_MANIFEST), "repeats": repeats, "events": n_events}
    bring: list[dict[str, float]] = []
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("deploy benchmark", total=repeats + 2)
        for i in range(repeats):
            progress.update(task, description=f"bring-up {i + 1}/{repeats}")
            bring.append(bring_up_once(m, tmp / f"up{i}"))
            progress.advance(task)
        progress.update(task, description="latency: loopback")
        summary["latency_loopback"] = latency_loopback(tmp, n_events)
        progress.advance(task)
        progress.update(task, description="latency: namespaces")
        try:
            summary["latency_netns"] = latency_netns(tmp, n_events)
        except NetnsUnavailable as exc:
            summary["latency_netns"] = {"n": 0, "unavailable": str(exc)}
        progress.advance(task)
    summary["bring_up"] = bring
    summary["bring_up_median_s"] = statistics.median(b["modules_alive_s"] for b in bring)
    (out_dir / "deploy.json").write_text(json.dumps(summary, indent=2))

    t = Table(title=f"default manifest ({bring[0]['nodes']} nodes, {bring[0]['modules']} modules) on this machine")
    for col in ("run", "all nodes alive s", "all modules alive s", "stop s"):
        t.add_column(col)
    for i, b in enumerate(bring):
        t.add_row(str(i + 1), f"{b['nodes_alive_s']:.2f}", f"{b['modules_alive_s']:.2f}", f"{b['stop_s']:.2f}")
    console.print(t)
    t = Table(title="fused contact-event latency, one-way, same clock: tactile reading -> event at the observer "
                    "(cue) and event stamp -> observer (transport)")
    for col in ("path", "events", "cue p50 ms", "cue p99 ms", "cue max ms", "transport p50 ms", "transport p99 ms"):
        t.add_column(col)
    for label, key in (("loopback", "latency_loopback"), ("between namespaces (veth + bridge)", "latency_netns")):
        s = summary[key]
        if s.get("n"):
            tr = s["transport"]
            t.add_row(label, str(s["n"]), f"{s['p50_ms']:.2f}", f"{s['p99_ms']:.2f}", f"{s['max_ms']:.2f}",
                      f"{tr['p50_ms']:.3f}", f"{tr['p99_ms']:.3f}")
        else:
            t.add_row(label, "0", s.get("unavailable", "no events"), "", "", "", "")
    console.print(t)
    return summary
