"""Thesis task files (YAML): pick, place, pick-and-place, clear the table, empty a box."""

from __future__ import annotations

import pathlib

from contactflow.nodes.taskgraph import TaskGraph

TASKS_DIR = pathlib.Path(__file__).parent


def load(name: str = "thesis") -> tuple[dict[str, TaskGraph], str]:
    """Load and validate ``<name>.yaml`` of this folder: (tasks by name, main task)."""
    from contactflow.nodes.taskfile import load_tasks

    return load_tasks(TASKS_DIR / f"{name}.yaml")
