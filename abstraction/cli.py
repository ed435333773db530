"""``contactflow run`` and ``contactflow robots``: dispatch abstract tasks, list robots."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.live import Live
from rich.table import Table

from contactflow.abstraction.atd import AtdError, parse_atd, read_atd
from contactflow.abstraction.client import TaskFollow, close, dispatch, robots
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.session import default_site, open_tool_session

console = Console()


def parse_params(items: list[str] | None) -> dict[str, float | str | list[float]]:
    """``name=0.5,0.1,0.8`` → a list of floats; ``name=0.5`` → a float; else the string."""
    out: dict[str, float | str | list[float]] = {}
    for item in items or []:
        name, eq, value = item.partition("=")
        if not eq or not name:
            raise typer.BadParameter(f"{item!r} is not name=value")
        try:
            nums = [float(v) for v in value.split(",")]
            out[name] = nums if "," in value else nums[0]
        except ValueError:
            out[name] = value
    return out


def progress_table(follow: TaskFollow) -> Table:
    table = Table(title=f"task {follow.task_id}", expand=False)
    for col in ("robot", "attempt", "state", "last event", "transitions", "outcome"):
        table.add_column(col)
    rows: dict[str, dict[str, str]] = {}
    for m in follow.progress:
        if m.robot == "broker":
            continue
        r = rows.setdefault(m.robot, {"attempt": "1", "state": "", "event": "", "edges": "0", "outcome": ""})
        r["attempt"] = str(m.attempt)
        if m.kind in ("entered", "started") and m.state:
            r["state"] = m.state
        if m.event or m.concrete:
            r["event"] = f"{m.event or '-'} ({m.concrete})" if m.concrete else m.event
        if m.kind == "edge":
            r["edges"] = str(int(r["edges"]) + 1)
        if m.final:
            r["outcome"] = m.outcome
    for robot, r in sorted(rows.items()):
        colour = {"success": "green", "": "white"}.get(r["outcome"], "red")
        table.add_row(robot, r["attempt"], r["state"], r["event"], r["edges"], f"[{colour}]{r['outcome']}[/]")
    notes = [m for m in follow.progress if m.robot == "broker"]
    if notes:
        table.caption = " | ".join(f"{m.kind}: {m.detail.splitlines()[0] if m.detail else ''}" for m in notes[-3:])
    return table


def register(app: typer.Typer) -> None:
    @app.command("run")
    def run_cmd(task: Path,
                on: Annotated[str, typer.Option("--on", help="any | all | ROBOT")] = "any",
                param: Annotated[list[str] | None, typer.Option("--param", "-p", help="plan parameter name=value")] = None,
                site: Annotated[str | None, typer.Option("--site", "-s")] = None,
                connect: Annotated[list[str] | None, typer.Option("--connect", "-e")] = None,
                timeout: float = 600.0) -> None:
        """Dispatch an abstract task description (XML or YAML) and follow it live."""
        try:
            data = read_atd(task)  # read once: a pipe cannot be read again
            parse_atd(data, str(task))
        except AtdError as exc:
            console.print(f"[red]invalid ATD, not dispatched:[/]\n{exc}")
            raise typer.Exit(2) from None
        ks = KeySpace(default_site(site))
        t = open_tool_session(connect)
        follow: TaskFollow | None = None
        try:
            follow = dispatch(t, ks, data.decode("utf-8"), str(task), target=on, params=parse_params(param),
                              on_contact=lambda c: console.print(
                                  f"[magenta]contact[/] {c.robot}/{c.link} {c.event} at "
                                  f"({', '.join(f'{v:.3f}' for v in c.location)})"))
            if follow.reply is not None and not follow.reply.ok:
                console.print(f"[red]{follow.reply.error}[/]")
                for robot, reasons in sorted(follow.reply.refusals.items()):
                    console.print(f"  [bold]{robot}[/]: " + "; ".join(reasons))
                raise typer.Exit(1)
            console.print(f"dispatched to {', '.join(follow.reply.robots)}")
            with Live(progress_table(follow), console=console, refresh_per_second=4) as live:
                while not follow.done.wait(0.25):
                    live.update(progress_table(follow))
                    timeout -= 0.25
                    if timeout <= 0:
                        break
                live.update(progress_table(follow))
        finally:
            if follow is not None:
                close(follow)
            t.close()
        outcome = follow.outcome
        console.print(f"task {follow.task_id}: [bold]{outcome}[/] {follow.final.detail if follow.final else ''}")
        raise typer.Exit(0 if outcome == "success" else 1)

    @app.command("robots")
    def robots_cmd(site: Annotated[str | None, typer.Option("--site", "-s")] = None,
                   connect: Annotated[list[str] | None, typer.Option("--connect", "-e")] = None) -> None:
        """List the robots advertising on a site with their capabilities."""
        ks = KeySpace(default_site(site))
        t = open_tool_session(connect)
        try:
            caps = robots(t, ks)
        finally:
            t.close()
        table = Table(title=f"site {ks.site}: {len(caps)} robots")
        for col in ("robot", "node", "hand", "busy"):
            table.add_column(col, no_wrap=True)
        table.add_column("sensors")
        table.add_column("primitives")
        for c in caps:
            table.add_row(c.robot, c.node, c.hand, str(c.busy), ", ".join(c.sensors), ", ".join(c.primitives))
        console.print(table)
