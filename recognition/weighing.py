"""Weight W of a lifted object from wrist F/T readings (thesis ch. 8): before/after lift difference of the vertical force."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRAVITY = 9.81  # m/s^2


@dataclass(frozen=True)
class ForceAverage:
    """Mean vertical force (N, world z, on the hand) over a window, its standard error and sample count."""

    force_z: float
    sem: float
    samples: int


def average_force_z(forces: np.ndarray, where: str = "forces") -> ForceAverage:
    """Average the z component of (N, 3) world-axis forces; non-finite rows are dropped."""
    f = np.asarray(forces, dtype=np.float64)
    if f.size == 0:
        return ForceAverage(float("nan"), float("nan"), 0)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{where}: expected an (N, 3) array of forces, got shape {f.shape}")
    z = f[np.isfinite(f).all(axis=1), 2]
    if len(z) == 0:
        return ForceAverage(float("nan"), float("nan"), 0)
    sem = float(z.std(ddof=1) / np.sqrt(len(z))) if len(z) > 1 else float("inf")
    return ForceAverage(float(z.mean()), sem, len(z))


def lifted_weight(before: ForceAverage, after: ForceAverage) -> tuple[float, float]:
    """(W, std) in N: the held object pulls the hand down, so the vertical force drops by its weight."""
    return before.force_z - after.force_z, float(np.hypot(before.sem, after.sem))
