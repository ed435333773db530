"""Benchmark: bring-up time of the default manifest on this machine, and event latency between
network namespaces against loopback in the same run."""

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
from contactflow.deploy.testing import BEACON, LabDeployment, ProbeClient, lab_manifest
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port_block
from contactflow.nodes.transport import ZenohSettings, ZenohTransport

console = Console()


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


def _latency(samples: list[dict[str, Any]]) -> dict[str, float]:
    lat = sorted((e["recv"] - e["t_wall"]) * 1e3 for e in samples)
    if not lat:
        return {"n": 0}
    return {"n": len(lat), "p50_ms": statistics.median(lat), "p99_ms": lat[min(len(lat) - 1, int(0.99 * len(lat)))],
            "mean_ms": statistics.fmean(lat), "max_ms": lat[-1]}


HOSTS = {"src": {"nodes": {"beacon": {"robot": "bench", "modules": [
    {"name": "beacon", "type": BEACON, "params": {"rate_hz": 100}, "autostart": True}]}}}, "obs": {}}


def _collect(probe: ProbeClient, site: str, n: int, timeout: float) -> list[dict[str, Any]]:
    ks = KeySpace(site)
    cid = probe.send("sub", key=ks.events("bench", "*", "beacon"))
    end = time.monotonic() + timeout
    while time.monotonic() < end and probe.count(cid) < n + 20:
        time.sleep(0.05)
    return probe.events(cid)[20:]  # the first events include connection set-up


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
    probe = ProbeClient([], tool_endpoints(m, local=True), name="obs")
    try:
        return _latency(_collect(probe, m.site, n, 60))
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
        probe = ProbeClient(lab.wrap("obs", []), tool_endpoints(m, local=False), name="obs")
        return _latency(_collect(probe, m.site, n, 60))
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
    n_events = 100 if quick else 1000
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
    t = Table(title="contact-event latency (beacon at 100 Hz, one-way, same clock)")
    for col in ("path", "n", "p50 ms", "p99 ms", "mean ms", "max ms"):
        t.add_column(col)
    for label, key in (("loopback", "latency_loopback"), ("between namespaces (veth + bridge)", "latency_netns")):
        s = summary[key]
        if s.get("n"):
            t.add_row(label, str(s["n"]), f"{s['p50_ms']:.3f}", f"{s['p99_ms']:.3f}", f"{s['mean_ms']:.3f}", f"{s['max_ms']:.3f}")
        else:
            t.add_row(label, "0", s.get("unavailable", "no events"), "", "", "")
    console.print(t)
    return summary
