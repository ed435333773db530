"""``contactflow contacts``: watch fused contact events live."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Annotated

import typer
from rich.console import Console

from contactflow.fusion.messages import ContactEventMsg
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.session import default_site, open_tool_session
from contactflow.nodes.status import Event
from contactflow.nodes.transport import Handle, Transport
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
