"""Supervision of a host's node processes: start, restart with exponential back-off, stop.

The supervisor keeps one ``contactflow node`` child per launch, a log file per node, and a
state file (``supervisor.json``) rewritten atomically on every change, so that ``deploy
status`` and ``deploy stop`` work from another shell. A node that dies is restarted after
``backoff_delay(failures)``; the failure count resets once a node has run for
``stable_s``.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from contactflow.deploy.launcher import Launch
from contactflow.nodes.procs import spawn_node, stop_process

STATE_FILE = "supervisor.json"
log = logging.getLogger("contactflow.deploy.supervisor")


def backoff_delay(failures: int, base: float = 0.5, cap: float = 30.0) -> float:
    """Seconds to wait before restart number ``failures`` (1, 2, ...) of a crashing node."""
    if failures <= 0:
        return 0.0
    return min(cap, base * 2.0 ** (failures - 1))


@dataclass
class NodeState:
    host: str
    node: str
    config: str
    log: str
    endpoint: str
    pid: int = 0
    state: str = "starting"  # starting | running | backoff | stopped
    restarts: int = 0
    failures: int = 0
    started_at: float = 0.0
    next_start: float = 0.0
    last_exit: int | None = None


@dataclass
class SupervisorState:
    scope: str
    manifest: str
    pid: int
    started_at: float
    state: str = "running"  # running | stopping | stopped
    nodes: dict[str, NodeState] = field(default_factory=dict)


def read_state(scope_dir: Path) -> SupervisorState | None:
    path = scope_dir / STATE_FILE
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    nodes = {k: NodeState(**v) for k, v in raw.pop("nodes", {}).items()}
    return SupervisorState(nodes=nodes, **raw)


def pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a zombie child of ours counts as dead
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except OSError:
        return True


class Supervisor:
    """Runs and watches the node processes of one scope (a host, or all hosts locally)."""

    def __init__(self, launches: list[Launch], scope_dir: Path, manifest: str, *, base_delay: float = 0.5,
                 max_delay: float = 30.0, stable_s: float = 10.0, env: dict[str, str] | None = None) -> None:
        self.launches = {ln.node.name: ln for ln in launches}
        self.scope_dir = scope_dir
        self.base_delay, self.max_delay, self.stable_s = base_delay, max_delay, stable_s
        self.env = env
        self.procs: dict[str, subprocess.Popen] = {}
        self.state = SupervisorState(scope=scope_dir.name, manifest=manifest, pid=os.getpid(), started_at=time.time())
        for ln in launches:
            self.state.nodes[ln.node.name] = NodeState(ln.node.host, ln.node.name, str(ln.config), str(ln.log), ln.endpoint)
        self._lock = threading.Lock()

    def _write(self) -> None:
        data = asdict(self.state)
        tmp = self.scope_dir / f".{STATE_FILE}.{os.getpid()}"
        tmp.write_text(json.dumps(data, indent=1))
        tmp.replace(self.scope_dir / STATE_FILE)

    def _spawn(self, name: str) -> None:
        ln, ns = self.launches[name], self.state.nodes[name]
        ln.log.parent.mkdir(parents=True, exist_ok=True)
        with open(ln.log, "a") as f:
            f.write(f"--- supervisor: start #{ns.restarts + 1} at {time.strftime('%Y-%m-%dT%H:%M:%S')}\n")
        proc = spawn_node(ln.config, ln.log, env=self.env)
        self.procs[name] = proc
        ns.pid, ns.state, ns.started_at = proc.pid, "running", time.time()
        log.info("started %s (pid %d)", ln.node.id, proc.pid)

    def start(self) -> None:
        self.scope_dir.mkdir(parents=True, exist_ok=True)
        with self._lock:
            for name in self.launches:
                self._spawn(name)
            self._write()

    def poll(self) -> None:
        """Notice exits and (re)start nodes whose back-off has elapsed."""
        now = time.time()
        changed = False
        with self._lock:
            if self.state.state != "running":
                return
            for name, ns in self.state.nodes.items():
                proc = self.procs.get(name)
                if ns.state == "running" and proc is not None and proc.poll() is not None:
                    ns.failures = 1 if now - ns.started_at >= self.stable_s else ns.failures + 1
                    delay = backoff_delay(ns.failures, self.base_delay, self.max_delay)
                    ns.last_exit, ns.state, ns.pid, ns.next_start = proc.returncode, "backoff", 0, now + delay
                    log.warning("%s/%s exited with %s; restart in %.1f s", ns.host, name, proc.returncode, delay)
                    changed = True
                elif ns.state == "backoff" and now >= ns.next_start:
                    ns.restarts += 1
                    self._spawn(name)
                    changed = True
            if changed:
                self._write()

    def run(self, stop: threading.Event, period: float = 0.1) -> None:
        """Supervise until ``stop`` is set, then stop every node."""
        while not stop.wait(period):
            self.poll()
        self.shutdown()

    def shutdown(self, timeout: float = 5.0) -> None:
        with self._lock:
            self.state.state = "stopping"
            self._write()
            procs = list(self.procs.items())
            for _, p in procs:
                if p.poll() is None:
                    p.send_signal(signal.SIGTERM)
            for name, p in procs:
                stop_process(p, timeout)
                ns = self.state.nodes[name]
                ns.state, ns.pid, ns.last_exit = "stopped", 0, p.returncode
            self.state.state = "stopped"
            self._write()


def stop_scope(scope_dir: Path, timeout: float = 10.0) -> list[str]:
    """Stop a scope started from another shell: SIGTERM its supervisor, then its nodes."""
    st = read_state(scope_dir)
    if st is None:
        return []
    done = []
    if st.state != "stopped" and pid_alive(st.pid):
        os.kill(st.pid, signal.SIGTERM)
        end = time.monotonic() + timeout
        while pid_alive(st.pid) and time.monotonic() < end:
            time.sleep(0.05)
        if pid_alive(st.pid):
            os.kill(st.pid, signal.SIGKILL)
        done.append(f"supervisor {st.pid}")
    st = read_state(scope_dir) or st
    for ns in st.nodes.values():
        if ns.pid and pid_alive(ns.pid):  # orphans of a supervisor that was killed
            os.kill(ns.pid, signal.SIGKILL)
            done.append(f"node {ns.host}/{ns.node} {ns.pid}")
    return done
