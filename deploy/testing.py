"""Helpers for deployment tests and benchmarks: a probe client, test source modules, a lab deployment."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from contactflow.deploy.launcher import default_run_dir
from contactflow.deploy.manifest import Manifest, load_manifest
from contactflow.deploy.netns import NetLab
from contactflow.deploy.supervisor import read_state
from contactflow.embodiments.messages import TactileArray, TaxelPoses
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import NDArray

BEACON = "contactflow.deploy.testing:Beacon"
TAP_PAD = "contactflow.deploy.testing:TapPad"


class Beacon(Module):
    """Test primitive: one CONTACT event per step, numbered, never finishes (loss and latency probes)."""

    layer = Layer.PRIMITIVE
    events = (Event.CONTACT,)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz, events per second

    def start(self) -> None:
        self._n = 0

    def step(self) -> Status:
        self._n += 1
        self.io.emit(Event.CONTACT, detail="beacon", values={"n": float(self._n)})
        return Status.RUNNING


class TapPad(Module):
    """Test sensor: one tactile pad, flat at a fixed world pose, pressed and released in turn.

    It stands in for a hand's tactile driver and pose publisher so that the real tactile
    generator and contact fusion downstream turn each press into ``contact_made`` and each
    release into ``contact_broken`` (a steady stream of contact events for loss checks).
    """

    layer = Layer.SERVICE
    outputs = (Port("tactile", TactileArray, "pressure image of the pad, N per taxel"),
               Port("taxels", TaxelPoses, "world positions and normals of the pad's taxels"))

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 30.0  # Hz, readings per second
        robot: str = "robot"  # robot the pad belongs to
        hand: str = "hand"  # hand name of the readings
        press_s: float = 0.2  # s, pressed time per cycle
        release_s: float = 0.2  # s, released time per cycle
        force: float = 2.0  # N per taxel while pressed
        taxels: int = 3  # taxels per side of the square pad
        pitch: float = 0.005  # m, taxel spacing
        origin: tuple[float, ...] = (0.5, 0.0, 0.8)  # m, world position of the pad's first taxel

    def start(self) -> None:
        p = self.params
        if p.press_s <= 0 or p.release_s <= 0 or p.taxels < 1:
            raise ValueError(f"{self.name}: press_s, release_s and taxels must be positive")
        grid = np.stack(np.meshgrid(np.arange(p.taxels), np.arange(p.taxels), indexing="ij"), axis=-1) * p.pitch
        pos = np.zeros((1, p.taxels, p.taxels, 3))
        pos[0, :, :, :2] = grid
        pos += np.asarray(p.origin, dtype=float)
        normals = np.zeros_like(pos)
        normals[..., 2] = 1.0
        self._poses = TaxelPoses(robot=p.robot, hand=p.hand, t=0.0, pads=["pad"], positions=NDArray.of(pos),
                                 normals=NDArray.of(normals))
        self._t0 = self.io.now

    def step(self) -> Status:
        p = self.params
        pressed = (self.io.now - self._t0) % (p.press_s + p.release_s) < p.press_s
        self.io.publish("taxels", self._poses)
        pressure = np.full((1, p.taxels, p.taxels), p.force if pressed else 0.0)
        self.io.publish("tactile", TactileArray(hand=p.hand, pads=["pad"], pressure=NDArray.of(pressure)))
        return Status.RUNNING


_PROBE_WITH = "import importlib, sys\nfor m in {mods!r}: importlib.import_module(m)\nfrom contactflow.deploy.probe import main\nsys.exit(main())"


class ProbeClient:
    """Drives one ``contactflow.deploy.probe`` process; every wait is bounded in time.

    ``messages`` names modules of message types the probe must decode besides the runtime's
    (a message type is known once its module is imported), e.g. ``contactflow.fusion.messages``.
    """

    def __init__(self, prefix: list[str], connect: list[str], config: Path | None = None, name: str = "probe", stderr: Any = subprocess.DEVNULL,
                 ready_timeout: float = 15.0, messages: tuple[str, ...] = ()) -> None:
        main = ["-c", _PROBE_WITH.format(mods=tuple(messages))] if messages else ["-m", "contactflow.deploy.probe"]
        argv = [sys.executable, *main, "--name", name]
        for e in connect:
            argv += ["--connect", e]
        if config is not None:
            argv += ["--config", str(config)]
        self.proc = subprocess.Popen(prefix + argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=stderr, text=True, bufsize=1)
        self.lines: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._new = threading.Condition(self._lock)
        self._ids = 0
        threading.Thread(target=self._read, daemon=True).start()
        first = self.wait(lambda e: e["ev"] in ("ready", "fatal"), ready_timeout)
        if first is None or first["ev"] != "ready":
            self.close()
            raise RuntimeError(f"probe {name} did not start: {first}")

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                ev = json.loads(line)
            except json.JSONDecodeError:
                continue
            with self._new:
                self.lines.append(ev)
                self._new.notify_all()

    def send(self, op: str, wait: bool = True, timeout: float = 5.0, **fields: Any) -> int:
        with self._lock:
            self._ids += 1
            cid = self._ids
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps({"op": op, "id": cid, **fields}) + "\n")
        self.proc.stdin.flush()
        if wait:
            ack = self.wait(lambda e: e.get("id") == cid and e["ev"] in ("ok", "error"), timeout)
            if ack is None or ack["ev"] == "error":
                raise RuntimeError(f"probe {op} {fields}: {ack}")
        return cid

    def wait(self, pred: Callable[[dict[str, Any]], bool], timeout: float, start: int = 0) -> dict[str, Any] | None:
        end = time.monotonic() + timeout
        with self._new:
            i = start
            while True:
                while i < len(self.lines):
                    if pred(self.lines[i]):
                        return self.lines[i]
                    i += 1
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self._new.wait(min(left, 0.2))

    def events(self, cid: int, ev: str = "sample") -> list[dict[str, Any]]:
        with self._lock:
            return [e for e in self.lines if e.get("id") == cid and e["ev"] == ev]

    def count(self, cid: int, ev: str = "sample") -> int:
        return len(self.events(cid, ev))

    def query(self, key: str, timeout: float = 1.0, **fields: Any) -> list[dict[str, Any]]:
        cid = self.send("query", wait=False, key=key, timeout=timeout, **fields)
        rep = self.wait(lambda e: e.get("id") == cid and e["ev"] in ("reply", "error"), timeout + 5.0)
        return rep.get("replies", []) if rep else []

    def peers(self) -> int:
        cid = self.send("peers", wait=False)
        rep = self.wait(lambda e: e.get("id") == cid and e["ev"] == "peers", 5.0)
        return rep["count"] if rep else -1

    def wait_peers(self, n: int, timeout: float = 8.0) -> bool:
        """Whether the probe's session has ``n`` peers within ``timeout`` s."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.peers() >= n:
                return True
            time.sleep(0.2)
        return False

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.write(json.dumps({"op": "quit"}) + "\n")
                self.proc.stdin.flush()
                self.proc.wait(3)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait(3)


def lab_manifest(path: Path, lab: NetLab, hosts: dict[str, dict[str, Any]], **top: Any) -> Manifest:
    """Write a manifest whose hosts get the lab's namespace addresses; returns it parsed."""
    doc = dict(top)
    doc["hosts"] = {h: {"address": lab.addresses[h], **spec} for h, spec in hosts.items()}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_manifest(path)


class LabDeployment:
    """``contactflow deploy MANIFEST --host H`` started inside each host's namespace."""

    def __init__(self, lab: NetLab, manifest: Manifest, run_dir: Path) -> None:
        self.lab, self.m, self.run_dir = lab, manifest, run_dir
        self.supervisors: dict[str, subprocess.Popen] = {}

    def up(self, host: str) -> None:
        argv = [sys.executable, "-m", "contactflow.deploy.cli", "deploy", self.m.file, "--host", host,
                "--run-dir", str(self.run_dir)]
        log = open(self.run_dir / f"supervisor-{host}.log", "ab")  # noqa: SIM115 - handed to the child
        self.supervisors[host] = subprocess.Popen(self.lab.wrap(host, argv), stdout=log, stderr=subprocess.STDOUT)
        log.close()

    def node_pid(self, host: str, node: str) -> int:
        st = read_state(self.run_dir / host)
        return st.nodes[node].pid if st and node in st.nodes else 0

    def restarts(self, host: str, node: str) -> int:
        st = read_state(self.run_dir / host)
        return st.nodes[node].restarts if st and node in st.nodes else 0

    def logs(self) -> str:
        out = []
        for f in sorted(self.run_dir.rglob("*.log")):
            out.append(f"==> {f}\n{f.read_text(errors='replace')[-1500:]}")
        return "\n".join(out)

    def down(self) -> None:
        for p in self.supervisors.values():
            if p.poll() is None:
                p.terminate()
        for p in self.supervisors.values():
            try:
                p.wait(8)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(3)


__all__ = ["BEACON", "TAP_PAD", "Beacon", "LabDeployment", "ProbeClient", "TapPad", "default_run_dir", "lab_manifest"]
