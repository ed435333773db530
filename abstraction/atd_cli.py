"""``contactflow atd``: check an Abstract Task Description and translate it per robot."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from contactflow.abstraction.atd import AtdError, load_atd
from contactflow.abstraction.factory import MappingRefused, factory_for
from contactflow.abstraction.profiles import PROFILES
from contactflow.abstraction.translator import TranslationError, translate
from contactflow.nodes.taskgraph import REQUIRED, NodeKind

app = typer.Typer(help="Abstract Task Descriptions (thesis ch. 7): check and translate.",
                  no_args_is_help=True, pretty_exceptions_show_locals=False)
console = Console()


def _say(text: str) -> None:
    console.print(text, markup=False, highlight=False, soft_wrap=True)


def _load(atd_file: Path):
    try:
        return load_atd(atd_file)
    except AtdError as exc:
        console.print(f"[red]refused:[/] {atd_file}")
        for issue in exc.issues:
            _say(f"  {issue}")
        raise typer.Exit(2) from None


@app.command()
def check(atd_file: Path) -> None:
    """Parse and validate ATD_FILE (XML or YAML); list its states and transitions."""
    atd = _load(atd_file)
    table = Table(title=f"{atd.name}: {len(atd.states)} states, {len(atd.transitions)} transitions")
    for col in ("state", "type", "movement", "hand shape", "goal"):
        table.add_column(col)
    for s in atd.states:
        table.add_row(s.name, str(s.type), str(s.movement or ""), s.hand_shape,
                      " ".join(f"{c:g}" for c in s.goal) if s.goal else s.target_object)
    console.print(table)
    for t in atd.transitions:
        _say(f"  {t.origin} -> {t.destination}  on {' & '.join(str(e.event) for e in t.events)}")


@app.command("translate")
def translate_cmd(
    atd_file: Path,
    robot: Annotated[str, typer.Option("--robot", "-r", help="robot name, or 'all'")] = "all",
    yaml_out: Annotated[bool, typer.Option("--yaml", help="print the ESTD task file")] = False,
) -> None:
    """Translate ATD_FILE into each robot's task (ESTD), or say why a robot cannot run it."""
    atd = _load(atd_file)
    names = sorted(PROFILES) if robot == "all" else [robot]
    failed = 0
    for name in names:
        if name not in PROFILES:
            console.print(f"[red]unknown robot {name!r}[/] (known: {', '.join(sorted(PROFILES))})")
            raise typer.Exit(2)
        try:
            tr = translate(atd, factory_for(PROFILES[name]))
        except (TranslationError, MappingRefused) as exc:
            failed += 1
            console.print(f"[red]{name} refuses:[/]")
            for reason in getattr(exc, "reasons", [str(exc)]):
                _say(f"  {reason}")
            continue
        if yaml_out:
            _say(tr.to_yaml())
            continue
        table = Table(title=f"{name}: ESTD {tr.estd.name}")
        for col in ("ATD state", "primitive", "detectors / companions", "timeout s"):
            table.add_column(col)
        for nid, node in tr.estd.nodes.items():
            kind = node.type if node.kind is NodeKind.PRIMITIVE else str(node.kind)
            helpers = ", ".join(f"{h.name}={h.type}" for h in node.helpers)
            timeout = "" if node.kind.terminal else f"{tr.estd.timeout_of(node):g}"
            table.add_row(tr.states[nid], kind, helpers, timeout)
        console.print(table)
        unbound = [k for k, v in tr.estd.params.items() if v is REQUIRED]
        if unbound:
            _say(f"  plan must bind: {', '.join(unbound)}")
        for note in tr.notes:
            _say(f"  note: {note}")
    if failed:
        raise typer.Exit(1)
