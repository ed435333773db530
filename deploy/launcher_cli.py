"""``contactflow deploy [up] MANIFEST --host NAME|--local``, ``status``, ``stop``, ``certs``.

``contactflow deploy MANIFEST --host NAME`` (the issue's form) and ``contactflow deploy up
MANIFEST --host NAME`` are the same command: a first argument that names no subcommand is
the manifest of ``up``.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Annotated

import click
import typer
from rich.console import Console
from rich.table import Table
from typer.core import TyperGroup

from contactflow.deploy.manifest import DEFAULT_MANIFEST, ConfigError, Manifest, load_manifest


class _UpByDefault(TyperGroup):
    """A group whose first argument, when it names no subcommand, is the manifest of ``up``."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        if args and not args[0].startswith("-") and args[0] not in self.commands:
            args = ["up", *args]
        return super().parse_args(ctx, args)


app = typer.Typer(help="Deploy a manifest: supervised node processes per host, status, stop, certificates. "
                       "`contactflow deploy MANIFEST --host NAME` is short for `contactflow deploy up MANIFEST --host NAME`.",
                  no_args_is_help=True, pretty_exceptions_show_locals=False, cls=_UpByDefault)
console = Console()

ManifestArg = Annotated[Path, typer.Argument(help="deployment manifest (YAML)")]
OptManifest = Annotated[Path, typer.Argument(help="deployment manifest (default: the thesis layout)")]
RunDir = Annotated[Path | None, typer.Option("--run-dir", help="run directory (default: $CONTACTFLOW_RUN_DIR/<site> or /tmp/contactflow-<uid>/<site>)")]


def _load(path: Path) -> Manifest:
    try:
        return load_manifest(path)
    except ConfigError as exc:
        console.print(f"[red]manifest error:[/] {exc}")
        raise typer.Exit(2) from None


def _run_dir(m: Manifest, run_dir: Path | None) -> Path:
    from contactflow.deploy.launcher import default_run_dir

    return (run_dir or default_run_dir(m)).resolve()


@app.command()
def up(manifest: ManifestArg, host: Annotated[str | None, typer.Option(help="start this host's nodes")] = None,
       local: Annotated[bool, typer.Option(help="start every host's nodes on this machine (loopback)")] = False,
       run_dir: RunDir = None,
       detach: Annotated[bool, typer.Option(help="run the supervisor in the background and return")] = False,
       wait: Annotated[float, typer.Option(help="with --detach: seconds to wait for every node's liveliness")] = 30.0) -> None:
    """Start a host's nodes (or all, --local) under supervision; Ctrl-C / SIGTERM stops them.

    `contactflow deploy MANIFEST --host NAME` (without `up`) does the same.
    """
    from contactflow.deploy.launcher import LOCAL, render
    from contactflow.deploy.security import SecurityError
    from contactflow.deploy.supervisor import Supervisor, pid_alive, read_state

    if (host is None) == (not local):
        console.print("[red]give exactly one of --host NAME or --local[/]")
        raise typer.Exit(2)
    m = _load(manifest)
    if host is not None and host not in m.hosts:
        console.print(f"[red]no host {host!r} in {manifest}[/] (hosts: {', '.join(m.hosts)})")
        raise typer.Exit(2)
    rd = _run_dir(m, run_dir)
    scope = rd / (LOCAL if local else host)
    old = read_state(scope)
    if old is not None and old.state != "stopped" and pid_alive(old.pid):
        console.print(f"[red]{scope} is already supervised by pid {old.pid}[/]; `contactflow deploy stop` first")
        raise typer.Exit(1)
    if detach:
        _detach(manifest, host, local, rd, scope, m, wait)
        return
    try:
        launches = render(m, rd, host=host, local=local)
    except SecurityError as exc:
        console.print(f"[red]security:[/] {exc}")
        raise typer.Exit(2) from None
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", force=True)
    sup = Supervisor(launches, scope, str(Path(manifest).resolve()))
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    sup.start()
    console.print(f"supervising {len(launches)} nodes of {'all hosts' if local else host} (run dir {scope})")
    sup.run(stop)


def _detach(manifest: Path, host: str | None, local: bool, rd: Path, scope: Path, m: Manifest, wait: float) -> None:
    from contactflow.deploy.health import alive_nodes, open_observer

    scope.mkdir(parents=True, exist_ok=True)
    args = [sys.executable, "-m", "contactflow.deploy.cli", "deploy", "up", str(manifest), "--run-dir", str(rd)]
    args += ["--local"] if local else ["--host", host]
    with open(scope / "supervisor.log", "ab") as out:
        proc = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                                env=dict(os.environ, PYTHONUNBUFFERED="1"))
    wanted = {n.id for n in m.nodes(None if local else host)}
    t0 = time.monotonic()
    seen: set[str] = set()
    obs = open_observer(m, local)
    try:
        while time.monotonic() - t0 < wait and proc.poll() is None:
            seen = alive_nodes(m, obs, timeout=0.5) & wanted
            if seen == wanted:
                break
    finally:
        obs.close()
    if proc.poll() is not None:
        console.print(f"[red]the supervisor exited with {proc.returncode}[/]; see {scope / 'supervisor.log'}")
        raise typer.Exit(1)
    colour = "green" if seen == wanted else "yellow"
    console.print(f"[{colour}]{len(seen)}/{len(wanted)} nodes alive after {time.monotonic() - t0:.1f} s[/] "
                  f"(supervisor pid {proc.pid}, run dir {scope})")


@app.command()
def status(manifest: OptManifest = DEFAULT_MANIFEST, run_dir: RunDir = None,
           as_host: Annotated[str | None, typer.Option("--as", help="join as this host (its certificate and password)")] = None,
           local: Annotated[bool | None, typer.Option(help="nodes listen on loopback (default: if the run dir has a local scope)")] = None,
           timeout: float = 1.0) -> None:
    """Show each host and node: supervisor process state, restarts and liveliness."""
    from contactflow.deploy.health import alive_nodes, health, is_local_run, open_observer

    m = _load(manifest)
    rd = _run_dir(m, run_dir)
    lo = is_local_run(rd) if local is None else local
    obs = open_observer(m, lo, as_host)
    try:
        alive = alive_nodes(m, obs, timeout=timeout)
    finally:
        obs.close()
    rows = health(m, rd, alive)
    table = Table(title=f"site {m.site}: {sum(r.alive for r in rows)}/{len(rows)} nodes alive ({rd})")
    for col in ("host", "node", "liveliness", "process", "pid", "restarts", "scope"):
        table.add_column(col)
    for r in rows:
        table.add_row(r.host, r.node, "[green]alive[/]" if r.alive else "[red]missing[/]", r.process,
                      str(r.pid or ""), str(r.restarts), r.scope)
    console.print(table)
    if not all(r.alive for r in rows):
        raise typer.Exit(1)


@app.command()
def stop(manifest: OptManifest = DEFAULT_MANIFEST, run_dir: RunDir = None,
         host: Annotated[str | None, typer.Option(help="stop only this scope (host name or 'local')")] = None) -> None:
    """Stop the supervisors (and their nodes) started from this machine's run directory."""
    from contactflow.deploy.health import scopes
    from contactflow.deploy.supervisor import stop_scope

    m = _load(manifest)
    rd = _run_dir(m, run_dir)
    found = scopes(rd)
    if host is not None:
        found = {k: v for k, v in found.items() if k == host}
    if not found:
        console.print(f"nothing to stop in {rd}")
        return
    for scope in found:
        stopped = stop_scope(rd / scope)
        console.print(f"{scope}: " + (", ".join(stopped) if stopped else "already stopped"))


@app.command()
def certs(manifest: ManifestArg,
          extra: Annotated[list[str] | None, typer.Option("--extra", help="also make a certificate and password for this name (tests: a guest)")] = None) -> None:
    """Create a CA, a certificate per host and a zenoh password file under security.certs."""
    from contactflow.deploy.certs import CertError, make_ca, make_host_cert, make_passwords

    m = _load(manifest)
    d = m.security.certs or (Path(m.file).parent / "certs").resolve()
    try:
        make_ca(d, f"contactflow {m.site} CA")
        names = list(m.hosts) + list(extra or [])
        for name in names:
            addr = [m.hosts[name].address] if name in m.hosts else []
            make_host_cert(d, name, addr)
        make_passwords(d / "passwords.txt", names)
    except CertError as exc:
        console.print(f"[red]{exc}[/]")
        raise typer.Exit(1) from None
    console.print(f"CA and {len(names)} certificates in {d} ({', '.join(names)}); passwords in {d / 'passwords.txt'}")
