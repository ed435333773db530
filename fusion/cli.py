"""``contactflow contacts``: watch fused contact events live, re-fuse a recording offline."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from contactflow.fusion.messages import ContactEventMsg
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.params import params_dict
from contactflow.nodes.session import default_site, open_tool_session
from contactflow.nodes.status import Event
from contactflow.nodes.transport import Handle, Transport, key_matches
from contactflow.nodes.wire import WireError, decode

app = typer.Typer(help="Fused contact events (thesis ch. 4).", no_args_is_help=True)
console = Console()


@app.callback()
def contacts() -> None:
    """Fused contact events (thesis ch. 4)."""


def format_event(msg: ContactEventMsg) -> str:
    colour = "green" if msg.event == Event.CONTACT_MADE else "red"
    x, y, z = msg.location
    where = f"{msg.robot}/{msg.link}" if msg.link else msg.robot
    return (f"[dim]{msg.t:9.3f}[/] [{colour}]{msg.event.value:<14}[/] #{msg.contact_id:<4} {where:<24} "
            f"at ({x:+.3f}, {y:+.3f}, {z:+.3f}) m  p={msg.likelihood:.2f}")


def watch_events(transport: Transport, ks: KeySpace, robot: str | None,
                 on_event: Callable[[ContactEventMsg], None],
                 on_error: Callable[[str], None] | None = None) -> Handle:
    """Subscribe to the fused contact events of ``robot`` (every robot when None)."""
    def on_sample(key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, ContactEventMsg, key)
        except WireError as exc:
            if on_error is not None:
                on_error(str(exc))
            return
        on_event(msg)

    return transport.subscribe(ks.fused(robot or "*", "events"), on_sample)


@app.command()
def watch(
    robot: Annotated[str | None, typer.Argument(help="robot whose fused contacts to watch (default: all)")] = None,
    site: Annotated[str | None, typer.Option("--site", "-s", help="site (default: $CONTACTFLOW_SITE or 'default')")] = None,
    connect: Annotated[list[str] | None, typer.Option("--connect", "-e", help="zenoh endpoint (repeatable)")] = None,
    duration: Annotated[float, typer.Option(help="stop after this many seconds (0: until Ctrl-C)")] = 0.0,
) -> None:
    """Print contact made / broken events as they happen (zenoh peer, no multicast scouting)."""
    ks = KeySpace(default_site(site))
    transport = open_tool_session(connect)
    done = threading.Event()
    count = 0

    def show(msg: ContactEventMsg) -> None:
        nonlocal count
        count += 1
        console.print(format_event(msg))

    sub = watch_events(transport, ks, robot, show, lambda e: console.print(f"[yellow]rejected:[/] {e}"))
    console.print(f"watching [bold]{ks.fused(robot or '*', 'events')}[/] (Ctrl-C to stop)")
    try:
        if duration > 0:
            done.wait(duration)
        else:
            while not done.is_set():
                time.sleep(0.2)
    except KeyboardInterrupt:
        console.print("interrupted")
    finally:
        sub.close()
        transport.close()
    console.print(f"{count} events")


def _pairs(items: list[str] | None, what: str) -> dict[str, str]:
    out = {}
    for item in items or ():
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise typer.BadParameter(f"{item!r}: expected NAME=VALUE", param_hint=what)
        out[name.strip()] = value.strip()
    return out


@app.command()
def refuse(recording: Annotated[Path, typer.Argument(help="an MCAP file written by contactflow record")],
           set_: Annotated[list[str] | None, typer.Option("--set", help="fusion parameter NAME=VALUE (repeatable), e.g. voxel_size=0.01")] = None,
           weight: Annotated[list[str] | None, typer.Option(help="generator weight GENERATOR=FACTOR on its likelihoods (repeatable)")] = None,
           robot: Annotated[str, typer.Option(help="the fused stream's robot segment (site: a shared integrator)")] = "*",
           grid: Annotated[bool, typer.Option("--grid", help="step every 1/rate_hz s from the clouds' stamps, not on the recorded loop's cycles (for another rate_hz or timeouts)")] = False,
           window: Annotated[float, typer.Option(help="s, largest time difference of a matched pair")] = 0.1,
           radius: Annotated[float, typer.Option(help="m, largest location difference of a matched pair")] = 0.03,
           out: Annotated[Path | None, typer.Option(help="write the comparison as JSON here")] = None) -> None:
    """Re-fuse a recording's hypothesis clouds with other parameters and compare with its recorded events."""
    from contactflow.deploy.recording import Recording, RecordingError
    from contactflow.fusion.messages import ContactList, HypothesisCloud
    from contactflow.fusion.refusion import EventRecord, compare, refuse
    from contactflow.fusion.service import FusionParams
    from contactflow.nodes.params import ParamError, replace_params

    try:
        params = replace_params(FusionParams(), _pairs(set_, "--set"), where="--set ")
        weights = {g: float(v) for g, v in _pairs(weight, "--weight").items()}
        rec = Recording.open(recording)
    except (ParamError, RecordingError, ValueError) as exc:
        console.print(f"[red]{exc}[/]")
        raise typer.Exit(2) from None
    ks = KeySpace(rec.site)
    events_key, contacts_key = ks.fused(robot, "events"), ks.fused(robot, "contacts")
    clouds, recorded, cycles = [], [], []
    for s in rec.samples():
        if isinstance(s.msg, HypothesisCloud):
            clouds.append(s.msg)
        elif isinstance(s.msg, ContactEventMsg) and key_matches(events_key, s.key):
            recorded.append(EventRecord.of(s.msg))
        elif isinstance(s.msg, ContactList) and key_matches(contacts_key, s.key):
            cycles.append(s.msg)
    loops = {c.hdr.source for c in cycles}
    if not grid and len(loops) > 1:
        console.print(f"[red]{recording}: the cycles of {len(loops)} fusion loops ({', '.join(sorted(loops))}): "
                      f"name one with --robot, or step on a grid with --grid[/]")
        raise typer.Exit(2)
    timing = "a grid" if grid or not cycles else f"the recorded loop's {len(cycles)} cycle{'s' if len(cycles) != 1 else ''}"
    try:
        refused = refuse(clouds, params, weights, None if grid else cycles)
    except (ValueError, WireError) as exc:
        console.print(f"[red]{exc}[/]")
        raise typer.Exit(2) from None
    cmp = compare(recorded, refused, window, radius)
    table = Table(title=f"re-fusion of {recording.name}: {len(clouds)} clouds on {timing}")
    for col in ("", "recorded", "re-fused"):
        table.add_column(col)
    for kind in sorted(set(cmp.recorded) | set(cmp.refused)):
        table.add_row(kind, str(cmp.recorded.get(kind, 0)), str(cmp.refused.get(kind, 0)))
    console.print(table)
    console.print(f"matched {cmp.matched} (within {window:g} s, {radius:g} m): |dt| mean {cmp.dt_mean * 1e3:.1f} ms, "
                  f"max {cmp.dt_max * 1e3:.1f} ms; distance mean {cmp.dist_mean * 1e3:.1f} mm, max {cmp.dist_max * 1e3:.1f} mm; "
                  f"unmatched {len(cmp.unmatched_recorded)} recorded, {len(cmp.unmatched_refused)} re-fused")
    if out is not None:
        out.write_text(json.dumps({"recording": str(recording), "clouds": len(clouds), "timing": timing,
                                   "params": params_dict(params),
                                   "weights": weights, **cmp.as_dict()}, indent=2))

