"""CLI of the embodiments area: list the registered robots, show one, write its composed URDF."""

from __future__ import annotations

import pathlib

import typer
from rich.console import Console
from rich.table import Table

from contactflow.embodiments import registry

app = typer.Typer(help="Simulated embodiments (robots as data).", no_args_is_help=True)


@app.command("list")
def list_robots() -> None:
    """Every registered embodiment with its arms, hands and sensors."""
    console = Console()
    table = Table(title="embodiments")
    for col in ("robot", "arms", "hands", "F/T", "tactile pads", "cameras"):
        table.add_column(col)
    for name in registry.names():
        s = registry.get(name)
        table.add_row(name, ", ".join(f"{a.name} ({len(a.joints)})" for a in s.arms),
                      ", ".join(f"{h.name} ({h.kind})" for h in s.hands),
                      ", ".join(f.name + (" (estimated)" if f.estimated else "") for f in s.fts),
                      str(sum(len(h.pads) for h in s.hands)), ", ".join(c.name for c in s.cameras) or "-")
    console.print(table)


@app.command()
def show(robot: str) -> None:
    """Capabilities, workspace, computers and controlled frames of one robot."""
    console = Console()
    try:
        s = registry.get(robot)
    except registry.RegistryError as exc:
        console.print(f"[red]{exc}[/red]")
        raise typer.Exit(2) from None
    console.print(f"[bold]{s.name}[/bold]: {s.description}")
    for a in s.arms:
        console.print(f"  arm {a.name}: {len(a.joints)} joints, controlled frame {a.ee_frame}, hand {a.hand or '-'}, F/T {a.ft or '-'}")
    if s.capabilities:
        c = s.capabilities
        console.print(f"  primitives: {', '.join(sorted(c.primitives))}")
        console.print(f"  workspace: {c.workspace_min} .. {c.workspace_max} m, payload {c.payload} kg")
    for comp in s.computers:
        console.print(f"  computer {comp.name} ({comp.role}): {', '.join(comp.modules)}")


@app.command()
def urdf(robot: str, out_dir: pathlib.Path = typer.Option(None, help="write here instead of the cache")) -> None:
    """Compose the robot's URDF from example-robot-data parts and print its path."""
    console = Console()
    try:
        path = registry.get(robot).urdf(out_dir)
    except registry.RegistryError as exc:
        console.print(f"[red]{exc}[/red]")
        raise typer.Exit(2) from None
    console.print(str(path))
