"""Example Abstract Task Descriptions: Fig. 7.2 and the §7.3 experiment (Fig. 7.4)."""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent


def path(name: str) -> Path:
    """Path of an example ATD file by name (``fig7_2.xml``, ``push_away.xml``, ...)."""
    p = HERE / name
    if not p.is_file():
        known = sorted(f.name for f in HERE.iterdir() if f.suffix in (".xml", ".yaml"))
        raise FileNotFoundError(f"no example ATD {name!r} (have: {', '.join(known)})")
    return p
