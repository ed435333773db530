"""``contactflow protocol``: the wire protocol's generated field tables."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from contactflow.nodes.fieldtables import DOC, missing, render

app = typer.Typer(no_args_is_help=True)
console = Console()


@app.callback()
def protocol() -> None:
    """The wire protocol (docs/protocol.md, docs/messages.md)."""


@app.command()
def fields(out: Annotated[Path, typer.Option(help="where to write the tables")] = DOC,
           check: Annotated[bool, typer.Option(help="only compare OUT with the code; exit 1 when it differs")] = False,
           ) -> None:
    """Write the field table of every wire message (docs/messages.md) from the msgspec structs."""
    gaps = missing()
    if gaps:
        console.print("[red]undocumented:[/]\n" + "\n".join(gaps))
        raise typer.Exit(1)
    text = render()
    if check:
        same = out.is_file() and out.read_text() == text
        console.print(f"{out}: {'up to date' if same else 'differs from the code; run contactflow protocol fields'}")
        raise typer.Exit(0 if same else 1)
    out.write_text(text)
    console.print(f"wrote {out} ({text.count(chr(10) + '### ')} types)")
