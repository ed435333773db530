"""Test hosts in Linux network namespaces: one namespace per host, veth links to a bridge.

The bridge lives in its own namespace too, so nothing is added to the machine's own network
namespace: every address (``10.77.0.0/24`` by default) exists only inside the namespaces
this lab creates, and ``close`` deletes them all (killing what still runs inside). Cutting a
host's link sets its bridge port down; healing sets it up again. Needs root and ``ip``.
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass, field

SUBNET = "10.77.0"  # /24 used only inside the lab's namespaces


class NetnsUnavailable(RuntimeError):
    """Network namespaces cannot be created here; the message says why."""


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)
    if check and proc.returncode != 0:
        raise NetnsUnavailable(f"`ip {' '.join(args)}` failed: {proc.stderr.strip()}")
    return proc


def check_available() -> None:
    """Raise :class:`NetnsUnavailable` with the reason when namespaces cannot be used."""
    if shutil.which("ip") is None:
        raise NetnsUnavailable("the `ip` command (iproute2) is not installed")
    if os.geteuid() != 0:
        raise NetnsUnavailable(f"network namespaces need root (running as uid {os.geteuid()})")
    probe = f"cfprobe{secrets.token_hex(3)}"
    _ip("netns", "add", probe)
    _ip("netns", "del", probe)


@dataclass
class NetLab:
    """A bridge namespace and one namespace per named host."""

    hosts: list[str]
    subnet: str = SUBNET
    tag: str = field(default_factory=lambda: secrets.token_hex(2))
    addresses: dict[str, str] = field(default_factory=dict)
    _created: list[str] = field(default_factory=list)

    @property
    def switch(self) -> str:
        return f"cfd{self.tag}-sw"

    def ns(self, host: str) -> str:
        return f"cfd{self.tag}-{self.hosts.index(host)}"

    def port(self, host: str) -> str:
        return f"v{self.tag}p{self.hosts.index(host)}"

    def open(self) -> NetLab:
        check_available()
        try:
            sw = self.switch
            _ip("netns", "add", sw)
            self._created.append(sw)
            _ip("-n", sw, "link", "set", "lo", "up")
            _ip("-n", sw, "link", "add", "br0", "type", "bridge")
            _ip("-n", sw, "link", "set", "br0", "up")
            for i, h in enumerate(self.hosts):
                ns = self.ns(h)
                _ip("netns", "add", ns)
                self._created.append(ns)
                _ip("-n", ns, "link", "set", "lo", "up")
                _ip("-n", sw, "link", "add", self.port(h), "type", "veth", "peer", "name", "eth0", "netns", ns)
                _ip("-n", sw, "link", "set", self.port(h), "master", "br0", "up")
                addr = f"{self.subnet}.{10 + i}"
                _ip("-n", ns, "addr", "add", f"{addr}/24", "dev", "eth0")
                _ip("-n", ns, "link", "set", "eth0", "up")
                self.addresses[h] = addr
        except Exception:
            self.close()
            raise
        return self

    def wrap(self, host: str, argv: list[str]) -> list[str]:
        """``argv`` run inside the host's namespace."""
        return ["ip", "netns", "exec", self.ns(host), *argv]

    def cut(self, host: str) -> None:
        _ip("-n", self.switch, "link", "set", self.port(host), "down")

    def heal(self, host: str) -> None:
        _ip("-n", self.switch, "link", "set", self.port(host), "up")

    def pids(self, host: str) -> list[int]:
        out = _ip("netns", "pids", self.ns(host), check=False).stdout.split()
        return [int(p) for p in out if p.isdigit()]

    def close(self) -> None:
        """Kill what runs inside, delete every namespace this lab created (idempotent)."""
        for ns in list(self._created):
            for sig in (signal.SIGTERM, signal.SIGKILL):
                pids = [int(p) for p in _ip("netns", "pids", ns, check=False).stdout.split() if p.isdigit()]
                for pid in pids:
                    try:
                        os.kill(pid, sig)
                    except ProcessLookupError:
                        continue
                end = time.monotonic() + 3.0
                while pids and time.monotonic() < end:
                    pids = [int(p) for p in _ip("netns", "pids", ns, check=False).stdout.split() if p.isdigit()]
                    time.sleep(0.05)
                if not pids:
                    break
        for ns in reversed(self._created):
            _ip("netns", "del", ns, check=False)
        self._created.clear()

    def __enter__(self) -> NetLab:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()
