"""``contactflow demo``: the README's main command."""

from __future__ import annotations

from pathlib import Path

from contactflow.deploy import pipeline_demo


def run(out: Path, quick: bool = False) -> int:
    return pipeline_demo.run(out, quick=quick)
