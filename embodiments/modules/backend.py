"""The robot backend the interface modules talk to; ``SimRobot`` implements it, a real driver could too."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np


class RobotBackend(Protocol):
    name: str
    failed: bool
    failure: str

    def joint_state(self) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]: ...

    def submit_joint_command(self, source: str, names: list[str], q: np.ndarray, qd: np.ndarray | None = None,
                             weight: float = 1.0) -> None: ...

    def ft(self, arm: str) -> Any: ...

    def tactile(self, hand: str) -> dict[str, np.ndarray]: ...

    def camera(self, name: str) -> Any: ...

    def ground_truth(self) -> Any: ...
