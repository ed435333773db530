"""open3d, loaded on first use: its import takes 1.2 s (plotly and dash through open3d.visualization).

A process that only reads depth frames, vision or fusion messages (a world, a control node's robot
link, a probe, the CLI) never loads it; a module that meshes, fits planes or clusters calls
:func:`load` in its ``setup``, so its first step does not hold its loop on the import.
"""

from __future__ import annotations

from types import ModuleType


def load() -> ModuleType:
    """The open3d module (imported once, by the first call)."""
    import open3d

    return open3d
