"""The ``contactflow`` command line (typer + rich)."""

from __future__ import annotations

import importlib
import inspect
import json
import logging
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.logging import RichHandler
from rich.markup import escape
from rich.table import Table

from contactflow.nodes.keys import KeySpace
from contactflow.nodes.params import ParamError
from contactflow.nodes.session import default_site, open_tool_session
from contactflow.nodes.wire import WireError, decode, decode_any, to_builtins

app = typer.Typer(help="contactflow: distributed runtime for contact-driven manipulation.",
                  no_args_is_help=True, pretty_exceptions_show_locals=False)
console = Console()

BENCHMARKS = {
    "messaging": "contactflow.nodes.bench_messaging",
    "sim": "contactflow.embodiments.bench_sim",
    "grasp": "contactflow.embodiments.bench_grasp",
    "unscrew": "contactflow.embodiments.bench_unscrew",
    "empty-box": "contactflow.embodiments.bench_empty_box",
    "shared-contacts": "contactflow.embodiments.bench_shared_contacts",
    "catch-zone": "contactflow.embodiments.bench_catch_zone",
    "contacts": "contactflow.fusion.bench_contacts",
    "prediction": "contactflow.embodiments.bench_prediction",
    "fusion": "contactflow.fusion.bench_fusion",
    "vision": "contactflow.recognition.bench_vision",
    "recognition": "contactflow.recognition.bench_recognition",
    "deploy": "contactflow.deploy.bench_deploy",
    "fuzz": "contactflow.deploy.bench_fuzz",
    "record": "contactflow.deploy.bench_record",
    "dispatch": "contactflow.abstraction.bench_dispatch",
}
"""``contactflow bench NAME`` runs ``run(out_dir, quick)`` of the module named here."""

SUBCOMMANDS = {
    "contacts": ("contactflow.fusion.cli", "Fused contact events: watch them live."),
    "deploy": ("contactflow.deploy.launcher_cli", "Deploy manifests across hosts."),
    "atd": ("contactflow.abstraction.atd_cli", "Abstract task descriptions: check and translate."),
    "embodiments": ("contactflow.embodiments.cli", "Simulated embodiments: list, show, URDF."),
    "protocol": ("contactflow.nodes.protocol_cli", "The wire protocol: every message's fields."),
}
"""Sub-applications contributed by the areas (a ``typer.Typer`` named ``app`` each)."""

Site = Annotated[str | None, typer.Option("--site", "-s", help="site name (default: $CONTACTFLOW_SITE or 'default')")]
Connect = Annotated[list[str] | None, typer.Option("--connect", "-e", help="zenoh endpoint to connect to (repeatable)")]


def setup_logging(verbose: bool = False) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format="%(message)s",
                        handlers=[RichHandler(console=Console(stderr=True), show_path=False)], force=True)


@app.command()
def node(config: Path, verbose: bool = False) -> None:
    """Run one node process hosting the modules CONFIG names (until SIGINT/SIGTERM)."""
    from contactflow.nodes.config import ConfigError
    from contactflow.nodes.node import run_node

    setup_logging(verbose)
    try:
        run_node(config)
    except ConfigError as exc:
        console.print(f"[red]config error:[/] {exc}")
        raise typer.Exit(2) from None


@app.command("ls")
def list_nodes(site: Site = None, connect: Connect = None, wait: float = 1.3) -> None:
    """List nodes and modules of a site with their status (liveliness + status stream)."""
    from contactflow.nodes.messages import StatusMsg

    ks = KeySpace(default_site(site))
    t = open_tool_session(connect)
    statuses: dict[str, StatusMsg] = {}

    def on_status(key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, StatusMsg, key)
        except WireError:
            return
        statuses[msg.module] = msg

    sub = t.subscribe(ks.status(), on_status)
    nodes = t.alive(ks.alive_node(), timeout=1.0)
    modules = t.alive(ks.alive_module(), timeout=1.0)
    time.sleep(wait)
    sub.close()
    t.close()
    table = Table(title=f"site {ks.site}: {len(nodes)} nodes, {len(modules)} modules")
    for col in ("host/node", "module", "layer", "state", "rate Hz", "steps", "CPU s", "rejected", "gaps", "dropped", "detail"):
        table.add_column(col)
    for n in sorted(nodes):
        host, node_name = n.split("/")[-2:]
        table.add_row(f"[bold]{host}/{node_name}[/]", "", "", "[green]alive[/]", "", "", "", "", "", "", "")
        for m in sorted(modules):
            robot, mnode, mname = m.split("/")[-3:]
            if mnode != node_name:
                continue
            s = statuses.get(f"{robot}/{mnode}/{mname}")
            table.add_row("", f"{robot}/{mname}", s.layer if s else "?", str(s.state) if s else "?",
                          f"{s.rate_hz:g}" if s else "", str(s.steps) if s else "", f"{s.cpu_s:.2f}" if s else "",
                          str(s.rejected) if s else "", _per_port(s.gaps) if s else "",
                          _per_port(s.dropped) if s else "", (s.detail[:40] if s else ""))
    console.print(table)


def _per_port(counts: dict[str, int]) -> str:
    """Messages missed (gaps) or pushed out of a full queue (dropped) per input port, in red; "0" for none."""
    lost = {port: n for port, n in sorted(counts.items()) if n}
    return " ".join(f"[red]{port}:{n}[/]" for port, n in lost.items()) if lost else "0"


@app.command()
def ctl(module: Annotated[str, typer.Argument(help="[robot/]module")],
        command: Annotated[str, typer.Argument(help="run | stop | reset | describe | set")],
        assignments: Annotated[list[str] | None, typer.Argument(help="key=value for set")] = None,
        site: Site = None, connect: Connect = None, robot: str = "site") -> None:
    """Send a control message to a module and print its reply."""
    from contactflow.nodes.messages import Command, ControlReply, ControlRequest
    from contactflow.nodes.wire import encode

    try:
        cmd = Command(command)
    except ValueError:
        console.print(f"[red]unknown command {command!r}[/]: use {', '.join(c.value for c in Command)}")
        raise typer.Exit(2) from None
    params: dict[str, str] = {}
    for a in assignments or []:
        k, eq, v = a.partition("=")
        if not eq:
            console.print(f"[red]{a!r} is not key=value[/]")
            raise typer.Exit(2)
        params[k] = v
    r, _, mname = module.rpartition("/")
    ks = KeySpace(default_site(site))
    t = open_tool_session(connect)
    try:
        replies = t.query(ks.control(r or robot, "*", mname), encode(ControlRequest(cmd=cmd, params=params, issuer="cli")))
    finally:
        t.close()
    if not replies:
        console.print(f"[red]no module answers on {ks.control(r or robot, '*', mname)}[/]")
        raise typer.Exit(1)
    failed = False
    for key, payload in replies:
        try:
            reply = decode(payload, ControlReply, key)
        except WireError as exc:
            console.print(f"[red]{escape(str(exc))}[/]")
            failed = True
            continue
        colour = "green" if reply.ok else "red"
        console.print(f"[{colour}]{escape(key)}: {'ok' if reply.ok else escape(reply.error)}[/] state={reply.state}")
        if reply.description:
            console.print(escape(reply.description))
        elif reply.params:
            console.print(reply.params)
        failed = failed or not reply.ok
    if failed:
        raise typer.Exit(1)


@app.command()
def echo(keyexpr: Annotated[str, typer.Argument(help="key expression, e.g. 'cf/default/**'")],
         count: int = 0, duration: float = 0.0, connect: Connect = None, raw: bool = False) -> None:
    """Print decoded messages on KEYEXPR (Ctrl-C to stop)."""
    t = open_tool_session(connect)
    seen = 0
    done = threading.Event()
    printing = threading.Lock()

    def on_sample(key: str, payload: bytes) -> None:
        nonlocal seen
        with printing:
            if done.is_set():
                return  # the count was reached: a sample that came before the subscriber closed is not printed
            try:
                view = to_builtins(decode_any(payload, key))
            except WireError as exc:
                console.print(f"[red]{escape(str(exc))}[/]")
                return
            seen += 1
            if raw:
                console.print_json(json.dumps({"key": key, "msg": view}, default=str))
            else:
                console.print(f"[cyan]{escape(key)}[/] {escape(str(view))}")
            if count and seen >= count:
                done.set()

    sub = t.subscribe(keyexpr, on_sample)
    try:
        done.wait(duration if duration > 0 else None)
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
        t.close()


@app.command()
def record(keys: Annotated[list[str] | None, typer.Argument(help="key expressions (default: the whole site, cf/<site>/**)")] = None,
           out: Annotated[Path, typer.Option("--out", "-o", help="the MCAP file to write")] = Path("run.mcap"),
           site: Site = None, connect: Connect = None,
           duration: Annotated[float, typer.Option(help="s to record (0: until Ctrl-C)")] = 0.0,
           view: Annotated[bool, typer.Option(help="also write the Foxglove view channels")] = True) -> None:
    """Record the key space into an MCAP file (JSON channels per key, plus Foxglove view channels)."""
    from rich.live import Live

    from contactflow.deploy.recorder import Recorder

    site = site or default_site()
    t = open_tool_session(connect)
    rec = Recorder(t, keys or [f"{KeySpace(site).prefix}/**"], out, site, view=view).start()
    end = time.monotonic() + duration if duration > 0 else math.inf

    def line() -> str:
        s = rec.stats
        return (f"recording {escape(str(out))}: {s.recorded} messages, {s.bytes / 1e6:.1f} MB, "
                f"{s.dropped} dropped, {s.lost} lost, {s.rejected} rejected")
    try:
        with Live(line(), console=console, refresh_per_second=4, transient=True) as live:
            while time.monotonic() < end:
                time.sleep(0.25)
                live.update(line())
    except KeyboardInterrupt:  # Ctrl-C is how a recording without --duration ends: the file is finished below
        pass
    finally:
        stats = rec.stop()
        t.close()
    console.print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB): " + ", ".join(f"{k} {v:g}" for k, v in stats.as_dict().items()))


@app.command()
def replay(recording: Annotated[Path, typer.Argument(help="an MCAP file written by contactflow record")],
           rate: Annotated[float, typer.Option(help="x recorded speed (0: as fast as possible)")] = 1.0,
           site: Annotated[str | None, typer.Option("--site", "-s", help="the site to publish on (default: the recorded one)")] = None,
           key: Annotated[list[str] | None, typer.Option("--key", "-k", help="replay only this recorded key (repeatable)")] = None,
           force: Annotated[bool, typer.Option(help="replay even where live publishers use the recorded keys")] = False,
           connect: Connect = None) -> None:
    """Republish a recording on a site, its clock among it, so modules run again on recorded sensors."""
    from rich.progress import Progress, TextColumn

    from contactflow.deploy.recording import Recording, RecordingError
    from contactflow.deploy.replayer import Replayer, ReplayError

    try:
        rec = Recording.open(recording)
        unknown = sorted(set(key or ()) - set(rec.channels))
        if unknown:
            raise RecordingError(f"{recording}: no channel for key {unknown[0]!r} (keys: {', '.join(sorted(rec.channels)[:8])} ...)")
    except RecordingError as exc:
        console.print(f"[red]{escape(str(exc))}[/]")
        raise typer.Exit(2) from None
    t = open_tool_session(connect)
    try:
        player = Replayer(t, rec, site, rate, set(key) if key else None)
        live = player.check(force)
        if live:
            console.print(f"[yellow]warning: live publishers on {len(live)} recorded keys; replaying anyway (--force)[/]")
        span = (rec.end_ns - rec.start_ns) / 1e9
        console.print(f"replaying {sum(rec.counts.values())} messages ({span:.1f} s) of site {rec.site!r} on {player.site!r}")
        with Progress(*Progress.get_default_columns(), TextColumn("{task.fields[n]} messages"), console=console) as bar:
            task = bar.add_task("replay", total=max(span, 1e-9), n=0)
            stats = player.run(lambda n, t_rec: bar.update(task, completed=t_rec, n=n))
    except ReplayError as exc:
        console.print(f"[red]{escape(str(exc))}[/]")
        raise typer.Exit(2) from None
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    finally:
        t.close()
    console.print(f"replayed {stats.messages} messages in {stats.seconds:.1f} s ({stats.speed:.2f}x real time)")


@app.command()
def new(kind: Annotated[str, typer.Argument(help="service | primitive | task")], name: str,
        out: Path = Path("."), package: str | None = None) -> None:
    """Generate a module skeleton, its description and its configuration (thesis §6.2.1)."""
    from contactflow.nodes.generate import generate

    try:
        files = generate(kind, name, out, package)
    except (ValueError, FileExistsError) as exc:
        console.print(f"[red]{exc}[/]")
        raise typer.Exit(2) from None
    for f in files:
        console.print(f"wrote {f}")


@app.command()
def bench(name: Annotated[str, typer.Argument(help=f"one of: {', '.join(BENCHMARKS)}")],
          out: Path = Path("bench-results"), quick: bool = False,
          jobs: Annotated[int, typer.Option(min=1, help="worker processes, for benchmarks made of independent runs")] = 1,
          runs: Annotated[int | None, typer.Option(min=1, help="runs per strategy (empty-box; default 10), per variant (shared-contacts; default 10) or per case (prediction; default 20)")] = None,
          trials: Annotated[int | None, typer.Option(min=1, help="trials per object and condition (grasp, unscrew; default 10)")] = None,
          max_time: Annotated[float | None, typer.Option(min=1.0, help="simulated s per run before the supervisor stops it (empty-box, shared-contacts)")] = None,
          max_attempts: Annotated[int | None, typer.Option(min=1, help="grasp attempts per run (empty-box, shared-contacts)")] = None,
          strategy: Annotated[list[str] | None, typer.Option(help="only this strategy, repeatable (empty-box; default all)")] = None,
          first_seed: Annotated[int | None, typer.Option(help="seed of the first run, the next runs count up (empty-box, shared-contacts; default 100)")] = None,
          executor: Annotated[str | None, typer.Option(help="local (primitives in this process), runtime (world and control nodes over zenoh) or both side by side (grasp, unscrew, empty-box, catch-zone, vision, contacts)")] = None,
          preshape: Annotated[list[str] | None, typer.Option(help="the hand preshape both grasp controllers close from, repeatable for side by side (grasp; default claw)")] = None,
          rig: Annotated[str | None, typer.Option(help="the robot whose hand touches: tombatossals (the thesis's Allegro hand), melfa, or both side by side (contacts; default both)")] = None,
          sensor: Annotated[list[str] | None, typer.Option(help="what the exploration's guarded moves stop on: own (wrist and pads) or fused (the robot's fused contacts), repeatable for side by side (empty-box; default own)")] = None,
          objects: Annotated[int | None, typer.Option(help="objects in the box (shared-contacts; default 5)")] = None) -> None:
    """Run a benchmark: prints a table and writes JSON (and plots) under OUT."""
    path = BENCHMARKS.get(name)
    if path is None:
        console.print(f"[red]unknown benchmark {name!r}[/]: {', '.join(BENCHMARKS)}")
        raise typer.Exit(2)
    try:
        mod = importlib.import_module(path)
    except ModuleNotFoundError as exc:
        console.print(f"[red]benchmark {name!r} is not available: {exc}[/]")
        raise typer.Exit(1) from None
    given = {"jobs": jobs if jobs != 1 else None, "runs": runs, "trials": trials, "max_time": max_time, "max_attempts": max_attempts,
             "strategy": strategy or None, "first_seed": first_seed, "executor": executor, "preshape": preshape or None, "rig": rig,
             "sensor": sensor or None, "objects": objects}
    extra = {k: v for k, v in given.items() if v is not None}
    accepted = inspect.signature(mod.run).parameters
    for key in extra:
        if key not in accepted:
            why = " (it measures one process or pairs them itself)" if key == "jobs" else ""
            console.print(f"[red]benchmark {name!r} does not take --{key.replace('_', '-')}[/]{why}")
            raise typer.Exit(2)
    out.mkdir(parents=True, exist_ok=True)
    try:
        mod.run(out, quick=quick, **extra)
    except ParamError as exc:  # a refused option value; other errors keep their traceback
        console.print(f"[red]{exc}[/]")
        raise typer.Exit(2) from None
    console.print(f"results in {out}")


@app.command()
def demo(out: Path = Path("demo-report"), quick: bool = False,
         pipeline: Annotated[bool, typer.Option(help="only the two-node service pipeline demo")] = False,
         site: Annotated[str | None, typer.Option("--site", "-s", help="the demo's site (default: a fresh demoNNNNN)")] = None,
         connect: Annotated[list[str] | None, typer.Option(
             "--connect", "-e", help="a zenoh endpoint every demo node also connects to (repeatable)")] = None,
         listen: Annotated[list[str] | None, typer.Option(
             "--listen", "-l", help="an endpoint the demo's session listens on for outside clients (repeatable; "
             "default loopback only)")] = None,
         record: Annotated[bool, typer.Option(help="record the key space into OUT/demo.mcap (open it in Foxglove)")] = False) -> None:
    """The thesis §7.3 experiment on three simulated robots over zenoh, with a report (README's main command)."""
    if pipeline:
        from contactflow.deploy import pipeline_demo

        raise typer.Exit(pipeline_demo.run(out, quick=quick))
    from contactflow.deploy import demo as full
    from contactflow.nodes.keys import KeyExprError, segment

    try:
        if site is not None:
            segment(site, "--site")
    except KeyExprError as exc:
        console.print(f"[red]{exc}[/]")
        raise typer.Exit(2) from None
    raise typer.Exit(full.run(out, quick=quick, site=site, connect=tuple(connect or ()), listen=tuple(listen or ()),
                              record=record))


def _mount_subcommands() -> None:
    for name, (path, help_text) in SUBCOMMANDS.items():
        try:
            mod = importlib.import_module(path)
        except ModuleNotFoundError as exc:
            if exc.name != path:
                raise
            continue
        app.add_typer(mod.app, name=name, help=help_text)
    for path in ("contactflow.abstraction.cli",):
        try:
            mod = importlib.import_module(path)
        except ModuleNotFoundError as exc:
            if exc.name != path:
                raise
            continue
        mod.register(app)


def main() -> None:
    os.environ.setdefault("PYTHONWARNINGS", "ignore::UserWarning")
    own = {c.name or c.callback.__name__ for c in app.registered_commands if c.callback is not None}
    # a command of this app's own needs none of the subcommands, whose imports cost about 0.9 s of CPU at the
    # start of every node process
    if not (sys.argv[1:2] and sys.argv[1] in own):
        _mount_subcommands()
    app(prog_name="contactflow")


if __name__ == "__main__":
    sys.exit(main())
